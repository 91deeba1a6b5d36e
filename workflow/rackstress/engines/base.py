"""The one interface every engine answers, so that one driver (:mod:`rackstress.engines.driver`)
steps any scene through its schedule.

An engine holds the state of one scene (positions p and velocities v of Eq. 5) and moves it by
``motion = netForce • integrate(t)`` (Eqs. 6–7). The driver asks it to enter a phase, to advance
a few steps, to check the watchdog, and for the gathered state; the engine writes its own
trajectory frames every ``dump_every`` steps. Both engines raise
:class:`~rackstress.errors.DivergenceError` for whatever stops a run that flew apart — the
watchdog, LAMMPS losing atoms, a callback that no longer finds a partner — naming the step and
the particle.
"""
from __future__ import annotations

from typing import Mapping, Protocol, runtime_checkable

import numpy as np

from rackstress.model.scene import Scene


@runtime_checkable
class Engine(Protocol):
    """What :func:`rackstress.engines.driver.drive` needs of an engine.

    Attributes
    ----------
    scene : Scene
        The scene being stepped.
    step_count : int
        Steps done so far (the iteration counter of Eq. 5).
    check_every : int
        Steps between watchdog checks: 1 on the reference engine, 10 on LAMMPS with the
        Python callback, 100 with the plugin alone (its styles name a non-finite term's step
        themselves).
    root : bool
        Whether this process is rank 0 of the engine's ranks (writes records and files).
    """

    scene: Scene
    step_count: int
    check_every: int
    root: bool

    def enter_phase(self, phase_vars: Mapping) -> None:
        """Switch the operators' phase conditions (⟨P⟩ of Eq. 4) to ``phase_vars``."""

    def advance(self, n: int) -> None:
        """Move the state ``n`` steps (Eq. 5 each); frames are written as they fall due."""

    def check(self) -> None:
        """The watchdog: raise DivergenceError if a particle is non-finite or out of bound."""

    def positions(self) -> np.ndarray:
        """All positions in global particle order (every rank takes part, every rank gets them)."""

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities in global particle order (gathered, on every rank)."""

    def write_frame(self) -> None:
        """Write a trajectory frame of the current step (the driver's last step)."""

    def close(self) -> None:
        """Release the engine (files, LAMMPS instance)."""


class Resumable(Engine, Protocol):
    """An engine that can start from a checkpoint (LAMMPS)."""

    def restore(self, checkpoint) -> None:
        """Re-enter the checkpoint's phase with its step, positions, velocities and forces."""


class Checkpoints(Protocol):
    """What the driver asks of a checkpoint writer (:class:`rackstress.runs.checkpoint.Checkpointer`)."""

    def maybe(self, engine, phase_index: int, phase_done: int, cycle: int) -> None:
        """Write a checkpoint if one is due at the engine's step."""

    def final(self, engine, phase_index: int, phase_done: int, cycle: int) -> None:
        """Write a checkpoint at the last step (if none is there yet)."""
