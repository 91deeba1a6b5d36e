"""Checkpoints of long LAMMPS runs: what is written, every N steps, and the commit point.

The format and the guarantees are described in :mod:`rackstress.runs.resume`, which reads them.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rackstress.errors import RunDirError
from rackstress.lib.jsonio import write_json
from rackstress.model.scene import PhaseEnd

PROGRESS = "progress.json"
RESTART_DIR = "restart"


def default_restart_every(total_steps: int) -> int:
    """About ten checkpoints a run, at least 100 steps apart."""
    return max(100, -(-int(total_steps) // 10))


@dataclass
class Checkpoint:
    """A loaded checkpoint: where the schedule stood and the exact state (global order)."""

    step: int
    phase_index: int
    phase_done: int
    cycle: int
    x: np.ndarray
    v: np.ndarray
    f: np.ndarray
    meta: dict = field(default_factory=dict)


def _save_npz(path: Path, **arrays) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(tmp, path)


class Checkpointer:
    """Writes checkpoints of one :class:`~rackstress.engines.lammps.runner.LammpsRun` (all ranks call)."""

    def __init__(self, out: Path, comm, every: int, *, mode: str, dump_every: int,
                 resumed: Checkpoint | None = None):
        if int(every) < 1:
            raise RunDirError(f"restart interval must be >= 1 step, got {every}")
        self.out, self.comm, self.every = Path(out), comm, int(every)
        self.root = comm.Get_rank() == 0
        self.dir = self.out / RESTART_DIR
        self.meta = {"engine": "lammps", "mode": mode, "dump_every": int(dump_every),
                     "restart_every": self.every, "ranks": comm.Get_size()}
        self.t0 = time.perf_counter()
        self.wall_before = 0.0
        self.phase_ends: list[str] = []
        self.last = None          # the committed checkpoint's meta
        if resumed is not None:
            self.wall_before = float(resumed.meta.get("wall_s", 0.0))
            self.phase_ends = list(resumed.meta.get("phase_ends", []))
            self.last = resumed.meta
        if self.root:
            self.dir.mkdir(parents=True, exist_ok=True)
        self.last_step = int(resumed.step) if resumed is not None else 0

    # ------------------------------------------------------------------ phase ends
    def wrap_phase_end(self, on_phase_end):
        """Persist each phase end (for the scene's report after a resume), then pass it on."""
        if on_phase_end is None:
            return None

        def record(pe: PhaseEnd):
            if self.root:
                name = f"phase-end-{len(self.phase_ends):05d}.npz"
                _save_npz(self.dir / name, p=pe.p, step=pe.step, cycle=pe.cycle,
                          meta=json.dumps({"phase": pe.phase, "vars": dict(pe.vars)}))
                self.phase_ends.append(name)
            on_phase_end(pe)
        return record

    # ------------------------------------------------------------------ writing
    def maybe(self, runner, phase_index: int, phase_done: int, cycle: int) -> None:
        if runner.step // self.every > self.last_step // self.every:
            self.write(runner, phase_index, phase_done, cycle)

    def final(self, runner) -> None:
        """A checkpoint at the last step (if none there yet): resuming a run killed while it
        wrote its summary then has nothing left to step."""
        if self.last_step != runner.step or self.last is None:
            sched = list(runner.scene.schedule())
            k = len(sched) - 1
            self.write(runner, k, sched[k][1].steps, sched[k][2])

    def write(self, runner, phase_index: int, phase_done: int, cycle: int) -> None:
        step = runner.step
        x = runner.gather_positions()
        v = runner.gather_velocities()
        f = runner.gather_forces()
        stem = f"state-{step:09d}"
        restart = self.dir / f"{stem}.restart"
        # noinit: no re-initialization or atom migration, so the run goes on untouched
        runner.command(f"write_restart {restart} noinit")
        runner.realign(f)
        meta = dict(self.meta, step=int(step), phase_index=int(phase_index),
                    phase_done=int(phase_done), cycle=int(cycle),
                    total_steps=runner.scene.total_steps,
                    state=f"{RESTART_DIR}/{stem}.npz", restart=f"{RESTART_DIR}/{stem}.restart",
                    phase_ends=list(self.phase_ends),
                    wall_s=self.wall_before + time.perf_counter() - self.t0,
                    written=time.strftime("%Y-%m-%dT%H:%M:%S"))
        if self.root:
            _save_npz(self.out / meta["state"], x=x, v=v, f=f)
            write_json(self.out / PROGRESS, meta)          # the commit point
            keep = {Path(meta["state"]).name, Path(meta["restart"]).name}
            for old in self.dir.glob("state-*"):
                if old.name not in keep:
                    old.unlink(missing_ok=True)
        self.last, self.last_step = meta, step
        self.comm.Barrier()
