"""The paper's false-colour stress pictures, a sheet like Fig. 12, a movie, and plots of a run.

``render(rundir, ...)`` (``rackstress render RUNDIR``) writes into ``RUNDIR/figures/`` (the paper
measure) or ``RUNDIR/figures/MEASURE/`` (any other measure), or ``out`` if given. It adds files
and replaces only files of the same name: renders never delete each other's pictures.

* ``{view}_{step:06d}.png`` — one picture per chosen frame and view, pyvista off-screen: every
  particle of the coloured parts as a sphere, grey (0.6, 0.6, 0.6) and translucent (α = 0.15) at
  zero stress, redder and more opaque as the stress grows, red and opaque (α = 1) at the top of the
  colour scale (Section 5.2; ``cmap`` swaps grey→red for a matplotlib colour map, keeping the
  opacity ramp). Above the model, never over it: the title, the colour bar with the measure and
  its units, the legend of parts (coloured, context, hidden) and the run's peak; in the picture
  the iteration (as in Fig. 12), each part's name beside it, and in the peak frame a ring round
  the peak particle.
* ``sheet.png`` — the chosen frames side by side, one row per view (Fig. 12), the peak frame
  marked;
* ``movie.mp4`` (``movie=True``) — every frame of the run (at most ``movie_max_frames``, evenly
  strided) in ``movie_view`` (default: the first view), H.264 through imageio-ffmpeg;
* ``stress_over_time.png`` — max and mean of the measure per coloured part against the
  iteration, the peak marked;
* ``com_path.png`` — each part's centre-of-mass path, top view (x–z) and side view (x–y);
* ``footprints.png`` — for a group of kind ``sediment``, its particles' deepest vertical
  displacement as a top-view map (skipped with a note when the scene has no sediment);
* ``render.json`` — what was rendered: measure, scale, peak, frames asked and used, parts,
  views, notes, timings.

**Frames.** By default four frames spread over the run (the paper's Fig. 12 iterations 1320,
2600, 4720, 17480 when the run reaches them) *and the peak frame* — the iteration at which the
measure is largest over the coloured parts. **Scale.** By default the colour scale runs from 0 to
that peak value, so the peak is never clipped; ``vmax`` sets it. The measures come from
:func:`rackstress.stress.post.compute_fields` (cached in ``RUNDIR/measures.npz``), the same
numbers as ``summary.json``'s peaks, the report and the VTK files; the paper measure uses the
robust fit everywhere.

**Views**, as Fig. 3, relative to the walking direction (MagPod walks towards +x, y is up, its
right side is +z): ``right`` looks from +z, ``left`` from −z, ``front`` from +x (at its face),
``back`` from −x, ``top`` from +y, ``iso`` from (+x, +y, +z). The camera is orthographic, follows
the coloured parts' centre, and keeps one scale for the whole render, fitted to the parts' own
extent (1st–99th percentile of their particles): a part that flew far from the others, or a few
particles that flew from their part, are left out of the framing with a note, so the rest does
not shrink to dots.

**Parts** (``groups``): by default the parts of kind other than ``rack`` and ``sediment`` are
coloured by stress, a sediment is light-sand context (it has no rest shape; see
``footprints.png``) and racks are hidden (the paper's invisible mechanism). ``groups=["body",
"leftleg"]`` shows only those (coloured, whatever their kind); ``groups=["-sediment"]`` hides one
from the default set.

**Speed.** One off-screen plotter serves every view and frame (points and colours are updated in
place, no multisampling: spheres are drawn as point sprites), pictures are read straight from the
render window and saved with light PNG compression, and the sheet is tiled with NumPy.

Frames asked for that the dump does not hold are replaced by the nearest dumped frame, and
``render`` says so. Everything is written into a temporary directory first and moved in only
when complete; on any error nothing of the render remains.
"""
from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rackstress.errors import EXIT_STORAGE, StorageError, storage_error
from rackstress.lib.jsonio import write_json
from rackstress.render.draw import (LABEL_H, PNG_COMPRESS, VIEWS, _inside, colour_bar,
                                    colour_table, ring_text_box, stress_rgba)
from rackstress.render.draw import font as _font
from rackstress.render.draw import offscreen as _offscreen
from rackstress.render.draw import part_radius as _part_radius
from rackstress.render.draw import screen_axes as _screen_axes
from rackstress.render.draw import snapshot
from rackstress.stress import PartMotion, StressInputError, load_run
from rackstress.stress.post import LABELS, compute_fields

#: The iterations of the paper's Fig. 12.
PAPER_FRAMES = (1320, 2600, 4720, 17480)
DEFAULT_VIEWS = ("right", "front", "left")
CONTEXT_RGB, CONTEXT_ALPHA = (0.78, 0.74, 0.66), 0.12
WINDOW = (1024, 768)
FIGURES = "figures"
#: Height of the strip above the model (title, colour bar, legend, peak): a multiple of 16.
HEADER_H = 112
#: A part whose centre is further than this many times the coloured parts' first-frame size
#: from the others' box has flown away; particles this many part sizes outside their part's
#: 1–99 % box likewise.
FLOWN = 2.0
#: the plots' PNG files likewise (matplotlib's default is zlib 6): the same pixels, magpod-small's
#: three 0.18 MB against 0.16 MB, encoded in 22 ms of CPU against 31
PLOT_PNG = {"compress_level": PNG_COMPRESS}


@dataclass
class RenderReport:
    outdir: Path
    files: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    vmax: float = 0.0
    frames: list = field(default_factory=list)   # (requested, frame index, step)
    peak: dict | None = None
    parts: dict = field(default_factory=dict)
    report: Path | None = None


# ----------------------------------------------------------------------------- parts
def select_parts(run, groups=None) -> tuple[list, list, list]:
    """(coloured parts, context parts, hidden names) for ``groups`` (module docstring)."""
    names = list(run.parts)
    if not groups:
        coloured = run.displayed()
        context = run.context()
    else:
        tokens = [g.strip() for g in groups if g and g.strip()]
        unknown = [t.lstrip("-") for t in tokens if t.lstrip("-") not in run.parts]
        if unknown:
            raise StressInputError(f"--groups: no part(s) {', '.join(unknown)} in {run.rundir}; "
                                   f"parts: {', '.join(names)}")
        shown = [t for t in tokens if not t.startswith("-")]
        hidden = {t[1:] for t in tokens if t.startswith("-")}
        if shown:
            coloured = [run.parts[n] for n in names if n in shown and n not in hidden]
            context = []
        else:
            coloured = [p for p in run.displayed() if p.name not in hidden]
            context = [p for p in run.context() if p.name not in hidden]
    if not coloured:
        raise StressInputError(f"{run.rundir}: no part to colour (parts: {', '.join(names)}; "
                               "every group is a rack or sediment, or --groups hid them all)")
    shown = {p.name for p in coloured + context}
    return coloured, context, [n for n in names if n not in shown]


# ----------------------------------------------------------------------------- framing
def _robust_box(q: np.ndarray):
    if len(q) >= 20:
        return np.quantile(q, 0.01, axis=0), np.quantile(q, 0.99, axis=0)
    return q.min(axis=0), q.max(axis=0)


def frame_boxes(run, positions: dict, parts, notes: list) -> dict:
    """Per frame index: (lo, hi) of the box to frame — the parts' own extent, without a part
    that flew away from the others or particles that flew away from their part (noted)."""
    allq = np.concatenate([run.o[p.index] for p in parts])      # the rest shape's size
    size0 = float(np.max(allq.max(axis=0) - allq.min(axis=0))) or 1.0
    flown_parts, flown_particles = {}, {}
    out = {}
    for k in sorted(positions):
        p = positions[k]
        boxes = {}
        for part in parts:
            q = p[part.index]
            lo, hi = _robust_box(q)
            ext = float(np.max(hi - lo)) or size0
            far = np.any((q < lo - FLOWN * ext) | (q > hi + FLOWN * ext), axis=1)
            if far.any() and part.name not in flown_particles:
                j = int(np.flatnonzero(far)[0])
                flown_particles[part.name] = (int(far.sum()), int(run.data.ids[part.index[j]]),
                                              int(run.steps[k]))
            boxes[part.name] = (lo, hi)
        keep = list(boxes)
        if len(boxes) > 1:
            for name, (lo, hi) in boxes.items():
                others = [boxes[n] for n in boxes if n != name]
                olo = np.min([b[0] for b in others], axis=0)
                ohi = np.max([b[1] for b in others], axis=0)
                c = 0.5 * (lo + hi)
                gap = float(np.linalg.norm(np.maximum(0, np.maximum(olo - c, c - ohi))))
                if gap > FLOWN * size0:
                    keep.remove(name)
                    flown_parts.setdefault(name, (gap, int(run.steps[k])))
            if not keep:
                keep = list(boxes)
        lo = np.min([boxes[n][0] for n in keep], axis=0)
        hi = np.max([boxes[n][1] for n in keep], axis=0)
        out[k] = (lo, hi)
    for name, (gap, step) in flown_parts.items():
        notes.append(f"warning: part {name} flew away ({gap:.3g} units from the other parts at "
                     f"iteration {step}); the pictures frame the other parts")
    for name, (count, pid, step) in flown_particles.items():
        notes.append(f"warning: {count} particle(s) of {name} flew away from their part (e.g. "
                     f"particle {pid} at iteration {step}); the pictures frame the part without "
                     "them")
    return out


def framing(run, positions: dict, parts, view: str, aspect: float, notes: list):
    """({frame: centre}, one half-height) fitting the parts' own extent in every frame."""
    boxes = frame_boxes(run, positions, parts, notes)
    right, up, _ = _screen_axes(view)
    centre, h = {}, 0.0
    for k, (lo, hi) in boxes.items():
        centre[k] = 0.5 * (lo + hi)
        half = 0.5 * (hi - lo)
        h = max(h, float(np.abs(half) @ np.abs(up)), float(np.abs(half) @ np.abs(right)) / aspect)
    radius = max(_part_radius(run, p) for p in parts)
    return centre, 1.1 * max(h + 2 * radius, 1e-6)


# ----------------------------------------------------------------------------- the painter
class Painter:
    """One off-screen VTK render window for every view and frame; ``paint`` → RGB uint8 image.

    Plain VTK (no pyvista plotter: importing its plotting layer costs more than painting a run's
    default pictures): one actor per part, spheres drawn as point sprites
    (``RenderPointsAsSpheres``), colours as direct RGBA scalars, no multisampling.
    """

    def __init__(self, run, coloured, context, vmax: float, cmap: str = "paper",
                 window_size=WINDOW):
        _offscreen()
        import vtkmodules.vtkRenderingOpenGL2  # noqa: F401 - registers the OpenGL classes
        from vtkmodules.vtkRenderingCore import (vtkActor, vtkPolyDataMapper, vtkRenderer,
                                                 vtkRenderWindow)

        self.run, self.vmax, self.cmap = run, vmax, cmap
        self.size = (int(window_size[0]), int(window_size[1]))
        self.ren = vtkRenderer()
        self.ren.SetBackground(1.0, 1.0, 1.0)
        self.rw = vtkRenderWindow()
        self.rw.SetOffScreenRendering(1)
        self.rw.SetMultiSamples(0)
        self.rw.AddRenderer(self.ren)
        self.rw.SetSize(*self.size)
        # No depth peeling: with EGL/Mesa it drops sphere-imposter points altogether. Points are
        # drawn back to front instead (``paint`` sorts them), which blends translucency right.
        o = run.o
        self.meshes, self.context = [], []
        for parts, group, rgba in ((coloured, self.meshes, True), (context, self.context, False)):
            for part in parts:
                poly = _points_poly(o[part.index])
                mapper = vtkPolyDataMapper()
                mapper.SetInputData(poly)
                actor = vtkActor()
                actor.SetMapper(mapper)
                prop = actor.GetProperty()
                prop.SetRenderPointsAsSpheres(True)
                if rgba:
                    mapper.ScalarVisibilityOn()
                    mapper.SetColorModeToDirectScalars()
                    mapper.SetScalarModeToUsePointData()
                else:
                    mapper.ScalarVisibilityOff()
                    prop.SetColor(*CONTEXT_RGB)
                    prop.SetOpacity(CONTEXT_ALPHA)
                self.ren.AddActor(actor)
                group.append((part, poly, actor, _part_radius(run, part)))
        self.ren.GetActiveCamera().ParallelProjectionOn()

    def project(self, q: np.ndarray, view: str, centre, half: float) -> np.ndarray:
        """Pixel (x, y from the top) of points q in a picture of ``view`` (orthographic)."""
        right, up, _ = _screen_axes(view)
        w, h = self.size
        s = 0.5 * h / half
        d = np.atleast_2d(q) - centre
        return np.column_stack([0.5 * w + (d @ right) * s, 0.5 * h - (d @ up) * s])

    def paint(self, p: np.ndarray, values: np.ndarray, view: str, centre, half: float):
        from vtkmodules.util.numpy_support import numpy_to_vtk

        right, up, direction = _screen_axes(view)
        px_per_unit = self.size[1] / (2.0 * half)
        for group, coloured in ((self.meshes, True), (self.context, False)):
            for part, poly, actor, r in group:
                q = p[part.index]
                order = np.argsort(q @ direction, kind="stable")   # farthest first
                poly.GetPoints().SetData(numpy_to_vtk(np.ascontiguousarray(q[order]), deep=True))
                if coloured:
                    rgba = stress_rgba(values[part.index][order], self.vmax, self.cmap)
                    arr = numpy_to_vtk(rgba, deep=True)
                    arr.SetName("rgba")
                    poly.GetPointData().SetScalars(arr)
                poly.Modified()
                actor.GetProperty().SetPointSize(max(2.0, 2.0 * r * px_per_unit))
        return snapshot(self.ren, self.rw, self.size, centre, up, direction, half)

    def warm(self) -> None:
        """Paint the rest shape once, unseen: the render window and its GL programs are made
        (a first picture's cost) before the pictures are asked for."""
        o = self.run.o
        lo, hi = o.min(axis=0), o.max(axis=0)
        self.paint(o, np.zeros(len(o)), DEFAULT_VIEWS[0], 0.5 * (lo + hi),
                   max(float(np.max(hi - lo)), 1e-6))

    def close(self):
        self.rw.Finalize()


#: painters made before their render (:func:`prepare_painter`), by :func:`_painter_key`
_READY: dict = {}


def _painter_key(run, coloured, context, cmap, size) -> tuple:
    return (str(Path(run.rundir).resolve()), tuple(p.name for p in coloured),
            tuple(p.name for p in context), cmap, tuple(int(x) for x in size))


def prepare_painter(run, cmap: str = "paper", sheet_only: bool = True) -> None:
    """Make, and paint once unseen (:meth:`Painter.warm`), the painter :func:`render` will ask
    for with the default parts of ``run`` (a run still being written will do: the painter
    holds its particles' rest positions and radii only), so that ``rackstress run``'s render
    starts painting at once (its head start, render/prepare.py); the colour scale is set
    when the render takes it."""
    coloured, context, _ = select_parts(run)
    size = (WINDOW[0] // 2, WINDOW[1] // 2) if sheet_only else WINDOW
    painter = Painter(run, coloured, context, 1.0, cmap, size)
    painter.warm()
    _READY[_painter_key(run, coloured, context, cmap, size)] = painter


def _take_painter(run, coloured, context, vmax: float, cmap: str, size):
    """The prepared painter of these parts and size, its colour scale set to ``vmax``, or a
    new one."""
    painter = _READY.pop(_painter_key(run, coloured, context, cmap, size), None)
    if painter is None:
        return Painter(run, coloured, context, vmax, cmap, size)
    painter.vmax = vmax
    return painter


def _points_poly(q: np.ndarray):
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData

    n = len(q)
    pts = vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(q, dtype=np.float64), deep=True))
    verts = vtkCellArray()
    verts.SetData(numpy_to_vtkIdTypeArray(np.arange(n + 1, dtype=np.int64), deep=True),
                  numpy_to_vtkIdTypeArray(np.arange(n, dtype=np.int64), deep=True))
    poly = vtkPolyData()
    poly.SetPoints(pts)
    poly.SetVerts(verts)
    return poly


# ----------------------------------------------------------------------------- annotations
def header_strip(width: int, title: str, label: str, vmax: float, cmap: str, legend: list,
                 peak_line: str, height: int = HEADER_H) -> np.ndarray:
    """The strip above a picture: title, legend and peak on the left, colour bar on the right."""
    from PIL import Image, ImageDraw

    img = Image.new("RGB", (width, height), "white")
    dr = ImageDraw.Draw(img)
    big, small = _font(17), _font(13)
    dr.text((10, 6), title, fill="black", font=big)
    y = 32
    for text, colour in legend:
        dr.rectangle([10, y + 3, 22, y + 15], fill=colour, outline="black")
        dr.text((28, y), text, fill="black", font=small)
        y += 18
    if peak_line:
        dr.text((10, y), peak_line, fill=(150, 0, 0), font=small)
    return np.asarray(colour_bar(img, int(0.55 * width), int(0.96 * width), label, vmax, cmap))


def annotate(img: np.ndarray, step: int, view: str, labels: list, ring=None,
             ring_text: str = "") -> np.ndarray:
    """The iteration at the bottom (Fig. 12), the view, part names, a ring round the peak.

    The ring and its text come first; each part name is then placed where it covers neither
    (:func:`place_labels`): a name under its part's anchor used to land on the ring."""
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    dr = ImageDraw.Draw(im)
    w, h = im.size
    f16, f13 = _font(18), _font(13)
    text = f"{step} iterations"
    dr.text(((w - dr.textlength(text, font=f16)) / 2, h - 30), text, fill="black", font=f16)
    dr.text((8, h - 24), f"{view} view", fill=(80, 80, 80), font=f13)
    taken = []
    if ring is not None:
        x, y, r = ring
        if -r <= x < w + r and -r <= y < h + r:
            dr.ellipse([x - r, y - r, x + r, y + r], outline=(0, 0, 0), width=3)
            dr.ellipse([x - r - 3, y - r - 3, x + r + 3, y + r + 3], outline=(255, 255, 255),
                       width=2)
            tw = dr.textlength(ring_text, font=f13)
            box = ring_text_box(x, y, r, tw, LABEL_H, w, h)
            dr.text(box[:2], ring_text, fill="black", font=f13)
            taken += [(x - r - 5, y - r - 5, x + r + 5, y + r + 5), box]
    shown = [(name, (x, y)) for name, (x, y) in labels if 0 <= x < w and 0 <= y < h]
    widths = [dr.textlength(name, font=f13) for name, _ in shown]
    for (name, _), box in zip(shown, place_labels([a for _, a in shown], widths, taken, w, h)):
        dr.text(box[:2], name, fill=(40, 40, 160), font=f13)
    return np.asarray(im)


def _overlaps(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def place_labels(anchors, widths, taken, w, h, th: int = LABEL_H) -> list:
    """Boxes (x0, y0, x1, y1) for part names: under each anchor (a part's projected point),
    or, where that would cover a box in ``taken`` (the peak ring, its text, a name placed
    before), the nearest of below, above, left or right of what it would cover."""
    boxes = []
    for (x, y), tw in zip(anchors, widths):
        x0, y0 = _inside(x - tw / 2, tw, w), min(h - 48, y + 14)
        candidates = [(x0, y0)]
        for t in taken:
            candidates += [(x0, t[3] + 3), (x0, t[1] - 3 - th), (t[0] - 4 - tw, y0),
                           (t[2] + 4, y0)]
        best = None
        for cx, cy in candidates:
            cx, cy = _inside(cx, tw, w), min(max(cy, 2), h - 48)
            box = (cx, cy, cx + tw, cy + th)
            if not any(_overlaps(box, t) for t in taken):
                dist = abs(cx - x0) + abs(cy - y0)
                if best is None or dist < best[0]:
                    best = (dist, box)
        box = best[1] if best is not None else (x0, y0, x0 + tw, y0 + th)
        boxes.append(box)
        taken = [*taken, box]
    return boxes


def _save_png(path: Path, img: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(img).save(path, compress_level=PNG_COMPRESS)


class _Saver:
    """PNG files written by a thread while the next picture renders (zlib releases the GIL)."""

    def __init__(self):
        from concurrent.futures import ThreadPoolExecutor

        self.pool = ThreadPoolExecutor(max_workers=1)
        self.futures = []

    def save(self, path: Path, img: np.ndarray) -> None:
        self.futures.append(self.pool.submit(_save_png, path, img))

    def wait(self) -> None:
        try:
            for f in self.futures:
                f.result()
        finally:
            self.pool.shutdown(wait=True)


# ----------------------------------------------------------------------------- choices
def default_iterations(run, peak_iteration: int | None = None) -> list:
    """For MagPod, the paper's Fig. 12 iterations if the run reaches them; else 4 spread over
    the run, the last included; and the peak iteration."""
    last = int(run.steps[-1])
    if str(run.scene.get("scene", "")).startswith("magpod") and last >= PAPER_FRAMES[-1]:
        its = set(PAPER_FRAMES)
    else:
        its = {int(round(last * q)) for q in (0.25, 0.5, 0.75, 1.0)}
    if peak_iteration is not None:
        its.add(int(peak_iteration))
    return sorted(its)


def find_peak(run, values: np.ndarray, parts) -> dict | None:
    """Largest value over the whole run among ``parts``: value, frame, iteration, particle."""
    best = None
    for part in parts:
        sub = values[:, part.index]
        fin = np.isfinite(sub)
        if not fin.any():
            continue
        flat = int(np.argmax(np.where(fin, sub, -np.inf)))
        k, j = divmod(flat, sub.shape[1])
        if best is None or sub[k, j] > best["value"]:
            best = {"value": float(sub[k, j]), "frame": int(k), "iteration": int(run.steps[k]),
                    "group": part.name, "row": int(part.index[j]), "index": int(j),
                    "particle": int(run.data.ids[part.index[j]])}
    return best


def output_dir(rundir: Path, measure: str, out=None, default: str = "paper") -> Path:
    """``out``, else ``RUNDIR/figures`` (the run's default measure: von Mises stress for a scene
    with a material, else the paper's) or ``RUNDIR/figures/MEASURE``."""
    if out is not None:
        return Path(out)
    return rundir / FIGURES if measure == default else rundir / FIGURES / measure


# ----------------------------------------------------------------------------- render
def _first_nonfinite(run) -> int | None:
    """The iteration of the first dumped frame with a non-finite position (None: all finite)."""
    for k, ts in enumerate(run.trajectory):
        if not np.isfinite(ts.positions).all():
            return int(run.steps[k])
    return None


def render(rundir, frames=None, measure: str | None = None, views=DEFAULT_VIEWS, movie: bool = False,
           vmax: float | None = None, allow_truncated: bool = False, window_size=WINDOW,
           movie_max_frames: int = 400, fps: int = 10, plots: bool = True, groups=None,
           out=None, cmap: str = "paper", movie_view: str | None = None,
           progress: bool = False, sheet_only: bool = False, meanwhile=None,
           beside=None) -> RenderReport:
    """Render the pictures, sheet, optional movie and plots of a run (module docstring).

    Parameters
    ----------
    rundir : path
        A run directory.
    frames : list of int, optional
        Iterations to picture (nearest dumped frame); default: spread over the run + the peak.
    measure : str, optional
        ``paper``, ``accumulated``, ``strain``, ``d2min``, ``virial`` or ``von_mises``; default:
        ``von_mises`` (in the scene's stress unit) for a scene with a material, else ``paper``.
    views : list of str
        Any of ``right, left, front, back, top, iso``.
    movie, movie_view : bool, str
        Also write ``movie.mp4`` of ``movie_view`` (default: the first view).
    vmax : float, optional
        Top of the colour scale; default: the peak over the coloured parts.
    groups : list of str, optional
        Parts to show (``body``) or hide (``-sediment``).
    out : path, optional
        Output folder (default ``RUNDIR/figures`` or ``RUNDIR/figures/MEASURE``).
    cmap : str
        ``paper`` (grey→red) or a matplotlib colour map name.
    progress : bool
        A progress bar on a terminal.
    sheet_only : bool
        Paint only ``sheet.png``, each cell at half the window's size (what the report shows;
        ``rackstress run``'s default), and no ``{view}_{step}.png``: a third of the painting
        time and a seventh of the bytes.
    meanwhile : callable, optional
        ``meanwhile(report, measure, cmap)``, called once the pictures are painted, while the
        plots' process is still drawing.
    beside : (work, done), optional
        ``work(report, measure, cmap)`` in the plots' forked process once they are drawn
        (without plots, in a forked child of its own: :class:`~rackstress.runs.forked.ForkedJob`,
        the other core), its JSON-able result handed to ``done`` once the pictures are
        painted (``rackstress run`` builds the 3D view so).

    Returns
    -------
    RenderReport

    Example
    -------
    >>> rep = render("runs/plane-rack", views=["right", "top"], movie=True)   # doctest: +SKIP
    >>> rep.peak["iteration"], rep.vmax                                       # doctest: +SKIP
    """
    from rackstress.lib.progress import progress_bar

    t0, c0 = time.perf_counter(), time.process_time()
    rundir = Path(rundir)
    from rackstress.stress.headline import is_static

    if is_static(rundir):           # one state, no time: the part's surface (render/static.py)
        from rackstress.render.static import STATIC_VIEWS

        if frames or movie:
            raise StressInputError(
                f"{rundir} is a static analysis: it has one state, the equilibrium, so "
                f"{'--frames' if frames else '--movie'} has nothing to choose from; render it "
                "without")
        return render_static(rundir, measure=measure,
                             views=STATIC_VIEWS if list(views) == list(DEFAULT_VIEWS) else views,
                             vmax=vmax, cmap=cmap, out=out, progress=progress, beside=beside,
                             groups=groups,
                             window_size=None if tuple(window_size) == WINDOW else window_size)
    if measure is not None and measure not in LABELS:
        raise StressInputError(f"unknown measure '{measure}'; measures: {', '.join(LABELS)}")
    views = list(views)
    if not views:
        raise StressInputError("no view given; views: " + ", ".join(VIEWS))
    movie_view = movie_view or views[0]
    for v in [*views, movie_view]:
        if v not in VIEWS:
            raise StressInputError(f"unknown view '{v}'; views: {', '.join(VIEWS)}")
    if vmax is not None and not vmax > 0:
        raise StressInputError(f"--vmax must be positive, got {vmax}")
    if sheet_only and movie:
        raise StressInputError("a movie needs the full-size pictures: not with sheet_only")
    colour_table(cmap)                                         # fail early on a bad name
    run = load_run(rundir, allow_truncated=allow_truncated)
    report = RenderReport(None)
    if run.truncation:
        report.notes.append(f"{run.truncation}; rendering the complete frames only")
    coloured, context, hidden = select_parts(run, groups)
    report.parts = {"coloured": [p.name for p in coloured], "context": [p.name for p in context],
                    "hidden": hidden}
    try:
        fields = compute_fields(run, cache=True)
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        bad = _first_nonfinite(run)
        if bad is None:
            raise
        raise StressInputError(
            f"{rundir}: the frame of iteration {bad} in {run.index.path.name} holds non-finite "
            "positions (the run diverged there: see its summary.json), so no stress can be "
            "measured over the run; nothing was rendered") from None
    measure = measure or fields.default
    report.outdir = outdir = output_dir(rundir, measure, out, fields.default)
    if measure == "von_mises" and measure not in fields.values:
        raise StressInputError(
            f"{rundir}: no von Mises stress: it needs a part with a material and a volume "
            "(scene.json) and the run's bindings.npz, which runs of scenes with a material "
            "write; use --measure paper, accumulated, strain or d2min for this run")
    if measure not in fields.values:
        from rackstress.stress.measures import VirialStress

        VirialStress(run)                 # raises the clear error: the dump has no virial
    values = fields.values[measure]
    label = fields.label(measure)
    report.timings["load+measures_s"] = time.perf_counter() - t0
    peak = find_peak(run, values, coloured)
    if peak and measure in fields.units:          # the scene's own unit (MPa, mm) on the picture
        peak["units"] = fields.unit(measure)
    report.peak = peak
    if frames:
        asked = list(frames)
    else:
        asked = default_iterations(run, peak["iteration"] if peak else None)
    report.frames = run.nearest_frames(asked)
    for req, k, step in report.frames:
        if req != step:
            report.notes.append(f"iteration {req} is not in the dump; using the nearest frame, "
                                f"iteration {step}")
    if vmax is not None:
        report.vmax = float(vmax)
        if peak and peak["value"] > vmax:
            report.notes.append(f"the peak {peak['value']:.4g} is above --vmax {vmax:.4g}: "
                                "it shows clipped at full red")
    elif peak and peak["value"] > 0:
        report.vmax = peak["value"]
    else:
        report.vmax = 1.0
        report.notes.append("the measure is zero on every coloured particle; colour scale "
                            "set to 0..1")

    tmp = rundir / f".render.tmp{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        n_pics = len({k for _, k, _ in report.frames}) * len(views)
        movie_ks = _movie_frames(run, movie_max_frames) if movie else []
        # the plots (matplotlib) are drawn by a forked process while this one paints; with
        # ``beside``, that process does its work after the plots (one fork fewer on the way to
        # the first picture), forked once VTK's rendering classes are loaded (the painter's),
        # which it uses too
        plotter = side = None
        if plots and beside is None:
            plotter = _Background(_plots, run, values, label, coloured, context, report, tmp)
        with progress_bar(n_pics + len(movie_ks), progress, "pictures") as bar:
            bar.unit = "picture"
            t = time.perf_counter()
            cell = (window_size[0] // 2, window_size[1] // 2) if sheet_only else window_size
            painter = _take_painter(run, coloured, context, report.vmax, cmap, cell)
            if beside is not None and plots:
                plotter = _Background(_plots, run, values, label, coloured, context, report,
                                      tmp, then=lambda: beside[0](report, measure, cmap))
            elif beside is not None:
                from rackstress.runs.forked import ForkedJob

                side = ForkedJob(lambda: beside[0](report, measure, cmap), tmp / ".beside.json")
            try:
                # its rows compressed by a thread as they are painted (zlib lets go of the GIL)
                sheet = _Sheet(tmp / "sheet.png", run, report, views,
                               lambda width: _header(run, report, label, cmap, coloured,
                                                     context, hidden, width),
                               painter.size, reduce=not sheet_only)
                _pictures(run, painter, values, report, views, label, cmap, coloured,
                          context, hidden, tmp, bar, save=not sheet_only, sheet=sheet)
                report.timings["pictures_s"] = time.perf_counter() - t
                report.timings["pictures_cpu_s"] = time.process_time() - c0
                t = time.perf_counter()
                sheet.close()
                report.files.append("sheet.png")
                report.timings["sheet_s"] = time.perf_counter() - t
                if movie:
                    t = time.perf_counter()
                    _movie(run, painter, values, report, movie_view, label, cmap, coloured,
                           context, hidden, movie_ks, fps, tmp / "movie.mp4", bar)
                    report.files.append("movie.mp4")
                    report.timings["movie_s"] = time.perf_counter() - t
                    report.timings["movie_frames"] = len(movie_ks)
            finally:
                painter.close()
        if meanwhile is not None:
            t = time.perf_counter()
            meanwhile(report, measure, cmap)
            report.timings["meanwhile_s"] = time.perf_counter() - t
        if side is not None:
            done, side = side, None
            _join_beside(done, beside, report)
        if plotter is not None:
            t = time.perf_counter()
            files, notes, wall, then = plotter.join()
            report.files += files
            report.notes += notes
            report.timings["plots_s"] = wall
            report.timings["plots_wait_s"] = time.perf_counter() - t
            if plotter.job.cpu_s is not None:
                report.timings["plots_cpu_s"] = plotter.job.cpu_s - then["cpu_s"]
            if beside is not None:
                report.timings["beside_cpu_s"] = then["cpu_s"]
                beside[1](then["result"])
        report.timings["total_s"] = time.perf_counter() - t0
        report.timings["cpu_s"] = time.process_time() - c0
        manifest = {"rundir": str(rundir), "measure": measure, "label": label,
                    "fit": fields.fit, "vmax": report.vmax, "cmap": cmap, "views": views,
                    "movie_view": movie_view if movie else None,
                    "peak": report.peak, "parts": report.parts,
                    "frames": [{"requested": r, "frame": k, "iteration": s,
                                "peak": bool(peak and k == peak["frame"])}
                               for r, k, s in report.frames],
                    "files": report.files, "notes": report.notes, "timings": report.timings}
        write_json(tmp / "render.json", manifest)
        report.files.append("render.json")
        _move_in(tmp, outdir, check=out is not None)
    except BaseException as exc:
        if plots and "plotter" in locals() and plotter is not None:
            plotter.kill()
        if "side" in locals() and side is not None:
            side.kill()
        if "sheet" in locals():
            sheet.abort()                   # no write into tmp after it is gone
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError) and not isinstance(exc, StorageError) and exc.errno:
            raise storage_error(exc, "write the pictures into", outdir) from None
        raise
    return report


def render_static(rundir, measure: str | None = None, views=None,
                  vmax: float | None = None, cmap: str = "paper", out=None, window_size=None,
                  progress: bool = False, beside=None, groups=None):
    """The pictures of a static run (:mod:`rackstress.render.static`: the part's surface,
    deformed, the stress painted on it; the particles) into ``RUNDIR/figures`` (or ``out``).

    Parameters
    ----------
    rundir : path
        A static run directory (``analysis = "static"``).
    measure : str, optional
        Default: von Mises stress for a part with a material, else the paper's measure.
    views : list of str
        Of ``iso, front, right, top, left, back`` (:data:`rackstress.render.pictures.VIEWS`).
    vmax : float, optional
        Top of the colour scale (default: the headline's value, else the largest on the part).
    beside : (work, done), optional
        As :func:`rackstress.render.pictures.render`: ``work(report, measure, cmap)`` in a forked
        child (the 3D view) while the pictures are painted, its result handed to ``done``.

    Returns
    -------
    rackstress.render.pictures.RenderReport

    Example
    -------
    >>> rep = render_static("runs/cantilever")                   # doctest: +SKIP
    >>> rep.files                                                # doctest: +SKIP
    ['sheet.png', 'particles.png', 'render.json']
    """
    from rackstress.render.static import (CELL, RED, STATIC_VIEWS, SurfacePainter, _cell,
                                          _project, _save, _sheet, framing, header,
                                          magnification)
    from rackstress.stress.headline import headline, headline_text, unsettled_text
    from rackstress.stress.surface import surfaces_for

    t0, c0 = time.perf_counter(), time.process_time()
    rundir = Path(rundir)
    views = list(views or STATIC_VIEWS)
    for v in views:
        if v not in VIEWS:
            raise StressInputError(f"unknown view '{v}'; views: {', '.join(VIEWS)}")
    if measure is not None and measure not in LABELS:
        raise StressInputError(f"unknown measure '{measure}'; measures: {', '.join(LABELS)}")
    if vmax is not None and not vmax > 0:
        raise StressInputError(f"--vmax must be positive, got {vmax}")
    colour_table(cmap)
    run = load_run(rundir)
    fields = compute_fields(run, cache=True)
    measure = measure or fields.default
    if measure not in fields.values:
        raise StressInputError(f"{rundir}: no measure '{measure}' in this run; measures: "
                               f"{', '.join(fields.values)}")
    try:
        summary = json.loads((rundir / "summary.json").read_text())
    except (OSError, ValueError):
        summary = {}
    scene = run.scene or {}
    report = RenderReport(output_dir(rundir, measure, out, fields.default))
    coloured, _, hidden = select_parts(run, groups)
    report.parts = {"coloured": [p.name for p in coloured], "context": [], "hidden": hidden}
    t = time.perf_counter()
    surfaces = [s for s in surfaces_for(run, fields, notes=report.notes)
                if s.group in report.parts["coloured"]]
    report.timings["surface_s"] = time.perf_counter() - t
    k = len(run.steps) - 1
    p = np.asarray(run.trajectory[k].data["positions64"], dtype=np.float64)
    values = np.asarray(fields.values[measure][k], dtype=np.float64)
    for s in surfaces:                      # another measure than the surfaces carry
        if measure not in s.values:
            from rackstress.stress.surface import interpolate

            part = run.parts[s.group]
            col = values[part.index]
            s.values[measure] = interpolate(run.o[part.index],
                                            np.where(np.isfinite(col), col, 0.0), s.points,
                                            s.spacing)
    head = headline(summary, scene, rundir) if measure == fields.default else None
    label = fields.label(measure)
    idx = np.concatenate([q.index for q in coloured])
    top = float(np.nanmax(values[idx])) if np.isfinite(values[idx]).any() else 0.0
    if vmax is not None:
        report.vmax = float(vmax)
    elif head and head.get("value") and head["value"] > 0:
        report.vmax = float(head["value"])
    else:
        report.vmax = top if top > 0 else 1.0
    if top > report.vmax * (1 + 1e-9):
        report.notes.append(f"values up to {top:.4g} lie above the colour scale's top "
                            f"{report.vmax:.4g} (" + ("--vmax" if vmax is not None else
                            "the headline's, away from singular points") + "): full colour")
    # the magnification: the largest displacement about FRACTION of the parts' size
    u = p[idx] - run.o[idx]
    if not np.isfinite(u).all():        # a state that did not settle may hold anything
        report.notes.append(f"{int((~np.isfinite(u).all(axis=1)).sum())} particle(s) have no "
                            "finite position: drawn at their undeformed place")
        p[idx] = np.where(np.isfinite(p[idx]), p[idx], run.o[idx])
        u = p[idx] - run.o[idx]
        for s in surfaces:
            s.values["displacement"] = np.nan_to_num(s.values["displacement"], nan=0.0,
                                                     posinf=0.0, neginf=0.0)
    umax = float(np.linalg.norm(u, axis=1).max()) if len(u) else 0.0
    allpts = np.concatenate([s.points for s in surfaces]) if surfaces else run.o[idx]
    size = float(np.max(allpts.max(axis=0) - allpts.min(axis=0)))
    scale = magnification(umax, size)
    far = scale * umax > size           # the part come apart: its shape is no picture of it
    if far:
        report.notes.append(f"the largest displacement, {umax:.3g}, exceeds the part's size "
                            f"{size:.3g}: the pictures show the part undeformed")
        scale = 0.0
    units = ((scene.get("units") or {}).get("length")) or "length units"
    settled = summary.get("settled", True) is not False
    lines = []
    if not settled:
        lines.append((unsettled_text(summary, short=True), RED))
    elif head:                           # the safety on a line of its own: one line ran
        stress, _, safety = headline_text(head).partition("; ")    # under the colour bar
        lines += [(stress, (0, 0, 0))] + ([(safety, (0, 0, 0))] if safety else [])
    lines.append((f"deformed × {scale:g}: the largest displacement, {umax:.3g} {units}, drawn as "
                  f"{scale * umax:.3g} {units} ({100 * scale * umax / size:.2g} % of the part's "
                  f"size {size:.3g} {units})" if scale > 1 else
                  f"deformation drawn to scale (largest displacement {umax:.3g} {units})"
                  if scale == 1 else f"drawn undeformed: the largest displacement, {umax:.3g} "
                  f"{units}, exceeds the part's size", (0, 0, 0)))
    lines.append(("dark outline: the undeformed shape; positions in the part's own "
                  "(undeformed) coordinates", (90, 90, 90)))
    name = scene.get("scene", rundir.name)
    tmp = rundir / f".render.tmp{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    side = None
    try:
        if beside is not None:
            from rackstress.runs.forked import ForkedJob

            side = ForkedJob(lambda: beside[0](report, measure, cmap), tmp / ".beside.json")
        cw, ch = window_size or CELL
        aspect = cw / ch
        pts = [] if far else [s.points + scale * s.values["displacement"] for s in surfaces]
        frame_pts = np.concatenate(pts + [s.points for s in surfaces]) if surfaces else run.o[idx]
        where = None
        if head and head.get("particle") is not None and settled:
            row = int(np.searchsorted(run.data.ids, int(head["particle"])))
            if row < run.n_atoms and run.data.ids[row] == int(head["particle"]):
                where = run.o[row] + scale * (p[row] - run.o[row])
        ring_text = (f"{head['value']:.3g} {head.get('units', '')}".strip()
                     if head and settled else "")
        t = time.perf_counter()
        painter = SurfacePainter(surfaces, scale, measure, report.vmax, cmap, (cw, ch))
        cells = []
        try:
            for view in views:
                centre, half = framing(frame_pts, view, aspect)
                ring = None
                if where is not None:
                    x, y = _project(where, view, centre, half, (cw, ch))
                    ring = (x, y, 14.0)
                cells.append(_cell(painter.paint(view, centre, half), view, ring, ring_text))
        finally:
            painter.close()
        W = cw * min(2, len(cells))
        sheet_head = header(W, f"{name}: {label.split(' [')[0]} on the part's surface", label,
                            report.vmax, cmap, lines)
        _save(tmp / "sheet.png", _sheet(cells, sheet_head))
        report.files.append("sheet.png")
        report.timings["surface_pictures_s"] = time.perf_counter() - t
        t = time.perf_counter()
        shown = p.copy()
        shown[idx] = run.o[idx] + scale * (p[idx] - run.o[idx])
        painter = Painter(run, coloured, [], report.vmax, cmap, (cw, ch))
        cells = []
        try:
            for view in views:
                centre, half = framing(run.o[idx] if far else
                                       np.concatenate([shown[idx], run.o[idx]]), view, aspect)
                cells.append(_cell(painter.paint(shown, values, view, centre, half), view))
        finally:
            painter.close()
        part_lines = [("each particle (a lattice site of the part) coloured by its own value; "
                       + (f"deformed × {scale:g} as the surface" if scale else "undeformed"),
                       (0, 0, 0))]
        if not settled:
            part_lines.insert(0, (unsettled_text(summary, short=True), RED))
        _save(tmp / "particles.png",
              _sheet(cells, header(W, f"{name}: the particles", label, report.vmax, cmap,
                                   part_lines)))
        report.files.append("particles.png")
        report.timings["particle_pictures_s"] = time.perf_counter() - t
        if side is not None:
            done, side = side, None
            _join_beside(done, beside, report)
        report.peak = head
        report.timings["total_s"] = time.perf_counter() - t0
        report.timings["cpu_s"] = time.process_time() - c0
        manifest = {"rundir": str(rundir), "static": True, "measure": measure, "label": label,
                    "vmax": report.vmax, "cmap": cmap, "views": views, "headline": head,
                    "settled": settled, "magnification": scale, "max_displacement": umax,
                    "part_size": size, "length_unit": units,
                    "surfaces": [{"group": s.group, "source": s.source, "points": len(s.points),
                                  "triangles": len(s.faces), "spacing": s.spacing}
                                 for s in surfaces],
                    "parts": report.parts, "frames": [], "files": report.files,
                    "notes": report.notes, "timings": report.timings}
        write_json(tmp / "render.json", manifest)
        report.files.append("render.json")
        _move_in(tmp, report.outdir)
    except BaseException as exc:
        if side is not None:
            side.kill()
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError) and not isinstance(exc, StorageError) and exc.errno:
            raise storage_error(exc, "write the pictures into", report.outdir) from None
        raise
    return report


class _Background:
    """``fn(run, values, label, coloured, context, report, out)`` in a forked child process
    (:class:`~rackstress.runs.forked.ForkedJob`), concurrently with the pictures (this
    machine's second core), then ``then()`` if given; ``join`` → (files, notes, wall time)
    it added to the report and ``then``'s ``{"result", "cpu_s"}`` (its JSON-able result, or
    ``{"error": [kind, message]}`` if it raised), or re-raises ``fn``'s error. Where fork is
    not available it runs in this process at ``join``."""

    def __init__(self, fn, run, values, label, coloured, context, report, out: Path,
                 then=None):
        from rackstress.runs.forked import ForkedJob

        def work():
            t = time.perf_counter()
            n_files, n_notes = len(report.files), len(report.notes)
            fn(run, values, label, coloured, context, report, out)
            files, notes = report.files[n_files:], report.notes[n_notes:]
            del report.files[n_files:], report.notes[n_notes:]
            wall = time.perf_counter() - t
            after = {"result": None, "cpu_s": 0.0}
            if then is not None:
                c = time.process_time()
                try:
                    after["result"] = then()
                except Exception as exc:  # noqa: BLE001 - said by its caller, the plots kept
                    after["result"] = {"error": [type(exc).__name__, str(exc)]}
                after["cpu_s"] = time.process_time() - c
            return files, notes, wall, after

        self.out = out
        self.job = ForkedJob(work, out / ".plots.json")

    def join(self):
        from rackstress.runs.forked import ForkedError

        try:
            files, notes, wall, then = self.job.join()
        except ForkedError as exc:
            if exc.exitcode == EXIT_STORAGE:
                raise StorageError(f"could not write the plots into {self.out}: the file "
                                   "system refused the write (full?); free space on it") from None
            if exc.exitcode is not None:
                raise RuntimeError(f"drawing the plots failed (exit code {exc.exitcode})") \
                    from None
            if exc.errno:
                raise StorageError(f"could not draw the plots into {self.out}: {exc.message}") \
                    from None
            raise RuntimeError(f"drawing the plots failed: {exc.message}") from None
        return files, notes, wall, then

    def kill(self):
        self.job.kill()


def _join_beside(side, beside, report) -> None:
    """Wait for the job run beside the pictures (``side``, a ForkedJob), time it into
    ``report`` and hand its result, or its error, to ``beside``'s second callable."""
    from rackstress.runs.forked import ForkedError

    t = time.perf_counter()
    try:
        got = side.join()
    except ForkedError as exc:
        got = {"error": ["RuntimeError", exc.message]}
    report.timings["beside_wait_s"] = time.perf_counter() - t
    if side.cpu_s is not None:
        report.timings["beside_cpu_s"] = side.cpu_s
    beside[1](got)


def render_default(rundir, progress: bool = False) -> RenderReport:
    """What ``rackstress run`` renders at the end: the default measure (von Mises stress for a
    scene with a material, else the paper's), default frames and views, the sheet alone
    (what the report shows, painted at its cells' size: ``rackstress render RUNDIR`` adds the
    full-size pictures, ``--movie`` the movie) and the plots; the render's wall time goes into
    ``summary.json``, and ``RUNDIR/report.html`` is written."""
    from rackstress.render.report import write_report

    import json

    built = {}

    def view3d(report, measure, cmap):          # in a child, beside the pictures and plots
        from rackstress.render.view3d import build_view

        try:
            rec = build_view(rundir, measure=measure, cmap=cmap, vmax=report.vmax)
            return {"rec": json.loads(json.dumps(rec, default=lambda x: x.tolist()))}
        except Exception as exc:  # noqa: BLE001 - the report says why there is no 3D view
            return {"error": [type(exc).__name__, str(exc)]}

    def done(got):
        if "rec" in got:
            built["rec"] = got["rec"]
        else:                                   # the report names the child's error as it was
            name, message = got["error"]
            built["error"] = type(name, (Exception,), {})(message)

    t0 = time.perf_counter()
    rep = render(rundir, progress=progress, sheet_only=True, beside=(view3d, done))
    wall = time.perf_counter() - t0
    record_render(Path(rundir), rep, wall)          # first, so that the report shows it
    t = time.perf_counter()
    rep.report = write_report(rundir, built_view=built)
    rep.timings["report_s"] = time.perf_counter() - t
    record_render(Path(rundir), rep, wall)
    return rep


def record_render(rundir: Path, rep: RenderReport, wall_s: float) -> None:
    """``summary.json``'s ``render``: wall time, pictures, where (atomically)."""
    path = rundir / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return
    summary["render"] = {"wall_s": wall_s, "outdir": str(rep.outdir.relative_to(rundir))
                         if rep.outdir.is_relative_to(rundir) else str(rep.outdir),
                         "files": len(rep.files),
                         "pictures": sum(f.endswith(".png") for f in rep.files),
                         "timings": rep.timings}
    write_json(path, summary)


def _move_in(tmp: Path, outdir: Path, check: bool = False) -> None:
    """Move every file of ``tmp`` into ``outdir`` (replacing same names only), then drop tmp.

    ``check`` (an ``--out`` of the user's choosing): first refuse if ``outdir`` holds a file of
    one of those names that rackstress did not write, and record them in its manifest
    (:func:`rackstress.runs.rundir.own`)."""
    if check:
        from rackstress.runs.rundir import own

        own(outdir, sorted(f.name for f in tmp.iterdir()), "the pictures")
    outdir.mkdir(parents=True, exist_ok=True)
    for f in sorted(tmp.iterdir()):
        if f.name != "render.json":
            os.replace(f, outdir / f.name)
    os.replace(tmp / "render.json", outdir / "render.json")   # the manifest last
    shutil.rmtree(tmp, ignore_errors=True)


def _legend(run, coloured, context, hidden, cmap):
    hot = tuple(int(round(255 * c)) for c in colour_table(cmap)[-1])
    rows = [(f"coloured: {', '.join(p.name for p in coloured)}", hot)]
    if context:
        rows.append((f"context: {', '.join(p.name for p in context)}",
                     tuple(int(255 * c) for c in CONTEXT_RGB)))
    if hidden:
        rows.append((f"hidden: {', '.join(hidden)}", (255, 255, 255)))
    return rows


def _peak_line(peak) -> str:
    if not peak:
        return ""
    unit = f" {peak['units']}" if peak.get("units") else ""
    return (f"peak {peak['value']:.4g}{unit} at iteration {peak['iteration']}, "
            f"particle {peak['particle']} ({peak['group']})")


def _header(run, report, label, cmap, coloured, context, hidden, width) -> np.ndarray:
    title = f"{run.scene.get('scene', run.rundir.name)}"
    return header_strip(width, title, label, report.vmax, cmap,
                        _legend(run, coloured, context, hidden, cmap), _peak_line(report.peak))


def _one(run, painter, values, k, step, view, centre, half, coloured, header, report):
    p = run.trajectory[k].data["positions64"]
    img = painter.paint(p, values[k], view, centre, half)
    labels = []
    for part in coloured:
        q = p[part.index]
        low = q[np.argmin(q @ _screen_axes(view)[1])]          # name under the part
        labels.append((part.name, tuple(painter.project(low, view, centre, half)[0])))
    ring, ring_text = None, ""
    pk = report.peak
    if pk and k == pk["frame"]:
        x, y = painter.project(p[pk["row"]], view, centre, half)[0]
        r = max(10.0, 2.5 * _part_radius(run, run.parts[pk["group"]]) * painter.size[1]
                / (2 * half))
        ring, ring_text = (x, y, r), f"peak {pk['value']:.3g}"
    img = annotate(img, step, view, labels, ring, ring_text)
    return img if header is None else np.concatenate([header, img], axis=0)


def _positions(run, ks) -> dict:
    return {k: run.trajectory[k].data["positions64"].copy() for k in ks}


def _pictures(run, painter, values, report, views, label, cmap, coloured, context, hidden,
              out: Path, bar, save: bool = True, sheet=None) -> None:
    """Every chosen frame in every view: (``save``) their PNGs, and each into ``sheet`` (a
    :class:`_Sheet`) as it is painted; without ``save`` the images have no header strip
    (they are the sheet's cells)."""
    saver = _Saver()
    ks = sorted({k for _, k, _ in report.frames})
    pos = _positions(run, ks)
    aspect = painter.size[0] / painter.size[1]
    header = _header(run, report, label, cmap, coloured, context, hidden, painter.size[0]) \
        if save else None
    for r, view in enumerate(views):
        centre, half = framing(run, pos, coloured, view, aspect,
                               report.notes if view == views[0] else [])
        for c, k in enumerate(ks):
            step = int(run.steps[k])
            img = _one(run, painter, values, k, step, view, centre[k], half, coloured, header,
                       report)
            if sheet is not None:
                sheet.add(r, c, img)
            if save:
                name = f"{view}_{step:06d}.png"
                saver.save(out / name, img)
                report.files.append(name)
            bar.update(1)
    saver.wait()


class _Sheet:
    """Fig. 12-like sheet: rows = views, columns = frames (half size), one header on top,
    written as it is painted.

    The header, the column titles and the row labels are drawn before the first picture;
    each cell is pasted as it is painted (:meth:`add`), and once a row of cells is whole a
    thread PNG-filters and compresses it (:class:`_PngRows`; zlib lets go of the GIL) while
    the next row is painted: after the last picture only the last row is left to compress
    (magpod-small: the whole sheet's encoding took 0.1 s after it, on the critical path).
    The pixels are those of the sheet composed at once; any error leaves a partial file in
    the render's temporary directory only.

    ``reduce``: the cells are full-size pictures (header strip included), halved here; else
    they are the cells already, painted at half size."""

    def __init__(self, path: Path, run, report, views, header_fn, size, reduce: bool = True):
        from PIL import Image, ImageDraw

        self.views, self.reduce = list(views), reduce
        self.ks = ks = sorted({k for _, k, _ in report.frames})
        w, h = size                                 # the pictures' (the window's) size
        self.cw, self.ch = cw, ch = (w // 2, h // 2) if reduce else (w, h)
        self.lab_w, self.top = lab_w, top = 28, 24
        W = lab_w + cw * len(ks)
        self.im = im = Image.new("RGB", (W, top + ch * len(self.views)), "white")
        dr = ImageDraw.Draw(im)
        f = _font(14)
        self.peak_col = None
        for c, k in enumerate(ks):
            peak = report.peak is not None and k == report.peak["frame"]
            text = f"iteration {int(run.steps[k])}" + ("  (peak)" if peak else "")
            x = lab_w + c * cw + (cw - dr.textlength(text, font=f)) / 2
            dr.text((x, 4), text, fill=(170, 0, 0) if peak else "black", font=f)
            if peak:
                self.peak_col = c
        for r, view in enumerate(self.views):
            txt = Image.new("RGB", (ch, lab_w), "white")
            ImageDraw.Draw(txt).text((ch / 2 - 20, 6), view, fill="black", font=f)
            im.paste(txt.rotate(90, expand=True), (0, top + r * ch))
        self.filled = [0] * len(self.views)
        header = header_fn(W)
        self.png = _PngRows(path, W, header.shape[0] + im.size[1])
        self.png.add(np.concatenate([header, np.asarray(im.crop((0, 0, W, top)))], axis=0))

    def add(self, r: int, c: int, img: np.ndarray) -> None:
        """The picture of view ``r`` (its row) and frame ``c`` (its column)."""
        from PIL import Image, ImageDraw

        if self.reduce:
            img = Image.fromarray(img[HEADER_H:]).reduce(2)
        else:
            img = Image.fromarray(img)
        y0 = self.top + r * self.ch
        self.im.paste(img, (self.lab_w + c * self.cw, y0))
        self.filled[r] += 1
        if self.filled[r] < len(self.ks):
            return
        if self.peak_col is not None:               # drawn over the cells, as they come
            x0 = self.lab_w + self.peak_col * self.cw
            ImageDraw.Draw(self.im).rectangle(
                [x0 + 1, self.top, x0 + self.cw - 2, self.top + self.ch * len(self.views) - 2],
                outline=(170, 0, 0), width=2)
        self.png.add(np.asarray(self.im.crop((0, y0, self.im.size[0], y0 + self.ch))))

    def close(self) -> None:
        """Wait for the rows' compression; the file complete."""
        if any(n < len(self.ks) for n in self.filled):
            raise RuntimeError("the sheet is missing pictures")
        self.png.close()

    def abort(self) -> None:
        self.png.abort()


class _PngRows:
    """A PNG file (8-bit RGB) written band by band, top to bottom, by a thread: each band
    "Up"-filtered (PNG filter 2: a row minus the row above; magpod-small's sheet 1.94 MB
    against 2.13 MB unfiltered and PIL's 1.96 MB) and compressed into one zlib stream at
    :data:`PNG_COMPRESS`, each piece an IDAT chunk as it comes."""

    def __init__(self, path: Path, width: int, height: int):
        import struct
        import zlib
        from concurrent.futures import ThreadPoolExecutor

        self.width, self.height, self.rows = width, height, 0
        self.pool = ThreadPoolExecutor(max_workers=1)
        self.futures = []
        self.z = zlib.compressobj(PNG_COMPRESS)
        self.last = np.zeros(width * 3, np.uint8)       # the row above the first: zeros
        self.fh = open(path, "wb")
        self.fh.write(b"\x89PNG\r\n\x1a\n")
        self._chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))

    def _chunk(self, kind: bytes, data: bytes) -> None:
        import struct
        import zlib

        self.fh.write(struct.pack(">I", len(data)) + kind + data
                      + struct.pack(">I", zlib.crc32(data, zlib.crc32(kind))))

    def add(self, band: np.ndarray) -> None:
        """The next rows, (n, width, 3) uint8."""
        if band.shape[1:] != (self.width, 3):
            raise ValueError(f"a band of {band.shape} in a PNG {self.width} wide")
        self.rows += band.shape[0]
        self.futures.append(self.pool.submit(self._write, np.ascontiguousarray(band)))

    def _write(self, band: np.ndarray) -> None:
        rows = band.reshape(band.shape[0], -1)
        out = np.empty((rows.shape[0], rows.shape[1] + 1), np.uint8)
        out[:, 0] = 2
        np.subtract(rows[0], self.last, out=out[0, 1:])
        np.subtract(rows[1:], rows[:-1], out=out[1:, 1:])
        self.last = rows[-1].copy()
        data = self.z.compress(out.tobytes())
        if data:
            self._chunk(b"IDAT", data)

    def close(self) -> None:
        try:
            for f in self.futures:
                f.result()
            if self.rows != self.height:
                raise RuntimeError(f"a PNG of {self.height} rows given {self.rows}")
            self._chunk(b"IDAT", self.z.flush())
            self._chunk(b"IEND", b"")
            self.fh.close()             # its last bytes written, or the disk's refusal raised
        finally:
            self.abort()

    def abort(self) -> None:
        """Stop (after the band under way) and close the file: after an error, what it still
        held is dropped (a full disk refuses it again; the error said is the first one)."""
        for f in self.futures:
            f.cancel()
        self.pool.shutdown(wait=True)
        try:
            self.fh.close()
        except OSError:
            pass


def _movie_frames(run, max_frames: int) -> list:
    n = run.index.n_frames
    stride = max(1, int(np.ceil(n / max_frames)))
    ks = list(range(0, n, stride))
    if ks[-1] != n - 1:
        ks.append(n - 1)
    return ks


def _movie(run, painter, values, report, view, label, cmap, coloured, context, hidden, ks,
           fps, path: Path, bar) -> int:
    import imageio_ffmpeg

    aspect = painter.size[0] / painter.size[1]
    pos = _positions(run, ks)
    centre, half = framing(run, pos, coloured, view, aspect, [])
    header = _header(run, report, label, cmap, coloured, context, hidden, painter.size[0])
    w, h = painter.size[0] // 16 * 16, (painter.size[1] + HEADER_H) // 16 * 16
    writer = imageio_ffmpeg.write_frames(str(path), (w, h), fps=fps, codec="libx264",
                                         pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
                                         macro_block_size=16, quality=7,
                                         ffmpeg_log_level="error")
    writer.send(None)
    try:
        for k in ks:
            img = _one(run, painter, values, k, int(run.steps[k]), view, centre[k], half,
                       coloured, header, report)
            writer.send(np.ascontiguousarray(img[:h, :w, :3]).tobytes())
            bar.update(1)
    finally:
        writer.close()
    return len(ks)


#: The footprints panel's plot height and least width (its two-line title's, if that is less),
#: in inches.
PANEL_H, PANEL_MIN_W = 3.3, 3.4


def _text_w(strings, size: float = 10.0) -> float:
    """The widest of ``strings`` in points at ``size`` (the default font's metrics: what Agg
    draws them with, to a point)."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import text_to_path

    prop = FontProperties(size=size)
    return max((text_to_path.get_text_width_height_descent(t, prop, ismath=False)[0]
                for t in strings), default=0.0)


def _tick_labels(axis) -> list:
    """The labels ``axis`` will draw at its limits and size (its locator and formatter, no
    ticks made)."""
    lo, hi = sorted(axis.get_view_interval())
    locs = [v for v in axis.get_major_locator()() if lo <= v <= hi]
    fmt = axis.get_major_formatter()
    return [*fmt.format_ticks(locs), fmt.get_offset()]


def footprints_figure(run, motion, coloured, context):
    """The footprints plot: each context part's deepest vertical displacement over the walk,
    seen from above, with the coloured parts' centre-of-mass paths.

    The figure takes the shape of what it frames (an equal-aspect panel of a tall patch in a
    wide figure left half of it empty), and the title is two short lines over the panel: it
    was one line longer than the panel, cut at the figure's edge. The panels and their colour
    bars are placed in inches, their margins from their labels' own widths (the fonts'
    metrics): a constrained layout measured every tick label in a draw of its own, a third
    of the plot's CPU."""
    from matplotlib.figure import Figure

    steps = run.steps
    names = motion.results.names
    pt = 1 / 72
    panels = []
    for part in context:
        dy = motion.results.footprints[part.name]["min_dy"]
        o = run.o[part.index]
        lim = float(np.abs(dy).max()) or 1.0
        com = motion.results.com[:, [names.index(p.name) for p in coloured]]
        # frame the walk, not the whole sediment: the displaced particles and the path, padded
        moved = np.abs(dy) > 0.01 * lim
        pts = np.concatenate([o[moved][:, [0, 2]], com[:, :, [0, 2]].reshape(-1, 2)])
        pts = pts[np.isfinite(pts).all(axis=1)]
        if not len(pts):
            pts = o[:, [0, 2]]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        pad = 0.15 * float((hi - lo).max()) + 4.0
        box = [lo[0] - pad, hi[0] + pad, lo[1] - pad, hi[1] + pad]
        title = (f"footprints in {part.name}\ndeepest vertical displacement, "
                 f"iterations {steps[0]}–{steps[-1]}")
        # a frame narrower than the title is widened (about its centre) to the title's width
        least = min(PANEL_MIN_W, _text_w(title.split("\n")) * pt + 0.1)
        grow = (least / PANEL_H) * (box[3] - box[2]) - (box[1] - box[0])
        if grow > 0:
            box[0], box[1] = box[0] - grow / 2, box[1] + grow / 2
        # the plot as wide as its frame is at PANEL_H, at most 9 inches (then less high)
        aspect = (box[1] - box[0]) / max(box[3] - box[2], 1e-9)
        w = min(9.0, PANEL_H * aspect)
        panels.append((part, dy, o, lim, com, box, title, w, w / aspect))
    # margins in inches: above, the two-line title (2 × 1.2 lines of 10 pt, its pad 6 pt);
    # below, ticks (3.5 + 3.5 pt), tick labels (10 pt), the x label (4 pt pad, 12 pt);
    # 4 pt at the figure's edges
    top, bottom, edge = 34 * pt, 37 * pt, 4 * pt
    plot_h = max(p[-1] for p in panels)
    H = plot_h + top + bottom
    fig = Figure(figsize=(1.0, H))      # its height first: the locators see the plots' sizes
    axes = []
    for part, dy, o, lim, com, box, title, w, h in panels:
        ax = fig.add_axes((0, 0, 1, 1))
        cax = fig.add_axes((0, 0, 1, 1))
        # the particles the frame shows (a tenth of it around, for the markers at its edge):
        # a million-particle bed's others drew nothing, at a minute's cost
        mx, mz = 0.1 * (box[1] - box[0]), 0.1 * (box[3] - box[2])
        seen = ((o[:, 0] >= box[0] - mx) & (o[:, 0] <= box[1] + mx)
                & (o[:, 2] >= box[2] - mz) & (o[:, 2] <= box[3] + mz))
        sc = ax.scatter(o[seen, 0], o[seen, 2], c=dy[seen], cmap="RdBu", vmin=-lim, vmax=lim,
                        s=6, marker="s")
        for j in range(com.shape[1]):
            ax.plot(com[:, j, 0], com[:, j, 2], lw=0.8, color="k", alpha=0.5)
        ax.set_xlim(box[0], box[1])
        ax.set_ylim(box[2], box[3])
        ax.set_aspect("equal")
        ax.set(xlabel="x", ylabel="z")
        ax.set_title(title, fontsize=10)
        fig.colorbar(sc, cax=cax, label="vertical displacement\n[length units]")
        axes.append((ax, cax, w, h))
    for ax, cax, w, h in axes:
        ax.set_position((0, (bottom + (plot_h - h) / 2) / H, w, h / H))
        cax.set_position((0, (bottom + (plot_h - h) / 2) / H, 0.155, h / H))
    widths = []
    for ax, cax, w, h in axes:
        # left: the z tick labels, ticks and label; right of the bar, the same for its two-line
        # label; the panel column at least as wide as the title
        left = edge + (7 + _text_w(_tick_labels(ax.yaxis)) + 4 + 12) * pt
        right = 0.18 + 0.155 + edge + (7 + _text_w(_tick_labels(cax.yaxis)) + 4 + 24) * pt
        half = _text_w(ax.get_title().split("\n")) * pt / 2 + edge - w / 2   # title centred
        widths.append((max(left, half), max(right, half)))
    W = sum(w + a + b for (_, _, w, _), (a, b) in zip(axes, widths))
    fig.set_size_inches(W, H)
    x = 0.0
    for (ax, cax, w, h), (a, b) in zip(axes, widths):
        y = (bottom + (plot_h - h) / 2) / H
        ax.set_position(((x + a) / W, y, w / W, h / H))
        cax.set_position(((x + a + w + 0.18) / W, y, 0.155 / W, h / H))
        x += a + w + b
    return fig


def stress_figure(run, values, label, coloured, peak):
    """The stress-over-time plot: max and mean of the measure per coloured part, the peak."""
    from matplotlib.figure import Figure     # no pyplot: no GUI backend, faster to import

    steps = run.steps
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    for k, part in enumerate(coloured):
        v = values[:, part.index]
        colour = f"C{k % 10}"
        with np.errstate(all="ignore"):
            fin = np.isfinite(v)
            vmax = np.where(fin.any(axis=1), np.max(np.where(fin, v, -np.inf), axis=1), np.nan)
            vmean = np.where(fin.any(axis=1), np.nansum(v, axis=1) / np.maximum(fin.sum(axis=1),
                                                                                 1), np.nan)
        ax.plot(steps, vmax, color=colour, label=f"{part.name} max")
        ax.plot(steps, vmean, color=colour, ls="--", label=f"{part.name} mean")
    if label.startswith(LABELS["von_mises"][0]):
        # the governing stress (away from singular points) frame by frame (stress/governing)
        from rackstress.stress.governing import over_time

        try:
            gov = over_time(run, values)
        except Exception:  # noqa: BLE001 - a plot line, not a result: the max stays drawn
            gov = {}
        for k, part in enumerate(coloured):
            if part.name in gov and np.isfinite(gov[part.name]).any():
                ax.plot(steps, gov[part.name], color=f"C{k % 10}", ls=":", lw=1.6,
                        label=f"{part.name} governing")
    pk = peak
    if pk:
        ax.plot([pk["iteration"]], [pk["value"]], "k*", ms=12,
                label=f"peak {pk['value']:.3g} ({pk['group']}, it. {pk['iteration']})")
    ax.set_xlabel("iteration")
    ax.set_ylabel(label.replace(" [", "\n["))
    ax.set_title(f"{run.scene.get('scene', '')}: stress per part over time")
    timed = _time_axis(ax, run)
    ax.legend(fontsize=7, ncol=2)
    fig.subplots_adjust(left=0.14, right=0.98, bottom=0.12, top=0.82 if timed else 0.92)
    return fig


def _time_axis(ax, run) -> bool:
    """A physical-units run's time on the top axis (iteration × dt, in s, ms or µs as its
    length asks), beside the iterations; whether there is one."""
    if run.time_unit is None or not len(run.steps):
        return False
    dt = run.dt
    total = dt * float(max(run.steps[-1], 1))
    scale, name = next(((f, n) for f, n in ((1.0, ""), (1e3, "m"), (1e6, "µ"), (1e9, "n"))
                        if total * f >= 1.0), (1e9, "n"))
    k = dt * scale
    top = ax.secondary_xaxis("top", functions=(lambda it: it * k, lambda t: t / k))
    top.set_xlabel(f"time [{name}{run.time_unit}]", fontsize=8)
    top.tick_params(labelsize=7)
    return True


def com_figure(motion, coloured):
    """The centre-of-mass plot: each coloured part's path, top view (x–z) and side view (x–y)."""
    from matplotlib.figure import Figure

    names = motion.results.names
    fig = Figure(figsize=(10, 4))
    top, side = fig.subplots(1, 2)
    for k, part in enumerate(coloured):
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
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.13, top=0.92, wspace=0.25)
    return fig


def _plots(run, values, label, coloured, context, report, out: Path) -> None:
    fig = stress_figure(run, values, label, coloured, report.peak)
    fig.savefig(out / "stress_over_time.png", dpi=110, pil_kwargs=PLOT_PNG)
    report.files.append("stress_over_time.png")

    motion = PartMotion(run).run()
    fig = com_figure(motion, coloured)
    fig.savefig(out / "com_path.png", dpi=110, pil_kwargs=PLOT_PNG)
    report.files.append("com_path.png")

    if not context:
        report.notes.append("no sediment group shown: footprints plot skipped")
        return
    fig = footprints_figure(run, motion, coloured, context)
    fig.savefig(out / "footprints.png", dpi=110, pil_kwargs=PLOT_PNG)
    report.files.append("footprints.png")
