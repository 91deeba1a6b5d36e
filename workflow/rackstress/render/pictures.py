"""The paper's false-colour stress pictures, a sheet like Fig. 12, a movie, and plots of a run.

``render(rundir, ...)`` (``rackstress render RUNDIR``) writes into ``RUNDIR/figures/``:

* ``{view}_{step:06d}.png`` — one picture per chosen frame and view, pyvista off-screen: every
  particle of the displayed parts as a sphere, grey (0.6, 0.6, 0.6) and translucent (α = 0.15)
  at zero stress, redder and more opaque as the stress grows, red and opaque (α = 1) at the top
  of the colour scale (Section 5.2); a colour bar with the measure and its units; the iteration
  at the bottom (as in Fig. 12). The scale's top is ``vmax`` if given, else the 99th percentile
  of the measure over the displayed particles in the chosen frames (one scale for all pictures
  and the movie, so they compare).
* ``sheet.png`` — the chosen frames side by side, one row per view (Fig. 12);
* ``movie.mp4`` (``movie=True``) — every frame of the run (at most ``movie_max_frames``, evenly
  strided) in the first view, H.264 through imageio-ffmpeg;
* ``stress_over_time.png`` — max and mean of the measure per displayed part against the
  iteration;
* ``com_path.png`` — each part's centre-of-mass path, top view (x–z) and side view (x–y);
* ``footprints.png`` — for a group of kind ``sediment``, its particles' deepest vertical
  displacement as a top-view map (skipped with a note when the scene has no sediment);
* ``render.json`` — what was rendered: measure, scale, frames asked and used, views, notes,
  timings.

Views, as Fig. 3, relative to the walking direction (MagPod walks towards +x, y is up, its right
side is +z): ``right`` looks from +z, ``left`` from −z, ``front`` from +x (at its face),
``back`` from −x, ``top`` from +y, ``iso`` from (+x, +y, +z). The camera is orthographic, follows
the displayed parts' centre, and keeps one scale for the whole render.

Which particles: the parts of kind other than ``rack`` and ``sediment`` are drawn coloured by
stress; racks are not drawn (the paper's invisible mechanism); a sediment is drawn as light grey
context (it has no rest shape; see ``footprints.png``). Frames asked for that the dump does not
hold are replaced by the nearest dumped frame, and ``render`` says so.

Files appear all at once: everything is written into a temporary directory that replaces
``figures/`` only when complete; on any error nothing of the render remains.
"""
from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rackstress.stress import MEASURES, PartMotion, StressInputError, load_run

#: The iterations of the paper's Fig. 12.
PAPER_FRAMES = (1320, 2600, 4720, 17480)
DEFAULT_VIEWS = ("right", "front", "left")
#: view → (direction from the focal point to the camera, view-up).
VIEWS = {
    "right": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "left": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "front": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "back": ((-1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "top": ((0.0, 1.0, 0.0), (0.0, 0.0, -1.0)),
    "iso": ((1.0, 0.8, 1.0), (0.0, 1.0, 0.0)),
}
GREY = np.array([0.6, 0.6, 0.6])
RED = np.array([1.0, 0.0, 0.0])
ALPHA0 = 0.15
CONTEXT_RGB, CONTEXT_ALPHA = (0.78, 0.74, 0.66), 0.12
WINDOW = (1024, 768)
FIGURES = "figures"


@dataclass
class RenderReport:
    outdir: Path
    files: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    vmax: float = 0.0
    frames: list = field(default_factory=list)   # (requested, frame index, step)


# ----------------------------------------------------------------------------- colours
def stress_rgba(values: np.ndarray, vmax: float) -> np.ndarray:
    """Section 5.2's colouring: grey translucent at 0 → red opaque at vmax (uint8 RGBA)."""
    s = np.clip(np.nan_to_num(np.asarray(values, float), nan=0.0) / vmax, 0.0, 1.0)
    rgb = GREY[None, :] * (1.0 - s[:, None]) + RED[None, :] * s[:, None]
    alpha = ALPHA0 + (1.0 - ALPHA0) * s
    return np.round(np.column_stack([rgb, alpha]) * 255).astype(np.uint8)


def _bar_cmap():
    from matplotlib.colors import ListedColormap

    s = np.linspace(0.0, 1.0, 256)
    return ListedColormap(GREY[None, :] * (1 - s[:, None]) + RED[None, :] * s[:, None])


def _pyvista():
    if not os.environ.get("DISPLAY"):
        # no X server: render through EGL, without VTK first trying (and warning about) X
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    pv.OFF_SCREEN = True
    return pv


def _radius(o: np.ndarray) -> float:
    """Half the typical nearest-neighbour distance (the particles of a part touch)."""
    if len(o) < 2:
        return 0.5
    from scipy.spatial import cKDTree

    d = cKDTree(o).query(o, k=2)[0][:, 1]
    return 0.5 * float(np.median(d))


# ----------------------------------------------------------------------------- the painter
class Painter:
    """One off-screen pyvista plotter for one view; ``paint`` a frame → RGB image array."""

    def __init__(self, run, view: str, vmax: float, label: str, half_height: float,
                 window_size=WINDOW, title: str = ""):
        pv = _pyvista()
        if view not in VIEWS:
            raise StressInputError(f"unknown view '{view}'; views: {', '.join(VIEWS)}")
        self.run, self.view, self.vmax = run, view, vmax
        self.pl = pv.Plotter(off_screen=True, window_size=list(window_size))
        self.pl.set_background("white")
        # No depth peeling: with EGL/Mesa it drops sphere-imposter points altogether. Points are
        # drawn back to front instead (``paint`` sorts them), which blends translucency right.
        px_per_unit = window_size[1] / (2.0 * half_height)
        self.meshes = []
        o = run.o
        for part in run.displayed():
            mesh = pv.PolyData(o[part.index].copy())
            mesh.point_data["rgba"] = np.zeros((part.n, 4), dtype=np.uint8)
            size = max(2.0, 2.0 * _radius(o[part.index]) * px_per_unit)
            actor = self.pl.add_mesh(mesh, scalars="rgba", rgba=True, point_size=size,
                                     render_points_as_spheres=True, show_scalar_bar=False)
            self.meshes.append((part, actor.mapper.dataset))
        self.context = []
        for part in run.context():
            mesh = pv.PolyData(o[part.index].copy())
            size = max(2.0, 2.0 * _radius(o[part.index]) * px_per_unit)
            actor = self.pl.add_mesh(mesh, color=CONTEXT_RGB, opacity=CONTEXT_ALPHA,
                                     point_size=size, render_points_as_spheres=True)
            self.context.append((part, actor.mapper.dataset))
        bar = pv.PolyData(np.zeros((2, 3)))
        self.pl.add_mesh(bar, scalars=np.array([0.0, vmax]), cmap=_bar_cmap(), clim=(0.0, vmax),
                         opacity=0.0, show_scalar_bar=True,
                         scalar_bar_args=dict(title=label, color="black", vertical=False,
                                              position_x=0.5, position_y=0.86, width=0.46,
                                              height=0.08, title_font_size=16,
                                              label_font_size=14, fmt="%.3g", n_labels=5))
        self.pl.add_text(title, position="upper_left", font_size=10, color="black")
        self.step_text = self.pl.add_text(" ", position="lower_edge", font_size=16,
                                          color="black")
        direction, up = VIEWS[view]
        cam = self.pl.camera
        cam.parallel_projection = True
        self.direction = np.asarray(direction) / np.linalg.norm(direction)
        cam.up = up
        cam.parallel_scale = half_height
        self.half_height = half_height

    def paint(self, p: np.ndarray, values: np.ndarray, step: int, centre: np.ndarray):
        for part, mesh in self.meshes:
            q = p[part.index]
            order = np.argsort(q @ self.direction, kind="stable")   # farthest first
            mesh.points = q[order]
            mesh.point_data["rgba"] = stress_rgba(values[part.index][order], self.vmax)
            mesh.Modified()
        for part, mesh in self.context:
            q = p[part.index]
            mesh.points = q[np.argsort(q @ self.direction, kind="stable")]
            mesh.Modified()
        cam = self.pl.camera
        cam.focal_point = tuple(centre)
        cam.position = tuple(centre + self.direction * 10.0 * self.half_height)
        cam.parallel_scale = self.half_height
        self.pl.renderer.ResetCameraClippingRange()
        self.step_text.set_text("lower_edge", f"{step} iterations")
        self.pl.render()
        return self.pl.screenshot(return_img=True)

    def close(self):
        self.pl.close()


def _screen_axes(view: str):
    direction, up = VIEWS[view]
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    u = np.asarray(up, float) - np.dot(up, d) * d
    u /= np.linalg.norm(u)
    return np.cross(u, d), u     # screen right, screen up


def _framing(motion, run, frames, view: str, aspect: float):
    """Centre per frame and one half-height that fits the displayed parts in all ``frames``."""
    names = motion.results.names
    cols = [names.index(p.name) for p in run.displayed()] or list(range(len(names)))
    lo = motion.results.lo[:, cols].min(axis=1)
    hi = motion.results.hi[:, cols].max(axis=1)
    centre = 0.5 * (lo + hi)
    right, up = _screen_axes(view)
    half = 0.5 * (hi - lo)[frames]                                   # (k, 3)
    ext_up = np.abs(half) @ np.abs(up)
    ext_right = np.abs(half) @ np.abs(right)
    radius = max([_radius(run.o[p.index]) for p in run.displayed()] or [0.5])
    h = float(max(ext_up.max(), ext_right.max() / aspect)) + 2 * radius
    return centre, 1.12 * max(h, 1e-6)


# ----------------------------------------------------------------------------- render
def default_iterations(run) -> list:
    """The paper's Fig. 12 iterations if the run reaches them; else 4 spread over the run."""
    last = int(run.steps[-1])
    if last >= PAPER_FRAMES[-1]:
        return list(PAPER_FRAMES)
    return sorted({int(round(last * q)) for q in (0.25, 0.5, 0.75, 1.0)})


def _choose_vmax(values, run, frames, vmax, notes) -> float:
    if vmax is not None:
        if not vmax > 0:
            raise StressInputError(f"--vmax must be positive, got {vmax}")
        return float(vmax)
    idx = np.concatenate([p.index for p in run.displayed()] or [np.arange(run.n_atoms)])
    sel = values[np.ix_(frames, idx)]
    sel = sel[np.isfinite(sel)]
    v = float(np.percentile(sel, 99)) if sel.size else 0.0
    if not v > 0:
        notes.append("the measure is zero on every displayed particle of the chosen frames; "
                     "colour scale set to 0..1")
        return 1.0
    return v


def render(rundir, frames=None, measure: str = "paper", views=DEFAULT_VIEWS, movie: bool = False,
           vmax: float | None = None, allow_truncated: bool = False, window_size=WINDOW,
           movie_max_frames: int = 400, fps: int = 10, plots: bool = True) -> RenderReport:
    """Render the pictures, sheet, optional movie and plots of a run into RUNDIR/figures/."""
    t0 = time.perf_counter()
    rundir = Path(rundir)
    if measure not in MEASURES:
        raise StressInputError(f"unknown measure '{measure}'; measures: {', '.join(MEASURES)}")
    views = list(views)
    if not views:
        raise StressInputError("no view given; views: " + ", ".join(VIEWS))
    for v in views:
        if v not in VIEWS:
            raise StressInputError(f"unknown view '{v}'; views: {', '.join(VIEWS)}")
    run = load_run(rundir, allow_truncated=allow_truncated)
    report = RenderReport(rundir / FIGURES)
    if run.truncation:
        report.notes.append(f"{run.truncation}; rendering the complete frames only")
    if not run.displayed():
        raise StressInputError(f"{rundir}: no part to draw (every group is a rack or sediment)")
    t = time.perf_counter()
    ana = MEASURES[measure](run).run()
    motion = PartMotion(run).run()
    report.timings["load+analyse_s"] = time.perf_counter() - t0
    values = ana.results.per_particle
    label = f"{ana.LABEL} [{ana.UNITS}]"
    asked = list(frames) if frames else default_iterations(run)
    report.frames = run.nearest_frames(asked)
    for req, k, step in report.frames:
        if req != step:
            report.notes.append(f"iteration {req} is not in the dump; using the nearest frame, "
                                f"iteration {step}")
    fidx = [k for _, k, _ in report.frames]
    report.vmax = _choose_vmax(values, run, fidx, vmax, report.notes)

    tmp = rundir / f".{FIGURES}.tmp{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        t = time.perf_counter()
        pictures = _pictures(run, motion, values, report, views, label, window_size, tmp)
        report.timings["pictures_s"] = time.perf_counter() - t
        t = time.perf_counter()
        _sheet(pictures, report, views, tmp / "sheet.png")
        report.files.append("sheet.png")
        report.timings["sheet_s"] = time.perf_counter() - t
        if movie:
            t = time.perf_counter()
            n = _movie(run, motion, values, report, views[0], label, window_size,
                       movie_max_frames, fps, tmp / "movie.mp4")
            report.files.append("movie.mp4")
            report.timings["movie_s"] = time.perf_counter() - t
            report.timings["movie_frames"] = n
        if plots:
            t = time.perf_counter()
            _plots(run, ana, motion, report, tmp)
            report.timings["plots_s"] = time.perf_counter() - t
        report.timings["total_s"] = time.perf_counter() - t0
        manifest = {"rundir": str(rundir), "measure": measure, "label": label,
                    "vmax": report.vmax, "views": views,
                    "frames": [{"requested": r, "frame": k, "iteration": s}
                               for r, k, s in report.frames],
                    "files": report.files, "notes": report.notes, "timings": report.timings}
        (tmp / "render.json").write_text(json.dumps(manifest, indent=2) + "\n")
        report.files.append("render.json")
        _swap_in(tmp, rundir / FIGURES)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return report


def render_default(rundir) -> RenderReport:
    """What ``rackstress run`` renders at the end: the paper measure, default frames and views,
    sheet and plots (no movie)."""
    return render(rundir)


def _swap_in(tmp: Path, final: Path) -> None:
    old = final.with_name(f".{final.name}.old{os.getpid()}")
    if final.exists():
        os.replace(final, old)
    os.replace(tmp, final)
    if old.exists():
        shutil.rmtree(old, ignore_errors=True)


def _pictures(run, motion, values, report, views, label, window_size, out: Path) -> dict:
    """{(view, frame index): image} and the PNGs."""
    from matplotlib import image as mpimg

    images = {}
    fidx = [k for _, k, _ in report.frames]
    aspect = window_size[0] / window_size[1]
    title = f"{run.scene.get('scene', run.rundir.name)} — "
    for view in views:
        centre, half = _framing(motion, run, fidx, view, aspect)
        painter = Painter(run, view, report.vmax, label, half, window_size,
                          title=title + f"{view} view")
        try:
            for _, k, step in report.frames:
                if (view, k) in images:
                    continue
                ts = run.trajectory[k]
                p = np.asarray(ts.data["positions64"])
                img = painter.paint(p, values[k], step, centre[k])
                images[(view, k)] = img
                name = f"{view}_{step:06d}.png"
                mpimg.imsave(out / name, img)
                report.files.append(name)
        finally:
            painter.close()
    return images


def _sheet(images, report, views, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = []
    for _, k, step in report.frames:
        if (k, step) not in cols:
            cols.append((k, step))
    h, w = next(iter(images.values())).shape[:2]
    fig, axes = plt.subplots(len(views), len(cols), squeeze=False,
                             figsize=(3.2 * len(cols), 3.2 * len(views) * h / w + 0.3))
    for r, view in enumerate(views):
        for c, (k, step) in enumerate(cols):
            ax = axes[r][c]
            ax.imshow(images[(view, k)])
            ax.set_axis_off()
        axes[r][0].text(-0.02, 0.5, view, transform=axes[r][0].transAxes, rotation=90,
                        ha="right", va="center", fontsize=9)
    fig.tight_layout(pad=0.3)
    fig.savefig(path, dpi=200)
    plt.close(fig)


def _movie(run, motion, values, report, view, label, window_size, max_frames, fps,
           path: Path) -> int:
    import imageio_ffmpeg

    n = run.index.n_frames
    stride = max(1, int(np.ceil(n / max_frames)))
    ks = list(range(0, n, stride))
    if ks[-1] != n - 1:
        ks.append(n - 1)
    aspect = window_size[0] / window_size[1]
    centre, half = _framing(motion, run, ks, view, aspect)
    w, h = (int(window_size[0]) // 16 * 16, int(window_size[1]) // 16 * 16)
    painter = Painter(run, view, report.vmax, label, half, (w, h),
                      title=f"{run.scene.get('scene', run.rundir.name)} — {view} view")
    writer = imageio_ffmpeg.write_frames(str(path), (w, h), fps=fps, codec="libx264",
                                         pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
                                         macro_block_size=16, quality=7,
                                         ffmpeg_log_level="error")
    writer.send(None)
    try:
        for k in ks:
            ts = run.trajectory[k]
            img = painter.paint(np.asarray(ts.data["positions64"]), values[k],
                                int(run.steps[k]), centre[k])
            writer.send(np.ascontiguousarray(img[:h, :w, :3]).tobytes())
    finally:
        writer.close()
        painter.close()
    return len(ks)


def _plots(run, ana, motion, report, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = ana.results.steps
    parts = run.displayed()
    fig, ax = plt.subplots(figsize=(7, 4))
    for k, part in enumerate(parts):
        pp = ana.results.per_part[part.name]
        colour = f"C{k % 10}"
        ax.plot(steps, pp["max"], color=colour, label=f"{part.name} max")
        ax.plot(steps, pp["mean"], color=colour, ls="--", label=f"{part.name} mean")
    ax.set_xlabel("iteration")
    ax.set_ylabel(f"{ana.LABEL}\n[{ana.UNITS}]")
    ax.set_title(f"{run.scene.get('scene', '')}: stress per part over time")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(out / "stress_over_time.png", dpi=130)
    plt.close(fig)
    report.files.append("stress_over_time.png")

    names = motion.results.names
    moving = parts
    fig, (top, side) = plt.subplots(1, 2, figsize=(10, 4))
    for k, part in enumerate(moving):
        c = motion.results.com[:, names.index(part.name)]
        for ax, (a, b) in ((top, (0, 2)), (side, (0, 1))):
            ax.plot(c[:, a], c[:, b], color=f"C{k % 10}", label=part.name)
            ax.plot(c[0, a], c[0, b], "o", color=f"C{k % 10}", ms=4)
            ax.plot(c[-1, a], c[-1, b], "s", color=f"C{k % 10}", ms=4)
    top.set(xlabel="x", ylabel="z", title="centre of mass, top view (○ start, □ end)")
    side.set(xlabel="x", ylabel="y", title="centre of mass, side view")
    for ax in (top, side):
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    top.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "com_path.png", dpi=130)
    plt.close(fig)
    report.files.append("com_path.png")

    sediments = run.context()
    if not sediments:
        report.notes.append("no sediment group: footprints plot skipped")
        return
    fig, axes = plt.subplots(1, len(sediments), figsize=(8 * len(sediments), 4), squeeze=False)
    for ax, part in zip(axes[0], sediments):
        dy = motion.results.footprints[part.name]["min_dy"]
        o = run.o[part.index]
        lim = float(np.abs(dy).max()) or 1.0
        sc = ax.scatter(o[:, 0], o[:, 2], c=dy, cmap="RdBu", vmin=-lim, vmax=lim, s=6,
                        marker="s")
        com = motion.results.com[:, [names.index(p.name) for p in moving]]
        for j in range(com.shape[1]):
            ax.plot(com[:, j, 0], com[:, j, 2], lw=0.8, color="k", alpha=0.5)
        # frame the walk, not the whole sediment: the displaced particles and the path, padded
        moved = np.abs(dy) > 0.01 * lim
        pts = np.concatenate([o[moved][:, [0, 2]], com[:, :, [0, 2]].reshape(-1, 2)])
        pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts):
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            pad = 0.15 * float((hi - lo).max()) + 4.0
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal")
        ax.set(xlabel="x", ylabel="z",
               title=f"footprints in {part.name}: deepest vertical displacement "
                     f"(iterations {steps[0]}–{steps[-1]})")
        fig.colorbar(sc, ax=ax, label="vertical displacement [length units]")
    fig.tight_layout()
    fig.savefig(out / "footprints.png", dpi=130)
    plt.close(fig)
    report.files.append("footprints.png")
