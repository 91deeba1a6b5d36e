"""The linear stability limit of Eq. 5 for a scene, and the run-time check that uses it.

Eq. 5 (``v += t·a; p += t·v``, semi-implicit Euler) applied to a damped oscillator
``x'' = −λ·x − γ·x'`` gives the amplification matrix
``[[1 − λt², t(1 − γt)], [−λt, 1 − γt]]`` with trace ``2 − γt − λt²`` and determinant
``1 − γt``. Its eigenvalues stay inside the unit circle (Jury's test) iff

    0 ≤ γt < 2   and   λt² < 4 − 2γt,     i.e.   t < t_max(λ, γ) = 4 / (γ + √(γ² + 4λ)),

which is ``2/ω`` without damping (λ = ω²) and tends to ``2/γ`` for strong damping. A scene is
linearized about its initial positions: ``a ≈ −K·x − Γ·v`` with K the (3N × 3N, generally
non-symmetric, because coefficients are directed) Jacobian of the pair operators and Γ the
per-particle damping. Each pair (p ← u) contributes the block

* ``bind`` (Eq. 12), d = ‖u − p‖, L0 its original length:
  ``B = c·[(1 − L0²/d²)·(I − nnᵀ) + (1 + L0²/d²)·nnᵀ]`` (``2c·nnᵀ`` at rest, norm c(1 + L0²/d²));
* ``collide`` (Eq. 10) the same with L0 → R (sum of the radii) for pairs already overlapping
  (d < R, stiffer the deeper: c(1 + R²/d²)); pairs within ``CONTACT_MARGIN``·R of touching count
  as contacts at d = R (``2c·nnᵀ``). A collide whose groups are nowhere near touching at the
  start (two blobs pushed together) is given *virtual contacts* with ``2c·nnᵀ``: every target
  particle is paired with the source particles it would meet first coming straight at them
  (those within (``CONTACT_MARGIN`` − 1)·R of its nearest source distance: one partner for
  aligned lattices, a few for staggered ones);
* ``attract`` (Eq. 14): ``B = (c/d)·(I − nnᵀ)`` with d the current distance;

at K[p, p] += B and K[p, u] −= B. Damping Γ is per particle: the group's dampen coefficients,
with a conditional ``extra`` included whenever its phase conditions can hold (contact assumed).
Operators are evaluated per distinct phase of the schedule (phase conditions decide which are
active) and the smallest limit is kept.

Two estimates of ω² = λ_max come out:

* ``t_max_gershgorin``, per particle from the Gershgorin row sum ‖K_pp‖ + Σ_u ‖K_pu‖ ≤ 2·Σ‖B‖
  and the particle's own γ: a cheap bound on the linearization (up to 2× pessimistic in ω² for
  one-way couplings), which names the limiting particle and operator row by row;
* ``t_max`` (the prediction used by :func:`check_dt`), from the actual spectrum: the largest
  eigenvalues of K (scipy ARPACK on the sparse matrix; dense for small scenes), each with the
  damping its eigenvector sees (Rayleigh quotient of Γ), and of each group's own principal block
  with the group's damping (so a strongly damped group is judged with its own γ).

For a scene with ``integrator = "verlet"`` (:mod:`rackstress.model.verlet`) the same spectrum
is judged by that mode's limit, t < 2/ω whatever the damping (``t_limit_verlet``).

It is a *linear* prediction at the start: a scene whose bindings are compressed or whose
contacts deepen as it runs becomes stiffer (the factor 1 + L0²/d² grows); ``rackstress bench
stability`` measures how far the prediction holds.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from rackstress.errors import SceneError
from rackstress.lib.roots import inside_unit_circle, largest_stable
from rackstress.model.operators import contact_candidates, phase_active
from rackstress.model.scene import Scene
from rackstress.model.verlet import t_limit_verlet

#: Pairs this close to touching (relative to the contact distance R) count as contacts.
CONTACT_MARGIN = 1.05
#: Problems with at most this many unknowns use a dense eigen-solver.
DENSE_MAX = 900


# ---------------------------------------------------------------------------- scalar limit
def t_limit(lam, gamma: float = 0.0) -> float:
    """The largest stable t of Eq. 5 for x'' = −λx − γx' (λ = ω², γ ≥ 0); ∞ if none binds.

    Real λ ≥ 0: ``4/(γ + √(γ² + 4λ))``. Complex λ (directed couplings can give them): the
    boundary of max|μ| < 1 of μ² − (2 − γt − λt²)μ + (1 − γt) = 0, by bisection. λ with a
    negative real part is a physical instability (no t cures it) and sets no limit here.
    """
    lam = complex(lam)
    gamma = max(0.0, float(gamma))
    if lam.real < 0 or abs(lam) == 0:
        return 2.0 / gamma if gamma > 0 else math.inf
    if abs(lam.imag) <= 1e-12 * abs(lam):
        lr = lam.real
        return 4.0 / (gamma + math.sqrt(gamma * gamma + 4.0 * lr))

    def stable(t):
        return inside_unit_circle([1.0, -(2.0 - gamma * t - lam * t * t), 1.0 - gamma * t])

    return largest_stable(stable, 4.0 / (gamma + math.sqrt(gamma * gamma + 4.0 * abs(lam))) * 4.0)


# ---------------------------------------------------------------------------- linearization
def _phases(scene: Scene) -> list[dict]:
    seen, out = set(), []
    for ph in scene.phases:
        key = tuple(sorted(ph.vars.items()))
        if key not in seen:
            seen.add(key)
            out.append(dict(ph.vars))
    return out or [{}]


def _label(target: str, op) -> str:
    """'plane' bind(plane, within(100) magnitude 100): how an operator is named in messages."""
    return f"'{target}' {op.label()}"


def _collide_pairs(scene: Scene, p: np.ndarray, target: str, op) -> tuple:
    """(I, J, Lsq, virtual) contact pairs of a collide, as described in the module docstring."""
    from scipy.spatial import cKDTree

    sl_t, sl_s = scene.slice(target), scene.slice(op.source)
    rt, rs = scene.groups[target].r, scene.groups[op.source].r
    reach = (rt.max() + rs.max()) * CONTACT_MARGIN
    i, j = contact_candidates(p[sl_t], p[sl_s], reach, same=target == op.source)
    I, J = i + sl_t.start, j + sl_s.start
    R = scene.radii()[I] + scene.radii()[J]
    d = np.linalg.norm(p[J] - p[I], axis=1)
    keep = d < R * CONTACT_MARGIN
    I, J, R, d = I[keep], J[keep], R[keep], d[keep]
    if len(I):
        # touching or nearly: at d = R (2c·nnᵀ); overlapping: the exact block at d
        Lsq = np.where(d < R, R * R, d * d)
        return I, J, Lsq, False
    # nowhere near at the start: virtual contacts. Each target particle is paired with the
    # source particles it would meet first coming straight at them: those within 5 % of R of
    # its nearest source particle's distance (one for aligned lattices, a few for staggered).
    src = p[sl_s]
    same = target == op.source
    k = min(8 + same, len(src))
    dd, jj = cKDTree(src).query(p[sl_t], k=k)
    dd, jj = np.asarray(dd).reshape(len(p[sl_t]), k), np.asarray(jj).reshape(len(p[sl_t]), k)
    if same:        # a group colliding with itself: a particle never meets itself (d = 0)
        dd = np.where(jj == np.arange(len(src))[:, None], np.inf, dd)
    R = rt[:, None] + rs.max()
    tie = np.isfinite(dd) & (dd <= dd.min(axis=1, keepdims=True) + (CONTACT_MARGIN - 1.0) * R)
    I = np.repeat(np.arange(sl_t.start, sl_t.stop), k).reshape(-1, k)[tie]
    J = jj[tie] + sl_s.start
    diff = p[J] - p[I]
    return I, J, np.einsum("ij,ij->i", diff, diff), True


def linearize(scene: Scene, phase: Mapping, p: np.ndarray | None = None) -> dict:
    """The pair blocks and damping of ``scene`` in ``phase`` about positions ``p`` (default o).

    Returns ``I, J`` (global indices, p ← u), ``B`` (n×3×3), ``norm`` (‖B‖₂), ``label`` (index
    into ``labels``), ``labels`` (operator descriptions), ``gamma`` (per particle), ``virtual``
    (labels of collides given virtual contacts).
    """
    o = scene.original_positions()
    p = o if p is None else np.asarray(p, dtype=float)
    N = scene.n_particles
    gamma = np.zeros(N)
    Is, Js, Bs, norms, labs, labels, virtual = [], [], [], [], [], [], []
    for target, seq in scene.operators.items():
        sl = scene.slice(target)
        g_t = scene.groups[target]
        for op in seq:
            if getattr(op, "kind", "") == "volume":
                if phase_active(op.when, phase):      # a material part's many-body term
                    I, J, B = _volume_blocks(op, g_t, sl.start, p[sl])
                    if len(I):
                        labels.append(_label(target, op))
                        Is.append(I)
                        Js.append(J)
                        Bs.append(B)
                        norms.append(np.linalg.norm(B, ord=2, axis=(1, 2)))
                        labs.append(np.full(len(I), len(labels) - 1))
                continue
            if not op.pair:        # dampen: Γ (contact assumed); force: a constant
                gamma[sl] += op.damping(phase_active(op.when, phase))
                continue
            if not phase_active(op.when, phase):
                continue
            if op.fixed_pairs:     # bind, attract: the coefficient matrix's pairs
                pl = op.pairs(g_t, scene.groups[op.source], phase)
                I, J, c, q = pl.i + sl.start, pl.j + scene.offset(op.source), pl.c, pl.q
            else:                  # collide: contacts (or virtual ones) at p
                I, J, q, virt = _collide_pairs(scene, p, target, op)
                if virt:
                    virtual.append(_label(target, op))
                c = np.full(len(I), float(op.coeff.c))
            if not len(I):
                continue
            B, nrm = op.jacobian(p[J] - p[I], c, q)
            if not len(I):
                continue
            labels.append(_label(target, op))
            Is.append(I)
            Js.append(J)
            Bs.append(B)
            norms.append(nrm)
            labs.append(np.full(len(I), len(labels) - 1))
    cat = (lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape))
    return {"I": cat(Is, (0,)).astype(np.int64), "J": cat(Js, (0,)).astype(np.int64),
            "B": cat(Bs, (0, 3, 3)), "norm": cat(norms, (0,)),
            "label": cat(labs, (0,)).astype(np.int64), "labels": labels, "gamma": gamma,
            "virtual": virtual}


def _volume_blocks(op, group, offset: int, p: np.ndarray):
    """The volumetric term's tangent stiffness (:meth:`rackstress.model.volume.Volume.hessian`)
    as pair blocks: K[p, u] = −B for every p ≠ u, so K[p, p] = Σ_u B (its rows sum to zero: a
    translation moves no extension)."""
    from rackstress.model.volume import Volume

    H = Volume.hessian(p, op.terms(group)).tocoo()
    n = group.n
    # 64-bit: SciPy's int32 rows would overflow r·n above 46,341 particles in the group
    r, c = H.row.astype(np.int64) // 3, H.col.astype(np.int64) // 3
    off = r != c
    B = np.zeros((0, 3, 3))
    if off.any():
        key = r[off] * n + c[off]
        uniq, inv = np.unique(key, return_inverse=True)
        B = np.zeros((len(uniq), 3, 3))
        np.add.at(B, (inv, H.row[off] % 3, H.col[off] % 3), -H.data[off])
        return uniq // n + offset, uniq % n + offset, B
    return np.zeros(0, np.int64), np.zeros(0, np.int64), B


def stiffness_matrix(lin: dict, N: int):
    """K (3N × 3N, CSR) with a ≈ −K·x: K[p, p] += B, K[p, u] −= B for every pair.

    Built block by block: the 2m blocks (p, p) and (p, u) sorted by p·N + column, each run of
    one key summed, then one BSR matrix of 3 × 3 blocks (a 46,512-particle block's 1.8 million
    pairs: 0.4 s, where 18 scalar COO entries per block took 6 s and three times the memory).
    """
    from scipy.sparse import bsr_matrix

    I, J = np.asarray(lin["I"], np.int64), np.asarray(lin["J"], np.int64)
    B, m = lin["B"], len(I)
    keys = np.concatenate([I * N + I, I * N + J])
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if m else np.zeros(0, np.int64)
    blocks = B[order % m] * np.where(order < m, 1.0, -1.0)[:, None, None]
    data = np.add.reduceat(blocks, first, axis=0) if m else np.zeros((0, 3, 3))
    rows, cols = np.divmod(keys[first], N)
    indptr = np.searchsorted(rows, np.arange(N + 1))
    return bsr_matrix((data, cols, indptr), shape=(3 * N, 3 * N)).tocsr()


def _top_eigen(K, k: int = 4):
    """A few largest-magnitude eigenvalues of K with their (right) eigenvectors.

    Rows of K that are zero (particles no pair operator acts on, e.g. resting sediment) are
    dropped first: that is exact (K is block triangular with a zero block; the other
    eigenvectors are zero there) and shrinks MagPod's problem tenfold.
    """
    n_all = K.shape[0]
    if n_all == 0 or K.nnz == 0:
        return np.zeros(0, complex), np.zeros((n_all, 0), complex)
    live = np.flatnonzero(np.diff(K.indptr) > 0)
    if len(live) < n_all:
        w, v = _top_eigen(K[live][:, live], k)
        full = np.zeros((n_all, v.shape[1]), complex)
        full[live] = v
        return w, full
    n = n_all
    sym = abs(K - K.T).max() <= 1e-12 * abs(K).max()
    if n <= DENSE_MAX:
        A = K.toarray()
        if sym:
            w, v = np.linalg.eigh(A)
        else:
            w, v = np.linalg.eig(A)
        order = np.argsort(-np.abs(w))[:k]
        return w[order].astype(complex), v[:, order].astype(complex)
    from scipy.sparse.linalg import ArpackNoConvergence, eigs, eigsh

    k = min(k, n - 2)
    v0 = np.ones(n) / math.sqrt(n)   # deterministic start
    try:
        if sym:
            w, v = eigsh(K, k=k, which="LM", tol=1e-4, v0=v0, maxiter=20 * n)
        else:
            w, v = eigs(K, k=k, which="LM", tol=1e-4, v0=v0, maxiter=20 * n)
    except ArpackNoConvergence as exc:
        w, v = exc.eigenvalues, exc.eigenvectors
        if len(w) == 0:   # fall back on the Gershgorin bound through the caller
            raise
    return np.asarray(w, complex), np.asarray(v, complex)


def _mode_gamma(vec: np.ndarray, gamma: np.ndarray) -> float:
    w = np.abs(vec.reshape(-1, 3)) ** 2
    w = w.sum(axis=1)
    return float((w * gamma).sum() / w.sum()) if w.sum() > 0 else 0.0


def predict(scene: Scene, p: np.ndarray | None = None) -> dict:
    """The linear stability limit of Eq. 5 for ``scene`` (see the module docstring).

    Returns ``t_max`` (the prediction), ``t_max_gershgorin`` (the row-sum bound), ``omega2``
    and ``gamma`` of the limiting mode, and where it sits: ``group``, ``particle`` (index in the
    group), ``operator`` (the operator contributing most to that particle's row), ``phase``,
    ``how`` ('spectrum' of the whole scene or 'group block'), and the Gershgorin limit's
    ``gershgorin`` record likewise.
    """
    N = scene.n_particles
    verlet = scene.integrator == "verlet"
    limit = t_limit_verlet if verlet else t_limit
    best = {"t_max": math.inf, "omega2": 0.0, "gamma": 0.0, "group": None, "particle": None,
            "operator": None, "phase": None, "how": None}
    gbest = {"t_max": math.inf, "omega2": 0.0, "gamma": 0.0, "group": None, "particle": None,
             "operator": None, "phase": None}
    virtual = set()
    for phase in _phases(scene):
        lin = linearize(scene, phase, p)
        virtual.update(lin["virtual"])
        gamma = lin["gamma"]
        I, norm, lab = lin["I"], lin["norm"], lin["label"]
        # --- Gershgorin, per particle
        row = 2.0 * np.bincount(I, weights=norm, minlength=N)
        if verlet:    # t < 2/ω whatever the damping (rackstress.model.verlet)
            with np.errstate(divide="ignore"):
                t_row = 2.0 / np.sqrt(row)
        else:
            t_row = np.array([t_limit(r, g) for r, g in zip(row, gamma)]) if N < 5000 else \
                4.0 / (gamma + np.sqrt(gamma ** 2 + 4.0 * row))
        t_row = np.where((row == 0) & (gamma <= 0), np.inf, t_row)
        k = int(np.argmin(t_row))

        def top_operator(k):
            sel = I == k
            if not sel.any():
                return "dampen"
            per = np.bincount(lab[sel], weights=norm[sel], minlength=len(lin["labels"]))
            return lin["labels"][int(np.argmax(per))]

        if t_row[k] < gbest["t_max"]:
            grp, loc = scene.group_of(k)
            gbest.update(t_max=float(t_row[k]), omega2=float(row[k]), gamma=float(gamma[k]),
                         group=grp, particle=int(loc), operator=top_operator(k),
                         phase=dict(phase))
        # --- spectrum: whole scene (Rayleigh damping) and each group's block (its damping)
        K = stiffness_matrix(lin, N)
        candidates = []
        try:
            w, v = _top_eigen(K)
            for m in range(len(w)):
                candidates.append((w[m], _mode_gamma(v[:, m], gamma), v[:, m], None, "spectrum"))
        except Exception:  # noqa: BLE001 - ARPACK failed: the bound stands in
            pass
        for name in scene.groups:
            sl = scene.slice(name)
            idx = np.arange(3 * sl.start, 3 * sl.stop)
            Kg = K[idx][:, idx]
            if Kg.nnz == 0:
                continue
            try:
                w, v = _top_eigen(Kg, k=1)
            except Exception:  # noqa: BLE001
                continue
            g_max = float(gamma[sl].max())
            for m in range(len(w)):
                full = np.zeros(3 * N, complex)
                full[idx] = v[:, m]
                candidates.append((w[m], g_max, full, name, "group block"))
        # damping alone (no stiffness) limits at γt < 2
        kg = int(np.argmax(gamma))
        if gamma[kg] > 0:
            e = np.zeros(3 * N, complex)
            e[3 * kg] = 1.0
            candidates.append((0.0, float(gamma[kg]), e, None, "damping"))
        for lam, g, vec, _, how in candidates:
            t = limit(lam, g)
            if t < best["t_max"]:
                amp = (np.abs(vec.reshape(-1, 3)) ** 2).sum(axis=1)
                kk = int(np.argmax(amp))
                grp, loc = scene.group_of(kk)
                best.update(t_max=float(t), omega2=float(abs(lam)), gamma=float(g), group=grp,
                            particle=int(loc),
                            operator=top_operator(kk) if how != "damping" else "dampen",
                            phase=dict(phase), how=how)
    # the spectrum cannot be less stable than the row-sum bound says
    if best["t_max"] < gbest["t_max"]:
        best = {**gbest, "how": "gershgorin"}
    best["t_max_gershgorin"] = gbest["t_max"]
    best["gershgorin"] = gbest
    best["virtual_contacts"] = sorted(virtual)
    best["dt"] = scene.dt
    best["ratio"] = scene.dt / best["t_max"] if best["t_max"] > 0 else math.inf
    return best


def describe_limit(pred: dict) -> str:
    """'set by ...' words for a prediction."""
    if pred["group"] is None:
        return "no operator sets a limit"
    ph = f" in phase {pred['phase']}" if pred.get("phase") else ""
    return (f"set by {pred['operator']} (ω² ≈ {pred['omega2']:.4g}, damping γ = "
            f"{pred['gamma']:.4g}; most at '{pred['group']}' particle {pred['particle']}"
            f"{ph})")


def check_dt(scene: Scene, allow: bool = False, pred: dict | None = None) -> dict:
    """Refuse a time step beyond the predicted limit (unless ``allow``); return the prediction."""
    pred = pred or predict(scene)
    if scene.dt > pred["t_max"] and not allow:
        raise SceneError(
            f"scene '{scene.name}': time step {scene.dt:g} exceeds the predicted stability "
            f"limit {pred['t_max']:.4g} of Eq. 5 (t < 4/(γ + √(γ² + 4ω²)), = 2/ω without "
            f"damping), {describe_limit(pred)}. The run would most likely diverge: use "
            f"--dt {0.9 * pred['t_max']:.3g} or less, or weaker coefficients; pass "
            "--allow-unstable (allow_unstable=True) to run anyway.")
    return pred
