"""The one loop that steps a scene through its schedule, for every engine and every caller.

``rackstress run``, ``--resume``, ``batch``, the benchmarks, the scripts and the tests all call
:func:`drive`: every phase of every cycle (the schedule is generated lazily, so any number of
steps costs nothing up front), each phase's steps in chunks of ``engine.check_every`` (cut at
each checkpoint's step) with the watchdog after each chunk, the progress bar, a
:class:`~rackstress.model.scene.PhaseEnd` record at each phase end (what a scene's ``report``
reads), checkpoints, and the frame of the last step (written even when the number of steps is
not a multiple of the dump interval).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rackstress.errors import DivergenceError
from rackstress.model.scene import PhaseEnd


@dataclass
class Outcome:
    """How a driven run ended: the steps done and the final positions (global order); and
    where the driver's wall time went (``timings``: ``steps_s`` in the engine's chunks,
    ``checks_s`` in the watchdog after them, ``between_s`` the rest of the loop — progress,
    checkpoints, phase ends): what a thread beside it (``rackstress run``'s head start) slows."""

    steps: int
    positions: np.ndarray
    timings: dict = field(default_factory=dict)


def drive(engine, *, progress=None, on_phase_end=None, checkpoint=None, resume=None,
          check_every: int | None = None, final_frame: bool = True,
          on_chunk=None) -> Outcome:
    """Step ``engine`` through its scene's whole schedule.

    Parameters
    ----------
    engine : rackstress.engines.base.Engine
        The reference engine or a LAMMPS runner, already set up.
    progress : object with ``update(n)``, optional
        A progress bar (:func:`rackstress.lib.progress.progress_bar`).
    on_phase_end : callable, optional
        Called with a :class:`PhaseEnd` at the end of every phase.
    checkpoint : rackstress.engines.base.Checkpoints, optional
        Asked after every chunk and phase end whether to write a checkpoint.
    resume : rackstress.runs.checkpoint.Checkpoint, optional
        Start from this checkpoint: earlier phases are skipped, its phase is re-entered exactly
        (``engine.restore``).
    check_every : int, optional
        Steps between watchdog checks (default: the engine's own).
    final_frame : bool
        Write a frame of the last step if the engine's dump interval did not fall on it.
    on_chunk : callable, optional
        Called with the engine after every chunk (after its watchdog check): what a benchmark
        observes step by step (``check_every=1``).

    Returns
    -------
    Outcome
        Steps done and the final positions.

    Raises
    ------
    DivergenceError
        With ``p_end`` (positions when stopped) and ``steps_done`` attached.

    Examples
    --------
    >>> from rackstress import scenes
    >>> from rackstress.engines.reference import Reference
    >>> sc = scenes.build("plane-bound", d=2).with_steps(5)
    >>> drive(Reference(sc)).steps
    5
    """
    import time

    scene = engine.scene
    every = int(check_every or engine.check_every)
    t_all, t_steps, t_checks = time.perf_counter(), 0.0, 0.0
    ck_every = int(getattr(checkpoint, "every", 0) or 0)
    last = None
    try:
        for k, (_, phase, cycle) in enumerate(scene.schedule()):
            left = phase.steps
            if resume is not None and k < resume.phase_index:
                continue
            if resume is not None and k == resume.phase_index:
                engine.restore(resume)
                left = phase.steps - resume.phase_done
                last = (k, phase.steps, cycle)
                if left == 0:       # the checkpoint was at this phase's end
                    continue
            else:
                engine.enter_phase(phase.vars)
            while left > 0:
                n = min(every, left)
                if ck_every:        # a chunk ends at each checkpoint's step, however long
                    n = min(n, ck_every - engine.step_count % ck_every)
                t = time.perf_counter()
                engine.advance(n)
                t1 = time.perf_counter()
                engine.check()
                t_steps, t_checks = t_steps + (t1 - t), t_checks + (time.perf_counter() - t1)
                left -= n
                if on_chunk is not None:
                    on_chunk(engine)
                if progress is not None:
                    progress.update(n)
                if left > 0 and checkpoint is not None:
                    checkpoint.maybe(engine, k, phase.steps - left, cycle)
            last = (k, phase.steps, cycle)
            if on_phase_end is not None:
                on_phase_end(PhaseEnd(engine.step_count, phase.name, dict(phase.vars), cycle,
                                      engine.positions()))
            if checkpoint is not None:
                checkpoint.maybe(engine, k, phase.steps, cycle)
        resumed_at_end = resume is not None and last is not None and engine.step_count == resume.step
        if final_frame and not resumed_at_end:
            engine.write_frame()
        if checkpoint is not None and last is not None:
            checkpoint.final(engine, *last)
    except DivergenceError as err:
        if getattr(err, "p_end", None) is None:
            err.p_end = engine.positions()
        err.steps_done = engine.step_count
        raise
    wall = time.perf_counter() - t_all
    return Outcome(engine.step_count, engine.positions(),
                   {"steps_s": t_steps, "checks_s": t_checks,
                    "between_s": wall - t_steps - t_checks})
