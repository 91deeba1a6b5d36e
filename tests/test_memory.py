"""Memory: a limit on the process (``ulimit -v``, a batch job's) is what the up-front
estimates compare with, and a MemoryError met anywhere is one paragraph and exit 2 (errors.py),
never a traceback. Real processes under a real ``ulimit -v``."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
RS = str(BIN / "rackstress")
REPO = Path(__file__).resolve().parents[1]
HANG_S = 900        # a hang guard, not a speed limit


def limited(kb: int, *args, cwd=None):
    """``rackstress ARGS`` under ``ulimit -v KB`` (bash's, as a user or a batch system sets it)."""
    cmd = " ".join(f"'{a}'" for a in (RS, *map(str, args)))
    return subprocess.run(["bash", "-c", f"ulimit -v {kb} && exec {cmd}"], cwd=cwd,
                          capture_output=True, text=True, timeout=HANG_S)


def test_the_memory_estimate_compares_with_the_process_limit(tmp_path):
    """27 million particles need ~5 GiB to build (200 B each): under ulimit -v 2 GB refused up
    front, naming both figures (was: compared with the machine's 20 GiB free, then a
    MemoryError after the allocations began)."""
    scene = tmp_path / "huge.toml"
    scene.write_text('name = "huge"\nsteps = 1\n[[group]]\nname = "a"\nkind = "part"\n'
                     'lattice = { shape = [300, 300, 300] }\nradius = 0.5\n')
    r = limited(2_000_000, "run", scene, "--engine", "reference", "--out", tmp_path / "r",
                "--no-progress")
    assert r.returncode == 2, r.stderr
    assert "needs about 5.0 GiB" in r.stderr and "ulimit -v" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "r").exists()


@pytest.mark.slow
def test_a_memory_error_is_a_message_and_exit_2(tmp_path):
    """``rackstress fea`` of the bracket (2,664 particles) under ulimit -v 1.5 GB: its FE
    assembly cannot allocate (was: numpy's _ArrayMemoryError traceback, exit 1)."""
    run = tmp_path / "b"
    r = subprocess.run([RS, "run", REPO / "examples/bracket/static.toml", "--out", run,
                        "--no-render", "--no-progress"], capture_output=True, text=True,
                       timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    r = limited(1_500_000, "fea", run)
    assert r.returncode == 2, r.stderr
    assert "memory" in r.stderr and "Traceback" not in r.stderr
    assert r.stderr.count("rackstress: error:") == 1
