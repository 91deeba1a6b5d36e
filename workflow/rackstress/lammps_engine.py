"""Running a compiled deck through the ``lammps`` Python module, serial or under ``mpiexec``.

The runner executes the deck's setup commands, attaches the Python callback, and drives the
schedule itself: the same commands as the deck's schedule, but each phase's ``run N`` split into
chunks so that the watchdog and the progress bar see the state between chunks. ``run k pre no
post no`` continues a run without recomputing forces, so chunking changes nothing (DESIGN.md §2).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .callbacks import PyForces
from .deck import PY_FIX, Deck
from .errors import DivergenceError, RackstressError
from .reference import find_divergence, divergence_error
from .scene import PhaseEnd

#: Steps between watchdog checks (and progress updates) on LAMMPS.
CHECK_EVERY = 10


class LammpsRun:
    """One LAMMPS instance running one deck (all ranks of ``comm`` take part)."""

    def __init__(self, deck: Deck, out: Path | None, comm=None, dump_every: int = 100,
                 log: bool = True):
        from .mpi import lammps_module, world

        self.deck, self.scene = deck, deck.scene
        self.comm = comm or world()
        out = Path(out).resolve() if out is not None else None
        args = ["-screen", "none", "-nocite", "-log",
                str(out / "log.lammps") if (out is not None and log) else "none"]
        self.lmp = lammps_module().lammps(cmdargs=args, comm=self.comm)
        self.step = 0
        self.py = None
        self._py_on = False
        self._phase = None
        data = (out / "particles.data") if out is not None else None
        if data is None:
            import tempfile
            self._tmp = tempfile.TemporaryDirectory()
            data = Path(self._tmp.name) / "particles.data"
            if self.comm.Get_rank() == 0:
                data.write_text(deck.data_text())
            data = Path(self.comm.bcast(str(data), root=0))
            self.comm.Barrier()
        dump = str(out / "trajectory.dump") if out is not None else None
        for cmd in deck.setup_commands(str(data), dump, dump_every):
            self.command(cmd)
        for cmd in deck.velocity_variables():
            self.command(cmd)
        if deck.python_ops:
            self.py = PyForces(self.lmp, deck, self.comm)

    # ------------------------------------------------------------------ commands
    def command(self, cmd: str) -> None:
        try:
            if "\n" in cmd:
                self.lmp.commands_string(cmd)
            elif cmd.startswith("#"):
                return
            else:
                self.lmp.command(cmd)
        except Exception as exc:
            self._lammps_failed(cmd, exc)

    def _lammps_failed(self, cmd, exc):
        x = self.positions_local()
        if x is not None and not np.isfinite(x[0]).all():
            self.check()  # raises DivergenceError naming the particle
        raise RackstressError(f"LAMMPS failed on '{cmd}' at step {self.step}: {exc}") from None

    # ------------------------------------------------------------------ phases
    def enter_phase(self, phase_vars) -> None:
        """Switch exactly to a phase (the deck's switch commands) and toggle the callback."""
        deck = self.deck
        cmds = deck.switch_commands(phase_vars, self._phase)
        run0 = cmds.index("run 0 post no")
        for cmd in cmds[:run0]:
            self.command(cmd)
        if self.py is not None:
            want = self.py.set_phase(phase_vars)
            if want and not self._py_on:
                self.command(f"fix {PY_FIX} all external pf/callback 1 1")
                self.lmp.set_fix_external_callback(PY_FIX, self.py, self)
            elif self._py_on and not want:
                self.command(f"unfix {PY_FIX}")
            self._py_on = want
        for cmd in cmds[run0:]:
            self.command(cmd)
        self._check_callback()
        self._phase = dict(phase_vars)

    def advance(self, n: int) -> None:
        self.command(f"run {n} pre no post no")
        self.step += n
        self._check_callback()

    def _check_callback(self):
        err = self.py.error if self.py is not None else None
        flag = self.comm.allreduce(err is not None)
        if flag:
            msgs = self.comm.allgather(None if err is None else f"step {err[0]}: {err[1]}")
            msg = next(m for m in msgs if m)
            raise RackstressError(f"the Python operator callback failed at {msg}")

    # ------------------------------------------------------------------ state
    def positions_local(self):
        try:
            nlocal = self.lmp.extract_global("nlocal")
            x = self.lmp.numpy.extract_atom("x")[:nlocal]
            v = self.lmp.numpy.extract_atom("v")[:nlocal]
            tag = self.lmp.numpy.extract_atom("id")[:nlocal].astype(np.int64)
            return x, v, tag
        except Exception:  # noqa: BLE001
            return None

    def check(self) -> None:
        """The watchdog on every rank's atoms; all ranks raise the same DivergenceError."""
        x, v, tag = self.positions_local()
        o = self.scene.original_positions()[tag - 1]
        found = find_divergence(self.scene, x, v, o, tag - 1)
        everything = [f for f in self.comm.allgather(found) if f is not None]
        if everything:
            worst = max(everything, key=lambda f: (not f["finite"], f["disp"]))
            worst["count"] = sum(f["count"] for f in everything)
            raise divergence_error(self.scene, self.step, worst)

    def gather_positions(self) -> np.ndarray:
        """All positions in global particle order (on every rank)."""
        x = self.lmp.gather_atoms("x", 1, 3)
        return np.ctypeslib.as_array(x).reshape(-1, 3).copy()

    def gather_forces(self) -> np.ndarray:
        f = self.lmp.gather_atoms("f", 1, 3)
        return np.ctypeslib.as_array(f).reshape(-1, 3).copy()

    def close(self):
        self.lmp.close()

    # ------------------------------------------------------------------ the whole schedule
    def run_schedule(self, progress=None, check_every: int = CHECK_EVERY,
                     on_phase_end=None) -> None:
        """Every phase of every cycle; ``on_phase_end(PhaseEnd)`` sees each phase's last state."""
        for _, phase, cycle in self.scene.schedule():
            self.enter_phase(phase.vars)
            left = phase.steps
            while left > 0:
                k = min(check_every, left)
                self.advance(k)
                self.check()
                left -= k
                if progress is not None:
                    progress.update(k)
            if on_phase_end is not None:
                on_phase_end(PhaseEnd(self.step, phase.name, dict(phase.vars), cycle,
                                      self.gather_positions()))


def run_lammps(scene, out: Path, mode: str, dump_every: int, progress: bool, deck=None,
               on_phase_end=None):
    """Run ``scene`` on LAMMPS into ``out``; return (final positions, steps done, extra summary)."""
    from .deck import compile_deck
    from .run import progress_bar

    deck = deck or compile_deck(scene, mode)
    runner = LammpsRun(deck, out, dump_every=dump_every)
    try:
        with progress_bar(scene.total_steps, progress, f"{scene.name} (lammps)") as bar:
            try:
                runner.run_schedule(bar, on_phase_end=on_phase_end)
            except DivergenceError as err:
                err.p_end = runner.gather_positions()
                err.steps_done = runner.step
                raise
        p = runner.gather_positions()
        extra = {"ranks": runner.comm.Get_size(), "lammps_version": runner.lmp.version(),
                 "python_operators": [f"{r.target} <- {r.op.kind}" for r in deck.python_ops],
                 "masses": deck.masses}
        return p, runner.step, extra
    finally:
        runner.close()
