"""Whether the measures' compiled loop (:mod:`rackstress.stress.kernels`) is in this machine's
cache, and compiling it apart when not, without importing numba: ``rackstress run`` asks
before its simulation, where numba's import (0.15 s) would only delay the start."""
from __future__ import annotations

import os
from importlib.util import find_spec
from pathlib import Path

from rackstress.lib.jit import cache_dir

_WARMING: dict = {}


def compiled() -> bool:
    """Whether this machine's kernel cache already holds the loop and the dump's number parser
    (lib/numtext.py; a first run has not); True without numba (the NumPy path compiles
    nothing)."""
    if find_spec("numba") is None:
        return True
    import tempfile

    # numba_or_none's fallback for an unwritable cache (lib/jit.py) is looked in too
    places = [cache_dir(), Path(tempfile.gettempdir()) / f"rackstress-numba-{os.getuid()}"]
    return any(any(d.glob("stress_*/kernels._strain-*.nbi"))
               and any(d.glob("stress_*/kernels._robust_keep-*.nbi"))
               and any(d.glob("lib_*/numtext._numbers-*.nbi")) for d in places)


def warm_in_background() -> None:
    """On a machine whose cache lacks the loop, compile it in a separate process now (while
    the simulation runs on the other core), so that the measures later only load it;
    :func:`wait_warm` waits for that process. Nothing to do where it is cached already."""
    import subprocess
    import sys

    if compiled() or "proc" in _WARMING:
        return
    try:
        _WARMING["proc"] = subprocess.Popen(
            [sys.executable, "-c", "from rackstress.stress.kernels import warm; warm()"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        pass                            # the measures compile it themselves


def wait_warm() -> None:
    """Wait for :func:`warm_in_background`'s process, if one runs."""
    proc = _WARMING.pop("proc", None)
    if proc is not None:
        try:
            proc.wait(timeout=120)
        except Exception:  # noqa: BLE001 - a stuck compile: the measures compile it themselves
            proc.kill()
