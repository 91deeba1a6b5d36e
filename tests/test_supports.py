"""Supports (``Group.held``) and initial velocities (``Group.v0``) on both engines.

Expected values by hand: under a constant acceleration a from v0, Eq. 5 (v += t·a; p += t·v)
gives v_n = v0 + n·t·a and p_n = o + n·t·v0 + t²·a·n(n+1)/2; a held particle stays at o with
v = 0 whatever acts on it. Parity: LAMMPS exact mode against the reference engine.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from rackstress.engines.lammps.deck import compile_deck, id_ranges, support_commands
from rackstress.engines.lammps.runner import LammpsRun
from rackstress.engines.reference import Reference
from rackstress.errors import SceneError
from rackstress.model.operators import Bind, Collide, Const, Contact, Dampen, Force, Within
from rackstress.model.particles import Group, lattice
from rackstress.model.scene import Phase, Scene
from conftest import HANG_S

MPIEXEC = Path(sys.executable).with_name("mpiexec")


def free_flight_scene(steps=50):
    """Three particles far apart under a = (0, −2, 1): the first held, the others from v0."""
    o = np.array([[0.0, 0, 0], [10, 0, 0], [20, 0, 0]])
    g = Group("g", o, 0.5, held=np.array([True, False, False]),
              v0=[[9.0, 9.0, 9.0], [1.0, 0.5, 0.0], [0.0, 0.0, -3.0]])
    return Scene("flight", {"g": g}, {"g": [Force((0.0, -2.0, 1.0))]}, [Phase("run", steps)],
                 dt=0.01)


def expected_flight(sc, n):
    t, a = sc.dt, np.array([0.0, -2.0, 1.0])
    v0 = np.array([[0.0, 0, 0], [1.0, 0.5, 0.0], [0.0, 0.0, -3.0]])   # the held one: v0 = 0
    p = sc.original_positions() + n * t * v0 + t * t * a * n * (n + 1) / 2
    v = v0 + n * t * a
    p[0], v[0] = sc.original_positions()[0], 0.0
    return p, v


def impact_scene(steps=120, phases=1):
    """A beam held at one end, bound within 1.5, struck by a block thrown at it (v0), both
    colliding both ways, gravity, contact-conditioned damping: every path of both engines."""
    beam_o = lattice((8, 2, 2), 1.0)
    beam = Group("beam", beam_o, 0.5, held=beam_o[:, 0] < 0.5)
    block = Group("block", lattice((2, 2, 2), 1.0, (5.0, 3.2, 0.0)), 0.5, v0=[0.3, -2.0, 0.0])
    ops = {"beam": [Bind("beam", Within(1.5, 50.0)), Collide("block", Const(100.0)),
                    Force((0, -1.0, 0)), Dampen(0.5)],
           "block": [Bind("block", Within(1.8, 50.0)), Collide("beam", Const(100.0)),
                     Force((0, -1.0, 0)), Dampen(0.5, extra=2.0, when=(Contact("beam"),))]}
    ph = [Phase(f"p{k}", steps // phases) for k in range(phases)]
    return Scene("impact", {"beam": beam, "block": block}, ops, ph, dt=0.01)


def run_reference(sc):
    ref = Reference(sc)
    for _, phase, _ in sc.schedule():
        for _ in range(phase.steps):
            ref.step(phase.vars)
    return ref


def run_lammps(sc):
    run = LammpsRun(compile_deck(sc), None)
    try:
        run.run_schedule()
        return run.gather_positions(), run.gather_velocities()
    finally:
        run.close()


def test_group_fields_default_and_check():
    g = Group("g", lattice((3, 1, 1)), 0.5)
    assert g.held.tolist() == [False] * 3 and (g.v0 == 0).all() and g.v0.shape == (3, 3)
    g = Group("g", lattice((3, 1, 1)), 0.5, held=np.array([False, True, False]), v0=[1.0, 2, 3])
    assert g.v0.tolist() == [[1, 2, 3], [0, 0, 0], [1, 2, 3]]   # a held particle starts at rest
    with pytest.raises(SceneError, match="held must be 3 booleans"):
        Group("g", lattice((3, 1, 1)), 0.5, held=[1, 0])
    with pytest.raises(SceneError, match="v0 must be three finite numbers"):
        Group("g", lattice((3, 1, 1)), 0.5, v0=[1.0, float("nan"), 0])


def test_reference_free_flight_by_hand():
    sc = free_flight_scene()
    ref = Reference(sc)
    np.testing.assert_array_equal(ref.v[1:], [[1.0, 0.5, 0.0], [0.0, 0.0, -3.0]])  # v at step 0
    for n in range(1, 51):
        ref.step({})
        p, v = expected_flight(sc, n)
        np.testing.assert_allclose(ref.p, p, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ref.v, v, rtol=0, atol=1e-12)
    assert (ref.p[0] == sc.original_positions()[0]).all() and (ref.v[0] == 0).all()


@pytest.mark.lammps
def test_lammps_free_flight_by_hand():
    sc = free_flight_scene()
    p_l, v_l = run_lammps(sc)
    p, v = expected_flight(sc, 50)
    np.testing.assert_allclose(p_l, p, rtol=0, atol=1e-12)
    # LAMMPS holds v + t/2·a after the last step (fix nve's half step); the paper's v is v − t/2·a
    np.testing.assert_allclose(v_l[1:] - 0.005 * np.array([0.0, -2.0, 1.0]), v[1:], atol=1e-12)
    assert (p_l[0] == sc.original_positions()[0]).all() and (v_l[0] == 0).all()


@pytest.mark.lammps
@pytest.mark.parametrize("phases", [1, 3])
def test_impact_parity_reference_vs_lammps(phases):
    sc = impact_scene(phases=phases)
    ref = run_reference(sc)
    p_l, v_l = run_lammps(sc)
    held = sc.held()
    assert held.sum() == 4
    assert np.abs(ref.p - sc.original_positions()).max() > 0.5          # the block really hit
    assert (ref.p[held] == sc.original_positions()[held]).all()          # held: never moved
    assert (p_l[held] == sc.original_positions()[held]).all()
    assert (v_l[held] == 0).all() and (ref.v[held] == 0).all()           # and at rest
    assert np.abs(p_l - ref.p).max() <= 1e-8


def test_deck_support_commands():
    assert id_ranges([1, 2, 3, 4, 7, 9, 10]) == "1:4 7 9:10"
    sc = impact_scene()
    cmds, nve = support_commands(sc)
    assert nve == "rs_free"
    assert cmds[0] == "group rs_held id 1 9 17 25"        # x = 0 of an 8×2×2 beam, x fastest
    assert "fix rs_hold rs_held setforce 0.0 0.0 0.0" in cmds
    assert "velocity rs_v0 set 0.3 -2.0 0.0 units box" in cmds
    assert "group rs_v0 id 33:40" in cmds
    deck = compile_deck(sc)
    assert "fix rs_nve rs_free nve" in deck.setup_commands()
    assert all("gmask(rs_free)" in v for v in deck.velocity_variables())
    # a scene with neither: nothing added, fix nve on all (the committed decks stay as they are)
    plain = Scene("p", {"g": Group("g", lattice((2, 1, 1)), 0.5)}, {}, [Phase("r", 1)])
    assert support_commands(plain) == ([], "all")


@pytest.mark.lammps
@pytest.mark.mpi
def test_impact_parity_under_mpi(tmp_path):
    from conftest import lammps_under_mpi

    p, counts = lammps_under_mpi(tmp_path, """
from test_supports import impact_scene
scenes_ = {"impact": impact_scene(phases=3)}
""", timeout=HANG_S)["impact"]
    assert counts.min() > 0                               # both ranks hold atoms
    sc = impact_scene(phases=3)
    ref = run_reference(sc)
    assert (p[sc.held()] == sc.original_positions()[sc.held()]).all()
    assert np.abs(p - ref.p).max() <= 1e-8
