"""Shared pieces of the test suite.

* the venv's executables (``RACKSTRESS``, ``MPIEXEC``), for tests that run real processes;
* :func:`reference_final`: a scene's final positions on the reference engine (the independent
  path every parity test compares against), computed once per test process and scene — keyed
  by the scene's fingerprint, so two tests that build the same scene share one trajectory.

Markers (registered in pyproject.toml): ``lammps``, ``mpi``, ``slow``; the quick tier is
``pytest -m 'not slow'``. README's test command runs everything on both cores (pytest-xdist).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

BIN = Path(sys.executable).parent
RACKSTRESS, MPIEXEC = str(BIN / "rackstress"), str(BIN / "mpiexec")

_FINAL: dict = {}


def reference_final(scene) -> np.ndarray:
    """Final positions of ``scene`` on the reference engine (read-only, cached by fingerprint)."""
    from rackstress.engines.driver import drive
    from rackstress.engines.reference import Reference
    from rackstress.runs.fingerprint import dumps, fingerprint

    key = dumps(fingerprint(scene, engine="reference", mode="exact", dump_every=1))
    if key not in _FINAL:
        p = drive(Reference(scene)).positions
        p.flags.writeable = False
        _FINAL[key] = p
    return _FINAL[key]


@pytest.fixture(name="reference_final")
def _reference_final_fixture():
    return reference_final
