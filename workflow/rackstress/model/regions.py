"""Regions by shape: which particles of a group a scene selects.

A region answers one question, :meth:`Region.mask`: given a group's *original* positions ``o``
(n×3, in the group's particle order), which particles lie in it? Everything in a scene that
selects particles takes a region: the ``where`` of ``force`` (Eq. 8's selection, Eq. 15's
⟨‖o‖² < 10⟩ is ``Norm2Below(10)``), attraction regions (the index vectors of Eqs. 27–28),
supports (:attr:`rackstress.model.particles.Group.held`), and the solid a part is filled from.

=====================  ============================================================================
region                 contains the point x when
=====================  ============================================================================
``Box(lo, hi)``        lo ≤ x ≤ hi in every axis
``Sphere(c, r)``       ‖x − c‖ ≤ r
``Cylinder(a, b, r)``  x projects onto the segment a–b and lies within r of its axis (closed caps)
``HalfSpace(p, n)``    (x − p)·n ≥ 0: the side of the plane through p that the normal n points to
``Norm2Below(v)``      ‖x‖² < v (Eq. 15's pulled corner; strict, as printed)
``Ids(ids)``           its index in the group is one of ``ids`` (0-based, the group's id order)
``Surface(mesh)``      inside a closed triangle mesh (VTK's enclosed-points test, via pyvista)
``NearSurface(t, d)``  within d of the triangles t (a named hole's bore, a flat face)
``Union(a, b, …)``     in any of them;  ``a | b``
``Intersection(…)``    in all of them;  ``a & b``
``Difference(a, b…)``  in a and inside none of the others (closed);  ``a - b``
=====================  ============================================================================

Boundaries are included (closed shapes) up to :data:`TOL` times the shape's size, so a lattice
particle that lies on a face by construction (0.1 + 0.2 is not 0.3 in floating point) is
selected the same on every machine. A difference is closed too, the closure of a − b
(constructive solid geometry's regularized difference): a point on b's boundary that borders
what is left of a is kept (:func:`_in_closure`), so a hole whose radius the spacing divides
keeps the particles on its rim as a box keeps those on its faces. Taking them away left a
one-particle notch where each lattice axis meets the rim — at a plate's hole under tension,
where the stress is largest.

Id order: a group's particles are numbered from 0 in the order its positions were built — for
lattices and filled parts x fastest, then y, then z (:mod:`rackstress.model.particles`); in a
scene, groups follow in file order, so a particle's global index is its group's offset plus its
index in the group (LAMMPS atom id = global index + 1).

Example
-------
>>> import numpy as np
>>> o = np.array([[0., 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
>>> (Box([0.5, -1, -1], [2.5, 1, 1]) - Ids([2])).mask(o).tolist()
[False, True, False, False]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rackstress.errors import SceneError

#: Relative tolerance of region boundaries (times the shape's size; absolute 1e-12 at least).
TOL = 1e-9
#: A difference keeps a point on a taken-away part's boundary when one of the six points this
#: many times TOL × the shapes' size away along the axes is left (:func:`_in_closure`): beyond
#: the boundaries' own tolerance even where a face's normal is diagonal (1/√3 of it).
PROBE = 4.0


def _as_points(o) -> np.ndarray:
    return np.ascontiguousarray(o, dtype=np.float64).reshape(-1, 3)


def _vec(value, what: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise SceneError(f"{what} must be three finite numbers [x, y, z], got {value!r}")
    return v


class Region:
    """A set of points in space (or of particle indices): combine with ``|``, ``&`` and ``-``."""

    def mask(self, o: np.ndarray) -> np.ndarray:
        """Boolean mask over the rows of ``o`` (original positions, the group's id order)."""
        raise NotImplementedError

    def select(self, o: np.ndarray) -> np.ndarray:
        """The selected particle indices in increasing order."""
        return np.flatnonzero(self.mask(o))

    def grid_mask(self, origin, spacing, dims) -> np.ndarray:
        """:meth:`mask` over the regular grid origin + (i, j, k)·spacing, i < dims[0] …, in
        VTK image order (x fastest, then y, then z): what filling a part asks. Regions with a
        faster way for whole grids (a mesh: VTK's scan conversion) override it."""
        return self.mask(grid_points(origin, spacing, dims))

    def bounds(self):
        """(lo, hi) of a box holding the region, or None when it is unbounded / index-based."""
        return None

    def inner(self, o: np.ndarray) -> np.ndarray:
        """Boolean mask of the rows of ``o`` inside the region and not on its boundary (beyond
        its tolerance): what a difference takes away (:class:`Difference`). A shape without a
        boundary of its own to tell (a mesh, an open set): its :meth:`mask`."""
        return self.mask(o)

    def scale(self) -> float:
        """The size the region's boundary tolerance is relative to (TOL × it)."""
        b = self.bounds()
        return float(np.max(np.asarray(b[1]) - np.asarray(b[0]))) if b is not None else 1.0

    #: Whether membership is a matter of position (every shape), not of index (``Ids``):
    #: only then has the region a boundary for a difference to keep (:func:`_in_closure`).
    geometric = True

    def __or__(self, other: "Region") -> "Region":
        return Union((self, other))

    def __and__(self, other: "Region") -> "Region":
        return Intersection((self, other))

    def __sub__(self, other: "Region") -> "Region":
        return Difference((self, other))


@dataclass(frozen=True, eq=False)
class Box(Region):
    """The axis-aligned box lo ≤ x ≤ hi (closed)."""

    lo: tuple
    hi: tuple

    def __post_init__(self):
        lo, hi = _vec(self.lo, "box min"), _vec(self.hi, "box max")
        if np.any(hi < lo):
            raise SceneError(f"box max {hi.tolist()} is below its min {lo.tolist()} in some axis")
        object.__setattr__(self, "lo", tuple(lo))
        object.__setattr__(self, "hi", tuple(hi))

    def mask(self, o):
        o = _as_points(o)
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        tol = max(TOL * float(np.max(hi - lo)), 1e-12)
        return np.all((o >= lo - tol) & (o <= hi + tol), axis=1)

    def inner(self, o):
        o = _as_points(o)
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        tol = max(TOL * float(np.max(hi - lo)), 1e-12)
        return np.all((o > lo + tol) & (o < hi - tol), axis=1)

    def bounds(self):
        return np.asarray(self.lo), np.asarray(self.hi)


@dataclass(frozen=True, eq=False)
class Sphere(Region):
    """The closed ball ‖x − centre‖ ≤ radius."""

    centre: tuple
    radius: float

    def __post_init__(self):
        object.__setattr__(self, "centre", tuple(_vec(self.centre, "sphere centre")))
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise SceneError(f"sphere radius must be positive, got {self.radius!r}")

    def mask(self, o):
        d = _as_points(o) - np.asarray(self.centre)
        r = self.radius * (1 + TOL)
        return np.einsum("ij,ij->i", d, d) <= r * r

    def inner(self, o):
        d = _as_points(o) - np.asarray(self.centre)
        r = self.radius * (1 - TOL)
        return np.einsum("ij,ij->i", d, d) < r * r

    def scale(self):
        return float(self.radius)

    def bounds(self):
        c = np.asarray(self.centre)
        return c - self.radius, c + self.radius


@dataclass(frozen=True, eq=False)
class Cylinder(Region):
    """The closed finite cylinder of ``radius`` around the segment ``start``–``end``."""

    start: tuple
    end: tuple
    radius: float

    def __post_init__(self):
        a, b = _vec(self.start, "cylinder start"), _vec(self.end, "cylinder end")
        if not np.linalg.norm(b - a) > 0:
            raise SceneError("cylinder start and end coincide: the axis has no direction")
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise SceneError(f"cylinder radius must be positive, got {self.radius!r}")
        object.__setattr__(self, "start", tuple(a))
        object.__setattr__(self, "end", tuple(b))

    def _axial(self, o):
        """(t along the axis, squared distance from it, length, tolerance) of the rows of o."""
        a, b = np.asarray(self.start), np.asarray(self.end)
        length = float(np.linalg.norm(b - a))
        u = (b - a) / length
        d = _as_points(o) - a
        t = d @ u
        radial = d - t[:, None] * u
        return t, np.einsum("ij,ij->i", radial, radial), length, TOL * max(length, self.radius)

    def mask(self, o):
        t, r2, length, tol = self._axial(o)
        r = self.radius + tol
        return (t >= -tol) & (t <= length + tol) & (r2 <= r * r)

    def inner(self, o):
        t, r2, length, tol = self._axial(o)
        r = self.radius - tol
        return (t > tol) & (t < length - tol) & (r2 < r * r)

    def scale(self):
        return float(max(np.linalg.norm(np.asarray(self.end) - np.asarray(self.start)),
                         self.radius))

    def bounds(self):
        a, b = np.asarray(self.start), np.asarray(self.end)
        return np.minimum(a, b) - self.radius, np.maximum(a, b) + self.radius


@dataclass(frozen=True, eq=False)
class HalfSpace(Region):
    """The closed half-space (x − point)·normal ≥ 0: the side the normal points to."""

    point: tuple
    normal: tuple

    def __post_init__(self):
        p, n = _vec(self.point, "plane point"), _vec(self.normal, "plane normal")
        if not np.linalg.norm(n) > 0:
            raise SceneError("plane normal must not be zero")
        object.__setattr__(self, "point", tuple(p))
        object.__setattr__(self, "normal", tuple(n / np.linalg.norm(n)))

    def mask(self, o):
        p = np.asarray(self.point)
        s = (_as_points(o) - p) @ np.asarray(self.normal)
        return s >= -TOL * max(1.0, float(np.abs(p).max()))

    def inner(self, o):
        p = np.asarray(self.point)
        s = (_as_points(o) - p) @ np.asarray(self.normal)
        return s > TOL * max(1.0, float(np.abs(p).max()))

    def scale(self):
        return max(1.0, float(np.abs(np.asarray(self.point)).max()))


@dataclass(frozen=True, eq=False)
class Norm2Below(Region):
    """⟨‖o‖² < value⟩ (Eq. 15, strict as printed): the plane experiments' pulled corner."""

    value: float

    def mask(self, o):
        from rackstress.model.operators import norm2_below   # Eq. 15, one home

        return np.asarray(norm2_below(_as_points(o), self.value), dtype=bool)


@dataclass(frozen=True, eq=False)
class Ids(Region):
    """Particles by index in their group (0-based, the group's id order)."""

    ids: tuple

    def __post_init__(self):
        ids = tuple(self.ids)
        for i in ids:
            if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)):
                raise SceneError(f"particle index {i!r} is not an integer")
        object.__setattr__(self, "ids", tuple(int(i) for i in ids))

    geometric = False

    def mask(self, o):
        n = len(_as_points(o))
        out = np.zeros(n, dtype=bool)
        for i in self.ids:
            if not 0 <= i < n:
                raise SceneError(f"ids: particle index {i} is not in the group (0..{n - 1})")
            out[i] = True
        return out


class Surface(Region):
    """The inside of a closed, watertight triangle mesh (a :class:`pyvista.PolyData`).

    The inside test is VTK's ``vtkSelectEnclosedPoints`` (``select_interior_points``), a ray-
    casting test over an OBB tree; :mod:`rackstress.scenes.mesh` reads and checks the mesh
    (watertight, not self-intersecting) before it becomes a region. ``name`` (the file) is for
    messages.
    """

    def __init__(self, polydata, name: str = "mesh"):
        self.polydata, self.name = polydata, name

    def mask(self, o):
        o = _as_points(o)
        if not len(o):
            return np.zeros(0, dtype=bool)
        return inside_surface(self.polydata, o)

    def bounds(self):
        b = np.asarray(self.polydata.bounds, dtype=float)
        return b[0::2], b[1::2]

    def grid_mask(self, origin, spacing, dims):
        """The grid points inside, by VTK's scan conversion of the closed surface
        (``vtkPolyDataToImageStencil`` through pyvista's ``voxelize_binary_mask``): the surface
        is cut at every z of the grid and each row filled between its crossings, in C++ —
        measured 100–300× faster than testing the points one by one, with the same result."""
        import pyvista as pv

        dims = tuple(int(d) for d in dims)
        if min(dims) < 1:
            return np.zeros(0, dtype=bool)
        ref = pv.ImageData(dimensions=dims, spacing=tuple(float(x) for x in spacing),
                           origin=tuple(float(x) for x in origin))
        img = self.polydata.voxelize_binary_mask(reference_volume=ref)
        return np.asarray(img.point_data["mask"]) != 0

    def __repr__(self):
        return f"Surface({self.name!r})"


class NearSurface(Region):
    """Points within ``distance`` of a piece of a part's surface: the triangles ``triangles``
    (k×3×3) of a named hole's bore or a flat face (:mod:`rackstress.scenes.features`), whose
    ``name`` ("hole H2", "face F5") is for messages. The distance is trimesh's closest point
    on those triangles, for the points in their bounding box grown by ``distance``."""

    def __init__(self, triangles, distance: float, name: str = "surface"):
        self.triangles = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
        self.distance, self.name = float(distance), name
        if not len(self.triangles):
            raise SceneError(f"{name}: has no triangles")
        if not self.distance > 0:
            raise SceneError(f"{name}: the selection distance must be positive")

    def _distances(self, o):
        """(rows of o in the triangles' box grown by the distance, their distances)."""
        import trimesh

        o = _as_points(o)
        lo, hi = self.bounds()
        near = np.flatnonzero(np.all((o >= lo) & (o <= hi), axis=1))
        if not len(near):
            return near, np.zeros(0)
        tri = self.triangles
        sub = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3),
                              process=False)
        _, dist, _ = trimesh.proximity.closest_point(sub, o[near])
        return near, np.asarray(dist)

    def mask(self, o):
        near, dist = self._distances(o)
        out = np.zeros(len(_as_points(o)), dtype=bool)
        out[near] = dist <= self.distance * (1.0 + TOL)
        return out

    def inner(self, o):
        near, dist = self._distances(o)
        out = np.zeros(len(_as_points(o)), dtype=bool)
        out[near] = dist < self.distance * (1.0 - TOL)
        return out

    def bounds(self):
        pts = self.triangles.reshape(-1, 3)
        return pts.min(axis=0) - self.distance, pts.max(axis=0) + self.distance

    def __repr__(self):
        return f"NearSurface({self.name!r}, within {self.distance:g})"


def grid_points(origin, spacing, dims) -> np.ndarray:
    """Points origin + (i, j, k)·spacing of a regular grid, x fastest, then y, then z."""
    nx, ny, nz = (int(d) for d in dims)
    axes = [float(origin[a]) + float(spacing[a]) * np.arange(n) for a, n in enumerate((nx, ny, nz))]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), z.ravel()])


def inside_surface(polydata, points: np.ndarray, chunk: int = 2_000_000) -> np.ndarray:
    """Which ``points`` lie inside the closed surface ``polydata`` (VTK's enclosed-points test).

    Points are tested in chunks, so a large fill needs no more memory than one chunk's VTK
    arrays. The tolerance is VTK's default (1e-5 of the surface's bounding-box diagonal).
    """
    import pyvista as pv

    out = np.empty(len(points), dtype=bool)
    for start in range(0, len(points), chunk):
        part = pv.PolyData(np.ascontiguousarray(points[start:start + chunk]))
        sel = part.select_interior_points(polydata, check_surface=False)
        out[start:start + chunk] = np.asarray(sel.point_data["selected_points"]) != 0
    return out


def _in_closure(first: Region, others, pts: np.ndarray) -> np.ndarray:
    """Which of ``pts`` — each in ``first`` and on the boundary of one of ``others``, inside
    none — lie in the closure of ``first`` minus ``others``: one of the six points
    :data:`PROBE` × TOL × the shapes' size away along ±x, ±y, ±z is in ``first`` and in none of
    ``others``. A point on the rim of a hole has one (off the hole); one on a hole's opening in
    the face of ``first``, or on the face two touching parts of a union share, has none."""
    scale = max([first.scale()] + [p.scale() for p in others])
    delta = PROBE * TOL * max(scale, float(np.abs(pts).max()) if len(pts) else 0.0, 1e-3)
    keep = np.zeros(len(pts), dtype=bool)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            rows = np.flatnonzero(~keep)
            if not len(rows):
                return keep
            q = pts[rows].copy()
            q[:, axis] += sign * delta
            ok = np.asarray(first.mask(q), dtype=bool)
            for p in others:
                ok &= ~np.asarray(p.mask(q), dtype=bool)
            keep[rows[ok]] = True
    return keep


class _Combination(Region):
    kind = "combination"

    def __init__(self, parts):
        parts = tuple(parts)
        if not parts:
            raise SceneError(f"{self.kind} needs at least one region")
        for p in parts:
            if not isinstance(p, Region):
                raise SceneError(f"{self.kind}: {p!r} is not a region")
        self.parts = parts

    @property
    def geometric(self):
        return all(p.geometric for p in self.parts)

    def scale(self):
        return max([p.scale() for p in self.parts if p.geometric] or [1.0])

    def __repr__(self):
        return f"{type(self).__name__}({', '.join(map(repr, self.parts))})"


class Union(_Combination):
    """Points in any of the parts."""

    kind = "union"

    def mask(self, o):
        out = self.parts[0].mask(o)
        for p in self.parts[1:]:
            out = out | p.mask(o)
        return out

    def inner(self, o):
        """Inside one of the parts (a point on the face two touching parts share is in
        neither's inner: a difference that takes the union away probes it, :func:`_in_closure`)."""
        out = self.parts[0].inner(o)
        for p in self.parts[1:]:
            out = out | p.inner(o)
        return out

    def grid_mask(self, origin, spacing, dims):
        out = self.parts[0].grid_mask(origin, spacing, dims)
        for p in self.parts[1:]:
            out = out | p.grid_mask(origin, spacing, dims)
        return out

    def bounds(self):
        bs = [p.bounds() for p in self.parts]
        if any(b is None for b in bs):
            return None
        return np.min([b[0] for b in bs], axis=0), np.max([b[1] for b in bs], axis=0)


class Intersection(_Combination):
    """Points in every part."""

    kind = "intersection"

    def mask(self, o):
        out = self.parts[0].mask(o)
        for p in self.parts[1:]:
            out = out & p.mask(o)
        return out

    def inner(self, o):
        out = self.parts[0].inner(o)
        for p in self.parts[1:]:
            out = out & p.inner(o)
        return out

    def grid_mask(self, origin, spacing, dims):
        out = self.parts[0].grid_mask(origin, spacing, dims)
        for p in self.parts[1:]:
            out = out & p.grid_mask(origin, spacing, dims)
        return out

    def bounds(self):
        bs = [b for b in (p.bounds() for p in self.parts) if b is not None]
        if not bs:
            return None
        lo, hi = np.max([b[0] for b in bs], axis=0), np.min([b[1] for b in bs], axis=0)
        return lo, np.maximum(hi, lo)


class Difference(_Combination):
    """Points in the first part and in none of the others, closed: the closure of the first
    minus the others (constructive solid geometry's regularized difference), so a point on
    another's boundary that borders what is left is kept (:func:`_in_closure`). Parts named by
    index (``Ids``) are taken away as they are."""

    kind = "difference"

    def _subtract(self, out: np.ndarray, hits: list, points) -> np.ndarray:
        """``out`` (the first part's mask) less the others' (``hits``: their closed masks):
        what lies inside one goes, what lies only on their boundaries goes unless it borders
        what is left (``points(rows)``: the rows' positions)."""
        first, geo = self.parts[0], [p for p in self.parts[1:] if p.geometric]
        edge = np.zeros(len(out), dtype=bool)
        for p, h in zip(self.parts[1:], hits):
            h = h & out
            if not p.geometric or not first.geometric:
                out = out & ~h
                continue
            rows = np.flatnonzero(h)
            if len(rows):
                inside = np.asarray(p.inner(points(rows)), dtype=bool)
                out[rows[inside]] = False
                edge[rows[~inside]] = True
        edge &= out
        if edge.any():
            rows = np.flatnonzero(edge)
            out[rows[~_in_closure(first, geo, points(rows))]] = False
        return out

    def mask(self, o):
        o = _as_points(o)
        out = np.asarray(self.parts[0].mask(o), dtype=bool).copy()
        hits = [np.asarray(p.mask(o), dtype=bool) for p in self.parts[1:]]
        return self._subtract(out, hits, lambda rows: o[rows])

    def grid_mask(self, origin, spacing, dims):
        out = np.asarray(self.parts[0].grid_mask(origin, spacing, dims), dtype=bool).copy()
        hits = [np.asarray(p.grid_mask(origin, spacing, dims), dtype=bool)
                for p in self.parts[1:]]
        nx, ny, _ = (int(d) for d in dims)

        def points(rows):
            ijk = np.column_stack([rows % nx, (rows // nx) % ny, rows // (nx * ny)])
            return np.asarray(origin, float) + ijk * np.asarray(spacing, float)

        return self._subtract(out, hits, points)

    def inner(self, o):
        """Inside the first part and in none of the others, their boundaries included."""
        out = np.asarray(self.parts[0].inner(o), dtype=bool).copy()
        for p in self.parts[1:]:
            out &= ~np.asarray(p.mask(o), dtype=bool)
        return out

    def bounds(self):
        return self.parts[0].bounds()


def index_vector(regions, o: np.ndarray) -> np.ndarray:
    """An attraction-region index vector from shapes: particle i gets k + 1 for the first
    region k (in the list's order) that holds it, 0 for none (Eqs. 27–28's regions)."""
    o = _as_points(o)
    out = np.zeros(len(o), dtype=np.int64)
    for k, region in enumerate(regions):
        m = region.mask(o) & (out == 0)
        out[m] = k + 1
    return out
