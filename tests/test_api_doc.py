"""docs/api.md's examples run as written (a plane-rack run on LAMMPS, the reference engine, the
stress measures and the post-processing): expected values in it come from the scene's geometry
(20 × 20 plane, six racks, Eq. 15's pulled corner) and Eq. 5 by hand (t²·â after one step)."""
from __future__ import annotations

import doctest
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[1] / "docs" / "api.md"


@pytest.mark.lammps
def test_api_examples_run_as_documented(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = doctest.testfile(str(DOC), module_relative=False, optionflags=doctest.ELLIPSIS,
                              raise_on_error=False, verbose=False)
    assert result.attempted >= 20
    assert result.failed == 0, f"{result.failed} of docs/api.md's examples failed (see output)"


DOCTESTED = ["rackstress.scenes.builtins", "rackstress.scenes", "rackstress.model.operators",
             "rackstress.model.particles", "rackstress.model.regions", "rackstress.model.verlet",
             "rackstress.lib.rigid", "rackstress.runs.fingerprint", "rackstress.runs.rundir",
             "rackstress.engines.lammps.runner", "rackstress.stress.legs",
             "rackstress.stress.notch", "rackstress.stress.governing", "rackstress.lib.forked",
             "rackstress.stress.offsets"]


@pytest.mark.parametrize("module", DOCTESTED)
def test_docstring_examples_of_public_entry_points(module):
    """The Examples sections of the public entry points run as written."""
    import importlib

    result = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS)
    assert result.attempted >= 1 and result.failed == 0
