"""What the still pictures and the 3D view draw alike: Section 5.2's colours, the drawn
radius of a part's particles, off-screen VTK.

:mod:`rackstress.render.pictures` (the PNG pictures) and :mod:`rackstress.render.view3d` (the
interactive view in ``report.html``) both take their colours from here, so a particle has the
same colour in both.
"""
from __future__ import annotations

import os

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
