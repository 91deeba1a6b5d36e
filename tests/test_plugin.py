"""The compiled operator styles (lammps_inputs/plugin, docs/plugin.md) against the reference
engine: whole trajectories, serial and under ``mpiexec -n 2``, and standalone decks in the venv's
plain ``lmp``.

Expected values come from the independent path, the reference engine (the paper's equations in
NumPy); the plugin runs in real LAMMPS.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rackstress import scenes
from rackstress.engines.driver import drive
from rackstress.engines.lammps import plugin
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import LammpsRun

BIN = Path(sys.executable).parent
pytestmark = pytest.mark.lammps


def _reference_final(scene):
    from conftest import reference_final   # computed once per scene (tests/conftest.py)

    return reference_final(scene)


def _gait_cycle():
    """magpod-small's whole gait cycle (four phases of 300 iterations): every plugin style —
    rack couplings, index-matched attraction following the phase, one-way and phase-conditioned
    collisions, contact-conditioned damping."""
    return scenes.build("magpod-small", phase_steps=300, cycles=1)


def _plugin_final(scene):
    deck = compile_deck(scene, "exact", plugin=True)
    assert deck.plugin and not deck.python_ops        # nothing left in the Python callback
    run = LammpsRun(deck, None)
    try:
        return drive(run).positions
    finally:
        run.close()


def test_the_plugin_is_built_for_this_lammps():
    lib, why = plugin.locate()
    assert lib is not None, why
    assert plugin.version_string("2025.7.22.4.0") == "22 Jul 2025"


def test_plugin_realizes_every_python_operator():
    deck = compile_deck(_gait_cycle(), "exact", plugin=True)
    hows = {r.how for r in deck.realized}
    assert {"rs/rack", "rs/attract", "rs/collide", "viscous+rs/dampen"} <= hows
    assert "python" not in hows and not deck.passive
    # the ghosts cover a collision's reach, not a body: 2 r_max (sediment 2) + skin 2 + 1
    assert deck.ghost_cutoff == pytest.approx(2 * 2.0 + 2.0 + 1.0)


@pytest.mark.parametrize("name,params", [("plane-rack", {"steps": 1200}),
                                         ("plane-bound", {"steps": 1200, "d": 2.0})])
def test_plugin_trajectory_parity_plane_scenes(name, params):
    scene = scenes.build(name, **params)
    ref = _reference_final(scene)
    assert np.abs(ref - scene.original_positions()).max() > 1.0      # it really moved
    assert np.abs(_plugin_final(scene) - ref).max() <= 1e-10


@pytest.mark.slow
def test_plugin_trajectory_parity_gait_cycle():
    """plugin = reference engine ≤ 1e-10 over magpod-small's whole gait cycle."""
    sc = _gait_cycle()
    ref = _reference_final(sc)
    p = _plugin_final(sc)
    sed = sc.slice("sediment")
    assert np.abs(ref[sed] - sc.original_positions()[sed]).max() > 0.01   # the soles landed
    assert np.abs(p - ref).max() <= 1e-10


@pytest.mark.slow
@pytest.mark.mpi
def test_plugin_trajectory_parity_under_mpi(tmp_path):
    """The same under ``mpiexec -n 2``: each rank its own atoms, racks and regions reduced."""
    from conftest import lammps_under_mpi

    runs = lammps_under_mpi(tmp_path, """
from rackstress import scenes
scenes_ = {"gait": scenes.build("magpod-small", phase_steps=300, cycles=1),
           "rack": scenes.build("plane-rack", steps=1200),
           "d2": scenes.build("plane-bound", steps=1200, d=2.0)}
""", timeout=1200, plugin=True)
    for key, scene in [("gait", _gait_cycle()), ("rack", scenes.build("plane-rack", steps=1200)),
                       ("d2", scenes.build("plane-bound", steps=1200, d=2.0))]:
        p, counts = runs[key]
        assert len(counts) == 2 and counts.min() > 0      # atoms really are split over both ranks
        assert np.abs(p - _reference_final(scene)).max() <= 1e-10
