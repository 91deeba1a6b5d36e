"""Running a compiled deck through the ``lammps`` Python module, serial or under ``mpiexec``.

The runner executes the deck's setup commands, attaches the Python callback, and answers the
engine interface (:mod:`rackstress.engines.base`) so that the one driver
(:mod:`rackstress.engines.driver`) steps it: each phase's ``run N`` split into chunks so that the
watchdog and the progress bar see the state between chunks. ``run k pre no post no`` continues a
run without recomputing forces, so chunking changes nothing (docs/model.md, "On LAMMPS").

**Failures.** Whatever stops a run that flew apart is a :class:`DivergenceError` naming the step
and a particle: the watchdog (every :data:`CHECK_EVERY` steps, :data:`PLUGIN_CHECK_EVERY` on the
plugin alone), LAMMPS' own errors of flown-apart
atoms (``Lost atoms``, ``Too many neighbor bins``, ``Out of range atoms``), and the operator
callback losing sight of a bind partner. An exception inside the callback stops LAMMPS after the
step it happened in (the callback forces LAMMPS' timeout, which is checked before every step;
under MPI the ranks agree on it inside the callback, so all stop at the same step): positions in
the trajectory never come from a step with missing forces. The plugin's styles never add a
non-finite term (a bound pair that coincides) and record its step instead; the next watchdog
check names that step, and the frames after it are cut from the dump (``trim_after``). Under MPI the ghost cutoff grows with
the scene: at every check the reach of every bind and attraction (the bounding box of its two
groups) is measured and, when it has used half of its margin, the cutoff is raised
(``comm_modify cutoff``) and the neighbour lists rebuilt, so a scene that runs in serial runs
under MPI. A LAMMPS error raised on one rank only (the others wait in a collective) ends all
ranks with one message (:func:`abort_all`).
"""
from __future__ import annotations

import gc
from pathlib import Path

import numpy as np

from rackstress.engines.lammps.deck import (MOVE_GROUP, PY_FIX, PY_NAPPLY, VOLUME_ATOMS, Deck,
                                           _global_int, balance_commands)
from rackstress.engines.lammps.plugin import locate as _locate_plugin
from rackstress.errors import DivergenceError, RackstressError, StorageError
from rackstress.lib.vec import fresh_zeros
from rackstress.engines.watchdog import divergence_error, find_divergence, force_error, too_fast

#: Steps between watchdog checks (and progress updates) on LAMMPS.
CHECK_EVERY = 10
#: The same with the plugin's styles alone (no Python callback): they record a non-finite term's
#: step themselves (``rackstress_first_nonfinite``), LAMMPS stops atoms that fly apart (Lost
#: atoms …), and no ghost cutoff is grown, so the checks between chunks are the bound of the
#: watchdog and the progress bar. Each chunk's ``run`` and checks cost ~0.2 ms (one rank) to
#: ~0.3 ms (two: LAMMPS' barriers and reductions, the check's one reduction); 100 steps make that
#: ~3 % of magpod's steps, and a bound crossed is reported within 100 steps
#: (docs/benchmarks/scaling.md, "Under rackstress run").
PLUGIN_CHECK_EVERY = 100
#: LAMMPS errors that mean the atoms flew apart (a divergence, not bad input).
DIVERGED_MARKERS = ("Lost atoms", "Too many neighbor bins", "Out of range atoms", "Bond atoms",
                    "Non-numeric atom coords", "Too many atoms", "Domain too large",
                    "Neighbor list overflow", "Too many local+ghost atoms",
                    "before LAMMPS integrated it")     # rs/collide activate: moved > a skin
#: LAMMPS errors of the file system.
STORAGE_MARKERS = ("Cannot open", "No space", "Error writing", "Cannot write", "Disk quota",
                   "Read-only", "Could not write", "Cannot close", "I/O error")


class LammpsRun:
    """One LAMMPS instance running one deck (all ranks of ``comm`` take part): an engine
    (:class:`rackstress.engines.base.Engine`) for :func:`rackstress.engines.driver.drive`."""

    check_every = CHECK_EVERY

    def __init__(self, deck: Deck, out: Path | None, comm=None, dump_every: int = 100,
                 log: bool = True, append: bool = False):
        """``append``: continue an interrupted run in ``out`` (resume): the log and the
        trajectory are appended to, not replaced."""
        from rackstress.lib.mpi import lammps_module, world

        self.deck, self.scene = deck, deck.scene
        self.check_every = (PLUGIN_CHECK_EVERY if deck.plugin and not deck.python_ops
                            else CHECK_EVERY)
        self.comm = comm or world()
        out = Path(out).resolve() if out is not None else None
        self.out = out
        logfile = str(out / "log.lammps") if (out is not None and log) else "none"
        # the log's path as a command-line argument: LAMMPS opens it as given, unparsed
        args = ["-screen", "none", "-nocite", "-log", "none" if append else logfile]
        lammps = lammps_module()
        with _plugins_loaded_once(deck.plugin):
            self.lmp = lammps.lammps(cmdargs=args, comm=self.comm)
        self._words, self._paths = 0, {}
        if append and logfile != "none":
            self.command(f"log {self.path_word(logfile)} append")
        self.step = 0
        self._looked = 0            # the state the run starts from is the scene's own
        self.root = self.comm.Get_rank() == 0
        self.dump_every = int(dump_every)
        self._dump_file = (self.path_word(out / "trajectory.dump", dump=True)
                           if out is not None else None)
        self.cutoff = float(deck.ghost_cutoff)
        # a plugin deck's ghosts cover the real interaction range (rack couplings and
        # attraction are reductions): nothing grows with a body's size
        self._reach = [] if deck.plugin else _reach_pairs(self.scene)
        # the deck's cutoff is 1.5 reach + 2 r_max + LAMMPS' skin + 1 (deck.ghost_cutoff)
        self._extra = 2 * float(self.scene.radii().max()) + deck.lammps_skin + 1.0
        self._reach0 = (self.cutoff - self._extra) / 1.5
        self._span = max((self.scene.slice(g).stop for pair in self._reach for g in pair),
                         default=0)
        self._ids = np.arange(1, self.scene.n_particles + 1)
        # the originals in global order (the watchdog's reference; built once per process): here,
        # while LAMMPS reads its data, not at the first check inside the run, where on the 4 M
        # bed (96 MB) rank 1 built it while rank 0 (which wrote the data file and had it) waited
        # (0.2 s of a 200-iteration run on 2 ranks, measured)
        self.scene.original_positions()
        self._nlocal_ptr, self._owned_key, self._owned_views = None, None, None
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
                deck.write_data(data)
            data = Path(self.comm.bcast(str(data), root=0))
            self.comm.Barrier()
        dump = self._dump_file
        self._plugin = None
        if deck.plugin:
            lib = plugin_library()
            self.command(f"plugin load {self.path_word(lib)}")
            self._plugin = _watch_plugin(lib, self.lmp)
        # rs/volume's cells beside the data file, through its own path variable (a variable
        # names no folder: volume.atoms beside "${rs_pathN}" would be relative to the cwd)
        vol = self.path_word(data.with_name(VOLUME_ATOMS)) if deck.volumes else None
        for cmd in deck.setup_commands(self.path_word(data), dump, dump_every, vol):
            self.command(cmd)
            if dump is not None and cmd.startswith("dump ") and " custom " in cmd:
                self._dump_id = cmd.split()[1]
                if append:
                    self.command(f"dump_modify {self._dump_id} append yes")
        for cmd in deck.velocity_variables():
            self.command(cmd)
        if deck.passive and (self.comm.Get_size() == 1 or deck.plugin):
            # serial, or the plugin's styles on any number of ranks: LAMMPS clears forces,
            # checks displacements and bins only its first rows (the moving group, atom_modify
            # first). A resting row's force then stays what it is, so it is zeroed once here;
            # nothing writes it later (the callback and the plugin's styles add forces only to
            # moving rows), so v + dt/2·f/m keeps it at rest. (The callback under MPI passes
            # over its own rows and keeps the full clearing.)
            self.command(f"neigh_modify include {MOVE_GROUP}")
            self.scatter("f", np.zeros((self.scene.n_particles, 3)))
        for cmd in (balance_commands(deck) if self.comm.Get_size() > 1 else []):
            self.command(cmd)
        #: LAMMPS' mask bit of the moving group (a deck with a passive group), else None: an
        #: atom without it has never moved, so it sits at its original position with v = 0
        self._move_bit = (1 << list(self.lmp.available_ids("group")).index(MOVE_GROUP)
                          if deck.passive else None)
        if deck.python_ops:
            # imported here: its compiled kernels (numba, 0.2-0.5 s to import) are not
            # needed where the plugin runs every operator
            from rackstress.engines.lammps.callback import PyForces

            self.py = PyForces(self.lmp, deck, self.comm)

    @property
    def step_count(self) -> int:
        """Steps done (the engine interface's name for :attr:`step`)."""
        return self.step

    # ------------------------------------------------------------------ commands
    def path_word(self, path, dump: bool = False) -> str:
        """The word that stands for the file ``path`` in a LAMMPS command, whatever the path
        holds (spaces, quotes, non-ASCII characters): ``${rs_pathN}``, a string variable set
        through the library to the path in quotes it does not contain (:func:`quote_path`).
        Not the path itself in the command: LAMMPS' input parser (``Input::parse``,
        ``utils::utf8_subst``) drops the first byte of every non-ASCII character of a command
        line (``é``, C3 A9, becomes A9: the "'utf-8' codec can't decode byte 0xa9" of LAMMPS'
        message on the mangled path), and a variable's value is put in after that step.
        ``dump``: a dump or restart file, whose path may hold neither ``*`` nor ``%``."""
        quoted = quote_path(path, dump)
        self._words += 1
        name = f"rs_path{self._words}"
        self._paths["${" + name + "}"] = str(path)
        self.command(f"variable {name} string none")
        if self.lmp.set_string_variable(name, quoted) != 0:
            raise RackstressError(f"LAMMPS refused the path {path} as a string variable")
        return "${" + name + "}"

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
        """Turn a LAMMPS error into the error it means: a divergence (naming the step and a
        particle), a full or unwritable disk, or a failed command."""
        if isinstance(exc, UnicodeDecodeError):     # LAMMPS' message holds bytes not UTF-8
            exc = exc.object.decode("utf-8", "replace")
        for word, path in getattr(self, "_paths", {}).items():     # the paths, as given
            cmd = cmd.replace(word, path)
        msg = str(getattr(exc, "message", exc)).strip().strip("'\"")
        msg = msg.split("\nFor more information")[0].split(" (src/")[0].strip()
        self._sync_step()
        lone = type(exc).__name__ == "MPIAbortException" and self.comm.Get_size() > 1
        if any(m in msg for m in DIVERGED_MARKERS):
            if lone:
                abort_all(self.comm, f"run diverged at step {self.step}: LAMMPS: {msg}", 3)
            raise self._diverged(f"LAMMPS stopped with '{msg}'")
        if any(m in msg for m in STORAGE_MARKERS):
            if lone:
                abort_all(self.comm, f"LAMMPS could not write at step {self.step}: {msg}", 5)
            raise StorageError(f"LAMMPS could not write at step {self.step} ('{cmd}'): {msg}"
                               f"{self._free_space(msg)}; free space on that file system or "
                               "choose another --out")
        if lone:
            abort_all(self.comm, f"LAMMPS failed on '{cmd}' at step {self.step}: {msg}", 2)
        found = self._finder()
        if found is not None:
            raise divergence_error(self.scene, self.step, found)
        raise RackstressError(f"LAMMPS failed on '{cmd}' at step {self.step}: {msg}")

    def _free_space(self, msg: str = "") -> str:
        import shutil

        try:
            free = shutil.disk_usage(self.out).free if self.out is not None else None
        except OSError:
            return ""
        if free is None:
            return ""
        return "" if free == 0 and "No space" in msg else (
            " (No space left on device)" if free == 0 else f" ({free} bytes free there)")

    def _sync_step(self) -> None:
        try:
            self.step = int(self.lmp.extract_global("ntimestep"))
        except Exception:  # noqa: BLE001 - keep the count we had
            pass

    def _diverged(self, why: str) -> DivergenceError:
        """A DivergenceError for a run LAMMPS stopped: the watchdog's particle if it finds one,
        else a lost atom, else the particle furthest from its original position."""
        found = self._finder(strict=False)
        k = found["index"] if found else 0
        group, local = self.scene.group_of(k)
        if found and found.get("lost"):
            what = (f"{found['count']} atom(s) left LAMMPS' domain between two reneighbourings, "
                    f"the first '{group}' particle {local} (atom id {k + 1})")
        elif found:
            what = (f"'{group}' particle {local} (atom id {k + 1}) is "
                    + ("not finite" if not found["finite"] else
                       f"{found['disp']:.4g} units from its original position"))
        else:
            what = "no particle could be named"
        return DivergenceError(
            f"run diverged at step {self.step}: {why}; {what}. A smaller time step (dt = "
            f"{self.scene.dt:g} now) or weaker coefficients keep Eq. 5 stable; the output "
            "written up to here is kept.", step=self.step, index=k, group=group, local=local,
            value=found.get("disp") if found else None)

    def _finder(self, strict: bool = True):
        """The watchdog's worst particle over all ranks (collective); with ``strict=False`` also
        lost atoms and, failing both, the particle furthest from its original position."""
        got = self.positions_local()
        o = self.scene.original_positions()
        found = far = None
        tags = np.zeros(0, dtype=np.int64)
        if got is not None and len(got[2]):
            x, v, tags = got
            idx = tags - 1
            found = find_divergence(self.scene, x, v, o[idx], idx)
            if not strict:
                d = np.where(np.isfinite(x).all(1), np.linalg.norm(x - o[idx], axis=1), np.inf)
                j = int(np.argmax(d))
                far = {"index": int(idx[j]), "finite": bool(np.isfinite(d[j])),
                       "disp": float(d[j]), "count": 1}
        everything = self.comm.allgather((found, far, None if strict else tags))
        hits = [f for f, _, _ in everything if f is not None]
        if hits:
            worst = max(hits, key=lambda f: (not f["finite"], f["disp"]))
            worst["count"] = sum(f["count"] for f in hits)
            return worst
        if strict:
            return None
        present = np.zeros(self.scene.n_particles + 1, dtype=bool)
        for _, _, t in everything:
            present[t] = True
        missing = np.flatnonzero(~present[1:])
        if len(missing):
            return {"index": int(missing[0]), "finite": False, "disp": float("inf"),
                    "count": int(len(missing)), "lost": True}
        fars = [f for _, f, _ in everything if f is not None]
        return max(fars, key=lambda f: f["disp"]) if fars else None

    # ------------------------------------------------------------------ phases
    def enter_phase(self, phase_vars) -> None:
        """Switch exactly to a phase (the deck's switch commands) and toggle the callback."""
        deck = self.deck
        cmds = deck.switch_commands(phase_vars, self._phase)
        run0 = cmds.index("run 0 post no")
        for cmd in cmds[:run0]:
            self.command(cmd)
        self._toggle_callback(phase_vars)
        for k, cmd in enumerate(cmds[run0:], start=run0):
            if cmd == "run 0 post no":
                if cmds[k - 1] != cmd:      # a deck's second run 0 (Deck.switch_commands):
                    self._run0()            # _run0 runs it when needed
            elif not self._set_velocity(cmd):
                self.command(cmd)
        self._check_callback()
        self._phase = dict(phase_vars)

    def _set_velocity(self, cmd: str) -> bool:
        """The deck's half-step velocity shift (``velocity rs_move set v_rs_vh… units box``,
        v ± dt/2·f/m) done here on the moving group's rows, if the deck has a passive group:
        LAMMPS' command evaluates its atom variables into a fresh array over every atom. The
        same arithmetic in the same order (v + (dt/2·f)/m, m of the atom's type), so the same
        bits. Returns whether ``cmd`` was such a command (else the caller runs it)."""
        if self._move_bit is None or not cmd.startswith(f"velocity {MOVE_GROUP} set v_rs_v"):
            return False
        sign = cmd.split()[3][len("v_rs_v"):-1]         # h: v + dt/2·f/m; p: v − dt/2·f/m
        if sign not in ("h", "p") or self.scene.fixed().any():
            return False                                 # (held atoms: the deck's gmask form)
        lmp = self.lmp
        nlocal = lmp.extract_global("nlocal")
        rows = np.flatnonzero((lmp.numpy.extract_atom("mask")[:nlocal] & self._move_bit) != 0)
        v, f = lmp.numpy.extract_atom("v"), lmp.numpy.extract_atom("f")
        m = lmp.numpy.extract_atom("mass")[lmp.numpy.extract_atom("type")[rows]]
        h = 0.5 * float(self.scene.dt)
        shift = (h * f[rows]) / m[:, None]
        v[rows] = v[rows] + shift if sign == "h" else v[rows] - shift
        return True

    def _run0(self) -> None:
        """``run 0 post no`` (forces at the current state). If the callback activated resting
        particles there (Deck.passive) that LAMMPS has not yet put among its integrated first
        rows (``atom_modify first``), once more: LAMMPS reorders them, and the forces, from the
        same positions and velocities, are the same."""
        py = self.py
        if py is not None:
            py.activated_late, py.late = False, None
        self.command("run 0 post no")
        if py is None and self.deck.plugin and self._move_bit is not None:
            self._plugin_reorder()
            return
        if py is None or not self.comm.allreduce(py.activated_late or py.late is not None):
            return
        py.activated_late, py.late = False, None
        # forces the first setup left on rows LAMMPS is about to hand to other atoms would stay
        # there (serially it clears only its first rows: neigh_modify include)
        self.lmp.numpy.extract_atom("f")[:self.lmp.extract_global("nlocal")] = 0.0
        self.command("run 0 post no")
        self._check_late()

    def _plugin_reorder(self) -> None:
        """After a plugin deck's ``run 0`` (Deck.passive): if rs/collide activated resting
        particles there that LAMMPS has not yet put among its first rows (a moving-group row
        after a resting one), ``run 0`` once more: LAMMPS reorders them, and the forces, from the
        same positions and velocities, are the same (each target sums its partners in atom-id
        order). The forces the first left on rows about to hold other atoms are cleared first
        (serially LAMMPS clears only its first rows: neigh_modify include)."""
        lmp = self.lmp
        nlocal = lmp.extract_global("nlocal")
        moving = (lmp.numpy.extract_atom("mask")[:nlocal] & self._move_bit) != 0
        k = int(moving.sum())
        if not self.comm.allreduce(bool(k < nlocal and moving[k:].any())):
            return
        lmp.numpy.extract_atom("f")[:nlocal] = 0.0
        self.command("run 0 post no")

    def _check_late(self) -> None:
        """Stop if a force reached a resting particle LAMMPS did not yet integrate (Deck.passive):
        it would have moved. Activation one reneighbouring early (within reach + 2 skins) rules
        this out unless a particle moves more than a skin between two reneighbourings."""
        if self.py is None:     # the plugin alone: no callback, nothing touched late
            return
        late = self.py.late
        if not self.comm.allreduce(late is not None):
            return
        step, k = next(x for x in self.comm.allgather(late) if x is not None)
        group, local = self.scene.group_of(k)
        raise DivergenceError(
            f"run diverged at step {step}: resting '{group}' particle {local} (atom id {k + 1}) "
            "was touched before LAMMPS integrated it: a particle moved more than the neighbour "
            f"skin ({self.deck.lammps_skin:g}) between two reneighbourings, so the run could not stay "
            f"exact. A smaller time step (dt = {self.scene.dt:g} now) or weaker coefficients "
            "keep Eq. 5 stable; the output written up to here is kept.",
            step=int(step), index=int(k), group=group, local=int(local))

    def _toggle_callback(self, phase_vars) -> None:
        """The fix external exists only in phases where the callback has work: a Python operator
        is active, or it adds the constant forces and damping (Deck.callback_natives)."""
        if self.py is None:
            return
        want = self.py.set_phase(phase_vars)
        if want and not self._py_on:
            self.command(f"fix {PY_FIX} {self.deck.moving} external pf/callback 1 {PY_NAPPLY}")
            attach_callback(self.lmp, PY_FIX, self.py, self)
            # rollers' setforce after the callback's forces (LAMMPS' fix order)
            from rackstress.engines.lammps.deck import partial_support_commands
            for cmd in partial_support_commands(self.scene, redefine=True):
                self.command(cmd)
        elif self._py_on and not want:
            self.command(f"unfix {PY_FIX}")
        self._py_on = want

    def advance(self, n: int) -> None:
        """``n`` steps (fewer if the callback failed: it stops LAMMPS after its step)."""
        # no cyclic garbage collection inside the run: the callback makes no reference cycles,
        # and a collection pass over every live object (numba, scipy, LAMMPS' wrappers) every
        # few hundred allocations was a measurable share of each step
        gc_was = gc.isenabled()
        gc.disable()
        try:
            self.command(f"run {n} pre no post no")
        finally:
            if gc_was:
                gc.enable()
        self.step += n
        self._check_callback()
        self._check_late()

    def _check_callback(self):
        if self.py is None:     # the plugin alone (the same deck on every rank): nothing to ask
            return
        err = self.py.error
        if not self.comm.allreduce(err is not None):
            return
        # the callback stopped LAMMPS after the step it failed in: that is where the run is
        self._sync_step()
        self.command("timer timeout off")
        # (step, kind, message, particle) of the first rank that failed: plain data travels
        mine = None if err is None else (int(err[0]), type(err[1]).__name__, str(err[1]),
                                         getattr(err[1], "index", None))
        step, kind, text, index = next(e for e in self.comm.allgather(mine) if e is not None)
        if kind == "NonFiniteForce":        # found in the step it arose in (before the finder,
            raise force_error(self.scene, step, index)   # which sees its NaN velocities)
        # particles that flew apart (a partner out of ghost reach) are a divergence: the
        # watchdog names the particle first, else the callback's own account does
        found = self._finder()
        if found is not None:
            raise divergence_error(self.scene, self.step, found)
        if index is not None:
            group, local = self.scene.group_of(int(index))
            raise DivergenceError(
                f"run diverged at step {step}: {text}. The particles flew further apart than "
                f"the ghost cutoff ({self.cutoff:.4g} units) within {CHECK_EVERY} steps; the "
                "output written up to here is kept.", step=int(step), index=int(index),
                group=group, local=local)
        raise RackstressError(f"the Python operator callback failed at step {step}: "
                              f"{kind}: {text}")

    # ------------------------------------------------------------------ state
    def positions_local(self, rows: int | None = None):
        """Positions, velocities and atom ids of the owned atoms (the first ``rows`` of them)."""
        try:
            nlocal = self.lmp.extract_global("nlocal")
            n = nlocal if rows is None else min(rows, nlocal)
            x = self.lmp.numpy.extract_atom("x")[:n]
            v = self.lmp.numpy.extract_atom("v")[:n]
            tag = self.lmp.numpy.extract_atom("id")[:n].astype(np.int64)
            return x, v, tag
        except Exception:  # noqa: BLE001
            return None

    def _owned(self, rows: int | None = None):
        """Views of LAMMPS' positions, velocities and atom ids (its int32) of the first ``rows``
        owned atoms, kept from one watchdog check to the next while LAMMPS' arrays stay where
        they are (it moves them only when it grows them, at a reneighbouring; the ids are read
        through the view, so a reordering shows): the ``lammps`` module's extract_atom makes
        new arrays at every call, about 0.1 ms a check."""
        import ctypes

        lmp = self.lmp
        if self._nlocal_ptr is None:
            self._nlocal_ptr = _global_int(lmp, "nlocal")
        fn = lmp.lib.lammps_extract_atom
        fn.restype = ctypes.c_void_p        # (lmp.extract_atom sets it at each of its calls)
        rows_of = ctypes.c_void_p.from_address     # x, v: double**, their data's address
        px, pv = fn(lmp.lmp, b"x"), fn(lmp.lmp, b"v")
        nlocal = self._nlocal_ptr[0]
        key = (nlocal, rows_of(px).value if px else None, rows_of(pv).value if pv else None,
               fn(lmp.lmp, b"id"))
        if key != self._owned_key:
            self._owned_key = key
            self._owned_views = tuple(lmp.numpy.extract_atom(name)[:nlocal]
                                      for name in ("x", "v", "id", "mask"))
        if rows == "moving":
            # a plugin deck's moving group (rs/collide activates): its rows come first (those
            # activated since LAMMPS last reordered rest still: harmless to leave out or keep)
            rows = self._nfirst = moving_prefix(self._owned_views[3], self._move_bit,
                                                getattr(self, "_nfirst", 0))
        n = nlocal if rows is None else min(rows, nlocal)
        return tuple(a[:n] for a in self._owned_views[:3])

    #: the step of the watchdog's last look that found nothing (None: none yet)
    _looked: int | None = None

    def check(self) -> None:
        """The watchdog on every rank's atoms; all ranks raise the same DivergenceError. Under
        MPI one reduction decides (the plugin's non-finite record and the watchdog's finding on
        each rank); the collectives naming what was found follow only when a rank found it. Under
        MPI it also keeps the ghost cutoff ahead of the scene's reach (:meth:`_grow_cutoff`)."""
        # only LAMMPS' first rows move (atom_modify first, Deck.passive): a resting particle
        # after them is where the data file put it, with v = 0
        moving = self._py_on and self.py.move_bit is not None
        if moving:
            rows = self.py.nfirst
        else:
            rows = "moving" if self.deck.plugin and self._move_bit is not None else None
        x, v, tag = self._owned(rows)
        o = self.scene.original_positions()
        k = self.py.compiled if self.py is not None else None
        if k is not None and k.within_bound(x, v, o, tag, float(self.scene.bound) ** 2) \
                and not too_fast(self.scene, v, tag.astype(np.int64) - 1).any():
            found = None            # the common case, in one compiled pass
        elif len(tag) and tag[0] == 1 and tag[-1] == len(tag) and np.array_equal(
                tag, self._ids[:len(tag)]):
            found = find_divergence(self.scene, x, v, o[:len(tag)])   # row k holds particle k
        else:
            tag = tag.astype(np.int64)
            found = find_divergence(self.scene, x, v, o[tag - 1], tag - 1)
        if self.comm.Get_size() == 1:
            self._check_plugin()
            everything = [found] if found is not None else []
        else:
            # one reduction a check, whatever it finds: (the first step this rank's plugin styles
            # met a non-finite term, or none; 0 if the watchdog found a particle here, else 1),
            # both by their minimum; the collectives that name the step, the atom and the worst
            # particle follow only when a rank has something (every rank then takes them)
            from mpi4py import MPI

            none = np.iinfo(np.int64).max
            here = self._plugin.rackstress_nonfinite_here(self.lmp.lmp) if self._plugin else -1
            flags = np.array([here if here >= 0 else none, 0 if found is not None else 1],
                             dtype=np.int64)
            self.comm.Allreduce(MPI.IN_PLACE, flags, op=MPI.MIN)
            if flags[0] != none:
                self._check_plugin()
            everything = ([f for f in self.comm.allgather(found) if f is not None]
                          if flags[1] == 0 else [])
        if everything:
            worst = max(everything, key=lambda f: (not f["finite"], f["disp"]))
            worst["count"] = sum(f["count"] for f in everything)
            raise divergence_error(self.scene, self.step, worst, since=self._looked)
        self._looked = self.step
        if self.comm.Get_size() > 1 and self._reach:
            self._grow_cutoff(x, tag.astype(np.int64))

    def _check_plugin(self) -> None:
        """The first step at which one of the plugin's styles met a non-finite term (rs_common.h,
        ``nonfinite``: it left the term out, so the positions since are finite but wrong), named
        as the callback names it; collective. The frames after that step are cut from the dump
        (``trim_after``)."""
        if self._plugin is None:
            return
        import ctypes

        step, tag = ctypes.c_longlong(), ctypes.c_longlong()
        if not self._plugin.rackstress_first_nonfinite(self.lmp.lmp, ctypes.byref(step),
                                                      ctypes.byref(tag)):
            return
        err = force_error(self.scene, int(step.value), int(tag.value) - 1)
        err.trim_after = int(step.value)
        raise err

    def _grow_cutoff(self, x, tag) -> None:
        """Raise the ghost cutoff once a bind's or attraction's reach (the diagonal of its two
        groups' bounding box, which :func:`~rackstress.engines.lammps.deck.ghost_cutoff` takes
        at the start with a margin of half of it) has used half that margin; then rebuild the
        ghosts and neighbour lists (:meth:`realign`, the forces kept)."""
        from mpi4py import MPI

        sc = self.scene
        names = list(sc.groups)
        starts = np.array([sc.offset(n) for n in names])
        lo = np.full((len(names), 3), np.inf)
        hi = np.full((len(names), 3), -np.inf)
        idx = tag - 1
        if self._span < sc.n_particles:      # only the groups binds and attractions join
            keep = idx < self._span           # (MagPod's robot, not its sediment)
            idx, x = idx[keep], x[keep]
        if len(idx):
            gid = np.searchsorted(starts, idx, side="right") - 1
            for g in np.unique(gid):
                rows = x[gid == g]
                lo[g], hi[g] = rows.min(0), rows.max(0)
        self.comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
        self.comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
        reach = 0.0
        for a, b in self._reach:
            ia, ib = names.index(a), names.index(b)
            span = np.maximum(hi[ia], hi[ib]) - np.minimum(lo[ia], lo[ib])
            reach = max(reach, float(np.linalg.norm(span)))
        if reach > 1.25 * self._reach0:
            self._reach0 = reach
            self.cutoff = 1.5 * reach + self._extra
            f = self.gather_forces()
            self.command(f"comm_modify cutoff {self.cutoff:.6g}")
            self.realign(f)

    def positions(self) -> np.ndarray:
        """All positions in global particle order (on every rank); NaN for lost atoms."""
        n = self.scene.n_particles
        if self._move_bit is not None:
            fast = self._moved_only(x=True)         # None if an atom was lost
            if fast is not None:
                return fast[0]
        got = self.positions_local()
        if self.comm.allreduce(0 if got is None else len(got[2])) == n:
            return self.gather_positions()
        p = np.full((n, 3), np.nan)
        for part in self.comm.allgather(None if got is None else (got[2], np.array(got[0]))):
            if part is not None and len(part[0]):
                p[part[0] - 1] = part[1]
        return p

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities in global particle order (on every rank)."""
        fast = self._moved_only(x=True, v=True)
        return fast if fast is not None else (self.gather_positions(), self.gather_velocities())

    def moving_mask(self) -> np.ndarray | None:
        """Which particles (global order) are in LAMMPS' moving group, on every rank; None in
        a deck without a passive group. A checkpoint keeps it, so that a resumed run's group,
        and with it its trajectory's frames, are the uninterrupted run's."""
        if self._move_bit is None:
            return None
        lmp = self.lmp
        nlocal = lmp.extract_global("nlocal")
        mask = lmp.numpy.extract_atom("mask")[:nlocal]
        ids = lmp.numpy.extract_atom("id")[:nlocal].astype(np.int64) - 1
        mine = ids[(mask & self._move_bit) != 0]
        parts = [mine] if self.comm.Get_size() == 1 else self.comm.allgather(mine)
        out = np.zeros(self.scene.n_particles, dtype=bool)
        for part in parts:
            out[part] = True
        return out

    def _moved_only(self, x: bool = False, v: bool = False):
        """Positions and/or velocities in global order without gathering every atom (a deck
        with a passive group, every atom present; else None): an atom outside LAMMPS' moving
        group has never moved (Deck.passive: it has had zero velocity and zero force since step
        0), so its position is its original one, exactly as the data file gave it, and its
        velocity 0. The global arrays are those, with the moving group's rows written in
        (under MPI, every rank's moving rows gathered). The same arrays as
        :meth:`gather_positions` and :meth:`gather_velocities`, bit for bit."""
        if self._move_bit is None:
            return None
        lmp, n = self.lmp, self.scene.n_particles
        nlocal = lmp.extract_global("nlocal")
        mask = lmp.numpy.extract_atom("mask")[:nlocal]
        rows = np.flatnonzero((mask & self._move_bit) != 0)       # (a bool: nonzero is faster)
        idx = lmp.numpy.extract_atom("id")[:nlocal][rows].astype(np.int64) - 1
        mine = [idx, int(nlocal)]
        if x:
            mine.append(lmp.numpy.extract_atom("x")[:nlocal][rows])
        if v:
            mine.append(lmp.numpy.extract_atom("v")[:nlocal][rows])
        parts = [mine] if self.comm.Get_size() == 1 else self.comm.allgather(mine)
        if sum(p[1] for p in parts) != n:
            return None     # an atom was lost: the full gathers decide
        out = []
        if x:
            out.append(fresh_zeros((n, 3)))
            out[0][:] = self.scene.original_positions()
        if v:
            out.append(fresh_zeros((n, 3)))
        for part in parts:
            for arr, vals in zip(out, part[2:]):
                arr[part[0]] = vals
        return tuple(out)

    def gather_positions(self) -> np.ndarray:
        """All positions in global particle order (on every rank)."""
        x = self.lmp.gather_atoms("x", 1, 3)
        return np.ctypeslib.as_array(x).reshape(-1, 3).copy()

    def gather_forces(self) -> np.ndarray:
        f = self.lmp.gather_atoms("f", 1, 3)
        return np.ctypeslib.as_array(f).reshape(-1, 3).copy()

    def write_frame(self) -> None:
        """A frame of the current step in ``trajectory.dump`` (the deck's dump columns and
        format), unless the dump interval already wrote it."""
        if self._dump_id is None or self.step % self.dump_every == 0:
            return
        self.command(self.deck.write_dump_command(self._dump_file))

    def close(self):
        try:
            self.lmp.close()
        except Exception:  # noqa: BLE001 - closing after a failure: nothing more to learn
            pass

    # ------------------------------------------------------------------ the whole schedule
    def run_schedule(self, progress=None, check_every: int | None = None,
                     on_phase_end=None, checkpoint=None, resume=None) -> None:
        """Every phase of every cycle: :func:`rackstress.engines.driver.drive` on this engine."""
        from rackstress.engines.driver import drive

        drive(self, progress=progress, check_every=check_every, on_phase_end=on_phase_end,
              checkpoint=checkpoint, resume=resume)

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
        self._run0()
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
        if self._move_bit is not None:
            # every particle the checkpoint holds displaced or moving was in the moving group of
            # the uninterrupted run (a resting particle joins it once touched and never leaves):
            # it joins again here, before the run 0 that reorders the rows, whether or not the
            # callback runs in this phase (it tells the resting bed at its first call)
            o = self.scene.original_positions()
            off = (ck.x != o).any(axis=1) | (ck.v != 0).any(axis=1)
            moving = getattr(ck, "moving", None)
            if moving is not None:        # the group as it was (joined, moving or not yet)
                off = off | moving
            nlocal = self.lmp.extract_global("nlocal")
            mask = self.lmp.numpy.extract_atom("mask")[:nlocal]
            ids = self.lmp.numpy.extract_atom("id")[:nlocal].astype(np.int64) - 1
            mask[off[ids]] |= self._move_bit
        self.step = self._looked = int(ck.step)
        self.realign(ck.f)
        self._phase = previous


def attach_callback(lmp, fix_id: str, fn, caller) -> None:
    """``lmp.set_fix_external_callback`` without its per-step cost: the ``lammps`` module
    wraps each call's three pointers into new NumPy arrays (~30 µs a step); the callback here
    only needs fix external's force array, whose view is kept until its address or the number
    of owned atoms changes (LAMMPS grows or exchanges arrays only when it reneighbours). The
    pointers arrive as plain addresses (``c_void_p``: no ctypes pointer objects made a step);
    the call is the one LAMMPS makes (the same C signature).

    The callback adds its forces into LAMMPS' force array itself; fix external's own pass,
    which would add its array to every owned atom of its group, runs only at steps that are
    multiples of ``PY_NAPPLY`` (step 0): its array is zeroed before those."""
    import ctypes

    view = {}
    first_row = ctypes.c_void_p      # fix external's double**: the address of its rows' data
    rows_t = ctypes.POINTER(ctypes.POINTER(ctypes.c_double))

    def wrapper(caller_, step, nlocal, tag_ptr, x_ptr, fext_ptr):
        key = (nlocal, first_row.from_address(fext_ptr).value if fext_ptr else None)
        f = view.get(key)
        if f is None:
            view.clear()
            f = view[key] = (lmp.numpy.darray(ctypes.cast(fext_ptr, rows_t), nlocal, 3)
                             if key[1] else np.zeros((0, 3)))
        if step % PY_NAPPLY == 0:
            f[:] = 0.0       # fix external's add pass runs this step: let it add nothing
        fn(caller_, step, nlocal, None, None, f)

    c_ptr = ctypes.c_void_p
    cfunc = ctypes.CFUNCTYPE(None, ctypes.py_object, lmp.c_bigint, ctypes.c_int, c_ptr, c_ptr,
                             c_ptr)(wrapper)
    lmp.callback[fix_id] = {"function": cfunc, "caller": caller}   # kept alive with lmp
    from lammps.core import ExceptionCheck

    with ExceptionCheck(lmp):          # a bad fix id raises, as lmp.set_fix_external_callback's
        lmp.lib.lammps_set_fix_external_callback(
            lmp.lmp, fix_id.encode(), ctypes.cast(cfunc, lmp.FIX_EXTERNAL_CALLBACK_FUNC), caller)


#: what LAMMPS reads in a dump or restart file's name: ``*`` the step, ``%`` the processor
DUMP_SPECIAL = "*%"


def quote_path(path, dump: bool = False) -> str:
    """``path`` in quotes LAMMPS' input parser takes as one word with nothing inside it
    substituted (``'…'``, ``"…"`` or ``\"\"\"…\"\"\"``, the first the path does not
    contain); ``dump``: a dump or restart file.

    Raises
    ------
    RunDirError
        The path has a control character, or all three quotes, or (``dump``) a ``*`` or a
        ``%``, which LAMMPS reads as the step and the processor in such a file's name.

    Examples
    --------
    >>> print(quote_path("/runs/T15 résultat/particles.data"))
    '/runs/T15 résultat/particles.data'
    >>> print(quote_path("/runs/it's/particles.data"))
    "/runs/it's/particles.data"
    """
    from rackstress.errors import RunDirError

    text = str(path)
    bad = sorted({c for c in text if ord(c) < 32 or ord(c) == 127})
    if bad:
        raise RunDirError(f"the path {text!r} holds a control character "
                          f"({', '.join(repr(c) for c in bad)}), which LAMMPS cannot take in a "
                          "file name: choose another --out")
    if dump and any(c in text for c in DUMP_SPECIAL):
        raise RunDirError(f"the path {text} holds '*' or '%', which LAMMPS reads in a dump or "
                          "restart file's name as the step and the processor number: choose "
                          "an --out without them")
    if "'" not in text:
        return f"'{text}'"
    if '"' not in text:
        return f'"{text}"'
    if '"""' not in text and not text.endswith('"'):
        return f'"""{text}"""'
    raise RunDirError(f"the path {text} holds both quotes (' and \") in a way LAMMPS' input "
                      "cannot quote: choose an --out without one of them")


def check_paths(out) -> None:
    """Refuse, before anything is written, a run directory whose files LAMMPS cannot be given
    (:func:`quote_path`: control characters, ``*`` or ``%``, quotes it cannot quote)."""
    quote_path(Path(out).resolve() / "trajectory.dump", dump=True)


class _plugins_loaded_once:
    """Creating a LAMMPS instance without the directories of rackstress's plugin on
    ``LAMMPS_PLUGIN_PATH``, for a deck that loads the plugin itself (``plugin load``, the one
    :func:`plugin_library` chose): ``import lammps`` puts the ``lammps.plugins`` entry points'
    directories there (for the venv's ``lmp``), so every instance loaded the plugin at start
    and the deck's ``plugin load`` was refused ("Ignoring load of fix style rs/rack: must
    unload existing rs/rack plugin first") — or another build's plugin stayed the one used."""

    def __init__(self, plugin: bool):
        self.plugin = plugin

    def __enter__(self):
        import os

        from rackstress.engines.lammps.plugin import LIBRARY

        self.old = os.environ.get("LAMMPS_PLUGIN_PATH")
        if self.plugin and self.old:
            keep = [d for d in self.old.split(os.pathsep)
                    if d and not (Path(d) / LIBRARY).exists()]
            if keep:
                os.environ["LAMMPS_PLUGIN_PATH"] = os.pathsep.join(keep)
            else:
                del os.environ["LAMMPS_PLUGIN_PATH"]
        return self

    def __exit__(self, *exc):
        import os

        if self.old is not None:
            os.environ["LAMMPS_PLUGIN_PATH"] = self.old
        return False


def _watch_plugin(lib: str, lmp):
    """The loaded plugin (the same library LAMMPS loaded: ``dlopen`` of one file returns it
    again), told that this LAMMPS instance is driven by rackstress: its styles record a
    non-finite term for :meth:`LammpsRun._check_plugin` instead of stopping LAMMPS."""
    import ctypes

    so = ctypes.CDLL(lib)
    so.rackstress_watch.argtypes = [ctypes.c_void_p]
    so.rackstress_watch.restype = None
    so.rackstress_first_nonfinite.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
    so.rackstress_first_nonfinite.restype = ctypes.c_int
    so.rackstress_nonfinite_here.argtypes = [ctypes.c_void_p]
    so.rackstress_nonfinite_here.restype = ctypes.c_longlong
    so.rackstress_watch(lmp.lmp)
    return so


def plugin_library() -> str:
    """The compiled plugin for a plugin deck (deck.use_plugin found it when the deck was made)."""
    lib, why = _locate_plugin()
    if lib is None:
        raise RackstressError(f"the deck needs the rackstress LAMMPS plugin, which is not "
                              f"available: {why}")
    return str(lib)


def _reach_pairs(scene) -> list[tuple[str, str]]:
    """The (target, source) group pairs of every bind and attraction: what the ghost cutoff
    must cover under MPI."""
    from rackstress.model.operators import Attract, Bind

    return sorted({(t, op.source) for t, seq in scene.operators.items() for op in seq
                   if isinstance(op, (Bind, Attract))})


def abort_all(comm, message: str, code: int) -> None:
    """The last resort under MPI: one rank failed where the others cannot learn of it (they wait
    in a collective inside LAMMPS). Print one message and end every rank with ``code``."""
    import sys

    from rackstress.lib.mpi import abort

    sys.stderr.write(f"rackstress: error: {message} (rank {comm.Get_rank()}; all ranks "
                     "ended)\n")
    abort(comm, code)


def moving_prefix(mask: np.ndarray, bit: int, hint: int = 0) -> int:
    """The length of the leading rows of ``mask`` that carry ``bit`` (LAMMPS' ``atom_modify
    first`` keeps the moving group's rows first), found from ``hint`` (the last answer) in
    time proportional to the moving rows, not to every atom: a million resting particles cost
    nothing at each watchdog check."""
    n = len(mask)
    h = min(int(hint), n)
    if h and not np.all(mask[:h] & bit):
        return int(np.argmin((mask[:h] & bit) != 0))
    step = 256
    while h < n:
        seg = (mask[h:h + step] & bit) != 0
        if not seg.all():
            return h + int(np.argmin(seg))
        h += len(seg)
        step *= 2
    return h
