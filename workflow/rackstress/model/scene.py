"""A scene: named particle groups, the operator sequence acting on each, and a schedule of phases.

This is the paper's model of motion (Eqs. 6, 26, 32–33) as data: for every group the list of
operators composed left to right (Eqs. 2–3), then ``integrate(dt)`` over all particles at once.
Engines (reference, LAMMPS) take a :class:`Scene` and nothing else.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from rackstress.model import operators as ops_mod
from rackstress.model.units import PAPER
from rackstress.errors import SceneError

#: Distance below which two particles count as coincident (their col/bin is undefined): this
#: many units, or a few rounding steps of the coordinates' magnitude if that is larger. Not
#: relative to the scene's size: two particles 1 unit apart stay apart however far a third is.
COINCIDENT_TOL = 1e-9


@dataclass(frozen=True)
class Phase:
    """One phase of the schedule: ``steps`` iterations of motion with the phase variables ``vars``.

    MagPod's gait phase (r, l) = (4, 6) is ``Phase('4-6', 1200, {'r': 4, 'l': 6})``.
    """

    name: str
    steps: int
    vars: Mapping = field(default_factory=dict)
    #: physical time of the phase when it was given as a duration (``steps`` = round(duration
    #: / dt)); :meth:`Scene.with_dt` recomputes ``steps`` from it.
    duration: float | None = None


@dataclass(frozen=True)
class PhaseEnd:
    """The state when a phase of the schedule ends: what a scene's ``report`` looks at."""

    step: int
    phase: str | None
    vars: Mapping
    cycle: int
    p: np.ndarray


@dataclass
class Scene:
    """Groups + per-group operator sequences + schedule + time step ``dt`` (Eq. 5's t).

    ``bound`` is the watchdog's limit on any particle's distance from its original position.
    ``params`` records how the scene was built (for the summary and for rebuilding with --set).
    """

    name: str
    groups: dict
    operators: dict
    phases: list
    dt: float = 0.01
    cycles: int = 1
    bound: float = 1.0e4
    params: dict = field(default_factory=dict)
    #: Optional ``report(scene, records) -> dict`` over the states at phase ends (a list of
    #: :class:`PhaseEnd`, the first being the initial state); its result goes into the summary.
    report: object = None
    #: physical time of the whole run when the scene gave ``duration`` instead of ``steps``
    #: (total steps = round(duration / dt)); :meth:`with_dt` keeps it, so a dt sweep compares
    #: the same time.
    duration: float | None = None
    #: Run exactly this many steps (the cycle of phases repeated or cut short, generated
    #: lazily by :meth:`schedule`); None: ``cycles`` whole cycles. Set by :meth:`with_steps`.
    limit: int | None = None
    #: ``"euler"``: Eq. 5, the paper's (default); ``"verlet"``: the second-order mode of
    #: :mod:`rackstress.model.verlet` (leapfrog with trapezoidal damping).
    integrator: str = "euler"
    #: what the scene's numbers mean (:mod:`rackstress.model.units`); the paper's dimensionless
    #: units unless a scene declares another system
    units: object = None
    #: ``"dynamic"``: time stepping (the paper's); ``"static"``: find the equilibrium
    analysis: str = "dynamic"

    def __post_init__(self):
        if self.units is None:
            self.units = PAPER
        # engines key what they prepare by an operator's place (group, index in its sequence),
        # so the same Dampen(1) object may well sit on several groups
        self.operators = {t: list(seq) for t, seq in self.operators.items()}
        self.validate()
        starts = np.cumsum([0] + [g.n for g in self.groups.values()])
        self._offset = {name: int(s) for name, s in zip(self.groups, starts[:-1])}

    # ------------------------------------------------------------------ structure
    @property
    def n_particles(self) -> int:
        return sum(g.n for g in self.groups.values())

    def offset(self, group: str) -> int:
        """Index of the group's first particle in the engines' global particle order."""
        return self._offset[group]

    def slice(self, group: str) -> slice:
        start = self._offset[group]
        return slice(start, start + self.groups[group].n)

    def group_of(self, index: int) -> tuple[str, int]:
        """(group name, index within the group) of a global particle index."""
        for name, g in self.groups.items():
            start = self._offset[name]
            if start <= index < start + g.n:
                return name, index - start
        raise IndexError(index)

    def original_positions(self) -> np.ndarray:
        """o of every particle in global order (built once; read-only, copy to change it)."""
        if getattr(self, "_o", None) is None:
            self._o = np.concatenate([g.o for g in self.groups.values()])
            self._o.flags.writeable = False
        return self._o

    def held(self) -> np.ndarray:
        """Which particles are held at their original positions (supports), in global order."""
        if getattr(self, "_held", None) is None:
            self._held = np.concatenate([g.held for g in self.groups.values()])
            self._held.flags.writeable = False
        return self._held

    def fixed(self) -> np.ndarray:
        """n×3: the directions each particle is held in (supports, rollers), global order."""
        return np.concatenate([g.fixed for g in self.groups.values()])

    def prescribed(self) -> np.ndarray:
        """n×3 prescribed displacements of the fixed directions (zero unless a load gives one)."""
        return np.concatenate([g.u0 if g.u0 is not None else np.zeros((g.n, 3))
                               for g in self.groups.values()])

    def masses(self) -> np.ndarray:
        """Mass of every particle in the scene's units (:meth:`Group.mass`), global order."""
        return np.concatenate([np.full(g.n, g.mass(self.units)) for g in self.groups.values()])

    def speed_limits(self) -> np.ndarray | None:
        """Each particle's material wave speed √(E/ρ) in the scene's units (∞ where its group
        has no material), or None when no group has one (the paper's scenes).

        A particle moving faster than its material's wave speed carries a strain of order one
        (a wave's particle velocity is ε·c): the elastic lattice has blown up, which the
        watchdog stops as a divergence."""
        if getattr(self, "_speed", False) is False:
            lim = [np.full(g.n, np.sqrt(g.material.in_units(self.units)["E"]
                                        / g.material.in_units(self.units)["density"])
                           if g.material is not None else np.inf)
                   for g in self.groups.values()]
            self._speed = None if all(g.material is None for g in self.groups.values()) \
                else np.concatenate(lim)
            if self._speed is not None:
                self._speed.flags.writeable = False
        return self._speed

    def initial_velocities(self) -> np.ndarray:
        """v at step 0 of every particle in global order (zero unless a group sets ``v0``)."""
        return np.concatenate([g.v0 for g in self.groups.values()])

    def radii(self) -> np.ndarray:
        """r of every particle in global order (built once; read-only)."""
        if getattr(self, "_r", None) is None:
            self._r = np.concatenate([g.r for g in self.groups.values()])
            self._r.flags.writeable = False
        return self._r

    @property
    def steps_per_cycle(self) -> int:
        return sum(p.steps for p in self.phases)

    @property
    def total_steps(self) -> int:
        if self.limit is not None:
            return int(self.limit)
        return self.steps_per_cycle * self.cycles

    def schedule(self):
        """Yield (first_step, phase, cycle) for every phase of every cycle, in order.

        Generated as it is walked: a run of 10¹² steps holds one phase at a time."""
        step = 0
        if self.limit is None:
            for cycle in range(self.cycles):
                for phase in self.phases:
                    yield step, phase, cycle
                    step += phase.steps
            return
        end = int(self.limit)
        if end == 0 or self.steps_per_cycle == 0:
            first = self.phases[0]
            yield 0, Phase(first.name, 0, first.vars), 0
            return
        cycle = 0
        while step < end:
            for phase in self.phases:
                take = min(phase.steps, end - step)
                if take > 0:
                    yield step, (phase if take == phase.steps
                                 else Phase(phase.name, take, phase.vars)), cycle
                    step += take
                if step >= end:
                    break
            cycle += 1

    def with_steps(self, steps: int) -> "Scene":
        """The same scene run for exactly ``steps`` iterations (its cycle of phases repeated or
        cut short; nothing is built per phase, so any number of steps costs nothing up front)."""
        if int(steps) != steps or steps < 0:
            raise SceneError(f"steps must be a non-negative integer, got {steps!r}")
        spc = self.steps_per_cycle
        cycles = max(1, -(-int(steps) // spc)) if spc else 1
        return Scene(self.name, self.groups, self.operators, self.phases, self.dt, cycles,
                     self.bound, {**self.params, "steps": int(steps)}, self.report,
                     duration=self.duration, limit=int(steps), integrator=self.integrator,
                     units=self.units, analysis=self.analysis)

    def with_dt(self, dt: float) -> "Scene":
        """The same scene with time step ``dt``; what was given as a physical time stays one.

        A phase given by ``duration`` gets round(duration / dt) steps, and a scene given by a
        total ``duration`` is run for round(duration / dt) iterations, so a dt sweep compares
        the same physical time; a scene given in steps keeps its steps.

        Example
        -------
        >>> sc.with_dt(0.005).total_steps     # doctest: +SKIP  (duration = 3: 600 steps)
        """
        dt = float(dt)
        if not (np.isfinite(dt) and dt > 0):
            raise SceneError(f"scene '{self.name}': time step dt must be positive, got {dt!r}")
        if self.duration is None and all(p.duration is None for p in self.phases):
            self.dt = dt                      # given in steps: only the step changes
            self.params["dt"] = dt
            self.validate()
            return self
        phases = [Phase(p.name, steps_for(p.duration, dt, f"phase '{p.name}'"), p.vars,
                        p.duration) if p.duration is not None else p for p in self.phases]
        ops = {t: [op.with_dt(dt) for op in seq] for t, seq in self.operators.items()}
        sc = Scene(self.name, self.groups, ops, phases, dt, self.cycles, self.bound,
                   {**self.params, "dt": dt}, self.report, self.duration, self.limit,
                   self.integrator, self.units, self.analysis)
        if self.duration is not None:
            sc = sc.with_steps(steps_for(self.duration, dt, "duration"))
            sc.duration = self.duration
            sc.params["duration"] = self.duration
        if "steps" in sc.params:      # the record says what runs (phase durations at this dt)
            sc.params["steps"] = sc.total_steps
        return sc

    # ------------------------------------------------------------------ validation
    def validate(self) -> None:
        if not self.groups:
            raise SceneError(f"scene '{self.name}' has no groups")
        for key, g in self.groups.items():
            if key != g.name:
                raise SceneError(f"scene '{self.name}': group stored as '{key}' is named '{g.name}'")
            if g.host is not None and g.host not in self.groups:
                raise SceneError(f"rack group '{g.name}' names unknown host '{g.host}'")
        for target, seq in self.operators.items():
            if target not in self.groups:
                raise SceneError(f"scene '{self.name}': operators given for unknown group "
                                 f"'{target}' (groups: {', '.join(self.groups)})")
            for op in seq:
                if not isinstance(op, tuple(ops_mod.OPERATOR_KINDS.values())):
                    raise SceneError(f"scene '{self.name}': '{op!r}' on '{target}' is not an "
                                     f"operator (known: {', '.join(ops_mod.OPERATOR_KINDS)})")
                ops_mod.check_operator(op, target, self.groups)
        if self.analysis not in ("dynamic", "static"):
            raise SceneError(f"scene '{self.name}': analysis must be 'dynamic' (time stepping) "
                             f"or 'static' (the equilibrium), got {self.analysis!r}")
        if self.analysis == "dynamic" and any(g.u0 is not None and np.any(g.u0)
                                              for g in self.groups.values()):
            raise SceneError(f"scene '{self.name}': a prescribed displacement is a static "
                             "analysis' load; set analysis = \"static\" (a dynamic run holds "
                             "supports at their original positions)")
        if self.integrator not in ("euler", "verlet"):
            raise SceneError(f"scene '{self.name}': integrator must be 'euler' (Eq. 5) or "
                             f"'verlet', got {self.integrator!r}")
        if self.integrator == "verlet":
            rubbing = [t for t, seq in self.operators.items()
                       if any(getattr(op, "mu", 0.0) > 0 for op in seq)]
            if rubbing:
                raise SceneError(f"scene '{self.name}': the friction of '{rubbing[0]}''s "
                                 "contact reads the velocities of Eq. 5's step; it is not "
                                 "modelled with integrator 'verlet': use 'euler'")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise SceneError(f"scene '{self.name}': time step dt must be positive, got {self.dt!r}")
        if not self.phases:
            raise SceneError(f"scene '{self.name}' has no phases")
        for p in self.phases:
            if int(p.steps) != p.steps or p.steps < 0:
                raise SceneError(f"phase '{p.name}': steps must be a non-negative integer, "
                                 f"got {p.steps!r}")
        if int(self.cycles) != self.cycles or self.cycles < 1:
            raise SceneError(f"scene '{self.name}': cycles must be a positive integer")
        if not self.bound > 0:
            raise SceneError(f"scene '{self.name}': watchdog bound must be positive")
        for name, g in self.groups.items():
            if not np.isfinite(g.o).all():
                k = int(np.flatnonzero(~np.isfinite(g.o).all(axis=1))[0])
                raise SceneError(f"scene '{self.name}': '{name}' particle {k} has a non-finite "
                                 f"position {g.o[k].tolist()}")
            r = np.asarray(g.r, dtype=float)
            bad = ~(np.isfinite(r) & (r > 0) & (r <= self.bound))
            if bad.any():
                k = int(np.flatnonzero(bad)[0])
                raise SceneError(f"scene '{self.name}': '{name}' particle {k} has radius "
                                 f"{float(r[k])!r}; a radius must be positive, finite and at most the "
                                 f"watchdog bound {self.bound:g} (the collision test squares "
                                 "the sum of two radii)")
            u0 = getattr(g, "u0", None)
            if u0 is not None:
                u = np.asarray(u0, dtype=float)     # the norm scaled: 1e300 squared overflows
                big = np.abs(u).max(axis=1)
                with np.errstate(invalid="ignore", divide="ignore"):
                    far = ~(np.nan_to_num(big * np.linalg.norm(
                        u / np.where(big > 0, big, 1.0)[:, None], axis=1), nan=np.inf)
                        <= self.bound)
                if far.any():
                    k = int(np.flatnonzero(far)[0])
                    raise SceneError(
                        f"scene '{self.name}': '{name}' particle {k} has a prescribed "
                        f"displacement {np.asarray(u0[k]).tolist()}, farther than the watchdog "
                        f"bound {self.bound:g}: the run would be stopped as diverged at once "
                        "(check the displacement's length unit, or raise 'bound')")
        for target, seq in self.operators.items():
            for op in seq:
                where = getattr(op, "where", None)
                if isinstance(op, ops_mod.Force) and where is not None \
                        and not np.asarray(where, dtype=bool).any():
                    raise SceneError(f"scene '{self.name}': the force {tuple(op.accel)} on "
                                     f"'{target}' selects no particle (its 'where' is false "
                                     "everywhere): remove it or widen 'where'")
        self._check_coincident()

    def _check_coincident(self) -> None:
        o = np.concatenate([g.o for g in self.groups.values()])
        ulp = 8 * np.finfo(float).eps * float(np.abs(o).max()) if len(o) else 0.0
        from rackstress.lib.cells import close_pairs

        pairs = close_pairs(o, max(COINCIDENT_TOL, ulp))
        if len(pairs):
            a, b = (int(x) for x in pairs[0])
            starts = np.cumsum([0] + [g.n for g in self.groups.values()])
            names = list(self.groups)

            def where(k):
                gi = int(np.searchsorted(starts, k, side="right") - 1)
                return f"'{names[gi]}' particle {k - starts[gi]}"

            raise SceneError(
                f"scene '{self.name}': {where(a)} and {where(b)} are coincident at {o[a]} "
                f"({len(pairs)} coincident pair(s) in all). Collision and binding forces "
                "(Eqs. 10, 12) divide by the squared distance, which is zero there: move or "
                "remove one of them.")


def steps_for(duration: float, dt: float, what: str = "duration") -> int:
    """Iterations covering the physical time ``duration`` at time step ``dt``: round(T / dt).

    The time reached, steps·dt, is within dt/2 of ``duration``.
    """
    if not (np.isfinite(duration) and duration >= 0):
        raise SceneError(f"{what} must be a non-negative physical time, got {duration!r}")
    return int(round(duration / dt))
