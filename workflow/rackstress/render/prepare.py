"""A head start for post-processing: its imports, loaded while the simulation runs.

This module imports nothing heavy itself, so that ``rackstress run`` can start it before the
simulation without paying for it there.
"""
from __future__ import annotations

#: What the measures need first (:func:`rackstress.stress.post.follow`, and the run's summary
#: after its last step: the rigid fit), then what the VTK writer, the pictures, the plots and
#: the 3D view import, first what most of them share and what the longest of them (the
#: plots' process) needs: done by :func:`prepare_in_background` while the simulation runs.
_FIRST = ("scipy.spatial.transform", "rackstress.stress.post")
_PREPARE = ("vtkmodules.vtkCommonDataModel", "vtkmodules.util.numpy_support",
            "matplotlib.figure", "matplotlib.backends.backend_agg",
            "vtkmodules.vtkRenderingOpenGL2", "vtkmodules.vtkRenderingCore", "PIL.Image",
            "PIL.ImageDraw", "PIL.PngImagePlugin", "vtkmodules.vtkIOXML",
            "rackstress.stress.export", "rackstress.render.pictures", "rackstress.render.report",
            "rackstress.render.view3d", "trame_vtk.modules.vtk.serializers",
            "vtkmodules.vtkFiltersSources", "vtkmodules.vtkFiltersCore")


def _later(squeeze=None):
    """:data:`_PREPARE`'s imports and the fonts, one step a call (what :func:`follow` does
    while no new chunk of frames is written), each yielding True; then, given ``squeeze`` (a
    :class:`~rackstress.engines.dumpio.GzAhead`), the trajectory's frames compressed as they
    are written, yielding whether one was."""
    import gc
    import importlib

    for name in _PREPARE:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001, S112 - only a head start: the user imports it
            pass
        gc.freeze()             # what it made: in no collection while the thread runs
        yield True
    try:
        from rackstress.render.pictures import _font

        for size in (13, 14, 17, 18):
            _font(size)
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
