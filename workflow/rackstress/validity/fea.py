"""Linear-elastic finite-element references for the validity cases (scikit-fem, plane stress).

Three planar bodies of unit thickness, quadratic triangles (P2), a direct sparse solve (MKL
PARDISO where it is, else SuperLU: :func:`rackstress.engines.linear.factorize`):

* :func:`cantilever` — a beam [x0, x0+L] × [y0, y0+h] clamped at x = x0 (both displacement
  components zero), a shear traction of total P on its free end (Euler–Bernoulli: tip deflection
  PL³/3EI, bending stress 6P(L−s)/h² at the top and bottom fibres a distance s from the root);
* :func:`plate_with_hole` — a square plate [−W, W]² with a central hole of radius a, uniaxial
  tension σ on x = ±W (Kirsch: σ_xx = 3σ at the hole's sides (0, ±a), across the load);
  solved on the quarter x, y ≥ 0 with symmetry conditions, mirrored for evaluation;
* :func:`l_bracket` — an L: a vertical leg [0, w] × [0, H] fixed along y = 0 and a horizontal
  arm [0, Lx] × [H−w, H] carrying a downward shear traction of total P on x = Lx. The
  re-entrant corner (w, H−w) is a stress singularity (σ ~ r^−0.456): the peak over the mesh does
  not converge, so every figure here is taken at given points (the particles' positions, at
  least half a lattice spacing from the corner), where it does.

Material: isotropic (E, ν; plane stress) by default, or ``stiffness = (C11, C12, C44)``, a 2D
material with square (cubic) symmetry along x and y — σxx = C11 εxx + C12 εyy, σyy = C12 εxx +
C11 εyy, σxy = 2 C44 εxy — which is what a square lattice with nearest and diagonal bindings of
equal stiffness k represents to first order (:func:`square_lattice_stiffness`: C11 = 2k,
C12 = C44 = k per unit area), so the FEA can solve the lattice's own material.

Every solver returns an :class:`FEAResult`; :meth:`FEAResult.at` interpolates displacement,
small strain ε, plane-stress σ, the von Mises stress σ_vm = √(σxx² − σxxσyy + σyy² + 3σxy²) and
the von Mises shear strain η of the particle measure (OVITO's definition, with ε_zz = 0 as the
particle measure's membrane completion has it) at any points inside the body. Strains are the
L2 projection of the P2 displacement's gradient onto continuous P2, then interpolated.

Convergence (:func:`refinement_study`): the same case at mesh densities n, 2n, …; the peak of
σ_vm over the given points must change by at most 2 % between the last two.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

try:
    import skfem
    from skfem import (Basis, BilinearForm, ElementTriP2, ElementVector, FacetBasis, LinearForm,
                       MeshTri, asm, condense)
    from skfem.models.elasticity import lame_parameters, linear_elasticity
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError("rackstress.validity.fea needs scikit-fem: pip install 'rackstress[fem]'"
                      ) from exc

#: Default material: a unit Young's modulus (the figures compared are ranks and ratios) and
#: steel's Poisson ratio.
E_DEFAULT = 1.0
NU_DEFAULT = 0.3
#: Convergence target: relative change of the peak von Mises stress between the last two meshes.
CONVERGED = 0.02


@dataclass
class FEAResult:
    """A solved case: mesh, P2 vector basis, displacement dofs and the projected strain fields."""

    name: str
    mesh: object
    basis: object
    u: np.ndarray
    E: float
    nu: float
    density: int
    mirror: bool = False
    info: dict = field(default_factory=dict)
    stiffness: tuple | None = None

    def __post_init__(self):
        sb = self.basis.with_element(ElementTriP2())
        du = self.basis.interpolate(self.u)
        g = du.grad  # g[i][j] = ∂u_i/∂x_j at quadrature points
        self._sbasis = sb
        # scikit-fem's L2 projection (Basis.project: M e = ∫ g·v), its mass matrix factorized
        # once for the three components
        M = asm(BilinearForm(lambda u, v, w: u * v), sb)
        rhs = np.stack([asm(LinearForm(lambda v, w: w.g * v), sb, g=x)
                        for x in (g[0][0], g[1][1], 0.5 * (g[0][1] + g[1][0]))], axis=1)
        eps = _solved(M, rhs)
        self._eps = tuple(np.ascontiguousarray(eps[:, k]) for k in range(3))

    @property
    def n_dofs(self) -> int:
        return int(self.basis.N)

    def _inside(self, x: np.ndarray) -> np.ndarray:
        """Points on the boundary (or between a curved edge and its chord) moved just inside
        (:func:`move_inside`); a point still outside is an error naming the body."""
        return move_inside(self.mesh, x, body=self.name)

    def at(self, points) -> dict:
        """Fields at ``points`` (n × 2 or n × 3; z ignored), each an array of n values.

        Keys: ``ux, uy, exx, eyy, exy`` (tensor shear), ``sxx, syy, sxy``, ``von_mises_stress``,
        ``von_mises_strain``. A mirrored (quarter) model is evaluated at (|x|, |y|), displacements
        carrying the signs back.
        """
        x = np.asarray(points, dtype=float)[:, :2].copy()
        sx = sy = np.ones(len(x))
        if self.mirror:
            sx, sy = np.sign(x[:, 0]) + (x[:, 0] == 0), np.sign(x[:, 1]) + (x[:, 1] == 0)
            x = np.abs(x)
        x = self._inside(x)
        P = _probes(self._sbasis, x)
        exx, eyy, exy = (P @ e for e in self._eps)
        uv = _probes(self.basis, x) @ self.u
        ux, uy = uv[: len(x)], uv[len(x):]
        if self.mirror:
            ux, uy, exy = ux * sx, uy * sy, exy * sx * sy
        if self.stiffness is not None:
            C11, C12, C44 = self.stiffness
            sxx, syy, sxy = C11 * exx + C12 * eyy, C12 * exx + C11 * eyy, 2 * C44 * exy
        else:
            k = self.E / (1.0 - self.nu ** 2)
            sxx, syy = k * (exx + self.nu * eyy), k * (eyy + self.nu * exx)
            sxy = self.E / (1.0 + self.nu) * exy
        return {"ux": ux, "uy": uy, "exx": exx, "eyy": eyy, "exy": exy,
                "sxx": sxx, "syy": syy, "sxy": sxy,
                "von_mises_stress": np.sqrt(sxx ** 2 - sxx * syy + syy ** 2 + 3 * sxy ** 2),
                "von_mises_strain": von_mises_strain_2d(exx, eyy, exy)}


def von_mises_strain_2d(exx, eyy, exy):
    """η of a planar strain (ε_zz = 0, tensor shear exy), as the particle ``strain`` measure."""
    return np.sqrt(exy ** 2 + ((exx - eyy) ** 2 + eyy ** 2 + exx ** 2) / 6.0)


# ----------------------------------------------------------------------------- meshes
def rectangle_mesh(x0, x1, y0, y1, density: int):
    """Triangles of a rectangle, ``density`` intervals per unit length (at least 2 a side)."""
    nx = max(2, int(round((x1 - x0) * density)))
    ny = max(2, int(round((y1 - y0) * density)))
    return MeshTri.init_tensor(np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1))


def l_mesh(w, H, Lx, density: int, corner_levels: int = 4, corner_radius: float = 2.0):
    """Triangles of the L [0, w]×[0, H] ∪ [0, Lx]×[H−w, H] (grid lines through the corner).

    The elements within ``corner_radius`` of the re-entrant corner (w, H−w) are refined
    ``corner_levels`` more times, the radius halving each time (the singularity needs it).
    """
    m = rectangle_mesh(0.0, Lx, 0.0, H, density)
    c = m.p[:, m.t].mean(axis=1)
    out = (c[0] > w) & (c[1] < H - w)
    m = m.remove_elements(np.flatnonzero(out))
    r = corner_radius
    for _ in range(corner_levels):
        c = m.p[:, m.t].mean(axis=1)
        near = np.flatnonzero(np.hypot(c[0] - w, c[1] - (H - w)) < r)
        if len(near):
            m = m.refined(near)
        r *= 0.5
    return m


def hole_quarter_mesh(a, W, density: int, grading: float = 3.0):
    """O-grid of the quarter [0, W]² minus the disc of radius a, graded towards the hole.

    Two blocks (the diagonal splits them); radial node positions follow s^grading-like
    geometric spacing so elements at the hole are ~a/density·(π/2) wide.
    """
    n_t = max(4, int(round(density * a * np.pi / 4)))       # per block, along the arc
    n_r = max(4, int(round(density * (W - a) / grading)))
    s = np.linspace(0.0, 1.0, n_r + 1)
    s = (np.expm1(grading * s) / np.expm1(grading))           # clustered at the hole
    pts, tris, base = [], [], 0
    for block in range(2):
        th = np.linspace(0.0, np.pi / 4, n_t + 1) + block * np.pi / 4
        inner = np.stack([a * np.cos(th), a * np.sin(th)], axis=1)
        q = np.linspace(0.0, W, n_t + 1)      # outer nodes evenly along x = W, then y = W
        outer = (np.stack([np.full_like(q, W), q], axis=1) if block == 0
                 else np.stack([W - q, np.full_like(q, W)], axis=1))
        if block == 1:
            inner[-1] = (0.0, a)
        P = (1 - s)[:, None, None] * inner[None] + s[:, None, None] * outer[None]
        idx = base + np.arange((n_r + 1) * (n_t + 1)).reshape(n_r + 1, n_t + 1)
        a00, a01, a10, a11 = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
        tris += [np.stack([a00, a10, a11]).reshape(3, -1), np.stack([a00, a11, a01]).reshape(3, -1)]
        pts.append(P.reshape(-1, 2))
        base += (n_r + 1) * (n_t + 1)
    P, T = np.concatenate(pts), np.concatenate(tris, axis=1)
    a, b, c = P[T[0]], P[T[1]], P[T[2]]
    flip = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) < 0
    T[1, flip], T[2, flip] = T[2, flip], T[1, flip].copy()   # counter-clockwise throughout
    from scipy.spatial import cKDTree

    # merge the nodes the two blocks share on the diagonal
    keep = np.arange(len(P))
    for i, j in sorted(cKDTree(P).query_pairs(1e-9 * W)):
        keep[max(i, j)] = keep[min(i, j)]
    used, T = np.unique(keep[T], return_inverse=True)
    T = T.reshape(3, -1)
    return MeshTri(np.ascontiguousarray(P[used].T), T)


# ----------------------------------------------------------------------------- solver
def _boundary(mesh, test):
    return mesh.facets_satisfying(test, boundaries_only=True)


def square_lattice_stiffness(k: float) -> tuple:
    """(C11, C12, C44) per unit area of a square lattice of spacing 1 whose nearest and diagonal
    neighbours are joined by springs of stiffness k (first order; bind's k = 2c, Eq. 12).

    Energy per particle ½ k Σ (n·ε·n)² L² over one axial bond each way and both diagonals
    (L² = 2, n_x⁴ = n_x² n_y² = ¼): C11 = k + k, C12 = C44 = k. Along the axes E = C11 −
    C12²/C11 = 1.5k and ν = C12/C11 = ½; the shear modulus C44 is twice an isotropic sheet's.

    Example
    -------
    >>> square_lattice_stiffness(40.0)
    (80.0, 40.0, 40.0)
    """
    return (2.0 * k, float(k), float(k))


def _anisotropic(stiffness):
    from skfem.helpers import sym_grad

    C11, C12, C44 = (float(x) for x in stiffness)

    @BilinearForm
    def form(u, v, w):
        eu, ev = sym_grad(u), sym_grad(v)
        sxx = C11 * eu[0, 0] + C12 * eu[1, 1]
        syy = C12 * eu[0, 0] + C11 * eu[1, 1]
        sxy = 2.0 * C44 * eu[0, 1]
        return sxx * ev[0, 0] + syy * ev[1, 1] + 2.0 * sxy * ev[0, 1]
    return form


def _solve(mesh, E, nu, fixed, traction, stiffness=None):
    """Plane-stress linear elasticity; ``fixed`` = [(facets, components)], traction [(facets, t)].
    ``stiffness``: (C11, C12, C44) of a square-symmetric 2D material instead of (E, ν)."""
    e = ElementVector(ElementTriP2())
    basis = Basis(mesh, e, intorder=4)
    if stiffness is not None:
        K = asm(_anisotropic(stiffness), basis)
    else:
        lam, mu = lame_parameters(E, nu)
        lam = 2 * lam * mu / (lam + 2 * mu)    # plane stress
        K = asm(linear_elasticity(lam, mu), basis)
    f = np.zeros(basis.N)
    for facets, t in traction:
        fb = FacetBasis(mesh, e, facets=facets, intorder=4)
        tx, ty = float(t[0]), float(t[1])
        f += asm(LinearForm(lambda v, w: tx * v[0] + ty * v[1]), fb)
    D = []
    for facets, comps in fixed:
        dofs = basis.get_dofs(facets)
        for c in comps:
            D.append(dofs.all(f"u^{c + 1}"))
    D = np.unique(np.concatenate(D))
    A, b, u, free = condense(K, f, D=D)
    u = u.copy()
    u[free] = _solved(A, b)
    return basis, u


def _solved(A, b: np.ndarray) -> np.ndarray:
    """A x = b (``A`` symmetric; ``b`` one right-hand side or its columns) by the static
    path's direct solver (:func:`rackstress.engines.linear.factorize`: MKL PARDISO, else
    SuperLU), its factor freed after."""
    from rackstress.engines.linear import factorize

    f = factorize(A.tocsr())
    try:
        return f.solve(b) if b.ndim == 1 else f.solve_many(b)
    finally:
        f.free()


def cantilever(L, h, P, x0=0.0, y0=0.0, density=8, E=E_DEFAULT, nu=NU_DEFAULT,
               stiffness=None) -> FEAResult:
    """Beam clamped at x = x0, total downward end load P on x = x0 + L (module docstring).

    Example
    -------
    >>> r = cantilever(20.0, 1.0, 1e-3, density=4)
    >>> round(float(-r.at([[20.0, 0.5]])["uy"][0] / (4 * 1e-3 * 20 ** 3)), 2)  # PL³/3EI, I=1/12
    1.0
    """
    m = rectangle_mesh(x0, x0 + L, y0, y0 + h, density)
    tol = 1e-9 * max(L, h)
    clamp = _boundary(m, lambda x: np.abs(x[0] - x0) < tol)
    end = _boundary(m, lambda x: np.abs(x[0] - x0 - L) < tol)
    basis, u = _solve(m, E, nu, [(clamp, (0, 1))], [(end, (0.0, -P / h))], stiffness)
    return FEAResult("cantilever", m, basis, u, E, nu, density,
                     info={"L": L, "h": h, "P": P, "x0": x0, "y0": y0}, stiffness=stiffness)


def plate_with_hole(a, W, sigma, density=8, E=E_DEFAULT, nu=NU_DEFAULT,
                    stiffness=None) -> FEAResult:
    """Plate [−W, W]² with a hole of radius a, tension σ along x (quarter model, mirrored)."""
    m = hole_quarter_mesh(a, W, density)
    tol = 1e-9 * W
    left = _boundary(m, lambda x: np.abs(x[0]) < tol)
    bottom = _boundary(m, lambda x: np.abs(x[1]) < tol)
    right = _boundary(m, lambda x: np.abs(x[0] - W) < tol)
    basis, u = _solve(m, E, nu, [(left, (0,)), (bottom, (1,))], [(right, (sigma, 0.0))],
                      stiffness)
    return FEAResult("plate-hole", m, basis, u, E, nu, density, mirror=True,
                     info={"a": a, "W": W, "sigma": sigma}, stiffness=stiffness)


def l_bracket(w, H, Lx, P, density=8, E=E_DEFAULT, nu=NU_DEFAULT,
              stiffness=None) -> FEAResult:
    """The L of the module docstring: fixed along y = 0, downward end load P on x = Lx."""
    m = l_mesh(w, H, Lx, density)
    tol = 1e-9 * max(H, Lx)
    base = _boundary(m, lambda x: np.abs(x[1]) < tol)
    end = _boundary(m, lambda x: np.abs(x[0] - Lx) < tol)
    basis, u = _solve(m, E, nu, [(base, (0, 1))], [(end, (0.0, -P / w))], stiffness)
    return FEAResult("l-bracket", m, basis, u, E, nu, density,
                     info={"w": w, "H": H, "Lx": Lx, "P": P, "corner": (w, H - w)},
                     stiffness=stiffness)


def refinement_study(solver, points, densities=(4, 8, 16), **kw) -> dict:
    """Solve at each mesh density; peak σ_vm over ``points`` and its change between meshes.

    Returns ``{"densities", "n_dofs", "peak_von_mises", "change" (relative, last two),
    "converged" (change ≤ 2 %), "result" (the finest FEAResult)}``.
    """
    peaks, ndofs, res = [], [], None
    for d in densities:
        res = solver(density=d, **kw)
        peaks.append(float(np.max(res.at(points)["von_mises_stress"])))
        ndofs.append(res.n_dofs)
    change = abs(peaks[-1] - peaks[-2]) / abs(peaks[-1]) if len(peaks) > 1 else float("nan")
    return {"densities": list(densities), "n_dofs": ndofs, "peak_von_mises": peaks,
            "change": change, "converged": bool(change <= CONVERGED), "result": res}


__all__ = ["FEAResult", "cantilever", "plate_with_hole", "l_bracket", "refinement_study",
           "square_lattice_stiffness",
           "von_mises_strain_2d", "rectangle_mesh", "l_mesh", "hole_quarter_mesh", "skfem",
           "CONVERGED", "E_DEFAULT", "NU_DEFAULT"]


#: bytes one element search may take: scikit-fem's finder, when a point is not in the 10
#: elements nearest to it, tries every element for every point asked at once (n × elements × 3
#: doubles: 13.7 GiB for the cantilever's 10,100 particles on 60,600 tetrahedra)
PROBE_BYTES = 64 * 2 ** 20


def probe_chunks(n_points: int, n_elements: int) -> list:
    """Slices of at most PROBE_BYTES / (24 × n_elements) points (at least 16): the points
    asked of scikit-fem's element search (``element_finder``, ``probes``) at a time.

    >>> len(probe_chunks(5000, 1_000_000)), probe_chunks(100, 60_600)
    (313, [slice(0, 46, None), slice(46, 92, None), slice(92, 100, None)])
    """
    step = max(16, PROBE_BYTES // (24 * max(1, int(n_elements))))
    return [slice(i, min(n_points, i + step)) for i in range(0, n_points, step)]


def _probes(basis, x: np.ndarray):
    """``basis.probes(x.T)`` asked PROBE_BYTES at a time (:func:`probe_chunks`): the same
    sparse matrix, its rows the components' values at each point (scikit-fem's order:
    component-major for a vector basis)."""
    import scipy.sparse as sp

    chunks = probe_chunks(len(x), basis.mesh.t.shape[1])
    if len(chunks) == 1:
        return basis.probes(x.T)
    parts = [basis.probes(x[sl].T).tocsr() for sl in chunks]
    dim = parts[0].shape[0] // (chunks[0].stop - chunks[0].start)
    rows = [p[d * (sl.stop - sl.start):(d + 1) * (sl.stop - sl.start)]
            for d in range(dim) for p, sl in zip(parts, chunks)]
    return sp.vstack(rows).tocsr()


def move_inside(mesh, x: np.ndarray, fracs=(1e-9, 1e-6, 1e-3, 1e-2, 0.1, 0.5),
                body: str | None = None) -> np.ndarray:
    """``x`` with each point that scikit-fem's element search misses (on the boundary, or
    between a curved edge and its chord) moved towards the centroid of its nearest element by
    the first of ``fracs`` of the way at which it is found; it moves by less than the chord's
    sagitta.

    A point found at none of them is an error naming ``body``, or stays where it is when
    ``body`` is None. Serves the planar FEA here and the tetrahedral one
    (:mod:`rackstress.validity.solid`)."""
    find = mesh.element_finder()
    missed = []
    for sl in probe_chunks(len(x), mesh.t.shape[1]):
        try:
            find(*x[sl].T)
        except ValueError:
            missed.extend(range(sl.start, sl.stop))
    if not missed:
        return x
    from scipy.spatial import cKDTree

    cent = mesh.p[:, mesh.t].mean(axis=1).T
    tree = cKDTree(cent)
    x = x.copy()
    for k in missed:
        try:
            find(*x[k:k + 1].T)
            continue
        except ValueError:
            pass
        c = cent[tree.query(x[k])[1]]
        for frac in fracs:
            y = x[k] + frac * (c - x[k])
            try:
                find(*y[None].T)
                x[k] = y
                break
            except ValueError:
                continue
        else:
            if body is not None:
                raise ValueError(f"point {x[k]} is outside the {body} body")
    return x
