"""MagPod in physical units: each leg's von Mises stress in MPa, quasi-static per frame.

The gait runs as the paper's scene does (paper units, unchanged). A stated mapping
(:class:`PhysicalMapping`) gives the paper's numbers a size and a time: a length per paper
unit, aluminium legs (``rackstress.model.materials``), and the paper's push-down
``force((0, −50, 0))`` on every leg particle read as gravity g, which fixes the acceleration
scale and with the particles' masses every operator's force in newtons.

Per dump frame, each leg's **load** is everything acting on it but its own elasticity: the
attraction to the body, the collisions with body and sediment, the push-down (the operators of
Eqs. 28–30 on the leg, evaluated at the dumped positions by the reference engine's kernels),
the rack binding left out: that binding *is* the paper's leg elasticity, which the aluminium
lattice replaces here. The dump holds positions only, so the damping (−γ·v) is not evaluated:
the leg's γ is one number for all its particles and their masses are equal, so the damping of
the leg's rigid motion is a rigid-acceleration field, removed whole by the relief below; only
the damping of the deformation's own velocity is left out.

**Quasi-static per frame** (inertia relief, d'Alembert): the load's resultant force and
moment are balanced by the leg's rigid-body acceleration (A + α × r on every particle, m equal),
so the relieved load is self-equilibrated; the leg's aluminium lattice (Eq. 12 bindings of
:mod:`rackstress.model.solid`, :func:`rackstress.engines.static.stiffness`) is solved under it
with its six rigid modes held by six pinned unknowns (whose reactions are then zero), the
factorization made once per leg (:func:`rackstress.engines.linear.factorize`) and
back-substituted per frame. No elastic wave in the leg: acceptable when the leg's lowest
natural frequency (:meth:`LegLattice.lowest_frequency`) is far above the gait's forcing
(docs/magpod/physical.md). The stress is the project's own measure (the bindings' virial, the
cells' moment restored, patch recovery: :class:`rackstress.stress.measures.ParticleStress`'s
``"patch"`` route).

Example
-------
>>> from rackstress.scenes import build                                     # doctest: +SKIP
>>> res = leg_stress(build("magpod-physical-small"), frames)                # doctest: +SKIP
>>> res.peak["von_mises_mpa"]                                               # doctest: +SKIP
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: the legs of MagPod, in the scene's group names
LEGS = ("rightleg", "leftleg")
#: per-frame von Mises file beside the dump: float32, frames × leg particles (right, then left)
VM_FILE = "legs_von_mises.f32"
#: the summary of the physical stress (mapping, peaks, timings)
JSON_FILE = "legs_physical.json"
#: standard gravity, m/s²
G = 9.81
#: the paper's push-down on every leg particle (Eq. 28's force((0, −50, 0))), paper units
PUSH = 50.0


@dataclass(frozen=True)
class PhysicalMapping:
    """The paper's units in SI: what each number of the scene means physically.

    Parameters
    ----------
    unit_length : float
        Metres per paper length unit (a guess: the paper gives no size).
    material : str
        The legs' material (a preset of :mod:`rackstress.model.materials`).
    g : float
        The acceleration the paper's push-down ``push`` stands for (m/s²).
    push : float
        The push-down's magnitude in paper accelerations (Eq. 28: 50).
    spacing : float
        The legs' lattice spacing in paper units (the scene's ``spacing``).

    Examples
    --------
    >>> m = PhysicalMapping(unit_length=0.005)
    >>> round(m.accel, 4), round(m.time, 4), round(m.a * 1000, 3)
    (0.1962, 0.1596, 10.0)
    """

    unit_length: float = 0.005
    material: str = "aluminium"
    g: float = G
    push: float = PUSH
    spacing: float = 2.0

    @property
    def accel(self) -> float:
        """m/s² per paper acceleration unit: the push-down is g."""
        return self.g / self.push

    @property
    def time(self) -> float:
        """Seconds per paper time unit: acceleration = length / time²."""
        return float(np.sqrt(self.unit_length / self.accel))

    @property
    def a(self) -> float:
        """The legs' lattice spacing in metres."""
        return self.spacing * self.unit_length

    def props(self) -> dict:
        """E (Pa), ν, density (kg/m³), yield (Pa) of the legs' material, SI."""
        from rackstress.model.materials import material

        m = material(self.material)
        return {"E": m.E, "nu": m.nu, "density": m.density, "yield": m.yield_strength}

    @property
    def particle_mass(self) -> float:
        """kg of one leg particle: ρ·a³."""
        return self.props()["density"] * self.a ** 3

    def figures(self, scene) -> dict:
        """The mapping's derived figures for ``scene`` (a MagPod): sizes, masses, times, the
        sediment's implied density and stiffness (docs/magpod/physical.md's table)."""
        L, m = self.unit_length, self.particle_mass
        leg = scene.groups[LEGS[0]]
        body, sed = scene.groups["body"], scene.groups["sediment"]
        ext = np.ptp(leg.o, axis=0) + 2 * leg.r.max()
        bext = np.ptp(body.o, axis=0) + 2 * body.r.max()
        dt = scene.dt * self.time
        phase = scene.phases[0].steps * dt
        # the collide of Eq. 10 near contact: c·(R²/d − d) ≈ 2c·δ per pair (an acceleration of
        # the leg particle), so a pair's stiffness is 2·c·m in newtons per metre
        c_leg_sed = _coefficient(scene, LEGS[0], "sediment")
        c_sed_leg = _coefficient(scene, "sediment", LEGS[0])
        k_pair = 2.0 * c_leg_sed * m * self.accel / L
        s_sp = float(scene.params.get("sediment_spacing", 3.0)) * L
        s_r = float(sed.r.max()) * L
        # the directed pair leg←sediment 50, sediment←leg 1 is one reciprocal interaction when
        # m_sed·1 = m_leg·50 (the deck's masses): the sediment particle's implied mass
        m_sed = m * c_leg_sed / c_sed_leg
        return {
            "unit_length_mm": L * 1e3, "spacing_mm": self.a * 1e3,
            "accel_per_unit": self.accel, "time_per_unit_s": self.time,
            "dt_s": dt, "phase_s": phase, "cycle_s": phase * len(scene.phases),
            "leg_size_mm": (ext * L * 1e3).tolist(), "body_size_mm": (bext * L * 1e3).tolist(),
            "particle_mass_g": m * 1e3, "leg_mass_g": leg.n * m * 1e3,
            "body_mass_g": body.n * m * 1e3,
            "leg_weight_n": leg.n * m * self.g,
            "contact_stiffness_n_per_m": k_pair,
            "sediment_subgrade_n_per_m3": k_pair / s_sp ** 2,
            "sediment_modulus_pa": k_pair / s_sp ** 2 * 2 * s_r,
            "sediment_particle_mass_g": m_sed * 1e3,
            "sediment_density_kg_m3": m_sed / (s_sp ** 2 * 2 * s_r),
            "material": self.material, "g": self.g,
            "E_pa": self.props()["E"], "nu": self.props()["nu"],
            "density_kg_m3": self.props()["density"], "yield_pa": self.props()["yield"],
        }


def _coefficient(scene, target: str, source: str) -> float:
    """The constant c of the unconditional collide on ``target`` from ``source``."""
    from rackstress.model.operators import Collide

    for op in scene.operators[target]:
        if isinstance(op, Collide) and op.source == source and not op.when:
            return float(op.coeff.c)
    raise ValueError(f"no unconditional collide on {target} from {source}")


def mapping_of(scene) -> PhysicalMapping:
    """The mapping a scene's parameters state (``unit_length_mm``, ``material``, ``g``)."""
    p = scene.params
    return PhysicalMapping(unit_length=float(p.get("unit_length_mm", 5.0)) * 1e-3,
                           material=str(p.get("leg_material", "aluminium")),
                           g=float(p.get("g", G)), spacing=float(p.get("spacing", 2.0)))


# ----------------------------------------------------------------------------- the relief
def relieve(x: np.ndarray, f: np.ndarray, m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inertia relief (d'Alembert): the load ``f`` (n, 3) at positions ``x`` (n, 3) on
    particles of mass ``m`` (scalar or n) less the inertia of the rigid acceleration that its
    resultant gives the body, A + α × r (r from the centre of mass): the relieved load has zero
    resultant force and zero moment.

    Returns
    -------
    (f_relieved, A, alpha)

    Examples
    --------
    >>> x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> g, A, al = relieve(x, np.array([[0.0, 4, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]), 1.0)
    >>> np.allclose(g.sum(axis=0), 0), A.tolist()
    (True, [0.0, 1.0, 0.0])
    """
    x, f = np.asarray(x, float), np.asarray(f, float)
    m = np.broadcast_to(np.asarray(m, float), (len(x),))
    M = m.sum()
    c = (m[:, None] * x).sum(axis=0) / M
    r = x - c
    A = f.sum(axis=0) / M
    torque = np.cross(r, f).sum(axis=0)
    J = (m[:, None, None] * (np.einsum("ij,ij->i", r, r)[:, None, None] * np.eye(3)
                             - np.einsum("ij,ik->ijk", r, r))).sum(axis=0)
    alpha = np.linalg.solve(J, torque)
    return f - m[:, None] * (A[None, :] + np.cross(alpha[None, :], r)), A, alpha


# ----------------------------------------------------------------------------- the leg lattice
def layer_boxes(o: np.ndarray, a: float):
    """The part the lattice sites ``o`` fill, as the union of one box per layer (along y) when
    every layer is a full rectangle of sites (MagPod's leg: a column on a foot), each site's
    cell of side ``a`` inside; None otherwise. With it no binding crosses the notch at the
    column's foot (:class:`rackstress.model.operators.WithinInside`)."""
    from rackstress.model.regions import Box

    o = np.asarray(o, float)
    y = np.round((o[:, 1] - o[:, 1].min()) / a).astype(np.int64)
    region = None
    for k in np.unique(y):
        q = o[y == k]
        lo, hi = q.min(axis=0), q.max(axis=0)
        ext = np.round((hi - lo) / a).astype(np.int64) + 1
        if ext[0] * ext[2] != len(q) or ext[1] != 1:
            return None
        box = Box(tuple(lo - a / 2), tuple(hi + a / 2))
        region = box if region is None else region | box
    return region


class LegLattice:
    """One leg as an elastic lattice of its material: Eq. 12 bindings within 1.5 spacings
    (:class:`rackstress.model.solid.Solid`, the free faces compensated), its stiffness
    factorized once with six unknowns pinned against the rigid modes, and the project's
    stress measure on it.

    Parameters
    ----------
    o : (n, 3) array
        The leg's original positions, in metres, on a cubic lattice of spacing ``a``.
    a : float
        The spacing (m).
    material : str
        A preset of :mod:`rackstress.model.materials`.

    Examples
    --------
    A free bar 12 × 3 × 3 at 10 mm pulled by 90 N at each end: F/A = 90 / 0.03² = 0.1 MPa

    >>> o = np.stack(np.meshgrid(*[np.arange(k) * 0.01 for k in (12, 3, 3)], indexing="ij"),
    ...              -1).reshape(-1, 3)
    >>> leg = LegLattice(o, 0.01)
    >>> f = np.zeros_like(o); f[o[:, 0] == 0, 0] = -10.0; f[np.isclose(o[:, 0], 0.11), 0] = 10.0
    >>> vm = leg.von_mises(leg.solve(f))
    >>> round(float(vm[np.isclose(o[:, 0], 0.06)].mean()), 2)
    0.1
    """

    def __init__(self, o: np.ndarray, a: float, material: str = "aluminium"):
        import scipy.linalg as sla

        from rackstress.engines.linear import factorize
        from rackstress.engines.static import rigid_modes, stiffness
        from rackstress.model.materials import material as preset
        from rackstress.model.operators import Bind
        from rackstress.model.particles import Group
        from rackstress.model.solid import REACH, Solid, bind_coefficient
        from rackstress.model.units import SYSTEMS
        from rackstress.stress import tensor as T

        self.o = np.ascontiguousarray(o, float)
        self.a = float(a)
        n = self.n = len(self.o)
        mat = self.material = preset(material)
        self.m = mat.density * self.a ** 3
        c = bind_coefficient(mat, SYSTEMS["SI"], self.a)
        g = Group("leg", self.o, 0.5 * self.a, material=mat, volume=self.a ** 3)
        self.region = layer_boxes(self.o, self.a)
        pl = Bind("leg", Solid(REACH * self.a, c, self.region, spacing=self.a,
                               material=mat.name)).pairs(g, g)
        self.pairs = (pl.i, pl.j, pl.c, pl.q)
        mass = np.full(n, self.m)
        t0 = time.perf_counter()
        self.K = stiffness(self.o, self.pairs, mass)
        # the six unknowns that hold the rigid modes best: QR with column pivoting on Bᵀ
        self.B = rigid_modes(self.o, np.ones(3 * n, bool))
        _, _, piv = sla.qr(self.B.T, mode="economic", pivoting=True)
        self.pinned = np.sort(piv[:6])
        self._Bpinv = np.linalg.pinv(self.B)
        self.free = np.setdiff1d(np.arange(3 * n), self.pinned)
        Kf = self.K[self.free][:, self.free].tocsr()
        self.factor = factorize(Kf)
        self.factor_s = time.perf_counter() - t0
        # the stress measure's pieces (ParticleStress "patch"), once
        i, j, k, q = pl.i, pl.j, pl.c * self.m, pl.q
        self.bindings = (i, j, k, q)
        self.gather = T.incidence(i, n)
        self.wm = T.surface_moment(self.o, i, j, q, n)
        self.patch = T.patch_matrix(self.o, self.a, T.part_recovery_points(self.o, self.a),
                                    np.zeros(n, np.int64))
        self.V = np.full(n, self.a ** 3)
        self._d0 = self.o[j] - self.o[i]
        self._dd = np.stack([self._d0[:, r] * self._d0[:, c] for r, c in T.VOIGT], axis=1)

    def solve(self, f: np.ndarray) -> np.ndarray:
        """Displacements (n, 3) of the lattice under the self-equilibrated load ``f`` (n, 3,
        newtons), the rigid-body part removed (what remains is the deformation alone); ``f``
        (k, n, 3): k loads back-substituted at once, (k, n, 3) displacements."""
        f = np.asarray(f, float)
        many = f.ndim == 3
        b = f.reshape(len(f) if many else 1, -1).T                # 3n × k
        u = np.zeros_like(b)
        if b.shape[1]:
            u[self.free] = self.factor.solve_many(np.asfortranarray(b[self.free]))
        u -= self.B @ (self._Bpinv @ u)           # the rigid part (least squares)
        u = u.T.reshape(-1, self.n, 3)
        return u if many else u[0]

    def reactions(self, u: np.ndarray, f: np.ndarray) -> np.ndarray:
        """K·u − f at the pinned unknowns: zero for a self-equilibrated load (a check);
        (k, n, 3) arrays give (k, 6)."""
        u, f = np.asarray(u, float), np.asarray(f, float)
        U = u.reshape(-1, 3 * self.n).T
        r = (self.K @ U - f.reshape(-1, 3 * self.n).T)[self.pinned].T
        return r if u.ndim == 3 else r[0]

    def stress(self, u: np.ndarray) -> np.ndarray:
        """Stress (n, 6, internal Voigt, Pa) at displacements ``u``: the bindings' virial per
        cell (linearized: small strain), the cells' moment restored, patch-recovered
        (ParticleStress's ``patch``)."""
        from rackstress.stress import tensor as T

        i, j, k, q = self.bindings
        u = np.asarray(u, float)
        # Eq. 12's virial linearized about the rest state, ½·k·(1 − L0²/d²)·d ⊗ d →
        # k·(d0·Δu)/L0²·d0 ⊗ d0: exact to the strain (~1e-6 in aluminium here) and linear in u,
        # where o + u would lose digits to rounding at such strains
        coef = k * np.einsum("ij,ij->i", self._d0, u[j] - u[i]) / q
        W = np.asarray(self.gather @ (coef[:, None] * self._dd))
        s = T.stress(self.o, self.bindings, None, self.V, W=W)
        s = T.moment_corrected(s, i, j, self.wm, self.gather)
        return np.asarray(self.patch @ s)

    def von_mises(self, u: np.ndarray) -> np.ndarray:
        """von Mises (MPa) per particle at displacements ``u``."""
        from rackstress.stress import tensor as T

        return T.von_mises(self.stress(u)) / 1e6

    def lowest_frequency(self) -> float:
        """The leg's lowest natural frequency (Hz), free-free: the smallest non-rigid ω² of
        K·φ = ω²·m·φ (a dense eigen-solve: a leg has a few hundred particles)."""
        lam = np.linalg.eigvalsh(self.K.toarray()) / self.m
        return float(np.sqrt(max(lam[6], 0.0)) / (2 * np.pi))


# ----------------------------------------------------------------------------- the loads
def phase_at(scene, step: int) -> dict:
    """The phase variables of the iteration that moves the state from ``step`` (the forces a
    dumped frame feels); the last phase for the last step."""
    last = None
    for first, phase, _ in scene.schedule():
        if first <= step < first + phase.steps:
            return dict(phase.vars)
        last = phase
    return dict(last.vars) if last is not None else {}


class LegLoads:
    """The load on each leg at a state: every operator on it but its rack binding (module
    doc), as paper accelerations per particle, by the reference engine's kernels."""

    def __init__(self, scene):
        from rackstress.engines.reference import Reference

        self.scene = scene
        self.ref = Reference(scene)
        self.ref.v[:] = 0.0

    def accelerations(self, p: np.ndarray, phase: dict) -> dict:
        """{leg: (n, 3) paper accelerations} at positions ``p`` (every particle) in ``phase``."""
        from rackstress.engines.reference import KERNELS
        from rackstress.model.operators import Bind

        self.ref.p = np.asarray(p, float)
        out, cache = {}, {}
        for leg in LEGS:
            a = np.zeros_like(self.ref.p)
            for k, op in enumerate(self.scene.operators[leg]):
                if isinstance(op, Bind):
                    continue                # the rack binding: the leg's own elasticity
                KERNELS[type(op)](self.ref, a, (leg, k), op, phase, cache)
            out[leg] = a[self.scene.slice(leg)]
        return out


@dataclass
class LegStress:
    """What :func:`leg_stress` found: per frame and leg particle the von Mises (MPa, float32,
    right leg then left), the steps, the peaks, the mapping's figures and timings."""

    steps: np.ndarray
    von_mises: np.ndarray
    legs: dict
    figures: dict
    peak: dict
    max_per_particle: np.ndarray
    max_frame: np.ndarray
    paper: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    checks: dict = field(default_factory=dict)


def over_run(vm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per particle, the largest of the frames' values ``vm`` (frames × n) and its frame."""
    vm = np.asarray(vm)
    k = np.argmax(vm, axis=0)
    return vm[k, np.arange(vm.shape[1])], k


def leg_stress(scene, frames, mapping: PhysicalMapping | None = None,
               paper_at_peak: bool = True) -> LegStress:
    """The legs' quasi-static von Mises in MPa over ``frames`` ((step, positions) pairs).

    Parameters
    ----------
    scene : Scene
        A MagPod (``magpod``, ``magpod-small``, ``magpod-physical-small``,
        ``magpod-physical``).
    frames : iterable of (int, (n, 3) array)
        The dumped states (paper units), e.g. :func:`rackstress.engines.dumpio.read_frames`.
    mapping : PhysicalMapping, optional
        Default: the scene's parameters (:func:`mapping_of`).

    Returns
    -------
    LegStress

    Examples
    --------
    >>> from rackstress.engines.dumpio import read_frames, dump_path          # doctest: +SKIP
    >>> sc = build("magpod-physical-small")                                   # doctest: +SKIP
    >>> res = leg_stress(sc, read_frames(dump_path("runs/mps"), sc.original_positions()))
    ... # doctest: +SKIP
    >>> res.peak["von_mises_mpa"], res.peak["step"]                           # doctest: +SKIP
    (0.145, 0)
    """
    from rackstress.lib.rigid import kabsch, robust_deformation

    mp = mapping or mapping_of(scene)
    t0 = time.perf_counter()
    o = scene.original_positions()
    lat = {leg: LegLattice(o[scene.slice(leg)] * mp.unit_length, mp.a, mp.material)
           for leg in LEGS}
    t_factor = time.perf_counter() - t0
    loads = LegLoads(scene)
    steps, frames_kept = [], []
    F = {leg: [] for leg in LEGS}
    paper_max = {leg: [] for leg in LEGS}
    t_load = t_solve = 0.0
    idx = np.concatenate([np.arange(scene.slice(leg).start, scene.slice(leg).stop)
                          for leg in LEGS])
    for step, p in frames:
        ta = time.perf_counter()
        acc = loads.accelerations(p, phase_at(scene, int(step)))
        for leg in LEGS:
            L, ol, pl = lat[leg], o[scene.slice(leg)], p[scene.slice(leg)]
            R, _ = kabsch(ol, pl)
            f = (acc[leg] @ R) * (L.m * mp.accel)          # newtons, in the leg's own frame
            F[leg].append(relieve(L.o, f, L.m)[0])
            if paper_at_peak:       # the paper's colouring of this leg (Section 5.2)
                paper_max[leg].append(float(robust_deformation(ol, pl).max()))
        t_load += time.perf_counter() - ta
        steps.append(int(step))
        frames_kept.append(p[idx] if paper_at_peak else None)
    tb = time.perf_counter()
    parts, worst_reaction = [], 0.0
    for leg in LEGS:                # every frame's load back-substituted at once
        L = lat[leg]
        Fl = np.asarray(F[leg]).reshape(-1, L.n, 3)
        U = L.solve(Fl)
        if len(Fl):
            # against the largest relieved load of the run (a frame whose load is ~0 has
            # only rounding, no share to speak of)
            scale = float(np.abs(Fl).max()) or 1.0
            worst_reaction = max(worst_reaction, float(np.abs(L.reactions(U, Fl)).max()) / scale)
        parts.append(np.array([L.von_mises(u) for u in U]).reshape(len(Fl), L.n))
    t_solve = time.perf_counter() - tb
    rows = np.concatenate(parts, axis=1) if steps else np.zeros((0, len(idx)))
    vm = np.array(rows, dtype=np.float32).reshape(len(rows), -1)
    n_r = lat[LEGS[0]].n
    legs = {}
    for k, leg in enumerate(LEGS):
        part = vm[:, k * n_r:(k + 1) * n_r]
        gov = part.max(axis=1) if len(part) else np.zeros(0)
        legs[leg] = {"governing_mpa": gov.tolist(), "n": int(part.shape[1])}
    top, kf = over_run(vm) if len(vm) else (np.zeros(0), np.zeros(0, int))
    peak = {}
    if len(vm):
        j = int(np.argmax(top))
        fk = int(kf[j])
        leg = LEGS[j // n_r]
        peak = {"von_mises_mpa": float(top[j]), "frame": fk, "step": steps[fk],
                "time_s": steps[fk] * scene.dt * mp.time, "leg": leg, "particle": int(j % n_r),
                "phase": phase_at(scene, steps[fk])}
    paper = {}
    if paper_at_peak and peak:
        pl = frames_kept[peak["frame"]]
        paper = {leg: robust_deformation(o[scene.slice(leg)],
                                         pl[k * n_r:(k + 1) * n_r]).tolist()
                 for k, leg in enumerate(LEGS)}
        paper["positions"] = pl.tolist()
        paper["max_per_frame"] = paper_max
        paper["max_over_run"] = max(max(v) for v in paper_max.values())
        # the frame where the paper's colouring of the legs is largest, for the picture beside
        kp = int(np.argmax(np.max(np.array([paper_max[leg] for leg in LEGS]), axis=0)))
        pp = frames_kept[kp]
        paper["at_paper_peak"] = {
            "frame": kp, "step": steps[kp], "time_s": steps[kp] * scene.dt * mp.time,
            "positions": pp.tolist(),
            **{leg: robust_deformation(o[scene.slice(leg)], pp[k * n_r:(k + 1) * n_r]).tolist()
               for k, leg in enumerate(LEGS)}}
    return LegStress(np.array(steps), vm, legs, mp.figures(scene), peak, top, kf, paper,
                     {"factorize_s": t_factor, "loads_s": t_load, "solve_stress_s": t_solve},
                     {"largest_reaction_share": worst_reaction})


def write(res: LegStress, out) -> Path:
    """``legs_von_mises.f32`` (frames × leg particles, float32) and ``legs_physical.json``
    into the run directory ``out``; returns the JSON's path."""
    out = Path(out)
    res.von_mises.astype("<f4").tofile(out / VM_FILE)
    rec = {"file": VM_FILE, "shape": list(res.von_mises.shape), "dtype": "<f4",
           "order": "frames x (rightleg particles, leftleg particles)", "units": "MPa",
           "steps": res.steps.tolist(), "legs": res.legs, "mapping": res.figures,
           "peak": res.peak, "max_per_particle_mpa": res.max_per_particle.tolist(),
           "max_frame": res.max_frame.tolist(),
           "max_step": [int(res.steps[k]) for k in res.max_frame],
           "timings": res.timings, "checks": res.checks,
           "paper_max_per_frame": res.paper.get("max_per_frame"),
           "paper_max_over_run": res.paper.get("max_over_run"),
           "paper_peak": {k: v for k, v in res.paper.get("at_paper_peak", {}).items()
                          if k in ("frame", "step", "time_s")},
           "approximation": "quasi-static per frame: inertia as a rigid-body d'Alembert load, "
                            "no elastic wave in the leg"}
    path = out / JSON_FILE
    path.write_text(json.dumps(rec, indent=1))
    return path


def run_legs(rundir, progress: bool = False) -> tuple[LegStress, Path]:
    """The legs' physical stress of a finished MagPod run: the scene rebuilt from its
    ``scene.json``, the dump's frames read, :func:`leg_stress`, :func:`write`.

    Returns
    -------
    (LegStress, Path)
        The result and the path of ``legs_physical.json``.

    Examples
    --------
    >>> res, path = run_legs("runs/mps")                       # doctest: +SKIP
    >>> res.von_mises.shape                                    # doctest: +SKIP
    (101, 764)
    """
    from rackstress.engines.dumpio import dump_path, read_frames
    from rackstress.scenes import build, parameters

    rundir = Path(rundir)
    rec = json.loads((rundir / "scene.json").read_text())
    known = parameters(rec["scene"])
    scene = build(rec["scene"], **{k: v for k, v in rec.get("params", {}).items() if k in known})
    from rackstress.lib import numtext

    numtext.warm()                  # the dump's numbers read compiled (cached on disk)
    frames = read_frames(dump_path(rundir), scene.original_positions())
    t0 = time.perf_counter()
    res = leg_stress(scene, frames)
    res.timings["total_s"] = time.perf_counter() - t0
    return res, write(res, rundir)
