"""Contact lists are renewed in time, each by the motion of its own particles.

A list first searched part-way through a LAMMPS layout (a second contact condition asked only
once the first holds; a collide gated on a contact) used to be renewed by displacement checks
measured from the layout's start, so a pair that closed in by more than a skin since the search
was missed. Each list is now renewed once one of its own particles has moved half its skin
since its search: a particle in no list must not renew it (nor make it miss anything), and a
moving particle of a resting group must. These scenes make exactly those cases happen (with a
resting bed, so LAMMPS' skin is the passive decks' wide one) and compare LAMMPS exact with the
reference engine.
"""
from __future__ import annotations

import numpy as np
import pytest

from rackstress import Collide, Const, Contact, Dampen, Force, Group, Phase, Scene, lattice
from rackstress.engines.driver import drive
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import LammpsRun
from rackstress.engines.reference import Reference
from conftest import HANG_S


def _bed():
    return Group("bed", lattice((3, 1, 3), 1.0, origin=(0.0, -40.0, 0.0)), 0.5, kind="leg")


def lazy_condition_scene(condition: bool = True) -> Scene:
    """a's extra damping needs contact with b *and* c: the (a, c) list is asked for only once
    a touches b (step ~95), while a's second particle and c close in by ~4 units a layout."""
    u, g = 2.0, 4.0 / 1.9
    a = Group("a", np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]), 0.5, kind="body",
              v0=[[-0.3 / 0.95, 0.0, 0.0], [0.0, -u, 0.0]])
    b = Group("b", np.array([[-1.3, 0.0, 0.0]]), 0.5, kind="body")
    c = Group("c", np.array([[10.0, 2.0, 0.0]]), 0.5, kind="body", v0=[[0.0, u, 0.0]])
    ops = {"a": [Force((0.0, g, 0.0), where=(False, True))]
           + [Dampen(0.0, extra=3.0, when=(Contact("b"), Contact("c")))] * condition,
           "c": [Force((0.0, -g, 0.0))],
           "bed": [Collide("a", Const(1.0)), Dampen(5.0)]}
    return Scene("lazy", {"a": a, "b": b, "c": c, "bed": _bed()}, ops, [Phase("go", 228, {})],
                 dt=0.01)


def gated_collide_scene(condition: bool = True) -> Scene:
    """a collides with c only while a touches b: the (a, c) list is first searched mid-layout."""
    u, g = 4.0, 16.0 / 7.6
    a = Group("a", np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]), 0.5, kind="body",
              v0=[[-0.3 / 1.9, 0.0, 0.0], [0.0, -u, 0.0]])
    b = Group("b", np.array([[-1.3, 0.0, 0.0]]), 0.5, kind="body")
    c = Group("c", np.array([[10.0, 4.0, 0.0]]), 0.5, kind="body", v0=[[0.0, u, 0.0]])
    ops = {"a": [Force((0.0, g, 0.0), where=(False, True))]
           + [Collide("c", Const(50.0), when=(Contact("b"),))] * condition,
           "c": [Force((0.0, -g, 0.0))],
           "bed": [Collide("a", Const(1.0)), Dampen(5.0)]}
    return Scene("gated", {"a": a, "b": b, "c": c, "bed": _bed()}, ops, [Phase("go", 455, {})],
                 dt=0.01)


def _reference(scene) -> np.ndarray:
    ref = Reference(scene)
    drive(ref)
    return ref.p


def _lammps(scene) -> np.ndarray:
    run = LammpsRun(compile_deck(scene, "exact"), None, log=False)
    try:
        drive(run)
        return run.gather_positions()
    finally:
        run.close()


@pytest.mark.lammps
@pytest.mark.parametrize("kernels", ["numpy", "numba"])
@pytest.mark.parametrize("build", [lazy_condition_scene, gated_collide_scene])
def test_a_list_first_asked_for_mid_layout_misses_no_contact(build, kernels, monkeypatch):
    monkeypatch.setenv("RACKSTRESS_KERNELS", kernels)
    sc = build()
    assert compile_deck(sc, "exact").passive == ("bed",)     # the wide LAMMPS skin
    ref = _reference(sc)
    # the conditional operator really acts (both contacts happen): without it a ends elsewhere
    assert np.abs(_reference(build(condition=False)) - ref).max() > 0.05
    assert np.abs(_lammps(sc) - ref).max() <= 1e-10


@pytest.mark.lammps
@pytest.mark.mpi
def test_a_list_first_asked_for_mid_layout_misses_no_contact_under_mpi(tmp_path):
    from conftest import lammps_under_mpi

    runs = lammps_under_mpi(tmp_path, """
from test_contact_lists import gated_collide_scene, lazy_condition_scene
scenes_ = {"gated": gated_collide_scene(), "lazy": lazy_condition_scene()}
""", timeout=HANG_S)
    for key, build in (("gated", gated_collide_scene), ("lazy", lazy_condition_scene)):
        p, counts = runs[key]
        assert np.abs(p - _reference(build())).max() <= 1e-10, key


class _Counting:
    """Compiled kernels that count the calls of one of them (a contact search)."""

    def __init__(self, k, name):
        self.k, self.name, self.calls = k, name, 0

    def __getattr__(self, name):
        if name == self.name:
            self.calls += 1
        return getattr(self.k, name)


def racing_rack_scene() -> Scene:
    """a and b close in at 4 units/time each from 7.05 apart, b's list searched at steps 0, 25,
    50, 75 (each has moved half a skin, 1, since the last search: d = 7.05, 5.05, 3.05, 1.05;
    reach + skin = 3), and touch (d < 1) at step 77, which a list renewed only after each has
    moved a whole skin (searched at d = 3.05, then at step 100) misses. A third particle in no
    contact list (a rack's role) flies at 30, so LAMMPS (skin 8) reneighbours every ~13 steps
    and a displacement check over every particle would renew the lists every ~4."""
    a = Group("a", np.array([[0.0, 0.0, 0.0]]), 0.5, kind="body", v0=[[4.0, 0.0, 0.0]])
    b = Group("b", np.array([[7.05, 0.0, 0.0]]), 0.5, kind="body", v0=[[-4.0, 0.0, 0.0]])
    rack = Group("rack", np.array([[0.0, 30.0, 0.0]]), 0.5, kind="rack", v0=[[30.0, 0.0, 0.0]])
    ops = {"a": [Collide("b", Const(50.0)), Dampen(0.0, extra=1.0, when=(Contact("b"),))],
           "b": [Collide("a", Const(20.0))],
           "bed": [Collide("a", Const(20.0)), Dampen(5.0)]}
    return Scene("racing-rack", {"a": a, "b": b, "rack": rack, "bed": _bed()}, ops,
                 [Phase("go", 110, {})], dt=0.01)


@pytest.mark.lammps
@pytest.mark.parametrize("kernels", ["numpy", "numba"])
def test_a_particle_in_no_list_renews_no_list(kernels, monkeypatch):
    """Each contact list is renewed by its own particles' motion only (skin 2: once one of
    them has moved 1, relative to the other group for two moving groups): the (a, b) list is
    searched once per 25 steps of their closing in, not every time the fast particle in no
    list has moved 1 (every ~4 steps), and the contact at step 77 is seen when it happens:
    equal to the reference engine to 1e-10."""
    from rackstress.engines.lammps import callback as cb

    monkeypatch.setenv("RACKSTRESS_KERNELS", kernels)
    # every list of the phase is searched (or kept) at each layout's first step, though the
    # (a, b) list kept from the layout before is there already: the (a, bed) list makes the
    # layout's activation search then
    frame, layouts = cb.PyForces._frame, []

    def checked(self, nlocal):
        fr = frame(self, nlocal)
        if not layouts or layouts[-1] is not fr:
            layouts.append(fr)
            missing = [AB for AB in self._phase_lists()
                       if ("cand", AB[0].start, AB[1].start) not in fr.memo]
            assert not missing, f"lists not searched at a layout's first step: {missing}"
        return fr
    monkeypatch.setattr(cb.PyForces, "_frame", checked)
    sc = racing_rack_scene()
    deck = compile_deck(sc, "exact")
    assert deck.passive == ("bed",) and deck.lammps_skin == 8.0 and deck.skin == 2.0
    run = LammpsRun(deck, None, log=False)
    try:
        pair = bed = None
        if kernels == "numba":      # the (a, b) list's searches and the resting bed's
            pair = run.py.overlaps.k = _Counting(run.py.overlaps.k, "candidates")
            bed = run.py.bed.k = _Counting(run.py.bed.k, "grid_candidates")
        drive(run)
        p = run.gather_positions()
    finally:
        run.close()
    ref = _reference(sc)
    # they touched and bounced (without the contact they would pass through each other:
    # gap 7.05 − 8·1.1 < 0 at the end)
    assert ref[1, 0] - ref[0, 0] > 0.0
    assert np.abs(p - ref).max() <= 1e-10
    assert len(layouts) >= 6
    if pair is not None:
        # measured: 4 and 8 (the bed's list also at each of LAMMPS' ~8 reneighbourings);
        # renewed whenever any particle has moved 1: 4 (kept by relative motion) and 32
        assert 4 <= pair.calls <= 6 and 4 <= bed.calls <= 12


def kicked_bed_scene() -> Scene:
    """A resting bed particle p overlaps a still kicker k at step 0 (so it is activated before
    the first step) and is pushed off towards a still particle s, 3.2 away (outside the (s,
    bed) list: reach + skin = 3); p reaches s (d < 1) after ~2.2 of travel, before it has
    moved 4 (LAMMPS' half skin): only p moves, so only a renewal of the list driven by the
    bed's moving particles (not by s, which stands still) sees the contact."""
    p0 = np.array([0.0, 0.0, 0.0])
    s = Group("s", np.array([p0 + [3.2, 0.0, 0.0]]), 0.5, kind="body")
    k = Group("k", np.array([p0 - [0.6, 0.0, 0.0]]), 0.5, kind="body")
    bed = Group("bed", np.array([p0, p0 + [0.0, -1.0, 0.0], p0 + [0.0, 0.0, -1.0]]), 0.5,
                kind="leg")
    # (the contact-conditioned dampings put the collisions in the callback's search)
    ops = {"s": [Collide("bed", Const(30.0)), Dampen(0.0, extra=1.0, when=(Contact("bed"),))],
           "k": [Dampen(0.0, extra=1.0, when=(Contact("bed"),))],
           "bed": [Collide("k", Const(40.0)), Collide("s", Const(30.0)), Dampen(0.1)]}
    return Scene("kicked-bed", {"s": s, "k": k, "bed": bed}, ops, [Phase("go", 120, {})],
                 dt=0.01)


@pytest.mark.lammps
@pytest.mark.parametrize("kernels", ["numpy", "numba"])
def test_a_moving_bed_particle_renews_its_list(kernels, monkeypatch):
    """A list against a resting group is renewed when one of the group's *moving* particles
    has moved half a skin, even though the searching group stands still: equal to the
    reference engine to 1e-10 (renewed only by s's motion or LAMMPS' reneighbouring, the
    contact is missed)."""
    monkeypatch.setenv("RACKSTRESS_KERNELS", kernels)
    sc = kicked_bed_scene()
    deck = compile_deck(sc, "exact")
    assert deck.passive == ("bed",) and deck.lammps_skin == 8.0 and deck.skin == 2.0
    o = sc.original_positions()
    first = Reference(sc)           # the contact p–s: when, and how far p has travelled
    for n in range(120):
        first.advance(1)
        if np.linalg.norm(first.p[2] - first.p[0]) < 1.0:
            break
    assert 2.05 < np.linalg.norm(first.p[2] - o[2]) < 4.0 and (first.p[0] == o[0]).all()
    ref = _reference(sc)
    assert np.linalg.norm(ref[0] - o[0]) > 0.01      # p pushed s
    assert np.abs(_lammps(sc) - ref).max() <= 1e-10


@pytest.mark.lammps
def test_a_diverging_run_keeps_the_resting_bed_grid_within_the_bed():
    """A run beyond its stability limit (magpod-small at t = 0.022, > the predicted 0.0194)
    flings leg particles thousands of units away before the watchdog stops it. The resting
    bed's grid is built round the searching sole, but never beyond the bed itself: it has at
    most as many cells as a grid over the bed's own bounding box (from the scene's geometry),
    grown by a cell a side (before, it grew with the flung particles to ~3e8 cells and
    gigabytes), and the run ends in the watchdog's DivergenceError."""
    from rackstress import scenes
    from rackstress.errors import DivergenceError

    sc = scenes.build("magpod-small", dt=0.022).with_steps(1000)
    run = LammpsRun(compile_deck(sc, "exact"), None, log=False)
    try:
        with pytest.raises(DivergenceError):
            drive(run)
        bed = run.py.bed
        o = sc.original_positions()[sc.slice("sediment")]
        extent = o.max(axis=0) - o.min(axis=0)
        grids = list(bed._grids.values())
        assert grids
        for lo, size, nc, *_ in grids:
            assert np.prod(nc) <= np.prod(np.floor(extent / size) + 3)
    finally:
        run.close()
