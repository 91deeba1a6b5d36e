"""Where numba keeps compiled code: one place for every compiled module.

``NUMBA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/rackstress/numba`` (``~/.cache/…``); an
unwritable one (a batch node's home) falls back to the temporary directory. Importing
:func:`numba` through :func:`numba_or_none` sets it before any ``cache=True`` function is
compiled, so the first run on a machine compiles and later ones load.
"""
from __future__ import annotations

import os
from pathlib import Path


def cache_root() -> Path:
    """rackstress' own cache: ``$XDG_CACHE_HOME/rackstress``, else ``~/.cache/rackstress``
    (compiled kernels here, fTetWild's meshes: ``validity.solid.tetwild_cache``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rackstress"


def cache_dir() -> Path:
    """Where compiled kernels are kept (``NUMBA_CACHE_DIR`` if set)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    return cache_root() / "numba"


def numba_or_none():
    """The numba module with its cache directory set (module docstring), or None."""
    try:
        import numba as nb
    except ImportError:
        return None
    if not os.environ.get("NUMBA_CACHE_DIR"):
        nb.config.CACHE_DIR = str(cache_dir())
    try:
        Path(nb.config.CACHE_DIR).mkdir(parents=True, exist_ok=True)
    except OSError:
        import tempfile

        os.environ["NUMBA_CACHE_DIR"] = str(Path(tempfile.gettempdir())
                                            / f"rackstress-numba-{os.getuid()}")
        nb.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
    return nb
