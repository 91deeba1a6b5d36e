"""Any output path works in LAMMPS: spaces, both quotes and non-ASCII characters in every path
rackstress hands LAMMPS (read_data, the dump, the log, write_restart, plugin load, the static
analysis' write_dump), serial and under ``mpiexec -n 2``; a resumed run into such a directory;
a standalone deck in such a directory run by plain ``lmp`` and ``mpiexec -n 2 lmp``; a path
LAMMPS cannot take refused with exit 2 before anything is written. The plugin is loaded once.
Real processes, real LAMMPS, real MPI."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import dump_text, trajectory

BIN = Path(sys.executable).parent
RS, MPIEXEC, LMP = str(BIN / "rackstress"), str(BIN / "mpiexec"), str(BIN / "lmp")
QUIET = ["--no-render", "--no-progress"]
#: a hang guard, not a speed limit: minutes on a 2-core machine that others load fully
HANG_S = 900
#: a space, both quotes, a LAMMPS comment and variable sign, and non-ASCII letters
ODD = "T15 résultat 'q\" #$x ünï"


def rs(*args, mpi: bool = False, **kw):
    cmd = ([MPIEXEC, "-n", "2"] if mpi else []) + [RS, *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=HANG_S, **kw)


def frames_of(run: Path) -> str:
    return dump_text(trajectory(run))


@pytest.mark.lammps
@pytest.mark.mpi
@pytest.mark.slow
def test_runs_into_a_path_with_spaces_quotes_and_non_ascii(tmp_path):
    plain = tmp_path / "plain"
    r = rs("run", "plane-rack", "--steps", "60000", "--dump-every", "5000", "--restart-every",
           "1000", "--out", plain, *QUIET)
    assert r.returncode == 0, r.stderr
    # serial, killed after a checkpoint (write_restart into the odd path), then resumed (the
    # log appended to through its own path): the plain path's trajectory, byte for byte
    odd = tmp_path / ODD / "run"
    p = subprocess.Popen([RS, "run", "plane-rack", "--steps", "60000", "--dump-every", "5000",
                          "--restart-every", "1000", "--out", str(odd), *QUIET],
                         start_new_session=True, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + HANG_S
        while not (odd / "progress.json").exists() and p.poll() is None \
                and time.monotonic() < end:
            time.sleep(0.02)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        _, err = p.communicate()
    assert (odd / "progress.json").exists() and not (odd / "summary.json").exists(), err
    r = rs("run", "--resume", odd, *QUIET)
    assert r.returncode == 0, r.stderr
    assert frames_of(odd) == frames_of(plain)
    log = (odd / "log.lammps").read_text(errors="replace")
    # the plugin loaded once a LAMMPS instance, by the deck's own plugin load (the run and its
    # resumption: two), never also from LAMMPS_PLUGIN_PATH at the instance's start
    assert "Ignoring load" not in log and "plugins from" not in log
    assert log.count("Loading plugin: rackstress: the rack coupling") == \
        len(re.findall(r"^plugin load '", log, re.M)) >= 1
    # two ranks into such a path
    two = tmp_path / ODD / "two"
    r = rs("run", "plane-rack", "--steps", "300", "--dump-every", "50", "--restart-every",
           "100", "--out", two, *QUIET, mpi=True)
    assert r.returncode == 0, r.stderr
    assert re.findall(r"ITEM: TIMESTEP\n(\d+)", frames_of(two)) == \
        [str(k) for k in range(0, 301, 50)]
    assert (two / "restart").is_dir()


@pytest.mark.lammps
def test_a_static_analysis_and_a_standalone_deck_in_such_a_path(tmp_path):
    scene = tmp_path / "bar.toml"
    scene.write_text('name = "bar"\nunits = "mm-N-s"\nanalysis = "static"\n\n[[group]]\n'
                     'name = "bar"\nfill = { box = { min = [0, 0, 0], max = [10, 3, 3] } }\n'
                     'spacing = 1.0\nmaterial = "steel"\n\n[[support]]\non = "bar"\n'
                     'where = { box = { min = [-1, -1, -1], max = [0.5, 4, 4] } }\n\n[[load]]\n'
                     'on = "bar"\nwhere = { box = { min = [9.5, -1, -1], max = [11, 4, 4] } }\n'
                     'force = [0, -10, 0]\n')
    out = tmp_path / ODD / "static"
    r = rs("run", scene, "--out", out, *QUIET)
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["settled"] is True
    # the equilibrium frame written by write_dump through the odd path
    steps = re.findall(r"ITEM: TIMESTEP\n(\d+)", frames_of(out))
    assert steps[0] == "0" and int(steps[-1]) == max(1, s["iterations"])
    # a deck: relative file names, run from its folder by plain LAMMPS, 1 and 2 ranks
    deck = tmp_path / ODD / "deck"
    r = rs("deck", "plane-rack", "--steps", "100", "--dump-every", "50", "--out", deck)
    assert r.returncode == 0, r.stderr
    for cmd in ([LMP, "-in", "in.lammps"], [MPIEXEC, "-n", "2", LMP, "-in", "in.lammps"]):
        (deck / "trajectory.dump").unlink(missing_ok=True)
        r = subprocess.run(cmd, cwd=deck, capture_output=True, text=True, timeout=HANG_S)
        assert r.returncode == 0, r.stdout[-2000:] + r.stderr
        text = (deck / "trajectory.dump").read_text()
        assert re.findall(r"ITEM: TIMESTEP\n(\d+)", text) == ["0", "50", "100"]


def test_a_path_lammps_cannot_take_is_refused_before_anything_is_written(tmp_path):
    for name in ("a*b", "line\nbreak"):
        out = tmp_path / name
        r = rs("run", "plane-bound", "--steps", "5", "--out", out, *QUIET)
        assert r.returncode == 2, r.stderr
        assert "LAMMPS" in r.stderr and "choose" in r.stderr and "Traceback" not in r.stderr
        assert not out.exists()
    # the reference engine hands LAMMPS nothing: any path is its own
    r = rs("run", "plane-bound", "--engine", "reference", "--steps", "5", "--out",
           tmp_path / "a*b", *QUIET)
    assert r.returncode == 0, r.stderr
