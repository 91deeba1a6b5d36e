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

from rackstress.errors import RunDirError, StorageError, storage_error
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
    #: which particles were in LAMMPS' moving group (a deck with a passive group), else None
    moving: np.ndarray | None = None


def _save_npz(path: Path, **arrays) -> None:
    """Write arrays atomically; on an OS error (full disk) no temporary file is left."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise storage_error(exc, "write the checkpoint file", path) from None


def _on_root(fn, comm):
    """``fn`` on rank 0; every rank raises what it raised (no rank waits for a failed one)."""
    from rackstress.lib.mpi import on_root

    return on_root(fn, comm)


def discard_finished(out: Path) -> bool:
    """Remove a finished run's checkpoint (``progress.json``, then ``restart/``) when it was
    written only to survive a kill (``keep`` false: the default interval, not an asked-for
    ``--restart-every``); a finished run is never resumed. Returns whether it was removed.

    ``progress.json`` goes first: it is the commit point, so a kill midway leaves no checkpoint
    named, and the run's ``summary.json`` says it finished."""
    import shutil

    out = Path(out)
    try:
        meta = json.loads((out / PROGRESS).read_text())
    except (OSError, ValueError):
        return False
    if meta.get("keep", True) or not (out / "summary.json").exists():
        return False
    try:
        (out / PROGRESS).unlink()
    except OSError:
        return False
    shutil.rmtree(out / RESTART_DIR, ignore_errors=True)
    return True


class Checkpointer:
    """Writes checkpoints of one :class:`~rackstress.engines.lammps.runner.LammpsRun` (all ranks call)."""

    def __init__(self, out: Path, comm, every: int, *, mode: str, dump_every: int,
                 resumed: Checkpoint | None = None, fingerprint: dict | None = None,
                 keep: bool = True):
        if int(every) < 1:
            raise RunDirError(f"restart interval must be >= 1 step, got {every}")
        self.out, self.comm, self.every = Path(out), comm, int(every)
        self.root = comm.Get_rank() == 0
        self.dir = self.out / RESTART_DIR
        self.meta = {"engine": "lammps", "mode": mode, "dump_every": int(dump_every),
                     "restart_every": self.every, "ranks": comm.Get_size(),
                     "fingerprint": dict(fingerprint or {}),
                     # False: checkpoints only for a kill (the default interval), removed once
                     # the run has finished (:func:`discard_finished`)
                     "keep": bool(keep)}
        self.t0 = time.perf_counter()
        self.wall_before = 0.0
        self.phase_ends: list[str] = []
        self.last = None          # the committed checkpoint's meta
        if resumed is not None:
            self.wall_before = float(resumed.meta.get("wall_s", 0.0))
            self.phase_ends = list(resumed.meta.get("phase_ends", []))
            self.last = resumed.meta
            self.meta["keep"] = bool(resumed.meta.get("keep", True))
        def prepare():
            try:
                self.dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise storage_error(exc, "create the checkpoint directory") from None
            for tmp in self.dir.glob(".*.tmp"):        # a writer killed midway
                tmp.unlink(missing_ok=True)
        _on_root(prepare, comm)
        self.last_step = int(resumed.step) if resumed is not None else 0

    # ------------------------------------------------------------------ phase ends
    def wrap_phase_end(self, on_phase_end):
        """Persist each phase end (for the scene's report after a resume), then pass it on."""
        if on_phase_end is None:
            return None

        def record(pe: PhaseEnd):
            name = f"phase-end-{len(self.phase_ends):05d}.npz"
            _on_root(lambda: _save_npz(self.dir / name, p=pe.p, step=pe.step, cycle=pe.cycle,
                                       meta=json.dumps({"phase": pe.phase,
                                                        "vars": dict(pe.vars)})), self.comm)
            self.phase_ends.append(name)
            on_phase_end(pe)
        return record

    # ------------------------------------------------------------------ writing
    def maybe(self, runner, phase_index: int, phase_done: int, cycle: int) -> None:
        if runner.step // self.every > self.last_step // self.every:
            self.write(runner, phase_index, phase_done, cycle)

    def final(self, runner, phase_index: int, phase_done: int, cycle: int) -> None:
        """A checkpoint at the last step (if none there yet): resuming a run killed while it
        wrote its summary then has nothing left to step."""
        if self.last_step != runner.step or self.last is None:
            self.write(runner, phase_index, phase_done, cycle)

    def write(self, runner, phase_index: int, phase_done: int, cycle: int) -> None:
        step = runner.step
        x, v = runner.state()       # a deck with a passive group: only the moving rows gathered
        f = runner.gather_forces()
        moving = runner.moving_mask() if hasattr(runner, "moving_mask") else None
        stem = f"state-{step:09d}"
        restart = self.dir / f"{stem}.restart"
        part = self.dir / f".{stem}.restart.tmp"
        # noinit: no re-initialization or atom migration, so the run goes on untouched; written
        # under a temporary name, so a full disk leaves no partial restart file under its name
        try:
            runner.command(f"write_restart {runner.path_word(part, dump=True)} noinit")
        except Exception:
            _on_root(lambda: part.unlink(missing_ok=True), self.comm)
            raise
        _on_root(lambda: os.replace(part, restart), self.comm)
        runner.realign(f)
        meta = dict(self.meta, step=int(step), phase_index=int(phase_index),
                    phase_done=int(phase_done), cycle=int(cycle),
                    total_steps=runner.scene.total_steps,
                    state=f"{RESTART_DIR}/{stem}.npz", restart=f"{RESTART_DIR}/{stem}.restart",
                    phase_ends=list(self.phase_ends),
                    wall_s=self.wall_before + time.perf_counter() - self.t0,
                    written=time.strftime("%Y-%m-%dT%H:%M:%S"))
        def commit():
            try:
                extra = {} if moving is None else {"moving": moving}
                _save_npz(self.out / meta["state"], x=x, v=v, f=f, **extra)
                write_json(self.out / PROGRESS, meta)          # the commit point
            except OSError as exc:
                # not committed: this checkpoint's files go, the previous one stays whole
                for name in (meta["state"], meta["restart"]):
                    (self.out / name).unlink(missing_ok=True)
                (self.out / f".{PROGRESS}.tmp").unlink(missing_ok=True)
                if isinstance(exc, StorageError):
                    raise
                raise storage_error(exc, "write the checkpoint") from None
            keep = {Path(meta["state"]).name, Path(meta["restart"]).name}
            for old in self.dir.glob("state-*"):
                if old.name not in keep:
                    old.unlink(missing_ok=True)
        _on_root(commit, self.comm)
        self.last, self.last_step = meta, step
