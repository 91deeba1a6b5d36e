"""MagPod on LAMMPS: parity with the reference engine, and a four-cycle walk end to end.

The walk's criteria are the issue's: the body advances in every cycle and by at least one foot
length per cycle in all; both feet leave footprints where they stood and nowhere else; the body
never capsizes; nothing diverges over 19,200 iterations (more than Fig. 12's 17,480).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rackstress import scenes
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import LammpsRun
from rackstress.engines.driver import drive

EXE = Path(sys.executable).parent / "rackstress"


@pytest.mark.slow
@pytest.mark.lammps
def test_parity_magpod_small_600_iterations(reference_final):
    """Exact mode vs the reference engine over 600 iterations, all four gait phases."""
    sc = scenes.build("magpod-small", phase_steps=150, cycles=1)
    assert sc.total_steps == 600
    ref_p = reference_final(sc)
    run = LammpsRun(compile_deck(sc, "exact"), None)
    try:
        p = drive(run).positions
    finally:
        run.close()
    moved = np.abs(ref_p - sc.original_positions()).max()
    assert moved > 1.0                              # the legs really moved
    assert np.abs(p - ref_p).max() <= 1e-10     # measured 8.9e-14


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """``rackstress run magpod-small`` for 4 gait cycles through LAMMPS (19,200 iterations)."""
    out = tmp_path_factory.mktemp("walk") / "run"
    proc = subprocess.run([str(EXE), "run", "magpod-small", "--set", "cycles=4", "--out", str(out),
                           "--no-progress", "--dump-every", "400"],
                          capture_output=True, text=True, timeout=1500)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, json.loads((out / "summary.json").read_text())


def _foot_length(sc) -> float:
    """Extent of a sole along the walk (+x), radii included, from the original geometry."""
    o = sc.groups["rightleg"].o
    sole = o[o[:, 1] < o[:, 1].min() + 0.5]
    return float(sole[:, 0].max() - sole[:, 0].min() + 2 * sc.groups["rightleg"].r[0])


@pytest.mark.slow
def test_walk_runs_without_divergence(walk):
    _, s = walk
    assert s["status"] == "ok" and s["steps"] == 19200 >= 17480
    for g in s["groups"].values():
        assert np.isfinite(g["max_deformation"])


def test_walk_advances_every_cycle(walk):
    _, s = walk
    cycles = s["report"]["cycles"]
    assert len(cycles) == 4
    advances = [c["advance"] for c in cycles]
    assert all(a > 0 for a in advances), advances
    foot = _foot_length(scenes.build("magpod-small"))
    assert sum(advances) >= 4 * foot, (advances, foot)


def test_walk_never_capsizes(walk):
    _, s = walk
    for ph in s["report"]["phases"]:
        assert ph["up_y"] > 0.5, ph       # the body's up axis never tilts past 60°


def test_footprints_at_stances_only(walk):
    """Sediment moved (more than 10 % of its radius) under every stance, and nowhere else.

    A sediment particle moves only when a leg particle touches it (Eq. 31: no other force), so
    "under a stance" is: its original (x, z) within r_leg + r_sed of a sole particle's (x, z)
    at a reported stance, or at the initial pose (the robot starts standing).
    """
    from scipy.spatial import cKDTree

    from rackstress.stress.measures import positions
    from rackstress.stress.rundata import load_run

    out, s = walk
    sc = scenes.build("magpod-small")
    sed = sc.slice("sediment")
    o = sc.original_positions()[sed]
    r_sed, r_leg = sc.groups["sediment"].r[0], sc.groups["rightleg"].r[0]
    run = load_run(out)
    steps = [int(x) for x in run.steps]
    run.trajectory[-1]
    moved = np.linalg.norm(positions(run.trajectory.ts)[sed] - o, axis=1) > 0.1 * r_sed
    stances = s["report"]["stances"]
    assert {st["leg"] for st in stances} == {"rightleg", "leftleg"}
    assert sum(st["pulling"] for st in stances) >= 8          # both feet, every cycle
    tree = cKDTree(o[:, [0, 2]])
    covered = np.zeros(len(o), dtype=bool)
    initial = [{"step": 0, "leg": leg} for leg in ("rightleg", "leftleg")]
    for st in initial + stances:
        run.trajectory[steps.index(st["step"])]
        q = positions(run.trajectory.ts)[sc.slice(st["leg"])]
        L = sc.groups[st["leg"]].o
        sole = q[L[:, 1] < L[:, 1].min() + 0.5]
        near = np.zeros(len(o), dtype=bool)
        for hits in tree.query_ball_point(sole[:, [0, 2]], r_leg + r_sed):
            near[hits] = True
        if st["step"] > 0:
            assert moved[near].any(), st                      # a print where the foot stood
        covered |= near
    assert moved.sum() > 50
    assert not moved[~covered].any(), o[moved & ~covered][:5]   # and none elsewhere
    depth = max(c["footprint_depth"] for c in s["report"]["cycles"])
    assert depth > 0.1 * r_sed


@pytest.mark.lammps
@pytest.mark.mpi
def test_parity_magpod_small_under_mpi(tmp_path, reference_final):
    """400 iterations through all four phases on two ranks: callbacks see only their rank's
    atoms (and ghosts), the contact test is reduced over ranks; positions stay at round-off."""
    from conftest import lammps_under_mpi

    p, counts = lammps_under_mpi(tmp_path, """
from rackstress import scenes
scenes_ = {"m": scenes.build("magpod-small", phase_steps=100, cycles=1)}
""")["m"]
    assert counts.min() > 0 and counts.sum() == scenes.build("magpod-small").n_particles
    sc = scenes.build("magpod-small", phase_steps=100, cycles=1)
    ref_p = reference_final(sc)
    assert np.abs(ref_p - sc.original_positions()).max() > 1.0
    assert np.abs(p - ref_p).max() <= 1e-10
