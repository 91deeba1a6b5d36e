"""Running a compiled deck through the ``lammps`` Python module, serial or under ``mpiexec``.

The runner executes the deck's setup commands, attaches the Python callback, and drives the
schedule itself: the same commands as the deck's schedule, but each phase's ``run N`` split into
chunks so that the watchdog and the progress bar see the state between chunks. ``run k pre no
post no`` continues a run without recomputing forces, so chunking changes nothing (docs/model.md, "On LAMMPS").
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rackstress.engines.lammps.callback import PyForces
from rackstress.engines.lammps.deck import PY_FIX, Deck
from rackstress.errors import RackstressError
from rackstress.engines.watchdog import divergence_error, find_divergence
from rackstress.model.scene import PhaseEnd

#: Steps between watchdog checks (and progress updates) on LAMMPS.
CHECK_EVERY = 10


def balance_commands(scene, nranks: int) -> list[str]:
    """Load balancing a scene asks for in ``params['balance']`` (``sediment-large``).

    ``rcb``: ``comm_style tiled`` and one recursive-coordinate-bisection ``balance`` in which
    every particle outside the passive ``sediment`` group weighs ``robot_weight`` (the robot's
    particles carry the Python operators); ``shift``: ``balance shift xz`` on particle counts.
    Nothing in serial, nor for scenes that ask for nothing (every scene but sediment-large).
    """
    how = (scene.params or {}).get("balance", "none")
    if nranks < 2 or how in (None, "none"):
        return []
    if how == "shift":
        return ["balance 1.05 shift xz 20 1.05"]
    if how == "rcb":
        w = float(scene.params.get("robot_weight", 20.0))
        L = ["comm_style tiled"]
        if "sediment" in scene.groups:
            L += ["group rs_active subtract all sediment",
                  f"balance 1.0 rcb weight group 1 rs_active {w!r}"]
        else:
            L += ["balance 1.0 rcb"]
        return L
    raise RackstressError(f"unknown balance '{how}' (rcb, shift or none)")


class LammpsRun:
    """One LAMMPS instance running one deck (all ranks of ``comm`` take part)."""

    def __init__(self, deck: Deck, out: Path | None, comm=None, dump_every: int = 100,
                 log: bool = True, append: bool = False):
        """``append``: continue an interrupted run in ``out`` (resume): the log and the
        trajectory are appended to, not replaced."""
        from rackstress.lib.mpi import lammps_module, world

        self.deck, self.scene = deck, deck.scene
        self.comm = comm or world()
        out = Path(out).resolve() if out is not None else None
        self.out = out
        logfile = str(out / "log.lammps") if (out is not None and log) else "none"
        args = ["-screen", "none", "-nocite", "-log", "none" if append else logfile]
        self.lmp = lammps_module().lammps(cmdargs=args, comm=self.comm)
        if append and logfile != "none":
            self.lmp.command(f"log {logfile} append")
        self.step = 0
        self._ids = np.arange(1, self.scene.n_particles + 1)
        self.py = None
        self._py_on = False
        self._phase = None
        self._dump_id = None
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
            if dump is not None and cmd.startswith("dump ") and " all custom " in cmd:
                self._dump_id = cmd.split()[1]
                if append:
                    self.command(f"dump_modify {self._dump_id} append yes")
        for cmd in deck.velocity_variables():
            self.command(cmd)
        for cmd in balance_commands(self.scene, self.comm.Get_size()):
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
        self._toggle_callback(phase_vars)
        for cmd in cmds[run0:]:
            self.command(cmd)
        self._check_callback()
        self._phase = dict(phase_vars)

    def _toggle_callback(self, phase_vars) -> None:
        """The fix external exists only in phases where a Python operator is active."""
        if self.py is None:
            return
        want = self.py.set_phase(phase_vars)
        if want and not self._py_on:
            self.command(f"fix {PY_FIX} all external pf/callback 1 1")
            self.lmp.set_fix_external_callback(PY_FIX, self.py, self)
        elif self._py_on and not want:
            self.command(f"unfix {PY_FIX}")
        self._py_on = want

    def advance(self, n: int) -> None:
        self.command(f"run {n} pre no post no")
        self.step += n
        self._check_callback()

    def _check_callback(self):
        err = self.py.error if self.py is not None else None
        flag = self.comm.allreduce(err is not None)
        if flag:
            # a callback that failed because particles flew apart (a partner out of ghost
            # reach) is a divergence: let the watchdog name it first
            self.check()
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
        o = self.scene.original_positions()
        if len(tag) == len(o) and tag[0] == 1 and np.array_equal(tag, self._ids):
            found = find_divergence(self.scene, x, v, o)    # row k holds particle k
        else:
            found = find_divergence(self.scene, x, v, o[tag - 1], tag - 1)
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
                     on_phase_end=None, checkpoint=None, resume=None) -> None:
        """Every phase of every cycle; ``on_phase_end(PhaseEnd)`` sees each phase's last state.

        ``checkpoint``: a :class:`rackstress.runs.resume.Checkpointer`, asked after every chunk
        (and after each phase end) whether to write one. ``resume``: a loaded checkpoint
        (:class:`rackstress.runs.resume.Checkpoint`): phases before it are skipped and its phase is
        re-entered exactly (:meth:`restore`).
        """
        for k, (_, phase, cycle) in enumerate(self.scene.schedule()):
            left = phase.steps
            if resume is not None:
                if k < resume.phase_index:
                    continue
                if k == resume.phase_index:
                    self.restore(resume)
                    left = phase.steps - resume.phase_done
                    if left == 0:       # the checkpoint was at this phase's end
                        continue
                else:
                    self.enter_phase(phase.vars)
            else:
                self.enter_phase(phase.vars)
            while left > 0:
                k_ = min(check_every, left)
                self.advance(k_)
                self.check()
                left -= k_
                if progress is not None:
                    progress.update(k_)
                if left > 0 and checkpoint is not None:
                    checkpoint.maybe(self, k, phase.steps - left, cycle)
            if on_phase_end is not None:
                on_phase_end(PhaseEnd(self.step, phase.name, dict(phase.vars), cycle,
                                      self.gather_positions()))
            if checkpoint is not None:
                checkpoint.maybe(self, k, phase.steps, cycle)
        if checkpoint is not None:
            checkpoint.final(self)

    # ------------------------------------------------------------------ checkpoints
    def gather_velocities(self) -> np.ndarray:
        v = self.lmp.gather_atoms("v", 1, 3)
        return np.ctypeslib.as_array(v).reshape(-1, 3).copy()

    def scatter(self, name: str, values: np.ndarray) -> None:
        """Set a per-atom 3-vector (x, v, f) of every atom from an array in global order."""
        import ctypes

        flat = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
        self.lmp.scatter_atoms(name, 1, 3, flat.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))

    def realign(self, f: np.ndarray) -> None:
        """Rebuild the neighbour lists here, as a resumed run does, keeping the state exact.

        ``run 0`` recomputes forces with LAMMPS' full-step velocity, so the forces of the last
        step (``f``, in global order) are put back; positions and velocities are untouched.
        Done at every checkpoint, so that an interrupted and resumed run sums its pair forces in
        the same order as an uninterrupted one (bitwise in serial)."""
        self.command("run 0 post no")
        self.scatter("f", f)
        self._check_callback()

    def restore(self, ck) -> None:
        """Re-enter the checkpoint's phase exactly: the fixes as the uninterrupted run had them
        (every phase switch replayed, so the fixes sum in the same order), the step, positions
        and velocities, then ``run 0`` (neighbour lists, as :meth:`realign` did when the
        checkpoint was written) and the last step's forces put back."""
        previous = None
        for k, (_, phase, _) in enumerate(self.scene.schedule()):
            if k > ck.phase_index:
                break
            for cmd in self.deck.phase_commands(phase.vars, previous):
                self.command(cmd)
            self._toggle_callback(phase.vars)
            previous = dict(phase.vars)
        self.command(f"reset_timestep {int(ck.step)}")
        if self._dump_id is not None:
            # the frame at the checkpoint's step is already in the file: write from the next one
            self.command(f"dump_modify {self._dump_id} delay {int(ck.step) + 1}")
        self.scatter("x", ck.x)
        self.scatter("v", ck.v)
        self.step = int(ck.step)
        self.realign(ck.f)
        self._phase = previous
