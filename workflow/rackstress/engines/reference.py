"""The reference engine: evaluates a scene exactly by the paper's equations, float64, unit masses.

It is the ground truth the LAMMPS backend is measured against, so it stays simple: every
operator's acceleration is its own kernel (:mod:`rackstress.model.operators`), the operators of
all groups are evaluated on the same state (the composite of Eqs. 26 and 32), and ``integrate``
is Eq. 5 (:func:`rackstress.model.operators.integrate`). Collision neighbours come from the one
contact search, :func:`rackstress.model.operators.contact_candidates` (the same pairs as an
all-pairs search). Which kernel evaluates an operator is looked up in :data:`KERNELS` by the
operator's class.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from rackstress.errors import DivergenceError
from rackstress.lib.vec import rowdot
from rackstress.model.operators import (Attract, Bind, Collide, Dampen, Force, Indent,
                                        contact_candidates, contact_groups, integrate,
                                        phase_active)
from rackstress.model.scene import Scene
from rackstress.model.verlet import integrate_verlet
from rackstress.model.volume import Volume
from rackstress.engines.watchdog import check, first_nonfinite, force_error

__all__ = ["Reference", "integrate", "KERNELS"]


def _accumulate(a, idx, contrib):
    """a[idx] += contrib, summing repeated indices (a bincount per component)."""
    n = len(a)
    for k in range(3):
        a[:, k] += np.bincount(idx, weights=contrib[:, k], minlength=n)


class Reference:
    """State (p, v) of a scene under the reference engine, stepping by Eq. 5."""

    name = "reference"

    def __init__(self, scene: Scene):
        self.scene = scene
        self.o = scene.original_positions()
        self.radius = scene.radii()
        self.p = self.o.copy()
        self.v = scene.initial_velocities()   # v at step 0: zero unless a group sets v0
        # supports: held particles get zero acceleration (and start at rest), so Eq. 5 keeps
        # them at o exactly, like LAMMPS' fix setforce 0 0 0 with zero velocity
        # rollers and symmetry planes: only some directions of a particle are fixed
        fixed = scene.fixed()
        self._held = fixed if fixed.any() else None
        self.step_count = 0
        #: (group, index in its sequence) [+ phase] → the operator's PairList in global indices
        self._pairs = {}

    # ------------------------------------------------------------------ contact search
    def contacts(self, target: str, source: str, cache: dict | None = None):
        """Global index pairs (I, J) with ‖p_I − p_J‖ < r_I + r_J, I in target, J in source,
        and their R² = (r_I + r_J)² (Eq. 10's support). ``cache`` shares one search per
        evaluation between both directions and the contact conditions."""
        if cache is not None and (target, source) in cache:
            return cache[(target, source)]
        sc = self.scene
        st, ss = sc.slice(target), sc.slice(source)
        cut = sc.groups[target].r.max() + sc.groups[source].r.max()
        a, b = contact_candidates(self.p[st], self.p[ss], cut, same=target == source)
        I, J = a + st.start, b + ss.start
        diff = self.p[J] - self.p[I]
        d2 = rowdot(diff, diff)
        R2 = (self.radius[I] + self.radius[J]) ** 2
        keep = Collide.touching(d2, R2)
        I, J, d2, R2 = I[keep], J[keep], d2[keep], R2[keep]
        if np.any(d2 == 0.0):
            k = int(np.flatnonzero(d2 == 0.0)[0])
            self._coincide(int(I[k]), int(J[k]))
        if cache is not None:
            cache[(target, source)] = (I, J, R2)
            if source != target:
                cache[(source, target)] = (J, I, R2)
        return I, J, R2

    def _coincide(self, a: int, b: int):
        ga, la = self.scene.group_of(a)
        gb, lb = self.scene.group_of(b)
        raise DivergenceError(
            f"step {self.step_count}: '{ga}' particle {la} and '{gb}' particle {lb} coincide at "
            f"{self.p[a]}; the collision force (Eq. 10) is undefined there.",
            step=self.step_count, index=a, group=ga, local=la)

    # ------------------------------------------------------------------ netForce
    def accelerations(self, phase: Mapping) -> np.ndarray:
        """netForce of the scene on the current state: the accelerations of all particles."""
        a = np.zeros_like(self.p)
        cache = {}
        for target, seq in self.scene.operators.items():
            for k, op in enumerate(seq):
                KERNELS[type(op)](self, a, (target, k), op, phase, cache)
        return a

    def holds(self, conditions, target: str, phase: Mapping, cache: dict | None = None) -> bool:
        """⟨P⟩ of Eq. 4 for an operator's conditions: phase ones first, contact ones if needed."""
        if not phase_active(conditions, phase):
            return False
        return all(len(self.contacts(target, g, cache)[0]) > 0 for g in contact_groups(conditions))

    def _pair_list(self, site, op, phase=None):
        """The operator's pairs in global indices, prepared once (per phase for attract)."""
        key = site if phase is None else (site, tuple(sorted(phase.items())))
        if key not in self._pairs:
            sc, target = self.scene, site[0]
            pl = op.pairs(sc.groups[target], sc.groups[op.source], phase)
            self._pairs[key] = pl.shifted(sc.offset(target), sc.offset(op.source))
        return self._pairs[key]

    def _force(self, a, site, op, phase, cache):
        if self.holds(op.when, site[0], phase, cache):
            sl = self.scene.slice(site[0])
            if op.where is None:
                a[sl] += op.vector()
            else:
                a[sl][np.asarray(op.where, dtype=bool)] += op.vector()

    def _dampen(self, a, site, op, phase, cache):
        # conditions gate only the extra term (Eq. 28)
        holds = bool(op.extra) and self.holds(op.when, site[0], phase, cache)
        sl = self.scene.slice(site[0])
        a[sl] += Dampen.accel(self.v[sl], op.coefficient(holds))

    def _collide(self, a, site, op, phase, cache):
        if self.holds(op.when, site[0], phase, cache):
            I, J, R2 = self.contacts(site[0], op.source, cache)
            c = np.full(len(I), float(op.coeff.c))
            contrib = Collide.accel(self.p[I], self.p[J], c, R2)
            if op.mu > 0:       # Coulomb friction, from the velocities of this state
                contrib = contrib + Collide.friction(self.p[I], self.p[J], self.v[I],
                                                     self.v[J], c, R2, op.mu, op.eta)
            _accumulate(a, I, contrib)

    def _bind(self, a, site, op, phase, cache):
        if self.holds(op.when, site[0], phase, cache):
            pl = self._pair_list(site, op)
            _accumulate(a, pl.i, Bind.accel(self.p[pl.i], self.p[pl.j], pl.c, pl.q))

    def _volume(self, a, site, op, phase, cache):
        if self.holds(op.when, site[0], phase, cache):
            key = ("volume", site)
            if key not in self._pairs:
                sl = self.scene.slice(site[0])
                self._pairs[key] = (sl, op.terms(self.scene.groups[site[0]]))
            sl, t = self._pairs[key]
            a[sl] += Volume.accel(self.p[sl], t)

    def _attract(self, a, site, op, phase, cache):
        if self.holds(op.when, site[0], phase, cache):
            pl = self._pair_list(site, op, phase)
            _accumulate(a, pl.i, Attract.accel(self.p[pl.i], self.p[pl.j], pl.c))

    def _indent(self, a, site, op, phase, cache):
        # the sphere's centre at this step: a(p_n) uses the centre of step n (rs/indent's
        # ntimestep when LAMMPS evaluates the forces of the same state)
        if self.holds(op.when, site[0], phase, cache):
            sl = self.scene.slice(site[0])
            a[sl] += Indent.accel(self.p[sl], self.radius[sl], np.asarray(op.k, float),
                                  op.centre_at(self.step_count), op.radius)

    # ------------------------------------------------------------------ motion
    def damping(self, phase: Mapping) -> np.ndarray:
        """γ per particle: the dampen coefficients (Eq. 9) acting now, extras whose conditions hold."""
        g = np.zeros(len(self.p))
        cache = {}
        for target, seq in self.scene.operators.items():
            sl = self.scene.slice(target)
            for op in seq:
                if isinstance(op, Dampen):
                    holds = bool(op.extra) and self.holds(op.when, target, phase, cache)
                    g[sl] += op.coefficient(holds)
        return g

    def step(self, phase: Mapping) -> None:
        """motion = netForce • integrate(t) (Eqs. 6–7), then the watchdog.

        With ``scene.integrator == "verlet"`` the step is :func:`integrate_verlet` instead
        (v holds v_{n+½}); the first step is velocity Verlet's half kick,
        v_½ = v₀ + (t/2)·a(p₀, v₀)/(1 + γt/2), as LAMMPS' fix nve starts it.
        """
        if self.scene.integrator == "verlet":
            t = self.scene.dt
            g = self.damping(phase)
            a = self._finite(phase)
            if self._held is not None:
                a[self._held] = 0.0
            if self.step_count == 0:
                self.v = self.v + (0.5 * t) * a / (1.0 + 0.5 * t * g)[:, None]
                self.p = self.p + t * self.v
            else:
                self.p, self.v = integrate_verlet(self.p, self.v, a + g[:, None] * self.v, g, t)
            self.step_count += 1
            check(self.scene, self.p, self.v, self.o, self.step_count)
            return
        a = self._finite(phase)
        if self._held is not None:
            a[self._held] = 0.0
        self.p, self.v = integrate(self.p, self.v, a, self.scene.dt)
        self.step_count += 1
        check(self.scene, self.p, self.v, self.o, self.step_count)

    def _finite(self, phase: Mapping) -> np.ndarray:
        """The accelerations, or a divergence at this step if one is not finite (a bound pair
        that coincides): found where it arises, so no non-finite position is ever dumped."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            a = self.accelerations(phase)
        k = first_nonfinite(a)
        if k >= 0:
            raise force_error(self.scene, self.step_count, k)
        return a

    # ------------------------------------------------------------------ the engine interface
    #: Steps between the driver's watchdog checks: every step (:meth:`step` checks itself).
    check_every = 1
    #: The reference engine runs on one process, which writes everything.
    root = True
    _dump = None
    _dump_every = 1
    _phase: Mapping = {}

    def open_dump(self, path, dump_every: int) -> None:
        """Write frames of the trajectory to ``path`` every ``dump_every`` steps, starting now."""
        from rackstress.engines.dumpio import DumpWriter
        from rackstress.model import topology

        sc = self.scene
        self._dump = DumpWriter(path, topology.per_particle(sc, topology.group_types(sc)),
                                topology.per_particle(sc, topology.group_mols(sc)))
        self._dump_every = int(dump_every)
        self._dump.write(self.step_count, self.p)

    def enter_phase(self, phase_vars: Mapping) -> None:
        """The phase variables the operators' conditions read (⟨P⟩ of Eq. 4) from now on."""
        self._phase = dict(phase_vars)

    def advance(self, n: int) -> None:
        """``n`` steps of :meth:`step` in the current phase, writing frames as they fall due."""
        for _ in range(int(n)):
            self.step(self._phase)
            self._checked_at = self.step_count
            if self._dump is not None and self.step_count % self._dump_every == 0:
                self._dump.write(self.step_count, self.p)

    _checked_at = -1

    def check(self) -> None:
        """The watchdog (every :meth:`step` runs it already: not again for the same step)."""
        if self._checked_at != self.step_count:
            check(self.scene, self.p, self.v, self.o, self.step_count)
            self._checked_at = self.step_count

    def positions(self) -> np.ndarray:
        return self.p.copy()

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.p.copy(), self.v.copy()

    def write_frame(self) -> None:
        """A frame of the current step, unless the dump interval already wrote it."""
        if self._dump is not None and self.step_count % self._dump_every != 0:
            self._dump.write(self.step_count, self.p)

    def close(self) -> None:
        if self._dump is not None:
            self._dump.close()
            self._dump = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


#: The reference kernel evaluating each operator class (adding an operator adds one entry).
KERNELS = {Force: Reference._force, Dampen: Reference._dampen, Collide: Reference._collide,
           Bind: Reference._bind, Attract: Reference._attract, Volume: Reference._volume,
           Indent: Reference._indent}
