"""What ``rackstress run`` leaves behind by default, and the head start it takes (issue 24):
a finished run drops the checkpoints it wrote only to survive a kill (a killed one still
resumes to the uninterrupted trajectory, byte for byte), and the post-processing's imports load
in a thread while LAMMPS runs. Real LAMMPS, real processes, a real SIGKILL."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import dump_text, trajectory

BIN = Path(sys.executable).parent
RACKSTRESS = str(BIN / "rackstress")
#: no --restart-every: the default interval, about ten checkpoints (every 120 steps here)
RUN = ["run", "plane-rack", "--steps", "1200", "--dump-every", "4", "--no-render",
       "--no-progress"]


def _run(args):
    return subprocess.run([RACKSTRESS, *args], capture_output=True, text=True, timeout=300)


def _killed_after(rundir: Path, at: int):
    """test_resume's kill, on this file's run (its default checkpoint interval)."""
    from test_resume import _killed_at

    return _killed_at(rundir, at, RUN)


@pytest.mark.lammps
def test_default_checkpoints_survive_a_kill_and_go_when_the_run_is_done(tmp_path):
    full = tmp_path / "full"
    r = _run([*RUN, "--out", str(full)])
    assert r.returncode == 0, r.stderr
    # finished: nothing left that only a killed run needs
    assert not (full / "restart").exists() and not (full / "progress.json").exists()
    for attempt in range(3):         # the kill must land between step 600 and the end
        cut = tmp_path / f"cut{attempt}"
        step = _killed_after(cut, 600)
        if step is not None and step < 1200:
            break
    else:
        raise AssertionError("could not kill the run between step 600 and its end")
    meta = json.loads((cut / "progress.json").read_text())
    assert meta["keep"] is False and (cut / meta["state"]).stat().st_size > 0
    r = _run(["run", "--resume", str(cut), "--no-render", "--no-progress"])
    assert r.returncode == 0, r.stderr
    assert json.loads((cut / "summary.json").read_text())["resumed_from_step"] == step
    assert trajectory(full).name == trajectory(cut).name == "trajectory.dump.gz"
    assert trajectory(full).read_bytes() == trajectory(cut).read_bytes()
    ta, tb = dump_text(trajectory(full)), dump_text(trajectory(cut))
    assert tb.count("ITEM: TIMESTEP") == 1200 // 4 + 1 and ta == tb
    assert not (cut / "restart").exists() and not (cut / "progress.json").exists()


@pytest.mark.lammps
def test_an_asked_for_checkpoint_interval_is_kept(tmp_path):
    out = tmp_path / "k"
    r = _run(["run", "plane-rack", "--steps", "300", "--restart-every", "100", "--no-render",
              "--no-progress", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    meta = json.loads((out / "progress.json").read_text())
    assert meta["step"] == 300 and meta["keep"] is True
    assert (out / meta["restart"]).stat().st_size > 0      # LAMMPS can go on from it
    # the simulation's wall time split by the driver's loop: three parts, none negative, each
    # within the run's wall time, the chunks of steps and the watchdog within their sum
    summary = json.loads((out / "summary.json").read_text())
    d = summary["driver_s"]
    assert sorted(d) == ["between_s", "checks_s", "steps_s"]
    assert all(0 <= d[k] <= summary["wall_s"] for k in d) and d["steps_s"] > 0
    assert d["steps_s"] + d["checks_s"] <= sum(d.values()) + 1e-12
    assert sum(d.values()) <= summary["wall_s"]


def test_prepare_imports_in_a_thread_and_restores_the_switch_interval():
    """A fresh interpreter: the thread imports the post-processing's heavy modules (none of
    them imported before), and hands the GIL back at the usual interval when done."""
    code = (
        "import sys\n"
        "heavy = ('matplotlib.figure', 'vtkmodules.vtkIOXML', 'vtkmodules.vtkRenderingOpenGL2',"
        " 'MDAnalysis', 'rackstress.render.pictures')\n"
        "before = sys.getswitchinterval()\n"
        "from rackstress.render.prepare import prepare_in_background, wait_prepared\n"
        "assert not any(m in sys.modules for m in heavy), [m for m in heavy if m in sys.modules]\n"
        "t = prepare_in_background()\n"
        "wait_prepared()\n"
        "assert not t.is_alive() and not t.daemon\n"
        "assert all(m in sys.modules for m in heavy), [m for m in heavy if m not in sys.modules]\n"
        "assert sys.getswitchinterval() == before\n"
        "print('ok')\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


@pytest.mark.lammps
def test_sheet_only_paints_the_cells_at_half_size_and_nothing_else(tmp_path):
    """``render(sheet_only=True)`` (what ``rackstress run`` paints): the sheet's geometry is that
    of the full render's (cells of half the 1024 × 768 window, a 28-pixel label column, a
    24-pixel row of titles, the 112-pixel header), and no per-view picture is written."""
    from PIL import Image

    from rackstress.render.pictures import HEADER_H, render

    out = tmp_path / "pr"
    r = _run(["run", "plane-rack", "--steps", "150", "--dump-every", "3", "--no-render",
              "--no-progress", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    rep = render(out, sheet_only=True, plots=False)
    cols = len({k for _, k, _ in rep.frames})
    with Image.open(out / "figures" / "sheet.png") as im:
        assert im.size == (28 + 512 * cols, HEADER_H + 24 + 3 * 384)
    assert sorted(rep.files) == ["render.json", "sheet.png"]
    assert sorted(p.name for p in (out / "figures").iterdir()) == ["render.json", "sheet.png"]
    with pytest.raises(Exception, match="movie"):
        render(out, sheet_only=True, movie=True)


def test_the_head_start_needs_an_idle_core(monkeypatch):
    """``rackstress run`` starts post-processing beside the simulation only where the 1-minute
    load average is below the number of cores, and never under RACKSTRESS_HEAD_START=0."""
    import os

    from rackstress import cli

    cores = os.cpu_count() or 1
    monkeypatch.delenv("RACKSTRESS_HEAD_START", raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (cores - 0.5, 0.0, 0.0))
    assert cli._idle_core()
    monkeypatch.setattr(os, "getloadavg", lambda: (float(cores), 0.0, 0.0))
    assert not cli._idle_core()
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    monkeypatch.setenv("RACKSTRESS_HEAD_START", "0")
    assert not cli._idle_core()
