"""Linear-elastic FEA of a run's own part: the same shape, supports and loads, on tetrahedra.

``rackstress fea RUNDIR`` (:func:`check_run`) answers "is the particle picture right on *my*
part?" with an independent solution of the same problem:

* **shape** — a mesh part (its STL, placed as in the scene) is meshed into tetrahedra by gmsh
  (the surface reparametrized and remeshed at the FE size, then the volume); a part filled
  from boxes, spheres, … (or a mesh gmsh refuses) is the union of its particles' lattice cells,
  each cube cut into 6 tetrahedra (Freudenthal: conforming across faces);
* **material** — E, ν of the part's material (``summary.json``), else given;
* **supports** — every FE node inside (the closed cell of) a held particle is fixed in that
  particle's fixed directions (``held_mask``: rollers and symmetry planes fix some);
* **loads** — each loaded particle's force is spread over the FE nodes in its cell with weights
  w_k (Σ w_k = 1, Σ w_k x_k = x_p: the least-norm correction of equal weights), so the total
  force and its moment about any point are the particles' exactly; a cell holding too few nodes
  gives its force to the vertices of the tetrahedron holding the particle (barycentric: the same
  two sums);
* **solution** — quadratic tetrahedra (P2, scikit-fem), one sparse direct solve; the strain is
  the L2 projection of the displacement gradient onto continuous P2, σ = λ tr ε I + 2μ ε, and
  σ_vm = √(3 J₂(σ)).

Agreement (:func:`agreement`): Spearman ρ and top-5 % overlap of the particle measure against
FEA's σ_vm at the particles' original positions (:func:`rackstress.validity.compare.agreement`),
and the peak ratio *away from singular points*: particles within one wall thickness t of a
re-entrant (concave) edge of the FE boundary, of a held or of a loaded particle are left out of
the peaks. σ is unbounded at a sharp re-entrant edge and under a concentrated load or support
in the continuum, so a peak there measures the mesh, not the part; by Saint-Venant's principle
such a local disturbance has decayed about one thickness of the member away, where both
models converge. t is the part's own (:func:`wall_thickness`: the median over the particles of
the shortest chord through the part along x, y or z), so the same points are compared at every
spacing. A ``strain`` measure
(von Mises shear strain η) is turned into stress by σ_vm = 2√3·G·η (exact for isotropic linear
elasticity: both are √J₂ of the deviator), G = E / 2(1 + ν).

Example
-------
>>> import numpy as np
>>> from rackstress.validity.solid import cell_mesh, solve
>>> o = np.array([[x, 0.0, 0.0] for x in range(4)])          # a 4 × 1 × 1 bar of cells
>>> p, t = cell_mesh(o, 1.0)
>>> sol = solve(p, t, E=1.0, nu=0.0, fixed=p[:, 0] < -0.49, forces=None)   # doctest: +SKIP
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: Singular points: particles nearer than this many of the part's wall thickness
#: (:func:`wall_thickness`) to a re-entrant edge, a support or a load are left out of the peak
#: ratio — Saint-Venant's distance, a length of the part's own, the same at every spacing.
SINGULAR_WALLS = 1.0
#: An FE boundary edge is re-entrant when its dihedral angle is concave by more than this.
CONCAVE_DEG = 20.0
#: Targets of issue 22 (3D part against tetrahedral FEA).
TARGET = {"spearman": 0.8, "top5_overlap": 0.5, "peak_ratio_error": 0.15}
#: FE size in spacings (gmsh's largest element edge; cells are cut at the spacing).
SIZE_SPACINGS = 1.0
#: FE systems up to this many unknowns are solved directly (SuperLU), larger by AMG-CG
DIRECT_DOFS = 20_000
#: relative residual of the FE conjugate-gradient solve
CG_RTOL = 1e-10


# --------------------------------------------------------------------------- meshes
def cell_mesh(o: np.ndarray, spacing: float):
    """Tetrahedra of the union of the lattice cells (cubes of side ``spacing``) centred on
    ``o``: (p 3×N, t 4×M). Each cube is cut into the 6 tetrahedra around its main diagonal
    (Freudenthal), the same way in every cube, so faces match."""
    o = np.asarray(o, float).reshape(-1, 3)
    s = float(spacing)
    lo = o.min(axis=0) - s / 2
    ijk = np.rint((o - o.min(axis=0)) / s).astype(np.int64)
    dims = ijk.max(axis=0) + 2                     # corner grid
    c = {d: (ijk[:, 0] + d[0]) + dims[0] * ((ijk[:, 1] + d[1]) + dims[1] * (ijk[:, 2] + d[2]))
         for d in [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]}
    tets = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        path = [(0, 0, 0)]
        for ax in perm:
            nxt = list(path[-1])
            nxt[ax] = 1
            path.append(tuple(nxt))
        tets.append(np.stack([c[v] for v in path]))
    t = np.concatenate(tets, axis=1)
    used, t = np.unique(t, return_inverse=True)
    t = t.reshape(4, -1)
    i = used % dims[0]
    j = (used // dims[0]) % dims[1]
    k = used // (dims[0] * dims[1])
    p = (lo[:, None] + s * np.stack([i, j, k]).astype(float))
    # orient every tetrahedron positively
    a, b, cc, d = (p[:, t[r]] for r in range(4))
    vol = np.einsum("ij,ij->j", np.cross(b - a, cc - a, axis=0), d - a)
    swap = vol < 0
    t[1, swap], t[2, swap] = t[2, swap].copy(), t[1, swap].copy()
    return p, t


def drop_slivers(vertices: np.ndarray, faces: np.ndarray, rel: float = 1e-9) -> np.ndarray:
    """The triangles without the zero-area ones (three collinear vertices, as CSG leaves where
    a hole meets a face), the surface kept closed and conforming: the neighbour across a
    sliver's long edge is split at the sliver's middle vertex. gmsh cannot parametrize a patch
    holding a sliver."""
    v = np.asarray(vertices, float)
    f = [list(map(int, t)) for t in np.asarray(faces)]
    tiny = rel * float(np.ptp(v, axis=0).max()) ** 2
    k = 0
    while k < len(f):
        a, b, c = f[k]
        if np.linalg.norm(np.cross(v[b] - v[a], v[c] - v[a])) > tiny:
            k += 1
            continue
        tri = f[k]
        lens = [np.linalg.norm(v[tri[(i + 1) % 3]] - v[tri[(i + 2) % 3]]) for i in range(3)]
        i = int(np.argmax(lens))
        m, p, q = tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]
        for j, t in enumerate(f):              # the triangle with the edge q → p
            r = next((r for r in range(3) if t[r] == q and t[(r + 1) % 3] == p), None)
            if j != k and r is not None:
                d = t[(r + 2) % 3]
                f[j] = [q, m, d]
                f.append([m, p, d])
                break
        else:
            k += 1                             # no neighbour: leave it to gmsh
            continue
        del f[k]
        k = 0
    return np.asarray(f, dtype=np.int64)


def surface_mesh(vertices: np.ndarray, faces: np.ndarray, size: float):
    """Tetrahedra of the closed surface (vertices, triangles) by gmsh, largest edge ``size``:
    (p 3×N, t 4×M). Slivers are removed (:func:`drop_slivers`), the surface is classified into
    patches (40° feature angle), each reparametrized and remeshed, then the volume meshed
    (gmsh runs headless, quietly)."""
    import gmsh

    faces = drop_slivers(vertices, faces)

    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("part")
        s = gmsh.model.addDiscreteEntity(2)
        v = np.asarray(vertices, float)
        f = np.asarray(faces, np.int64)
        gmsh.model.mesh.addNodes(2, s, np.arange(1, len(v) + 1), v.ravel())
        gmsh.model.mesh.addElementsByType(s, 2, [], (f + 1).ravel())
        gmsh.model.mesh.classifySurfaces(math.radians(40.0), True, True, math.pi)
        gmsh.model.mesh.createGeometry()
        loop = gmsh.model.geo.addSurfaceLoop([e[1] for e in gmsh.model.getEntities(2)])
        gmsh.model.geo.addVolume([loop])
        gmsh.model.geo.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", float(size))
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        etypes, _, enodes = gmsh.model.mesh.getElements(3)
    finally:
        gmsh.finalize()
    tet = [n for ty, n in zip(etypes, enodes) if ty == 4]
    if not tet:
        raise RuntimeError("gmsh made no tetrahedra")
    index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    t = index[np.asarray(tet[0], np.int64).reshape(-1, 4)].T
    used, t = np.unique(t, return_inverse=True)
    return (np.ascontiguousarray(coords.reshape(-1, 3)[used].T),
            np.ascontiguousarray(t.reshape(4, -1)))


# --------------------------------------------------------------------------- solution
@dataclass
class Solution:
    """A solved part: mesh, P2 basis, displacement, projected strain; :meth:`at` evaluates."""

    mesh: object
    basis: object
    u: np.ndarray
    E: float
    nu: float
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        from skfem import ElementTetP2

        self._sb = self.basis.with_element(ElementTetP2())
        g = self.basis.interpolate(self.u).grad
        self._eps = _project(self._sb, [0.5 * (g[i][j] + g[j][i]) for i, j in
                                        ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))])

    def _inside(self, x: np.ndarray) -> np.ndarray:
        """Points the element search misses (on the boundary) moved a little towards the
        nearest element's centroid (:func:`rackstress.validity.fea.move_inside`, up to the
        centroid itself)."""
        from rackstress.validity.fea import move_inside

        return move_inside(self.mesh, x, fracs=(1e-9, 1e-6, 1e-3, 1e-2, 0.1, 0.5, 1.0))

    def at(self, points) -> dict:
        """``displacement`` (n×3), ``stress`` (n×6: xx yy zz xy xz yz) and ``von_mises`` (n) at
        ``points`` (n×3)."""
        from rackstress.validity.fea import _probes

        x = self._inside(np.asarray(points, float).reshape(-1, 3))
        P = _probes(self._sb, x)
        e = np.stack([P @ c for c in self._eps], axis=1)
        u = (_probes(self.basis, x) @ self.u).reshape(3, -1).T
        lam = self.E * self.nu / ((1 + self.nu) * (1 - 2 * self.nu))
        mu = self.E / (2 * (1 + self.nu))
        tr = e[:, :3].sum(axis=1)
        s = 2 * mu * e
        s[:, :3] += lam * tr[:, None]
        return {"displacement": u, "stress": s, "von_mises": von_mises(s)}


def _project(sb, fields) -> list:
    """L² projections of quadrature-point ``fields`` onto the scalar basis ``sb``: one mass
    matrix, conjugate gradients with its diagonal (a P2 mass matrix is well conditioned; a
    sparse factorization of it fills in and takes minutes on 10⁵ tetrahedra)."""
    import scipy.sparse.linalg as spla
    from skfem import BilinearForm, LinearForm, asm

    M = asm(BilinearForm(lambda u, v, w: u * v), sb).tocsr()
    D = spla.LinearOperator(M.shape, matvec=lambda x, d=1.0 / M.diagonal(): d * x)
    out = []
    for fld in fields:
        f = asm(LinearForm(lambda v, w: w["e"] * v), sb, e=fld)
        scale = max(float(np.abs(f).max()), 1e-300)
        x, info = spla.cg(M, f / scale, rtol=1e-12, atol=0.0, maxiter=2000, M=D)
        if info != 0:
            raise RuntimeError(f"the stress projection did not converge ({info})")
        out.append(x * scale)
    return out


def von_mises(s: np.ndarray) -> np.ndarray:
    """σ_vm = √(½[(σxx−σyy)² + (σyy−σzz)² + (σzz−σxx)²] + 3(σxy² + σxz² + σyz²))."""
    xx, yy, zz, xy, xz, yz = s.T
    return np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2)
                   + 3 * (xy ** 2 + xz ** 2 + yz ** 2))


def solve(p, t, E: float, nu: float, fixed, forces) -> Solution:
    """Linear elasticity on the tetrahedra (p, t) with P2 elements.

    ``fixed``: N×3 bool over the mesh vertices (a direction fixed), or N bool (all three);
    ``forces``: N×3 nodal forces at the vertices (None: none).
    """
    from skfem import Basis, ElementTetP2, ElementVector, MeshTet, asm, condense, solve as lsolve
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    mesh = MeshTet(np.ascontiguousarray(p, float), np.ascontiguousarray(t, np.int64))
    basis = Basis(mesh, ElementVector(ElementTetP2()))
    K = asm(linear_elasticity(*lame_parameters(E, nu)), basis)
    nod = basis.nodal_dofs                     # 3 × N: the dofs of each vertex, per direction
    N = mesh.p.shape[1]
    fixed = np.asarray(fixed, bool)
    if fixed.ndim == 1:
        fixed = np.repeat(fixed[:, None], 3, axis=1)
    f = np.zeros(basis.N)
    if forces is not None:
        for d in range(3):
            f[nod[d]] += np.asarray(forces, float)[:N, d]
    D = np.concatenate([nod[d][fixed[:N, d]] for d in range(3)])
    if not len(D):
        raise ValueError("no FE node is fixed: the part is not supported")
    if basis.N <= DIRECT_DOFS:
        u = lsolve(*condense(K, f, D=D))
    else:
        u = _amg_solve(K, f, D, basis)
    return Solution(mesh, basis, u, float(E), float(nu),
                    {"vertices": int(N), "tetrahedra": int(mesh.t.shape[1]),
                     "dofs": int(basis.N)})


def _amg_solve(K, f, D, basis) -> np.ndarray:
    """K u = f with the dofs D fixed at 0, by conjugate gradients preconditioned with
    smoothed-aggregation AMG (pyamg) on the six rigid-body modes of the dofs' own positions:
    seconds where SuperLU's fill-in on P2 tetrahedra takes minutes; converged to
    :data:`CG_RTOL` of the load, far below the discretization error."""
    import pyamg
    import scipy.sparse.linalg as spla

    free = np.ones(basis.N, dtype=bool)
    free[D] = False
    x = np.asarray(basis.doflocs, float).T                  # N_dofs × 3
    comp = np.empty(basis.N, dtype=np.int64)
    for d, idx in enumerate(basis.split_indices()):
        comp[idx] = d
    c = x - x.mean(axis=0)
    B = np.zeros((basis.N, 6))
    B[np.arange(basis.N), comp] = 1.0
    for m, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):      # rotation about axis m
        B[comp == a, 3 + m] = -c[comp == a, b]
        B[comp == b, 3 + m] = c[comp == b, a]
    Kf = K[free][:, free].tocsr()
    ml = pyamg.smoothed_aggregation_solver(Kf, B=B[free], symmetry="symmetric",
                                           strength=("symmetric", {"theta": 0.0}),
                                           max_coarse=500, coarse_solver="splu")
    u = np.zeros(basis.N)
    u[free], info = spla.cg(Kf, f[free], rtol=CG_RTOL, maxiter=5000,
                            M=ml.aspreconditioner(cycle="V"))
    if info != 0:
        raise RuntimeError(f"the FE solve did not converge (conjugate gradients, {info} steps)")
    return u


# --------------------------------------------------------------------------- boundary
def nodal_forces(p: np.ndarray, t: np.ndarray, x: np.ndarray, F: np.ndarray,
                 spacing: float) -> np.ndarray:
    """N×3 vertex forces carrying the particle forces F at x with the same total force and
    moment (module docstring)."""
    from scipy.spatial import cKDTree

    from skfem import MeshTet

    P = p.T
    out = np.zeros_like(P)
    tree = cKDTree(P)
    h = 0.5 * spacing * (1 + 1e-9)
    mesh = None
    for xk, Fk in zip(np.asarray(x, float), np.asarray(F, float)):
        near = np.asarray(tree.query_ball_point(xk, h * math.sqrt(3)), dtype=np.int64)
        near = near[np.all(np.abs(P[near] - xk) <= h, axis=1)] if len(near) else near
        w = None
        if len(near) >= 4:
            A = np.vstack([np.ones(len(near)), P[near].T])          # 4 × m
            if np.linalg.matrix_rank(A) == 4:
                w0 = np.full(len(near), 1.0 / len(near))
                r = np.r_[1.0, xk] - A @ w0
                w = w0 + A.T @ np.linalg.solve(A @ A.T, r)
        if w is None:                                  # the tetrahedron holding it
            if mesh is None:
                mesh = MeshTet(p, t)
                find = mesh.element_finder()
            e = int(find(*xk[:, None])[0])
            near = t[:, e]
            V = np.vstack([np.ones(4), P[near].T])
            w = np.linalg.solve(V, np.r_[1.0, xk])
        out[near] += w[:, None] * Fk[None, :]
    return out


def fixed_nodes(p: np.ndarray, x: np.ndarray, mask: np.ndarray, spacing: float) -> np.ndarray:
    """N×3 bool: a vertex inside the closed cell of a held particle gets its fixed directions."""
    from scipy.spatial import cKDTree

    P = p.T
    out = np.zeros((len(P), 3), dtype=bool)
    if not len(x):
        return out
    h = 0.5 * spacing * (1 + 1e-6)
    tree = cKDTree(np.asarray(x, float))
    for k, cand in enumerate(tree.query_ball_point(P, h * math.sqrt(3))):
        for c in cand:
            if np.all(np.abs(P[k] - x[c]) <= h):
                out[k] |= mask[c]
    return out


def boundary_from_scene(scene) -> dict:
    """The arrays of ``boundary.npz`` (CONTRACT.md) derived from a scene: held particles (all
    three directions, or a group's ``fixed`` directions where it has them) and the ``force``
    operators' accelerations × the particles' mass (``Group.mass(scene.units)``)."""
    from rackstress.model.operators import Force

    held_ids, held_mask, load_ids, load_force = [], [], [], []
    units = getattr(scene, "units", None)
    for name, g in scene.groups.items():
        off = scene.offset(name)
        fixed = getattr(g, "fixed", None)
        if fixed is not None and np.ndim(fixed) == 2:
            fx = np.asarray(fixed, bool)
        else:
            fx = np.repeat((np.zeros(len(g.o), bool) if g.held is None
                            else np.asarray(g.held, bool))[:, None], 3, axis=1)
        k = np.flatnonzero(fx.any(axis=1))
        held_ids.append(off + k + 1)
        held_mask.append(fx[k])
        F = np.zeros((len(g.o), 3))
        m = g.mass(units) if hasattr(g, "mass") and units is not None else 1.0
        for op in scene.operators.get(name, []):
            if isinstance(op, Force):
                sel = np.ones(len(g.o), bool) if op.where is None else np.asarray(op.where, bool)
                F[sel] += np.asarray(op.accel, float) * np.broadcast_to(m, (len(g.o),))[sel, None]
        k = np.flatnonzero(np.any(F != 0, axis=1))
        load_ids.append(off + k + 1)
        load_force.append(F[k])
    return {"held_ids": np.concatenate(held_ids).astype(np.int64),
            "held_mask": np.concatenate(held_mask).reshape(-1, 3),
            "load_ids": np.concatenate(load_ids).astype(np.int64),
            "load_force": np.concatenate(load_force).reshape(-1, 3),
            "units": getattr(units, "name", "paper")}


# --------------------------------------------------------------------------- agreement
def concave_edges(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Midpoints (k×3) of the FE boundary's re-entrant edges (concave by > CONCAVE_DEG)."""
    import trimesh

    faces = np.sort(np.concatenate([t[[0, 1, 2]], t[[0, 1, 3]], t[[0, 2, 3]], t[[1, 2, 3]]],
                                   axis=1).T, axis=1)
    uniq, inv, cnt = np.unique(faces, axis=0, return_inverse=True, return_counts=True)
    # orient each boundary face outwards: away from its tetrahedron's fourth vertex
    bnd = np.flatnonzero(cnt[inv.reshape(-1)] == 1)
    tet = bnd % t.shape[1]
    tri = faces[bnd]
    other = np.array([np.setdiff1d(t[:, e], f)[0] for e, f in zip(tet, tri)])
    P = p.T
    n = np.cross(P[tri[:, 1]] - P[tri[:, 0]], P[tri[:, 2]] - P[tri[:, 0]])
    flip = np.einsum("ij,ij->i", n, P[other] - P[tri[:, 0]]) > 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    used, tri2 = np.unique(tri, return_inverse=True)
    tm = trimesh.Trimesh(P[used], tri2.reshape(-1, 3), process=False)
    adj = tm.face_adjacency
    concave = ~tm.face_adjacency_convex & (np.degrees(tm.face_adjacency_angles) > CONCAVE_DEG)
    e = tm.face_adjacency_edges[concave]
    return tm.vertices[e].mean(axis=1) if len(adj) else np.zeros((0, 3))


def wall_thickness(o: np.ndarray, spacing: float, shape=None) -> float:
    """The part's wall thickness: the median over its particles of the shortest chord through
    the part along x, y or z. A chord is a run of lattice neighbours, each cell counted with its
    share of the part along that axis (:func:`rackstress.model.solid.axis_fractions`, when the
    ``shape`` is known), so it is the part's own length, not a whole number of spacings.

    >>> o = np.array([[x, y, z] for x in range(20) for y in range(3) for z in range(8)], float)
    >>> wall_thickness(o, 1.0)                  # a 20 × 3 × 8 plate of cells: 3 thick
    3.0
    """
    a = float(spacing)
    o = np.asarray(o, float)
    g = np.rint((o - o.min(axis=0)) / a).astype(np.int64)
    if shape is not None:
        from rackstress.model.solid import axis_fractions

        phi = axis_fractions(o, a, shape)
    else:
        phi = np.ones((len(o), 3))
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
    return float(np.median(chord))


def agreement(values: np.ndarray, fea_vm: np.ndarray, points: np.ndarray, zone: float,
              singular: np.ndarray, to_stress: float | None = None) -> dict:
    """ρ, top-5 % overlap (:func:`rackstress.validity.compare.agreement`) and the peak ratio
    away from ``singular`` points (k×3), those within ``zone`` (a length: SINGULAR_WALLS ×
    :func:`wall_thickness`) left out: particle peak × ``to_stress`` / FEA peak."""
    from scipy.spatial import cKDTree

    from rackstress.validity.compare import agreement as ranks

    out = ranks(np.asarray(values, float), np.asarray(fea_vm, float), points)
    away = np.ones(len(points), dtype=bool)
    if len(singular):
        d, _ = cKDTree(singular).query(points)
        away = d > zone
    out["n_away"] = int(away.sum())
    out["zone"] = float(zone)
    if to_stress is not None and away.any():
        pv, fv = float(np.nanmax(values[away])) * to_stress, float(np.nanmax(fea_vm[away]))
        out.update(peak_particle=pv, peak_fea=fv, peak_ratio=pv / fv)
    else:
        out.update(peak_particle=None, peak_fea=None, peak_ratio=None)
    return out


def _json_default(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x))


def write_json(path: Path, data: dict) -> None:
    tmp = Path(path).with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_json_default))
    tmp.replace(path)


def solve_part(o, spacing, shape, held_x, held_mask, load_x, load_F, E, nu, size=None):
    """FEA of a part: its shape (a mesh :class:`~rackstress.model.regions.Surface` → gmsh; else
    the union of the cells of ``o``), nodes in held particles' cells fixed in ``held_mask``'s
    directions, the particle forces spread to the nodes. Returns (Solution, how it was meshed,
    a note or None, nodal forces, fixed nodes)."""
    from rackstress.model.regions import Surface

    how, note = "cells", None
    h = float(size) if size else SIZE_SPACINGS * spacing
    if isinstance(shape, Surface):
        try:
            pd = shape.polydata
            p, t = surface_mesh(np.asarray(pd.points), np.asarray(pd.regular_faces), h)
            how = f"gmsh tetrahedra of {Path(shape.name).name}"
        except Exception as exc:  # noqa: BLE001 - gmsh refused the surface: say so, use cells
            note = f"gmsh could not mesh {shape.name} ({exc}); the union of the cells is used"
    if how == "cells":
        p, t = cell_mesh(o, spacing)
        how = "the union of the particles' cells (6 tetrahedra a cube)"
    fixed = fixed_nodes(p, held_x, held_mask, spacing)
    forces = nodal_forces(p, t, load_x, load_F, spacing)
    return solve(p, t, E, nu, fixed, forces), how, note, forces, fixed


# --------------------------------------------------------------------------- a run directory
class _Recorded:
    """A run's parts from its own record (scene.json's groups, the original positions) when
    its scene cannot be rebuilt here (a scene file changed or gone): enough for the FEA of
    the particles' cells, with boundary.npz's supports and loads."""

    class _Group:
        def __init__(self, name, o):
            self.name, self.o, self.n, self.meta = name, o, len(o), {}

    def __init__(self, rundir: Path):
        from rackstress.stress.rundata import load_run

        rec = json.loads((rundir / "scene.json").read_text())
        o = np.asarray(load_run(rundir).o, float)
        self._slices = {g["name"]: slice(g["first_id"] - 1, g["first_id"] - 1 + g["n"])
                        for g in rec["groups"]}
        self.groups = {n: self._Group(n, o[sl]) for n, sl in self._slices.items()}
        self.operators = {}

    def slice(self, name: str) -> slice:
        return self._slices[name]


def _part_group(scene, summary: dict, boundary: dict, group: str | None) -> str:
    if group is not None:
        if group not in scene.groups:
            raise ValueError(f"no group '{group}' in the run (groups: {', '.join(scene.groups)})")
        return group
    mats = [n for n, g in (summary.get("groups") or {}).items() if isinstance(g, dict)
            and g.get("material")]
    if mats:
        return max(mats, key=lambda n: scene.groups[n].n)
    ids = np.concatenate([boundary["held_ids"], boundary["load_ids"]]) - 1
    best = None
    for name in scene.groups:
        sl = scene.slice(name)
        k = int(((ids >= sl.start) & (ids < sl.stop)).sum())
        if k and (best is None or scene.groups[name].n > scene.groups[best].n):
            best = name
    if best is None:
        raise ValueError("no group has supports or loads: nothing for the FEA to solve")
    return best


def _shape(scene, name: str):
    """The part's shape: the scene's solid (a filled region) or its bind-inside region."""
    from rackstress.model.operators import Bind, WithinInside

    g = scene.groups[name]
    shape = (g.meta.get("solid") or {}).get("shape") if isinstance(g.meta, dict) else None
    if shape is None:
        for op in scene.operators.get(name, []):
            if isinstance(op, Bind) and isinstance(op.coeff, WithinInside) and op.source == name:
                shape = op.coeff.region
    return shape


def _spacing(scene, name: str) -> float:
    from scipy.spatial import cKDTree

    g = scene.groups[name]
    s = (g.meta.get("solid") or {}).get("spacing") if isinstance(g.meta, dict) else None
    if s:
        return float(s)
    d, _ = cKDTree(g.o).query(g.o, k=2)
    return float(np.median(d[:, 1]))


def _boundary(rundir: Path, scene) -> tuple[dict, str]:
    path = rundir / "boundary.npz"
    if path.is_file():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}, "boundary.npz"
    return boundary_from_scene(scene), "the scene (no boundary.npz)"


def _particle_measure(rundir: Path, sl: slice, measure: str | None):
    """The measure at the last frame, from the post-processing's fields: ``measures.npz`` is
    only a cache (written on request), so the fields are computed when it is absent."""
    from rackstress.stress.post import compute_fields
    from rackstress.stress.rundata import load_run

    values = compute_fields(load_run(rundir), cache=True).values
    names = [m for m in ("von_mises", "strain") if m in values]
    if measure is None:
        if not names:
            raise ValueError(f"{rundir}: the run's measures have neither von_mises nor strain")
        measure = names[0]
    if measure not in values:
        raise ValueError(f"{rundir}: the run has no measure '{measure}'")
    return measure, np.asarray(values[measure][-1], float)[sl]


def _particle_displacement(rundir: Path, sl: slice):
    try:
        from rackstress.stress.rundata import load_run

        rd = load_run(rundir)
        rd.trajectory[-1]
        order = np.argsort(rd.universe.atoms.ids)
        return (np.asarray(rd.universe.atoms.positions, float)[order] - rd.o)[sl]
    except Exception:  # noqa: BLE001 - the displacement is shown when it can be read
        return None


def check_run(rundir, E: float | None = None, nu: float | None = None,
              size: float | None = None, group: str | None = None,
              measure: str | None = None, echo=print, keep: bool = False) -> dict:
    """Solve a run's part by FEA and compare it with the particle measure (module docstring).

    Writes ``fea.json`` (the agreement and how the FEA was set up), ``fea.npz``
    (``fea_von_mises``, ``fea_displacement`` per particle of the part, the particle measure),
    ``vtk/fea.vtp`` (the part's particles with both fields as point arrays), ``vtk/fea_mesh.vtu``
    (the FE mesh with ``von_mises`` and ``displacement``), ``figures/fea.png`` (both fields side
    by side) and the report's "Finite-element check" section.

    Example
    -------
    ``rackstress fea runs/bracket`` (docs/fea.md).
    """
    import time

    from rackstress.runs.resume import rebuild_scene

    t0 = time.perf_counter()
    rundir = Path(rundir)
    summary = json.loads((rundir / "summary.json").read_text())
    rebuilt = None
    try:
        scene = rebuild_scene(rundir)
    except Exception as exc:  # noqa: BLE001 - the run's own record still serves (cells)
        scene, rebuilt = _Recorded(rundir), f"the scene could not be rebuilt ({exc})"
        if not (rundir / "boundary.npz").is_file():
            raise ValueError(f"{rebuilt} and the run has no boundary.npz") from None
    bnd, bsource = _boundary(rundir, scene)
    if len(bnd.get("constrained_ids", ())):     # pinned, cylindrical, rollers off the axes
        raise ValueError(
            f"its supports hold {len(bnd['constrained_ids'])} particle(s) in directions that "
            "are not x, y or z (a pinned or cylindrical hole, a roller or symmetry plane at an "
            "angle); the FE check holds whole axes only: check a variant of the scene with "
            "those supports as type = \"fixed\"")
    name = _part_group(scene, summary, bnd, group)
    g, sl = scene.groups[name], scene.slice(name)
    spacing = _spacing(scene, name)
    mat = ((summary.get("groups") or {}).get(name) or {}).get("material") or {}
    E_ = float(E if E is not None else mat.get("E", 1.0))
    nu_ = float(nu if nu is not None else mat.get("nu", 0.3))
    shape = None if rebuilt else _shape(scene, name)
    hk = np.asarray(bnd["held_ids"], np.int64) - 1 - sl.start
    hin = (hk >= 0) & (hk < g.n)
    lk = np.asarray(bnd["load_ids"], np.int64) - 1 - sl.start
    lin = (lk >= 0) & (lk < g.n)
    if not lin.any():
        raise ValueError(f"part '{name}' carries no external load (boundary: {bsource}); a "
                         "load that reaches it by contact from another group is not modelled "
                         "by the FEA")
    echo(f"fea: {name}: meshing and solving …")
    sol, how, note, forces, fixed = solve_part(
        g.o, spacing, shape, g.o[hk[hin]], np.asarray(bnd["held_mask"], bool)[hin],
        g.o[lk[lin]], np.asarray(bnd["load_force"], float)[lin], E_, nu_, size)
    res = sol.at(g.o)
    mname, values = _particle_measure(rundir, sl, measure)
    G = E_ / (2 * (1 + nu_))
    to_stress = 1.0 if mname == "von_mises" else (2 * math.sqrt(3) * G if mat or E else None)
    singular = np.concatenate([concave_edges(sol.mesh.p, sol.mesh.t), g.o[hk[hin]],
                               g.o[lk[lin]]])
    zone = SINGULAR_WALLS * wall_thickness(g.o, spacing, shape)
    agree = agreement(values, res["von_mises"], g.o, zone, singular, to_stress)
    F_tot = np.asarray(bnd["load_force"], float)[lin].sum(axis=0)
    data = {
        "group": name, "particles": int(g.n), "spacing": spacing, "measure": mname,
        "to_stress": to_stress, "units": str(bnd.get("units", summary.get("units", "paper"))),
        "material": {"E": E_, "nu": nu_, "from": "summary.json" if mat else
                     ("options" if E is not None else "default (E = 1, ν = 0.3)")},
        "boundary": bsource, "mesh": how, "fe": sol.info,
        "note": "; ".join(x for x in (rebuilt and rebuilt + ": the part is the union of its "
                                      "particles' cells", note) if x) or None,
        "held_particles": int(hin.sum()), "fixed_fe_nodes": int(fixed.any(axis=1).sum()),
        "loaded_particles": int(lin.sum()), "total_force": F_tot,
        "fe_total_force": forces.sum(axis=0),
        "agreement": agree, "target": TARGET,
        "fea_peak_von_mises": float(res["von_mises"].max()),
        "fea_max_displacement": float(np.linalg.norm(res["displacement"], axis=1).max()),
    }
    data["wall_s"] = time.perf_counter() - t0
    disp = _particle_displacement(rundir, sl)
    _write_outputs(rundir, g.o, values, mname, res, disp, sol, data)
    if keep:          # for a benchmark's other stress routes: the same points and FEA field
        data.update(_o=g.o, _fea_vm=res["von_mises"], _singular=singular, _values=values,
                    _slice=sl, _zone=zone)
    return data


def _write_outputs(rundir: Path, o, values, mname, res, disp, sol, data) -> None:
    import pyvista as pv

    np.savez(rundir / "fea.npz", fea_von_mises=res["von_mises"],
             fea_displacement=res["displacement"], **{mname: values})
    (rundir / "vtk").mkdir(exist_ok=True)
    cloud = pv.PolyData(np.ascontiguousarray(o))
    cloud.point_data["fea_von_mises"] = res["von_mises"]
    cloud.point_data["fea_displacement"] = res["displacement"]
    cloud.point_data[mname] = values
    if disp is not None:
        cloud.point_data["displacement"] = disp
    cloud.save(rundir / "vtk" / "fea.vtp")
    m = sol.mesh
    grid = pv.UnstructuredGrid({pv.CellType.TETRA: m.t.T.copy()}, m.p.T.copy())
    nodal = sol.at(m.p.T)
    grid.point_data["von_mises"] = nodal["von_mises"]
    grid.point_data["displacement"] = nodal["displacement"]
    grid.save(rundir / "vtk" / "fea_mesh.vtu")
    (rundir / "figures").mkdir(exist_ok=True)
    picture(o, values, mname, res["von_mises"], rundir / "figures" / "fea.png", data)
    data["files"] = ["fea.json", "fea.npz", "vtk/fea.vtp", "vtk/fea_mesh.vtu", "figures/fea.png"]
    write_json(rundir / "fea.json", data)


def picture(o, values, mname, fea_vm, path: Path, data: dict) -> None:
    """The particle measure and FEA's von Mises side by side (each on its own scale, grey to
    red as the report's pictures; viewed along the part's thinnest axis)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axis = int(np.argmin(np.ptp(o, axis=0)))
    a, b = [k for k in range(3) if k != axis]
    order = np.argsort(o[:, axis])              # the near side drawn last
    fig, axes = plt.subplots(1, 2, figsize=(11, 5), constrained_layout=True)
    ag = data["agreement"]
    for ax, v, title in ((axes[0], values, f"particles: {mname}"),
                         (axes[1], fea_vm, "FEA: von Mises stress")):
        sc = ax.scatter(o[order, a], o[order, b], c=v[order], s=8, cmap="Reds",
                        vmin=0, vmax=np.nanpercentile(v, 99.5))
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("xyz"[a])
        ax.set_ylabel("xyz"[b])
        fig.colorbar(sc, ax=ax, shrink=0.8)
    fig.suptitle(f"{data['group']}: Spearman ρ = {ag['spearman']:.3f}, top-5 % overlap = "
                 f"{ag['top5_overlap']:.2f}" + ("" if ag.get("peak_ratio") is None else
                                                f", peak ratio {ag['peak_ratio']:.3f}"))
    fig.savefig(path, dpi=110)
    plt.close(fig)
