"""Contact lists that a phase uses only now and then are as old as the frame they serve.

A list first searched part-way through a LAMMPS layout (a second contact condition asked only
once the first holds; a collide gated on a contact) used to be renewed by displacement checks
measured from the layout's start, so a pair that closed in by more than a skin since the search
was missed. These scenes make exactly that happen (with a resting bed, so LAMMPS' skin is the
passive decks' wide one) and compare LAMMPS exact with the reference engine.
"""
from __future__ import annotations

import numpy as np
import pytest

from rackstress import Collide, Const, Contact, Dampen, Force, Group, Phase, Scene, lattice
from rackstress.engines.driver import drive
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import LammpsRun
from rackstress.engines.reference import Reference


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
""", timeout=600)
    for key, build in (("gated", gated_collide_scene), ("lazy", lazy_condition_scene)):
        p, counts = runs[key]
        assert np.abs(p - _reference(build())).max() <= 1e-10, key
