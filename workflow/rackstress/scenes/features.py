"""Named features of a part: its cylindrical holes (H1, H2, …) and flat faces (F1, F2, …),
and the thickness of its walls.

A CAD export is a triangle mesh: a hole's bore is a ring of N flat strips (N = 12 … 64 for the
usual chord tolerances), a flat face a group of coplanar triangles, a fillet a partial ring of
strips, a chamfer a narrow flat face at an angle. :func:`part_features` finds them with
trimesh's facets (coplanar groups) and face adjacency, and writes by hand only what trimesh
lacks — the grouping of strips into cylinders:

* two facets meeting at a small bend (0.5° … 40°) along an edge are neighbouring strips of
  one curved surface when every bend edge of each is parallel to the others (a strip's long
  sides are the cylinder's generators) and their local radii agree, r = w / (2·sin(θ/2))
  for a strip of width w between bends of θ (the chord of a regular N-gon);
* the strips so linked are a cylinder when their vertices, projected along the axis, lie on
  one circle (trimesh's least-squares ``fit_nsphere``, within 1 % of the radius);
* it is a **hole** when its normals point at the axis (material outside) and it closes at
  least 270° around it; a partial ring (fillets, rounded edges) or a convex one (bosses) is
  none, and its strips are no face;
* a hole is **through** when the axis leaves the part at both ends of the bore (VTK's cell
  locator casts the rays), else **blind**;
* a **face** is a facet of at least :data:`FACE_SHARE` of the surface area that is not a
  strip of a cylinder, nor a chamfer (narrow, and meeting its neighbours at 20° … 70°).

Names are stable: holes by radius (largest first), faces by area, ties by position; they are
found on the mesh as read and scaled, before any rotation or translation, so a placed part
keeps the names ``rackstress inspect`` prints for its file.

:func:`wall_thickness` measures walls by rays cast inward along the surface normals from
points spread over the surface by area: the distance to the opposite face (a hit on a triangle
facing the other way) is the wall's thickness there.

Example
-------
>>> import trimesh
>>> plate = trimesh.creation.box((40, 20, 4)).difference(
...     trimesh.creation.cylinder(radius=3, height=10, sections=32))
>>> f = part_features(plate)
>>> len(f.holes), f.holes[0].name, round(f.holes[0].radius, 3), f.holes[0].through
(1, 'H1', 3.0, True)
>>> f.faces[0].name, round(f.faces[0].area, 3)      # 40 × 20 less the 32-gon of r 3
('F1', 771.907)
>>> f.nearest([3.5, 0, 0])
'hole H1'
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from rackstress.errors import SceneError

#: bends between two strips of one curved surface (degrees): above, an edge (or a 90° corner)
BEND_MIN, BEND_MAX = 0.5, 40.0
#: a strip's bend edges are parallel within this (degrees)
PARALLEL_DEG = 3.0
#: two strips' local radii r = w / (2 sin θ/2) agree within this fraction
RADIUS_AGREE = 0.25
#: the strips' vertices lie on the fitted circle within this fraction of its radius
CIRCLE_TOL = 0.01
#: a hole closes at least this many degrees around its axis
HOLE_COVER_DEG = 240.0
#: a face is at least this share of the part's surface area
FACE_SHARE = 0.002
#: a chamfer: a face narrower than this fraction of its length, meeting its neighbours at
#: CHAMFER_BEND degrees over most of its boundary
CHAMFER_NARROW = 0.25
CHAMFER_BEND = (20.0, 70.0)
#: surface points whose inward rays measure the walls
WALL_SAMPLES = 6000


@dataclass(frozen=True)
class Hole:
    """A cylindrical hole: its axis (``centre``, at mid-depth, and unit ``axis``), ``radius``,
    ``depth`` (the bore's length along the axis), ``through`` or blind, the number of strips
    round the bore in the mesh (``segments``), its ``body`` and its bore's triangles."""

    name: str
    centre: np.ndarray
    axis: np.ndarray
    radius: float
    depth: float
    through: bool
    segments: int
    body: int
    triangles: np.ndarray = field(repr=False)

    @property
    def kind(self) -> str:
        return "hole"

    def to_dict(self) -> dict:
        return {"name": self.name, "centre": _r(self.centre), "axis": _r(self.axis),
                "radius": _r(self.radius), "diameter": _r(2 * self.radius),
                "depth": _r(self.depth), "through": self.through, "segments": self.segments,
                "body": self.body}


@dataclass(frozen=True)
class Face:
    """A flat face: outward unit ``normal``, ``area``, area ``centre``, in-plane ``extent``
    (length, width of its smallest enclosing rectangle), ``body`` and its triangles."""

    name: str
    normal: np.ndarray
    area: float
    centre: np.ndarray
    extent: tuple
    body: int
    triangles: np.ndarray = field(repr=False)

    @property
    def kind(self) -> str:
        return "face"

    def to_dict(self) -> dict:
        return {"name": self.name, "normal": _r(self.normal), "area": _r(self.area),
                "centre": _r(self.centre), "extent": _r(self.extent), "body": self.body}


def _r(x, digits: int = 6):
    """A value for JSON and tables: floats to ``digits`` significant digits."""
    if np.ndim(x) == 0:
        x = float(x)
        return float(f"{x:.{digits}g}") if np.isfinite(x) else None
    return [_r(v, digits) for v in np.asarray(x, dtype=float).ravel()]


@dataclass
class Features:
    """The named holes and faces of one mesh (:func:`part_features`), with the mesh's
    ``vertices`` and ``faces`` (triangles) they index, its number of ``bodies``, and the
    counts of what is neither (``fillets``: partial or convex cylinders)."""

    holes: list
    faces: list
    vertices: np.ndarray = field(repr=False)
    triangles: np.ndarray = field(repr=False)
    bodies: int = 1
    fillets: int = 0

    def names(self) -> list:
        return [h.name for h in self.holes] + [f.name for f in self.faces]

    def get(self, name: str):
        """The hole or face called ``name`` (KeyError listing the names there are)."""
        for x in (*self.holes, *self.faces):
            if x.name == name:
                return x
        raise KeyError(name)

    def feature_points(self, feature) -> np.ndarray:
        """The corners of a feature's triangles (k×3×3)."""
        return self.vertices[self.triangles[feature.triangles]]

    def distance(self, feature, points) -> np.ndarray:
        """Distance from each point to the feature's surface (its triangles)."""
        return _distance_to_triangles(self.feature_points(feature), np.asarray(points, float))

    def nearest(self, point, within: float | None = None, kinds=("hole", "face")) -> str | None:
        """``"hole H2"`` or ``"face F5"``: the feature whose surface is nearest ``point``, if
        within ``within`` (default: 5 % of the part's bounding-box diagonal), else None."""
        p = np.asarray(point, dtype=float).reshape(1, 3)
        if within is None:
            lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
            within = 0.05 * float(np.linalg.norm(hi - lo))
        best, name = math.inf, None
        for x in (*self.holes, *self.faces):
            if x.kind not in kinds:
                continue
            d = float(self.distance(x, p)[0])
            if d < best:
                best, name = d, f"{x.kind} {x.name}"
        return name if best <= within else None

    def placed(self, rotate=(0.0, 0.0, 0.0), translate=(0.0, 0.0, 0.0)) -> "Features":
        """The same features after a rigid placement (degrees about x, then y, then z, fixed
        axes; then a translation): the names stay those of the mesh as read."""
        from scipy.spatial.transform import Rotation

        R = Rotation.from_euler("xyz", rotate, degrees=True)
        t = np.asarray(translate, dtype=float)
        pt = lambda x: R.apply(np.asarray(x, float)) + t      # noqa: E731
        holes = [replace(h, centre=pt(h.centre), axis=R.apply(h.axis)) for h in self.holes]
        faces = [replace(f, centre=pt(f.centre), normal=R.apply(f.normal)) for f in self.faces]
        return Features(holes, faces, pt(self.vertices), self.triangles, self.bodies,
                        self.fillets)

    def to_dict(self) -> dict:
        return {"holes": [h.to_dict() for h in self.holes],
                "faces": [f.to_dict() for f in self.faces],
                "bodies": self.bodies, "fillets": self.fillets}


# --------------------------------------------------------------------------- the mesh
def as_trimesh(mesh):
    """A trimesh.Trimesh from a Trimesh, a pyvista PolyData, a :class:`MeshSurface` (its
    ``polydata``), or (vertices, triangles)."""
    import trimesh

    if isinstance(mesh, trimesh.Trimesh):
        return mesh
    if isinstance(mesh, tuple) and len(mesh) == 2:
        return trimesh.Trimesh(np.asarray(mesh[0], float), np.asarray(mesh[1], np.int64),
                               process=True)
    poly = getattr(mesh, "polydata", mesh)
    poly = poly.triangulate()
    return trimesh.Trimesh(np.asarray(poly.points, float),
                           np.asarray(poly.regular_faces, np.int64), process=True)


def _union_find(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected-component labels of n nodes joined by the pairs (a, b) (scipy's csgraph)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    g = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n))
    return connected_components(g, directed=False)[1]


def _basis(axis: np.ndarray) -> tuple:
    """Two unit vectors completing ``axis`` to a right-handed orthonormal basis."""
    a = axis / np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    u = np.cross(a, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(a, u)


def _canonical(d: np.ndarray) -> np.ndarray:
    """Unit directions with the sign that makes the largest component positive (a line's
    direction, whichever way its edge was written)."""
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    k = np.argmax(np.abs(d), axis=-1)
    s = np.sign(np.take_along_axis(d, k[..., None], axis=-1))
    return d * np.where(s == 0, 1.0, s)


# --------------------------------------------------------------------------- features
def part_features(mesh, cad: tuple | None = None) -> Features:
    """The named holes and faces of ``mesh`` (module doc).

    Parameters
    ----------
    mesh : trimesh.Trimesh, pyvista.PolyData, MeshSurface or (vertices, triangles)
        A closed surface; several bodies are allowed (features are found on each).
    cad : (face of each triangle, {face: kind}), optional
        A STEP part's CAD faces (:func:`rackstress.scenes.mesh.step_surface`): its planes are
        the faces and its cylinders the candidate holes, instead of strips found in the mesh.

    Returns
    -------
    Features
    """
    if cad is not None:          # the triangles keep their order: each is its CAD face's
        import trimesh

        tm = trimesh.Trimesh(np.asarray(mesh[0], float), np.asarray(mesh[1], np.int64),
                             process=False)
        tm.merge_vertices()
    else:
        tm = as_trimesh(mesh)
    V, T = np.asarray(tm.vertices), np.asarray(tm.faces)
    nT = len(T)
    if nT == 0:
        raise SceneError("the mesh has no triangles")
    body = _union_find(nT, tm.face_adjacency[:, 0], tm.face_adjacency[:, 1]) \
        if len(tm.face_adjacency) else np.zeros(nT, np.int64)
    # facets: trimesh's coplanar groups; every other triangle its own
    facet_of = np.full(nT, -1, dtype=np.int64)
    groups = list(tm.facets)
    for k, f in enumerate(groups):
        facet_of[f] = k
    singles = np.flatnonzero(facet_of < 0)
    facet_of[singles] = len(groups) + np.arange(len(singles))
    groups += [np.array([s]) for s in singles]
    nF = len(groups)
    area_t = tm.area_faces
    fa_area = np.bincount(facet_of, weights=area_t, minlength=nF)
    fa_normal = np.zeros((nF, 3))
    for k in range(3):
        fa_normal[:, k] = np.bincount(facet_of, weights=tm.face_normals[:, k] * area_t,
                                      minlength=nF)
    fa_normal /= np.maximum(np.linalg.norm(fa_normal, axis=1, keepdims=True), 1e-300)

    adj = tm.face_adjacency
    ang = np.degrees(tm.face_adjacency_angles)
    ev = tm.face_adjacency_edges
    fa, fb = facet_of[adj[:, 0]], facet_of[adj[:, 1]]
    between = fa != fb
    crease = between & (ang >= BEND_MIN) & (ang <= BEND_MAX)
    if cad is not None:
        owner, kinds = np.asarray(cad[0]), cad[1]
        groups = [np.flatnonzero(owner == tag) for tag in sorted(kinds)]
        groups = [g for g in groups if len(g)]
        facet_of = np.zeros(nT, dtype=np.int64)
        for k, g in enumerate(groups):
            facet_of[g] = k
        nF = len(groups)
        fa_area = np.array([tm.area_faces[g].sum() for g in groups])
        fa_normal = np.array([_unit(np.sum(tm.face_normals[g] * tm.area_faces[g, None], axis=0))
                              for g in groups])
        fa, fb = facet_of[adj[:, 0]], facet_of[adj[:, 1]]
        between = fa != fb
        kind_of = [kinds[int(owner[g[0]])] for g in groups]
        pieces = [_cad_cylinder(V, T, tm, g, k) for k, g in enumerate(groups)
                  if kind_of[k] == "Cylinder"]
        cyl = _merge_coaxial(V, [c for c in pieces if c is not None])
        for c in cyl:
            c["body"] = int(body[c["triangles"][0]])
        planar = np.array([kd == "Plane" for kd in kind_of])
    else:
        cyl = _merge_coaxial(V, _cylinders(V, T, tm, facet_of, nF, fa, fb, ang, ev, crease,
                                           body))
        planar = None
    in_curved = np.zeros(nF, dtype=bool)
    holes, fillets = [], 0
    for c in cyl:
        in_curved[c["facets"]] = True
        if c["hole"]:
            holes.append(c)
        else:
            fillets += 1
    loc = _locator(tm)[0] if holes else None
    holes = [_finish_hole(V, T, tm, h, loc) for h in holes]
    # names by size, ties by position, both to 1e-4 of the part's size (fits and float32
    # files differ below that)
    q = 1e-4 * float(np.linalg.norm(tm.extents))
    holes.sort(key=lambda h: (-round(h["radius"] / q), *np.round(h["centre"] / q)))
    hole_objs = [Hole(f"H{i}", h["centre"], h["axis"], h["radius"], h["depth"], h["through"],
                      h["segments"], h["body"], h["triangles"])
                 for i, h in enumerate(holes, 1)]

    if planar is not None:       # a CAD part: its planes only
        in_curved |= ~planar
    faces = _faces(V, T, tm, groups, facet_of, fa_area, fa_normal, in_curved, fa, fb, ang, ev,
                   between, body)
    faces.sort(key=lambda f: (-round(f["area"] / q ** 2 * 1e-4), *np.round(f["centre"] / q)))
    face_objs = [Face(f"F{i}", f["normal"], f["area"], f["centre"], f["extent"], f["body"],
                      f["triangles"]) for i, f in enumerate(faces, 1)]
    return Features(hole_objs, face_objs, V.copy(), T.copy(), int(body.max()) + 1, fillets)


def _cylinders(V, T, tm, facet_of, nF, fa, fb, ang, ev, crease, body) -> list:
    """Circular cylinders made of strips (module doc): one dict each, with ``hole``."""
    if not crease.any():
        return []
    ci = np.flatnonzero(crease)
    d = _canonical(V[ev[ci, 1]] - V[ev[ci, 0]])
    mid = 0.5 * (V[ev[ci, 0]] + V[ev[ci, 1]])
    # each facet's bend edges (facet, edge), both ways; per facet at once with reduceat
    f_of = np.concatenate([fa[ci], fb[ci]])
    e_of = np.concatenate([np.arange(len(ci))] * 2)
    order = np.argsort(f_of, kind="stable")
    f_of, e_of = f_of[order], e_of[order]
    starts = np.flatnonzero(np.r_[True, f_of[1:] != f_of[:-1]])
    count = np.diff(np.r_[starts, len(f_of)])
    first = np.repeat(e_of[starts], count)
    dd = d[e_of] * np.sign(np.sum(d[e_of] * d[first], axis=1))[:, None]
    a = np.add.reduceat(dd, starts, axis=0)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    cos_par = math.cos(math.radians(PARALLEL_DEG))
    parallel = np.minimum.reduceat(np.abs(np.sum(dd * np.repeat(a, count, axis=0), axis=1)),
                                   starts) >= cos_par
    helper = np.eye(3)[np.argmin(np.abs(a), axis=1)]
    u = np.cross(a, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(a, u)
    # the strip's width: its bend lines projected along the axis are two points
    m, m0 = mid[e_of], mid[first]
    uu, vv = np.repeat(u, count, axis=0), np.repeat(v, count, axis=0)
    gap = np.hypot(np.sum((m - m0) * uu, axis=1), np.sum((m - m0) * vv, axis=1))
    w = np.maximum.reduceat(gap, starts)
    theta = np.radians(np.maximum.reduceat(ang[ci][e_of], starts))
    ok = parallel & (w > 0) & (theta > 0)
    facets_here = f_of[starts]
    axis_f = np.full((nF, 3), np.nan)
    radius_f = np.full(nF, np.nan)
    axis_f[facets_here[ok]] = a[ok]
    radius_f[facets_here[ok]] = w[ok] / (2.0 * np.sin(theta[ok] / 2.0))
    A, B = fa[ci], fb[ci]
    ok = np.isfinite(radius_f[A]) & np.isfinite(radius_f[B])
    ok &= np.abs(np.sum(axis_f[A] * axis_f[B], axis=1)) >= cos_par
    ok &= np.abs(np.sum(np.nan_to_num(axis_f[A]) * d, axis=1)) >= cos_par
    rA, rB = radius_f[A], radius_f[B]
    ok &= np.abs(rA - rB) <= RADIUS_AGREE * np.fmax(rA, rB)
    if not ok.any():
        return []
    label = _union_find(nF, A[ok], B[ok])
    linked = np.zeros(nF, dtype=bool)
    linked[A[ok]] = linked[B[ok]] = True
    out = []
    tri_of_facet = _members(facet_of, nF)
    for lab in np.unique(label[linked]):
        facets = np.flatnonzero((label == lab) & linked)
        if len(facets) < 2:
            continue
        c = _fit_cylinder(V, T, tm, facets, tri_of_facet, axis_f)
        if c is not None:
            c["body"] = int(body[c["triangles"][0]])
            out.append(c)
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v


def _cad_cylinder(V, T, tm, tris: np.ndarray, facet: int) -> dict | None:
    """A CAD cylinder face (STEP) as a piece: its axis is the direction its normals are all
    perpendicular to (the least eigenvector of Σ a·n·nᵀ), its circle the least-squares fit of
    its vertices projected along it."""
    import trimesh

    n, w = tm.face_normals[tris], tm.area_faces[tris]
    evals, evecs = np.linalg.eigh((n * w[:, None]).T @ n)
    a = _canonical(evecs[:, 0])
    u, v = _basis(a)
    vid = np.unique(T[tris])
    q = np.column_stack([V[vid] @ u, V[vid] @ v])
    try:
        c2, r, _ = trimesh.nsphere.fit_nsphere(q)
    except Exception:  # noqa: BLE001 - a degenerate fit is no cylinder
        return None
    if not (r > 0 and np.isfinite(r)):
        return None
    centre0 = c2[0] * u + c2[1] * v
    cen = tm.triangles_center[tris]
    radial = cen - centre0 - np.outer(cen @ a, a)
    radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-300)
    inward = float(np.average(np.sum(n * radial, axis=1), weights=w)) < 0
    s = V[vid] @ a
    return {"facets": np.array([facet]), "triangles": np.asarray(tris), "axis": a,
            "point": centre0, "radius": float(r), "inward": inward,
            "span": (float(s.min()), float(s.max())), "vertices": vid}


def _members(facet_of: np.ndarray, nF: int) -> list:
    order = np.argsort(facet_of, kind="stable")
    cuts = np.searchsorted(facet_of[order], np.arange(nF + 1))
    return [order[cuts[k]:cuts[k + 1]] for k in range(nF)]


def _fit_cylinder(V, T, tm, facets, tri_of_facet, axis_f) -> dict | None:
    """The circle the strips ``facets`` lie on, or None; dropping strips off the circle once
    (a flat face linked in at a tangent)."""
    import trimesh

    a = _canonical(np.nansum(axis_f[facets] * np.sign(axis_f[facets] @ axis_f[facets[0]])[:, None],
                             axis=0))
    u, v = _basis(a)
    for attempt in range(2):
        tris = np.concatenate([tri_of_facet[f] for f in facets])
        vid = np.unique(T[tris])
        q = np.column_stack([V[vid] @ u, V[vid] @ v])
        try:
            c2, r, _ = trimesh.nsphere.fit_nsphere(q)
        except Exception:  # noqa: BLE001 - a degenerate fit is no cylinder
            return None
        dev = np.abs(np.linalg.norm(q - c2, axis=1) - r)
        size = float(np.ptp(V[vid], axis=0).max())
        tol = CIRCLE_TOL * r + 1e-7 * size
        if dev.max() <= tol:
            break
        if attempt:
            return None
        # keep the strips whose every vertex is near the circle
        dev_of = dict(zip(vid.tolist(), dev.tolist()))
        keep = [f for f in facets
                if max(dev_of[x] for x in T[tri_of_facet[f]].ravel()) <= tol]
        if len(keep) < 2 or len(keep) == len(facets):
            return None
        facets = np.asarray(keep)
    if not (r > 0 and np.isfinite(r)):
        return None
    centre0 = c2[0] * u + c2[1] * v
    # concave (a hole): the normals point at the axis
    cen = tm.triangles_center[tris]
    radial = cen - centre0 - np.outer(cen @ a, a)
    radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-300)
    inward = float(np.average(np.sum(tm.face_normals[tris] * radial, axis=1),
                              weights=tm.area_faces[tris])) < 0
    s = V[vid] @ a
    return {"facets": np.asarray(facets), "triangles": tris, "axis": a, "point": centre0,
            "radius": float(r), "inward": inward, "span": (float(s.min()), float(s.max())),
            "vertices": vid}


def _cover(V, c: dict) -> tuple:
    """(degrees the piece closes round its axis, strips a full turn would have)."""
    u, v = _basis(c["axis"])
    q = V[c["vertices"]] - c["point"]
    phi = np.sort(np.arctan2(q @ v, q @ u))
    gaps = np.diff(np.r_[phi, phi[0] + 2 * np.pi])
    steps = gaps[gaps > 1e-3]
    segments = int(round(2 * np.pi / float(np.median(steps)))) if len(steps) else 0
    return 360.0 - math.degrees(float(gaps.max())), segments


def _merge_coaxial(V, pieces: list) -> list:
    """Pieces of one circular cylinder — one axis, one radius, one side, overlapping along
    the axis — are one (a bore interrupted by a flat, a slot, a groove); each then a hole or
    not by how far it closes round its axis."""
    out = []
    cos_par = math.cos(math.radians(PARALLEL_DEG))
    for h in pieces:
        for g in out:
            if abs(float(g["axis"] @ h["axis"])) < cos_par or g["inward"] != h["inward"]:
                continue
            if abs(g["radius"] - h["radius"]) > 0.02 * g["radius"]:
                continue
            off = h["point"] - g["point"]
            if np.linalg.norm(off - (off @ g["axis"]) * g["axis"]) > 0.02 * g["radius"]:
                continue
            sign = 1.0 if float(g["axis"] @ h["axis"]) > 0 else -1.0
            lo, hi = sorted((sign * h["span"][0], sign * h["span"][1]))
            if lo > g["span"][1] + 0.1 * g["radius"] or hi < g["span"][0] - 0.1 * g["radius"]:
                continue                  # the same axis further along: another hole
            g["triangles"] = np.concatenate([g["triangles"], h["triangles"]])
            g["facets"] = np.concatenate([g["facets"], h["facets"]])
            g["vertices"] = np.union1d(g["vertices"], h["vertices"])
            g["span"] = (min(g["span"][0], lo), max(g["span"][1], hi))
            break
        else:
            out.append(dict(h))
    for g in out:
        g["cover"], g["segments"] = _cover(V, g)
        g["hole"] = bool(g["inward"] and g["cover"] >= HOLE_COVER_DEG)
    return out


def _finish_hole(V, T, tm, h: dict, loc=None) -> dict:
    """Centre at mid-depth, depth, and through or blind (rays along the axis)."""
    a = h["axis"]
    pts = V[np.unique(T[h["triangles"]])]
    s = (pts - h["point"]) @ a
    lo, hi = float(s.min()), float(s.max())
    centre = h["point"] + a * (0.5 * (lo + hi))     # the axis point at mid-depth
    depth = hi - lo
    r = h["radius"]
    hits = _first_hits(tm, np.vstack([centre, centre]), np.vstack([a, -a]),
                       reach=float(np.linalg.norm(tm.extents)) * 2, loc=loc)
    closed = [t is not None and t <= 0.5 * depth + 0.7 * r + 1e-9 * depth for t in hits]
    return {**h, "centre": centre, "depth": depth, "through": not any(closed)}


# --------------------------------------------------------------------------- faces
def _faces(V, T, tm, groups, facet_of, fa_area, fa_normal, in_curved, fa, fb, ang, ev,
           between, body) -> list:
    total = float(tm.area)
    out = []
    edge_len = np.linalg.norm(V[ev[:, 1]] - V[ev[:, 0]], axis=1)
    bi = np.flatnonzero(between)
    # each facet's boundary edges to other facets: bend angle and length
    f_of = np.concatenate([fa[bi], fb[bi]])
    e_of = np.concatenate([bi, bi])
    order = np.argsort(f_of, kind="stable")
    f_of, e_of = f_of[order], e_of[order]
    cuts = np.searchsorted(f_of, np.arange(len(groups) + 1))
    import trimesh

    for k, tris in enumerate(groups):
        if in_curved[k] or fa_area[k] < FACE_SHARE * total:
            continue
        n = fa_normal[k]
        u, v = _basis(n)
        pts = V[np.unique(T[tris])]
        q = np.column_stack([pts @ u, pts @ v])
        try:
            _, ext = trimesh.bounds.oriented_bounds_2D(q)
        except Exception:  # noqa: BLE001 - a degenerate outline: its axis-aligned box
            ext = np.ptp(q, axis=0)
        ext = tuple(sorted((float(x) for x in ext), reverse=True))
        es = e_of[cuts[k]:cuts[k + 1]]
        if ext[0] > 0 and ext[1] < CHAMFER_NARROW * ext[0] and len(es):
            lo, hi = CHAMFER_BEND
            slanted = edge_len[es][(ang[es] >= lo) & (ang[es] <= hi)].sum()
            if slanted > 0.5 * edge_len[es].sum():
                continue                      # a chamfer
        w = tm.area_faces[tris]
        centre = np.average(tm.triangles_center[tris], axis=0, weights=w)
        out.append({"normal": n, "area": float(fa_area[k]), "centre": centre, "extent": ext,
                    "body": int(body[tris[0]]), "triangles": np.asarray(tris)})
    return out


# --------------------------------------------------------------------------- rays, distances
def _locator(tm):
    """VTK's static cell locator over the mesh (ray casts ~60× faster than trimesh's
    pure-Python intersector on a 54,000-triangle part)."""
    import pyvista as pv
    from vtkmodules.vtkCommonDataModel import vtkStaticCellLocator

    poly = pv.PolyData.from_regular_faces(np.asarray(tm.vertices, float),
                                          np.asarray(tm.faces, np.int64))
    loc = vtkStaticCellLocator()
    loc.SetDataSet(poly)
    loc.BuildLocator()
    return loc, poly


def _first_hits(tm, origins, directions, reach: float, start: float = 0.0, loc=None,
                cells: bool = False):
    """The distance to the first surface hit along each ray (None: none within ``reach``),
    from ``start`` along it on; with ``cells`` also the hit triangle (-1: none)."""
    from vtkmodules.vtkCommonCore import reference
    from vtkmodules.vtkCommonDataModel import vtkGenericCell

    loc = loc or _locator(tm)[0]
    t = reference(0.0)
    x, pc = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    sub, cid = reference(0), reference(0)
    cell = vtkGenericCell()
    out, ids = [], []
    for o, d in zip(np.asarray(origins, float), np.asarray(directions, float)):
        p0 = o + start * d
        p1 = o + reach * d
        if loc.IntersectWithLine(p0, p1, 0.0, t, x, pc, sub, cid, cell):
            out.append(start + t.get() * (reach - start))
            ids.append(cid.get())
        else:
            out.append(None)
            ids.append(-1)
    return (out, np.asarray(ids)) if cells else out


def _distance_to_triangles(tri: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest of the triangles ``tri`` (k×3×3): trimesh's
    closest points on a mesh of those triangles."""
    import trimesh

    if not len(p):
        return np.zeros(0)
    sub = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3),
                          process=False)
    _, dist, _ = trimesh.proximity.closest_point(sub, p)
    return np.asarray(dist)


# --------------------------------------------------------------------------- walls
@dataclass
class Walls:
    """Wall thickness measured at ``points`` on the surface (``thickness``, NaN where the ray
    met no opposite face), with the area each point stands for (``weight``) and where the
    wall's middle is (``middle``)."""

    points: np.ndarray
    thickness: np.ndarray
    weight: np.ndarray
    middle: np.ndarray

    def percentile(self, q: float) -> float:
        """The thickness below which ``q`` % of the measured surface lies."""
        ok = np.isfinite(self.thickness)
        if not ok.any():
            return math.nan
        t, w = self.thickness[ok], self.weight[ok]
        order = np.argsort(t)
        cum = np.cumsum(w[order]) / w.sum()
        return float(t[order][min(np.searchsorted(cum, q / 100.0), len(t) - 1)])

    def thinner_than(self, limit: float, features: Features | None = None) -> list:
        """The places where walls are thinner than ``limit``: samples so thin grouped where
        they lie within ``limit`` of one another, thinnest first; each with its thinnest
        ``thickness``, its ``position`` (the wall's middle there), its share of the surface
        and the nearest named feature."""
        from scipy.sparse.csgraph import connected_components
        from scipy.spatial import cKDTree

        # strictly thinner: a wall of exactly 3 spacings (to the float32 file's digits) is not
        ok = np.flatnonzero(np.isfinite(self.thickness)
                            & (self.thickness < limit * (1.0 - 1e-6)))
        if not len(ok):
            return []
        mid = self.middle[ok]
        if np.linalg.norm(np.ptp(mid, axis=0)) < limit:
            # every two within the limit (a spacing the size of the part, a mesh in the wrong
            # units): one place, without listing each of the n² pairs (7 s at 4,000 samples)
            lab = np.zeros(len(ok), np.int64)
        else:
            pairs = cKDTree(mid).query_pairs(max(limit, 1e-300), output_type="ndarray")
            import scipy.sparse as sp

            g = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                              shape=(len(ok), len(ok))) if len(pairs) else \
                sp.coo_matrix((len(ok), len(ok)))
            _, lab = connected_components(g, directed=False)
        total = float(self.weight.sum())
        out = []
        for k in np.unique(lab):
            idx = ok[lab == k]
            j = idx[np.argmin(self.thickness[idx])]
            out.append({"thickness": float(self.thickness[j]),
                        "position": self.middle[j].tolist(),
                        "share": float(self.weight[idx].sum() / total),
                        "near": features.nearest(self.points[j]) if features else None})
        out.sort(key=lambda w: w["thickness"])
        return out


def wall_thickness(mesh, samples: int = WALL_SAMPLES, seed: int = 0) -> Walls:
    """Walls measured by rays cast inward along the normals (module doc): ``samples`` points
    spread over the surface by area (seeded: the same points each time)."""
    tm = as_trimesh(mesh)
    rng = np.random.default_rng(seed)
    area = tm.area_faces
    tri = rng.choice(len(area), size=samples, p=area / area.sum())
    r1, r2 = rng.random(samples), rng.random(samples)
    s = np.sqrt(r1)
    corners = tm.triangles[tri]
    pts = (1 - s)[:, None] * corners[:, 0] + (s * (1 - r2))[:, None] * corners[:, 1] \
        + (s * r2)[:, None] * corners[:, 2]
    n = tm.face_normals[tri]
    size = float(np.linalg.norm(tm.extents))
    loc, _ = _locator(tm)
    hits, cells = _first_hits(tm, pts, -n, reach=size, start=1e-7 * size, loc=loc, cells=True)
    t = np.array([np.nan if h is None else h for h in hits])
    opposite = np.zeros(samples, dtype=bool)
    hit = cells >= 0
    opposite[hit] = np.sum(tm.face_normals[cells[hit]] * n[hit], axis=1) < -0.5
    t[~opposite] = np.nan
    middle = pts - 0.5 * np.nan_to_num(t)[:, None] * n
    w = np.full(samples, float(area.sum()) / samples)
    return Walls(pts, t, w, middle)


# --------------------------------------------------------------------------- spacing
#: particles a part may have when its spacing is chosen from its walls (scene key ``budget``)
BUDGET = 20_000
#: particles wanted across a wall
ACROSS = 3
#: the walls a chosen spacing resolves: all but the thinnest WALL_PERCENTILE % of the surface
#: (a lone sliver or a glancing ray does not set the spacing of the whole part)
WALL_PERCENTILE = 2.0


def nice_up(x: float) -> float:
    """``x`` rounded up to two significant digits (0.2463 → 0.25, 1.234 → 1.3)."""
    if not (x > 0 and math.isfinite(x)):
        raise ValueError(f"not a positive length: {x!r}")
    e = 10.0 ** (math.floor(math.log10(x)) - 1)
    return float(f"{math.ceil(x / e * (1 - 1e-9)) * e:.12g}")


def nice_down(x: float) -> float:
    """``x`` rounded down to two significant digits (0.2467 → 0.24, 3.28 → 3.2)."""
    if not (x > 0 and math.isfinite(x)):
        raise ValueError(f"not a positive length: {x!r}")
    e = 10.0 ** (math.floor(math.log10(x)) - 1)
    return float(f"{math.floor(x / e * (1 + 1e-9)) * e:.12g}")


def choose_spacing(volume: float, walls: Walls | None, budget: int = BUDGET) -> dict:
    """The lattice spacing for a part of ``volume`` with these ``walls``: :data:`ACROSS`
    particles across all but the thinnest :data:`WALL_PERCENTILE` % of its walls, unless that
    makes more than ``budget`` particles (≈ volume / a³), in which case the budget sets it.

    Returns
    -------
    dict
        ``spacing``, ``particles`` (the estimate), ``budget``, ``wall`` (the wall thickness
        resolved, or None), ``limited_by`` ("walls" or "budget") and ``reason`` (a sentence).
    """
    if not (volume > 0):
        raise ValueError(f"a part of volume {volume!r} has no spacing")
    budget = int(budget)
    t = walls.percentile(WALL_PERCENTILE) if walls is not None else math.nan
    a_budget = (volume / budget) ** (1.0 / 3.0)
    a_wall = t / ACROSS if math.isfinite(t) else 0.0
    # rounded to two digits: down where the walls set it (they keep their 3 particles), up
    # where the budget does (it keeps its count)
    a = max(nice_down(a_wall) if a_wall > 0 else 0.0, nice_up(a_budget))
    n = volume / a ** 3
    if a_wall > 0 and nice_down(a_wall) >= nice_up(a_budget):
        why = (f"{ACROSS} particles across its walls of {t:.3g} (all but the thinnest "
               f"{WALL_PERCENTILE:g} % of its surface are at least that thick): about "
               f"{n:,.0f} particles, within the budget of {budget:,}")
        by = "walls"
    else:
        across = f"; its walls of {t:.3g} get {t / a:.1f} particles across ({ACROSS} wanted: " \
            f"a budget of {int(math.ceil(volume / (a_wall ** 3) / 1000.0)) * 1000:,} would " \
            "give them that)" if a_wall > 0 else ""
        why = (f"the particle budget of {budget:,} sets it: about {n:,.0f} particles"
               + across)
        by = "budget"
    return {"spacing": a, "particles": int(round(n)), "budget": budget,
            "wall": t if math.isfinite(t) else None, "limited_by": by, "reason": why}


# --------------------------------------------------------------------------- parts of scenes
def surface_features(surface) -> Features:
    """The named features of a placed mesh part (a :class:`rackstress.scenes.mesh.MeshSurface`
    from ``read_surface``): found on its file's mesh as read and scaled, so the names are
    the file's (``rackstress inspect FILE --scale S``), then rotated and moved with the part."""
    import os

    place = surface.placement
    f = _file_features(str(os.path.realpath(surface.file)), os.stat(surface.file).st_mtime_ns,
                       tuple(place.scale), bool(getattr(surface, "united", False)))
    return f.placed(place.rotate, place.translate)


from functools import lru_cache  # noqa: E402


@lru_cache(maxsize=16)
def _file_features(file: str, mtime_ns: int, scale: tuple, united: bool = False) -> Features:
    from rackstress.scenes.mesh import STEP_FORMATS, _checked, step_surface

    if file.lower().endswith(STEP_FORMATS) and not united:   # its CAD faces: planes, cylinders
        V, T, owner, kinds = step_surface(file, cad=True)
        return part_features((V * np.asarray(scale), T), cad=(owner, kinds))
    V, T, _ = _checked(file, mtime_ns, united)
    return part_features((V * np.asarray(scale), T))


class PartGeometry:
    """A mesh part of a scene (its placed surface and lattice spacing), whose named features
    regions select: ``hole = "H2"``, ``face = { near = [x, y, z] }`` (:meth:`region`)."""

    def __init__(self, surface, spacing: float):
        self.surface, self.spacing = surface, float(spacing)
        self._features = None

    @property
    def features(self) -> Features:
        if self._features is None:
            self._features = surface_features(self.surface)
        return self._features

    def feature(self, kind: str, spec):
        """The hole or face a region names: by name ("H2") or the nearest to a point
        ({ near = [x, y, z] })."""
        f = self.features
        have = f.holes if kind == "hole" else f.faces
        file = self.surface.file
        if isinstance(spec, dict):
            near = spec.get("near")
            if set(spec) != {"near"} or not (isinstance(near, list) and len(near) == 3 and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) for x in near)):
                raise SceneError(f"must be a {kind}'s name (\"{kind[0].upper()}1\") or "
                                 f"{{ near = [x, y, z] }}, got {spec!r}")
            if not have:
                raise SceneError(f"mesh {file} has no {kind}s to choose the nearest from "
                                 f"({_listing(f, kind)})")
            name = f.nearest(near, within=math.inf, kinds=(kind,))
            return f.get(name.split()[1])
        if not isinstance(spec, str):
            raise SceneError(f"must be a {kind}'s name (\"{kind[0].upper()}1\") or "
                             f"{{ near = [x, y, z] }}, got {spec!r}")
        for x in have:
            if x.name == spec:
                return x
        raise SceneError(f"mesh {file} has no {kind} '{spec}'; {_listing(f, kind)} (rackstress "
                         f"inspect {file}" + (f" --scale {self.surface.placement.scale[0]:g}"
                                              if self.surface.placement.scale[0] != 1 else "")
                         + " lists them with their positions)")

    def region(self, kind: str, spec):
        """The particles within one spacing of the named hole's bore or face
        (:class:`rackstress.model.regions.NearSurface`), the feature attached."""
        from rackstress.model.regions import NearSurface

        x = self.feature(kind, spec)
        reg = NearSurface(self.features.feature_points(x), self.spacing, f"{kind} {x.name}")
        reg.feature = x
        return reg


def _listing(f: Features, kind: str, most: int = 12) -> str:
    have = f.holes if kind == "hole" else f.faces
    if not have:
        return f"it has no {kind}s" + (f" (its faces: {', '.join(x.name for x in f.faces[:most])})"
                                        if kind == "hole" and f.faces else "")
    names = []
    for x in have[:most]:
        if kind == "hole":
            names.append(f"{x.name} (diameter {2 * x.radius:.4g}, {'through' if x.through else 'blind'}, "
                         f"at {[float(f'{c:.4g}') for c in x.centre]})")
        else:
            names.append(f"{x.name} (area {x.area:.4g}, normal "
                         f"{[float(f'{c:.3g}') + 0.0 for c in x.normal]})")
    more = f" and {len(have) - most} more" if len(have) > most else ""
    return f"its {kind}s are {', '.join(names)}{more}"
