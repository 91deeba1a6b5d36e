"""Faults of round three (issue 25), played with real processes as in ``test_faults.py``: a full
disk during post-processing and rendering (real tmpfs mounts), a schedule of 10¹² steps on the
LAMMPS engine, scene expressions that would take unbounded time, parameters that are themselves
expressions, NaN positions kept by a divergence, and the progress every long phase shows."""
from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import pytest

from test_faults import QUIET, RS, fill, frames, leftovers, rs, tmpfs  # noqa: F401 (fixture)


# ---------------------------------------------------------------------------- disks
@pytest.mark.lammps
def test_full_disk_during_post_processing_is_a_storage_error(tmpfs):
    """The run (5.4 MB of dump) fits in 8 MB, its VTK series (~20 MB) does not: VTK's own file
    writer crashed the process there (SIGSEGV, exit 139, nothing printed)."""
    disk = tmpfs("8m")
    out = disk / "r"
    r = rs("run", "plane-rack", "--steps", "3000", "--dump-every", "10", "--out", out, *QUIET,
           timeout=300)
    assert r.returncode == 5, (r.returncode, r.stderr)
    assert "No space left on device" in r.stderr and "Traceback" not in r.stderr
    assert f"rackstress stress {out}" in r.stderr          # what to do once there is space
    assert str(out / "vtk") in r.stderr                     # what could not be written
    # the run is whole; nothing of the VTK series is left, half or as if whole
    assert len(frames(out / "trajectory.dump")) == 301
    assert not (out / "vtk").exists() and leftovers(out) == []
    assert not [p for p in out.iterdir() if p.name.startswith(".vtk")]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok" and "stress" not in summary


@pytest.mark.lammps
def test_full_disk_while_rendering_is_a_storage_error(tmpfs):
    disk = tmpfs("8m")
    out = disk / "r"
    r = rs("run", "plane-rack", "--steps", "300", "--dump-every", "10", "--out", out, *QUIET)
    assert r.returncode == 0, r.stderr
    fill(disk / "filler")
    r = rs("render", out, "--no-progress", timeout=300)
    assert r.returncode == 5, (r.returncode, r.stderr)
    assert "No space left on device" in r.stderr and "Traceback" not in r.stderr
    assert str(out / "figures") in r.stderr
    assert not (out / "figures").exists() and not (out / "report.html").exists()
    assert leftovers(out) == [] and not [p for p in out.iterdir() if ".tmp" in p.name]
