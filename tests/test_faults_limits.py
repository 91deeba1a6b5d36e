"""Faults at the limits, played with real processes as in ``test_faults.py``: a full
disk during post-processing and rendering (real tmpfs mounts), a schedule of 10¹² steps on the
LAMMPS engine, scene expressions that would take unbounded time, parameters that are themselves
expressions, NaN positions kept by a divergence, and the progress every long phase shows."""
from __future__ import annotations

import json
import re
import os
import subprocess
import time
from pathlib import Path

import pytest
from conftest import HANG_S, dump_text, trajectory

from conftest import child_cpu
from test_faults import (QUIET, RS, fill, frames, leftovers,  # noqa: F401
                         memory_growth_over_phases, rs, tmpfs)


# ---------------------------------------------------------------------------- disks
@pytest.mark.lammps
def test_full_disk_during_post_processing_is_a_storage_error(tmpfs):  # noqa: F811 (the fixture imported above)
    """The run (5.4 MB of dump) fits in 8 MB, its VTK series (~20 MB) does not: VTK's own file
    writer crashed the process there (SIGSEGV, exit 139, nothing printed)."""
    disk = tmpfs("8m")
    out = disk / "r"
    r = rs("run", "plane-rack", "--steps", "3000", "--dump-every", "10", "--out", out, *QUIET,
           timeout=HANG_S)
    assert r.returncode == 5, (r.returncode, r.stderr)
    assert "No space left on device" in r.stderr and "Traceback" not in r.stderr
    assert f"rackstress stress {out}" in r.stderr          # what to do once there is space
    assert str(out / "vtk") in r.stderr                     # what could not be written
    # the run is whole; nothing of the VTK series is left, half or as if whole; the finished
    # trajectory is compressed all the same (5.4 MB of text in less)
    assert trajectory(out).name == "trajectory.dump.gz" and not (out / "trajectory.dump").exists(), \
        r.stderr
    assert len(frames(trajectory(out))) == 301
    assert not (out / "vtk").exists() and leftovers(out) == []
    assert not [p for p in out.iterdir() if p.name.startswith(".vtk")]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok" and "stress" not in summary


@pytest.mark.lammps
def test_full_disk_while_rendering_is_a_storage_error(tmpfs):  # noqa: F811 (the fixture imported above)
    disk = tmpfs("8m")
    out = disk / "r"
    r = rs("run", "plane-rack", "--steps", "300", "--dump-every", "10", "--out", out, *QUIET)
    assert r.returncode == 0, r.stderr
    fill(disk / "filler")
    r = rs("render", out, "--no-progress", timeout=HANG_S)
    assert r.returncode == 5, (r.returncode, r.stderr)
    assert "No space left on device" in r.stderr and "Traceback" not in r.stderr
    assert str(out / "figures") in r.stderr
    assert not (out / "figures").exists() and not (out / "report.html").exists()
    assert leftovers(out) == [] and not [p for p in out.iterdir() if ".tmp" in p.name]
    # and 'rackstress stress' of it: the storage status (was 2, bad input), nothing half left
    r = rs("stress", out, "--no-progress", timeout=HANG_S)
    assert r.returncode == 5, (r.returncode, r.stderr)
    assert "No space left on device" in r.stderr and "Traceback" not in r.stderr
    assert not (out / "stress.dump").exists() and leftovers(out) == []


# ---------------------------------------------------------------------------- long schedules
def _split_plane_bound(steps):
    """plane-bound with its cycle cut into two phases (7 + 5 steps), run for ``steps``."""
    from rackstress import scenes
    from rackstress.model.scene import Phase, Scene

    sc = scenes.build("plane-bound")
    return Scene(sc.name, sc.groups, sc.operators, [Phase("a", 7), Phase("b", 5)],
                 sc.dt).with_steps(steps)


@pytest.mark.lammps
def test_a_looped_deck_runs_as_the_written_out_one(tmp_path):
    """A long schedule becomes a LAMMPS loop over its identical cycles: plain ``lmp`` runs the
    looped deck (4 whole cycles of 2 phases and a cut one: 7 + 2 steps) to the same dump, byte
    for byte, as the deck with every phase written out."""
    import sys

    from rackstress.engines.lammps.deck import compile_deck

    lmp = Path(sys.executable).parent / "lmp"
    sc = _split_plane_bound(4 * 12 + 9)
    deck = compile_deck(sc, "fast")
    assert not deck.python_ops                    # plain lmp runs it alone
    dumps = {}
    for name, loop_after in (("written", 10**9), ("looped", 0)):
        d = tmp_path / name
        d.mkdir()
        (d / "particles.data").write_text(deck.data_text())
        text = deck.input_text(dump_every=1, loop_after=loop_after)
        (d / "in.lammps").write_text(text)
        assert ("jump SELF" in text) == (name == "looped")
        r = subprocess.run([str(lmp), "-in", "in.lammps"], cwd=d, capture_output=True,
                           text=True, timeout=HANG_S)
        assert r.returncode == 0, r.stdout[-2000:]
        dumps[name] = (d / "trajectory.dump").read_text()
    assert frames_of(dumps["looped"]) == list(range(0, 58))
    assert dumps["looped"] == dumps["written"]


def frames_of(text):
    import re

    return [int(m) for m in re.findall(r"ITEM: TIMESTEP\n(\d+)\n", text)]


@pytest.mark.lammps
def test_any_number_of_steps_costs_no_memory_up_front_on_lammps(tmp_path):
    """``--steps 1000000000000`` on LAMMPS: the deck's schedule was built eagerly (MemoryError
    after minutes); now its in.lammps is a few lines and the run's memory stays flat. The two
    600-step phases of test_faults.PHASES (damping switched by the phase), measured over work,
    not time: the memory once 120,000 steps are done (200 phase switches), then once 1,080,000
    more are (1,800 more switches, each a LAMMPS ``run`` and a velocity shift: a switch that
    left 11 kB behind would pass 20 MB)."""
    growth, out = memory_growth_over_phases(tmp_path, [], 120000, 1200000)
    assert growth < 20e6
    assert len((out / "in.lammps").read_text().splitlines()) < 200


# ---------------------------------------------------------------------------- scene expressions
def _scene(tmp_path, radius, params=""):
    p = tmp_path / "s.toml"
    p.write_text(f'name = "s"\nsteps = 1\n[params]\n{params}\n[[group]]\nname = "a"\n'
                 'kind = "part"\npositions = [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]\n'
                 f"radius = {radius}\n")
    return p


@pytest.mark.parametrize("expr, says", [
    ("9**9**9**9", "beyond the largest number"),     # hung forever: unbounded integers
    ("10**400", "beyond the largest number"),
    (" * ".join(["2**62"] * 20), "evaluates to inf"),
    ("(-8)**0.5", "not a real number"),
    ("gap + word", "parameter 'word', which is 'hi' (a string), not a number"),
])
def test_an_expression_takes_bounded_time_and_says_what_is_wrong(tmp_path, expr, says):
    scene = _scene(tmp_path, f'"$({expr})"', 'gap = 2\nword = "hi"')
    with child_cpu() as cpu:
        r = rs("deck", scene, "--out", tmp_path / "d")
    assert cpu.s < 30          # bounded work (was: 9**9**9**9 evaluated for ever)
    assert r.returncode == 2, r.stderr
    assert says in r.stderr and "group[0].radius" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "d").exists()


def test_an_expression_too_long_is_refused(tmp_path):
    scene = _scene(tmp_path, '"$(' + "+".join(["1"] * 2000) + ')"')
    r = rs("deck", scene, "--out", tmp_path / "d")
    assert r.returncode == 2 and "at most 1000" in r.stderr, r.stderr


def test_small_integer_powers_stay_exact(tmp_path):
    """2**3 = 8 and 10**6 stay integers (a lattice shape takes them); 2**0.5 is a float."""
    scene = tmp_path / "l.toml"
    scene.write_text('name = "l"\nsteps = 1\n[params]\nk = 3\n[[group]]\nname = "a"\n'
                     'kind = "part"\nlattice = { shape = ["$(2**k)", 1, "$(10**6 - 999998)"],'
                     ' spacing = "$(2**0.5)" }\nradius = 0.5\n')
    from rackstress.scenes.toml import load_toml

    sc = load_toml(scene)
    assert sc.groups["a"].n == 8 * 1 * 2
    o = sc.groups["a"].o
    assert abs((o[:, 0].max() - o[:, 0].min()) - 7 * 2 ** 0.5) < 1e-12


@pytest.mark.parametrize("params", ['gap = "$(1/0)"', 'gap = "$nosuch"',
                                    'gap = "$other"\nother = "$gap"'])
def test_a_parameter_that_is_an_expression_is_named(tmp_path, params):
    """Was: "unsupported operand type(s) for +: 'float' and 'str'" at the field using it."""
    scene = _scene(tmp_path, '"$(gap * 0.1 + 0.2)"', params)
    r = rs("deck", scene, "--out", tmp_path / "d")
    assert r.returncode == 2, r.stderr
    assert "[params] gap" in r.stderr and "parameter 'gap'" in r.stderr
    assert "must be a plain number, string or boolean" in r.stderr
    r = rs("deck", _scene(tmp_path, '"$(gap * 0.1)"', "gap = 2"), "--set", "gap=$(1/0)",
           "--out", tmp_path / "d")
    assert r.returncode == 2 and "gap" in r.stderr and "Traceback" not in r.stderr, r.stderr


# ---------------------------------------------------------------------------- divergence
COINCIDE = """name = "co"
dt = 1.0
steps = 20

[[group]]
name = "a"
kind = "part"
positions = [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 5.0, 0.0]]
radius = 0.4

[[operator]]
on = "a"
op = "bind"
from = "a"
c = 1.0

[[operator]]
on = "a"
op = "force"
accel = [1.0, 0.0, 0.0]
where = { ids = [0] }

[[operator]]
on = "a"
op = "force"
accel = [-1.0, 0.0, 0.0]
where = { ids = [1] }
"""


#: The same push made coincident by each operator that divides by a distance (Eq. 12's bind over
#: all pairs: rs/rack; bind within(d): rs/bind; attract, Eq. 14: rs/attract; collide, Eq. 10:
#: rs/collide). Two particles 2 apart, each accelerated by 1 towards the other (for attract the
#: push is 0.5 and the attraction c(u − p)/‖u − p‖ = 0.5 at d = 2; bind at its rest length and
#: collide beyond R = 0.8 add nothing at step 0): Eq. 5 puts both at x = 0 at step 1, where the
#: operator's direction is 0/0.
PAIR = """name = "co"
dt = 1.0
steps = 20

[[group]]
name = "a"
kind = "part"
positions = [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]{third}]
radius = 0.4

[[operator]]
on = "a"
{op}

[[operator]]
on = "a"
op = "force"
accel = [{push}, 0.0, 0.0]
where = {{ ids = [0] }}

[[operator]]
on = "a"
op = "force"
accel = [-{push}, 0.0, 0.0]
where = {{ ids = [1] }}
"""
OPS = {
    "bind": ('op = "bind"\nfrom = "a"\nc = 1.0', 1.0, ", [0.0, 5.0, 0.0]", "rs/rack"),
    "bind-within": ('op = "bind"\nfrom = "a"\nc = 1.0\nwithin = 3.0', 1.0,
                    ", [0.0, 5.0, 0.0]", "rs/bind"),
    "attract": ('op = "attract"\nfrom = "a"\nc = 0.5', 0.5, "", "rs/attract"),
    "collide": (None, 1.0, "", "rs/collide"),
}
#: collide directed (a from b, b feels nothing): rs/collide. A group colliding with itself both
#: ways is LAMMPS' own pair style (lepton), whose non-finite force is seen a step later.
COLLIDE = """name = "co"
dt = 1.0
steps = 20

[[group]]
name = "a"
kind = "part"
positions = [[-1.0, 0.0, 0.0]]
radius = 0.4

[[group]]
name = "b"
kind = "part"
positions = [[1.0, 0.0, 0.0]]
radius = 0.4

[[operator]]
on = "a"
op = "collide"
from = "b"
c = 1.0

[[operator]]
on = "a"
op = "force"
accel = [1.0, 0.0, 0.0]

[[operator]]
on = "b"
op = "force"
accel = [-1.0, 0.0, 0.0]
"""
COINCIDE = PAIR.format(op=OPS["bind"][0], push=1.0, third=OPS["bind"][2])


def coincide_run(tmp_path, op: str, how: str):
    """Run the pair scene of ``op`` on path ``how``: (exit status, stderr, summary, dump text,
    the operator path recorded)."""
    from test_faults import MPIEXEC

    text, push, third, _ = OPS[op]
    scene = tmp_path / f"co-{op}.toml"
    scene.write_text(COLLIDE if text is None else PAIR.format(op=text, push=push, third=third))
    out = tmp_path / f"r-{op}-{how}"
    args = ["run", scene, "--allow-unstable", "--dump-every", "1", "--out", out, *QUIET]
    if how == "reference":
        args += ["--engine", "reference"]
    cmd = ([MPIEXEC, "-n", "2"] if how.endswith("mpi") else []) + [RS, *map(str, args)]
    env = dict(os.environ)
    if how.startswith("callback"):
        env["RACKSTRESS_KERNELS"] = "numba"       # the Python callback, not the plugin
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=HANG_S, env=env)
    s = json.loads((out / "summary.json").read_text())
    path = (json.loads((out / "scene.json").read_text())["fingerprint"].get("operators")
            if how != "reference" else None)
    return r.returncode, r.stderr, s, dump_text(trajectory(out)), path, out


@pytest.mark.lammps
@pytest.mark.parametrize("op", list(OPS))
def test_a_pair_that_coincides_is_named_at_its_first_step_on_every_path(tmp_path, op):
    """A bound (attracted, colliding) pair that coincides. The reference engine names
    step 1 (hand calculation above); the compiled plugin (serial and ``mpiexec -n 2``) and the
    Python callback (serial and ``mpiexec -n 2``) name the same step and particle, exit 3
    ``diverged``, and keep frames 0 and 1 only, all finite. Was, on the plugin: step 2 (its
    positions were already NaN; the watchdog saw them at step 10 and the dump was cut there),
    because rs/bind, rs/rack, rs/attract and rs/collide added the NaN term. (collide, all
    paths: a traceback in the stability prediction, which paired each particle of a group
    colliding with itself with itself as its nearest "virtual contact".)"""
    expect = "run diverged at step 1: the force on 'a' particle 0 (atom id 1) is not finite"
    named = {}
    for how in ("reference", "plugin", "plugin-mpi", "callback", "callback-mpi"):
        code, err, s, dump, path, out = coincide_run(tmp_path, op, how)
        assert code == 3, (how, err)
        assert "Traceback" not in err and "Warning" not in err, (how, err)
        if op == "collide" and not how.startswith("plugin"):   # their own account of it
            assert {"reference": "step 1: 'a' particle 0 and 'b' particle 0 coincide",
                    "callback": "run diverged at step 1: collide on a: atom ids 1 and 2 "
                                "coincide"}[how.split("-")[0]] in err, (how, err)
        else:
            assert err.count("run diverged") == 1 and expect in err, (how, err)
        assert s["status"] == "diverged", how
        named[how] = (s["error"]["step"], s["error"]["atom_id"])
        assert "nan" not in dump.lower() and "inf" not in dump.lower(), how
        assert frames(out / "trajectory.dump") == [0, 1], how
        if how.startswith("plugin"):
            assert path == "plugin", how
            deck = (out / "in.lammps").read_text()
            assert OPS[op][3] in deck, (how, deck)
        elif how.startswith("callback"):
            assert path == "callback", how
    assert set(named.values()) == {(1, 1)}, named


@pytest.mark.lammps
def test_a_plain_lmp_run_of_a_coinciding_pair_stops_there(tmp_path):
    """A standalone plugin deck (``rackstress deck``) under plain ``lmp`` and ``mpiexec -n 2
    lmp``: the style that meets the non-finite term stops LAMMPS at that step with one message
    naming the atom (no NaN positions written, no rank left waiting)."""
    from test_faults import MPIEXEC
    from test_faults_plugin import LMP

    scene = tmp_path / "co.toml"
    scene.write_text(COINCIDE)
    deck = tmp_path / "deck"
    r = rs("deck", scene, "--dump-every", "1", "--out", deck)
    assert r.returncode == 0, r.stderr
    for mpi in ([], [MPIEXEC, "-n", "2"]):
        (deck / "trajectory.dump").unlink(missing_ok=True)
        r = subprocess.run([*mpi, LMP, "-in", "in.lammps"], cwd=deck, capture_output=True,
                           text=True, timeout=HANG_S)
        assert r.returncode != 0
        assert ("Fix rs/rack: the force on atom id 1 is not finite at step 1: two particles "
                "bound or attracted to each other coincide there") in r.stdout + r.stderr, \
            r.stdout[-2000:] + r.stderr[-2000:]
        text = (deck / "trajectory.dump").read_text()
        assert "nan" not in text.lower() and frames(deck / "trajectory.dump") == [0]


def test_trim_nonfinite_cuts_the_dump_before_the_first_bad_frame(tmp_path):
    from rackstress.engines.dumpio import trim_nonfinite

    def frame(step, x):
        return (f"ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n2\nITEM: BOX BOUNDS pp pp pp\n"
                f"0 1\n0 1\n0 1\nITEM: ATOMS id type mol x y z\n1 1 1 0 0 0\n2 1 1 {x} 0 0\n")
    dump = tmp_path / "trajectory.dump"
    good = frame(0, "1") + frame(10, "1.5")
    dump.write_text(good + frame(20, "-nan") + frame(30, "nan"))
    assert trim_nonfinite(dump) == 20
    assert dump.read_text() == good
    assert trim_nonfinite(dump) is None and dump.read_text() == good
    dump.write_text(frame(0, "1") + frame(5, "inf"))
    assert trim_nonfinite(dump) == 5 and frames(dump) == [0]


# ---------------------------------------------------------------------------- no silent minutes
def test_every_phase_says_so_in_a_log(tmp_path):
    """Not on a terminal (a log, a batch job): one line per phase, in order, as it starts —
    building the scene (a 70,000-particle part took 4 minutes here without a word), preparing,
    running, post-processing, pictures."""
    out = tmp_path / "r"
    r = rs("run", "plane-rack", "--engine", "reference", "--steps", "30", "--out", out,
           timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("rackstress: ")]
    assert [ln.split()[1] for ln in lines] == ["building", "preparing", "running", "computing",
                                               "rendering"], r.stderr
    assert "406 particles" in lines[1] and "30 steps" in lines[2]
    quiet = rs("run", "plane-rack", "--engine", "reference", "--steps", "30", "--out",
               tmp_path / "q", *QUIET)
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr


def test_a_long_phase_ticks_on_a_terminal(tmp_path):
    """On a terminal, a phase without a bar of its own shows its seconds after 2 s (a real
    pseudo-terminal, a real process), and clears the line when done."""
    import pty
    import sys

    script = ("import time\nfrom rackstress.lib.progress import phase\n"
              "with phase(\"building the scene 'slow'\"):\n    time.sleep(3.2)\n"
              "print('built')\n")
    chunks = []

    def read(fd):
        data = os.read(fd, 1024)
        chunks.append(data)
        return data
    t0 = time.monotonic()
    status = pty.spawn([sys.executable, "-c", script], read)
    text = b"".join(chunks).decode()
    assert status == 0, text
    assert time.monotonic() - t0 >= 3.2
    assert "building the scene 'slow'… 2 s" in text or "building the scene 'slow'… 3 s" in text
    assert "\r\x1b[K" in text and text.rstrip().endswith("built")
    assert "rackstress: building" not in text          # the log line is for non-terminals


def test_a_batch_says_when_each_job_starts(tmp_path):
    """A batch printed a line when a job ended only: a job of minutes was minutes of silence."""
    sweep = tmp_path / "s.toml"
    sweep.write_text('scene = "plane-bound"\nengine = "reference"\nsteps = 20\n'
                     '[[job]]\nname = "a"\n[[job]]\nname = "b"\n')
    r = rs("batch", sweep, "--out", tmp_path / "b", timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    lines = [ln.strip() for ln in r.stdout.splitlines()]
    for name in ("a", "b"):
        start = lines.index(f"{name}: started (group 0)")
        end = next(k for k, ln in enumerate(lines) if re.match(rf"\[\d/2\] {name}: ok", ln))
        assert start < end
