"""Shared pieces of the test suite.

* the venv's executables (``RACKSTRESS``, ``MPIEXEC``), for tests that run real processes;
* :func:`trajectory` and :func:`dump_text`: a run's trajectory file (``trajectory.dump``, or
  ``trajectory.dump.gz`` once ``rackstress run`` has finished) and its text, read with the
  standard library's ``gzip`` (not rackstress' reader, which is under test);
* :func:`reference_final`: a scene's final positions on the reference engine (the independent
  path every parity test compares against), computed once per test process and scene — keyed
  by the scene's fingerprint, so two tests that build the same scene share one trajectory.

* :data:`HANG_S` and :func:`child_cpu`: a test's time limits are for hangs, not for speed. A
  limit on a process, or on waiting for something it writes, is :data:`HANG_S` — minutes more
  than any command here takes on a 2-core machine that another process loads fully — so a
  loaded machine never fails a test; a claim of bounded work ("refused before building",
  "stops after its iterations") is the CPU time its processes used (:func:`child_cpu`), which
  another process's load does not change, or a count of the work done (steps, frames).

* :func:`pytest_sessionstart`: before the workers start, two processes compile (or load) the
  LAMMPS callback's numba kernels, one the fused step and one the rest, so that no worker and
  no ``rackstress run`` a test starts compiles them again (a fresh clone's install compiles
  them: 34 s in one process, and every process started before the cache is there compiled
  all of them itself).

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

#: the limit on any one process a test starts, and on waiting for what it writes: a hang guard
#: (pyproject.toml's pytest timeout is the whole test's)
HANG_S = 900


def pytest_sessionstart(session):
    """The callback's kernels compiled into the cache once, by two processes, before the
    workers start (module doc); in a worker, nothing. A warm-up that fails leaves each test to
    compile what it needs, as before."""
    import subprocess

    if hasattr(session.config, "workerinput"):
        return
    code = ("import sys; from rackstress.model.kernels import warm; warm(sys.argv[1]); "
            "from rackstress.stress.kernels import warm as w; sys.argv[1] == 'rest' and w()")
    procs = [subprocess.Popen([sys.executable, "-c", code, part], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL) for part in ("step", "rest")]
    for proc in procs:
        try:
            proc.wait(timeout=HANG_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class child_cpu:
    """The CPU time (user + system, seconds) of the child processes that ended and were waited
    for inside the ``with`` block (``resource.RUSAGE_CHILDREN``: the kernel's account, the same
    on a loaded machine and a quiet one).

    >>> import subprocess, sys
    >>> with child_cpu() as cpu:
    ...     _ = subprocess.run([sys.executable, "-c", "pass"])
    >>> 0 < cpu.s < 5
    True
    """

    def __enter__(self):
        import resource

        self._t0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        self.s = None
        return self

    def __exit__(self, *exc):
        import resource

        t1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        self.s = (t1.ru_utime - self._t0.ru_utime) + (t1.ru_stime - self._t0.ru_stime)
        return False


def trajectory(rundir) -> Path:
    """The run's trajectory: ``trajectory.dump.gz`` if the run finished (``rackstress run``
    compresses it), else ``trajectory.dump``."""
    gz = Path(rundir) / "trajectory.dump.gz"
    return gz if gz.is_file() else Path(rundir) / "trajectory.dump"


def dump_text(path) -> str:
    """A dump file's text as LAMMPS wrote it (a ``.gz`` read through ``gzip``)."""
    import gzip

    path = Path(path)
    if path.name.endswith(".gz"):
        with gzip.open(path, "rt") as fh:
            return fh.read()
    return path.read_text()


def lammps_finals(scene, monkeypatch):
    """Run ``scene`` on LAMMPS with the compiled plugin, then with the Python callback's numba
    and NumPy kernels: yields (plugin, kernels, the deck's input text, final positions)."""
    from rackstress.engines.driver import drive
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    for plugin, kernels in ((True, None), (False, "numba"), (False, "numpy")):
        if kernels:
            monkeypatch.setenv("RACKSTRESS_KERNELS", kernels)
        deck = compile_deck(scene, "exact", plugin=plugin)
        run = LammpsRun(deck, None)
        try:
            drive(run)
            p = run.gather_positions()
        finally:
            run.close()
        yield plugin, kernels, deck.input_text(), p


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


#: A script run by ``mpiexec -n 2``: each scene that ``SETUP`` puts in ``scenes_`` (key → scene)
#: runs as one LAMMPS instance over both ranks; rank 0 saves the final positions and the atoms
#: each rank held (``KEY.npy``, ``KEY-counts.npy``).
_MPI_SCRIPT = """
import sys, numpy as np
sys.path.insert(0, sys.argv[2])
from rackstress.engines.driver import drive
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import LammpsRun
from rackstress.lib.mpi import world
{setup}
for key, scene in scenes_.items():
    run = LammpsRun(compile_deck(scene, "exact"{compile_kw}), None)
    drive(run)
    p = run.gather_positions()
    counts = world().allgather(run.lmp.extract_global("nlocal"))
    run.close()
    if world().Get_rank() == 0:
        np.save(f"{{sys.argv[1]}}/{{key}}.npy", p)
        np.save(f"{{sys.argv[1]}}/{{key}}-counts.npy", np.array(counts))
"""


def lammps_under_mpi(tmp_path, setup: str, timeout: int = 900, plugin: bool = False) -> dict:
    """Run the scenes ``setup`` (Python source) defines in ``scenes_`` on two ranks, exact mode
    (``plugin``: with the compiled operator styles instead of the Python callback).

    Returns key → (final positions, atoms per rank). The tests folder is importable in
    ``setup`` (e.g. ``from test_supports import impact_scene``).
    """
    import subprocess

    script = tmp_path / "mpi_run.py"
    script.write_text(_MPI_SCRIPT.format(setup=setup,
                                         compile_kw=", plugin=True" if plugin else ""))
    proc = subprocess.run([MPIEXEC, "-n", "2", sys.executable, str(script), str(tmp_path),
                           str(Path(__file__).parent)], capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-3000:]
    keys = [p.name[:-len("-counts.npy")] for p in tmp_path.glob("*-counts.npy")]
    return {k: (np.load(tmp_path / f"{k}.npy"), np.load(tmp_path / f"{k}-counts.npy"))
            for k in keys}
