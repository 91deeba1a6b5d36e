"""Static analysis: the equilibrium of a scene, found by Newton's method on the bindings.

At equilibrium every free direction of every particle has zero net force, m·a(p) = 0, with a
the paper's accelerations (the operators of :mod:`rackstress.model.operators`, evaluated by
the reference engine's kernels). Eq. 12 is the gradient of c·(r²/2 − L0²·ln r) for a symmetric
pair (DESIGN §6), so the bindings' tangent stiffness K = −∂(m·a)/∂p is symmetric and Newton's
step K·Δp = m·a(p) converges quadratically; for small strains the first step is the linear-
elastic answer, and two or three more remove what the bindings' rotation leaves (Eq. 12 is
geometrically exact: ~1 % of the load on the cantilever). Each linear solve is a direct sparse factorization (SuperLU) for
up to :data:`DIRECT_DOFS` unknowns, else conjugate gradients preconditioned by smoothed-
aggregation algebraic multigrid (pyamg) with the six rigid-body modes as near-null space:
plain dynamic relaxation would need ~ω_max/ω_1·ln(1/tol) steps — tens of thousands for a
slender part — where this takes a few multigrid cycles per Newton step (docs/calibration.md).

Settled means: the largest unbalanced force on any particle is below :data:`TOLERANCE` times
the total applied load (the sum of the magnitudes of the external forces, or of the support
reactions where only displacements are prescribed). The run's engine then checks the state
itself (:func:`engine_residual`): LAMMPS evaluates its forces there, so the equilibrium is
proven on the engine that reports it.

Example
-------
>>> from rackstress.scenes import load                       # doctest: +SKIP
>>> res = solve(load("examples/cantilever/scene.toml"))      # doctest: +SKIP
>>> res.settled, res.iterations                               # doctest: +SKIP
(True, 4)
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np

from rackstress.errors import SceneError
from rackstress.model.operators import Bind, Dampen, Force

#: settled when the largest unbalanced particle force ≤ TOLERANCE × total applied load
TOLERANCE = 1e-6
#: Newton steps before giving up (a small-strain part settles in 2)
MAX_ITERATIONS = 25
#: unknowns up to which each Newton step is a direct sparse solve
DIRECT_DOFS = 6_000


@dataclass
class StaticResult:
    """The equilibrium found: positions, whether it settled, Newton steps, relative residual."""

    p: np.ndarray
    settled: bool
    iterations: int
    residual: float
    load: float
    history: list
    wall_s: float


def check_static(scene) -> None:
    """Refuse what static analysis cannot hold: operators other than bind, force and dampen
    (contacts and attractions change with the motion), conditional forces, no load at all."""
    for target, seq in scene.operators.items():
        for op in seq:
            if isinstance(op, Dampen):
                continue               # no velocity at equilibrium
            if isinstance(op, Bind) and not op.when:
                continue
            if isinstance(op, Force) and not op.when:
                continue
            raise SceneError(
                f"scene '{scene.name}': static analysis finds the equilibrium of bindings under "
                f"constant loads; '{op.label()}' on '{target}' is not one (collisions, "
                "attractions and phase-conditioned operators depend on the motion): set "
                "analysis = \"dynamic\"")
    from rackstress.model.constraints import supported

    if not supported(scene).any():
        raise SceneError(f"scene '{scene.name}': a static analysis needs a support (held or "
                         "[[support]]): without one the part has no equilibrium, it floats away")


def external_forces(scene) -> np.ndarray:
    """n×3 external force on each particle at full load, in the scene's force unit: m·â of
    every force operator (Eq. 8), phase-conditioned ones included (a ramp's every stair)."""
    n = scene.n_particles
    F = np.zeros((n, 3))
    m = scene.masses()
    for target, seq in scene.operators.items():
        sl = scene.slice(target)
        for op in seq:
            if isinstance(op, Force):
                sel = np.flatnonzero(op.mask(scene.groups[target].n)) + sl.start
                F[sel] += m[sel, None] * op.vector()[None, :]
    return F


def _bind_pairs(scene):
    """Every bind operator's pairs in global indices (i on the target, from j), c and L0²."""
    I, J, C, Q = [], [], [], []
    for target, seq in scene.operators.items():
        for op in seq:
            if isinstance(op, Bind):
                pl = op.pairs(scene.groups[target], scene.groups[op.source]).shifted(
                    scene.offset(target), scene.offset(op.source))
                I.append(pl.i), J.append(pl.j), C.append(pl.c), Q.append(pl.q)
    if not I:
        z = np.zeros(0, np.int64)
        return z, z, np.zeros(0), np.zeros(0)
    return np.concatenate(I), np.concatenate(J), np.concatenate(C), np.concatenate(Q)


def forces(scene, p: np.ndarray, pairs, F_ext: np.ndarray, m: np.ndarray) -> np.ndarray:
    """m·a(p): the bindings' force (Eq. 12) plus the external loads, n×3."""
    I, J, C, Q = pairs
    a = Bind.accel(p[I], p[J], C, Q)
    out = np.zeros_like(p)
    for k in range(3):
        out[:, k] = np.bincount(I, weights=a[:, k] * m[I], minlength=len(p))
    return out + F_ext


def stiffness(p: np.ndarray, pairs, m: np.ndarray):
    """K = −∂(m·a)/∂p of the bindings (3n×3n, CSR): Eq. 12 linearized (Bind.jacobian)."""
    import scipy.sparse as sp

    I, J, C, Q = pairs
    n = len(p)
    B, _ = Bind.jacobian(p[J] - p[I], C, Q)
    B = B * m[I][:, None, None]
    # the diagonal blocks summed per particle first (one 3×3 block each, not one per binding)
    D = np.zeros((n, 9))
    flat = B.reshape(-1, 9)
    for k in range(9):
        D[:, k] = np.bincount(I, weights=flat[:, k], minlength=n)
    r = np.arange(3)
    diag = np.arange(n)
    rows_d = (3 * diag[:, None, None] + r[None, :, None]).repeat(3, axis=2)
    cols_d = (3 * diag[:, None, None] + r[None, None, :]).repeat(3, axis=1)
    rows_ij = (3 * I[:, None, None] + r[None, :, None]).repeat(3, axis=2)
    cols_ij = (3 * J[:, None, None] + r[None, None, :]).repeat(3, axis=1)
    rows = np.concatenate([rows_d.ravel(), rows_ij.ravel()])
    cols = np.concatenate([cols_d.ravel(), cols_ij.ravel()])
    vals = np.concatenate([D.ravel(), -B.ravel()])
    return sp.csr_matrix((vals, (rows, cols)), shape=(3 * n, 3 * n))


def rigid_modes(p: np.ndarray, free) -> np.ndarray:
    """The six rigid-body modes (3 translations, 3 rotations) on the free unknowns (``free``:
    their boolean mask, or the supports' :class:`ConstraintMap`): the near-null space smoothed
    aggregation needs for elasticity."""
    n = len(p)
    c = p - p.mean(axis=0)
    B = np.zeros((3 * n, 6))
    for k in range(3):
        B[k::3, k] = 1.0
    B[1::3, 3], B[2::3, 3] = -c[:, 2], c[:, 1]
    B[0::3, 4], B[2::3, 4] = c[:, 2], -c[:, 0]
    B[0::3, 5], B[1::3, 5] = -c[:, 1], c[:, 0]
    return free.modes(B) if hasattr(free, "modes") else B[free]


def _linear_solve(K, b, p, free, rtol, cache: dict):
    """Solve K·x = b on the free unknowns: SuperLU when small, else conjugate gradients
    preconditioned by smoothed-aggregation AMG, whose hierarchy is built once (``cache``) and
    kept for the later Newton steps (the tangent changes little between them)."""
    import scipy.sparse.linalg as spla

    if K.shape[0] <= DIRECT_DOFS:
        return spla.spsolve(K.tocsc(), b), "direct"
    import pyamg

    if "M" not in cache:
        ml = pyamg.smoothed_aggregation_solver(K, B=rigid_modes(p, free), symmetry="symmetric",
                                               strength=("symmetric", {"theta": 0.0}),
                                               max_coarse=500, coarse_solver="splu")
        # splu: the coarsest level factorized once; pyamg's default (a pseudo-inverse by SVD of
        # a dense ~1,500² matrix) took 90 % of the bracket's solve (7 s against 0.7 s CPU)
        cache["M"] = ml.aspreconditioner(cycle="V")
    x, info = spla.cg(K, b, rtol=rtol, maxiter=2000, M=cache["M"])
    return x, "amg-cg" if info == 0 else "amg-cg (not converged)"


def solve(scene, tolerance: float = TOLERANCE, max_iterations: int = MAX_ITERATIONS,
          progress: bool = False) -> StaticResult:
    """The equilibrium of ``scene`` by Newton's method (module doc).

    Parameters
    ----------
    scene : Scene
        With supports, bindings and constant loads (:func:`check_static`).
    tolerance : float
        Settled when the largest unbalanced particle force ≤ tolerance × total applied load.
    progress : bool
        One line per Newton step on stderr (what a terminal shows for a long solve).

    Returns
    -------
    StaticResult
    """
    t0 = time.perf_counter()
    check_static(scene)
    o = scene.original_positions()
    n = len(o)
    m = scene.masses()
    from rackstress.model.constraints import ConstraintMap

    # the supports as u = T·q + prescribed (model/constraints.py): T selects the free unknowns
    # where only axes are fixed, rollers on any face and pins in holes otherwise
    cmap = ConstraintMap.of_scene(scene)
    free = cmap.free if cmap.trivial else cmap
    p = o + scene.prescribed()
    pairs = _bind_pairs(scene)
    F_ext = external_forces(scene)
    history = []
    say = (lambda msg: print(msg, file=sys.stderr, flush=True)) if progress else (lambda msg: None)
    load = float(np.linalg.norm(F_ext, axis=1).sum())
    it, settled, rel = 0, False, float("inf")
    cache: dict = {}
    # only displacements prescribed: the load is the support reactions at the current state,
    # as the engine's own check takes them (engine_residual); the first state's reactions
    # (the displaced face pulled against an undeformed part) were ~10⁴ × the equilibrium's,
    # and a residual "settled" against them failed the engine's check (exit 6)
    reactions = load == 0.0
    if progress:
        say(f"static: {n:,} particles, {len(pairs[0]):,} bindings, {cmap.unknowns:,} "
            f"unknowns")
    while True:
        f = forces(scene, p, pairs, F_ext, m)
        if reactions:
            load = float(np.linalg.norm(f - cmap.unbalanced(f), axis=1).sum())
        unbalanced = cmap.unbalanced(f)
        worst = float(np.linalg.norm(unbalanced, axis=1).max()) if n else 0.0
        rel = worst / load if load > 0 else (0.0 if worst == 0 else float("inf"))
        history.append(rel)
        say(f"static: iteration {it}, residual {rel:.3g} of the applied load "
            f"({time.perf_counter() - t0:.1f} s)")
        if not np.isfinite(rel):
            break
        if rel <= tolerance or load == 0.0:
            settled = True
            break
        if it >= max_iterations:
            break
        K = cmap.reduce(stiffness(p, pairs, m))
        b = cmap.restrict(f)
        # inexact Newton: the linear solve need only be as exact as the residual is small
        # (the step leaves rtol·‖b‖ unbalanced: a tenth of what settling allows)
        rtol = min(1e-2, max(1e-10, 0.1 * tolerance / rel))
        dx, _ = _linear_solve(K.tocsr(), b, p, free, rtol, cache)
        step = cmap.expand(dx).reshape(-1)
        # a Newton step that makes things much worse is halved (large rotations, buckling)
        scale = 1.0
        for _ in range(8):
            trial = p + scale * step.reshape(n, 3)
            ft = forces(scene, trial, pairs, F_ext, m)
            wt = float(np.linalg.norm(cmap.unbalanced(ft), axis=1).max())
            if np.isfinite(wt) and wt <= 4.0 * worst:
                break
            scale *= 0.5
        p = trial
        it += 1
    return StaticResult(p, settled, it, rel, load, history, time.perf_counter() - t0)


def rounding_floor(scene, p: np.ndarray) -> float:
    """The unbalanced force below which no solver of positions near ``p`` can go (an estimate;
    given the original positions, as a settled state is near them, whatever a failed solve did):
    each position is rounded to ~ε·|p|, and each binding turns that into a force error of about
    its stiffness (∂/∂d of Eq. 12 near L0 is 2c, times m); a particle sums them over its
    bindings. Relative to the applied load, it says whether the tolerance is reachable at all
    (a 40 m steel bar under 100 N: ~1e-5 of the load, above the 1e-6 asked)."""
    I, J, C, _ = _bind_pairs(scene)
    if len(I) == 0:
        return 0.0
    m = scene.masses()
    per = np.bincount(I, weights=2.0 * np.abs(C) * m[I], minlength=len(p))
    return float(np.finfo(float).eps * np.abs(p).max() * per.max())


def engine_residual(scene, engine, p: np.ndarray, reactions: float | None = None) -> float:
    """The largest unbalanced particle force at ``p`` as the run's engine computes it,
    relative to the applied load: the reference engine's accelerations, or LAMMPS' forces
    after ``run 0`` (divided by its masses: its accelerations are the paper's) × the scene's
    particle masses.

    ``reactions``: the support reactions at ``p`` as :func:`solve` measured them, the load of a
    scene with only prescribed displacements — the engines hold a fixed particle by zeroing
    its force, so they cannot give them (the check was then an absolute force in newtons
    read as a fraction of the load)."""
    from rackstress.model.constraints import ConstraintMap

    m = scene.masses()
    cmap = ConstraintMap.of_scene(scene)
    if getattr(engine, "name", "") == "reference":
        engine.p = p.copy()
        a = engine.accelerations({})
    else:
        engine.scatter("x", p)
        engine.command("run 0 post no")
        f = engine.gather_forces()
        mass_of_type = engine.deck.masses
        md = np.concatenate([np.full(g.n, mass_of_type.get(name, 1.0))
                             for name, g in scene.groups.items()])
        a = f / md[:, None]
    F_ext = external_forces(scene)
    load = float(np.linalg.norm(F_ext, axis=1).sum())
    f = m[:, None] * a
    if load == 0.0:
        load = reactions if reactions is not None else float(
            np.linalg.norm(f - cmap.unbalanced(f), axis=1).sum())
    worst = float(np.linalg.norm(cmap.unbalanced(f), axis=1).max())
    return worst / load if load > 0 else worst
