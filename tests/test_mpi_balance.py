"""Load balance of a deck with resting particles under ``mpiexec -n 2`` (deck.balance_commands,
docs/benchmarks/scaling.md): counted, not timed, so it holds on a loaded machine.

Expected values come from the scene's geometry: MagPod's robot (body, legs, racks) spans
x ∈ [−24, 24], z ∈ [−44, 44] on a sediment spanning x ∈ [−75, 822], z ∈ [−148.5, 148.5]; LAMMPS'
even split of the box cuts x in the middle (x ≈ 373), far from the robot, so one rank holds every
moving particle; the weighted bisection must cut through the robot instead.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from test_plugin import _cli
from conftest import HANG_S

BIN = Path(sys.executable).parent
pytestmark = [pytest.mark.lammps, pytest.mark.mpi]


def _moving_per_rank(deck: Path, name: str, text: str) -> tuple[np.ndarray, int, str]:
    """Run ``text`` on 2 ranks; the moving particles (rs_move) each rank owns at the end, the
    particles in all, and LAMMPS' log."""
    k = text.index("\nrun ")          # the compute must exist before LAMMPS' first run
    text = text[:k] + "\ncompute rs_proc all property/atom proc" + text[k:]
    (deck / name).write_text(text + f"write_dump rs_move custom {name}.procs id c_rs_proc\n"
                             f"write_dump all custom {name}.all id c_rs_proc\n")
    proc = subprocess.run([str(BIN / "mpiexec"), "-n", "2", str(BIN / "lmp"), "-in", name,
                           "-log", f"{name}.log"], cwd=deck, capture_output=True, text=True,
                          timeout=HANG_S)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    moving = np.loadtxt(deck / f"{name}.procs", skiprows=9, ndmin=2)
    n_all = len(np.loadtxt(deck / f"{name}.all", skiprows=9, ndmin=2))
    return (np.bincount(moving[:, 1].astype(int), minlength=2), n_all,
            (deck / f"{name}.log").read_text())


def test_magpod_deck_cuts_through_the_robot_on_two_ranks(tmp_path):
    """The generated MagPod deck splits the moving particles between 2 ranks (each ≥ 40 %);
    the same deck without its balance lines leaves them all on one (the problem it solves)."""
    deck = tmp_path / "deck"
    _cli("deck", "magpod", "--out", str(deck), "--set", "phase_steps=20", "--set", "cycles=1")
    text = (deck / "in.lammps").read_text()
    assert "comm_style tiled" in text and "balance 1.0 rcb weight group 1 rs_move" in text
    text = text.replace("trajectory.dump", "t.dump")

    counts, n_all, log = _moving_per_rank(deck, "in.balanced", text)
    n_moving = counts.sum()
    assert 3689 <= n_moving < n_all     # the robot (2907 + 2·382 + 3·6 particles), touched sediment
    assert counts.min() >= 0.4 * n_moving, counts
    # LAMMPS' own account of the weighted load after the bisection
    final = float(log.split("initial/final imbalance factor")[1].split()[2])
    assert final <= 1.05

    plain = "\n".join(ln for ln in text.splitlines()
                      if not ln.startswith(("balance ", "comm_style "))) + "\n"
    counts0, _, _ = _moving_per_rank(deck, "in.even", plain)
    assert sorted(counts0.tolist()) == [0, n_moving], counts0


def test_sediment_large_deck_cuts_through_the_robot_on_two_ranks(tmp_path):
    """sediment-large (scenes/large.py): the bed is longer (x) than wide, so a cut by particle
    count runs across x, ~500 units from the robot (x ∈ [−24, 24] near the bed's rear edge, 25
    columns of 3 in): its million resting particles must not outweigh the robot, or one rank
    holds every moving particle and the other waits (2 ranks slower than 1). The robot weighs as
    much as the bed: 1100 × 910 resting particles over the robot's 2907 + 2·382 + 3·6 = 3689 is
    271.3, rounded 271. The weighted bisection cuts through the robot: each rank holds at least a
    quarter of the moving ones."""
    deck = tmp_path / "deck"
    _cli("deck", "sediment-large", "--out", str(deck), "--set", "phase_steps=10")
    text = (deck / "in.lammps").read_text()
    assert "balance 1.0 rcb weight group 1 rs_move 271.0" in text
    text = text.replace("trajectory.dump", "t.dump")
    counts, n_all, _ = _moving_per_rank(deck, "in.balanced", text)
    n_moving = counts.sum()
    assert n_all == 1_004_689 and 3689 <= n_moving < 10_000
    assert counts.min() >= 0.25 * n_moving, counts


def test_a_longer_bed_weighs_its_robot_as_much_as_the_bed():
    """The 4 M-particle bed (sediment_nx=4400): 4400 × 910 = 4,004,000 resting particles over
    the robot's 3689 is 1085.4, so a moving particle weighs 1085 resting ones (at sediment-large's
    former fixed 150 the bisection cut across x, 5,600 units from the robot, and one rank held
    all 4,055 moving particles); a short bed keeps the floor of 150; a weight given is kept."""
    from rackstress import scenes
    from rackstress.engines.lammps.deck import balance_commands, compile_deck

    def weight(**kw):
        deck = compile_deck(scenes.build("sediment-large", **kw), "exact", plugin=True)
        return balance_commands(deck)[-1]

    assert weight(sediment_nx=4400) == "balance 1.0 rcb weight group 1 rs_move 1085.0"
    assert weight(sediment_nx=100, sediment_nz=100) == \
        "balance 1.0 rcb weight group 1 rs_move 150.0"        # 10,000 / 3689 = 2.7 < 150
    assert weight(sediment_nx=100, sediment_nz=100, robot_weight=40) == \
        "balance 1.0 rcb weight group 1 rs_move 40.0"


def _bed_scene(probe_reverse: bool):
    """A ball falling on a resting bed (passive: only the ball collides it), and a probe that
    feels the bed (probe <- collide bed) with or without the bed feeling the probe."""
    from rackstress import Collide, Dampen, Force, Group, Phase, Scene, lattice
    from rackstress.model.operators import Const

    o = lattice((12, 1, 12), 2.0) - np.array([11.0, 0.0, 11.0])
    # two radii: no single R per type pair, so the collisions stay the plugin's rs/collide
    # (a uniform one would fold into LAMMPS' pair_style lepton, and the bed not rest)
    bed = Group("bed", o, np.where(np.arange(len(o)) % 2 == 0, 1.0, 0.9))
    ball = Group("ball", lattice((2, 2, 2), 2.0) + np.array([-1.0, 3.0, -1.0]), 1.0)
    probe = Group("probe", lattice((2, 2, 2), 2.0) + np.array([6.0, 3.0, 6.0]), 1.0)
    ops = {"bed": [Collide("ball", Const(1.0)), Dampen(1.0)] + ([Collide("probe", Const(1.0))]
                                                           if probe_reverse else []),
           "ball": [Collide("bed", Const(50.0)), Force((0, -1.0, 0))],
           "probe": [Collide("bed", Const(50.0)), Force((0, -1.0, 0))]}
    return Scene("bed", {"bed": bed, "ball": ball, "probe": probe}, ops, [Phase("fall", 10)],
                 dt=0.01)


def test_resting_particles_are_ghosts_only_where_a_contact_would_miss_them():
    """``comm_modify group rs_move`` (no resting ghosts) only where every operator reading the
    passive bed across ranks is a contact whose source activates the bed: the probe, which the
    bed does not feel, would touch resting bed particles no rank sends it."""
    from rackstress.engines.lammps.deck import (balance_commands, compile_deck,
                                                moving_ghosts_suffice)

    both = compile_deck(_bed_scene(True), "exact", plugin=True)
    one_way = compile_deck(_bed_scene(False), "exact", plugin=True)
    assert both.passive == ("bed",) and one_way.passive == ("bed",)
    assert moving_ghosts_suffice(both) and "comm_modify group rs_move" in balance_commands(both)
    assert not moving_ghosts_suffice(one_way)
    assert not any(c.startswith("comm_modify group") for c in balance_commands(one_way))
