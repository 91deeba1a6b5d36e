"""Static analysis: the equilibrium of a scene, found by Newton's method on the bindings.

At equilibrium every free direction of every particle has zero net force, m·a(p) = 0, with a
the paper's accelerations (the operators of :mod:`rackstress.model.operators`, evaluated by
the reference engine's kernels). Eq. 12 is the gradient of c·(r²/2 − L0²·ln r) for a symmetric
pair (DESIGN §6), so the bindings' tangent stiffness K = −∂(m·a)/∂p is symmetric and Newton's
step K·Δp = m·a(p) converges quadratically; for small strains the first step is the linear-
elastic answer, and two or three more remove what the bindings' rotation leaves (Eq. 12 is
geometrically exact: ~1 % of the load on the cantilever).

Each linear solve (:mod:`rackstress.engines.linear`) is a sparse direct LDLᵀ factorization
(MKL PARDISO) wherever its own memory and work estimates fit, each step's tangent factorized
on the first one's ordering; AMG-preconditioned conjugate gradients for the largest parts. The
tangent carries μ·L (:data:`REGULARIZATION`), L the bindings' graph Laplacian: a wall one
particle thick has no stiffness across itself at rest, and μ·L makes each step defined there
and moves the wall with its edges. μ rises when a step does not lower the unbalanced force
and falls when it does (Levenberg–Marquardt): such walls are a nonlinear structure of their own
(a membrane's force ~ w³), and a plain Newton step there overshoots (18 steps on a gripper jaw
where the rest settled in two; docs/calibration.md "Static analysis").

After each step the particles lacking a direction at rest (a strut one particle wide, a wall
one particle thick: what :func:`check_part` warns of) are moved to their own equilibrium, the
rest held (:func:`_relax`, nonlinear elimination): held across only by their bindings' tension,
which each step changes by as much, they kept the whole part's residual falling ~4× a step or
oscillating while the rest had converged (so100-upper-arm: 11 steps, 2 with them settled).

Two material parts pressed together (``[[contact]]``: the paper's collide, Eq. 10, its c from
their materials) are a penalty whose pairs change with the positions: in contact Eq. 10 is
Eq. 12 with L0 = R, the sum of the radii, so each pair closer than R is taken as a binding of
that length, none beyond (docs/calibration.md "Contact"). The solver settles it by active
sets: the pairs in contact are held as two-sided bindings while Newton's method converges
(quadratically, as on bound parts), then the set is taken anew — pairs pulled apart leave,
pairs pressed closer than R join — until it no longer changes, where the two-sided and the
true one-sided contact give the same forces (:func:`_update_contacts`). Taking the pairs anew at
every state instead made their set chatter between steps on an assembly (a pin in a clevis:
the residual swung between 1e-3 and 0.4 and the pin left its hole).

Before the first step the part is checked (:func:`check_part`, :mod:`rackstress.engines.
mechanisms`): a body held by nothing, supports that leave a rigid motion free, a load across a
wall one particle thick or on a mechanism are refused in seconds (SceneError, exit 2) naming
the particles and what to do.

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
import weakref
from dataclasses import dataclass, field

import numpy as np

from rackstress.errors import SceneError
from rackstress.model.operators import Bind, Collide, Const, Dampen, Force, Indent
from rackstress.model.volume import Volume, volume_terms

#: settled when the largest unbalanced particle force ≤ TOLERANCE × total applied load
TOLERANCE = 1e-6
#: Newton steps before giving up (a small-strain part settles in 2)
MAX_ITERATIONS = 25


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
    #: n×3 force each support applies at ``p`` (zero on free directions); their sum balances
    #: the applied load (Σ reactions = −Σ loads, and so do their moments)
    reactions: np.ndarray | None = None
    #: the linear solver of the last step ("pardiso", "superlu", "amg-cg"; "-pcg" after a direct one:
    #: the bindings' tangent factorized, conjugate gradients on the whole: a volumetric term's)
    solver: str = ""
    #: tangents factorized (or AMG hierarchies built): Newton steps minus reused factors
    factorizations: int = 0
    #: what :func:`check_part` warned of (walls one particle thick)
    warnings: list = field(default_factory=list)
    #: where the largest unbalanced forces stay (a run that did not settle): :func:`unbalanced_at`
    unbalanced: dict | None = None
    #: contact: the active sets taken (the first at the start, one more each time Newton's
    #: method settled a set and the pairs in contact changed); 0 without contact
    contact_sets: int = 0


def check_static(scene) -> None:
    """Refuse what static analysis cannot hold: operators other than bind, force and dampen
    (contacts and attractions change with the motion), conditional forces, no load at all."""
    for target, seq in scene.operators.items():
        for op in seq:
            if isinstance(op, Dampen):
                continue               # no velocity at equilibrium
            if isinstance(op, (Bind, Volume)) and not op.when:
                continue
            if isinstance(op, Force) and not op.when:
                continue
            if isinstance(op, Indent) and not op.when and op.steps == 0:
                continue               # a rigid sphere at its place: a penalty (indenter.py)
            if is_contact(scene, target, op):
                continue               # two material parts' contact: a penalty (_pairs_at)
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


def is_contact(scene, target: str, op) -> bool:
    """Whether ``op`` on ``target`` is one side of two material parts' contact (``[[contact]]``,
    :func:`rackstress.scenes.physical.contacts`): a collide with a constant c between two parts
    with materials, the other side's collide there too with the same c·m, so that each pair's
    two forces are equal and opposite and its tangent symmetric."""
    if not (isinstance(op, Collide) and isinstance(op.coeff, Const) and not op.when):
        return False
    gt, gs = scene.groups[target], scene.groups.get(op.source)
    if gs is None or gt.material is None or gs.material is None or op.source == target:
        return False
    mt, ms = gt.mass(scene.units), gs.mass(scene.units)
    return any(isinstance(o, Collide) and isinstance(o.coeff, Const) and o.source == target
               and not o.when and abs(o.coeff.c * ms - op.coeff.c * mt)
               <= 1e-9 * abs(op.coeff.c * mt)
               for o in scene.operators.get(op.source, []))


def material_contacts(scene) -> tuple:
    """Each side of every material contact: (target slice, source slice, c, the target's and
    the source's radii)."""
    out = []
    for target, seq in scene.operators.items():
        for op in seq:
            if is_contact(scene, target, op):
                out.append((scene.slice(target), scene.slice(op.source), float(op.coeff.c),
                            np.asarray(scene.groups[target].r, float),
                            np.asarray(scene.groups[op.source].r, float)))
    return tuple(out)


def _contact_pairs(prob: "_Problem", p: np.ndarray, slack: float = 0.0):
    """Every pair of two parts in contact at ``p``, (i, j, c, R²) as a binding's: closer than
    the sum of their radii R (× (1 + ``slack``): a tangent also takes the pairs that just
    touch, whose force is zero and whose stiffness 2·c·m along the line of centres is not).
    In contact, Eq. 10 is Eq. 12 with L0 = R; beyond R a pair has no force and is left out."""
    from rackstress.lib.cells import touching_pairs

    I, J, C, Q = [], [], [], []
    for st, ss, c, rt, rs in prob.contact:
        i, j, R2 = touching_pairs(p[st], p[ss], rt, rs, slack)
        I.append(i + st.start)
        J.append(j + ss.start)
        C.append(np.full(len(i), c))
        Q.append(R2)
    return (np.concatenate(I), np.concatenate(J), np.concatenate(C), np.concatenate(Q))


def _pairs_at(prob: "_Problem", p: np.ndarray, slack: float = 0.0):
    """The bindings' pairs and, with contact, the pairs in contact — the active set while the
    solver holds one (:attr:`_Problem.active`), else those at ``p`` (:func:`_contact_pairs`)
    — as one list of bindings (forces, tangent)."""
    if not prob.contact:
        return prob.pairs
    extra = prob.active if prob.active is not None else _contact_pairs(prob, p, slack)
    return tuple(np.concatenate([a, b]) for a, b in zip(prob.pairs, extra))


def _update_contacts(prob: "_Problem", p: np.ndarray) -> bool:
    """The active set taken anew at ``p``: the pairs closer than R (those of the old set
    pulled apart leave, new ones pressed together join; a pair exactly at R, at zero force,
    stays as it was). Returns whether the set changed."""
    new = _contact_pairs(prob, p)
    old = prob.active
    if old is not None:
        d = p[old[1]] - p[old[0]]
        at = np.abs(np.einsum("ij,ij->i", d, d) - old[3]) <= 1e-12 * old[3]
        if at.any():                       # touching, no force: neither in nor out
            keep = {(int(i), int(j)) for i, j in zip(new[0], new[1])}
            add = [k for k in np.flatnonzero(at)
                   if (int(old[0][k]), int(old[1][k])) not in keep]
            if add:
                new = tuple(np.concatenate([a, b[add]]) for a, b in zip(new, old))
    changed = old is None or len(old[0]) != len(new[0]) or not np.array_equal(
        np.sort(old[0].astype(np.int64) * prob.n + old[1]),
        np.sort(new[0].astype(np.int64) * prob.n + new[1]))
    prob.active = new
    return changed


def contact_energy(prob: "_Problem", p: np.ndarray) -> float:
    """The contacts' potential at ``p``: per pair in contact m·c·((d² − R²)/2 − R²·ln(d/R))
    (Eq. 10's, zero at d = R; each pair listed from both ends, so halved) — the active set's
    pairs, two-sided, while the solver holds one."""
    if not prob.contact:
        return 0.0
    I, J, C, Q = prob.active if prob.active is not None else _contact_pairs(prob, p)
    d2 = np.einsum("ij,ij->i", p[J] - p[I], p[J] - p[I])
    with np.errstate(divide="ignore", invalid="ignore"):
        e = prob.m[I] * C * (0.5 * (d2 - Q) - 0.5 * Q * np.log(d2 / Q))
    return float(0.5 * np.sum(e))


def forces(scene, p: np.ndarray, pairs, F_ext: np.ndarray, m: np.ndarray,
           indenter=None) -> np.ndarray:
    """m·a(p): the bindings' force (Eq. 12) and the material parts' volumetric term
    (:func:`volume_force`) plus the external loads and the indenters' push (``indenter``:
    :class:`rackstress.engines.indenter.Indenters`, its held set while the solver holds one),
    n×3."""
    I, J, C, Q = pairs
    a = Bind.accel(p[I], p[J], C, Q)
    out = np.zeros_like(p)
    for k in range(3):
        out[:, k] = np.bincount(I, weights=a[:, k] * m[I], minlength=len(p))
    out = out + volume_force(volume_terms(scene), p, m) + F_ext
    if indenter is not None:
        out = out + indenter.force(p)
    return out


# ------------------------------------------------------------------ the volumetric term
def energy_change(prob: "_Problem", p: np.ndarray, trial: np.ndarray) -> float:
    """Π(trial) − Π(p): the change of the potential whose gradient is −m·a (module doc), per
    pair m·c·(Δ(r²)/2 − L0²·ln(r₁/r₀)) (Eq. 12's; each pair listed from both ends), the
    volumetric term's ½·m·κ·θ², minus the external forces' work. Taken as differences per
    pair, not as Π(trial) − Π(p): near equilibrium Π is many orders above its change. Still
    rounding-limited there, which is why :func:`solve` trusts it only within ρ ∈ [½, 2]."""
    I, J, C, Q = prob.pairs
    d0, d1 = p[J] - p[I], trial[J] - trial[I]
    r0, r1 = np.einsum("ij,ij->i", d0, d0), np.einsum("ij,ij->i", d1, d1)
    with np.errstate(divide="ignore", invalid="ignore"):
        bind = 0.5 * np.sum(prob.m[I] * C * (0.5 * (r1 - r0) - 0.5 * Q * np.log(r1 / r0)))
    out = float(bind) - float(np.sum(prob.F_ext * (trial - p)))
    if prob.contact:
        out += contact_energy(prob, trial) - contact_energy(prob, p)
    if prob.indenter is not None:
        out += prob.indenter.energy(trial) - prob.indenter.energy(p)
    vol = prob.volume
    if vol is not None:
        m = prob.m[vol.owner]
        out += float(np.sum(m * (Volume.term_energies(trial, vol) - Volume.term_energies(p, vol))))
    return out if np.isfinite(out) else float("inf")


def volume_force(vol, p: np.ndarray, m: np.ndarray):
    """m·a of the volumetric term (:meth:`rackstress.model.volume.Volume.accel`), or 0 when
    the scene has none (``vol`` None: no material part)."""
    if vol is None:
        return 0.0
    return m[:, None] * Volume.accel(p, vol)


def volume_stiffness(vol, p: np.ndarray, m: np.ndarray):
    """Its K = −∂(m·a)/∂p = m·∂²(U/m)/∂p² (3n × 3n, CSR, symmetric: a part's particles have
    one mass; :meth:`rackstress.model.volume.Volume.hessian`)."""
    import scipy.sparse as sp

    return (sp.diags(np.repeat(m, 3)) @ Volume.hessian(p, vol)).tocsr()


def summed(*mats):
    """The sum of sparse matrices (CSR) as one set of triplets: SciPy's ``+`` drops the
    entries that sum to zero, and a binding along an axis has zero cross terms at rest, so a
    first tangent summed so lacked entries the later ones have and the factorization's
    analysis was redone (~5 s at 93,236 particles) instead of refactorizing on it."""
    import scipy.sparse as sp

    cs = [m.tocoo() for m in mats]
    return sp.csr_matrix((np.concatenate([c.data for c in cs]),
                          (np.concatenate([c.row for c in cs]),
                           np.concatenate([c.col for c in cs]))), shape=mats[0].shape)


def stiffness(p: np.ndarray, pairs, m: np.ndarray, volume=None):
    """K = −∂(m·a)/∂p of the bindings (3n×3n, CSR): Eq. 12 linearized (Bind.jacobian), and of
    the volumetric term ``volume`` (:func:`volume_stiffness`) when there is one."""
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
    K = sp.csr_matrix((vals, (rows, cols)), shape=(3 * n, 3 * n))
    return K if volume is None else summed(K, volume_stiffness(volume, p, m))


def rigid_modes(p: np.ndarray, free) -> np.ndarray:
    """The six rigid-body modes (3 translations, 3 rotations) on the free unknowns (``free``:
    their boolean mask, or the supports' :class:`~rackstress.model.constraints.ConstraintMap`):
    the near-null space smoothed aggregation needs for elasticity."""
    n = len(p)
    c = p - p.mean(axis=0)
    B = np.zeros((3 * n, 6))
    for k in range(3):
        B[k::3, k] = 1.0
    B[1::3, 3], B[2::3, 3] = -c[:, 2], c[:, 1]
    B[0::3, 4], B[2::3, 4] = c[:, 2], -c[:, 0]
    B[0::3, 5], B[1::3, 5] = -c[:, 1], c[:, 0]
    return free.modes(B) if hasattr(free, "modes") else B[free]


#: the tangent carries μ·L (docs/calibration.md "Static analysis"): L is the bindings' graph
#: Laplacian, each binding a spring c·m in every direction, so μ·L resists only relative motion
#: of bound particles. A mode of K with no stiffness at rest (a wall one particle thick, bent
#: across itself) then follows its neighbours (L·Δx = 0 there: the harmonic interpolation of
#: the thick parts bounding it, whatever μ) instead of staying where it was; the forces are
#: Eq. 12's own, so the equilibrium found is the lattice's whatever μ. μ starts at this value,
#: rises (×100) when a step is not taken and falls (÷10) with each step taken: Levenberg–
#: Marquardt, the step shortened only in the soft modes (a membrane's w³ stiffness, a buckling
#: wall)
REGULARIZATION = 1e-10
#: μ's growth on a step not taken, its fall on one taken, its ceiling (then the step is halved
#: instead, as a line search)
MU_UP, MU_DOWN, MU_MAX = 100.0, 10.0, 1e-2
#: a step that raises the unbalanced force is still taken where the energy changed as the
#: tangent predicts within this factor (ρ = ΔΠ / (−½·b·Δx) in [½, 2]); further out ρ is the
#: rounding of a tiny ΔΠ near equilibrium, not progress
MODEL_AGREEMENT = 0.5
#: steps at μ's ceiling that do not halve the unbalanced force before the solve starts again
#: with ε·diag(K) and plain Newton steps
STALL = 2
#: ε·diag(K) beside μ·L: an anchor, so that a rigid motion the supports leave free (refused
#: by check_part before any step) cannot make the tangent singular
ANCHOR = 1e-14
#: a trial step may leave up to this many times the unbalanced force it started from (a full
#: Newton step from the undeformed state under a large load overshoots before it settles)
GROWTH = 4.0
#: within this many times the tolerance of settling, a step reuses the last tangent (a chord
#: step: the tangent moves with the displacement, and what is left to move is that small; a
#: third tangent of the 125 mm bar with the volumetric term at 0.5 mm cost 3.8 s of its 25
#: of CPU, where the chord step takes it from 1.07e-6 of the load to 3.8e-8 in 1.0 s; at
#: 10 × instead, the corpus' fixed jaw, shoulder bracket and wrist housing took one or two
#: steps fewer and as long or longer, 3.51 / 2.82 / 1.88 s against 3.41 / 1.89 / 1.63 s,
#: by hand). Not with contact or an indenter, whose
#: tangent changes with their sets; a chord step that does not lower the unbalanced force is
#: solved again on a new tangent, as any step, and one that raises the largest turns chord
#: steps off for the rest of the solve (:func:`solve`)
CHORD_BELOW = 100.0
#: a contact pair within (1 + this) × the sum of the radii is in the tangent (just touching:
#: no force yet, but its stiffness along the line of centres)
CONTACT_SLACK = 1e-6
#: contact: the active set is taken anew once Newton's method on it has brought the largest
#: unbalanced force to this fraction of the load (or to settling, if tighter): the pairs' side
#: of R is sure by then, and the next set's steps start from near its answer
CONTACT_SET_TOLERANCE = 1e-4
#: contact: active sets taken at most (then the solve goes on with the last, and reports if
#: it does not settle)
MAX_CONTACT_SETS = 20
#: settle the near-mechanisms on their own between Newton steps (:func:`_relax`); False: the
#: global steps alone, as before it (to compare the two)
RELAX = True
#: particles solved together at most in one local system (a dense one: its clusters batched up
#: to this size; a wall one particle thick larger than this is left to the global steps)
RELAX_MAX_PARTICLES = 400
#: local Newton steps at most per relaxation, and halvings of each
RELAX_STEPS, RELAX_HALVINGS = 20, 12
#: a relaxation stops when its particles' largest unbalanced force is this fraction of the
#: largest over the part (or a hundredth of what settling allows)
RELAX_GOAL = 1e-3
#: what check_part found per scene (by id, dropped with the scene): warnings, first step
_CHECKS: dict = {}


@dataclass
class _Problem:
    """What every Newton step needs: the scene's arrays, once."""

    n: int
    o: np.ndarray
    m: np.ndarray
    fixed: np.ndarray          # n×3: held directions (supports, prescribed displacements)
    free: np.ndarray           # 3n: the unknowns (the held directions' complement)
    pairs: tuple
    F_ext: np.ndarray
    load: float
    #: the supports as u = T·q + prescribed (model/constraints.py): T selects ``free`` where
    #: only axes are fixed; rollers on any face, symmetry planes and pins make it a map
    cmap: object = None
    #: the material parts' volumetric term (model/volume.py), None without one
    volume: object = None
    #: the bindings' Laplacian on the free unknowns (:func:`_spread`), built on first use
    spread: object = None
    #: the material contacts (:func:`material_contacts`): their pairs change with p
    contact: tuple = ()
    #: the pairs in contact held as two-sided bindings (i, j, c, R²) while Newton converges
    #: (:func:`_update_contacts`); None: the pairs closer than R at each state
    active: tuple | None = None
    #: the indenters (``[[indenter]]``: engines/indenter.py), None without one
    indenter: object = None
    #: with a volumetric term, the last tangent's bindings alone (and R), made when called:
    #: what the direct solver factorizes, the preconditioner of conjugate gradients on the
    #: whole tangent (_Linear)
    split: object = None
    #: the direct solver refused this problem for its size (_Linear): AMG-CG from then on
    direct_refused: bool = False
    #: the bindings' factor preconditioned the whole tangent too slowly (_Linear.SPLIT_SWITCH):
    #: the whole tangent factorized from then on
    split_slow: bool = False
    #: ... or the direct solver's plan for the whole did not fit: not analysed again
    whole_refused: bool = False
    #: AMG-CG did not converge within linear.AMG_PATIENCE steps: the direct solver's plans are
    #: made with linear.DIRECT_FLOPS_FALLBACK from then on (True), or that did not fit (None:
    #: AMG-CG to the end)
    amg_stalled: bool | None = False


def _problem(scene) -> _Problem:
    from rackstress.model.constraints import ConstraintMap

    o = scene.original_positions()
    fixed = scene.fixed()
    F = external_forces(scene)
    return _Problem(len(o), o, scene.masses(), fixed, ~fixed.reshape(-1), _bind_pairs(scene),
                    F, float(np.linalg.norm(F, axis=1).sum()), ConstraintMap.of_scene(scene),
                    volume_terms(scene), contact=material_contacts(scene),
                    indenter=_indenters(scene))


def _indenters(scene):
    """The scene's rigid spheres (``Indent`` operators) as engines/indenter.py's Indenters, or
    None without one."""
    from rackstress.engines.indenter import Indenters, indents

    return Indenters(scene) if next(indents(scene), None) is not None else None


def _spread(prob: _Problem):
    """L on the free unknowns: Σ over bindings of c·m·(e_i − e_j)(e_i − e_j)ᵀ ⊗ I₃ (the graph
    Laplacian of the bindings, isotropic), once per problem."""
    import scipy.sparse as sp

    if prob.spread is None:
        I, J, C, _ = prob.pairs
        n = prob.n
        w = 0.5 * C * prob.m[I]                 # each pair is listed from both ends
        k = np.arange(3)
        ri, rj = (3 * I[:, None] + k).ravel(), (3 * J[:, None] + k).ravel()
        ww = np.repeat(w, 3)
        L = sp.csr_matrix((np.concatenate([ww, -ww, ww, -ww]),
                           (np.concatenate([ri, ri, rj, rj]), np.concatenate([ri, rj, rj, ri]))),
                          shape=(3 * n, 3 * n))
        prob.spread = prob.cmap.reduce(L).tocsr()
    return prob.spread


def _tangent(p: np.ndarray, prob: _Problem, mu: float = REGULARIZATION, spread: bool = True):
    """K on the free unknowns at ``p`` plus the regularization R = μ·L + ε·diag(K)
    (:data:`REGULARIZATION`, :data:`ANCHOR`), or μ·diag(K) (``spread`` False: Marquardt's,
    after μ·L stalled); returns K + R and R."""
    import scipy.sparse as sp

    Kb = stiffness(p, _pairs_at(prob, p, slack=CONTACT_SLACK), prob.m)
    if prob.indenter is not None:             # the spheres' penalty, block diagonal
        Kb = summed(Kb, prob.indenter.stiffness(p))
    K = Kb if prob.volume is None else (Kb + volume_stiffness(prob.volume, p, prob.m)).tocsr()
    K = prob.cmap.reduce(K).tocsr()
    d = K.diagonal()
    pos = d[d > 0]
    floor = 1e-3 * float(pos.mean()) if len(pos) else 1.0
    D = sp.diags(np.maximum(d, floor))
    R = (mu * _spread(prob) + ANCHOR * D if spread else mu * D).tocsr()
    if prob.volume is not None:
        # the whole tangent only multiplies (conjugate gradients, _Linear); what is
        # factorized is the bindings' alone, made when a factorization is
        prob.split = lambda: summed(prob.cmap.reduce(Kb).tocsr(), R)
        return (K + R).tocsr(), R
    # K + R as a sum of triplets: SciPy's sparse addition drops the entries that are zero,
    # and a binding along an axis has zero cross terms at rest, so the first tangent's pattern
    # lacked entries the later ones have: the factorization's analysis was redone (~5 s at
    # 93,236 particles) instead of refactorizing on it
    prob.split = None
    return summed(K, R), R


def _relaxed_sets(scene, prob: _Problem, membrane: np.ndarray) -> list:
    """The particles :func:`_relax` settles: those lacking a direction at rest (``membrane``,
    :func:`check_part`) that no support or constraint holds, their clusters (bound to each
    other) batched into sets of at most :data:`RELAX_MAX_PARTICLES`, each sorted."""
    from rackstress.engines import mechanisms as mech

    idx = np.asarray(membrane, np.int64)
    if not len(idx):
        return []
    held = prob.fixed.any(axis=1).copy()
    cm = prob.cmap
    held[np.asarray(list(cm.bases), np.int64)] = True
    held[np.asarray(cm.ring_particles, np.int64)] = True
    idx = idx[~held[idx]]
    sets, batch = [], []
    for c in sorted(mech.clusters(scene, idx, prob.pairs[0], prob.pairs[1]), key=len):
        if len(c) > RELAX_MAX_PARTICLES:
            break
        if sum(map(len, batch)) + len(c) > RELAX_MAX_PARTICLES:
            sets.append(np.sort(np.concatenate(batch)))
            batch = []
        batch.append(c)
    if batch:
        sets.append(np.sort(np.concatenate(batch)))
    return sets


def _volume_near(vol, mark: np.ndarray):
    """The volumetric terms that pull on the particles ``mark``ed (those reading a pair with
    an end there), with every pair they read: their force and stiffness on those particles
    are the whole term's."""
    import scipy.sparse as sp

    from rackstress.model.volume import VolumeTerms

    if vol is None:
        return None
    C = sp.csr_matrix(vol.C)
    touch = (mark[vol.i] | mark[vol.j]).astype(float)
    terms = np.flatnonzero(abs(C) @ touch)
    if not len(terms):
        return None
    Ct = C[terms]
    read = np.unique(Ct.indices)
    return VolumeTerms(vol.i[read], vol.j[read], vol.L[read], vol.owner[terms],
                       vol.kappa[terms], Ct[:, read].tocsr(), vol.n)


def _relax_goal(unbalanced: np.ndarray, allowed: float) -> float:
    """Where :func:`_relax` stops: :data:`RELAX_GOAL` of the largest unbalanced force
    (``unbalanced``, n×3), at least a hundredth of ``allowed`` (what settling allows)."""
    return max(RELAX_GOAL * float(np.linalg.norm(unbalanced, axis=1).max()), 1e-2 * allowed)


def _relax(prob: _Problem, p: np.ndarray, sets: list, goal: float) -> tuple[np.ndarray, int,
                                                                             bool]:
    """``p`` with the particles of each of ``sets`` moved to their own equilibrium, every
    other particle held where it is (Newton's method on their few unknowns, dense, each step
    halved until their unbalanced force falls). Returns the new positions, the local steps and
    whether every set's largest unbalanced force came down to ``goal``.

    Why: a particle lacking a direction at rest (a strut one particle wide: its bindings along
    the strut and one diagonal line) is held across it only by its bindings' tension, ~strain
    × their stiffness, which the step itself changes by as much: the global Newton step moves
    it far outside the region where the tangent predicts its force, and the whole part's
    residual then falls ~4× a step, or oscillates (so100-upper-arm: 11 steps, the largest
    forces on a five-particle strut from the 3rd on; K exact, its solve exact to 1e-13, μ·L
    taking 1e-6 of the load). Settled on their own they are eliminated from the nonlinear
    problem (nonlinear elimination): what the global steps see is the stiff part, where
    Newton's method converges quadratically (the upper arm: 2 steps, the wrist 4 instead of 13).
    The forces are Eq. 12's own, so the equilibrium is the one the global steps seek; where
    the strut's own position is not determined within the tolerance (its stiffness across it
    is that small), this takes the one in line with its neighbours."""
    pairs = _pairs_at(prob, p)
    steps, reached = 0, True
    for cl in sets:
        p, k, done = _relax_set(prob, p, cl, pairs, goal)
        steps += k
        reached = reached and done
    return p, steps, reached


def _relax_set(prob: _Problem, p: np.ndarray, cl: np.ndarray, pairs, goal: float):
    """One set of :func:`_relax` (``cl``, sorted; ``pairs`` the bindings at ``p``)."""
    m = prob.m
    mark = np.zeros(prob.n, bool)
    mark[cl] = True
    k = np.flatnonzero(mark[pairs[0]])
    i, j, c, q = (a[k] for a in pairs)
    li = np.searchsorted(cl, i)
    inside = mark[j]
    lj = np.searchsorted(cl, j[inside])
    vol = _volume_near(prob.volume, mark)
    nc = len(cl)
    dofs = (3 * cl[:, None] + np.arange(3)).ravel()

    def force(x):
        a = Bind.accel(x[i], x[j], c, q) * m[i][:, None]
        f = np.stack([np.bincount(li, weights=a[:, d], minlength=nc) for d in range(3)], 1)
        f += prob.F_ext[cl]
        if vol is not None:
            f += volume_force(vol, x, m)[cl]
        return f

    def tangent(x):
        B, _ = Bind.jacobian(x[j] - x[i], c, q)
        B = B * m[i][:, None, None]
        K = np.zeros((nc, 3, nc, 3))
        D = np.zeros((nc, 3, 3))
        np.add.at(D, li, B)
        K[np.arange(nc), :, np.arange(nc), :] = D
        np.add.at(K, (li[inside], slice(None), lj, slice(None)), -B[inside])
        K = K.reshape(3 * nc, 3 * nc)
        if vol is not None:
            K += volume_stiffness(vol, x, m)[dofs][:, dofs].toarray()
        return K

    blocks = _components(nc, li[inside], lj, vol, cl)
    f = force(p)
    r = float(np.linalg.norm(f))
    steps = 0
    for _ in range(RELAX_STEPS):
        if not np.isfinite(r) or float(np.linalg.norm(f, axis=1).max()) <= goal:
            break
        K = tangent(p)
        dx = _blockwise_lstsq(0.5 * (K + K.T), f.ravel(), blocks)
        scale, taken = 1.0, False
        for _ in range(RELAX_HALVINGS):
            trial = p.copy()
            trial[cl] += scale * dx
            ft = force(trial)
            rt = float(np.linalg.norm(ft))
            if np.isfinite(rt) and rt < r:
                p, f, r, taken = trial, ft, rt, True
                break
            scale *= 0.5
        steps += 1
        if not taken:
            break
    done = bool(np.isfinite(r) and float(np.linalg.norm(f, axis=1).max()) <= goal)
    return p, steps, done


def _components(nc: int, a: np.ndarray, b: np.ndarray, vol, cl: np.ndarray) -> list:
    """The unknowns of each connected part of a relaxed set (its particles ``0..nc-1`` joined
    by the bindings ``a``–``b`` among them, and by any volumetric term reading two of them):
    the set's local tangent is block-diagonal over them."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    A = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(nc, nc)).tocsr()
    if vol is not None:                        # a term couples every particle it reads
        npair = len(vol.i)
        ends = sp.csr_matrix((np.ones(2 * npair), (np.r_[np.arange(npair), np.arange(npair)],
                                                    np.r_[vol.i, vol.j])), shape=(npair, vol.n))
        T = (abs(sp.csr_matrix(vol.C)) @ ends)[:, cl]
        A = A + (T.T @ T).tocsr()
    k, label = connected_components(A, directed=False)
    order = np.argsort(label, kind="stable")
    cuts = np.flatnonzero(np.diff(label[order])) + 1
    return [(3 * g[:, None] + np.arange(3)).ravel() for g in np.split(order, cuts)]


def _blockwise_lstsq(K: np.ndarray, f: np.ndarray, blocks: list) -> np.ndarray:
    """The least-squares (least-norm) solution of K·x = f for a K block-diagonal over
    ``blocks`` (:func:`_components`): each block's own, as one lstsq over the whole would give,
    at the cost of the blocks (a set of 400 particles, many small clusters: 0.8 s → ms)."""
    x = np.zeros_like(f)
    for d in blocks:
        x[d] = np.linalg.lstsq(K[np.ix_(d, d)], f[d], rcond=None)[0]
    return x.reshape(-1, 3)


class _Linear:
    """The linear solver of one tangent: the direct factorization where it fits
    (:func:`rackstress.engines.linear.plan_direct`), else AMG-CG.

    With a volumetric term the direct solver factorizes the bindings' tangent alone
    (``prob.split``) and conjugate gradients solve the whole with that factor as
    preconditioner, to the inexact Newton step's tolerance: the term couples particles two
    spacings apart, which doubled the thickness of the factorization's separators (the
    125 × 10 × 10 mm bar at 0.5 mm: 3.1× the CPU and 2.6× the memory of the bindings alone,
    ``rackstress bench lattice``); the bindings' tangent is the former lattice's, as stiff in
    shear and differing in the volume by the ratio of the two bulk moduli, so few iterations
    are needed (about ten a Newton step at ν = 0.33)."""

    #: False: AMG-CG whatever the size (``rackstress bench static`` compares the two)
    direct_allowed = True
    #: the most conjugate-gradient steps preconditioned by the bindings' factor
    SPLIT_ITERATIONS = 400
    #: ... a solve that takes more than this many factorizes the whole tangent instead, for the
    #: rest of the static solve, where the direct solver's plan for it fits. The bindings'
    #: factor preconditions a bulk part in a few tens of steps (the test bar at ν = 0 … 0.45:
    #: 7–30 a Newton step, measured while building this); on a part of thin walls the term's
    #: faces are much of its stiffness, and it did not converge in 400 steps on five of six
    #: Newton steps of the SO-100 shoulder bracket (ν = 0.36: 73 s of solve, the whole tangent
    #: factorized 11 s, measured while building this)
    SPLIT_SWITCH = 100
    #: False: the whole tangent factorized (the test of the split compares the two)
    split_allowed = True

    def __init__(self, K, p: np.ndarray, prob: _Problem):
        from rackstress.engines import linear

        t0 = time.process_time()
        self.prob = prob
        self.K = K
        self.split = prob.split is not None and self.split_allowed and not prob.split_slow
        P = prob.split() if self.split else K
        f = None
        if self.direct_allowed and not prob.direct_refused:
            f = linear.plan_direct(P, flops=linear.DIRECT_FLOPS_FALLBACK if prob.amg_stalled
                                   else None)
            # refused for its size: not analysed again at every Newton step of this solve
            prob.direct_refused = f is None
        if f is not None:
            if self.split and hasattr(f, "preconditioner"):
                f.preconditioner()
            self.solver, self.direct = f.factor(), True
        else:
            self.solver = linear.AMG(P, rigid_modes(p, prob.cmap))
            self.direct = False
        self.kind = self.solver.kind + ("-pcg" if self.split and self.direct else "")
        self.setup_s = time.process_time() - t0
        self._converged = True
        #: factorizations (AMG hierarchies) made for this solve so far
        self.count = 1

    def solve(self, b: np.ndarray, rtol: float, K=None) -> np.ndarray:
        if self.direct and not self.split:
            return self.solver.solve(b)
        if self.direct:
            import scipy.sparse.linalg as spla

            A = self.K if K is None else K
            M = spla.LinearOperator(A.shape, matvec=self.solver.solve, dtype=float)
            x, info = spla.cg(A, b, rtol=rtol, maxiter=self.SPLIT_SWITCH, M=M)
            if info != 0 and self._factor_whole(A):
                return self.solver.solve(b)
            if info != 0:
                x, info = spla.cg(A, b, x0=x, rtol=rtol,
                                  maxiter=self.SPLIT_ITERATIONS - self.SPLIT_SWITCH, M=M)
            self._converged = info == 0
            return x
        from rackstress.engines import linear

        A = self.K if K is None else K
        if not (self.direct_allowed and self.prob.amg_stalled is False):
            return self.solver.solve(b, rtol=rtol, K=A)
        x = self.solver.solve(b, rtol=rtol, K=A, maxiter=linear.AMG_PATIENCE)
        if self.solver.converged:
            return x
        # AMG-CG stalls on a part of thin walls: the whole tangent factorized instead, for the
        # rest of this solve, where it fits within DIRECT_FLOPS_FALLBACK
        if self._factor_whole(A, flops=linear.DIRECT_FLOPS_FALLBACK):
            self.prob.amg_stalled, self.prob.direct_refused = True, False
            return self.solver.solve(b)
        self.prob.amg_stalled = None
        return self.solver.solve(b, rtol=rtol, K=A, x0=x)        # AMG-CG goes on

    def _factor_whole(self, A, flops: float | None = None) -> bool:
        """The whole tangent ``A`` factorized in place of the split (:data:`SPLIT_SWITCH`) or
        of AMG-CG that did not converge within :data:`rackstress.engines.linear.AMG_PATIENCE`
        steps (``flops``: :data:`rackstress.engines.linear.DIRECT_FLOPS_FALLBACK`), and for
        the rest of this static solve; False where the direct solver's plan for it does not
        fit (the split, or AMG-CG, goes on)."""
        from rackstress.engines import linear

        if self.prob.whole_refused and flops is None:
            return False
        t0 = time.process_time()
        f = linear.plan_direct(A, flops=flops)
        if f is None:
            self.prob.whole_refused = True      # each Newton step's would be refused too
            self.setup_s += time.process_time() - t0
            return False
        self.solver.free()
        self.solver, self.split, self.K, self.direct = f.factor(), False, A, True
        self.kind, self._converged = self.solver.kind, True
        self.count += 1
        self.prob.split_slow = True
        self.setup_s += time.process_time() - t0
        return True

    @property
    def converged(self) -> bool:
        if self.direct:
            return self._converged
        return self.solver.converged

    def free(self) -> None:
        self.solver.free()


def _refactored(lin: _Linear, K, p: np.ndarray, prob: _Problem) -> _Linear:
    """``lin`` factorizing ``K`` on its own ordering where it can (same pattern: a new
    tangent, or the same one with another μ), else a new solver."""
    if lin.split and lin.converged:
        lin.K = K      # the first bindings' factor (hierarchy) still preconditions the new K
        return lin
    if lin.direct and lin.solver.refactor(K if not lin.split else prob.split()):
        lin.count += 1
        lin.K = K
        return lin
    lin.free()
    new = _Linear(K, p, prob)
    new.count += lin.count
    return new


def _refuse(scene, message: str):
    raise SceneError(f"scene '{scene.name}': the static analysis cannot hold this part: "
                     f"{message}")


def _held_rows(prob: _Problem, idx: np.ndarray):
    """For :func:`rackstress.engines.mechanisms.rigid_modes_left`: where a constraint holds
    part of the body (a pin, a roller off the axes), the rigid modes' rows that it holds —
    (I − T·Tᵀ) of the modes on the body's unknowns (T: the constraint map); None where only
    axes are fixed (the held directions' rows, as ever)."""
    if prob.cmap.trivial:
        return None

    def rows(R: np.ndarray) -> np.ndarray:            # R: (k, 3, 6) over the body
        T = prob.cmap.T
        full = np.zeros((3 * prob.n, R.shape[2]))
        dof = (3 * idx[:, None] + np.arange(3)).ravel()
        full[dof] = R.reshape(-1, R.shape[2])
        held = full - T @ (T.T @ full)
        return held[dof]
    return rows


def _with_constraints(D: np.ndarray, prob: _Problem) -> np.ndarray:
    """Each particle's stiffness block plus the directions a constraint holds it in (a
    roller's normal; every direction of a pinned ring's particles: the ring is rigid), as
    ``local_mechanisms`` adds the fixed axes."""
    cm = prob.cmap
    if cm.trivial:
        return D
    D = D.copy()
    scale = np.maximum(np.trace(D, axis1=1, axis2=2), 1e-300)
    for i, B in cm.bases.items():              # held: the complement of its free directions
        D[i] += scale[i] * (np.eye(3) - B @ B.T)
    for i in cm.ring_particles:
        D[i] += scale[i] * np.eye(3)
    return D


def _check_bodies(scene, prob: _Problem) -> None:
    """Check 1 of :mod:`rackstress.engines.mechanisms`: every body's six rigid-body modes are
    held. Raises SceneError naming the first body that is not, and how many more there are."""
    from rackstress.engines import mechanisms as mech

    # bodies pressed together hold each other (their contact's pairs at the start)
    I, J = _pairs_at(prob, prob.o, slack=CONTACT_SLACK)[:2]
    from rackstress.model.constraints import supported

    count, label = mech.components(prob.n, I, J)
    held = prob.fixed
    held_any = supported(scene)          # a fixed direction, a pin, a roller on any face
    problems = []
    order = np.argsort(label, kind="stable")
    bounds = np.searchsorted(label[order], np.arange(count + 1))
    bound = np.bincount(I, minlength=prob.n) > 0
    for c in range(count):
        idx = order[bounds[c]:bounds[c + 1]]
        if not held_any[idx].any():
            problems.append(f"{mech.where(scene, idx)} are held by no support and bound to "
                            "no particle that is: that body floats away. Add a [[support]] on "
                            "it, or bind it to the held part (bodies of one part must touch, "
                            "not only come close)")
            continue
        if len(idx) == 1 and not bound[idx[0]]:
            if not held[idx[0]].all():
                problems.append(f"{mech.where(scene, idx)} is bound to nothing and held in "
                                "only some directions: it slides freely; hold it in every "
                                "direction or remove it")
            continue
        left = mech.rigid_modes_left(prob.o[idx], held[idx], _held_rows(prob, idx))
        if left:
            mode = left[0]
            ax = np.round(mode["axis"], 4).tolist()
            if mode["kind"] == "translation":
                how = f"slide along {ax}"
            else:
                how = (f"turn about the axis along {ax} through "
                       f"{np.round(mode['point'], 4).tolist()}")
            problems.append(f"{mech.where(scene, idx)} are held so that the whole body can "
                            f"still {how}" + (f" (and {len(left) - 1} more rigid motion(s))"
                                              if len(left) > 1 else "")
                            + ": the supports leave a rigid-body motion free. Hold a region "
                            "that is not on one line (a face, or two bolts apart), or fix the "
                            "direction the rollers leave free somewhere")
    if problems:
        more = f" ({len(problems) - 1} more bod{'y' if len(problems) == 2 else 'ies'} like it)" \
            if len(problems) > 1 else ""
        _refuse(scene, problems[0] + more)


def _check_particles(scene, prob: _Problem) -> tuple[list[dict], np.ndarray]:
    """Check 2: particles lacking a direction. Loaded across it: refused; else one warning
    per group (a membrane: the lattice has no stiffness across a wall one particle thick).
    Returns the warnings and those particles (for :func:`unbalanced_at`)."""
    from rackstress.engines import mechanisms as mech

    I, J, C, _ = prob.pairs
    D = _with_constraints(mech.local_blocks(prob.n, prob.o, I, J, C, prob.m), prob)
    bad, rank, P = mech.local_mechanisms(D, prob.fixed)
    if not len(bad):
        return [], bad
    F = prob.F_ext[bad]
    across = np.linalg.norm(np.einsum("kij,kj->ki", P, F), axis=1)
    loaded = across > 1e-6 * np.maximum(np.linalg.norm(F, axis=1), 1e-300)
    a = scene.groups[scene.group_of(int(bad[0]))[0]].meta.get("spacing")
    finer = f" (spacing ≤ {a / 2:g} puts two across a wall of {a:g})" if a else ""
    if loaded.any():
        idx = bad[loaded]
        what = ("walls one particle thick" if (rank[loaded] == 2).any()
                else "struts one particle wide")
        _refuse(scene, f"{mech.where(scene, idx)} carry a load across a direction in which no "
                       f"binding holds them ({what}: the lattice has no stiffness across "
                       "them). Move the load onto the thick part, or use a finer spacing"
                       + finer)
    out = []
    for name in scene.groups:
        sl = scene.slice(name)
        k = bad[(bad >= sl.start) & (bad < sl.stop)]
        if not len(k):
            continue
        parts = mech.clusters(scene, k, I, J)
        out.append({"kind": "membrane", "groups": [name], "particles": int(len(k)),
                    "message": f"{mech.where(scene, k)} lie in walls one particle thick or "
                               f"struts one particle wide ({len(parts)} place(s), the largest "
                               f"{mech.where(scene, parts[0])}): no binding holds them across, "
                               "so those walls carry load only in their own plane (a "
                               "membrane), their bending is not represented; a finer spacing"
                               + finer + " represents it"})
    return out, bad


def _check_first_step(scene, prob: _Problem, lin: _Linear, dx: np.ndarray, b: np.ndarray,
                      R) -> None:
    """Check 3: the first step's work taken by the regularization R (a loaded mechanism)."""
    from rackstress.engines import mechanisms as mech

    work = abs(float(b @ dx))
    if not (work > 0) or not lin.converged:
        return
    share = abs(float(dx @ (R @ dx))) / work
    if not (share > mech.MECHANISM_SHARE) and np.all(np.isfinite(dx)):
        return
    # the particles it moves: by each one's Σ R_kk·Δx_k², not by μ·L's energy, which a block
    # that slides rigidly holds only in the bindings it slides on
    d = np.maximum(R.diagonal(), 0.0) * dx * dx
    cm = prob.cmap                  # each unknown's share spread on its particles
    per = (cm.expand(d) if cm.trivial else (abs(cm.T) @ d).reshape(-1, 3)).sum(axis=1)
    moving = mech.mechanism_particles(per)
    parts = mech.clusters(scene, moving, prob.pairs[0], prob.pairs[1])
    named = "; ".join(mech.where(scene, c) for c in parts[:mech.NAMED])
    _refuse(scene, f"the load moves {len(moving)} particle(s) that no binding resists (a "
                   f"mechanism: {named}): they are held by fewer bindings than they have "
                   "directions — hinged on one line of particles, a wall one particle thick "
                   "between thicker parts, or bodies that touch along an edge only. Add a "
                   "support there, thicken the wall or use a finer spacing, or join the "
                   "bodies along a face")


def check_part(scene, progress: bool = False) -> list[dict]:
    """Check the part before solving (:mod:`rackstress.engines.mechanisms`): bodies held by
    nothing or left a rigid motion, particles lacking a direction, loaded mechanisms. Raises
    :class:`SceneError` (exit 2) naming the particles, where they are and what to do; returns
    the warnings (walls one particle thick, unloaded). The first Newton step's factorization,
    made here, is kept on ``scene`` for :func:`solve`.

    Example
    -------
    >>> from rackstress.scenes import load                       # doctest: +SKIP
    >>> check_part(load("examples/cantilever/scene.toml"))       # doctest: +SKIP
    []
    """
    cached = _CHECKS.get(id(scene))
    if cached is not None:
        return cached["warnings"]
    t0 = time.perf_counter()
    check_static(scene)
    prob = _problem(scene)
    _check_bodies(scene, prob)
    warnings, membrane = _check_particles(scene, prob)
    p = prob.o + scene.prescribed()
    if prob.indenter is not None:             # the first set: the particles touched at start
        prob.indenter.update(p)
    f = forces(scene, p, _pairs_at(prob, p), prob.F_ext, prob.m, prob.indenter)
    b = prob.cmap.restrict(f)
    first = None
    if b.size and np.any(b != 0):
        K, R = _tangent(p, prob)
        lin = _Linear(K, p, prob)
        dx = lin.solve(b, rtol=1e-10)
        try:
            _check_first_step(scene, prob, lin, dx, b, R)
        except SceneError:
            lin.free()
            raise
        first = (lin, dx)
    _CHECKS[id(scene)] = {"warnings": warnings, "first": first, "membrane": membrane, "prob": prob,
                          "seconds": time.perf_counter() - t0}
    weakref.finalize(scene, release_id, id(scene))
    if progress:
        print(f"static: part checked in {time.perf_counter() - t0:.1f} s", file=sys.stderr,
              flush=True)
    return warnings


def reactions(scene, p: np.ndarray) -> np.ndarray:
    """n×3 force each support applies at ``p`` (zero on free directions): −(the bindings' force
    + the loads) on every held direction, so that with them every particle is balanced."""
    prob = _problem(scene)
    f = forces(scene, p, _pairs_at(prob, p), prob.F_ext, prob.m, prob.indenter)
    return -(f - prob.cmap.unbalanced(f))


def release(scene) -> None:
    """Drop what :func:`check_part` kept on ``scene`` (its first factorization): a rank that
    does not solve, or a caller that will not."""
    release_id(id(scene))


def release_id(key: int) -> None:
    cached = _CHECKS.pop(key, None)
    if cached and cached.get("first"):
        cached["first"][0].free()


def support_reactions(scene, res: StaticResult) -> dict:
    """``summary.json``'s ``reactions`` and ``applied_load`` (scene units): per ``[[support]]``
    (and prescribed displacement, and ``held``) the force its particles' held directions
    apply at the equilibrium and its moment about the origin, with its group and how many
    particles it holds (a particle two supports hold counts for the first); the loads' force
    and moment.
    Equilibrium makes their sums cancel: Σ reactions = −applied load, moments too (the
    bindings' forces are central, so they cancel in pairs, forces and moments)."""
    p, R = res.p, res.reactions
    F = external_forces(scene)
    taken = np.zeros(R.shape, dtype=bool)
    rows = []
    for name, g in scene.groups.items():
        sl = scene.slice(name)
        for label, mask, dirs in g.meta.get("supports", []):
            sel = np.zeros(R.shape, dtype=bool)
            # dirs None: a constraint (pin, roller off the axes): all of its particles' reaction
            sel[sl] = mask[:, None] & (True if dirs is None else dirs[None, :] & g.fixed)
            sel &= ~taken
            taken |= sel
            r = np.where(sel, R, 0.0)
            rows.append({"support": label if len(scene.groups) == 1 else f"{label} ({name})",
                         "group": name, "particles": int(sel.any(axis=1).sum()),
                         "force": r.sum(axis=0).tolist(),
                         "moment": np.cross(p, r).sum(axis=0).tolist()})
    from rackstress.model.constraints import supported

    held = ~taken & (scene.fixed() | supported(scene)[:, None])
    rest = np.where(held, R, 0.0)
    if rest.any():
        groups = [name for name in scene.groups if held[scene.slice(name)].any()]
        rows.append({"support": "held", "group": ", ".join(groups),
                     "particles": int(held.any(axis=1).sum()),
                     "force": rest.sum(axis=0).tolist(),
                     "moment": np.cross(p, rest).sum(axis=0).tolist()})
    out = {"reactions": rows,
           "applied_load": {"force": F.sum(axis=0).tolist(),
                            "moment": np.cross(p, F).sum(axis=0).tolist()}}
    # the rigid spheres' push (``[[indenter]]``): with the loads, what the supports balance
    from rackstress.engines.indenter import indenter_forces

    pushed = indenter_forces(scene, p)
    if pushed:
        out["indenters"] = pushed
    return out


def solve(scene, tolerance: float = TOLERANCE, max_iterations: int = MAX_ITERATIONS,
          progress: bool = False) -> StaticResult:
    """The equilibrium of ``scene`` by Newton's method (module doc), after :func:`check_part`.

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

    Raises
    ------
    SceneError
        What :func:`check_part` refuses: a body held by nothing or free to turn, a load across
        a wall one particle thick, a loaded mechanism.
    """
    t0 = time.perf_counter()
    say = (lambda msg: print(msg, file=sys.stderr, flush=True)) if progress else (lambda msg: None)
    warnings = check_part(scene, progress=progress)
    first = _CHECKS[id(scene)]["first"]
    membrane = _CHECKS[id(scene)]["membrane"]
    prob = _CHECKS[id(scene)]["prob"]
    n, cmap = prob.n, prob.cmap
    p = prob.o + scene.prescribed()
    start = p.copy()
    history = []
    load = prob.load
    it, settled, rel = 0, False, float("inf")
    # only displacements prescribed: the load is the support reactions at the current state,
    # as the engine's own check takes them (engine_residual); the first state's reactions
    # (the displaced face pulled against an undeformed part) were ~10⁴ × the equilibrium's,
    # and a residual "settled" against them failed the engine's check (exit 6)
    by_reactions = load == 0.0
    say(f"static: {n:,} particles, {len(prob.pairs[0]):,} bindings, {cmap.unknowns:,} "
        f"unknowns")
    lin, solver = None, ""
    mu, spread, stalled, least = REGULARIZATION, True, 0, None
    # chord steps while they lower the largest unbalanced force: one that raised it (accepted
    # by the energy's model, rounding-limited there) turns them off, else a chord step and a
    # new tangent's step can undo each other for good (a public string-light bracket at
    # 5.8e-5 ↔ 1.7e-4 of its load for 25 steps)
    chords, chord = True, None
    relaxed = _relaxed_sets(scene, prob, membrane) if RELAX else []

    def unbalanced_of(x: np.ndarray) -> np.ndarray:
        return cmap.unbalanced(forces(scene, x, _pairs_at(prob, x), prob.F_ext, prob.m,
                                      prob.indenter))

    sets = 0                                  # contact: active sets taken (module doc)
    if prob.contact:                          # the first set: the pairs touching at the start
        prob.active = _contact_pairs(prob, p, slack=CONTACT_SLACK)
        sets = 1
    if prob.indenter is not None:             # the particles the spheres touch at the start
        prob.indenter.update(p)
        sets = 1
    try:
        while True:
            f = forces(scene, p, _pairs_at(prob, p), prob.F_ext, prob.m, prob.indenter)
            unbalanced = cmap.unbalanced(f)
            if by_reactions:
                load = float(np.linalg.norm(f - unbalanced, axis=1).sum())
                if prob.indenter is not None:     # the spheres' push is a load too
                    load += _indenter_load(prob, p)
            worst = float(np.linalg.norm(unbalanced, axis=1).max()) if n else 0.0
            new = worst / load if load > 0 else (0.0 if worst == 0 else float("inf"))
            rel = new
            history.append(rel)
            if chord is not None and not rel < chord:
                chords = False
            chord = None
            if np.isfinite(rel) and (least is None or rel < least[0]):
                least = (rel, p)
            say(f"static: iteration {it}, residual {rel:.3g} of the applied load "
                f"({solver or 'start'}; {time.perf_counter() - t0:.1f} s)")
            if not np.isfinite(rel):
                break
            if prob.contact and rel <= max(tolerance, CONTACT_SET_TOLERANCE) \
                    and sets < MAX_CONTACT_SETS:
                # converged on this set (or nearly): take it anew at the state reached
                if _update_contacts(prob, p):
                    sets += 1
                    say(f"static: contact set {sets}: {len(prob.active[0]) // 2:,} pairs")
                    least = None              # another problem: its residuals start anew
                    continue
            if prob.indenter is not None and rel <= max(tolerance, CONTACT_SET_TOLERANCE) \
                    and sets < MAX_CONTACT_SETS and prob.indenter.update(p):
                sets += 1
                say(f"static: indenter set {sets}: {int(prob.indenter.active.sum()):,} "
                    "particles")
                least = None
                continue
            if rel <= tolerance or load == 0.0:
                settled = True
                break
            if it >= max_iterations:
                break
            b = cmap.restrict(f)
            # inexact Newton for AMG-CG: the linear solve need only be as exact as the
            # residual is small (the step leaves rtol·‖b‖ unbalanced: a tenth of what
            # settling allows)
            rtol = min(1e-2, max(1e-10, 0.1 * tolerance / rel))
            if it == 0 and first is not None:
                lin, dx = first
            elif (chords and lin is not None and rel <= CHORD_BELOW * tolerance
                  and not prob.contact and prob.indenter is None):
                K, chord = lin.K, rel         # a chord step (CHORD_BELOW)
                dx = lin.solve(b, rtol, K=K)
            else:
                K, _ = _tangent(p, prob, mu, spread)
                lin = _refactored(lin, K, p, prob) if lin is not None else _Linear(K, p, prob)
                dx = lin.solve(b, rtol, K=K)
            norm0 = float(np.linalg.norm(unbalanced))
            # Levenberg–Marquardt (REGULARIZATION): a step that does not lower the
            # unbalanced force (its 2-norm: the largest alone may rise while a wall catches
            # up with its edges) is solved again with μ ×100, which shortens it in the soft
            # modes only
            accepted, step = None, cmap.expand(dx)
            while spread:
                trial = p + step
                u2 = unbalanced_of(trial)
                r2 = float(np.linalg.norm(u2))
                if relaxed and np.isfinite(r2) and not r2 < norm0:
                    # judged again with the near-mechanisms settled (_relax): the step's
                    # linear motion of a strut or membrane may be far outside its tangent's
                    # reach (the SO-100 base at 93,236 particles, 3.3e-6 of the load: the full
                    # step raised the unbalanced force 850×, and two more factorizations
                    # shortened it; relaxed, it is 1e-8). Only then: where the plain step is
                    # taken, relaxing first slowed others (the fixed jaw: 4 → 20 steps)
                    settled_trial = _relax(prob, trial, relaxed,
                                           _relax_goal(u2, tolerance * load))[0]
                    rs = float(np.linalg.norm(unbalanced_of(settled_trial)))
                    if np.isfinite(rs) and rs < r2:
                        trial, r2 = settled_trial, rs
                if np.isfinite(r2) and r2 < norm0:
                    accepted = trial
                    break
                # or the energy fell as the tangent's quadratic model predicts (−½·b·Δx): a
                # sound Newton step whose residual rose where the model is least exact
                rho = energy_change(prob, p, trial) / (-0.5 * float(b @ dx))
                if MODEL_AGREEMENT <= rho <= 1.0 / MODEL_AGREEMENT:
                    accepted = trial
                    break
                if mu >= MU_MAX:
                    break
                mu = min(mu * MU_UP, MU_MAX)
                K, _ = _tangent(p, prob, mu, spread)
                lin = _refactored(lin, K, p, prob)
                dx = lin.solve(b, rtol, K=K)
                step = cmap.expand(dx)
            solver = lin.kind if lin.converged else lin.kind + " (not converged)"
            if accepted is not None:
                p = accepted
                stalled = stalled + 1 if mu > 0.5 * MU_MAX / MU_DOWN and r2 > 0.5 * norm0 else 0
                mu = max(mu / MU_DOWN, REGULARIZATION)
            else:
                # μ at its ceiling: the step is halved (large rotations, buckling); a trial may
                # leave up to GROWTH × the unbalanced force it started from, the best is kept
                scale, best = 1.0, None
                for _ in range(10):
                    trial = p + scale * step
                    r = float(np.linalg.norm(unbalanced_of(trial), axis=1).max())
                    if np.isfinite(r) and (best is None or r < best[0]):
                        best = (r, trial)
                    if np.isfinite(r) and r <= GROWTH * worst:
                        break
                    scale *= 0.5
                p = best[1] if best is not None else trial
                stalled += 1
            if relaxed:
                # the near-mechanisms settled on their own (_relax), kept where that does
                # not raise the unbalanced force (its 2-norm, as the steps'), or, where they
                # all settled, raises it less than GROWTH times (their neighbours take what
                # they no longer push: the next step's to remove)
                u0 = unbalanced_of(p)
                before = float(np.linalg.norm(u0))
                q, k, reached = _relax(prob, p, relaxed, _relax_goal(u0, tolerance * load))
                after = float(np.linalg.norm(unbalanced_of(q))) if k else before
                if k and (after <= before or reached and after <= GROWTH * before):
                    p = q
            if spread and stalled >= STALL:
                # μ·L stalled (a wall buckling under it): from the start again with ε·diag(K)
                # and full Newton steps, halved only where the unbalanced force grows more
                # than GROWTH times (what settled the wrist housing of examples/parts)
                spread, mu, stalled, p = False, REGULARIZATION, 0, start.copy()
                if prob.contact:
                    prob.active = _contact_pairs(prob, p, slack=CONTACT_SLACK)
                if prob.indenter is not None:
                    prob.indenter.update(p)
                say("static: the Levenberg–Marquardt steps stalled; from the start again "
                    "with plain Newton steps")
            it += 1
    finally:
        if lin is not None:
            lin.free()
        _CHECKS.pop(id(scene), None)
        prob.active = None                    # what follows sees the true one-sided contact
        if prob.indenter is not None:
            prob.indenter.active = None
    if settled and (prob.contact or prob.indenter is not None):
        # the last set is the one-sided contact's at p (it did not change), unless the sets
        # ran out: then the true contact decides
        f = forces(scene, p, _pairs_at(prob, p), prob.F_ext, prob.m, prob.indenter)
        true = float(np.linalg.norm(cmap.unbalanced(f), axis=1).max()) / load if load else 0.0
        if true > tolerance:
            settled, rel = False, true
            history.append(rel)
    if not settled and least is not None and least[0] < rel:
        # a solve that did not settle ends on the least unbalanced state it passed (the
        # restart after a stall may end worse than where μ·L stalled)
        rel, p = least
    if not settled and prob.contact:
        _check_separation(scene, prob, p)
    f = forces(scene, p, _pairs_at(prob, p), prob.F_ext, prob.m, prob.indenter)
    return StaticResult(p, settled, it, rel, load, history, time.perf_counter() - t0,
                        reactions=-(f - cmap.unbalanced(f)), solver=lin.kind if lin else "",
                        factorizations=lin.count if lin else 0, warnings=warnings,
                        contact_sets=sets, unbalanced=None if settled else unbalanced_at(
                            scene, prob, cmap.unbalanced(f), load, membrane))


def _indenter_load(prob: _Problem, p: np.ndarray) -> float:
    """The spheres' push at ``p``, Σ‖f_i‖: the load of a scene the indenters alone press (as
    :func:`engine_residual` takes it)."""
    return float(np.linalg.norm(prob.indenter.force(p), axis=1).sum())


def _check_separation(scene, prob: _Problem, p: np.ndarray) -> None:
    """An unsettled solve with contact: if two parts in contact no longer touch anywhere, the
    load pulls one off the other (contact pushes, it does not pull) and nothing else holds
    it: refused, naming them (exit 2), not reported as a state that did not settle."""
    from scipy.spatial import cKDTree

    names = list(scene.groups)
    starts = [scene.slice(n).start for n in names]
    for st, ss, c, rt, rs in prob.contact:
        reach = float(rt.max() + rs.max())
        d, _ = cKDTree(p[ss]).query(p[st], k=1)
        if np.all(d > reach):
            a = names[starts.index(st.start)]
            b = names[starts.index(ss.start)]
            gap = float(d.min() - reach)
            _refuse(scene, f"'{a}' and '{b}' separate: the load pulls them apart and contact "
                           f"pushes, it does not pull (their nearest particles end {gap:.3g} "
                           "further apart than touching), so nothing holds the part it pulls "
                           "off. Support that part, reverse the load, or bind the two parts "
                           "(one group) if they are joined")


#: the particles :func:`unbalanced_at` looks at: the largest unbalanced forces
WORST = 20


def unbalanced_at(scene, prob: _Problem, unbalanced: np.ndarray, load: float,
                  membrane: np.ndarray) -> dict:
    """Where a solve that did not settle leaves its largest unbalanced forces: the worst
    particle (index, position as drawn, its force over the load) and how many of the
    :data:`WORST` largest lie in walls one particle thick or next to them (``membrane``, from
    :func:`check_part`). Such a wall has no stiffness across itself at rest, only what its
    stretching gives it, which grows with its deflection and turns negative under compression
    (it buckles): Newton's method settles it slowly or not at all (docs/calibration.md
    "Static analysis"), and a finer spacing, which puts two particles across it, is the cure."""
    r = np.linalg.norm(unbalanced, axis=1)
    if not len(r) or not np.isfinite(r).all():
        return {}
    worst = np.argsort(-r)[:WORST]
    worst = worst[r[worst] >= 0.01 * r[worst[0]]]          # the forces that matter
    near = np.zeros(prob.n, bool)
    near[np.asarray(membrane, np.int64)] = True
    I, J = prob.pairs[0], prob.pairs[1]
    ring = near.copy()
    ring[J[near[I]]] = True
    ring[I[near[J]]] = True
    i = int(worst[0])
    group = scene.group_of(i)[0]
    return {"particle": i, "group": group,
            "position": [float(x) for x in prob.o[i]],
            "force": float(r[i] / load) if load > 0 else float(r[i]),
            "worst": int(len(worst)), "in_thin_walls": int(ring[worst].sum()),
            "spacing": scene.groups[group].meta.get("spacing")}


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
    vol = volume_terms(scene)
    if vol is not None:       # a pair's stiffness in the terms: Σ|Cᵀ·diag(κ)·C| along its row
        import scipy.sparse as sp

        A = abs(vol.C.T @ sp.diags(vol.kappa) @ vol.C)
        w = np.asarray(A.sum(axis=1)).ravel()
        per = per + m * (np.bincount(vol.i, weights=w, minlength=len(p))
                         + np.bincount(vol.j, weights=w, minlength=len(p)))
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
