"""Faults played with real processes: two runs on one directory, kill -9, stale and foreign
checkpoints, an edited scene file, divergence inside LAMMPS and inside the callback, full and
read-only disks (real tmpfs mounts), a failing rank under ``mpiexec -n 2``, and the input edges.
Every test runs the installed ``rackstress`` command and checks its exit status (errors.py), its
message and what it left on disk."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import HANG_S, child_cpu, dump_text, trajectory

BIN = Path(sys.executable).parent
RS = str(BIN / "rackstress")
MPIEXEC = str(BIN / "mpiexec")
QUIET = ["--no-render", "--no-progress"]


def rs(*args, timeout=HANG_S, **kw):
    return subprocess.run([RS, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, **kw)


def mpi_rs(*args, timeout=HANG_S):
    return subprocess.run([MPIEXEC, "-n", "2", RS, *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


def wait_for(pred, timeout=HANG_S, proc=None):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        if proc is not None and proc.poll() is not None:
            return pred()
        time.sleep(0.01)
    return False


def progress_step(rundir: Path):
    try:
        return json.loads((rundir / "progress.json").read_text())["step"]
    except (OSError, ValueError, KeyError):
        return None


def rss(pid: int) -> int:
    """A process's resident memory, bytes."""
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no VmRSS for {pid}")


def steps_done(rundir: Path, every: int) -> int:
    """Steps a running run has done, from the frames of its dump (one every ``every`` steps,
    the first at step 0); -1 before the dump exists: work counted, not time."""
    try:
        return every * ((rundir / "trajectory.dump").read_text().count("ITEM: TIMESTEP") - 1)
    except OSError:
        return -1


def frames(dump: Path) -> list[int]:
    text = dump_text(dump)
    return [int(m) for m in re.findall(r"ITEM: TIMESTEP\n(\d+)\n", text)]


def leftovers(d: Path) -> list[str]:
    return sorted(str(p.relative_to(d)) for p in d.rglob("*") if p.name.endswith(".tmp")
                  or ".tmp" in p.name)


def fill(path: Path) -> None:
    """Fill the file system holding ``path`` to the last byte."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT)
    try:
        for size in (1 << 16, 1 << 12, 1):
            try:
                while True:
                    os.write(fd, b"\0" * size)
            except OSError:
                pass
    finally:
        os.close(fd)


@pytest.fixture
def tmpfs(tmp_path):
    """A small real file system (tmpfs, root only): ``make(size, ro=False)`` mounts one."""
    mounts = []

    def make(size="2m", ro=False):
        d = tmp_path / f"mnt{len(mounts)}"
        d.mkdir()
        opts = f"size={size}" + (",ro" if ro else "")
        subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(d)], check=True)
        mounts.append(d)
        return d
    yield make
    for d in mounts:
        subprocess.run(["umount", "-l", str(d)], check=False)


TOML = """name = "blobs"
dt = 0.01
steps = {steps}

[[group]]
name = "a"
kind = "part"
lattice = {{ shape = [3, 3, 3], spacing = 1.0, origin = [0.0, 0.0, 0.0] }}
radius = 0.5

[[group]]
name = "b"
kind = "part"
lattice = {{ shape = [3, 3, 3], spacing = 1.0, origin = [3.0, 0.0, 0.0] }}
radius = 0.5

[[operator]]
on = "a"
op = "dampen"
c = 5.0

[[operator]]
on = "b"
op = "force"
accel = [40.0, 0.0, 0.0]

[[operator]]
on = "b"
op = "bind"
from = "a"
c = {c}

[[operator]]
on = "b"
op = "dampen"
c = 1.0
"""


# ---------------------------------------------------------------------------- one writer
@pytest.mark.lammps
def test_second_run_render_and_resume_refused_while_a_run_holds_the_directory(tmp_path):
    out = tmp_path / "X"
    a = subprocess.Popen([RS, "run", "plane-rack", "--steps", "5000000", "--restart-every", "0",
                          "--out", str(out), *QUIET], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: (out / "scene.json").exists(), proc=a), a.stderr.read()
        b = rs("run", "plane-rack", "--steps", "40", "--set", "plane_bind=50", "--out", out,
               *QUIET)
        assert b.returncode == 2, b.stderr
        assert f"pid {a.pid}" in b.stderr and "in use" in b.stderr
        r = rs("render", out)
        assert r.returncode == 2 and f"pid {a.pid}" in r.stderr, r.stderr
        c = rs("run", "--resume", out, *QUIET)
        assert c.returncode == 2 and f"pid {a.pid}" in c.stderr, c.stderr
        # the first run's files are untouched by the refused commands
        assert json.loads((out / "scene.json").read_text())["params"].get("plane_bind") != 50
    finally:
        a.send_signal(signal.SIGKILL)
        a.wait()
    # killed: the directory holds an unfinished run; a plain run is refused, naming --resume,
    # and the dead holder is reported as stale
    d = rs("run", "plane-rack", "--steps", "40", "--out", out, *QUIET)
    assert d.returncode == 2, d.stderr
    assert "did not finish" in d.stderr and "--resume" in d.stderr and "--overwrite" in d.stderr
    assert f"pid {a.pid}" in d.stderr        # the stale holder, named
    # --overwrite starts clean: nothing of the killed run is left
    e = rs("run", "plane-rack", "--steps", "40", "--set", "plane_bind=50", "--restart-every",
           "0", "--dump-every", "10", "--out", out, "--overwrite", *QUIET)
    assert e.returncode == 0, e.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["steps"] == 40 and s["params"]["plane_bind"] == 50
    assert frames(trajectory(out)) == [0, 10, 20, 30, 40]
    assert not (out / "restart").exists() and not (out / "progress.json").exists()
    assert not list(tmp_path.glob(".X.old-*"))


@pytest.mark.lammps
def test_overwrite_removes_old_checkpoints_so_resume_cannot_pick_them_up(tmp_path):
    out = tmp_path / "X"
    assert rs("run", "plane-rack", "--steps", "300", "--restart-every", "100", "--out", out,
              *QUIET).returncode == 0
    assert (out / "progress.json").exists() and (out / "restart").is_dir()
    r = rs("run", "plane-rack", "--steps", "50", "--restart-every", "0", "--set",
           "plane_bind=50", "--out", out, "--overwrite", *QUIET)
    assert r.returncode == 0, r.stderr
    assert not (out / "progress.json").exists() and not (out / "restart").exists()
    r = rs("run", "--resume", out, *QUIET)
    assert r.returncode == 2 and "nothing to resume" in r.stderr


def test_empty_out_refused_and_a_users_file_beside_a_run_kept(tmp_path):
    r = rs("run", "plane-bound", "--engine", "reference", "--steps", "5", "--out", "", *QUIET,
           cwd=tmp_path)
    assert r.returncode == 2 and "--out" in r.stderr and "is empty" in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    r = rs("run", "plane-bound", "--engine", "reference", "--steps", "5", "--out", mine,
           "--overwrite", *QUIET)
    assert r.returncode == 0, r.stderr
    assert "notes.txt" in r.stderr and "left as they are" in r.stderr
    assert (mine / "notes.txt").read_text() == "keep me"
    assert (mine / "summary.json").is_file()


# ---------------------------------------------------------------------------- --resume checks
def _kill_after_checkpoint(cmd, out: Path, at: int = 100):
    p = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    wait_for(lambda: (progress_step(out) or 0) >= at, proc=p)
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    return progress_step(out)



PARAMS_TOML = TOML.replace("steps = {steps}", "duration = {duration}\n\n[params]\nc = 0.05") \
                  .replace("c = {c}", 'c = "$c"')


@pytest.mark.lammps
@pytest.mark.parametrize("args", [["--set", "c=0.07"], ["--dt", "0.005"]])
def test_resume_of_a_toml_run_started_with_set_or_dt(tmp_path, args):
    """A scene file's own parameter set with --set, or a duration-given scene run at another
    dt, resumes: the rebuilt scene is the one the run started with (the file read with the
    recorded parameters, its phases' steps from the duration at the run's dt)."""
    scene = tmp_path / "blobs.toml"
    # long enough that the kill lands mid-run however loaded the machine (3000 steps took
    # ~1 s, which a busy test process could let finish between the checkpoint and the kill)
    scene.write_text(PARAMS_TOML.format(duration=100.0))
    out = tmp_path / "run"
    step = _kill_after_checkpoint([RS, "run", str(scene), *args, "--restart-every", "100",
                                   "--dump-every", "50", "--out", str(out), *QUIET], out)
    total = 20000 if "--dt" in args else 10000
    assert step is not None and step < total and not (out / "summary.json").exists()
    r = rs("run", "--resume", out, *QUIET)
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["steps"] == total and s["resumed_from_step"] == step

@pytest.mark.lammps
def test_resume_refuses_an_edited_scene_file_and_options_it_cannot_honour(tmp_path):
    scene = tmp_path / "blobs.toml"
    scene.write_text(TOML.format(steps=4000, c=0.05))
    out = tmp_path / "run"
    step = _kill_after_checkpoint([RS, "run", str(scene), "--restart-every", "100",
                                   "--dump-every", "1", "--out", str(out), *QUIET], out)
    assert step is not None and step < 4000 and not (out / "summary.json").exists()
    scene.write_text(TOML.format(steps=4000, c=0.06))          # the bind's c edited
    r = rs("run", "--resume", out, *QUIET)
    assert r.returncode == 2, r.stderr
    assert "operators on 'b'" in r.stderr and "changed" in r.stderr
    r = rs("run", "--resume", out, "--steps", "10", "--dt", "0.02", *QUIET)
    assert r.returncode == 2 and "--steps" in r.stderr and "--dt" in r.stderr
    assert progress_step(out) == step          # nothing was touched by the refusals
    scene.write_text(TOML.format(steps=4000, c=0.05))          # as it was: resumes
    r = rs("run", "--resume", out, *QUIET)
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["steps"] == 4000 and s["resumed_from_step"] == step


# ---------------------------------------------------------------------------- divergence
@pytest.mark.lammps
def test_divergence_inside_lammps_is_a_divergence(tmp_path):
    """Fast mode has no Python callback: the plane's bonds fly apart and LAMMPS itself stops
    ('Bond atoms missing' / 'Lost atoms') before the watchdog's check."""
    out = tmp_path / "fast"
    r = rs("run", "plane-bound", "--mode", "fast", "--dt", "0.5", "--steps", "300",
           "--allow-unstable", "--dump-every", "1", "--out", out, *QUIET)
    assert r.returncode == 3, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "diverged"
    e = s["error"]
    assert e["group"] == "plane" and 0 <= e["particle"] < s["n_particles"]
    assert 0 < e["step"] < 300 and f"step {e['step']}" in r.stderr
    # named as peaks, VTK and dumps name particles: by LAMMPS atom id (plane-bound: the plane
    # is the only group, so the in-group index is the global one and the id is one more)
    assert e["atom_id"] == e["particle"] + 1
    assert f"'plane' particle {e['particle']} (atom id {e['particle'] + 1})" in r.stderr
    assert frames(out / "trajectory.dump")[-1] <= e["step"]


@pytest.mark.lammps
def test_callback_failure_stops_lammps_at_its_step(tmp_path):
    """dt = 0.5 makes plane particles coincide inside the Python callback at step 7, which is
    not a watchdog check (every 10 steps): the run stops there, with no frame after it (the
    chunk used to run on to step 10 with the callback's forces zero, writing frame 9). The
    Python callback's behaviour: selected with RACKSTRESS_KERNELS (the plugin's run stops at
    LAMMPS' own "Lost atoms" instead, below)."""
    import os

    out = tmp_path / "pr"
    r = rs("run", "plane-rack", "--dt", "0.5", "--steps", "300", "--allow-unstable",
           "--dump-every", "3", "--out", out, *QUIET,
           env={**os.environ, "RACKSTRESS_KERNELS": "numba"})
    assert r.returncode == 3, r.stderr
    s = json.loads((out / "summary.json").read_text())
    step = s["error"]["step"]
    assert s["status"] == "diverged" and step % 10 != 0
    assert s["steps"] == step
    assert frames(out / "trajectory.dump") == list(range(0, step + 1, 3))
    # the compiled plugin (the default): LAMMPS stops inside the step the atoms flew off in,
    # a divergence (exit 3) naming that step; no frame of it is written
    out = tmp_path / "plugin"
    r = rs("run", "plane-rack", "--dt", "0.5", "--steps", "300", "--allow-unstable",
           "--dump-every", "3", "--out", out, *QUIET)
    assert r.returncode == 3, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "diverged" and "Lost atoms" in s["error"]["message"]
    assert frames(out / "trajectory.dump") == list(range(0, s["error"]["step"], 3))


@pytest.mark.lammps
def test_batch_records_a_lammps_divergence_as_diverged(tmp_path):
    sweep = tmp_path / "s.toml"
    sweep.write_text('scene = "plane-bound"\nengine = "lammps"\nmode = "fast"\nsteps = 60\n'
                     '[[job]]\nname = "calm"\n'
                     '[[job]]\nname = "wild"\ndt = 0.5\nallow_unstable = true\n')
    r = rs("batch", sweep, "--out", tmp_path / "b")
    assert r.returncode == 0, r.stderr
    index = json.loads((tmp_path / "b" / "batch.json").read_text())
    status = {j["name"]: j["status"] for j in index["jobs"]}
    assert status == {"calm": "ok", "wild": "diverged"}
    r = rs("batch", "--report", tmp_path / "b", "--figure", "groups.nope.x")
    assert r.returncode == 2 and "groups.nope.x" in r.stderr and "groups.plane" in r.stderr


# ---------------------------------------------------------------------------- disks
@pytest.mark.lammps
def test_full_disk_while_checkpointing_keeps_the_last_checkpoint(tmpfs):
    disk = tmpfs("4m")
    out = disk / "run"
    p = subprocess.Popen([RS, "run", "plane-rack", "--steps", "100000", "--restart-every", "50",
                          "--dump-every", "100000", "--out", str(out), *QUIET],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert wait_for(lambda: (progress_step(out) or 0) >= 100, proc=p)
    filler = disk / "filler"
    fill(filler)
    try:
        err = p.communicate(timeout=HANG_S)[1]
    except subprocess.TimeoutExpired:
        p.kill()
        raise
    assert p.returncode == 5, err
    assert "No space left" in err and "Traceback" not in err
    assert leftovers(out) == []
    step = progress_step(out)
    meta = json.loads((out / "progress.json").read_text())
    with np.load(out / meta["state"]) as z:
        assert z["x"].shape == (406, 3)
    assert (out / meta["restart"]).stat().st_size > 0
    filler.unlink()
    assert step is not None and step >= 100


@pytest.mark.lammps
def test_full_disk_on_the_reference_dump_keeps_whole_frames(tmpfs):
    disk = tmpfs("1m")
    out = disk / "run"
    r = rs("run", "plane-rack", "--engine", "reference", "--steps", "3000", "--dump-every", "1",
           "--out", out, *QUIET)
    assert r.returncode == 5, r.stderr
    assert "No space left" in r.stderr and "Traceback" not in r.stderr
    assert str(out / "trajectory.dump") in r.stderr
    text = (out / "trajectory.dump").read_text()
    n = len(frames(out / "trajectory.dump"))
    assert n > 0 and text.count("\n") == n * (9 + 406)      # whole frames only
    assert leftovers(out) == []


def test_read_only_out_is_a_message(tmpfs):
    disk = tmpfs("1m", ro=True)
    r = rs("run", "plane-bound", "--engine", "reference", "--steps", "5", "--out",
           disk / "run", *QUIET)
    assert r.returncode == 5, r.stderr
    assert "Read-only file system" in r.stderr and "Traceback" not in r.stderr


# ---------------------------------------------------------------------------- MPI
@pytest.mark.lammps
@pytest.mark.mpi
def test_a_scene_valid_in_serial_runs_under_mpi(tmp_path):
    """A weak bind stretched ~30 units (far past the initial ghost cutoff's margin): the cutoff
    grows with the scene, and both runs end where the serial one does."""
    scene = tmp_path / "stretch.toml"
    scene.write_text(TOML.format(steps=600, c=0.05))
    r1 = rs("run", scene, "--out", tmp_path / "s1", *QUIET)
    r2 = mpi_rs("run", scene, "--out", tmp_path / "s2", *QUIET)
    assert r1.returncode == 0 and r2.returncode == 0, r2.stderr
    a = json.loads((tmp_path / "s1" / "summary.json").read_text())["groups"]["b"]
    b = json.loads((tmp_path / "s2" / "summary.json").read_text())["groups"]["b"]
    assert a["com_end"][0] - a["com_start"][0] > 20          # really stretched
    assert np.allclose(a["com_end"], b["com_end"], rtol=0, atol=1e-8)


@pytest.mark.lammps
@pytest.mark.mpi
def test_full_disk_under_mpi_ends_all_ranks(tmpfs):
    disk = tmpfs("4m")
    out = disk / "run"
    p = subprocess.Popen([MPIEXEC, "-n", "2", RS, "run", "plane-rack", "--steps", "100000",
                          "--restart-every", "50", "--dump-every", "100000", "--out", str(out),
                          *QUIET], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert wait_for(lambda: (progress_step(out) or 0) >= 100, proc=p)
    fill(disk / "filler")
    try:
        err = p.communicate(timeout=HANG_S)[1]       # no hang: every rank ends
    except subprocess.TimeoutExpired:
        p.kill()
        raise AssertionError("mpiexec -n 2 hung after the disk filled")
    assert p.returncode == 5, err
    assert "No space left" in err and "Traceback" not in err
    assert leftovers(out) == []


@pytest.mark.lammps
@pytest.mark.mpi
def test_divergence_under_mpi_is_a_divergence(tmp_path):
    out = tmp_path / "pr"
    r = mpi_rs("run", "plane-rack", "--dt", "0.5", "--steps", "300", "--allow-unstable",
               "--out", out, *QUIET)
    assert r.returncode == 3, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "diverged" and s["ranks"] == 2 and s["error"]["step"] < 300


# ---------------------------------------------------------------------------- guards and edges
def test_final_step_is_always_dumped(tmp_path):
    out = tmp_path / "r"
    r = rs("run", "plane-rack", "--engine", "reference", "--steps", "25", "--dump-every",
           "1000", "--out", out, *QUIET)
    assert r.returncode == 0, r.stderr
    assert frames(trajectory(out)) == [0, 25]


@pytest.mark.lammps
def test_final_step_is_always_dumped_on_lammps(tmp_path):
    out = tmp_path / "r"
    r = rs("run", "plane-rack", "--steps", "25", "--dump-every", "10", "--out", out, *QUIET)
    assert r.returncode == 0, r.stderr
    assert frames(trajectory(out)) == [0, 10, 20, 25]


PHASES = """name = "phases"
dt = 0.01

[[group]]
name = "a"
kind = "part"
positions = [[0, 0, 0], [1.5, 0, 0], [0, 1.5, 0], [0, 0, 1.5]]
radius = 0.5

[[operator]]
on = "a"
op = "bind"
from = "a"
c = 1.0

[[operator]]
on = "a"
op = "dampen"
c = 1.0
extra = 1.0
when = { k = [1] }

[[phase]]
name = "one"
steps = 600
vars = { k = 1 }

[[phase]]
name = "two"
steps = 600
vars = { k = 2 }
"""


def memory_growth_over_phases(tmp_path, engine: list, first: int, then: int):
    """Run PHASES with ``--steps 1000000000000`` (``engine``: the engine's arguments) and
    measure its resident memory once ``first`` steps are done and again once ``then`` are,
    over work, not time; returns (the growth in bytes, the run directory)."""
    scene = tmp_path / "phases.toml"
    scene.write_text(PHASES)
    out = tmp_path / "r"
    err = tmp_path / "stderr"
    p = subprocess.Popen([RS, "run", scene, *engine, "--steps", "1000000000000",
                          "--restart-every", "0", "--dump-every", "600", "--out", str(out),
                          *QUIET], stdout=subprocess.DEVNULL, stderr=err.open("w"))
    try:
        assert wait_for(lambda: steps_done(out, 600) >= first, proc=p), err.read_text()
        before = rss(p.pid)
        assert wait_for(lambda: steps_done(out, 600) >= then, proc=p), err.read_text()
        assert p.poll() is None, err.read_text()
        return rss(p.pid) - before, out
    finally:
        p.kill()
        p.wait()


def test_any_number_of_steps_costs_no_memory_up_front(tmp_path):
    """``--steps 1000000000000`` on the reference engine: the memory of the run stays flat as
    it works (was: one Phase object per 1,200 steps kept, ~35 MB a second of running). A
    schedule of two 600-step phases, its damping switched by the phase, on four particles:
    measured over work, not time — the process's memory once 12,000 steps are done (20 phase
    switches: every kernel loaded), then once 108,000 more are (180 more switches: a phase
    that left 110 kB behind would pass 20 MB)."""
    growth, _ = memory_growth_over_phases(tmp_path, ["--engine", "reference"], 12000, 120000)
    assert growth < 20e6


def test_a_lattice_too_large_for_the_machine_is_refused(tmp_path):
    scene = tmp_path / "huge.toml"
    scene.write_text('name = "huge"\nsteps = 1\n[[group]]\nname = "a"\nkind = "part"\n'
                     'lattice = { shape = [1000, 1000, 1000] }\nradius = 0.5\n')
    with child_cpu() as cpu:
        r = rs("run", scene, "--engine", "reference", "--out", tmp_path / "r", *QUIET)
    assert r.returncode == 2 and "GiB" in r.stderr and "lattice" in r.stderr, r.stderr
    assert cpu.s < 30          # refused before building: seconds of CPU, whatever the load
    assert not (tmp_path / "r").exists()


def _positions_scene(tmp_path, positions, radius="0.5", extra=""):
    p = tmp_path / "s.toml"
    p.write_text(f'name = "s"\nsteps = 1\n[[group]]\nname = "a"\nkind = "part"\n'
                 f"positions = {positions}\nradius = {radius}\n{extra}")
    return p


def test_input_edges_give_clear_errors(tmp_path):
    # coincidence is judged in absolute terms: far-away particles do not merge near ones
    far = _positions_scene(tmp_path, "[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2e9, 0.0, 0.0]]")
    r = rs("deck", far, "--out", tmp_path / "d1")
    assert r.returncode == 0, r.stderr
    same = _positions_scene(tmp_path, "[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]")
    r = rs("deck", same, "--out", tmp_path / "d2")
    assert r.returncode == 2 and "coincident" in r.stderr
    huge = _positions_scene(tmp_path, "[[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]", radius="1e308")
    r = rs("run", huge, "--engine", "reference", "--out", tmp_path / "r1", *QUIET)
    assert r.returncode == 2 and "radius" in r.stderr and "Traceback" not in r.stderr
    sweep = tmp_path / "bad.toml"
    sweep.write_bytes(b'scene = "plane-bound"\n# caf\xe9\n')
    r = rs("batch", sweep, "--out", tmp_path / "b")
    assert r.returncode == 2 and "UTF-8" in r.stderr and str(sweep) in r.stderr


def test_render_of_a_run_with_non_finite_frames_is_refused_clearly(tmp_path):
    out = tmp_path / "r"
    assert rs("run", "plane-rack", "--engine", "reference", "--steps", "20", "--dump-every",
              "10", "--dump-text", "--out", out, *QUIET).returncode == 0
    dump = out / "trajectory.dump"             # kept as text (--dump-text), to be edited
    text = dump.read_text()
    last = text.rindex("ITEM: ATOMS")
    head, body = text[:last], text[last:].split("\n")
    body[5] = " ".join(body[5].split()[:3] + ["nan", "nan", "nan"])   # one particle of frame 20
    dump.write_text(head + "\n".join(body))
    r = rs("render", out)
    assert r.returncode == 2, r.stderr
    assert "iteration 20" in r.stderr and "non-finite" in r.stderr and "Traceback" not in r.stderr
    assert not (out / "figures").exists()


def test_a_render_killed_midway_leaves_nothing_the_next_render_keeps(tmp_path):
    out = tmp_path / "r"
    assert rs("run", "plane-rack", "--engine", "reference", "--steps", "20", "--out", out,
              *QUIET).returncode == 0
    p = subprocess.Popen([RS, "render", str(out), "--no-progress"], stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)

    def children():
        try:
            return Path(f"/proc/{p.pid}/task/{p.pid}/children").read_text().split()
        except OSError:
            return []

    # killed while writing, with its plot process (a fork) drawing beside it
    seen = wait_for(lambda: any(out.glob(".*.tmp*")) and children(), proc=p)
    kids = children()
    p.send_signal(signal.SIGKILL)
    p.wait()
    assert seen and kids and p.returncode == -signal.SIGKILL
    # the lock ended with the process that took it: the plot process holds no copy of it
    import fcntl

    fd = os.open(out / ".lock", os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)     # raises while a copy holds it
    finally:
        os.close(fd)
    # the plot process dies with it and holds no copy of the lock
    def alive(k):
        try:        # a zombie ('Z') waits only for its reaper
            return Path(f"/proc/{k}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:
            return False

    assert wait_for(lambda: not any(alive(k) for k in kids))
    r = rs("render", out, "--no-progress")
    assert r.returncode == 0, r.stderr
    assert [x.name for x in out.glob(".*tmp*")] == []
    assert not (out / ".lock").exists()


@pytest.mark.lammps
@pytest.mark.mpi
def test_full_disk_on_the_dump_under_mpi_ends_all_ranks(tmpfs):
    """LAMMPS writes the dump on rank 0 alone, so only rank 0 sees the full disk while rank 1
    waits in a collective: all ranks end (MPI_Abort with the storage status), no hang."""
    disk = tmpfs("1m")
    r = mpi_rs("run", "plane-rack", "--steps", "3000", "--dump-every", "1", "--restart-every",
               "0", "--out", disk / "run", *QUIET)       # a hang: TimeoutExpired (HANG_S)
    assert r.returncode == 5, r.stderr
    assert "No space left" in r.stderr and "Traceback" not in r.stderr
    assert leftovers(disk / "run") == []


def test_commands_on_a_missing_run_directory_are_bad_input(tmp_path):
    """--resume and render of a directory that does not exist: exit 2 naming it (not a disk
    error, exit 5, from trying to lock it), and nothing is created."""
    missing = tmp_path / "nope"
    for args in (["run", "--resume", missing], ["render", missing]):
        r = rs(*args)
        assert r.returncode == 2, r.stderr
        assert f"{missing} is not a run directory (it does not exist)" in r.stderr
    assert not missing.exists()
