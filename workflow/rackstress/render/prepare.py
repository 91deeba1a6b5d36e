"""A head start for post-processing: its imports, measures and painter, ready while the
simulation runs.

``rackstress run`` on one process forks :class:`Ahead`, the process that post-processes the
run, before the first step; under ``mpiexec`` (with a core beyond the ranks) rank 0 runs
:func:`prepare_in_background`, a thread. This module imports nothing heavy itself, so that
the run can start either without paying for it there.
"""
from __future__ import annotations

#: What the measures need first (:func:`rackstress.stress.post.follow`, and the run's summary
#: after its last step: the rigid fit), then what the pictures' painter needs (it is made
#: before the other imports where the run is followed: painting is the longest part of
#: post-processing, and a painter made after the last step adds its making and first
#: picture to it), then what the VTK writer, the plots and the 3D view import, first what
#: the longest of them (the plots' process) needs: done by :func:`prepare_in_background`
#: while the simulation runs.
_FIRST = ("scipy.spatial.transform", "rackstress.stress.post")
#: seconds: a followed run expected to end sooner starts no more of _PREPARE's imports (the
#: longest, matplotlib's, takes 0.15 s)
LAST_IMPORTS_S = 0.2
_PAINT = ("vtkmodules.vtkCommonDataModel", "vtkmodules.util.numpy_support",
          "vtkmodules.vtkRenderingOpenGL2", "vtkmodules.vtkRenderingCore", "PIL.Image",
          "PIL.ImageDraw", "PIL.ImageFont", "rackstress.render.pictures")
_PREPARE = _PAINT + ("matplotlib.figure", "matplotlib.backends.backend_agg",
                     "PIL.PngImagePlugin", "vtkmodules.vtkIOXML",
                     "rackstress.stress.export", "isal.isal_zlib", "rackstress.render.report",
                     "rackstress.render.view3d", "trame_vtk.modules.vtk.serializers",
                     "vtkmodules.vtkFiltersSources", "vtkmodules.vtkFiltersCore")


def _later(squeeze=None, rundir=None):
    """:data:`_PREPARE`'s imports and the fonts, one step a call (what :func:`follow` does
    while no new chunk of frames is written), each yielding True; given ``rundir`` (a run
    :func:`~rackstress.stress.post.follow` measures), after :data:`_PAINT`'s, its pictures'
    painter (:func:`rackstress.render.pictures.prepare_painter`, once follow has opened the
    run: False until then); then, given ``squeeze`` (a
    :class:`~rackstress.engines.dumpio.GzAhead`), the trajectory's frames compressed as they
    are written, yielding whether one was."""
    import gc
    import importlib

    def load(names, head=None):
        for name in names:
            # near the run's end an import is left to whoever needs it (a forked child, beside
            # the pictures): one under way when the last step is done delays post-processing
            # (matplotlib's: 0.14 s), and none of these is needed to measure the frames left
            if head is not None and head.seconds_left() < LAST_IMPORTS_S:
                return
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001, S112 - only a head start: the user imports it
                pass
            gc.freeze()         # what it made: in no collection while the thread runs
            yield True

    yield from load(_PAINT)
    try:                        # the pictures' fonts: their text is drawn with the first one
        from rackstress.render.pictures import _font

        for size in (13, 14, 17, 18):
            _font(size)
    except Exception:  # noqa: BLE001, S110 - only a head start
        pass
    yield True
    if rundir is not None:
        from pathlib import Path

        from rackstress.stress.post import _HEADS

        key = str(Path(rundir).resolve())
        while getattr(_HEADS.get(key), "run", None) is None:
            yield False                     # follow has not opened the run yet
        try:
            from rackstress.render.pictures import prepare_painter

            prepare_painter(_HEADS[key].run)
        except Exception:  # noqa: BLE001, S110 - only a head start: render makes its own
            pass
        yield True
    head = _HEADS.get(key) if rundir is not None else None
    yield from load(_PREPARE[len(_PAINT):], head)
    if head is None or head.seconds_left() >= LAST_IMPORTS_S:   # the plots' font likewise
        try:
            from matplotlib import font_manager

            font_manager.findfont("DejaVu Sans")
        except Exception:  # noqa: BLE001, S110 - only a head start
            pass
        yield True
    while squeeze is not None:
        yield squeeze.step()


def prepare_in_background(rundir=None, frames: int | None = None, compress: bool = False):
    """Load the measures' modules and compiled loop, then measure the frames LAMMPS writes, in
    a thread, while the simulation runs on the other core (LAMMPS runs the plugin without the
    GIL; ``rackstress run`` starts it just before the first step). Given the run directory
    ``rundir`` and the ``frames`` it will hold, the thread measures each whole chunk of frames
    as soon as the dump holds it (:func:`rackstress.stress.post.follow`) until
    :func:`wait_prepared`, so that post-processing measures only the last ones; while it waits
    for frames it imports what the VTK writer, the pictures, the plots and the 3D view need,
    one module at a time (:data:`_PREPARE`; the forked VTK and plot processes inherit them).
    Whatever is not imported when the run ends is left to whoever needs it (a forked child
    imports its own, beside the pictures); without ``rundir`` every import is done. Then,
    with ``compress`` (the run's trajectory becomes ``trajectory.dump.gz`` once finished),
    the frames written are compressed as :class:`~rackstress.engines.dumpio.CompressJob`
    would compress them (:class:`~rackstress.engines.dumpio.GzAhead`). The GIL is handed over every 0.5 ms meanwhile (not
    5), so the driver's Python between chunks of steps never waits long for it.
    :func:`stop_prepared` stops it (at once: it ends after the chunk or import under way),
    :func:`wait_prepared` stops and joins it, and a fork joins it first (``os.register_at_fork``:
    a child forked while the thread holds an import lock would wait on it forever), so that
    the last step's post-processing does not wait for an import it does not need. The thread
    is not a daemon: an interpreter that ends early waits for it rather than cut an import."""
    import importlib
    import sys
    import threading

    stop = threading.Event()

    def work():
        import gc

        old = sys.getswitchinterval()
        sys.setswitchinterval(5e-4)
        # the objects so far, and each import's, are in no collection until the thread ends:
        # a full one over them (0.15-0.3 s, holding the GIL) would stop the simulation's
        # driver between its chunks of steps
        gc.freeze()
        if sys.platform.startswith("linux"):
            import os

            try:    # this thread only (Linux): on a busy machine the simulation goes first
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), NICE)
            except OSError:
                pass
        try:
            # a run that is over imports what it needs itself; without one, all is imported
            over = (lambda: stop.is_set()) if rundir is not None else (lambda: False)
            for name in _FIRST:
                if over():
                    return
                importlib.import_module(name)
                gc.freeze()
            from rackstress.stress import kernels

            if kernels.available() and kernels.compiled() and not over():
                kernels.warm()          # load the cached loop (a first run compiles it apart)
            gc.freeze()
            squeeze = None
            if rundir is not None and compress:
                from pathlib import Path

                from rackstress.engines.dumpio import GzAhead

                squeeze = GzAhead(Path(rundir) / "trajectory.dump")
            later = _later(squeeze)
            if rundir is not None and frames:
                from rackstress.stress.post import follow

                follow(rundir, stop, frames, idle=lambda: next(later, False))
            else:
                for done in later:
                    if not done:
                        break
        except Exception:  # noqa: BLE001, S110 - only a head start
            pass
        finally:
            sys.setswitchinterval(old)
            gc.unfreeze()

    if not _THREAD and not _HOOKED:
        import os

        os.register_at_fork(before=wait_prepared)
        _HOOKED.append(True)
    t = threading.Thread(target=work, name="rackstress-prepare")
    t.start()
    _THREAD.append((t, stop))
    return t


_THREAD: list = []
_HOOKED: list = []
#: the thread's niceness: on a machine with no idle core it takes what the simulation leaves
#: (magpod-small at load 3.5: the simulation 1.25 s beside it, 2.4 s at the same niceness,
#: 1.1 s without it)
NICE = 10


def stop_prepared() -> None:
    """Tell :func:`prepare_in_background`'s thread to stop (without waiting for it), at the
    usual niceness where this process may set it (the simulation is over: what it has under
    way should end before the first fork needs it)."""
    import os

    for t, stop in _THREAD:
        stop.set()
        try:
            os.setpriority(os.PRIO_PROCESS, t.native_id, os.getpriority(os.PRIO_PROCESS, 0))
        except (OSError, AttributeError, TypeError):
            pass


def wait_prepared() -> None:
    """Stop :func:`prepare_in_background`'s thread (its measuring, not an import) and wait
    for it, if one runs."""
    while _THREAD:
        t, stop = _THREAD.pop()
        stop.set()
        t.join()


# ----------------------------------------------------------------------------- in a process
class _Told:
    """The parent's messages in :class:`Ahead`'s process (one byte each), read as they come.

    ``is_set()`` (``follow``'s ``stop``): a message is waiting. ``urgent()``: one other than
    ``F`` is: ``F`` arrives with the simulation's first steps, while the measures' modules
    are still loading, and only says "measure as frames come", so it must not cut short
    what the measures need (their compiled loop and the dump's number parser, which a
    follow without them would do without: NumPy's reader, 7x slower)."""

    def __init__(self, fd: int):
        self.fd, self.queue = fd, []

    def is_set(self) -> bool:
        return self.wait(0)

    def wait(self, timeout) -> bool:
        import select

        return bool(self.queue) or bool(select.select([self.fd], [], [], timeout)[0])

    def urgent(self) -> bool:
        """Whether a message other than ``F`` is waiting (those waiting are read now)."""
        import os
        import select

        while not (self.queue and self.queue[-1] == b"") \
                and select.select([self.fd], [], [], 0)[0]:
            self.queue.append(os.read(self.fd, 1))
        return any(m != b"F" for m in self.queue)

    def read(self) -> bytes:
        """The next message (waiting for it); ``b""`` once the pipe is closed."""
        import os

        return self.queue.pop(0) if self.queue else os.read(self.fd, 1)


class Ahead:
    """Post-processing in a process of its own, forked before the simulation starts
    (``rackstress run`` on one process): the head start of :func:`prepare_in_background`
    without a thread in the simulation's process, whose Python between LAMMPS' chunks of
    steps then never waits for the GIL (magpod-small: the simulation 0.98-1.0 s alone, 1.20 s
    beside the thread, between its chunks 0.11 -> 0.20 s).

    The child, niced (:data:`NICE`), imports what the measures need and loads their compiled
    loop, then :data:`_PREPARE`'s modules, and waits for the parent, which tells it over a
    pipe, one byte a message:

    * ``F`` (:meth:`follow`, the run's steps left look short): measure the frames LAMMPS
      writes (:func:`rackstress.stress.post.follow`), and in between compress them
      (``compress``) and prepare the pictures' painter
      (:func:`rackstress.render.pictures.prepare_painter`);
    * ``E`` (:meth:`ended`, LAMMPS has closed the dump): check the guard rails (``guards()``,
      in a forked process, on the core the simulation leaves: the parent, told
      ``guards=False``, leaves them out of ``summary.json``, and scipy's import off its own
      path) and measure the frames left, in memory;
    * ``G`` (:meth:`go`, ``summary.json`` written): ``finish(guards())`` — the guard rails'
      warnings into ``summary.json``, then the run's post-processing, the same code as
      without a head start, its output after the parent's — and end with its exit status,
      which it writes over a second pipe once its output is closed, and :meth:`go` returns
      (without waiting for the process's exit: a thread reaps it);
    * ``Q`` or the pipe closed (the run diverged, failed, or the parent died): end, having
      written nothing.

    The child writes nothing into the run directory before ``G``. It dies with the parent
    (``PR_SET_PDEATHSIG``) and holds no copy of the run directory's lock. Where it cannot be
    forked, or dies before it is done, :meth:`go` returns None and the parent checks the
    guard rails (``guards()``) and post-processes the run itself."""

    def __init__(self, rundir, frames: int, compress: bool, finish, guards):
        import os
        import sys

        self.rundir, self.pid, self.fd, self.status = rundir, None, None, None
        self.done = None            # the child's exit status comes over it (_said)
        self.guards = guards
        parent = os.getpid()
        sys.stdout.flush()
        sys.stderr.flush()
        r, w = os.pipe()
        try:
            dr, dw = os.pipe()
        except OSError:
            os.close(r)
            os.close(w)
            return
        try:
            pid = os.fork()
        except OSError:
            for fd in (r, w, dr, dw):
                os.close(fd)
            return
        if pid == 0:                                            # the child
            code = 70
            try:
                os.close(w)
                os.close(dr)
                code = _ahead_child(r, parent, rundir, frames, compress, finish, guards)
            except KeyboardInterrupt:
                code = 130
            except BaseException:  # noqa: BLE001 - said, and the parent post-processes instead
                import traceback

                traceback.print_exc()
            finally:
                try:
                    sys.stdout.flush()
                    sys.stderr.flush()
                    # its output closed, then its status said: the run ends without waiting
                    # for this process's memory to be given back (a few hundred MB: 20-30 ms)
                    os.close(1)
                    os.close(2)
                    os.write(dw, bytes([code & 0xFF]))
                finally:
                    os._exit(code)
        os.close(r)
        os.close(dw)
        self.pid, self.fd, self.done = pid, w, dr

    def _tell(self, what: bytes) -> bool:
        import os

        if self.fd is None:
            return False
        try:
            os.write(self.fd, what)
            return True
        except OSError:             # the child is gone (killed): the parent does its work
            return False

    def follow(self) -> None:
        """Measure the frames as they are written (and compress them, prepare the painter)."""
        self._tell(b"F")

    def ended(self) -> None:
        """LAMMPS has closed the dump: measure the frames left (nothing written yet), at the
        usual niceness where this process may set it (the simulation is over)."""
        self._renice()
        self._tell(b"E")

    def _renice(self) -> None:
        import os

        if self.pid is not None:
            try:
                os.setpriority(os.PRIO_PROCESS, self.pid, os.getpriority(os.PRIO_PROCESS, 0))
            except OSError:
                pass

    def go(self) -> int | None:
        """Post-process the finished run in the child (``summary.json`` is written, the
        parent's lines printed) and wait for it: its exit status, or None if it could not do
        it (it died, or was never forked): then the caller does it."""
        import sys

        if self.fd is None:
            return None
        sys.stdout.flush()
        sys.stderr.flush()
        self._renice()              # the simulation is over (if ended() was not told)
        told = self._tell(b"G")
        status = self._said() if told else None
        if status is None:
            status = self._wait()
        if not told or status is None or status < 0 or status in (70, 130):
            return None
        return status

    def _said(self) -> int | None:
        """The exit status the child wrote once its work and output were done, or None if it
        ended without (killed). Its exit is then reaped by a thread, not waited for."""
        import os
        import threading

        if self.done is None:
            return None
        try:
            got = os.read(self.done, 1)
        except OSError:
            got = b""
        self._close_pipes()
        if not got:
            return None
        pid, self.pid = self.pid, None
        threading.Thread(target=_reap, args=(pid,), daemon=True).start()
        self.status = got[0]
        return self.status

    def quit(self) -> None:
        """End the child without post-processing (the run failed, or was post-processed)."""
        import os
        import signal

        if self.pid is None:
            return
        if not self._tell(b"Q"):
            try:
                os.kill(self.pid, signal.SIGKILL)
            except OSError:
                pass
        self._wait()

    def _close_pipes(self) -> None:
        import os

        for name in ("done", "fd"):
            fd = getattr(self, name)
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
                setattr(self, name, None)

    def _wait(self) -> int | None:
        """Close the pipes and wait for the child: its exit status (negative: the signal that
        ended it)."""
        import os

        self._close_pipes()
        if self.pid is not None:
            try:
                _, st = os.waitpid(self.pid, 0)
                self.status = os.waitstatus_to_exitcode(st)
            except ChildProcessError:
                self.status = None
            self.pid = None
        return self.status


def _reap(pid: int) -> None:
    import os

    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass


def _ahead_child(r: int, parent: int, rundir, frames: int, compress: bool, finish,
                 guards) -> int:
    """:class:`Ahead`'s process: its exit status."""
    import gc
    import importlib
    import os

    from rackstress.runs.rundir import in_forked_child

    in_forked_child(parent)         # no copy of the lock; dies with the parent
    try:
        os.nice(NICE)               # on a busy machine the simulation goes first
    except OSError:
        pass
    told = _Told(r)
    gc.disable()                    # imports: no collection walks their objects (a third less)
    for name in _FIRST:
        if told.urgent():
            break
        importlib.import_module(name)
    from rackstress.stress import kernels

    if not told.urgent() and kernels.available() and kernels.compiled():
        kernels.warm()              # load the cached loop (a first run compiles it apart)
    squeeze = None
    if compress:
        from pathlib import Path

        from rackstress.engines.dumpio import GzAhead

        squeeze = GzAhead(Path(rundir) / "trajectory.dump")
    later = _later(squeeze, rundir)
    while not told.is_set():        # the rest of the imports, until told something
        if not next(later, False):
            break
    gc.freeze()                     # what is imported: in no collection from now on
    gc.enable()
    kept = checking = None
    while True:
        what = told.read()
        if what == b"F" and frames:
            from rackstress.stress.post import follow

            follow(rundir, told, frames, idle=lambda: next(later, False))
        elif what == b"E" and kept is None:
            from rackstress.stress.post import compute_fields
            from rackstress.stress.rundata import kept_open, load_run

            # while the parent summarizes: the guard rails in a process of their own (the
            # core the simulation used is idle now), the frames left here
            checking = _guards_beside(guards)
            kept = kept_open()
            kept.__enter__()
            try:
                compute_fields(load_run(rundir))
            except Exception:  # noqa: BLE001, S110 - post-processing says it again after G
                pass
        elif what == b"G":
            found = None
            if checking is not None:
                try:
                    found = tuple(checking.join())
                except Exception:  # noqa: BLE001, S110 - checked again here, and said then
                    pass
            return finish(found if found is not None else guards())
        elif what in (b"Q", b""):
            if checking is not None:
                checking.kill()
            return 0


def _guards_beside(guards):
    """``guards()`` in a forked process (:class:`~rackstress.runs.forked.ForkedJob`, its result
    in a temporary file outside the run directory), or None where it cannot start."""
    import tempfile
    from pathlib import Path

    from rackstress.runs.forked import ForkedJob

    try:
        fd, name = tempfile.mkstemp(prefix="rackstress-guards-", suffix=".json")
        import os

        os.close(fd)
        return ForkedJob(guards, Path(name))
    except Exception:  # noqa: BLE001 - checked after G instead
        return None
