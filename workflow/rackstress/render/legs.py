"""The pictures of MagPod in physical units (:mod:`rackstress.stress.legs`): the governing von
Mises of each leg over the gait, and the legs at the peak frame coloured in MPa beside the
paper's displacement colouring (Section 5.2's distance from the desired position) at the same
frame.

Example
-------
>>> from rackstress.stress.legs import run_legs                     # doctest: +SKIP
>>> res, _ = run_legs("runs/mps")                                    # doctest: +SKIP
>>> time_plot(res, "runs/mps/figures/legs_von_mises.png")           # doctest: +SKIP
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

#: the pictures' names in the run's ``figures/``
TIME_PLOT = "legs_von_mises.png"
PEAK_PICTURE = "legs_peak.png"


def time_plot(res, path, dt_s: float | None = None) -> Path:
    """The governing (largest) von Mises of each leg per frame, MPa, against physical time
    (and the iteration on the top axis), the peak marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = res.figures
    dt = fig["dt_s"] if dt_s is None else dt_s
    t = res.steps * dt
    f, ax = plt.subplots(figsize=(7.5, 3.6), dpi=110)
    for leg, rec in res.legs.items():
        ax.plot(t, rec["governing_mpa"], lw=1.2, label=leg)
    pk = res.peak
    paper = res.paper.get("max_per_frame") if res.paper else None
    if paper:
        ax2 = ax.twinx()
        for k, (leg, vals) in enumerate(paper.items()):
            ax2.plot(t, vals, lw=0.8, ls=":", color=f"C{k}", label=f"{leg}: paper's colouring")
        ax2.set_ylabel("largest distance from desired position\n(paper units, dotted)", fontsize=8)
        ax2.legend(fontsize=7, loc="upper center")
    if pk:
        ax.plot([pk["time_s"]], [pk["von_mises_mpa"]], "o", mfc="none", mec="k",
                label=f"peak {pk['von_mises_mpa']:.3g} MPa, {pk['leg']}, "
                      f"iteration {pk['step']}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("governing von Mises (MPa)")
    ax.set_title(f"MagPod's {fig['material'] if 'material' in fig else 'aluminium'} legs, "
                 f"quasi-static per frame ({fig['unit_length_mm']:g} mm a paper unit)",
                 fontsize=9)
    top = ax.secondary_xaxis("top", functions=(lambda x: x / dt, lambda i: i * dt))
    top.set_xlabel("iteration", fontsize=8)
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    f.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    f.savefig(path)
    plt.close(f)
    return path


def peak_picture(res, path, size=(1400, 1200)) -> Path:
    """The two legs, seen from the right and front, at two frames: the peak frame of the
    quasi-static von Mises (top) and the frame where the paper's colouring of the legs is
    largest (bottom); left, coloured by the von Mises (MPa, grey → red, Section 5.2's
    colours, scale: the run's peak); right, by the paper's distance from the desired position
    at the same frame (paper length units, scale: the legs' largest over the run)."""
    import pyvista as pv

    from rackstress.render.draw import colour_table, offscreen

    offscreen()
    pk = res.peak
    rows = [(pk["frame"], pk["step"], pk["time_s"], res.paper["positions"],
             np.concatenate([np.asarray(res.paper[leg], float) for leg in res.legs]),
             f"the von Mises peak, {pk['von_mises_mpa']:.3g} MPa on the {pk['leg']}")]
    pp = res.paper.get("at_paper_peak")
    if pp:
        rows.append((pp["frame"], pp["step"], pp["time_s"], pp["positions"],
                     np.concatenate([np.asarray(pp[leg], float) for leg in res.legs]),
                     "the paper's colouring's peak"))
    tops = (float(res.von_mises.max()) or 1.0, float(res.paper.get("max_over_run", 0.0)) or 1.0)
    pl = pv.Plotter(shape=(len(rows), 2), off_screen=True, window_size=list(size),
                    border=False)
    for r, (frame, step, t, pos, paper, what) in enumerate(rows):
        vm = res.von_mises[frame].astype(float)
        for col, (vals, title, unit) in enumerate((
                (vm, f"von Mises (MPa) at iteration {step} (t = {t:.2f} s):\n{what}", "MPa"),
                (paper, f"the paper's colouring at iteration {step}: distance from\nthe "
                        "desired position (paper units)", "units"))):
            pl.subplot(r, col)
            lut = pv.LookupTable(values=np.column_stack([colour_table("paper") * 255,
                                                         np.full(256, 255)]).astype(np.uint8))
            lut.scalar_range = (0.0, tops[col])
            cloud = pv.PolyData(np.asarray(pos, float))
            cloud["v"] = vals
            pl.add_mesh(cloud, scalars="v", cmap=lut, clim=[0.0, tops[col]],
                        render_points_as_spheres=True, point_size=12,
                        scalar_bar_args={"title": unit, "vertical": True, "fmt": "%.2g",
                                         "position_x": 0.84, "width": 0.06,
                                         "label_font_size": 12, "title_font_size": 12})
            pl.add_text(title, font_size=9, color="black")
            pl.set_background("white")
            pl.view_vector((0.35, 0.25, 1.0), viewup=(0.0, 1.0, 0.0))
            pl.reset_camera()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pl.screenshot(str(path))
    pl.close()
    return path
