"""Faults of the compiled plugin's path, played with real processes:
a plugin missing, cut short, corrupt or built for another LAMMPS (one line, then the Python
callback); a rank killed with ``kill -9`` under ``mpiexec -n 2 lmp`` and under ``mpiexec -n 2
rackstress run`` (every rank ends in bounded time; ``--resume`` writes the uninterrupted
trajectory byte for byte, serial and under two ranks); a disk that fills during ``write_restart`` (exit 5, the last
checkpoint whole). README's fault table lists each case."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import HANG_S, dump_text, trajectory

from test_faults import (MPIEXEC, QUIET, RS, fill, leftovers, progress_step, rs,  # noqa: F401
                         tmpfs, wait_for)

BIN = Path(sys.executable).parent
LMP = str(BIN / "lmp")
CALLBACK_LINE = "rackstress: using the Python callback for the exact operators: "


def operators(rundir: Path) -> str:
    """The operator path a run recorded in its fingerprint (``plugin`` or ``callback``)."""
    return json.loads((rundir / "scene.json").read_text())["fingerprint"]["operators"]


def the_plugin() -> Path:
    from rackstress.engines.lammps.plugin import locate

    lib, why = locate()
    assert lib is not None, why         # the install built it (setup.py)
    return lib


def broken(kind: str, d: Path) -> Path:
    """A plugin library that cannot serve this LAMMPS: ``missing``, ``corrupt`` (random bytes),
    ``cut`` (the real one cut in half, as a full disk or an interrupted copy leaves it) or
    ``other`` (the real one with the version string it registers changed to another
    release's, same length: what a build for another LAMMPS carries)."""
    lib = d / f"{kind}-rackstressplugin.so"
    real = the_plugin().read_bytes()
    if kind == "corrupt":
        lib.write_bytes(np.random.default_rng(1).bytes(4096))
    elif kind == "cut":
        lib.write_bytes(real[:len(real) // 2])
    elif kind == "other":
        assert real.count(b"22 Jul 2025") == 1
        lib.write_bytes(real.replace(b"22 Jul 2025", b"29 Aug 2024"))
    return lib


@pytest.fixture(scope="module")
def callback_run(tmp_path_factory):
    """plane-rack on the callback path, asked for (RACKSTRESS_PLUGIN=0): what a fallback must
    reproduce exactly."""
    out = tmp_path_factory.mktemp("cb") / "run"
    r = subprocess.run([RS, "run", "plane-rack", "--steps", "60", "--dump-every", "20", "--out",
                        str(out), *QUIET], capture_output=True, text=True, timeout=HANG_S,
                       env={**os.environ, "RACKSTRESS_PLUGIN": "0"})
    assert r.returncode == 0, r.stderr
    assert operators(out) == "callback"
    return out


# ---------------------------------------------------------------------------- broken plugin
@pytest.mark.lammps
@pytest.mark.parametrize("kind,says", [
    ("missing", "which does not exist"),
    ("corrupt", "is not a shared library (no ELF header)"),
    ("cut", "is cut short"),
    ("other", "was built for LAMMPS '29 Aug 2024', not for this one ('22 Jul 2025')")])
def test_a_broken_plugin_is_one_line_and_the_callback(tmp_path, callback_run, kind, says):
    """Without the check, a corrupt or cut library stopped the run at "Unrecognized fix style
    'rs/rack'" (exit 2) and one built for another LAMMPS was loaded anyway."""
    lib = broken(kind, tmp_path)
    out = tmp_path / "run"
    r = subprocess.run([RS, "run", "plane-rack", "--steps", "60", "--dump-every", "20", "--out",
                        str(out), *QUIET], capture_output=True, text=True, timeout=HANG_S,
                       env={**os.environ, "RACKSTRESS_PLUGIN": str(lib)})
    assert r.returncode == 0, r.stderr
    notes = [line for line in r.stderr.splitlines() if line.startswith("rackstress:")]
    assert len(notes) == 1 and notes[0].startswith(CALLBACK_LINE), r.stderr
    assert str(lib) in notes[0] and says in notes[0], notes[0]
    assert "Traceback" not in r.stderr
    assert operators(out) == "callback"
    # the whole run, exactly the callback's
    assert trajectory(out).read_bytes() == trajectory(callback_run).read_bytes()
    assert dump_text(trajectory(out)) == dump_text(trajectory(callback_run))


def _package_copy(root: Path, plugin_lib: str) -> dict:
    """The rackstress package copied under ``root`` without the plugin's sources, its packaged
    plugin ``gone`` or stamped for another LAMMPS (``stale``): an install whose plugin cannot
    be used and cannot be rebuilt. Returns the environment that imports the copy."""
    import rackstress

    pkg = Path(rackstress.__file__).parent
    dest = root / "site" / "workflow" / "rackstress"
    # no sources either: neither a repository above the copy nor the copy packaged beside the
    # module (a non-editable install carries them as plugin_src)
    shutil.copytree(pkg, dest, ignore=shutil.ignore_patterns("__pycache__", "plugin_src"))
    lib = dest / "engines" / "lammps" / "plugin_lib"
    if plugin_lib == "gone":
        shutil.rmtree(lib, ignore_errors=True)
    else:
        stamp = json.loads((lib / "build.json").read_text())
        stamp["lammps"], stamp["version"] = "2024.8.29.1.0", "29 Aug 2024"
        (lib / "build.json").write_text(json.dumps(stamp))
    return {**os.environ, "PYTHONPATH": str(dest.parent), "XDG_CACHE_HOME": str(root / "cache")}


@pytest.mark.lammps
@pytest.mark.parametrize("plugin_lib,says", [
    ("gone", "the plugin was not built at install"),
    ("stale", "the packaged plugin was built for another LAMMPS than 2025.7.22.4.0")])
def test_packaged_plugin_missing_or_stale_without_sources(tmp_path, plugin_lib, says):
    """An install whose packaged plugin is missing or stamped for another LAMMPS, with no
    sources to rebuild it: one line why, and the deck falls back to the callback."""
    env = _package_copy(tmp_path, plugin_lib)
    r = subprocess.run([RS, "deck", "plane-rack", "--out", str(tmp_path / "deck")],
                       capture_output=True, text=True, timeout=HANG_S, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    notes = [line for line in r.stderr.splitlines() if line.startswith("rackstress:")]
    assert len(notes) == 1 and notes[0].startswith(CALLBACK_LINE), r.stderr
    assert says in notes[0] and "sources are not here" in notes[0], notes[0]
    deck = (tmp_path / "deck" / "in.lammps").read_text()
    assert "fix external" in deck and "rs/rack" not in deck
    assert not (tmp_path / "cache" / "rackstress" / "plugin").exists()    # nothing built


# ---------------------------------------------------------------------------- kill -9 a rank
def descendants(pid: int) -> list[int]:
    """Every live process below ``pid`` (read from /proc)."""
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            kids.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        for k in kids.get(todo.pop(), []):
            out.append(k)
            todo.append(k)
    return out


def ranks(mpiexec: subprocess.Popen, name: str) -> list[int]:
    """The pids of the ranks mpiexec started: ``lmp``, the LAMMPS binary itself (the venv's
    ``lmp`` is a Python script that starts it), or ``rackstress``, the script run by Python."""
    found = []
    for p in descendants(mpiexec.pid):
        try:
            cmd = Path(f"/proc/{p}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        prog = cmd[0] if name == "lmp" else (cmd[1] if len(cmd) > 1 else b"")
        if Path(prog.decode(errors="replace")).name == name:
            found.append(p)
    return found


def kill_one_rank_and_time_the_end(p: subprocess.Popen, name: str, bound: float = HANG_S):
    """``kill -9`` one rank of ``p``; return mpiexec's (status, seconds to end, stderr)."""
    assert wait_for(lambda: len(ranks(p, name)) == 2, proc=p), "two ranks never appeared"
    os.kill(max(ranks(p, name)), signal.SIGKILL)
    t0 = time.monotonic()
    try:
        err = p.communicate(timeout=bound)[1]
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        raise AssertionError(f"mpiexec -n 2 {name} hung after one rank was killed")
    return p.returncode, time.monotonic() - t0, err


@pytest.mark.lammps
@pytest.mark.mpi
def test_rank_killed_under_mpiexec_lmp_on_a_plugin_deck_ends_every_rank(tmp_path):
    """A standalone plugin deck (no Python in the ranks) under ``mpiexec -n 2 lmp``: one rank
    killed, mpiexec ends the other and exits non-zero within seconds."""
    deck = tmp_path / "deck"
    r = rs("deck", "plane-rack", "--steps", "10000000", "--dump-every", "100", "--out", deck)
    assert r.returncode == 0, r.stderr
    assert "rs/rack" in (deck / "in.lammps").read_text()          # the plugin's deck
    p = subprocess.Popen([MPIEXEC, "-n", "2", LMP, "-in", "in.lammps"], cwd=deck,
                         start_new_session=True, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    try:
        dump = deck / "trajectory.dump"
        assert wait_for(lambda: dump.exists() and dump.stat().st_size > 100_000, proc=p), \
            p.stderr.read() if p.poll() is not None else "no frames"
        code, took, err = kill_one_rank_and_time_the_end(p, "lmp")
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert code != 0, err          # a hang: the bound (HANG_S) of the wait above
    assert descendants(p.pid) == []


@pytest.mark.lammps
@pytest.mark.mpi
@pytest.mark.parametrize("nranks,scene", [(1, "plane-rack"), (2, "plane-rack"),
                                          (2, "plane-bound")])
def test_rank_killed_under_rackstress_run_then_resume(tmp_path, nranks, scene):
    """``rackstress run`` on the plugin path (serial, and ``mpiexec -n 2``), one rank killed
    with ``kill -9`` after a checkpoint: every rank ends within seconds, and ``--resume`` (as
    many ranks) writes the uninterrupted run's trajectory byte for byte.

    Under two ranks this failed (frames after the checkpoint differed in the last bits, then the
    box line): ``rs/rack``'s partial sum over a rank's hosts (plane-rack) and ``rs/bind``'s
    per-atom sum over its bonds (plane-bound) were added in LAMMPS' row order, which an exchange
    and a resumed run's data file order change; they are now in atom-id order. The kill comes
    after step 2400: by then plane-rack's rack has moved the shrink-wrapped box's upper x bound,
    which the resumed run reproduces too (LAMMPS pads it by 1e-4 of the data file's box in
    both)."""
    mpi = [MPIEXEC, "-n", "2"] if nranks == 2 else []
    args = ["run", scene, "--steps", "8000", "--restart-every", "200", "--dump-every",
            "100", *QUIET]
    full, cut = tmp_path / "full", tmp_path / "cut"
    r = subprocess.run([*mpi, RS, *args, "--out", str(full)], capture_output=True, text=True,
                       timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    assert operators(full) == "plugin"
    p = subprocess.Popen([*mpi, RS, *args, "--out", str(cut)], start_new_session=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: (progress_step(cut) or 0) >= 2400, proc=p), "no checkpoint"
        if nranks == 2:
            code, took, err = kill_one_rank_and_time_the_end(p, "rackstress")
            assert code != 0, (code, took, err)      # a hang: HANG_S above
            assert descendants(p.pid) == []
        else:
            p.kill()
            p.communicate(timeout=HANG_S)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    step = progress_step(cut)
    assert step is not None and step < 8000 and not (cut / "summary.json").exists()
    r = subprocess.run([*mpi, RS, "run", "--resume", str(cut), *QUIET], capture_output=True,
                       text=True, timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    s = json.loads((cut / "summary.json").read_text())
    assert s["resumed_from_step"] == step and s["steps"] == 8000
    assert operators(cut) == "plugin"
    assert trajectory(cut).name == "trajectory.dump.gz"
    a, b = trajectory(cut).read_bytes(), trajectory(full).read_bytes()
    assert a == b, first_difference(trajectory(full), trajectory(cut))


def first_difference(dump_a: Path, dump_b: Path) -> str:
    """The first frame two LAMMPS dumps differ in, and its first differing line (a message)."""
    fa = dump_text(dump_a).split("ITEM: TIMESTEP\n")[1:]
    fb = dump_text(dump_b).split("ITEM: TIMESTEP\n")[1:]
    for x, y in zip(fa, fb):
        if x != y:
            line = next((p, q) for p, q in zip(x.split("\n"), y.split("\n")) if p != q)
            return f"step {x.split(chr(10), 1)[0]}: {line[0]!r} != {line[1]!r}"
    return f"{len(fa)} frames != {len(fb)}"


# ---------------------------------------------------------------------------- full disk
@pytest.mark.lammps
@pytest.mark.parametrize("nranks", [1, 2])
def test_full_disk_while_checkpointing_on_the_plugin_path(tmpfs, nranks):  # noqa: F811
    """The disk fills between two checkpoints of a plugin run: the next checkpoint's write
    (mostly LAMMPS' ``write_restart``) fails, every rank ends with exit 5 and one message, and the last committed checkpoint
    (``progress.json``) is whole: its state holds every particle, finite, and its restart
    file is the size of the previous ones."""
    disk = tmpfs("4m")
    out = disk / "run"
    mpi = [MPIEXEC, "-n", "2"] if nranks == 2 else []
    p = subprocess.Popen([*mpi, RS, "run", "plane-rack", "--steps", "1000000",
                          "--restart-every", "50", "--dump-every", "1000000", "--out", str(out),
                          *QUIET], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert wait_for(lambda: (progress_step(out) or 0) >= 100, proc=p)
    assert operators(out) == "plugin"
    fill(disk / "filler")
    try:
        err = p.communicate(timeout=HANG_S)[1]
    except subprocess.TimeoutExpired:
        p.kill()
        p.communicate()
        raise AssertionError("the run hung after the disk filled")
    assert p.returncode == 5, err
    assert err.count("No space left") == 1 and "Traceback" not in err, err
    # which write meets the full disk first is the race's: LAMMPS' write_restart (most of the
    # bytes of a checkpoint), the state file or progress.json; each is named
    assert ("write_restart" in err or str(out / "restart") in err
            or str(out / "progress.json") in err), err
    assert leftovers(out) == []
    meta = json.loads((out / "progress.json").read_text())
    assert meta["step"] >= 100 and meta["step"] % 50 == 0
    with np.load(out / meta["state"]) as z:
        assert z["x"].shape == (406, 3) and np.isfinite(z["x"]).all()
    restarts = sorted((out / "restart").iterdir())
    assert out / meta["restart"] in restarts
    assert (out / meta["restart"]).stat().st_size > 0
