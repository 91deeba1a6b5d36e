"""``rackstress batch``: sweeps over real MPI ranks (the venv's mpiexec), a job that
diverges, a batch killed mid-way and restarted, ranks per job, the report, bad sweep files."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rackstress.runs.sweep import SweepError, load_sweep
from conftest import HANG_S

BIN = Path(sys.executable).parent
RACKSTRESS, MPIEXEC = str(BIN / "rackstress"), str(BIN / "mpiexec")

DIVERGE = """
[[job]]
name = "diverge"
plane_bind = 1e5
allow_unstable = true
"""


def six_jobs(tmp_path: Path, steps: int) -> Path:
    """5 ok jobs (a grid of 5 explicit points) + 1 diverging job = 6 jobs."""
    jobs = "".join(f'\n[[job]]\nname = "bind{pb:g}-rack{rb:g}"\nplane_bind = {pb}\nrack_bind = {rb}\n'
                   for pb, rb in [(50.0, 0.5), (100.0, 0.5), (200.0, 0.5), (100.0, 2.0),
                                  (200.0, 2.0)])
    p = tmp_path / "six.toml"
    p.write_text(f'scene = "plane-rack"\nengine = "lammps"\nmode = "exact"\nsteps = {steps}\n'
                 + jobs + DIVERGE)
    return p


def batch(args, mpi: int | None = None, **kw):
    """``rackstress batch ARGS`` without the jobs' pictures (tests/test_batch_report.py
    renders them): these tests time and kill the runs themselves."""
    cmd = ([MPIEXEC, "-n", str(mpi)] if mpi else []) + [RACKSTRESS, "batch", *args]
    if "--report" not in args:
        cmd.append("--no-render")
    return subprocess.run(cmd, capture_output=True, text=True, timeout=HANG_S, **kw)


def index(d: Path) -> dict:
    return json.loads((d / "batch.json").read_text())


def events(d: Path):
    lines = (d / "events.log").read_text().splitlines()
    starts, ends = {}, {}
    for ln in lines:
        parts = ln.split()
        kind, name = parts[1], parts[2]
        (starts if kind == "start" else ends).setdefault(name, []).append(ln)
    return starts, ends


def check_complete(d: Path, names):
    ix = index(d)
    assert ix["complete"] is True
    assert ix["counts"] == {"ok": 5, "diverged": 1}
    by = {j["name"]: j for j in ix["jobs"]}
    assert set(by) == set(names)
    for name, j in by.items():
        assert j["status"] == ("diverged" if name == "diverge" else "ok")
        s = json.loads((d / name / "summary.json").read_text())
        assert s["status"] == j["status"]
        assert isinstance(j["wall_s"], float) and j["wall_s"] > 0
        if j["status"] == "ok":
            assert j["figures"]["groups.plane.max_deformation"] == \
                s["groups"]["plane"]["max_deformation"]
            assert j["error"] is None
        else:
            assert "diverged" in j["error"] and s["error"]["step"] > 0
    assert not list(d.glob(".tmp-*"))
    return by


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The six-job sweep run serially (no mpiexec): every job's figures. 5000 steps a job
    (~1 s) so that the kill test can land between jobs."""
    tmp = tmp_path_factory.mktemp("serial")
    sw = six_jobs(tmp, 5000)
    r = batch([str(sw), "--out", str(tmp / "b")])
    assert r.returncode == 0, r.stderr
    by = check_complete(tmp / "b", [j.name for j in load_sweep(sw).jobs])
    assert index(tmp / "b")["passes"][-1]["ranks"] == 1
    return {n: j["figures"] for n, j in by.items()}, sw


@pytest.mark.slow
@pytest.mark.lammps
@pytest.mark.mpi
def test_sweep_under_mpiexec_two_groups(reference, tmp_path):
    figs, sw = reference
    r = batch([str(sw), "--out", str(tmp_path / "b")], mpi=2)
    assert r.returncode == 0, r.stderr
    by = check_complete(tmp_path / "b", list(figs))
    # each group ran jobs, handed out dynamically; one LAMMPS rank per job
    assert {j["group"] for j in by.values()} == {0, 1}
    assert all(j["ranks"] == 1 and j["attempts"] == 1 for j in by.values())
    # the same numbers as one after another (each job is a serial LAMMPS run)
    assert {n: j["figures"] for n, j in by.items()} == figs
    starts, ends = events(tmp_path / "b")
    assert all(len(starts[n]) == 1 and len(ends[n]) == 1 for n in figs)
    p = index(tmp_path / "b")["passes"][-1]
    assert p["ranks"] == 2 and p["groups"] == 2 and p["jobs_run"] == 6


@pytest.mark.slow
@pytest.mark.lammps
@pytest.mark.mpi
def test_killed_batch_restarts_and_runs_each_job_once(reference, tmp_path):
    figs, sw = reference
    d = tmp_path / "b"
    p = subprocess.Popen([MPIEXEC, "-n", "2", RACKSTRESS, "batch", str(sw), "--out", str(d),
                          "--no-render"],
                         start_new_session=True, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + HANG_S
    done = 0
    while time.monotonic() < deadline and p.poll() is None:
        try:
            done = sum(index(d)["counts"].get(s, 0) for s in ("ok", "diverged", "failed"))
        except (FileNotFoundError, json.JSONDecodeError):
            pass
        if done >= 2:
            break
        time.sleep(0.01)
    os.killpg(p.pid, signal.SIGKILL)       # the whole mpiexec process group
    p.wait()
    # a job's directory is written as .tmp-<name>-<pid> and renamed when whole: a kill can
    # land between its summary and the rename (the next pass removes such a directory)
    finished = {q.name: q.joinpath("summary.json").stat().st_mtime_ns
                for q in d.iterdir() if q.is_dir() and not q.name.startswith(".tmp-")
                and (q / "summary.json").exists()}
    assert 2 <= len(finished) < 6, f"kill did not land mid-batch ({len(finished)} finished)"
    assert index(d)["complete"] is False
    # handed out (index says running) / started (events.log) but cut off by the kill
    running = [j["name"] for j in index(d)["jobs"] if j["status"] == "running"]
    s0, e0 = events(d)
    cut = [n for n in s0 if n not in e0]
    assert set(cut) <= set(running)

    r = batch([str(sw), "--out", str(d)], mpi=2)
    assert r.returncode == 0, r.stderr
    by = check_complete(d, list(figs))
    assert {n: j["figures"] for n, j in by.items()} == figs
    starts, ends = events(d)
    for n in figs:
        assert len(ends[n]) == 1, n                    # every job finished exactly once
    for n, mtime in finished.items():                  # finished before the kill: not rerun
        assert len(starts[n]) == 1 and by[n]["attempts"] == 1, n
        assert (d / n / "summary.json").stat().st_mtime_ns == mtime
    # only the jobs cut off by the kill started twice
    assert sum(len(v) for v in starts.values()) == 6 + len(cut)
    assert all(len(starts[n]) == (2 if n in cut else 1) for n in figs)
    # handed out again only if it did not finish: a kill can land after a job's directory is
    # whole and before the index says so (it is in both ``running`` and ``finished``, and the
    # assertion above already requires one attempt of it)
    again = set(running) - set(finished)
    assert all(by[n]["attempts"] == (2 if n in again else 1) for n in figs), (
        {n: by[n]["attempts"] for n in figs}, running, sorted(finished))
    assert [q["jobs_run"] for q in index(d)["passes"]][-1] == 6 - len(finished)
    # a third pass finds nothing to do
    r = batch([str(sw), "--out", str(d)])
    assert r.returncode == 0 and index(d)["passes"][-1]["jobs_run"] == 0


@pytest.mark.slow
def test_two_ranks_per_job(reference, tmp_path):
    figs, _ = reference
    sw = tmp_path / "two.toml"
    sw.write_text('scene = "plane-rack"\nsteps = 5000\n[[job]]\nname = "bind50-rack0.5"\n'
                  'plane_bind = 50.0\nrack_bind = 0.5\n' + DIVERGE)
    r = batch([str(sw), "--out", str(tmp_path / "b"), "--ranks-per-job", "2"], mpi=2)
    assert r.returncode == 0, r.stderr
    ix = index(tmp_path / "b")
    by = {j["name"]: j for j in ix["jobs"]}
    assert by["bind50-rack0.5"]["status"] == "ok" and by["diverge"]["status"] == "diverged"
    assert all(j["ranks"] == 2 for j in by.values())
    s = json.loads((tmp_path / "b" / "bind50-rack0.5" / "summary.json").read_text())
    assert s["ranks"] == 2
    # one LAMMPS over two ranks: the serial numbers to round-off
    ref = figs["bind50-rack0.5"]["groups.plane.max_deformation"]
    assert s["groups"]["plane"]["max_deformation"] == pytest.approx(ref, rel=1e-9)


def test_report(reference, tmp_path):
    _, sw = reference
    d = sw.parent / "b"
    r = subprocess.run([RACKSTRESS, "batch", "--report", str(d), "--figure",
                        "groups.plane.max_deformation", "--against", "plane_bind"],
                       capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].split()[:4] == ["name", "plane_bind", "rack_bind", "status"]
    rows = [ln for ln in lines[1:7]]
    assert len(rows) == 6 and sum(" ok " in ln for ln in rows) == 5
    assert any(ln.startswith("diverge") and "diverged" in ln for ln in rows)
    png = d / "report-groups.plane.max_deformation-vs-plane_bind.png"
    assert png.exists() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = subprocess.run([RACKSTRESS, "batch", "--report", str(d), "--against", "nope"],
                       capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 2 and "not a swept parameter" in r.stderr


@pytest.mark.parametrize("text, where", [
    ('scene = "plane-rack"\nstep = 5\n[grid]\ndt = [0.01]\n', "unknown key(s) 'step'"),
    ('scene = "plane-rack"\n[grid]\ndt = [0.01, -1]\n', "[grid] dt: dt must be a positive"),
    ('scene = "plane-rack"\n[grid]\nplane_bind = []\n', "[grid] plane_bind: must be a non-empty"),
    ('scene = "nope"\n[grid]\ndt = [0.01]\n', "scene: unknown scene 'nope'"),
    ('scene = "plane-rack"\n[[job]]\nname = "a b"\n', "[[job]] #1 name"),
    ('scene = "plane-rack"\n[[job]]\nname = "x"\n[[job]]\nname = "x"\n', "used twice"),
    ('scene = "plane-rack"\n', "no jobs"),
    ('scene = "plane-rack"\n[grid\n', "not valid TOML"),
])
def test_bad_sweep_files(tmp_path, text, where):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(SweepError) as ei:
        load_sweep(p)
    assert str(p) in str(ei.value) and where in str(ei.value)


def test_bad_scene_parameter_stops_before_running(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('scene = "plane-rack"\n[grid]\nplane_bnd = [1.0, 2.0]\n')
    r = batch([str(p), "--out", str(tmp_path / "b")])
    assert r.returncode == 2
    assert str(p) in r.stderr and "plane_bnd" in r.stderr and "job 'g000-plane_bnd=1'" in r.stderr
    assert not (tmp_path / "b" / "batch.json").exists()
