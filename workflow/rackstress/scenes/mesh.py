"""Parts from CAD meshes: read a closed surface (STL, OBJ, PLY, VTK …), check it, place it.

A mesh becomes a :class:`rackstress.model.regions.Surface` region; a part is that region filled
with particles (:func:`rackstress.model.particles.fill`), and the same region can select the
particles of another group (``where``, supports, attraction regions).

Reading is pyvista's (``pyvista.read``: every surface format VTK reads — ``.stl``, ``.obj``,
``.ply``, ``.vtk`` and ``.vtp``); the checks are trimesh's (watertight, consistent
winding; along rays through the part its winding number must stay 0 or 1, which two overlapping
shells or a surface folded through itself break). Nothing here tests points against triangles
by hand: inside tests are VTK's, ray–triangle hits trimesh's.

Placement, in this order: ``scale`` (one factor or one per axis), ``rotate`` (degrees about the
x, then the y, then the z axis, fixed axes, about the origin), ``translate``. Lengths are the
scene's units (dimensionless, as in the paper): a mesh written in millimetres with spacing 1 gets
one particle per cubic millimetre.

Example
-------
>>> from rackstress.scenes.mesh import read_surface                     # doctest: +SKIP
>>> part = read_surface("examples/bracket/bracket.stl", translate=[0, 0, 0])   # doctest: +SKIP
>>> part.volume                                                          # doctest: +SKIP
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from rackstress.errors import SceneError
from rackstress.model.regions import Surface

#: File endings read as surfaces (anything else is refused with this list).
SURFACE_FORMATS = (".stl", ".obj", ".ply", ".vtk", ".vtp", ".step", ".stp")
#: of them, STEP solids (read by gmsh's OpenCASCADE reader, the ``fem`` extra)
STEP_FORMATS = (".step", ".stp")


@dataclass(frozen=True)
class Placement:
    """scale → rotate (degrees about x, y, z; fixed axes) → translate."""

    scale: tuple = (1.0, 1.0, 1.0)
    rotate: tuple = (0.0, 0.0, 0.0)
    translate: tuple = (0.0, 0.0, 0.0)

    def apply(self, points: np.ndarray) -> np.ndarray:
        from scipy.spatial.transform import Rotation

        p = np.asarray(points, dtype=np.float64) * np.asarray(self.scale)
        if any(self.rotate):
            p = Rotation.from_euler("xyz", self.rotate, degrees=True).apply(p)
        return p + np.asarray(self.translate)


def placement(scale=None, rotate=None, translate=None) -> Placement:
    """A :class:`Placement` from scene values (None: identity), checked."""
    if scale is None:
        s = (1.0, 1.0, 1.0)
    elif np.ndim(scale) == 0:
        s = (float(scale),) * 3
    else:
        s = tuple(float(x) for x in scale)
    if len(s) != 3 or not all(np.isfinite(x) and x > 0 for x in s):
        raise SceneError(f"scale must be a positive number or three positive numbers, got {scale!r}")
    rot = tuple(float(x) for x in (rotate if rotate is not None else (0, 0, 0)))
    tr = tuple(float(x) for x in (translate if translate is not None else (0, 0, 0)))
    for what, v in (("rotate", rot), ("translate", tr)):
        if len(v) != 3 or not all(np.isfinite(x) for x in v):
            raise SceneError(f"{what} must be three finite numbers [x, y, z], got {v!r}")
    return Placement(s, rot, tr)


#: what a mesh part's ``bodies`` may be: "one" (a file of several bodies is refused, naming
#: them) or "united" (their union is the part)
BODIES = ("one", "united")


def is_united(bodies: str) -> bool:
    """Whether ``bodies`` (:data:`BODIES`) asks for the union of a file's bodies; anything
    else is a SceneError naming the values."""
    if bodies not in BODIES:
        raise SceneError(f"bodies must be one of {', '.join(map(repr, BODIES))} (\"united\": "
                         f"the union of the file's bodies is the part), got {bodies!r}")
    return bodies == "united"


class MeshSurface(Surface):
    """A checked, placed closed surface: a :class:`Surface` region with its ``volume``."""

    def __init__(self, polydata, name: str, volume: float):
        super().__init__(polydata, name)
        self.volume = float(volume)


def read_surface(path, scale=None, rotate=None, translate=None, base: Path | None = None,
                 bodies: str = "one") -> MeshSurface:
    """Read, check and place the closed surface in ``path`` (relative to ``base`` if given);
    ``bodies = "united"``: the union of the file's bodies (:func:`united_triangles`).

    Raises
    ------
    SceneError
        naming the file: missing, unreadable, not a surface, open (with its number of boundary
        edges), inconsistently oriented, self-intersecting, or of zero volume.
    """
    p = Path(path)
    if base is not None and not p.is_absolute():
        p = Path(base) / p
    place = placement(scale, rotate, translate)
    if not p.is_file():
        raise SceneError(f"mesh file {p} does not exist")
    if p.suffix.lower() not in SURFACE_FORMATS:
        raise SceneError(f"mesh file {p}: unknown surface format '{p.suffix}'; readable: "
                         f"{', '.join(SURFACE_FORMATS)}")
    united = is_united(bodies)
    vertices, faces, volume = _checked(str(p.resolve()), os.stat(p).st_mtime_ns, united)
    import pyvista as pv

    placed = place.apply(vertices)
    poly = pv.PolyData.from_regular_faces(placed, faces)
    det = float(np.prod(place.scale))
    surface = MeshSurface(poly, str(p), abs(volume * det))
    surface.file, surface.placement, surface.united = str(p), place, united
    return surface


def read_triangles(file) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of the surface in ``file``, as written (no checks): pyvista's
    readers, or for STEP (``.step``, ``.stp``) gmsh's OpenCASCADE reader (:func:`step_surface`).

    Raises
    ------
    SceneError
        naming the file: missing, of an unknown format, unreadable, or holding no triangles.
    """
    p = Path(file)
    if not p.is_file():
        raise SceneError(f"mesh file {p} does not exist")
    if p.suffix.lower() not in SURFACE_FORMATS:
        raise SceneError(f"mesh file {p}: unknown surface format '{p.suffix}'; readable: "
                         f"{', '.join(SURFACE_FORMATS)}")
    if p.suffix.lower() in STEP_FORMATS:
        return step_surface(str(p))
    import pyvista as pv
    import warnings

    file = str(p)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # the reader's failure is reported below
            data = pv.read(file)
    except Exception as exc:  # noqa: BLE001 - any reader failure is the file's fault
        raise SceneError(f"mesh file {file}: cannot be read as a surface ({exc})") from None
    if isinstance(data, pv.MultiBlock):
        data = data.combine()
    try:
        if not isinstance(data, pv.PolyData):
            data = data.extract_surface(algorithm="dataset_surface")
        surf = data.triangulate().clean()
    except Exception as exc:  # noqa: BLE001
        raise SceneError(f"mesh file {file}: holds no triangle surface ({exc})") from None
    if surf.n_cells == 0 or surf.n_points < 4:
        raise SceneError(f"mesh file {file}: holds no triangle surface (no faces)")
    return (np.asarray(surf.points, dtype=np.float64),
            np.asarray(surf.regular_faces, dtype=np.int64))


#: the chord tolerance of a STEP part's surface mesh: this fraction of its size (an STL
#: export's "fine": 0.05 mm on a 100 mm part); and at least this many segments round a circle
STEP_CHORD, STEP_SEGMENTS = 5e-4, 36


class _quiet:
    """Standard output and error of this process (its C++ libraries' too) to /dev/null for the
    block: OpenCASCADE prints its STEP reader's messages there, and the error that follows
    says what went wrong in one paragraph."""

    def __enter__(self):
        import sys

        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (AttributeError, ValueError):
                pass
        self.saved = []
        try:
            null = os.open(os.devnull, os.O_WRONLY)
        except OSError:
            return self
        for fd in (1, 2):
            try:
                self.saved.append((fd, os.dup(fd)))
                os.dup2(null, fd)
            except OSError:
                pass
        os.close(null)
        return self

    def __exit__(self, *exc):
        for fd, copy in self.saved:
            os.dup2(copy, fd)
            os.close(copy)
        return False


def step_surface(file: str, cad: bool = False) -> tuple:
    """(vertices, triangles) of the solids of a STEP file, meshed on their surfaces by gmsh
    (OpenCASCADE reads the file; curves get at least :data:`STEP_SEGMENTS` segments a full
    circle and the mesh no element larger than a fifth of the part). The triangles are turned
    to face out of each solid (trimesh's ``fix_normals``). gmsh is the ``fem`` extra's.

    ``cad``: also the CAD face each triangle lies on and each face's kind ("Plane",
    "Cylinder", ...: gmsh's ``getType``), for :func:`rackstress.scenes.features.part_features`.
    """
    try:
        import gmsh
    except ImportError as exc:
        raise SceneError(f"mesh file {file}: a STEP part is read by gmsh's OpenCASCADE reader, "
                         f"which needs the 'fem' extra: pip install 'rackstress[fem]' ({exc})"
                         ) from None
    import trimesh

    if gmsh.isInitialized():
        gmsh.finalize()
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
        try:
            with _quiet():                  # OpenCASCADE's own parse messages: said below
                gmsh.model.occ.importShapes(file)
            gmsh.model.occ.synchronize()
        except Exception as exc:  # noqa: BLE001 - gmsh raises Exception for a bad file
            raise SceneError(f"mesh file {file}: gmsh's OpenCASCADE reader cannot read it as "
                             f"STEP ({str(exc).strip() or 'no shape'}); export the part from "
                             "CAD again as STEP AP203/AP214, or as STL") from None
        if not gmsh.model.getEntities(3):
            raise SceneError(f"mesh file {file}: holds no solid (only "
                             f"{len(gmsh.model.getEntities(2))} surface(s)); a part is filled "
                             "from its inside: export the solid body")
        lo = np.array(gmsh.model.getBoundingBox(-1, -1)[:3])
        hi = np.array(gmsh.model.getBoundingBox(-1, -1)[3:])
        size = float(np.linalg.norm(hi - lo))
        gmsh.option.setNumber("Mesh.MeshSizeMax", size / 5.0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", STEP_SEGMENTS)
        gmsh.option.setNumber("Mesh.MeshSizeMin", STEP_CHORD * size)
        gmsh.model.mesh.generate(2)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        where = np.zeros(int(tags.max()) + 1, dtype=np.int64)
        where[tags.astype(np.int64)] = np.arange(len(tags))
        tris, owner, kinds = [], [], {}
        for dim, tag in gmsh.model.getEntities(2):
            kinds[int(tag)] = gmsh.model.getType(dim, tag)
            types, _, nodes = gmsh.model.mesh.getElements(dim, tag)
            for t, nd in zip(types, nodes):
                if t == 2:                                        # 3-node triangles
                    tris.append(where[np.asarray(nd, dtype=np.int64).reshape(-1, 3)])
                    owner.append(np.full(len(tris[-1]), int(tag)))
    finally:
        gmsh.finalize()
    if not tris:
        raise SceneError(f"mesh file {file}: gmsh made no surface triangles of its solids")
    # merged vertices, every triangle kept in order (each keeps its CAD face)
    tm = trimesh.Trimesh(np.asarray(coords, float).reshape(-1, 3), np.concatenate(tris),
                         process=False)
    tm.merge_vertices()
    tm.fix_normals(multibody=True)
    out = (np.asarray(tm.vertices), np.asarray(tm.faces, dtype=np.int64))
    return out + (np.concatenate(owner), kinds) if cad else out


#: ``bodies = "united"`` grows each body by this fraction about its box's centre before the
#: union: bodies that touch face to face then overlap and fuse (manifold3d keeps exactly
#: touching faces apart, as two solids), and gaps of a few micrometres between faces meant to
#: touch close (at 1e-4 the SO-ARM base kept such a pair, which the winding test of
#: :func:`self_intersections` could not tell apart from an overlap). 0.05 mm on a 100 mm body,
#: a few per cent of any spacing such a part gets; its volume grows 0.3 %
UNITE_GROW = 1e-3


def united_triangles(vertices: np.ndarray, faces: np.ndarray, file: str) -> tuple:
    """(vertices, triangles) of the union of the bodies (connected shells) of a surface: what
    ``bodies = "united"`` fills, and ``rackstress inspect`` names, for a file of several
    bodies that overlap or touch (a CAD export of a multi-body part; a slicer unites them the
    same way). Each body must be a closed, consistently oriented shell; the union is
    manifold3d's exact boolean (:data:`UNITE_GROW`), its zero-volume slivers dropped.

    Raises
    ------
    SceneError
        naming the body (its triangles and box) that is not a closed solid.
    """
    import trimesh
    from manifold3d import Error, Manifold, Mesh64, OpType

    tm = trimesh.Trimesh(vertices, faces, process=True)
    bodies = tm.split(only_watertight=False, repair=False)
    if len(bodies) < 2:
        return vertices, faces
    solids = []
    for i, b in enumerate(bodies, 1):
        lo, hi = b.bounds
        where = (f"mesh file {file}: body {i} of {len(bodies)} ({len(b.faces)} triangles, box "
                 f"{np.round(lo, 6).tolist()} … {np.round(hi, 6).tolist()})")
        _, counts = np.unique(b.edges_sorted, axis=0, return_counts=True)
        if np.any(counts != 2) or not b.is_winding_consistent:
            raise SceneError(f"{where} is not a closed, consistently oriented shell, so it "
                             "cannot be united with the others (bodies = \"united\" unites "
                             "closed bodies): close it in the CAD tool, or leave it out")
        V = np.asarray(b.vertices, float)
        F = np.asarray(b.faces, np.int64)
        if b.volume < 0:
            F = F[:, ::-1]
        c = 0.5 * (lo + hi)
        m = Manifold(Mesh64(np.ascontiguousarray(c + (V - c) * (1.0 + UNITE_GROW)),
                            np.ascontiguousarray(F, np.uint64)))
        if m.status() != Error.NoError or m.is_empty():
            raise SceneError(f"{where} is not a solid manifold3d can unite ({m.status().name})"
                             "; repair it in the CAD tool")
        solids.append(m)
    mesh = Manifold.batch_boolean(solids, OpType.Add).to_mesh64()
    u = trimesh.Trimesh(np.asarray(mesh.vert_properties, float)[:, :3],
                        np.asarray(mesh.tri_verts, np.int64), process=True)
    pieces = u.split(only_watertight=False, repair=False)
    with np.errstate(invalid="ignore", divide="ignore"):      # a sliver's centre of mass
        vols = [abs(float(x.volume)) for x in pieces]
    keep = [x for x, v in zip(pieces, vols) if v > 1e-9 * sum(vols)]
    out = keep[0] if len(keep) == 1 else trimesh.util.concatenate(keep)
    return np.asarray(out.vertices, float), np.asarray(out.faces, np.int64)


@lru_cache(maxsize=32)
def _checked(file: str, mtime_ns: int, united: bool = False):
    """(vertices, triangles, signed volume) of a checked mesh file (cached per file version);
    ``united``: of the union of its bodies (:func:`united_triangles`)."""
    import trimesh

    vertices, faces = read_triangles(file)
    if not np.all(np.isfinite(vertices)):
        raise SceneError(f"mesh file {file}: has non-finite vertex coordinates")
    if united:
        vertices, faces = united_triangles(vertices, faces, file)
    tm = trimesh.Trimesh(vertices=vertices, faces=faces, process=True)
    edges, counts = np.unique(tm.edges_sorted, axis=0, return_counts=True)
    if np.any(counts == 1):
        e = edges[counts == 1]
        raise SceneError(
            f"mesh file {file}: the surface is not closed ({len(e)} boundary edge(s), e.g. at "
            f"{np.round(tm.vertices[e[0][0]], 6).tolist()}); a part is filled from its inside, "
            "so its mesh must be watertight: close the holes in the CAD tool (or export the "
            "solid, not a surface)")
    if np.any(counts > 2):
        e = edges[counts > 2]
        raise SceneError(
            f"mesh file {file}: the surface touches or intersects itself ({len(e)} edge(s) "
            f"shared by more than two triangles, e.g. at "
            f"{np.round(tm.vertices[e[0][0]], 6).tolist()}); its inside is not defined. "
            + _bodies_advice(tm, file))
    if not tm.is_winding_consistent:
        raise SceneError(f"mesh file {file}: the triangles are not consistently oriented "
                         "(some normals point inwards); re-export the solid from the CAD tool")
    where = self_intersections(tm)
    if len(where):
        raise SceneError(
            f"mesh file {file}: the surface overlaps or intersects itself (e.g. at "
            f"{np.round(where[0], 6).tolist()} a ray is inside it twice); its inside is not "
            "defined. " + _bodies_advice(tm, file))
    volume = float(tm.volume)
    if not abs(volume) > 0:
        raise SceneError(f"mesh file {file}: encloses no volume")
    return tm.vertices.copy(), tm.faces.copy(), volume


def _bodies_advice(tm, file: str) -> str:
    """What to do with a surface whose inside is not defined: for a file of several bodies
    (connected shells, trimesh's ``split``), each body named by its triangles, volume and box
    in the file's units, and how to write them as files of their own for a group's ``parts``
    (united, overlaps filled once); else: union the bodies in the CAD tool."""
    bodies = tm.split(only_watertight=False, repair=False)
    if len(bodies) < 2:
        return ("Union the bodies in the CAD tool before exporting, or give each body as its "
                "own part (a group's parts are united)")
    stem = Path(file).stem
    first = ('Give bodies = "united" beside mesh to fill their union as one part (each body '
             "closed; bodies that overlap or touch are fused, as a slicer does; rackstress "
             f"inspect {Path(file).name} --bodies united names its holes and faces). ")
    listed = "; ".join(
        f"body {i}: {len(b.faces)} triangles, volume {abs(b.volume):.4g}, box "
        f"{np.round(b.bounds[0], 4).tolist()} … {np.round(b.bounds[1], 4).tolist()}"
        + ("" if b.is_watertight else " (not closed)")
        for i, b in enumerate(bodies, 1))
    names = ", ".join(f'{{ mesh = "{stem}-{i}.stl" }}' for i in range(1, len(bodies) + 1))
    return (f"It holds {len(bodies)} bodies ({listed}). " + first + "Or union them in the "
            "CAD tool before exporting, or write each to a file of its own (python -c \"import trimesh; "
            f"[b.export(f'{stem}-{{i}}.stl') for i, b in enumerate(trimesh.load("
            f"'{Path(file).name}').split(only_watertight=False), 1)]\") and fill the group "
            f"from them: parts = [{names}] (a group's parts are united: overlaps are filled "
            "once; the scale, rotate and translate go into each)")


def self_intersections(tm, rays_per_axis: int = 24, seed: int = 0) -> np.ndarray:
    """Points on rays where the surface ``tm`` (a trimesh) overlaps or crosses itself.

    The winding number of a closed, consistently oriented surface that does not intersect
    itself is 1 inside and 0 outside. Along a ray, each crossing of the surface changes it by
    ±1 (entering or leaving, from the triangle's normal): the running sum must stay 0 or 1. Two
    overlapping shells, or a surface folded through itself, make it 2 or −1 along every ray
    through the overlap. ``rays_per_axis``² rays along each axis at seeded random places in the
    bounding box test it (trimesh's ray–triangle queries); touching triangles of a valid mesh
    (T-junctions, slivers) change nothing. Returns the points where the sum left {0, 1}.
    """
    rng = np.random.default_rng(seed)
    lo, hi = tm.bounds
    ext = hi - lo
    sign = 1.0 if tm.volume > 0 else -1.0       # normals outwards (+) or all inwards (−)
    normals = tm.face_normals
    bad = []
    for axis in range(3):
        d = np.zeros(3)
        d[axis] = 1.0
        m = rays_per_axis ** 2
        origins = lo + rng.uniform(0.0, 1.0, (m, 3)) * ext
        origins[:, axis] = lo[axis] - 0.01 * ext[axis] - 1e-9
        dirs = np.tile(d, (m, 1))
        loc, iray, itri = tm.ray.intersects_location(origins, dirs, multiple_hits=True)
        if not len(iray):
            continue
        t = (loc - origins[iray]) @ d
        step = -sign * np.sign(normals[itri] @ d)        # +1 entering, −1 leaving
        order = np.lexsort((t, iray))
        iray, t, step, loc = iray[order], t[order], step[order], loc[order]
        # one crossing hit on a shared edge or vertex is reported once per triangle: merge
        keep = np.ones(len(t), dtype=bool)
        same = (iray[1:] == iray[:-1]) & (np.abs(t[1:] - t[:-1]) <= 1e-9 * max(ext.max(), 1.0)) \
            & (step[1:] == step[:-1])
        keep[1:] = ~same
        iray, step, loc = iray[keep], step[keep], loc[keep]
        starts = np.flatnonzero(np.r_[True, iray[1:] != iray[:-1]])
        run = np.cumsum(step)
        base = np.repeat(np.r_[0.0, run[starts[1:] - 1]], np.diff(np.r_[starts, len(step)]))
        wind = run - base
        out = (wind > 1.5) | (wind < -0.5)
        bad.append(loc[out])
    return np.concatenate(bad) if bad else np.zeros((0, 3))
