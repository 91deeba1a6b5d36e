"""What ``rackstress run`` leaves behind by default, and the head start it takes:
a finished run drops the checkpoints it wrote only to survive a kill (a killed one still
resumes to the uninterrupted trajectory, byte for byte), and the post-processing's imports load
in a thread while LAMMPS runs. Real LAMMPS, real processes, a real SIGKILL."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import HANG_S, dump_text, trajectory

BIN = Path(sys.executable).parent
RACKSTRESS = str(BIN / "rackstress")
#: no --restart-every: the default interval, about ten checkpoints (every 120 steps here)
RUN = ["run", "plane-rack", "--steps", "1200", "--dump-every", "4", "--no-render",
       "--no-progress"]


def _run(args):
    return subprocess.run([RACKSTRESS, *args], capture_output=True, text=True, timeout=HANG_S)


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
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=HANG_S)
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
    load average is below the number of cores (not checked under RACKSTRESS_HEAD_START=always)
    and the machine has a core beyond the simulation's ranks, and never under
    RACKSTRESS_HEAD_START=0."""
    import os

    from rackstress import cli

    cores = os.cpu_count() or 1
    monkeypatch.delenv("RACKSTRESS_HEAD_START", raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (cores - 0.5, 0.0, 0.0))
    assert cli._idle_core()
    monkeypatch.setattr(os, "getloadavg", lambda: (float(cores), 0.0, 0.0))
    assert not cli._idle_core()
    # a core beyond the simulation's ranks, whatever the load
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    assert cli._idle_core(cores - 1) and not cli._idle_core(cores)
    monkeypatch.setenv("RACKSTRESS_HEAD_START", "always")
    monkeypatch.setattr(os, "getloadavg", lambda: (float(cores), 0.0, 0.0))
    assert cli._idle_core() and not cli._idle_core(cores)
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    monkeypatch.setenv("RACKSTRESS_HEAD_START", "0")
    assert not cli._idle_core()


# ----------------------------------------------------------------------------- the head start's process
#: magpod-small's first 1200 iterations, a frame every 12: 101 frames, the scene's own count
HEAD = ["run", "magpod-small", "--steps", "1200", "--dump-every", "12", "--no-progress"]


def _derived(rundir: Path) -> dict:
    """What post-processing writes that must not depend on where it ran: every VTK file,
    the compressed trajectory, the pictures and plots, byte for byte; the peaks."""
    files = {str(p.relative_to(rundir)): p.read_bytes()
             for pattern in ("vtk/*", "trajectory.dump.gz", "figures/*.png")
             for p in sorted(rundir.glob(pattern))}
    stress = json.loads((rundir / "stress.json").read_text())
    summary = json.loads((rundir / "summary.json").read_text())
    return {"files": files, "peak": stress["peak"], "groups": stress["groups"],
            "summary_groups": summary["groups"], "warnings": summary.get("warnings")}


def _same(a: dict, b: dict) -> None:
    assert sorted(a["files"]) == sorted(b["files"]) and len(a["files"]) > 100
    assert [k for k in a["files"] if a["files"][k] != b["files"][k]] == []
    for k in ("peak", "groups", "summary_groups", "warnings"):
        assert a[k] == b[k], k


def _children(pid: int) -> list:
    try:
        return [int(x) for x in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _zlib_levels(png: Path) -> set:
    """The FLEVEL field (RFC 1950: 0 fastest .. 3 maximum compression) of the zlib stream in
    a PNG's IDAT chunks, read from the file's bytes."""
    import struct

    data, at, idat = png.read_bytes(), 8, b""
    while at < len(data):
        size, kind = struct.unpack(">I4s", data[at:at + 8])
        if kind == b"IDAT":
            idat += data[at + 8:at + 8 + size]
        at += 12 + size
    return {idat[1] >> 6}


@pytest.mark.lammps
def test_the_plots_are_written_at_the_fastest_zlib_level(tmp_path):
    """The plots' PNG files are compressed as the sheet is (zlib level 1, FLEVEL 0 in the
    stream's header; matplotlib's default, 6, writes FLEVEL 2): the same pixels, at each
    figure's size (figsize × 110 dpi: 7 × 4 and 10 × 4 inches)."""
    from PIL import Image

    from rackstress.render.pictures import render

    out = tmp_path / "pl"
    r = _run(["run", "plane-rack", "--steps", "150", "--dump-every", "3", "--no-render",
              "--no-progress", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    render(out, sheet_only=True, plots=True)
    sizes = {"stress_over_time.png": (770, 440), "com_path.png": (1100, 440)}
    for name, size in sizes.items():
        png = out / "figures" / name
        assert _zlib_levels(png) == {0}, name
        with Image.open(png) as im:
            assert im.size == size, name
    assert _zlib_levels(out / "figures" / "sheet.png") == {0}


@pytest.fixture(scope="module")
def alone(tmp_path_factory):
    """magpod-small's head without the head start (nothing beside the simulation)."""
    import os

    out = tmp_path_factory.mktemp("alone") / "run"
    r = subprocess.run([RACKSTRESS, *HEAD, "--out", str(out)], capture_output=True, text=True,
                       timeout=HANG_S, env=dict(os.environ, RACKSTRESS_HEAD_START="0"))
    assert r.returncode == 0, r.stderr
    return out


@pytest.mark.lammps
def test_a_killed_head_start_loses_nothing(tmp_path, alone):
    """The head start's process SIGKILLed as soon as it is forked (before the simulation's
    first step): the run post-processes itself and leaves what a run without a head start
    leaves, byte for byte, and no temporary file."""
    import os
    import signal
    import time

    out = tmp_path / "run"
    p = subprocess.Popen([RACKSTRESS, *HEAD, "--out", str(out)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ, RACKSTRESS_HEAD_START="always"))
    killed = None
    t0 = time.monotonic()
    while killed is None and p.poll() is None and time.monotonic() - t0 < HANG_S:
        kids = _children(p.pid)
        if kids:
            killed = kids[0]
            os.kill(killed, signal.SIGKILL)
        time.sleep(0.005)
    stdout, stderr = p.communicate(timeout=HANG_S)
    assert killed is not None, "no head start process was forked"
    assert p.returncode == 0, stderr
    assert "pictures:" in stdout and "peak paper" in stdout
    _same(_derived(out), _derived(alone))
    assert [q.name for q in out.iterdir() if ".tmp" in q.name] == []
    assert json.loads((out / "stress.json").read_text())["timings"][
        "frames_measured_while_running"] == 0


@pytest.mark.lammps
def test_the_head_start_process_hands_over_what_it_measured(tmp_path, alone):
    """The head start's process (render/prepare.py's Ahead) on a run whose dump is complete:
    told to follow, it measures every whole chunk of frames, compresses them and prepares the
    painter; told the run ended and to go on, it post-processes the run. What it leaves equals
    a run without a head start, byte for byte, and stress.json counts the frames it measured
    before it was told the run had ended: the whole chunks of the 101 frames."""
    import shutil

    from rackstress.stress.measures import frame_chunk, neighbourhoods
    from rackstress.stress.rundata import load_run

    out = tmp_path / "run"
    r = _run([*HEAD, "--out", str(out), "--no-render", "--dump-text"])
    assert r.returncode == 0, r.stderr
    for name in ("vtk", "stress.json"):         # back to the state the simulation left
        (shutil.rmtree if (out / name).is_dir() else Path.unlink)(out / name)
    summary = json.loads((out / "summary.json").read_text())
    summary["warnings"] = []                    # as the parent leaves them to the head start
    (out / "summary.json").write_text(json.dumps(summary))
    run = load_run(out)
    chunk = frame_chunk(run.n_atoms, neighbourhoods(run, list(run.parts.values())), 101)
    assert run.index.n_frames == 101 and 1 <= chunk < 101
    code = (
        "import sys, time\n"
        "from pathlib import Path\n"
        "from rackstress import cli\n"
        "from rackstress.render.prepare import Ahead\n"
        f"out = Path({str(out)!r})\n"
        "from rackstress import scenes\n"
        "from rackstress.engines.guards import check_run\n"
        "sc = scenes.build('magpod-small').with_steps(1200)\n"
        "a = Ahead(out, 101, True, lambda found: cli._post_in_child(out, True, False, False,\n"
        "          found), lambda: (sc.name, check_run(sc, out, echo=False, engine='lammps')))\n"
        "a.follow()\n"
        "def cpu():\n"
        "    f = Path(f'/proc/{a.pid}/stat').read_text().rsplit(')', 1)[1].split()\n"
        "    return int(f[11]) + int(f[12])\n"
        "last, still, t0 = -1, 0, time.monotonic()\n"
        "while still < 10 and time.monotonic() - t0 < 900:   # idle for a second: all done\n"
        "    time.sleep(0.1)\n"
        "    now = cpu()\n"
        "    still, last = (still + 1 if now == last else 0), now\n"
        "a.ended()\n"
        "print(a.go())\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0 and r.stdout.strip().splitlines()[-1] == "0", r.stderr
    assert "peak paper" in r.stdout
    _same(_derived(out), _derived(alone))
    assert not (out / "trajectory.dump").exists()
    timings = json.loads((out / "stress.json").read_text())["timings"]
    assert timings["frames_measured_while_running"] == 101 // chunk * chunk


@pytest.mark.lammps
def test_a_head_start_told_to_quit_writes_nothing(tmp_path):
    """Told to quit (the run diverged or failed), the head start's process ends having
    written nothing into the run directory, even after measuring its frames."""
    import time

    out = tmp_path / "run"
    r = _run(["run", "plane-rack", "--steps", "300", "--dump-every", "3", "--no-render",
              "--dump-text", "--no-progress", "--out", str(out)])
    assert r.returncode == 0, r.stderr
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    code = (
        "import time\n"
        "from pathlib import Path\n"
        "from rackstress.render.prepare import Ahead\n"
        f"a = Ahead(Path({str(out)!r}), 101, True, lambda found: 9, lambda: ('x', []))\n"
        "a.follow(); time.sleep(3); a.ended(); time.sleep(1)\n"
        "a.quit(); print(a.status)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0 and r.stdout.strip() == "0", r.stderr
    time.sleep(0.2)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before


@pytest.mark.lammps
def test_a_run_whose_output_is_a_python_stream_says_everything(tmp_path, monkeypatch):
    """Under click's test runner (stdout a Python object, no file descriptor a forked process
    could write to) ``rackstress run`` keeps its post-processing in its own process: every
    line is in the output, the peak and the pictures' included."""
    from click.testing import CliRunner

    from rackstress.cli import main

    monkeypatch.setenv("RACKSTRESS_HEAD_START", "always")
    out = tmp_path / "pr"
    res = CliRunner().invoke(main, ["run", "plane-rack", "--steps", "150", "--dump-every", "3",
                                    "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "peak paper = " in res.output and "pictures: " in res.output
    assert (out / "figures" / "sheet.png").is_file() and (out / "vtk" / "run.pvd").is_file()
