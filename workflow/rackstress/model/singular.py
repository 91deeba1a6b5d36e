"""Singular points of a part: where the continuum's stress is unbounded, so a peak there
measures the spacing, not the part.

Linear elasticity has no finite stress at three kinds of place (docs/stress.md "The governing
stress"), and a lattice — or a finite-element mesh — reads there a value that grows without
limit as the spacing shrinks:

* **re-entrant edge** — a sharp concave edge of the part: near a notch of interior angle
  2α > 180° the stress goes as r^(λ−1), λ < 1 (Williams: λ = 0.545 for a right-angled
  re-entrant corner). Found from the part's surface: a triangle mesh (an STL; a CSG shape is
  turned into one by manifold3d), where the surface turns concavely by at least
  :data:`SHARP_DEG` across a window :data:`WINDOW` spacings wide (:func:`sharp_edges`): a
  sharp edge turns by its full angle within any window, a fillet of radius r by only
  WINDOW·a/r, so a fillet of radius above about one spacing (1.43 a) is not singular. A part
  with no known shape falls back on the lattice itself (:func:`lattice_edges`);
* **unresolved fillet** — a concave edge that turns that far only across several facets
  within the window (each facet's own angle below :data:`SHARP_DEG`): a fillet of radius under
  1.43 spacings, faceted. The lattice reads it as a sharp edge and it is left out of the
  governing stress like one, but the part's peak there is bounded and its own: a spacing
  below r/1.43 resolves it (it is then no singular point at all);
* **support boundary** — where held particles meet free ones: the edge of a clamp is a
  mixed boundary (displacement given on one side, traction on the other), singular in the
  continuum; the boundary of the set of fully held particles (:func:`support_boundary`).
  Rollers and symmetry planes (held in some directions only) are mirrors, not clamps, and are
  left out;
* **point load** — a force on a cluster of particles at most :data:`POINT_ROWS` rows across in
  its second-largest direction (a point or a line load, :func:`point_loads`): its
  intensity per area grows as the spacing shrinks (a point force's stress goes as 1/r²).

:func:`find` gathers them for one part into a :class:`Singular` (points sampled along the
edges, each with its kind), which ``rackstress run`` writes into ``singular.npz`` and
:mod:`rackstress.stress.governing` reads.

Example
-------
>>> import numpy as np
>>> from rackstress.model.regions import Box, Union
>>> L = Union([Box([0, 0, 0], [10, 2, 2]), Box([0, 0, 0], [2, 10, 2])])   # an L, sharp inside
>>> s = find(np.zeros((0, 3)), 0.5, L)
>>> sorted(set(s.kinds())), bool(np.allclose(s.points[:, :2], [2, 2]))
(['re-entrant edge'], True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: The kinds of singular point, in the order ``Singular.kind`` indexes them.
KINDS = ("re-entrant edge", "support boundary", "point load", "contact edge",
         "unresolved fillet")
#: A concave edge is sharp when the surface turns by at least this across the window.
SHARP_DEG = 20.0
#: The window's width across an edge, in spacings (±WINDOW/2 about it): a fillet of radius r
#: turns WINDOW·a/r radians within it, so fillets above r = WINDOW·a/SHARP_DEG = 1.43 a are
#: not singular.
WINDOW = 0.5
#: Points along a sharp edge, this many spacings apart (distances to the edge read to 1/8).
SAMPLE = 0.25
#: A load on a cluster at most this many spacings across in its second-largest direction
#: (two rows) is a point or line load.
POINT_ROWS = 1.0
#: Lattice neighbours: within this many spacings (the 18 of the binding stencil).
NEIGHBOUR = 1.5
#: Concave edges asked about at a time (bounds the neighbour lists' memory).
CHUNK = 20_000
#: Segments of a cylinder or sphere when a CSG shape is meshed: 5° each (a hole of radius r
#: turns WINDOW·a/r over the window, well resolved).
SEGMENTS = 72


@dataclass
class Singular:
    """A part's singular points: ``points`` (k×3, the part's undeformed coordinates), ``kind``
    (k, index into :data:`KINDS`), ``angle`` (k, the concave turning in degrees of an edge's
    window; NaN for the other kinds) and ``source`` (how the edges were found)."""

    points: np.ndarray
    kind: np.ndarray
    angle: np.ndarray
    source: str = ""
    notes: list = field(default_factory=list)
    #: the part's surface the edges were found on, (vertices, faces), if any
    surface: tuple | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.points)

    def kinds(self) -> list:
        """The kind of every point, as text."""
        return [KINDS[int(k)] for k in self.kind]

    def distance(self, x) -> tuple[np.ndarray, np.ndarray]:
        """(distance to the nearest singular point, its index) for each row of ``x``; inf and
        -1 when there are none."""
        x = np.asarray(x, float).reshape(-1, 3)
        if not len(self.points):
            return np.full(len(x), np.inf), np.full(len(x), -1, dtype=np.int64)
        from scipy.spatial import cKDTree

        d, k = cKDTree(self.points).query(x)
        return d, k.astype(np.int64)

    def take(self, keep) -> "Singular":
        keep = np.asarray(keep)
        return Singular(self.points[keep], self.kind[keep], self.angle[keep], self.source,
                        list(self.notes))

    def counts(self) -> dict:
        """Points per kind (only the kinds present)."""
        return {KINDS[k]: int(n) for k, n in enumerate(np.bincount(self.kind.astype(int),
                                                                    minlength=len(KINDS))) if n}


def empty() -> Singular:
    return Singular(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0), "")


def concat(parts: list, source: str = "") -> Singular:
    """One :class:`Singular` of several."""
    parts = [p for p in parts if p is not None]
    if not parts:
        return empty()
    return Singular(np.concatenate([p.points for p in parts]).reshape(-1, 3),
                    np.concatenate([p.kind for p in parts]).astype(np.int64),
                    np.concatenate([p.angle for p in parts]).astype(float),
                    source or "; ".join(p.source for p in parts if p.source),
                    [n for p in parts for n in p.notes])


# --------------------------------------------------------------------------- re-entrant edges
def sharp_edges(vertices, faces, spacing: float, sharp_deg: float = SHARP_DEG,
                window: float = WINDOW):
    """The sharp re-entrant edges of a closed triangle surface at the scale of ``spacing``.

    For every concave edge of the mesh (its two faces turning inwards), the section plane
    through its midpoint m, normal to it, is crossed by the concave edges of the surface's
    profile there; those crossing within ``window``·spacing/2 of m add their turning angles.
    The edge is sharp when the sum reaches ``sharp_deg``: a sharp edge reaches its own angle,
    a fillet of radius r only window·spacing/r (plus one facet's angle), so a fillet is
    singular only when r < window·spacing/sharp_deg (1.43 spacings by default).

    Parameters
    ----------
    vertices : (n, 3) array
    faces : (m, 3) int array
        A closed, consistently oriented surface (outward normals).
    spacing : float
        The length scale: the lattice spacing of the part.

    Returns
    -------
    (segments, turning, own) : ((k, 2, 3) array, (k,) array, (k,) array)
        The sharp edges' end points, their windows' turning and each edge's own angle, in
        degrees (an own angle below ``sharp_deg``: a fillet's facet, sharp only with its
        neighbours).

    Example
    -------
    >>> import trimesh
    >>> box = trimesh.creation.box([2, 2, 2])
    >>> sharp_edges(box.vertices, box.faces, 0.5)[0].shape        # a box is convex: none
    (0, 2, 3)
    """
    E, own, turning, _ = concave_turning(vertices, faces, spacing, sharp_deg, window)
    sharp = np.degrees(turning) >= sharp_deg - 1e-9
    return E[sharp], np.degrees(turning[sharp]), np.degrees(own[sharp])


def concave_turning(vertices, faces, spacing: float, sharp_deg: float = SHARP_DEG,
                    window: float = WINDOW):
    """Every concave edge of a closed triangle surface with how far the surface turns across
    a window of ``window``·spacing about it (:func:`sharp_edges`' measure; an edge that turns
    by ``sharp_deg`` on its own counts only itself): (segments (c, 2, 3), own angles (c,),
    turning (c,), both in radians, unit normals into the part (c, 3)). A fillet or hole of
    radius r turns by about window·spacing/r: its radius at the scale of the window."""
    import trimesh
    from scipy.spatial import cKDTree

    tm = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64),
                         process=True, validate=False)
    none = (np.zeros((0, 2, 3)), np.zeros(0), np.zeros(0), np.zeros((0, 3)))
    if len(tm.faces) < 4:
        return none
    ang = np.asarray(tm.face_adjacency_angles, float)
    concave = ~np.asarray(tm.face_adjacency_convex, bool) & (ang > math.radians(0.5))
    if not concave.any():
        return none
    E = np.asarray(tm.vertices)[tm.face_adjacency_edges[concave]]        # (c, 2, 3)
    th = ang[concave]
    fn = np.asarray(tm.face_normals)[tm.face_adjacency[concave]]         # (c, 2, 3)
    inward = -(fn[:, 0] + fn[:, 1])
    inward /= np.maximum(np.linalg.norm(inward, axis=1), 1e-300)[:, None]
    a, b = E[:, 0], E[:, 1]
    L = np.linalg.norm(b - a, axis=1)
    ok = L > 0
    E, th, a, b, L, inward = E[ok], th[ok], a[ok], b[ok], L[ok], inward[ok]
    t = (b - a) / L[:, None]
    m = 0.5 * (a + b)
    half = 0.5 * window * float(spacing)
    # every edge cut into pieces no longer than half the window, for the neighbour search;
    # a piece crosses a plane when its ends lie on either side, [start, end) so that of two
    # pieces meeting on the plane only one counts
    npiece = np.maximum(1, np.ceil(L / half).astype(np.int64))
    parent = np.repeat(np.arange(len(E)), npiece)
    k = np.arange(len(parent)) - np.repeat(np.cumsum(npiece) - npiece, npiece)
    n_of = npiece[parent]
    pa = a[parent] + (k / n_of)[:, None] * (b - a)[parent]
    pb = a[parent] + ((k + 1) / n_of)[:, None] * (b - a)[parent]
    tree = cKDTree(0.5 * (pa + pb))
    turning = th.copy()                                 # an edge always counts itself
    todo = np.flatnonzero(np.degrees(th) < sharp_deg)   # the rest are sharp by themselves
    for start in range(0, len(todo), CHUNK):
        q = todo[start:start + CHUNK]
        hits = tree.query_ball_point(m[q], r=1.5 * half * (1 + 1e-9), return_sorted=False)
        cnt = np.fromiter((len(h) for h in hits), np.int64, len(hits))
        if not cnt.sum():
            continue
        I = np.repeat(q, cnt)
        P = np.fromiter((j for h in hits for j in h), np.int64, int(cnt.sum()))
        J = parent[P]
        other = J != I
        I, P, J = I[other], P[other], J[other]
        sa = np.einsum("ij,ij->i", pa[P] - m[I], t[I])
        sb = np.einsum("ij,ij->i", pb[P] - m[I], t[I])
        cross = ((sa < 0) & (sb >= 0)) | ((sb < 0) & (sa >= 0))
        I, P, J, sa, sb = I[cross], P[cross], J[cross], sa[cross], sb[cross]
        w = sa / (sa - sb)
        p = pa[P] + w[:, None] * (pb[P] - pa[P])
        near = np.linalg.norm(p - m[I], axis=1) <= half * (1 + 1e-9)
        turning += np.bincount(I[near], weights=th[J[near]], minlength=len(E))
    return E, th, turning, inward


def concave_points(vertices, faces, spacing: float) -> np.ndarray:
    """Points every :data:`SAMPLE` spacings along every concave edge of a closed surface that
    turns by more than half a degree: where it curves inwards (fillets, holes, and the sharp
    edges too) — a stress concentration the lattice resolves only as steps."""
    import trimesh

    tm = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64),
                         process=True, validate=False)
    if len(tm.faces) < 4:
        return np.zeros((0, 3))
    ang = np.asarray(tm.face_adjacency_angles, float)
    concave = ~np.asarray(tm.face_adjacency_convex, bool) & (ang > math.radians(0.5))
    seg = np.asarray(tm.vertices)[tm.face_adjacency_edges[concave]]
    return sample_segments(seg, SAMPLE * float(spacing))[0]


def sample_segments(segments: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along each segment, at most ``step`` apart, ends included: (points, segment)."""
    seg = np.asarray(segments, float).reshape(-1, 2, 3)
    if not len(seg):
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    L = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
    n = np.maximum(1, np.ceil(L / step).astype(np.int64)) + 1
    which = np.repeat(np.arange(len(seg)), n)
    k = np.arange(len(which)) - np.repeat(np.cumsum(n) - n, n)
    f = k / (n[which] - 1)
    return seg[which, 0] + f[:, None] * (seg[which, 1] - seg[which, 0]), which


def surface_of(shape, box=None):
    """The closed triangle surface (vertices, faces, how) of a part's shape, or None: a mesh
    part's own surface; a CSG shape of boxes, cylinders, spheres, half-spaces and meshes made
    exact by manifold3d (``box``: (lo, hi) clipping unbounded half-spaces); None for a shape
    that names particles (``ids``) or when manifold3d is missing."""
    from rackstress.model.regions import Surface

    if shape is None:
        return None
    if isinstance(shape, Surface):
        pd = shape.polydata
        return (np.asarray(pd.points, float), np.asarray(pd.regular_faces, np.int64),
                f"the surface of {shape.name}")
    try:
        import manifold3d  # noqa: F401
    except ImportError:
        return None
    try:
        man = _manifold(shape, box)
    except _NotGeometric:
        return None
    if man is None or man.is_empty():
        return None
    mesh = man.to_mesh64()
    return (np.asarray(mesh.vert_properties, float)[:, :3],
            np.asarray(mesh.tri_verts, np.int64), "the CSG surface (manifold3d)")


class _NotGeometric(Exception):
    pass


def _manifold(shape, box):
    """A manifold3d solid of a region (:mod:`rackstress.model.regions`)."""
    from manifold3d import Manifold, Mesh64

    from rackstress.model import regions as rg

    if isinstance(shape, rg.Box):
        lo, hi = np.asarray(shape.lo), np.asarray(shape.hi)
        return Manifold.cube(tuple(hi - lo)).translate(tuple(lo))
    if isinstance(shape, rg.Sphere):
        return Manifold.sphere(shape.radius, SEGMENTS).translate(tuple(shape.centre))
    if isinstance(shape, rg.Norm2Below):
        return Manifold.sphere(math.sqrt(shape.value), SEGMENTS)
    if isinstance(shape, rg.Cylinder):
        a, b = np.asarray(shape.start), np.asarray(shape.end)
        h = float(np.linalg.norm(b - a))
        cyl = Manifold.cylinder(h, shape.radius, circular_segments=SEGMENTS)
        u = (b - a) / h
        z = np.array([0.0, 0.0, 1.0])
        v = np.cross(z, u)
        s, c = float(np.linalg.norm(v)), float(z @ u)
        if s < 1e-12:
            R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
        else:
            K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
            R = np.eye(3) + s * K + (1 - c) * K @ K
        M = np.hstack([R, a[:, None]])                      # 3 × 4 affine
        return cyl.transform(M)
    if isinstance(shape, rg.HalfSpace):
        if box is None:
            raise _NotGeometric
        lo, hi = (np.asarray(x, float) for x in box)
        big = Manifold.cube(tuple(hi - lo)).translate(tuple(lo))
        n, p = np.asarray(shape.normal), np.asarray(shape.point)
        return big.trim_by_plane(tuple(n), float(n @ p))
    if isinstance(shape, rg.Surface):
        pd = shape.polydata
        man = Manifold(Mesh64(np.ascontiguousarray(np.asarray(pd.points, float)),
                              np.ascontiguousarray(np.asarray(pd.regular_faces, np.uint64))))
        if man.is_empty():
            raise _NotGeometric
        return man
    if isinstance(shape, rg.Union):
        out = _manifold(shape.parts[0], box)
        for p in shape.parts[1:]:
            out = out + _manifold(p, box)
        return out
    if isinstance(shape, rg.Intersection):
        out = _manifold(shape.parts[0], box)
        for p in shape.parts[1:]:
            out = out ^ _manifold(p, box)
        return out
    if isinstance(shape, rg.Difference):
        out = _manifold(shape.parts[0], box)
        for p in shape.parts[1:]:
            out = out - _manifold(p, box)
        return out
    raise _NotGeometric


def lattice_edges(o: np.ndarray, spacing: float) -> np.ndarray:
    """Re-entrant edges of a part known only by its particles (no shape): the lattice's own
    concave edges — a site whose two face neighbours along axes i and j are particles but
    whose diagonal neighbour between them is not. Returns the edges' points (the corner of
    the cells there, half a diagonal towards the missing site). A staircase of a curved or
    sloped face has such steps too; they are reported, for the lattice cannot tell them apart."""
    a = float(spacing)
    o = np.asarray(o, float).reshape(-1, 3)
    if len(o) < 2:
        return np.zeros((0, 3))
    lo = o.min(axis=0)
    g = np.rint((o - lo) / a).astype(np.int64) + 1
    dims = g.max(axis=0) + 2
    occ = np.zeros(tuple(dims), dtype=bool)
    occ[g[:, 0], g[:, 1], g[:, 2]] = True
    out = []
    for i in range(3):
        for j in range(i + 1, 3):
            for si in (1, -1):
                for sj in (1, -1):
                    ei = np.zeros(3, np.int64)
                    ei[i] = si
                    ej = np.zeros(3, np.int64)
                    ej[j] = sj
                    A, B, D = g + ei, g + ej, g + ei + ej
                    hit = (occ[A[:, 0], A[:, 1], A[:, 2]] & occ[B[:, 0], B[:, 1], B[:, 2]]
                           & ~occ[D[:, 0], D[:, 1], D[:, 2]])
                    if hit.any():
                        out.append(o[hit] + 0.5 * a * (ei + ej))
    return np.concatenate(out) if out else np.zeros((0, 3))


def reentrant(o: np.ndarray, spacing: float, shape=None) -> Singular:
    """The re-entrant edges of a part (module docstring): from its shape's surface when there
    is one (:func:`surface_of`, :func:`sharp_edges`), else from its lattice
    (:func:`lattice_edges`); points every :data:`SAMPLE` spacings along them."""
    o = np.asarray(o, float).reshape(-1, 3)
    box = None
    if len(o):
        box = (o.min(axis=0) - 4 * spacing, o.max(axis=0) + 4 * spacing)
    surf = None
    note = []
    try:
        surf = surface_of(shape, box)
    except Exception as exc:  # noqa: BLE001 - a shape manifold3d refuses: the lattice serves
        note.append(f"the shape's surface could not be made ({type(exc).__name__}: {exc}); "
                    "re-entrant edges from the lattice")
    if surf is not None:
        V, F, how = surf
        seg, turn, own = sharp_edges(V, F, spacing)
        pts, which = sample_segments(seg, SAMPLE * spacing)
        # an edge that turns sharply only with its neighbours within the window (its own
        # facet's angle below SHARP_DEG) is a fillet of radius under 1.43 spacings, faceted:
        # singular at this spacing, bounded in the part
        kind = np.where(own[which] >= SHARP_DEG - 1e-9, 0, KINDS.index("unresolved fillet"))
        return Singular(pts, kind.astype(np.int64), turn[which], how, note, (V, F))
    pts = lattice_edges(o, spacing) if len(o) else np.zeros((0, 3))
    return Singular(pts, np.zeros(len(pts), np.int64), np.full(len(pts), 90.0),
                    "the lattice's concave edges", note)


# --------------------------------------------------------------------------- supports, loads
def _neighbours(o: np.ndarray, spacing: float):
    from scipy.spatial import cKDTree

    return cKDTree(o).query_pairs(NEIGHBOUR * spacing * (1 + 1e-9), output_type="ndarray")


def support_boundary(o: np.ndarray, fixed: np.ndarray, spacing: float) -> np.ndarray:
    """Indices of the particles held in all three directions that have a lattice neighbour
    (:data:`NEIGHBOUR`) which is not: the boundary of the support set. ``fixed``: (n, 3) bool
    or (n,) bool."""
    o = np.asarray(o, float).reshape(-1, 3)
    f = np.asarray(fixed, bool)
    held = f.all(axis=1) if f.ndim == 2 else f
    if not held.any() or held.all():
        return np.zeros(0, np.int64)
    from scipy.spatial import cKDTree

    k = np.flatnonzero(held)
    r = NEIGHBOUR * spacing * (1 + 1e-9)
    every = cKDTree(o).query_ball_point(o[k], r, return_length=True)
    held_only = cKDTree(o[k]).query_ball_point(o[k], r, return_length=True)
    return k[every > held_only]


def point_loads(o: np.ndarray, force: np.ndarray, spacing: float,
                held=None) -> np.ndarray:
    """Indices of the loaded particles that belong to a point or line load: a connected
    cluster of loaded particles whose extent in its second-largest principal direction is at
    most :data:`POINT_ROWS` spacings. ``force``: (n, 3) external force per particle."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    o = np.asarray(o, float).reshape(-1, 3)
    loaded = np.any(np.asarray(force, float).reshape(-1, 3) != 0, axis=1)
    if held is not None:
        h = np.asarray(held, bool)
        loaded &= ~(h.all(axis=1) if h.ndim == 2 else h)
    k = np.flatnonzero(loaded)
    if not len(k):
        return np.zeros(0, np.int64)
    x = o[k]
    P = _neighbours(x, spacing) if len(k) > 1 else np.zeros((0, 2), np.int64)
    n = len(k)
    graph = coo_matrix((np.ones(len(P)), (P[:, 0], P[:, 1])), shape=(n, n))
    nc, label = connected_components(graph, directed=False)
    out = []
    for c in range(nc):
        sel = np.flatnonzero(label == c)
        y = x[sel] - x[sel].mean(axis=0)
        if len(sel) > 1:
            _, _, vt = np.linalg.svd(y, full_matrices=False)
            ext = np.sort(np.ptp(y @ vt.T, axis=0))[::-1]
            second = ext[1] if len(ext) > 1 else 0.0
        else:
            second = 0.0
        if second <= POINT_ROWS * spacing * (1 + 1e-6):
            out.append(k[sel])
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def find(o: np.ndarray, spacing: float, shape=None, fixed=None, force=None) -> Singular:
    """Every singular point of one part (module docstring).

    Parameters
    ----------
    o : (n, 3) array
        The part's particles' original positions.
    spacing : float
        Its lattice spacing.
    shape : Region, optional
        The shape it was filled from (a mesh :class:`~rackstress.model.regions.Surface` or a
        CSG region); None: re-entrant edges from the lattice.
    fixed : (n, 3) bool array, optional
        The directions each particle is held in.
    force : (n, 3) array, optional
        The external force on each particle.

    Returns
    -------
    Singular
    """
    o = np.asarray(o, float).reshape(-1, 3)
    parts = [reentrant(o, spacing, shape)]
    if fixed is not None and len(o):
        k = support_boundary(o, fixed, spacing)
        parts.append(Singular(o[k], np.ones(len(k), np.int64), np.full(len(k), np.nan),
                              "supports"))
    if force is not None and len(o):
        k = point_loads(o, force, spacing, fixed)
        parts.append(Singular(o[k], np.full(len(k), 2, np.int64), np.full(len(k), np.nan),
                              "loads"))
    out = concat(parts, parts[0].source)
    out.surface = parts[0].surface
    return out


def part_geometry(scene, name: str) -> tuple[float, object]:
    """(spacing, shape) of a scene's part: a material part's from its solid lattice
    (:class:`rackstress.model.solid.Solid`: its spacing and the shape it was filled from,
    None for a lattice block); else the ``spacing`` it was filled at, or the median nearest
    distance of its particles, and no shape."""
    from rackstress.model.operators import Bind, WithinInside
    from rackstress.model.solid import Solid

    g = scene.groups[name]
    for op in scene.operators.get(name, []):
        if isinstance(op, Bind) and op.source == name and isinstance(op.coeff, Solid):
            return float(op.coeff.spacing), op.coeff.part
    shape = None
    for op in scene.operators.get(name, []):
        if isinstance(op, Bind) and op.source == name and isinstance(op.coeff, WithinInside):
            shape = op.coeff.region
    meta = g.meta if isinstance(g.meta, dict) else {}
    s = meta.get("spacing") or (meta.get("solid") or {}).get("spacing")
    if s:
        return float(s), shape
    return nearest_spacing(g.o), shape


def nearest_spacing(o: np.ndarray) -> float:
    """The median distance of each particle to its nearest neighbour (1.0 for fewer than 2)."""
    from scipy.spatial import cKDTree

    o = np.asarray(o, float).reshape(-1, 3)
    if len(o) < 2:
        return 1.0
    d, _ = cKDTree(o).query(o, k=2)
    return float(np.median(d[:, 1]))


# --------------------------------------------------------------------------- the part's walls
def chords(o: np.ndarray, spacing: float, phi: np.ndarray | None = None) -> np.ndarray:
    """Per particle, the shortest chord through the part along x, y or z: the run of lattice
    neighbours holding it, each cell counted with its share of the part along that axis
    (``phi``, :func:`rackstress.model.solid.axis_fractions`; None: whole cells) — the local
    wall thickness there."""
    a = float(spacing)
    o = np.asarray(o, float).reshape(-1, 3)
    g = np.rint((o - o.min(axis=0)) / a).astype(np.int64)
    phi = np.ones((len(o), 3)) if phi is None else np.asarray(phi, float)
    chord = np.full(len(o), np.inf)
    for ax in range(3):
        other = [k for k in range(3) if k != ax]
        order = np.lexsort((g[:, ax], g[:, other[1]], g[:, other[0]]))
        gs = g[order]
        new = np.r_[True, np.any(gs[1:, other] != gs[:-1, other], axis=1)
                    | (gs[1:, ax] != gs[:-1, ax] + 1)]
        run = np.cumsum(new) - 1
        length = np.bincount(run, weights=phi[order, ax]) * a
        c = np.empty(len(o))
        c[order] = length[run]
        chord = np.minimum(chord, c)
    return chord


def wall_thickness(o: np.ndarray, spacing: float, shape=None, phi=None) -> float:
    """The part's wall thickness: the median over its particles of :func:`chords`, each
    boundary cell counted with its share of the part when the ``shape`` (or its fractions
    ``phi``) is known, so it is the part's own length, not a whole number of spacings.

    >>> o = np.array([[x, y, z] for x in range(20) for y in range(3) for z in range(8)], float)
    >>> wall_thickness(o, 1.0)                  # a 20 × 3 × 8 plate of cells: 3 thick
    3.0
    """
    o = np.asarray(o, float).reshape(-1, 3)
    if phi is None and shape is not None:
        from rackstress.model.solid import axis_fractions

        phi = axis_fractions(o, float(spacing), shape)
    return float(np.median(chords(o, spacing, phi)))
