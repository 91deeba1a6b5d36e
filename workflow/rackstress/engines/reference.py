"""The reference engine: evaluates a scene exactly by the paper's equations, float64, unit masses.

It is the ground truth the LAMMPS backend is measured against, so it stays simple: every
operator is one short function of the current state, the operators of all groups are evaluated
on the same state (the composite of Eqs. 26 and 32), and ``integrate`` is Eq. 5. Collision
neighbours come from ``scipy.spatial.cKDTree`` (the same pairs as an all-pairs search).
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
from scipy.spatial import cKDTree

from rackstress.lib.vec import rowdot
from rackstress.errors import DivergenceError
from rackstress.model.operators import (Attract, Bind, Collide, Contact, Dampen, Force, attract_pairs,
                        bind_pairs, phase_active)
from rackstress.model.scene import Scene
from rackstress.model.verlet import integrate_verlet
from rackstress.engines.watchdog import check


# ----------------------------------------------------------------------- the paper's functions
def col(p, u, r_p, r_u, c):
    """Eq. 10 (erratum: R = p_r + u_r) for arrays of pairs: c·(u−p)·min(0, 1 − R²/‖u−p‖²)."""
    diff = u - p
    d2 = rowdot(diff, diff)
    factor = np.minimum(0.0, 1.0 - (r_p + r_u) ** 2 / d2)
    return (c * factor)[:, None] * diff


def bin_(p, u, L0sq, c):
    """Eq. 12 for arrays of pairs: c·(u−p)·(1 − L0²/‖u−p‖²), L0 the pair's original distance."""
    diff = u - p
    d2 = rowdot(diff, diff)
    return (c * (1.0 - L0sq / d2))[:, None] * diff


def attraction(p, u, c):
    """Eq. 14 summand for arrays of pairs: c·(u−p)/‖u−p‖."""
    diff = u - p
    d = np.sqrt(rowdot(diff, diff))
    return (c / d)[:, None] * diff


def integrate(p, v, a, t):
    """Eq. 5 (forward-corrected Euler): v += t·a; p += t·v. Returns the new (p, v)."""
    v = v + t * a
    return p + t * v, v


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
        self.v = np.zeros_like(self.p)
        self.step_count = 0
        self._bind = {}      # id(op) → (I, J, c, L0²) in global indices
        self._attract = {}   # (id(op), phase key) → (I, J, c)
        for target, seq in scene.operators.items():
            for op in seq:
                if isinstance(op, Bind):
                    g_t, g_s = scene.groups[target], scene.groups[op.source]
                    i, j, c = bind_pairs(op, g_t, g_s)
                    I, J = i + scene.offset(target), j + scene.offset(op.source)
                    diff = self.o[J] - self.o[I]
                    self._bind[id(op)] = (I, J, c, rowdot(diff, diff))

    # ------------------------------------------------------------------ neighbour search
    def _trees(self):
        cache = {}

        def tree(group):
            if group not in cache:
                cache[group] = cKDTree(self.p[self.scene.slice(group)])
            return cache[group]
        return tree

    def contacts(self, target: str, source: str, tree) -> tuple[np.ndarray, np.ndarray]:
        """Global index pairs (I, J) with ‖p_I − p_J‖ < r_I + r_J, I in target, J in source."""
        sc = self.scene
        rt, rs = sc.groups[target].r, sc.groups[source].r
        sm = tree(target).sparse_distance_matrix(tree(source), rt.max() + rs.max(),
                                                 output_type="ndarray")
        i, j = sm["i"].astype(np.int64), sm["j"].astype(np.int64)
        I, J = i + sc.offset(target), j + sc.offset(source)
        if target == source:
            keep = I != J
            I, J = I[keep], J[keep]
        diff = self.p[J] - self.p[I]
        d2 = rowdot(diff, diff)
        keep = d2 < (self.radius[I] + self.radius[J]) ** 2
        I, J, d2 = I[keep], J[keep], d2[keep]
        if np.any(d2 == 0.0):
            k = int(np.flatnonzero(d2 == 0.0)[0])
            self._coincide(int(I[k]), int(J[k]))
        return I, J

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
        sc, p, v = self.scene, self.p, self.v
        a = np.zeros_like(p)
        tree = self._trees()
        for target, seq in sc.operators.items():
            sl = sc.slice(target)
            for op in seq:
                if isinstance(op, Dampen):  # conditions gate only the extra term (Eq. 28)
                    extra = op.extra if op.extra and self.holds(op.when, target, phase, tree) else 0.0
                    a[sl] -= (op.c + extra) * v[sl]
                    continue
                if not self.holds(op.when, target, phase, tree):
                    continue
                if isinstance(op, Force):
                    acc = np.asarray(op.accel, dtype=float)
                    if op.where is None:
                        a[sl] += acc
                    else:
                        a[sl][np.asarray(op.where, dtype=bool)] += acc
                elif isinstance(op, Collide):
                    I, J = self.contacts(target, op.source, tree)
                    c = np.full(len(I), float(op.coeff.c))
                    _accumulate(a, I, col(p[I], p[J], self.radius[I], self.radius[J], c))
                elif isinstance(op, Bind):
                    I, J, c, L0sq = self._bind[id(op)]
                    _accumulate(a, I, bin_(p[I], p[J], L0sq, c))
                elif isinstance(op, Attract):
                    I, J, c = self._attract_pairs(op, target, phase)
                    _accumulate(a, I, attraction(p[I], p[J], c))
        return a

    def holds(self, conditions, target: str, phase: Mapping, tree) -> bool:
        """⟨P⟩ of Eq. 4 for an operator's conditions: phase ones first, contact ones if needed."""
        if not phase_active(conditions, phase):
            return False
        return all(len(self.contacts(target, c.group, tree)[0]) > 0
                   for c in conditions if isinstance(c, Contact))

    def _attract_pairs(self, op, target, phase):
        key = (id(op), tuple(sorted(phase.items())))
        if key not in self._attract:
            sc = self.scene
            i, j, c = attract_pairs(op, sc.groups[target], sc.groups[op.source], phase)
            self._attract[key] = (i + sc.offset(target), j + sc.offset(op.source), c)
        return self._attract[key]

    # ------------------------------------------------------------------ motion
    def damping(self, phase: Mapping) -> np.ndarray:
        """γ per particle: the dampen coefficients (Eq. 9) acting now, extras whose conditions hold."""
        g = np.zeros(len(self.p))
        tree = self._trees()
        for target, seq in self.scene.operators.items():
            sl = self.scene.slice(target)
            for op in seq:
                if isinstance(op, Dampen):
                    extra = op.extra if op.extra and self.holds(op.when, target, phase, tree) else 0.0
                    g[sl] += op.c + extra
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
            a = self.accelerations(phase)
            if self.step_count == 0:
                self.v = self.v + (0.5 * t) * a / (1.0 + 0.5 * t * g)[:, None]
                self.p = self.p + t * self.v
            else:
                self.p, self.v = integrate_verlet(self.p, self.v, a + g[:, None] * self.v, g, t)
            self.step_count += 1
            check(self.scene, self.p, self.v, self.o, self.step_count)
            return
        a = self.accelerations(phase)
        self.p, self.v = integrate(self.p, self.v, a, self.scene.dt)
        self.step_count += 1
        check(self.scene, self.p, self.v, self.o, self.step_count)

