"""What the still pictures and the 3D view draw alike: Section 5.2's colours, the drawn
radius of a part's particles, off-screen VTK; and what a dynamic run's pictures and a static
run's (:mod:`rackstress.render.static`) share: the views, the fonts, the colour bar, the
peak ring's text.

:mod:`rackstress.render.pictures` (the PNG pictures) and :mod:`rackstress.render.view3d` (the
interactive view in ``report.html``) both take their colours from here, so a particle has the
same colour in both.
"""
from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from rackstress.stress import StressInputError

GREY = np.array([0.6, 0.6, 0.6])
RED = np.array([1.0, 0.0, 0.0])
ALPHA0 = 0.15


def colour_table(cmap: str = "paper") -> np.ndarray:
    """(256, 3) RGB in [0, 1] from zero to the top of the scale."""
    s = np.linspace(0.0, 1.0, 256)
    if cmap in (None, "paper"):
        return GREY[None, :] * (1 - s[:, None]) + RED[None, :] * s[:, None]
    import matplotlib

    try:
        cm = matplotlib.colormaps[cmap]
    except KeyError:
        raise StressInputError(f"unknown colour map '{cmap}'; use 'paper' (grey→red, Section "
                               "5.2) or a matplotlib colour map name such as viridis, inferno, "
                               "coolwarm") from None
    return np.asarray(cm(s))[:, :3]


def stress_rgba(values: np.ndarray, vmax: float, cmap: str = "paper") -> np.ndarray:
    """Section 5.2's colouring: grey translucent at 0 → red opaque at vmax (uint8 RGBA)."""
    s = np.clip(np.nan_to_num(np.asarray(values, float), nan=0.0) / vmax, 0.0, 1.0)
    if cmap in (None, "paper"):
        rgb = GREY[None, :] * (1.0 - s[:, None]) + RED[None, :] * s[:, None]
    else:
        rgb = colour_table(cmap)[np.round(s * 255).astype(int)]
    alpha = ALPHA0 + (1.0 - ALPHA0) * s
    return np.round(np.column_stack([rgb, alpha]) * 255).astype(np.uint8)


def offscreen():
    """Off-screen VTK without an X server (EGL)."""
    if not os.environ.get("DISPLAY"):
        # no X server: render through EGL, without VTK first trying (and warning about) X
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def part_radius(run, part) -> float:
    """The drawn radius of a part's particles, computed once per run."""
    cache = run.__dict__.setdefault("_drawn_radius", {})
    if part.name not in cache:
        cache[part.name] = drawn_radius(run.o[part.index])
    return cache[part.name]


def drawn_radius(o: np.ndarray) -> float:
    """Half the typical nearest-neighbour distance (the particles of a part touch)."""
    if len(o) < 2:
        return 0.5
    from scipy.spatial import cKDTree

    d = cKDTree(o).query(o, k=2)[0][:, 1]
    return 0.5 * float(np.median(d)) or 0.5


# ----------------------------------------------------------------------------- pictures
#: view → (direction from the focal point to the camera, view-up).
VIEWS = {
    "right": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "left": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "front": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "back": ((-1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "top": ((0.0, 1.0, 0.0), (0.0, 0.0, -1.0)),
    "iso": ((1.0, 0.8, 1.0), (0.0, 1.0, 0.0)),
}
PNG_COMPRESS = 1


@functools.lru_cache(maxsize=None)
def font(size: int):
    """DejaVu Sans at ``size`` pixels, loaded once."""
    import importlib.util

    from PIL import ImageFont

    # matplotlib's own copy of DejaVu Sans (found without importing matplotlib, which is slow)
    base = Path(importlib.util.find_spec("matplotlib").origin).parent
    return ImageFont.truetype(str(base / "mpl-data" / "fonts" / "ttf" / "DejaVuSans.ttf"), size)


def screen_axes(view: str):
    """(screen right, screen up, towards the camera) of ``view`` (:data:`VIEWS`)."""
    direction, up = VIEWS[view]
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    u = np.asarray(up, float) - np.dot(up, d) * d
    u /= np.linalg.norm(u)
    return np.cross(u, d), u, d     # screen right, screen up, towards the camera


def snapshot(ren, rw, size, centre, up, direction, half: float) -> np.ndarray:
    """The h×w×3 picture of VTK renderer ``ren`` in window ``rw``: a parallel camera on
    ``centre``, looking against ``direction`` with ``up`` up, ``half`` the half-height shown."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkUnsignedCharArray

    cam = ren.GetActiveCamera()
    cam.SetFocalPoint(*map(float, centre))
    cam.SetPosition(*map(float, np.asarray(centre) + direction * 10.0 * half))
    cam.SetViewUp(*map(float, up))
    cam.SetParallelScale(half)
    ren.ResetCameraClippingRange()
    rw.Render()
    buf = vtkUnsignedCharArray()
    w, h = size
    rw.GetPixelData(0, 0, w - 1, h - 1, 0, buf, 0)
    return vtk_to_numpy(buf).reshape(h, w, 3)[::-1].copy()


def colour_bar(img, x0: int, x1: int, label: str, vmax: float, cmap: str):
    """The colour bar from ``x0`` to ``x1`` of a header strip (a PIL image): its label above,
    the scale from 0 to ``vmax`` below; the image returned."""
    from PIL import Image, ImageDraw

    small = font(13)
    dr = ImageDraw.Draw(img)
    dr.text((x0, 6), label, fill="black", font=small)
    table = (colour_table(cmap) * 255).round().astype(np.uint8)
    cols = table[np.linspace(0, 255, x1 - x0).round().astype(int)]
    bar = np.repeat(cols[None, :, :], 22, axis=0)
    arr = np.asarray(img).copy()
    arr[28:50, x0:x1] = bar
    img = Image.fromarray(arr)
    dr = ImageDraw.Draw(img)
    dr.rectangle([x0, 28, x1 - 1, 49], outline="black")
    for t in np.linspace(0.0, 1.0, 5):
        x = x0 + t * (x1 - 1 - x0)
        dr.line([x, 50, x, 55], fill="black")
        s = f"{t * vmax:.3g}"
        tw = dr.textlength(s, font=small)
        dr.text((min(max(x - tw / 2, x0 - 10), x1 - tw), 57), s, fill="black", font=small)
    return img


#: Height of a 13-pixel label's box, in pixels.
LABEL_H = 16


def ring_text_box(x, y, r, tw, th, w, h) -> tuple:
    """The box (x0, y0, x1, y1) of the peak ring's text: right of the ring, else left of it,
    else under it — never over the ring, never cut at the picture's edge."""
    cy = min(max(y - 8, 2), h - 48)
    for tx in (x + r + 6, x - r - 6 - tw):
        if 2 <= tx and tx + tw <= w - 2:
            return (tx, cy, tx + tw, cy + th)
    tx = _inside(x - tw / 2, tw, w)
    ty = y + r + 6 if y + r + 6 + th <= h - 48 else max(2, y - r - 6 - th)
    return (tx, ty, tx + tw, ty + th)


def _inside(x: float, width: float, w: int, margin: float = 2.0) -> float:
    """The left edge of a text ``width`` wide moved so the text lies inside ``[0, w)``."""
    return max(margin, min(x, w - width - margin))
