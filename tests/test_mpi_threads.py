"""The thread support rackstress asks of MPI (lib/mpi.py, ``THREAD_LEVEL``): ``funneled`` for
everything (the main thread alone calls MPI; ``multiple`` made MPICH lock around every call,
magpod's 2-rank steps 5-10 % slower under ``rackstress run`` than in ``lmp``), ``multiple`` for
``rackstress batch``, whose manager thread on rank 0 serves the other ranks."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import HANG_S

BIN = Path(sys.executable).parent
ENV = {k: v for k, v in os.environ.items() if k != "MPI4PY_RC_THREAD_LEVEL"}


def query(code: str, env=None) -> str:
    r = subprocess.run([sys.executable, "-c", code + "\nfrom mpi4py import MPI\n"
                        "print({MPI.THREAD_SINGLE: 'single', MPI.THREAD_FUNNELED: 'funneled',"
                        " MPI.THREAD_SERIALIZED: 'serialized', MPI.THREAD_MULTIPLE: 'multiple'}"
                        "[MPI.Query_thread()])"], capture_output=True, text=True, timeout=HANG_S,
                       env=env or ENV)
    assert r.returncode == 0, r.stderr
    return r.stdout.split()[-1]


def test_rackstress_asks_for_the_main_thread_only_and_batch_for_every_thread():
    assert query("") == "multiple"                  # mpi4py's own default, without rackstress
    assert query("import rackstress") == "funneled"
    assert query("import rackstress\nfrom rackstress.lib.mpi import threads\n"
                 "assert threads('multiple')") == "multiple"
    # once MPI has started nothing changes; the environment wins
    assert query("import rackstress\nfrom mpi4py import MPI\nfrom rackstress.lib.mpi import "
                 "threads\nassert not threads('multiple')") == "funneled"
    assert query("import rackstress", env={**ENV, "MPI4PY_RC_THREAD_LEVEL": "serialized"}) \
        == "serialized"


@pytest.mark.lammps
@pytest.mark.mpi
def test_batch_under_two_ranks_keeps_its_manager_thread(tmp_path):
    """``mpiexec -n 2 rackstress batch``: rank 0's manager is a thread (it needs
    MPI_THREAD_MULTIPLE), so both ranks run jobs: the index says ``thread``."""
    sw = tmp_path / "two.toml"
    sw.write_text('scene = "plane-rack"\nengine = "lammps"\nmode = "exact"\nsteps = 20\n'
                  '\n[[job]]\nname = "a"\nplane_bind = 50.0\n'
                  '\n[[job]]\nname = "b"\nplane_bind = 100.0\n')
    d = tmp_path / "b"
    r = subprocess.run([str(BIN / "mpiexec"), "-n", "2", str(BIN / "rackstress"), "batch",
                        str(sw), "--out", str(d), "--no-render"], capture_output=True,
                       text=True, timeout=HANG_S, env=ENV)
    assert r.returncode == 0, r.stderr
    ix = json.loads((d / "batch.json").read_text())
    assert ix["complete"] is True and ix["passes"][-1]["manager"] == "thread", ix
    assert "rank 0 (thread)" in r.stdout, r.stdout
