"""A converged FE reference for a run's part: P2 tetrahedra graded toward its singular edges.

The governing stress (:mod:`rackstress.stress.governing`) is read at least a zone away from the
part's sharp re-entrant edges; a uniform FE mesh fine enough there is wasteful everywhere else.
:func:`graded_mesh` meshes the part's own surface (a mesh part's STL, a CSG part's exact
manifold3d surface: :func:`rackstress.model.singular.surface_of`) with gmsh, the element size
growing from ``h_near`` at the re-entrant edges, the concave curved faces (fillets, holes) and
the loaded particles by ``grow`` per unit
distance up to ``h_far``;
:func:`reference` solves it with the run's material, supports (the FE nodes in held particles'
cells) and loads by (P2, AMG-preconditioned CG), each loaded particle's force as a body force over the
elements whose centroids lie in its cell (:func:`solve_body`: bounded, as the particles' load
is, where nodal point forces would make the FE's own singular points). :func:`governing_fe` is the FE's governing stress: the largest von
Mises stress over the FE nodes (the surface included) at least the zone from every singular
point — the continuum's value the particles' governing stress converges to.

Example
-------
>>> ref = reference("runs/cframe", h_far=1.0, h_near=0.2)          # doctest: +SKIP
>>> governing_fe(ref, zone=4.0)["value"]                           # doctest: +SKIP
99.0
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np


def graded_mesh(vertices, faces, points, h_far: float, h_near: float, grow: float = 0.5):
    """Tetrahedra (p 3×N, t 4×M) of the closed surface, sized min(h_far, h_near + grow·d)
    at a distance d from the nearest of ``points`` (k×3; none: h_far everywhere). Where gmsh's
    default surface algorithm leaves overlapping facets (the bracket at 0.75/0.15 mm), its
    MeshAdapt algorithm is tried, then a near size 1.5 × larger."""
    tries = ((h_near, None), (h_near, 1), (1.5 * h_near, 1))
    for k, (hn, algorithm) in enumerate(tries):
        try:
            return _graded_mesh(vertices, faces, points, h_far, hn, grow, algorithm)
        except Exception:  # noqa: BLE001 - gmsh says only "Exception"; the last try raises it
            if k == len(tries) - 1:
                raise
    raise AssertionError("unreachable")


def _graded_mesh(vertices, faces, points, h_far, h_near, grow, algorithm):
    import gmsh

    from rackstress.lib.tet import read_tetrahedra, size_field
    from rackstress.validity.solid import drop_slivers

    F = drop_slivers(vertices, faces)
    pts = np.asarray(points, float).reshape(-1, 3)
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("part")
        s = gmsh.model.addDiscreteEntity(2)
        V = np.asarray(vertices, float)
        gmsh.model.mesh.addNodes(2, s, np.arange(1, len(V) + 1), V.ravel())
        gmsh.model.mesh.addElementsByType(s, 2, [], (np.asarray(F) + 1).ravel())
        gmsh.model.mesh.classifySurfaces(math.radians(40.0), True, True, math.pi)
        gmsh.model.mesh.createGeometry()
        loop = gmsh.model.geo.addSurfaceLoop([e[1] for e in gmsh.model.getEntities(2)])
        gmsh.model.geo.addVolume([loop])
        # the size field: h_near + grow·d, capped at h_far
        if len(pts):
            size_field(gmsh, pts, h_near, h_far, 0.0, (h_far - h_near) / grow)
        else:
            gmsh.model.geo.synchronize()
            gmsh.option.setNumber("Mesh.MeshSizeMax", float(h_far))
        for opt in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints",
                    "Mesh.MeshSizeFromCurvature"):
            gmsh.option.setNumber(opt, 0)
        if algorithm is not None:
            gmsh.option.setNumber("Mesh.Algorithm", algorithm)
        gmsh.model.mesh.generate(3)
        X, t = read_tetrahedra(gmsh)
    finally:
        gmsh.finalize()
    used, t = np.unique(t, return_inverse=True)
    return (np.ascontiguousarray(X[used].T), np.ascontiguousarray(t.reshape(4, -1)))


def reference(rundir, h_far: float, h_near: float, grow: float = 0.5, group: str | None = None,
              singular=None, curved: bool = True) -> dict:
    """Solve a run's part on a graded P2 mesh (module docstring).

    Parameters
    ----------
    rundir : path
        A finished static run of a part with a material and a known shape (mesh or CSG).
    h_far, h_near, grow : float
        Element sizes (the part's length units) away from and at the re-entrant edges, and
        their growth per unit distance.
    singular : Singular, optional
        The points the mesh is graded toward and the governing stress is read away from
        (default: the run's own, ``singular.npz``).
    curved : bool
        Grade toward the concave curved faces too (fillets, holes); False: only toward the
        re-entrant edges and the loads (which leaves a free hole's concentration coarse).

    Returns
    -------
    dict
        ``solution`` (:class:`rackstress.validity.solid.Solution`), ``o`` (the part's particle
        positions), ``singular``, ``spacing``, ``group``, ``cpu_s``, ``fe`` (mesh sizes).
    """
    from rackstress.model import singular as S
    from rackstress.runs.resume import rebuild_scene
    from rackstress.stress.governing import read_singular
    from rackstress.validity.solid import fixed_nodes

    t0 = time.process_time()
    rundir = Path(rundir)
    sc = rebuild_scene(rundir)
    summary = json.loads((rundir / "summary.json").read_text())
    mats = [n for n, g in sc.groups.items() if g.material is not None]
    name = group or (mats[0] if mats else None)
    if name is None:
        raise ValueError(f"{rundir}: no part with a material")
    g = sc.groups[name]
    spacing, shape = S.part_geometry(sc, name)
    box = (g.o.min(axis=0) - 4 * spacing, g.o.max(axis=0) + 4 * spacing)
    surf = S.surface_of(shape, box)
    if surf is None:
        raise ValueError(f"{rundir}: part '{name}' has no surface to mesh (a lattice part)")
    V, F, _ = surf
    if singular is None:
        singular = read_singular(rundir)[name][2]
    with np.load(rundir / "boundary.npz") as z:
        bnd = {k: z[k] for k in z.files}
    sl = sc.slice(name)
    hk = bnd["held_ids"] - 1 - sl.start
    hin = (hk >= 0) & (hk < g.n)
    lk = bnd["load_ids"] - 1 - sl.start
    lin = (lk >= 0) & (lk < g.n)
    # graded toward the re-entrant edges (their stress varies fastest), the concave curved
    # faces (fillets, free holes: bounded concentrations, often the governing stress) and the
    # loaded particles (each one's force a body force over the elements of its cell: they must
    # resolve it)
    toward = np.concatenate([singular.points[singular.kind == 0],
                             S.concave_points(V, F, h_far) if curved else np.zeros((0, 3)),
                             g.o[lk[lin]]])
    p, t = graded_mesh(V, F, toward, h_far, h_near, grow)
    fx = fixed_nodes(p, g.o[hk[hin]], bnd["held_mask"][hin], spacing)
    mat = summary["groups"][name]["material"]
    sol = solve_body(p, t, mat["E"], mat["nu"], fx, g.o[lk[lin]], bnd["load_force"][lin],
                     spacing)
    return {"solution": sol, "o": np.asarray(g.o), "singular": singular, "spacing": spacing,
            "group": name, "cpu_s": time.process_time() - t0,
            "fe": {**sol.info, "h_far": h_far, "h_near": h_near, "grow": grow,
                   "E": mat["E"], "nu": mat["nu"]}}


def governing_fe(ref: dict, zone: float, singular=None) -> dict:
    """The FE's governing stress: the largest nodal von Mises stress at least ``zone`` from
    every singular point (``singular``: default the reference's), and where."""
    sol = ref["solution"]
    s = singular if singular is not None else ref["singular"]
    nodes = np.asarray(sol.mesh.p)                  # the vertices: the first P2 nodes
    if "_nodal_vm" not in ref:
        ref["_nodal_vm"] = sol.nodal()["von_mises"][:len(nodes)]
    vm = ref["_nodal_vm"]
    d, _ = s.distance(nodes)
    ok = d >= zone
    k = int(np.flatnonzero(ok)[np.argmax(vm[ok])])
    return {"value": float(vm[k]), "position": [float(x) for x in nodes[k]],
            "distance": float(d[k]), "zone": float(zone)}


def solve_body(p, t, E: float, nu: float, fixed, x, F, spacing: float):
    """Linear elasticity on the tetrahedra (p, t), P2 (:func:`rackstress.validity.solid.solve`),
    the vertices ``fixed`` (N×3 bool), each particle force F_k (at x_k) a uniform body force
    over the elements whose centroids lie in its cell (the cube of side ``spacing`` about x_k):
    Σ over those elements = F_k exactly. A uniform body force b on a P2 tetrahedron of volume V
    loads each vertex by −bV/20 and each edge node by bV/5 (∫N_i dV)."""
    from scipy.spatial import cKDTree

    from rackstress.validity.solid import solve
    from rackstress.lib.tet import Tet2

    mesh = Tet2(np.asarray(p, float).T, np.asarray(t, np.int64).T)
    cen = mesh.p[mesh.t].mean(axis=1)
    vol = mesh.vol
    dens = np.zeros((mesh.n_elements, 3))
    x = np.asarray(x, float).reshape(-1, 3)
    F = np.asarray(F, float).reshape(-1, 3)
    if len(x):
        dist, k = cKDTree(x).query(cen, p=np.inf)
        inside = dist <= 0.5 * spacing * (1 + 1e-9)
        cell_v = np.bincount(k[inside], weights=vol[inside], minlength=len(x))
        missing = np.flatnonzero(cell_v <= 0)
        if len(missing):          # a cell no centroid falls in: the element holding x_k
            e, _ = mesh.locate(x[missing])
            for j, ek in zip(missing, np.atleast_1d(e)):
                inside[ek], k[ek] = True, j
            cell_v = np.bincount(k[inside], weights=vol[inside], minlength=len(x))
        dens[inside] = F[k[inside]] / cell_v[k[inside], None]
    Fe = dens * vol[:, None]                                      # each element's force
    w = np.r_[np.full(4, -1.0 / 20.0), np.full(6, 1.0 / 5.0)]      # ∫N_i dV / V, P2 tet
    f = np.zeros((mesh.n_nodes, 3))
    for c in range(3):
        f[:, c] = np.bincount(mesh.nodes.ravel(), weights=(Fe[:, c, None] * w).ravel(),
                              minlength=mesh.n_nodes)
    N = len(mesh.p)
    fixed = np.asarray(fixed, bool)[:N]
    fx = np.zeros((mesh.n_nodes, 3), bool)
    fx[:N] = fixed
    fx[N:] = fixed[mesh.edges[:, 0]] & fixed[mesh.edges[:, 1]]
    if not fx.any():
        raise ValueError("no FE node is fixed: the part is not supported")
    sol = solve(np.asarray(p, float), np.asarray(t, np.int64), E, nu, fx, f)
    sol.info["loads"] = "body forces over the loaded cells"
    return sol
