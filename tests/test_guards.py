"""Guard rails (``rackstress.engines.guards``): pass-through and forces on rack particles.

The pass-through check is fed hand-made motions (a block moved straight through a slab, around
it, or stopped on it), then real runs on the reference engine; the summary records the findings.
"""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from rackstress.engines.dumpio import DumpWriter, frame_text
from rackstress.engines.guards import dump_frames, force_on_racks, pass_through
from rackstress.model.operators import Bind, Collide, Const, Force
from rackstress.model.particles import Group, lattice, rack
from rackstress.model.scene import Phase, Scene
from conftest import HANG_S

RACKSTRESS = Path(sys.executable).with_name("rackstress")


def slab_and_block():
    slab = Group("slab", lattice((8, 1, 8), 1.0), 0.5)                 # y = 0, x, z ∈ 0..7
    block = Group("block", lattice((2, 2, 2), 1.0, (3.0, 3.0, 3.0)), 0.5)
    ops = {"slab": [Collide("block", Const(10.0))], "block": [Collide("slab", Const(10.0))]}
    return Scene("g", {"slab": slab, "block": block}, ops, [Phase("run", 10)])


def frames_moving_block(sc, path):
    """Frames with the block moved by each offset in ``path`` (the slab stays)."""
    o = sc.original_positions()
    out = []
    for k, offset in enumerate(path):
        p = o.copy()
        p[sc.slice("block")] += offset
        out.append((10 * k, p))
    return out


def test_straight_through_is_found_at_the_first_frame_past():
    sc = slab_and_block()
    # the block's centre starts at y = 3.5; it is past the slab (y = 0) once below 0
    path = [(0, 0, 0), (0, -2, 0), (0, -3.4, 0), (0, -3.6, 0), (0, -8, 0)]
    found = pass_through(sc, frames_moving_block(sc, path))
    assert len(found) == 1
    assert found[0]["groups"] == ["slab", "block"] and found[0]["step"] == 30
    assert "passed through" in found[0]["message"]


def test_around_or_stopped_is_not_pass_through():
    sc = slab_and_block()
    # around: first sideways beyond the slab's edge (x > 7.5 + 0.5), then down below it
    around = [(0, 0, 0), (6, 0, 0), (6, -8, 0)]
    assert pass_through(sc, frames_moving_block(sc, around)) == []
    # stopped on it: down to resting on the slab
    stopped = [(0, 0, 0), (0, -2, 0), (0, -2.5, 0)]
    assert pass_through(sc, frames_moving_block(sc, stopped)) == []


def test_groups_not_apart_at_start_are_not_judged():
    sc = slab_and_block()
    sc.groups["block"].o[:] += (0.5, -3.0, 0.5)       # block sunk into the slab at step 0
    sc = Scene("g", sc.groups, sc.operators, sc.phases)
    path = [(0, 0, 0), (0, -8, 0)]
    assert pass_through(sc, frames_moving_block(sc, path)) == []


def test_force_on_rack_is_reported_once_per_operator():
    host = Group("part", lattice((2, 2, 2)), 0.5)
    r = rack(host)
    ops = {"part": [Force((0, -9.81, 0)), Bind("partrack", Const(100.0))],
           "partrack": [Force((0, -9.81, 0)), Bind("part", Const(0.5))]}
    sc = Scene("r", {"part": host, "partrack": r}, ops, [Phase("run", 1)])
    found = force_on_racks(sc)
    assert len(found) == 1 and found[0]["group"] == "partrack"
    assert "rack particle" in found[0]["message"] and "'part'" in found[0]["message"]


def test_dump_frames_reads_back_what_was_written(tmp_path):
    rng = np.random.default_rng(1)
    n = 7
    written = []
    with DumpWriter(tmp_path / "t.dump", np.ones(n, int), np.ones(n, int)) as w:
        for step in range(0, 50, 10):
            p = rng.normal(size=(n, 3))
            w.write(step, p)
            written.append((step, p))
    got = list(dump_frames(tmp_path / "t.dump", np.zeros((n, 3)), max_frames=3))
    assert [s for s, _ in got] == [0, 20, 40]          # first, middle, last
    for s, p in got:
        np.testing.assert_allclose(p, dict(written)[s], rtol=1e-9)
    # a frame cut short (a killed run) is skipped
    text = (tmp_path / "t.dump").read_text().splitlines()
    (tmp_path / "cut.dump").write_text("\n".join(text[:-3]) + "\n")
    assert [s for s, _ in dump_frames(tmp_path / "cut.dump", np.zeros((n, 3)))] == [0, 10, 20, 30]
    # a frame that holds some particles: the others sit at their original positions
    o = rng.normal(size=(n, 3))
    part = "".join(frame_text(s, p[[1, 4]], ("id", "type", "mol", "x", "y", "z"),
                              np.column_stack([[2, 5], [1, 1], [1, 1], p[[1, 4]]]),
                              ["%d", "%d", "%d"] + ["%.17g"] * 3) for s, p in written)
    (tmp_path / "part.dump").write_text(part)
    for (s, p), (s2, q) in zip(written, dump_frames(tmp_path / "part.dump", o)):
        expect = o.copy()
        expect[[1, 4]] = p[[1, 4]]
        assert s == s2 and np.array_equal(q, expect)


SCENE = """
    name = "through"
    dt = 0.01
    duration = 1.0
    [params]
    speed = 40.0
    c = 5.0
    [[group]]
    name = "slab"
    lattice = { shape = [6, 2, 6], spacing = 1.0 }
    held = { box = { min = [0, 0, 0], max = [0, 1, 5] } }
    [[group]]
    name = "block"
    lattice = { shape = [2, 2, 2], spacing = 1.0, origin = [2, 3.0, 2] }
    velocity = [0, "$(-speed)", 0]
    [[operator]]
    on = "slab"
    op = "bind"
    from = "slab"
    c = 100
    within = 1.5
    [[operator]]
    on = "slab"
    op = "collide"
    from = "block"
    c = "$c"
    [[operator]]
    on = "block"
    op = "collide"
    from = "slab"
    c = "$c"
"""


@pytest.mark.parametrize("speed, c, passes", [(40.0, 5.0, True), (1.0, 100.0, False)])
def test_run_records_pass_through_in_summary(tmp_path, speed, c, passes):
    path = tmp_path / "scene.toml"
    path.write_text(textwrap.dedent(SCENE))
    out = tmp_path / "run"
    proc = subprocess.run([str(RACKSTRESS), "run", str(path), "--engine", "reference", "--out",
                           str(out), "--no-render", "--set", f"speed={speed}", "--set", f"c={c}"],
                          capture_output=True, text=True, timeout=HANG_S)
    assert proc.returncode == 0, proc.stderr[-2000:]
    s = json.loads((out / "summary.json").read_text())
    kinds = [w["kind"] for w in s["warnings"]]
    com = s["groups"]["block"]["com_end"][1]
    if passes:
        assert kinds == ["pass_through"] and com < 0           # really below the slab
        assert "warning" in proc.stderr and "passed through" in proc.stderr
    else:
        assert kinds == [] and com > 0.5


def test_through_the_arm_of_an_l_shape_is_found_below_the_arm():
    """A block over the tip of an L's arm, moved down through the arm: caught once its centre
    is below the arm (y < 18), though it is still far above the L's bottom and centre."""
    leg = lattice((2, 20, 2), 1.0)                                  # x 0..1, y 0..19
    arm = lattice((18, 2, 2), 1.0, (2.0, 18.0, 0.0))                # x 2..19, y 18..19
    ell = Group("ell", np.concatenate([leg, arm]), 0.5)
    block = Group("block", lattice((2, 2, 2), 1.0, (15.0, 21.0, 0.0)), 0.5)   # centre y 21.5
    ops = {"ell": [Collide("block", Const(10.0))], "block": [Collide("ell", Const(10.0))]}
    sc = Scene("l", {"ell": ell, "block": block}, ops, [Phase("run", 10)])
    inside = [(0, 0, 0), (0, -3.0, 0)]                              # centre 18.5: in the arm
    assert pass_through(sc, frames_moving_block(sc, inside)) == []
    below = [(0, 0, 0), (0, -3.0, 0), (0, -4.6, 0)]                  # centre 16.9: below it
    found = pass_through(sc, frames_moving_block(sc, below))
    assert [f["step"] for f in found] == [20]
    assert found[0]["message"].startswith("'block' passed through 'ell'")


def test_run_records_force_on_rack_in_summary(tmp_path):
    path = tmp_path / "rackforce.toml"
    path.write_text(textwrap.dedent("""
        name = "rackforce"
        steps = 20
        [[group]]
        name = "block"
        lattice = { shape = [2, 2, 2] }
        [[group]]
        name = "blockrack"
        rack = "block"
        [[operator]]
        on = "block"
        op = "bind"
        from = "blockrack"
        c = 100
        [[operator]]
        on = "blockrack"
        op = "force"
        accel = [0, -10, 0]
    """))
    out = tmp_path / "run"
    proc = subprocess.run([str(RACKSTRESS), "run", str(path), "--engine", "reference", "--out",
                           str(out), "--no-render"], capture_output=True, text=True, timeout=HANG_S)
    assert proc.returncode == 0, proc.stderr[-2000:]
    s = json.loads((out / "summary.json").read_text())
    assert [w["kind"] for w in s["warnings"]] == ["force_on_rack"]
    assert s["warnings"][0]["group"] == "blockrack" and "blockrack" in proc.stderr


@pytest.mark.lammps
def test_the_head_start_checks_the_guard_rails_as_the_run_would(tmp_path):
    """On LAMMPS, ``rackstress run``'s head start checks the guard rails beside the run
    (render/prepare.py's Ahead; the run leaves ``warnings`` to it): the summary records the
    same pass-through, and stderr says it, as a run without a head start."""
    import os

    path = tmp_path / "scene.toml"
    path.write_text(textwrap.dedent(SCENE))
    got = {}
    for how in ("always", "0"):
        out = tmp_path / f"run-{how}"
        proc = subprocess.run([str(RACKSTRESS), "run", str(path), "--out", str(out),
                               "--no-render", "--no-progress"], capture_output=True, text=True,
                              timeout=HANG_S, env=dict(os.environ, RACKSTRESS_HEAD_START=how))
        assert proc.returncode == 0, proc.stderr[-2000:]
        s = json.loads((out / "summary.json").read_text())
        assert s["engine"] == "lammps" and "passed through" in proc.stderr
        got[how] = s["warnings"]
    assert [w["kind"] for w in got["0"]] == ["pass_through"]
    assert got["always"] == got["0"]
