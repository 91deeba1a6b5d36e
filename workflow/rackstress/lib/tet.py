"""Quadratic tetrahedra (P2) for linear elasticity: numbered, assembled, solved and evaluated a
bounded chunk of elements at a time.

What ``rackstress fea`` needs of a finite-element code is small — one isotropic material, one
element, point supports and point loads — and it must stay within a minute and two gigabytes
for a 20,000-particle part (docs/fea.md). scikit-fem's general forms build each element
matrix from 900 symbolic products and keep every basis function's values and gradients at
every quadrature point (for 86,534 tetrahedra: 376 s and gigabytes before the solve), so the
few formulas are written here, vectorized over elements:

* **numbering** — the 10 nodes of a P2 tetrahedron are its 4 vertices and the midpoints of its
  6 edges (01, 12, 02, 03, 13, 23, scikit-fem's order); each node carries u_x, u_y, u_z, so the
  stiffness matrix is a block-sparse matrix of 3 × 3 node blocks (scipy BSR), the layout
  smoothed-aggregation AMG aggregates by node;
* **shape functions** in barycentric coordinates λ: vertex i, λ_i(2λ_i − 1); edge (i, j),
  4λ_iλ_j; their gradients from ∇λ, constant on an affine tetrahedron;
* **stiffness** K_e = Σ_q w_q V (λ ∇·N_a ∇·N_b + μ(∇N_a·∇N_b I + ∇N_b ⊗ ∇N_a)), a 4-point
  rule of degree 2, exact for the product of two linear gradients;
* **mass** (the L² projection of the strain) with an 11-point rule of degree 4, exact;
* **supports** by symmetric elimination in place (rows and columns of the fixed components
  zeroed, the diagonal kept), so the block structure stays;
* **solution** — conjugate gradients preconditioned by a two-grid cycle in the degree: Gauss–
  Seidel on P2, smoothed-aggregation AMG (pyamg, on the six rigid-body modes) on the P1
  vertices (:func:`p_multigrid`);
* **evaluation** — a point is found in one of the tetrahedra with the nearest centroids
  (k-d tree; its barycentric coordinates ≥ −1e-9), and a point a faceted surface leaves just
  outside is taken at the nearest point of its best tetrahedron (λ clipped to [0, 1]).

Example
-------
>>> import numpy as np
>>> p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
>>> m = Tet2(p, np.array([[0, 1, 2, 3]]))
>>> m.n_nodes, m.X[4].tolist()                        # 4 vertices, 6 midpoints; edge 01
(10, [0.5, 0.0, 0.0])
>>> round(float(m.vol[0]), 6)
0.166667
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: local edges of a tetrahedron, in the order of its nodes 4 … 9
EDGES = ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))
#: elements assembled or evaluated at a time (bounds the work arrays: 30 × 30 doubles each)
CHUNK = 8192
#: conjugate-gradient tolerance of the elastic solve (relative residual), far below the
#: discretization error of the stress (a per cent at the spacing)
CG_RTOL = 1e-8
#: a point is inside a tetrahedron when its smallest barycentric coordinate is above this
INSIDE_TOL = -1e-9


def _quadrature(order: int):
    """(λ (q, 4), weights (q,) summing to 1) of scikit-fem's rule of ``order`` on the
    reference tetrahedron."""
    from skfem.quadrature import get_quadrature
    from skfem.refdom import RefTet

    X, W = get_quadrature(RefTet, order)
    lam = np.vstack([1.0 - X.sum(axis=0), X]).T
    return lam, W / W.sum()


def shape(lam: np.ndarray) -> np.ndarray:
    """P2 shape functions (…, 10) at barycentric coordinates ``lam`` (…, 4)."""
    out = np.empty(lam.shape[:-1] + (10,))
    out[..., :4] = lam * (2.0 * lam - 1.0)
    for k, (i, j) in enumerate(EDGES):
        out[..., 4 + k] = 4.0 * lam[..., i] * lam[..., j]
    return out


def shape_grad(lam: np.ndarray, gl: np.ndarray) -> np.ndarray:
    """Gradients (e, q, 10, 3) of the shape functions at ``lam`` (q, 4) or (e, q, 4), with
    ``gl`` = ∇λ of each element (e, 4, 3)."""
    lam = np.broadcast_to(lam, (len(gl),) + lam.shape[-2:])
    out = np.empty(lam.shape[:2] + (10, 3))
    out[:, :, :4] = (4.0 * lam - 1.0)[..., None] * gl[:, None, :, :]
    for k, (i, j) in enumerate(EDGES):
        out[:, :, 4 + k] = 4.0 * (lam[..., i, None] * gl[:, None, j]
                                  + lam[..., j, None] * gl[:, None, i])
    return out


def _scatter_numpy(data, pos, M, lam_, mu):
    """data[pos[e, 10a + b]] += K_ab of each element from M_aibj (numpy: nine bincounts)."""
    Kb = lam_ * M.transpose(0, 1, 3, 2, 4) + mu * M.transpose(0, 1, 3, 4, 2)
    dot = mu * np.einsum("eakbk->eab", M)
    for d in range(3):
        Kb[..., d, d] += dot
    P, Kb = pos.ravel(), Kb.reshape(-1, 9)
    for c in range(9):
        data[:, c] += np.bincount(P, weights=Kb[:, c], minlength=len(data))


def _scatter_compiled():
    """:func:`_scatter_numpy` compiled (numba): one pass, no work array the size of K (the
    bincounts took 4.7 of 7.2 s for 134,000 tetrahedra); None without numba."""
    from rackstress.lib.jit import numba_or_none

    nb = numba_or_none()
    if nb is None:
        return None

    @nb.njit(cache=True, nogil=True)
    def scatter(data, pos, M, lam_, mu):
        for e in range(M.shape[0]):
            for a in range(10):
                for b in range(10):
                    k = pos[e, 10 * a + b]
                    tr = M[e, a, 0, b, 0] + M[e, a, 1, b, 1] + M[e, a, 2, b, 2]
                    for i in range(3):
                        for j in range(3):
                            v = lam_ * M[e, a, i, b, j] + mu * M[e, a, j, b, i]
                            if i == j:
                                v += mu * tr
                            data[k, 3 * i + j] += v

    return scatter


def _scatter_elastic(data, pos, M, lam_, mu):
    """Add each element's elastic blocks K_ab,ij = λ M_aibj + μ M_ajbi + μ δ_ij Σ_k M_akbk
    (M_aibj = Σ_q w G_ai G_bj) at its block positions ``pos`` (e, 100) of ``data``."""
    global _SCATTER
    if _SCATTER is None:
        _SCATTER = _scatter_compiled() or _scatter_numpy
    _SCATTER(data, np.ascontiguousarray(pos), np.ascontiguousarray(M), float(lam_), float(mu))


#: the compiled scatter, built on first use
_SCATTER = None


class Tet2:
    """A tetrahedral mesh with its P2 nodes: ``X`` (n_nodes, 3), ``nodes`` (e, 10), ``vol``
    and ``gl`` (∇λ, e × 4 × 3) per element. ``p`` (N, 3) vertices, ``t`` (e, 4)."""

    def __init__(self, p, t):
        p = np.ascontiguousarray(p, float)
        t = np.array(t, dtype=np.int64).reshape(-1, 4)
        J = np.stack([p[t[:, k]] - p[t[:, 0]] for k in (1, 2, 3)], axis=2)   # columns
        det = np.linalg.det(J)
        neg = det < 0
        t[neg, 1], t[neg, 2] = t[neg, 2].copy(), t[neg, 1].copy()
        J[neg] = J[neg][:, :, [1, 0, 2]]
        det = np.abs(det)
        self.p, self.t = p, t
        self.vol = det / 6.0
        Jinv = np.linalg.inv(J)                       # rows: ∇λ_1, ∇λ_2, ∇λ_3
        self.gl = np.concatenate([-Jinv.sum(axis=1, keepdims=True), Jinv], axis=1)
        e = np.sort(np.concatenate([t[:, [i, j]] for i, j in EDGES]), axis=1)
        uniq, inv = np.unique(e, axis=0, return_inverse=True)
        self.edges = uniq
        nv = len(p)
        self.nodes = np.concatenate([t, nv + inv.reshape(len(EDGES), -1).T], axis=1)
        self.X = np.concatenate([p, 0.5 * (p[uniq[:, 0]] + p[uniq[:, 1]])])
        self.n_nodes = len(self.X)
        self._tree = None

    def release(self) -> None:
        """Forget the assembly's sparsity pattern (100 positions an element)."""
        self._pat = None

    @property
    def n_elements(self) -> int:
        return len(self.t)

    # ------------------------------------------------------------------ assembly
    def _pattern(self):
        """The node-block sparsity (indptr, indices) and, per element, the position of each
        of its 100 blocks in it (e, 100), built once."""
        if getattr(self, "_pat", None) is None:
            import scipy.sparse as sp

            n, e = self.n_nodes, self.n_elements
            # nodes sharing an element: the pattern of Eᵀ E, E the element–node incidence;
            # its entries count the shared elements, so not int8: a vertex of 256 tetrahedra
            # counted 0, which the product drops, and its blocks went to its neighbour's
            inc = sp.csr_matrix((np.ones(10 * e, np.int32),
                                 (np.repeat(np.arange(e), 10), self.nodes.ravel())),
                                shape=(e, n))
            pat = (inc.T.tocsr() @ inc).tocsr()
            pat.sort_indices()
            indptr, indices = pat.indptr.astype(np.int64), pat.indices
            keys = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr)) * n + indices
            rows = np.repeat(self.nodes, 10, axis=1)
            pos = np.searchsorted(keys, rows * n + np.tile(self.nodes, (1, 10)))
            self._pat = (indptr, indices.astype(np.int32), pos)
        return self._pat

    def stiffness(self, E: float, nu: float):
        """K (3n × 3n, scipy BSR of 3 × 3 node blocks) of isotropic linear elasticity."""
        import scipy.sparse as sp

        lam_, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
        indptr, indices, pos = self._pattern()
        lq, wq = _quadrature(2)
        data = np.zeros((len(indices), 9))
        for s in range(0, self.n_elements, CHUNK):
            sl = slice(s, s + CHUNK)
            G = shape_grad(lq, self.gl[sl])                      # e, q, 10, 3
            w = self.vol[sl, None] * wq[None, :]                 # e, q
            Gw = G * w[..., None, None]
            # K_ab,ij = Σ_q w (λ G_ai G_bj + μ G_aj G_bi + μ δ_ij G_a·G_b): all three from
            # the one product M_aibj = Σ_q w G_ai G_bj (a batched matrix product, BLAS)
            ne = len(G)
            M = (Gw.reshape(ne, -1, 30).transpose(0, 2, 1) @ G.reshape(ne, -1, 30))
            _scatter_elastic(data, pos[sl], M.reshape(ne, 10, 3, 10, 3), lam_, mu)
        n = self.n_nodes
        return sp.bsr_matrix((data.reshape(-1, 3, 3), indices, indptr), shape=(3 * n, 3 * n))

    def mass(self):
        """M (n × n, CSR) of the scalar P2 basis: ∫ N_a N_b (degree-4 rule, exact)."""
        import scipy.sparse as sp

        indptr, indices, pos = self._pattern()
        lq, wq = _quadrature(4)
        N = shape(lq)                                            # q, 10
        ref = np.einsum("q,qa,qb->ab", wq, N, N).ravel()         # per unit volume
        data = np.bincount(pos.ravel(), weights=(self.vol[:, None] * ref[None]).ravel(),
                           minlength=len(indices))
        return sp.csr_matrix((data, indices, indptr), shape=(self.n_nodes,) * 2)

    def strain_load(self, u: np.ndarray) -> np.ndarray:
        """b (n, 6): ∫ ε(u) N_a per node, ε in xx yy zz xy xz yz (tensor shears), for the L²
        projection M e = b of the strain onto continuous P2."""
        lq, wq = _quadrature(4)
        N = shape(lq)
        U = u.reshape(-1, 3)
        out = np.zeros((self.n_nodes, 6))
        for s in range(0, self.n_elements, CHUNK):
            sl = slice(s, s + CHUNK)
            G = shape_grad(lq, self.gl[sl])                      # e, q, 10, 3
            g = np.einsum("eqak,eai->eqik", G, U[self.nodes[sl]])   # ∂u_i/∂x_k
            eps = _sym6(g)                                       # e, q, 6
            b = np.einsum("q,qa,eqc->eac", wq, N, eps) * self.vol[sl, None, None]
            idx = self.nodes[sl].ravel()
            for c in range(6):
                out[:, c] += np.bincount(idx, weights=b[..., c].ravel(), minlength=self.n_nodes)
        return out

    # ------------------------------------------------------------------ evaluation
    def locate(self, x: np.ndarray, k: int = 12):
        """(element, λ) of each point (m, 3): the tetrahedron holding it among the ``k``
        nearest centroids, else (a point on or just outside the surface) the candidate it is
        least outside of, λ clipped to [0, 1] — its nearest point there."""
        from scipy.spatial import cKDTree

        x = np.asarray(x, float).reshape(-1, 3)
        if self._tree is None:
            self._tree = cKDTree(self.p[self.t].mean(axis=1))
        elem = np.zeros(len(x), dtype=np.int64)
        lam = np.zeros((len(x), 4))
        todo = np.arange(len(x))
        for kk in (min(k, self.n_elements), min(8 * k, self.n_elements)):
            if not len(todo):
                break
            _, cand = self._tree.query(x[todo], k=kk)
            cand = np.asarray(cand).reshape(len(todo), kk)
            L = self._bary(x[todo], cand)                         # m, k, 4
            score = L.min(axis=2)
            best = np.argmax(score, axis=1)
            r = np.arange(len(todo))
            elem[todo] = cand[r, best]
            lam[todo] = L[r, best]
            todo = todo[score[r, best] < INSIDE_TOL]
        lam = np.clip(lam, 0.0, 1.0)
        lam /= lam.sum(axis=1, keepdims=True)
        return elem, lam

    def _bary(self, x, cand):
        x0 = self.p[self.t[cand, 0]]                              # m, k, 3
        l123 = np.einsum("mkij,mkj->mki", self.gl[cand][:, :, 1:], x[:, None, :] - x0)
        return np.concatenate([1.0 - l123.sum(axis=2, keepdims=True), l123], axis=2)

    def interpolate(self, values: np.ndarray, elem: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """Nodal ``values`` (n, c) at located points: (m, c)."""
        return np.einsum("ma,mac->mc", shape(lam), values[self.nodes[elem]])


def refine(p: np.ndarray, t: np.ndarray):
    """Each tetrahedron cut into 8 (its corners' four and the inner octahedron's four, about
    the diagonal between the midpoints of edges 02 and 13): (p N'×3, t M'×4), conforming —
    the second, finer mesh of a part made of cells.

    >>> p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    >>> q, u = refine(p, np.array([[0, 1, 2, 3]]))
    >>> len(q), len(u), round(float(Tet2(q, u).vol.sum()), 6)
    (10, 8, 0.166667)
    """
    m = Tet2(p, t)
    n = m.nodes                                   # 0-3 corners, 4: 01, 5: 12, 6: 02, 7: 03,
    kids = [(0, 4, 6, 7), (1, 4, 5, 8), (2, 5, 6, 9), (3, 7, 8, 9),     # 8: 13, 9: 23
            (4, 6, 7, 8), (4, 5, 6, 8), (6, 7, 8, 9), (5, 6, 8, 9)]
    return m.X, np.concatenate([n[:, list(k)] for k in kids])


def bisect(p: np.ndarray, t: np.ndarray, marked: np.ndarray | None = None):
    """Each tetrahedron (or each of ``marked``, indices) bisected at its longest edge, and its
    neighbours as conformity needs (scikit-fem's ``MeshTet.refined`` of those elements:
    longest-edge bisection): (p N'×3, t M'×4). All of them: about 4.3 times as many
    tetrahedra (fTetWild's 9,298 of the SO-100 base: 39,964 in 0.2 s; none below quality
    0.04), edges about 1/1.6 as long — a finer mesh between the same one and :func:`refine`'s
    8 times as many.

    >>> p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    >>> q, u = bisect(p, np.array([[0, 1, 2, 3]]))
    >>> len(u) > 1, round(float(Tet2(q, u).vol.sum()), 6)
    (True, 0.166667)
    """
    from skfem import MeshTet

    m = MeshTet(np.ascontiguousarray(p.T, float), np.ascontiguousarray(t.T, np.int32))
    state = np.random.get_state()     # scikit-fem seeds numpy's global generator: put it back
    try:
        r = m.refined(np.arange(m.t.shape[1]) if marked is None
                      else np.asarray(marked, np.int32))
    finally:
        np.random.set_state(state)
    return np.asarray(r.p.T, float), np.asarray(r.t.T, np.int64)


def _sym6(g: np.ndarray) -> np.ndarray:
    """Symmetric parts of gradients g[..., i, k] as (…, 6): xx yy zz xy xz yz."""
    return np.stack([g[..., 0, 0], g[..., 1, 1], g[..., 2, 2],
                     0.5 * (g[..., 0, 1] + g[..., 1, 0]), 0.5 * (g[..., 0, 2] + g[..., 2, 0]),
                     0.5 * (g[..., 1, 2] + g[..., 2, 1])], axis=-1)


def rigid_modes(X: np.ndarray) -> np.ndarray:
    """The six rigid-body motions of the nodes ``X`` (n, 3) as (3n, 6), interleaved x y z."""
    n = len(X)
    c = X - X.mean(axis=0)
    B = np.zeros((n, 3, 6))
    for d in range(3):
        B[:, d, d] = 1.0
    for m, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):      # rotation about axis m
        B[:, a, 3 + m] = -c[:, b]
        B[:, b, 3 + m] = c[:, a]
    return B.reshape(3 * n, 6)


def eliminate(K, fixed: np.ndarray):
    """K with the rows and columns of the ``fixed`` components (n, 3 bool) zeroed and their
    diagonal kept (symmetric elimination of u = 0 in place; the BSR structure stays)."""
    n = K.shape[0] // 3
    rows = np.repeat(np.arange(n), np.diff(K.indptr))
    keep_r = ~fixed[rows]                                      # nnzb, 3
    keep_c = ~fixed[K.indices]
    diag = K.diagonal().copy()
    K.data *= keep_r[:, :, None] & keep_c[:, None, :]
    on = rows == K.indices
    for d in range(3):
        sel = on & fixed[rows, d]
        K.data[sel, d, d] = diag[3 * rows[sel] + d]
    return K


def p_multigrid(mesh, K, fixed: np.ndarray):
    """A preconditioner for the P2 stiffness ``K`` (supports eliminated): one V-cycle of
    a two-grid method in the polynomial degree — a Gauss–Seidel sweep on P2, the
    residual restricted to the P1 vertices (a midpoint's value is its edge's mean), smoothed-
    aggregation AMG (pyamg, on the six rigid-body modes) on the Galerkin P1 operator, and back.
    Aggregating the P1 graph rather than the P2 one halves the conjugate gradients' work
    (61 against 89 iterations, 5.1 against 10.7 s of CPU on the C-frame's 62k unknowns);
    energy-minimizing prolongators and a sparse LU on a coarsest level of up to 3000 unknowns
    (not a pseudo-inverse, whose SVD alone took 17 s) halve it again: README's bracket at FE
    size 2 (463k unknowns) in 22 against 58 iterations, 12 against 31 s of CPU. A forward
    sweep before and a backward one after (not a symmetric sweep on each side): 27 iterations,
    10.9 s."""
    import pyamg
    import scipy.sparse as sp
    from pyamg.multilevel import MultilevelSolver
    from pyamg.relaxation.smoothing import change_smoothers

    nv, n = len(mesh.p), mesh.n_nodes
    mid = np.arange(nv, n)
    Pn = sp.csr_matrix((np.r_[np.ones(nv), np.full(2 * len(mid), 0.5)],
                        (np.r_[np.arange(nv), mid, mid],
                         np.r_[np.arange(nv), mesh.edges[:, 0], mesh.edges[:, 1]])),
                       shape=(n, nv))
    free = (~fixed.ravel()).astype(float)
    P = (sp.diags(free) @ sp.kron(Pn, sp.identity(3), format="csr")).tocsr()
    Kc = K.tocsr()
    A1 = (P.T @ Kc @ P).tocsr()
    empty = A1.diagonal() == 0                       # fixed vertex components
    A1 = (A1 + sp.diags(empty.astype(float))).tobsr(blocksize=(3, 3))
    B1 = rigid_modes(mesh.p)
    B1[empty] = 0.0
    ml1 = pyamg.smoothed_aggregation_solver(A1, B=B1, symmetry="symmetric",
                                            strength=("symmetric", {"theta": 0.0}),
                                            smooth=("energy", {"krylov": "cg", "maxiter": 4}),
                                            max_coarse=3000)
    top = MultilevelSolver.Level()
    top.A, top.P, top.R = Kc, P, P.T.tocsr()
    ml = MultilevelSolver([top] + ml1.levels, coarse_solver="splu")
    # forward Gauss–Seidel before, backward after: the V-cycle stays symmetric (a valid
    # preconditioner for CG) with half the sweeps of symmetric ones on both sides
    change_smoothers(ml, presmoother=("gauss_seidel", {"sweep": "forward"}),
                     postsmoother=("gauss_seidel", {"sweep": "backward"}))
    return Kc, ml.aspreconditioner(cycle="V")


def solve_cg(mesh, K, f: np.ndarray, fixed: np.ndarray, rtol: float = CG_RTOL):
    """K u = f by conjugate gradients preconditioned by :func:`p_multigrid`; returns
    (u, iterations)."""
    import scipy.sparse.linalg as spla

    Kc, M = p_multigrid(mesh, K, fixed)
    it = [0]

    def count(_):
        it[0] += 1

    u, info = spla.cg(Kc, f, rtol=rtol, atol=0.0, maxiter=2000, M=M, callback=count)
    if info != 0:
        raise RuntimeError(f"the FE solve did not converge (conjugate gradients, {info} steps)")
    return u, it[0]


# --------------------------------------------------------------------------- a solid's mesh and solution
# (the FE check, rackstress.validity.solid, and the notch reading's submodel,
# rackstress.stress.notch)
def _faces_once(t: np.ndarray):
    """The four faces of each tetrahedron t (M×4), face k of the 4M opposite corner k // M
    of tetrahedron k % M, and which of them belong to that tetrahedron only (the boundary)."""
    faces = np.concatenate([t[:, [1, 2, 3]], t[:, [0, 3, 2]], t[:, [0, 1, 3]], t[:, [0, 2, 1]]])
    _, inv, cnt = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True,
                            return_counts=True)
    return faces, cnt[inv.ravel()] == 1


def tet_volumes(X: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Signed volume of each tetrahedron t (M×4) of the points X (N×3)."""
    P = X[t]
    return np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]),
                     P[:, 3] - P[:, 0]) / 6


#: a tetrahedron is a sliver when its quality (:func:`quality`) is below this
SLIVER_Q = 0.05
#: a mesh with more than this share of slivers is poor: its stress is no reference. The
#: corpus (examples/parts, docs/benchmarks/parts.md): the meshes gmsh remeshes 0.0 %, those
#: filled inside a file's own facets 18–61 %, among them the fixed jaw's (43 %), whose FE put
#: 893 MPa at a sliver under a 10 N load that the particles carry at 0.57 MPa
POOR_SLIVERS = 0.05


def quality(X: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Each tetrahedron's quality q = 6·√2·V / ℓ³ (ℓ the root mean square of its six edges;
    1 for a regular tetrahedron, 0 for a flat one) of t (M×4, or a :class:`Tet2`'s M×10
    whose first four are its corners) over the points X (N×3).

    >>> p = np.array([[0, 0, 0], [1, 0, 0], [0.5, 3 ** 0.5 / 2, 0],
    ...               [0.5, 3 ** 0.5 / 6, (2 / 3) ** 0.5]])
    >>> round(float(quality(p, np.array([[0, 1, 2, 3]]))[0]), 12)
    1.0
    """
    T = np.asarray(t)[:, :4]
    X = np.asarray(X, float)
    P = X[T]
    V = np.abs(tet_volumes(X, T))
    l2 = np.mean([((P[:, i] - P[:, j]) ** 2).sum(axis=1)
                  for i in range(4) for j in range(i + 1, 4)], axis=0)
    return 6 * np.sqrt(2) * V / l2 ** 1.5


def sliver_share(X: np.ndarray, t: np.ndarray) -> float:
    """The share of the tetrahedra t of X that are slivers (:func:`quality` below
    :data:`SLIVER_Q`)."""
    return float(np.mean(quality(X, t) < SLIVER_Q))


def read_tetrahedra(gmsh):
    """The linear tetrahedra gmsh's current model holds: (points N×3, t 4×M numbering them);
    RuntimeError where it made none."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    etypes, _, enodes = gmsh.model.mesh.getElements(3)
    tet = [n for ty, n in zip(etypes, enodes) if ty == 4]
    if not tet:
        raise RuntimeError("gmsh made no tetrahedra")
    index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    return coords.reshape(-1, 3), index[np.asarray(tet[0], np.int64).reshape(-1, 4)].T


def size_field(gmsh, points, size_min: float, size_max: float, dist_min: float,
               dist_max: float) -> None:
    """gmsh's background mesh size: its own Distance to ``points`` (added to the geometry,
    not meshed) and a Threshold from ``size_min`` within ``dist_min`` of them to
    ``size_max`` beyond ``dist_max``, linear between (a Python callback per size query took
    minutes)."""
    tags = [gmsh.model.geo.addPoint(*map(float, x)) for x in np.asarray(points)]
    gmsh.model.geo.synchronize()
    fd = gmsh.model.mesh.field.add("Distance")
    gmsh.model.mesh.field.setNumbers(fd, "PointsList", tags)
    ft = gmsh.model.mesh.field.add("Threshold")
    gmsh.model.mesh.field.setNumber(ft, "InField", fd)
    gmsh.model.mesh.field.setNumber(ft, "SizeMin", float(size_min))
    gmsh.model.mesh.field.setNumber(ft, "SizeMax", float(size_max))
    gmsh.model.mesh.field.setNumber(ft, "DistMin", float(dist_min))
    gmsh.model.mesh.field.setNumber(ft, "DistMax", float(dist_max))
    gmsh.model.mesh.field.setAsBackgroundMesh(ft)


def gmsh_volume(v, f, size, near, near_size, reparametrize: bool, netgen: bool = False,
                grade: float = 0.25):
    """gmsh's tetrahedra inside the closed triangulated surface (v, f) (the FE check's
    :func:`rackstress.validity.solid.surface_mesh`, the notch reading's submodel), largest edge
    ``size``, graded toward the points ``near`` (``grade`` × the distance, from ``near_size``);
    ``netgen``: then Netgen's optimizer on them (inside fTetWild's surface of the fixed jaw:
    47 of 71,091 tetrahedra slivers without, whose nodal stress put the FE's governing point
    at 2.17 MPa where the rest reads 0.12; none with, 4.7 s instead of 1.2 s; at 3.2 mm
    0–1 of about 10,300 over five runs, fTetWild not being deterministic)."""
    import gmsh

    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("part")
        s = gmsh.model.addDiscreteEntity(2)
        gmsh.model.mesh.addNodes(2, s, np.arange(1, len(v) + 1), v.ravel())
        gmsh.model.mesh.addElementsByType(s, 2, [], (f + 1).ravel())
        if reparametrize:
            gmsh.model.mesh.classifySurfaces(math.radians(40.0), True, True, math.pi)
            gmsh.model.mesh.createGeometry()
        else:
            gmsh.model.mesh.createTopology()
        loop = gmsh.model.geo.addSurfaceLoop([e[1] for e in gmsh.model.getEntities(2)])
        gmsh.model.geo.addVolume([loop])
        gmsh.model.geo.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", float(size))
        gmsh.option.setNumber("Mesh.OptimizeNetgen", 1 if netgen else 0)
        if near is not None and len(near) and near_size and near_size < size:
            size_field(gmsh, near, near_size, size, near_size / grade, size / grade)
        gmsh.model.mesh.generate(3)
        X, t = read_tetrahedra(gmsh)
    finally:
        gmsh.finalize()
    if not reparametrize:
        # inside a file's own facets gmsh leaves flat tetrahedra, four corners on one face (the
        # SO-100 base: 89 of 13,879 with volume < 1e-6 × edge³, 6 of them inverted): no
        # stiffness, a singular system. They hold no volume; the rest stay conforming
        vol = tet_volumes(X, t.T)
        edge = np.max([np.linalg.norm(X[t[i]] - X[t[j]], axis=1)
                       for i in range(4) for j in range(i + 1, 4)], axis=0)
        t = t[:, np.abs(vol) > FLAT_TET * edge ** 3]
    used, t = np.unique(t, return_inverse=True)
    return (np.ascontiguousarray(X[used].T), np.ascontiguousarray(t.reshape(4, -1)))


#: a tetrahedron of volume ≤ this × its longest edge³ is flat (a regular one: 0.118)
FLAT_TET = 1e-6


@dataclass
class Solution:
    """A solved part: its P2 mesh (:class:`Tet2`), the displacement of
    every node (n × 3) and the strain projected onto continuous P2 (n × 6); :meth:`at`
    evaluates."""

    mesh: object
    u: np.ndarray
    eps: np.ndarray
    E: float
    nu: float
    info: dict = field(default_factory=dict)

    def at(self, points) -> dict:
        """``displacement`` (n×3), ``stress`` (n×6: xx yy zz xy xz yz) and ``von_mises`` (n) at
        ``points`` (n×3); a point on or just outside the faceted surface is taken at the
        nearest point of the mesh (:meth:`Tet2.locate`)."""
        x = np.asarray(points, float).reshape(-1, 3)
        u = np.empty((len(x), 3))
        e = np.empty((len(x), 6))
        for s in range(0, len(x), 65536):
            sl = slice(s, s + 65536)
            el, lam = self.mesh.locate(x[sl])
            u[sl] = self.mesh.interpolate(self.u, el, lam)
            e[sl] = self.mesh.interpolate(self.eps, el, lam)
        s = hooke(e, self.E, self.nu)
        return {"displacement": u, "stress": s, "von_mises": von_mises(s)}

    def nodal(self) -> dict:
        """The same fields at every P2 node of the mesh (``mesh.X``)."""
        s = hooke(self.eps, self.E, self.nu)
        return {"displacement": self.u, "stress": s, "von_mises": von_mises(s)}


def hooke(e: np.ndarray, E: float, nu: float) -> np.ndarray:
    """σ = λ tr ε I + 2μ ε of strains (n × 6, tensor shears) → stresses (n × 6)."""
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    s = 2 * mu * e
    s[:, :3] += lam * e[:, :3].sum(axis=1)[:, None]
    return s


def project_strain(mesh, u: np.ndarray, M=None) -> np.ndarray:
    """The L² projection of ε(u) onto continuous P2 (n × 6): one mass matrix, conjugate
    gradients with its diagonal (a P2 mass matrix is well conditioned)."""
    import scipy.sparse.linalg as spla

    M = mesh.mass() if M is None else M
    b = mesh.strain_load(u)
    D = spla.LinearOperator(M.shape, matvec=lambda x, d=1.0 / M.diagonal(): d * x)
    out = np.zeros_like(b)
    for c in range(6):
        scale = float(np.abs(b[:, c]).max())
        if scale == 0.0:
            continue
        x, info = spla.cg(M, b[:, c] / scale, rtol=1e-12, atol=0.0, maxiter=2000, M=D)
        if info != 0:
            raise RuntimeError(f"the stress projection did not converge ({info})")
        out[:, c] = x * scale
    return out


def von_mises(s: np.ndarray) -> np.ndarray:
    """σ_vm = √(½[(σxx−σyy)² + (σyy−σzz)² + (σzz−σxx)²] + 3(σxy² + σxz² + σyz²))."""
    xx, yy, zz, xy, xz, yz = s.T
    return np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2)
                   + 3 * (xy ** 2 + xz ** 2 + yz ** 2))


#: a triangle of area ≤ this × (the part's size)² is a sliver (:func:`drop_slivers`)
SLIVER_AREA = 1e-9


def _twice_areas(v: np.ndarray, F: np.ndarray) -> np.ndarray:
    """|(b − a) × (c − a)| of each triangle (a, b, c) of ``F``: twice its area."""
    return np.linalg.norm(np.cross(v[F[:, 1]] - v[F[:, 0]], v[F[:, 2]] - v[F[:, 0]]), axis=1)


def drop_slivers(vertices: np.ndarray, faces: np.ndarray, rel: float = SLIVER_AREA) -> np.ndarray:
    """The triangles without the zero-area ones (three collinear vertices, as CSG leaves where
    a hole meets a face), the surface kept closed and conforming: the neighbour across a
    sliver's long edge is split at the sliver's middle vertex. gmsh cannot parametrize a patch
    holding a sliver. The neighbour is found through a map of directed edges, and only the
    slivers (and the triangles a split makes) are visited: linear in the triangles (a rescan
    of every triangle for each sliver took over ten minutes on a printed finger link)."""
    v = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    tiny = rel * float(np.ptp(v, axis=0).max()) ** 2
    queue = [int(k) for k in np.flatnonzero(_twice_areas(v, F) <= tiny)][::-1]
    if not queue:
        return F
    f = F.tolist()

    def area2(t) -> float:
        return float(_twice_areas(v, np.asarray([t]))[0])

    owner = {}                                  # directed edge (a, b) -> its triangle
    alive = [True] * len(f)
    splits = 4 * len(queue) + 16        # a sliver beside a sliver splits it into slivers: bound

    def register(j: int, on: bool) -> None:
        t = f[j]
        for r in range(3):
            e = (t[r], t[(r + 1) % 3])
            if on:
                owner[e] = j
            elif owner.get(e) == j:
                del owner[e]

    for j in range(len(f)):
        register(j, True)
    while queue and splits > 0:
        k = queue.pop()
        if not alive[k] or area2(f[k]) > tiny:
            continue
        tri = f[k]
        lens = [np.linalg.norm(v[tri[(i + 1) % 3]] - v[tri[(i + 2) % 3]]) for i in range(3)]
        i = int(np.argmax(lens))
        m, p, q = tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]
        j = owner.get((q, p))                   # the triangle with the edge q → p
        if j is None or j == k or not alive[j]:
            continue                            # no neighbour: leave it to gmsh
        t = f[j]
        if area2(t) <= tiny:
            continue                            # the neighbour is a sliver too: gmsh's
        r = next(r for r in range(3) if t[r] == q and t[(r + 1) % 3] == p)
        d = t[(r + 2) % 3]
        splits -= 1
        register(j, False)
        register(k, False)
        alive[k] = False
        f[j] = [q, m, d]
        f.append([m, p, d])
        alive.append(True)
        register(j, True)
        register(len(f) - 1, True)
        queue.extend(x for x in (len(f) - 1, j) if area2(f[x]) <= tiny)
    return np.asarray([t for t, a in zip(f, alive) if a], dtype=np.int64)
