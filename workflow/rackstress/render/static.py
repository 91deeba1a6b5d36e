"""The pictures of a static analysis: the part as an FE post-processor shows it.

A static run has one state, the equilibrium, and no time: its pictures show the part's own
surface (:mod:`rackstress.stress.surface`: the mesh it was made from, or the lattice's outer
surface) with the stress painted on it, drawn deformed, and an outline of its undeformed shape;
nothing over time. :func:`rackstress.render.pictures.render_static` (``rackstress render
RUNDIR`` and ``rackstress run`` of a static scene) paints them with the pieces here into
``RUNDIR/figures/``:

* ``sheet.png`` — the surface in four views (``iso``, ``front``, ``right``, ``top``: from
  (+1, +0.8, +1), +x, +z and +y), coloured by the measure (von Mises stress for a part with a
  material) from 0 to the headline's value; the displacement magnified by a round factor
  (1, 2 or 5 × 10ᵏ) that draws the largest displacement as about :data:`FRACTION` of the
  part's size (never below 1: a large deformation is drawn as it is), said above the pictures;
  the undeformed shape's outline (its silhouette and sharp edges) in dark grey; a ring round
  the headline's point;
* ``particles.png`` — the same views of the particles (each a lattice site, coloured by its
  own value, at the same magnification): what the surface was interpolated from;
* ``render.json`` — what was drawn (measure, scale, magnification, headline, surfaces, notes,
  timings).

A run that did not settle gets the same pictures under a red "NOT SETTLED" line: its state is
not an equilibrium, its colours no result.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rackstress.render.draw import (LABEL_H, PNG_COMPRESS, colour_bar, colour_table, font,
                                    ring_text_box, screen_axes, snapshot)
from rackstress.render.draw import offscreen as _offscreen

#: the largest displacement is drawn as about this fraction of the part's size
FRACTION = 0.1
STATIC_VIEWS = ("iso", "front", "right", "top")
#: one view's picture, pixels
CELL = (640, 480)
HEADER_H = 112
OUTLINE_RGB = (0.2, 0.2, 0.2)
RED = (170, 0, 0)


def _round(x: float) -> float:
    """The nearest of 1, 2, 5 × 10ᵏ to ``x`` (on a log scale)."""
    if not x > 0 or not np.isfinite(x):
        return 1.0
    e = 10.0 ** np.floor(np.log10(x))
    return float(min((m * e for m in (1.0, 2.0, 5.0, 10.0)), key=lambda c: abs(np.log(c / x))))


def magnification(max_displacement: float, size: float, fraction: float = FRACTION) -> float:
    """The displacement's magnification in the pictures: the round factor (1, 2, 5 × 10ᵏ)
    nearest to drawing the largest displacement as ``fraction`` of the part's ``size`` (so
    between 0.07 and 0.16 of it), at least 1.

    >>> magnification(0.92, 100.0)
    10.0
    >>> magnification(0.684, 30.0)
    5.0
    >>> magnification(30.0, 100.0)
    1.0
    """
    if not max_displacement > 0 or not np.isfinite(max_displacement):
        return 1.0
    return max(1.0, _round(fraction * size / max_displacement))


# ----------------------------------------------------------------------------- painting
def _poly(points: np.ndarray, faces: np.ndarray):
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData

    pts = vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=True))
    cells = vtkCellArray()
    offsets = np.arange(0, 3 * len(faces) + 1, 3, dtype=np.int64)
    cells.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
                  numpy_to_vtkIdTypeArray(np.ascontiguousarray(faces, dtype=np.int64).ravel(),
                                          deep=True))
    poly = vtkPolyData()
    poly.SetPoints(pts)
    poly.SetPolys(cells)
    return poly


def surface_rgb(values: np.ndarray, vmax: float, cmap: str) -> np.ndarray:
    """Opaque colours (uint8 RGB) of the colour map from 0 to ``vmax``."""
    s = np.clip(np.nan_to_num(np.asarray(values, float), nan=0.0) / vmax, 0.0, 1.0)
    return np.round(colour_table(cmap)[np.round(s * 255).astype(int)] * 255).astype(np.uint8)


class SurfacePainter:
    """One off-screen VTK window: the parts' deformed surfaces coloured (lit, opaque), the
    undeformed shapes' outline (silhouette and edges sharper than 60°) over them."""

    def __init__(self, surfaces: list, scale: float, measure: str, vmax: float, cmap: str,
                 size=CELL):
        _offscreen()
        import vtkmodules.vtkRenderingOpenGL2  # noqa: F401 - registers the OpenGL classes
        from vtkmodules.util.numpy_support import numpy_to_vtk
        from vtkmodules.vtkFiltersCore import vtkPolyDataNormals
        from vtkmodules.vtkFiltersHybrid import vtkPolyDataSilhouette
        from vtkmodules.vtkRenderingCore import (vtkActor, vtkPolyDataMapper, vtkRenderer,
                                                 vtkRenderWindow)

        self.size = (int(size[0]), int(size[1]))
        self.ren = vtkRenderer()
        self.ren.SetBackground(1.0, 1.0, 1.0)
        self.rw = vtkRenderWindow()
        self.rw.SetOffScreenRendering(1)
        self.rw.SetMultiSamples(0)
        self.rw.AddRenderer(self.ren)
        self.rw.SetSize(*self.size)
        cam = self.ren.GetActiveCamera()
        cam.ParallelProjectionOn()
        self.keep = []
        for s in surfaces:
            deformed = _poly(s.points + scale * s.values["displacement"], s.faces)
            rgb = numpy_to_vtk(surface_rgb(s.values.get(measure, np.zeros(len(s.points))),
                                           vmax, cmap), deep=True)
            rgb.SetName("rgb")
            deformed.GetPointData().SetScalars(rgb)
            normals = vtkPolyDataNormals()
            normals.SetInputData(deformed)
            normals.SetFeatureAngle(40.0)
            normals.SplittingOn()
            normals.ConsistencyOn()
            mapper = vtkPolyDataMapper()
            mapper.SetInputConnection(normals.GetOutputPort())
            mapper.ScalarVisibilityOn()
            mapper.SetColorModeToDirectScalars()
            mapper.SetScalarModeToUsePointData()
            actor = vtkActor()
            actor.SetMapper(mapper)
            prop = actor.GetProperty()
            prop.SetAmbient(0.3)
            prop.SetDiffuse(0.7)
            prop.SetSpecular(0.0)
            self.ren.AddActor(actor)
            undeformed = _poly(*(s.shape or (s.points, s.faces)))
            outline = vtkPolyDataSilhouette()
            outline.SetInputData(undeformed)
            outline.SetCamera(cam)
            outline.SetEnableFeatureAngle(1)
            outline.SetFeatureAngle(60.0)
            outline.BorderEdgesOn()
            om = vtkPolyDataMapper()
            om.SetInputConnection(outline.GetOutputPort())
            om.ScalarVisibilityOff()
            om.SetRelativeCoincidentTopologyLineOffsetParameters(0.0, -4.0)
            oa = vtkActor()
            oa.SetMapper(om)
            oa.GetProperty().SetColor(*OUTLINE_RGB)
            oa.GetProperty().SetLineWidth(1.5)
            oa.GetProperty().SetLighting(False)
            self.ren.AddActor(oa)
            self.keep += [deformed, normals, mapper, actor, undeformed, outline, om, oa]

    def paint(self, view: str, centre, half: float) -> np.ndarray:
        _, up, direction = screen_axes(view)
        return snapshot(self.ren, self.rw, self.size, centre, up, direction, half)

    def close(self):
        self.rw.Finalize()


def framing(points: np.ndarray, view: str, aspect: float):
    """(centre, half-height) of an orthographic picture of ``view`` fitting ``points``."""
    right, up, _ = screen_axes(view)
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lo + hi)
    d = points - centre
    h = max(float(np.abs(d @ up).max()), float(np.abs(d @ right).max()) / aspect)
    return centre, 1.08 * max(h, 1e-9)


def _project(q, view, centre, half, size):
    right, up, _ = screen_axes(view)
    w, h = size
    s = 0.5 * h / half
    d = np.asarray(q, float) - centre
    return 0.5 * w + float(d @ right) * s, 0.5 * h - float(d @ up) * s


def _cell(img: np.ndarray, view: str, ring=None, ring_text: str = "") -> np.ndarray:
    """A view's picture with its name and the ring round the headline's point."""
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    dr = ImageDraw.Draw(im)
    w, h = im.size
    dr.text((8, h - 22), f"{view} view", fill=(80, 80, 80), font=font(13))
    if ring is not None:
        x, y, r = ring
        if -r <= x < w + r and -r <= y < h + r:
            dr.ellipse([x - r, y - r, x + r, y + r], outline=(0, 0, 0), width=3)
            dr.ellipse([x - r - 3, y - r - 3, x + r + 3, y + r + 3], outline=(255, 255, 255),
                       width=2)
            f = font(13)
            box = ring_text_box(x, y, r, dr.textlength(ring_text, font=f), LABEL_H, w, h)
            dr.text(box[:2], ring_text, fill="black", font=f)
    dr.rectangle([0, 0, w - 1, h - 1], outline=(210, 210, 210))
    return np.asarray(im)


def header(width: int, title: str, label: str, vmax: float, cmap: str, lines: list) -> np.ndarray:
    """The strip above a sheet: title and ``lines`` ((text, rgb)) on the left, the colour bar
    on the right."""
    from PIL import Image, ImageDraw

    img = Image.new("RGB", (width, HEADER_H), "white")
    dr = ImageDraw.Draw(img)
    dr.text((10, 6), title, fill="black", font=font(17))
    y = 32
    for text, rgb in lines:
        dr.text((10, y), text, fill=rgb, font=font(13))
        y += 18
    return np.asarray(colour_bar(img, int(0.62 * width), int(0.96 * width), label, vmax, cmap))


def _sheet(cells: list, head: np.ndarray, cols: int = 2) -> np.ndarray:
    h, w = cells[0].shape[:2]
    rows = -(-len(cells) // cols)
    grid = np.full((rows * h, cols * w, 3), 255, np.uint8)
    for i, c in enumerate(cells):
        r, k = divmod(i, cols)
        grid[r * h:(r + 1) * h, k * w:(k + 1) * w] = c
    return np.concatenate([head, grid], axis=0)


def _save(path: Path, img: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(img).save(path, compress_level=PNG_COMPRESS)
