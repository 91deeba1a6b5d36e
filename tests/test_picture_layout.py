"""Picture defects, checked on geometry: the footprints plot's title
lies inside the figure and its panel fills the figure (it was clipped at the right with the
left half empty), and no part name covers the peak ring (it did)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import HANG_S

RS = str(Path(sys.executable).parent / "rackstress")


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """magpod-small, a short walk (its sediment is a tall patch, 56 × 36 particles deep)."""
    out = tmp_path_factory.mktemp("walk") / "ms"
    r = subprocess.run([RS, "run", "magpod-small", "--steps", "200", "--dump-every", "50",
                        "--out", str(out), "--no-render", "--no-progress"],
                       capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    return out


def _footprints_geometry(fig):
    """The drawn footprints figure's extents, in pixels, as savefig draws them."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)          # what savefig draws a PNG with
    canvas.draw()
    return canvas.get_renderer(), fig.bbox.width, fig.bbox.height


def _assert_footprints_fit(fig):
    renderer, W, H = _footprints_geometry(fig)
    ax, cax = fig.axes
    title = ax.title.get_window_extent(renderer)
    assert title.x0 >= 0 and title.x1 <= W and title.y1 <= H, (title, W, H)
    box = ax.get_window_extent(renderer)
    assert title.y0 >= box.y1, (title, box)                    # over the panel, not on it
    # the panel and its colour bar, with every label, inside the figure and filling it: no
    # empty half, no band above or below
    used = [a.get_tightbbox(renderer) for a in fig.axes]
    left, right = min(b.x0 for b in used), max(b.x1 for b in used)
    bottom, top = min(b.y0 for b in used), max(b.y1 for b in used)
    assert left >= 0 and right <= W + 1 and bottom >= 0 and top <= H + 1, (used, W, H)
    assert (right - left) / W > 0.85, (left, right, W)
    assert (top - bottom) / H > 0.85, (bottom, top, H)
    # the colour bar right of the panel, as high as it, its labels clear of the panel's
    bar = cax.get_window_extent(renderer)
    assert bar.x0 > box.x1 and abs(bar.height - box.height) < 1.5, (bar, box)
    labels = cax.yaxis.get_tightbbox(renderer)
    assert labels.x0 > box.x1 and labels.x1 <= W, (labels, box, W)
    # the panel shows the frame it was given at equal aspect (x and z in the same units)
    (x0, x1), (z0, z1) = ax.get_xlim(), ax.get_ylim()
    assert abs(box.width / box.height - (x1 - x0) / (z1 - z0)) < 0.02 * box.width / box.height
    return title, box


@pytest.mark.lammps
def test_footprints_title_inside_and_panel_fills_the_figure(walk):
    from rackstress.render.pictures import footprints_figure, select_parts
    from rackstress.stress import PartMotion, load_run

    run = load_run(walk)
    coloured, context, _ = select_parts(run, None)
    assert [p.name for p in context] == ["sediment"]
    _assert_footprints_fit(footprints_figure(run, PartMotion(run).run(), coloured, context))


@pytest.mark.lammps
def test_footprints_long_title_widens_the_figure(walk):
    """A sediment whose name makes the title's first line wider than the panel: the figure
    widens so that the title, centred over the panel, stays inside it."""
    from rackstress.render.pictures import footprints_figure, select_parts
    from rackstress.stress import PartMotion, load_run

    run = load_run(walk)
    coloured, context, _ = select_parts(run, None)
    motion = PartMotion(run).run()
    long = "the-sediment-under-both-feet-of-the-walker"
    motion.results.footprints[long] = motion.results.footprints["sediment"]
    context[0].name = long
    fig = footprints_figure(run, motion, coloured, context)
    title, box = _assert_footprints_fit(fig)
    assert title.width > box.width                      # the case: a title wider than its panel
    assert abs((title.x0 + title.x1) / 2 - (box.x0 + box.x1) / 2) < 1.0


def test_a_part_name_never_covers_the_peak_ring():
    """A part whose name would sit on the ring (its anchor at the ring's centre, another just
    under it) and a ring at the right edge (its text goes left): the names are drawn, in their
    colour, outside the ring's box and off its text."""
    from rackstress.render.pictures import annotate, place_labels, ring_text_box

    w, h = 400, 300
    img = np.full((h, w, 3), 255, dtype=np.uint8)
    ring = (200.0, 120.0, 30.0)
    labels = [("rightleg", (200.0, 120.0)), ("body", (205.0, 140.0)),
              ("leftleg", (60.0, 60.0))]
    out = annotate(img, 100, "front", labels, ring, "peak 8.06")
    blue = np.all(out == (40, 40, 160), axis=2)
    ys, xs = np.nonzero(blue)
    assert len(xs) > 0
    x, y, r = ring
    inside = (np.abs(xs - x) <= r + 3) & (np.abs(ys - y) <= r + 3)
    assert not inside.any(), list(zip(xs[inside], ys[inside]))[:5]
    # the boxes themselves: clear of the ring, of its text and of each other
    tb = ring_text_box(x, y, r, 60, 16, w, h)
    ringbox = (x - r - 5, y - r - 5, x + r + 5, y + r + 5)
    boxes = place_labels([a for _, a in labels], [50, 30, 45], [ringbox, tb], w, h)

    def overlap(a, b):
        return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]
    for k, b in enumerate(boxes):
        assert not overlap(b, ringbox) and not overlap(b, tb)
        assert 0 <= b[0] and b[2] <= w and 0 <= b[1] and b[3] <= h
        assert not any(overlap(b, c) for c in boxes[k + 1:])
    assert boxes[2][:2] == (60.0 - 45 / 2, 74.0)        # a name far from the ring stays put
    # a ring at the right edge: its text left of it, clear of the circle
    tb = ring_text_box(380.0, 120.0, 30.0, 60, 16, w, h)
    assert tb[2] <= 380 - 30 and tb[0] >= 0
