"""A run directory only ever loses what rackstress wrote there (runs/rundir.py's manifest):
``--overwrite`` beside the user's scene and STL, a file of the user's named like a run's, a run
directory written before the manifest, ``--resume`` after ``kill -9``, ``fea``'s files, and the
folders of ``render --out``, ``stress --out``, ``deck --out`` and ``rackstress batch``. Real
processes throughout (the installed ``rackstress``)."""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
RS = str(BIN / "rackstress")
REPO = Path(__file__).resolve().parents[1]
QUIET = ["--no-render", "--no-progress"]
#: a hang guard, not a speed limit: minutes on a 2-core machine that others load fully
HANG_S = 900


def rs(*args, **kw):
    return subprocess.run([RS, *map(str, args)], capture_output=True, text=True,
                          timeout=HANG_S, **kw)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def manifest(d: Path) -> set:
    return set(json.loads((d / ".rackstress-files.json").read_text())["files"])


def _bracket(d: Path) -> Path:
    """The README's own part, as a user puts it: scene and STL side by side in one folder."""
    d.mkdir()
    (d / "my-part.stl").write_bytes((REPO / "examples/bracket/bracket.stl").read_bytes())
    text = (REPO / "examples/bracket/static.toml").read_text().replace("bracket.stl",
                                                                      "my-part.stl")
    (d / "my-part.toml").write_text(text)
    return d / "my-part.toml"


@pytest.mark.lammps
@pytest.mark.slow
def test_overwrite_keeps_the_scene_and_stl_the_run_sits_beside(tmp_path):
    """The user's scene and STL in the run directory, a note added after the run, ``fea``'s
    files: ``--overwrite`` removes the run's (fea.json too) and nothing else."""
    d = tmp_path / "part"
    scene = _bracket(d)
    before = {n: digest(d / n) for n in ("my-part.toml", "my-part.stl")}
    r = rs("run", scene, "--set", "spacing=2", "--out", d, *QUIET)
    assert r.returncode == 0, r.stderr
    assert "my-part.stl" in r.stderr and "left as they are" in r.stderr
    assert {"summary.json", "trajectory.dump.gz", "scene.json"} <= manifest(d)
    assert not {"my-part.stl", "my-part.toml"} & manifest(d)
    f = rs("fea", d, "--no-converge", "--size", "8")   # its files are the point, not the FE
    assert f.returncode == 0, f.stderr
    assert {"fea.json", "fea.npz"} <= manifest(d)
    (d / "notes.txt").write_text("mine")
    r = rs("run", scene, "--set", "spacing=2", "--set", "load=50", "--out", d, "--overwrite",
           *QUIET)
    assert r.returncode == 0, r.stderr
    assert {n: digest(d / n) for n in before} == before
    assert (d / "notes.txt").read_text() == "mine"
    assert not (d / "fea.json").exists()                 # the earlier run's FE check went
    assert json.loads((d / "summary.json").read_text())["params"]["load"] == 50


def test_a_users_file_named_like_a_run_file_is_refused_and_an_old_run_dir_keeps_others(
        tmp_path):
    # a report of the user's where the run would write its own: refused, nothing written
    d = tmp_path / "r"
    d.mkdir()
    (d / "report.html").write_text("<p>my report</p>")
    r = rs("run", "plane-bound", "--engine", "reference", "--steps", "5", "--out", d, *QUIET)
    assert r.returncode == 2, r.stderr
    assert "report.html" in r.stderr and "no run wrote" in r.stderr
    assert sorted(p.name for p in d.iterdir()) == ["report.html"]
    assert (d / "report.html").read_text() == "<p>my report</p>"
    # a run directory written before runs kept a manifest: the run's known names are its
    # own, any other name is the user's and stays
    old = tmp_path / "old"
    r = rs("run", "plane-bound", "--engine", "reference", "--steps", "5", "--out", old, *QUIET)
    assert r.returncode == 0, r.stderr
    (old / ".rackstress-files.json").unlink()
    (old / "figures-mine").mkdir()
    (old / "figures-mine" / "sketch.png").write_bytes(b"png")
    (old / "notes.txt").write_text("mine")
    r = rs("run", "plane-bound", "--engine", "reference", "--steps", "7", "--out", old,
           "--overwrite", *QUIET)
    assert r.returncode == 0, r.stderr
    assert json.loads((old / "summary.json").read_text())["steps"] == 7
    assert (old / "notes.txt").read_text() == "mine"
    assert (old / "figures-mine" / "sketch.png").read_bytes() == b"png"


@pytest.mark.lammps
def test_resume_after_kill_and_overwrite_keep_the_users_file(tmp_path):
    d = tmp_path / "k"
    d.mkdir()
    (d / "plan.txt").write_text("mine")
    p = subprocess.Popen([RS, "run", "plane-rack", "--steps", "200000", "--restart-every",
                          "100", "--out", str(d), *QUIET], start_new_session=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + HANG_S
        while not (d / "progress.json").exists() and time.monotonic() < end:
            assert p.poll() is None
            time.sleep(0.05)
    finally:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
    r = rs("run", "plane-rack", "--steps", "300", "--out", d, "--overwrite",
           "--restart-every", "100", *QUIET)
    assert r.returncode == 0, r.stderr
    assert (d / "plan.txt").read_text() == "mine"
    assert json.loads((d / "summary.json").read_text())["steps"] == 300
    assert "plan.txt" not in manifest(d)


@pytest.mark.slow
def test_render_stress_and_deck_out_never_replace_the_users_files(tmp_path):
    run = tmp_path / "run"
    r = rs("run", "plane-bound", "--engine", "reference", "--steps", "20", "--out", run, *QUIET)
    assert r.returncode == 0, r.stderr
    pics = tmp_path / "pics"
    pics.mkdir()
    (pics / "sheet.png").write_bytes(b"my sheet")
    r = rs("render", run, "--out", pics, "--no-progress")
    assert r.returncode == 2 and "sheet.png" in r.stderr and "did not write" in r.stderr, r.stderr
    assert sorted(p.name for p in pics.iterdir()) == ["sheet.png"]
    assert (pics / "sheet.png").read_bytes() == b"my sheet"
    # a folder rackstress wrote before is its own to write again
    fresh = tmp_path / "fresh"
    for _ in range(2):
        r = rs("render", run, "--out", fresh, "--no-progress")
        assert r.returncode == 0, r.stderr
    exp = tmp_path / "exp"
    (exp / "vtk").mkdir(parents=True)
    (exp / "vtk" / "mine.vtu").write_text("mine")
    r = rs("stress", run, "--out", exp, "--no-progress")
    assert r.returncode == 2 and "vtk" in r.stderr, r.stderr
    assert (exp / "vtk" / "mine.vtu").read_text() == "mine"
    assert not (exp / "stress.json").exists()
    deck = tmp_path / "deck"
    deck.mkdir()
    (deck / "in.lammps").write_text("# my own deck\n")
    r = rs("deck", "plane-bound", "--out", deck)
    assert r.returncode == 2 and "in.lammps" in r.stderr, r.stderr
    assert (deck / "in.lammps").read_text() == "# my own deck\n"
    assert not (deck / "particles.data").exists()


def test_batch_never_writes_over_a_folder_named_like_a_job(tmp_path):
    sweep = tmp_path / "s.toml"
    sweep.write_text('scene = "plane-bound"\nengine = "reference"\nsteps = 5\n\n[[job]]\n'
                     'name = "a"\nd = 10\n\n[[job]]\nname = "b"\nd = 12\n')
    out = tmp_path / "B"
    (out / "b").mkdir(parents=True)
    (out / "b" / "data.csv").write_text("mine")
    r = subprocess.run([RS, "batch", sweep, "--out", out, "--no-render"], capture_output=True,
                       text=True, timeout=HANG_S)
    assert r.returncode == 2 and "b" in r.stderr and "did not write" in r.stderr, r.stderr
    assert (out / "b" / "data.csv").read_text() == "mine"
    assert not (out / "a").exists() and not (out / "batch.json").exists()
