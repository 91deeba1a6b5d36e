"""A head start for post-processing: its imports, loaded while the simulation runs.

This module imports nothing heavy itself, so that ``rackstress run`` can start it before the
simulation without paying for it there.
"""
from __future__ import annotations

#: What post-processing and the default render import, kernels and fonts they load: done by
#: :func:`prepare_in_background` while the simulation runs.
_PREPARE = ("rackstress.stress.post", "rackstress.stress.export", "vtkmodules.vtkIOXML",
            "vtkmodules.vtkRenderingOpenGL2", "vtkmodules.vtkRenderingCore",
            "vtkmodules.util.numpy_support", "PIL.Image", "PIL.ImageDraw", "PIL.PngImagePlugin",
            "matplotlib.figure", "matplotlib.backends.backend_agg", "rackstress.render.pictures",
            "rackstress.render.report", "rackstress.render.view3d", "trame_vtk.modules.vtk.serializers",
            "vtkmodules.vtkFiltersSources", "vtkmodules.vtkFiltersCore")


def prepare_in_background(rundir=None, frames: int | None = None):
    """Import what the measures, the VTK writer, the pictures and the plots need, load the
    measures' compiled loop and the fonts, in a thread, while the simulation runs on the
    other core (LAMMPS runs the plugin without the GIL; ``rackstress run`` starts it once a
    quarter of the steps are done). About a second of a short run's start-up to
    results moves off the path; the forked VTK and plot processes inherit it all. Then, given
    the run directory ``rundir`` and the ``frames`` it will hold, the thread measures the
    frames LAMMPS has written so far (:func:`rackstress.stress.post.follow`) until
    :func:`wait_prepared`: post-processing measures only the last ones. The GIL is
    handed over every 0.5 ms meanwhile (not 5), so the driver's Python between chunks of
    steps never waits long for it. :func:`wait_prepared` stops and joins it: call it before
    forking (a child forked while the thread holds an import lock would wait on it forever).
    The thread is not a daemon: an interpreter that ends early waits for it rather than cut
    an import."""
    import importlib
    import sys
    import threading

    stop = threading.Event()

    def work():
        old = sys.getswitchinterval()
        sys.setswitchinterval(5e-4)
        try:
            for name in _PREPARE:
                try:
                    importlib.import_module(name)
                except Exception:  # noqa: BLE001, S112 - only a head start: the user imports it
                    continue
            from rackstress.stress import kernels

            if kernels.available() and kernels.compiled():
                kernels.warm()          # load the cached loop (a first run compiles it apart)
            from rackstress.render.pictures import _font

            for size in (13, 14, 17, 18):
                _font(size)
            from matplotlib import font_manager

            font_manager.findfont("DejaVu Sans")
            if rundir is not None and frames:
                from rackstress.stress.post import follow

                follow(rundir, stop, frames)
        except Exception:  # noqa: BLE001, S110 - only a head start
            pass
        finally:
            sys.setswitchinterval(old)

    t = threading.Thread(target=work, name="rackstress-prepare")
    t.start()
    _THREAD.append((t, stop))
    return t


_THREAD: list = []


def wait_prepared() -> None:
    """Stop :func:`prepare_in_background`'s thread (its measuring, not an import) and wait
    for it, if one runs."""
    while _THREAD:
        t, stop = _THREAD.pop()
        stop.set()
        t.join()
