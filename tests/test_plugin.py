"""The compiled operator styles (lammps_inputs/plugin, docs/plugin.md) against the reference
engine: whole trajectories, serial and under ``mpiexec -n 2``, and standalone decks in the venv's
plain ``lmp``.

Expected values come from the independent path, the reference engine (the paper's equations in
NumPy); the plugin runs in real LAMMPS.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import HANG_S, dump_text, trajectory

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
    assert "python" not in hows and deck.passive == ("sediment",)
    # the ghosts cover a collision's reach, not a body: 2 r_max (sediment 2) + skin + 1, and
    # one more skin for activating resting sediment (r_p + r_u + 2 skins); skin 4 (passive)
    assert deck.lammps_skin == 4.0
    assert deck.ghost_cutoff == pytest.approx(2 * 2.0 + 4.0 + 1.0 + 4.0)
    text = deck.input_text()
    assert "atom_modify map array sort 0 0.0 first rs_move" in text
    assert "fix rs_nve rs_move rs/nve" in text and " activate rs_move" in text


def test_bind_ghost_cutoff_is_the_longest_bond_plus_half_a_skin():
    """rs/bind needs a partner as a ghost only when LAMMPS builds its bond list: the longest
    bond of a within(1.5) unit lattice is the face diagonal √2 (geometry), plus half the skin
    (2), not 2·L0 + skin + 1 = 5.83."""
    from rackstress.bench.scaling import block_scene

    deck = compile_deck(block_scene(6, 4, 4, 10), "exact", plugin=True)
    assert deck.ghost_cutoff == pytest.approx(np.sqrt(2.0) + 1.0)


@pytest.mark.parametrize("name,params", [("plane-rack", {"steps": 1200}),
                                         # 21 x 21 = 441 hosts, 4·110 + 1: the rack pass's
                                         # blocks of four rows and its last row alone
                                         ("plane-rack", {"steps": 600, "n": 21}),
                                         ("plane-bound", {"steps": 1200, "d": 2.0})])
def test_plugin_trajectory_parity_plane_scenes(name, params):
    """Rack coupling (Eq. 23) and within(d) binds on the plugin: the reference engine's
    trajectory to 1e-10."""
    scene = scenes.build(name, **params)
    ref = _reference_final(scene)
    assert np.abs(ref - scene.original_positions()).max() > 1.0      # it really moved
    assert np.abs(_plugin_final(scene) - ref).max() <= 1e-10


@pytest.mark.parametrize("name", ["cantilever", "plate-hole", "l-bracket"])
def test_plugin_trajectory_parity_validation_scenes(name):
    """The validation scenes (rack coupling and within(1.5) binds, WithinInside's pairs as
    bonds, held supports), 2000 steps: equal to the reference engine to 1e-10."""
    scene = scenes.build(name, steps=2000)
    ref = _reference_final(scene)
    moved = np.abs(ref - scene.original_positions()).max()
    assert moved > 1e-5
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


# ------------------------------------------------------------------ active particles only
def _plugin_state(scene, active_only):
    deck = compile_deck(scene, "exact", plugin=True, active_only=active_only)
    assert deck.plugin and (bool(deck.passive) == active_only)
    run = LammpsRun(deck, None)
    try:
        run.run_schedule()
        p, v = run.gather_positions(), run.gather_velocities()
        n, lmp = scene.n_particles, run.lmp
        mask = np.zeros(n, dtype=np.int64)    # by particle: LAMMPS keeps moving rows first
        mask[lmp.numpy.extract_atom("id")[:n] - 1] = lmp.numpy.extract_atom("mask")[:n]
        return p, v, (None if run._move_bit is None else (mask & run._move_bit) != 0)
    finally:
        run.close()


@pytest.mark.slow
def test_plugin_active_only_is_exact_over_a_gait_cycle():
    """rs/collide activating the resting sediment (fix nve on the moving group only) changes
    nothing: bit for bit against integrating every particle, and the reference engine to
    1e-10, over magpod-small's whole gait cycle."""
    sc = _gait_cycle()
    p, v, active = _plugin_state(sc, True)
    p_all, v_all, none = _plugin_state(sc, False)
    assert none is None
    np.testing.assert_array_equal(p, p_all)
    np.testing.assert_array_equal(v, v_all)
    sed = sc.slice("sediment")
    moved = np.abs(p[sed] - sc.original_positions()[sed]).max(axis=1) > 0
    assert moved.any() and active[sed].sum() < sc.groups["sediment"].n   # some, not all
    assert np.all(active[sed][moved])           # every sediment particle that moved was active
    assert np.all(active[:sed.start])           # the robot always is
    assert np.abs(p - _reference_final(sc)).max() <= 1e-10


def test_plugin_active_only_is_exact_when_touched_at_the_start():
    """Resting particles touched at step 0 are put among LAMMPS' integrated rows by the deck's
    second run 0, those reached later one reneighbouring early: bit for bit against
    integrating every particle, and the reference engine to 1e-10."""
    from test_lammps_backend import _bed_scene

    from rackstress.engines.reference import Reference

    sc = _bed_scene()
    p, v, active = _plugin_state(sc, True)
    p_all, v_all, _ = _plugin_state(sc, False)
    np.testing.assert_array_equal(p, p_all)
    np.testing.assert_array_equal(v, v_all)
    o, bed = sc.original_positions(), sc.slice("bed")
    moved = np.abs(p[bed] - o[bed]).max(axis=1) > 0
    d0 = np.linalg.norm(o[bed][:, None] - o[sc.slice("block")][None], axis=2).min(axis=1)
    touched0 = d0 < 1.0                         # overlapping at step 0 (R = 0.5 + 0.5)
    assert touched0.sum() == 4 and moved[touched0].all()
    assert moved.sum() > 3 * touched0.sum() and not active[bed].all()   # more later, not all
    ref = Reference(sc)
    drive(ref)
    assert np.abs(p - ref.p).max() <= 1e-10


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


# ------------------------------------------------------------------ standalone decks
def _frames(path: Path) -> list:
    """(timestep, ids, positions) of every frame of a ``id type mol x y z`` dump."""
    lines, out, k = dump_text(path).splitlines(), [], 0
    while k < len(lines):
        if lines[k] == "ITEM: TIMESTEP":
            n = int(lines[k + 3])
            rows = np.array([ln.split() for ln in lines[k + 9:k + 9 + n]], dtype=float)
            out.append((int(lines[k + 1]), rows[:, 0].astype(int), rows[:, 3:6]))
            k += 9 + n
        else:
            k += 1
    return out


def _same_to_dump_precision(ours: list, ref: list) -> None:
    """Every frame equal to the dump's precision: ``%.10g``, so two values rounded from the same
    number (to far better than that) differ by at most one unit of their 10th digit — of the
    value, or of 1 where it is smaller (a coordinate that is round-off off zero, such as a flat
    plane's z of 8e-6 after 120 steps, is compared at the precision of the scene's lengths).
    A deck with resting particles dumps only those that moved (docs/output.md): a particle a
    frame of ``ours`` leaves out stands where it stood at step 0, the reference's first frame
    (which holds every particle), and is compared there."""
    assert len(ours) == len(ref) and len(ref) > 2
    ids0, x0 = ref[0][1], ref[0][2]
    for (s1, i1, x1), (s2, i2, x2) in zip(ours, ref):
        assert s1 == s2 and np.array_equal(i2, ids0)
        rows = np.searchsorted(ids0, i1)
        assert np.array_equal(ids0[np.minimum(rows, len(ids0) - 1)], i1), f"step {s1}: ids"
        full = x0.copy()
        full[rows] = x1
        unit = 10.0 ** (np.floor(np.log10(np.maximum(np.abs(x2), 1.0))) - 9)
        assert np.all(np.abs(full - x2) <= unit * 1.000001), f"step {s1}"


def _cli(*args, cwd=None, timeout=900):
    proc = subprocess.run([str(BIN / "rackstress"), *args], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def _lmp(deck: Path, ranks: int):
    """The venv's plain ``lmp`` (it loads the plugin through the lammps.plugins entry point:
    no flag, no rackstress code in the run), serial or under ``mpiexec -n 2``."""
    cmd = [str(BIN / "lmp"), "-in", "in.lammps"]
    if ranks > 1:
        cmd = [str(BIN / "mpiexec"), "-n", str(ranks), *cmd]
    proc = subprocess.run(cmd, cwd=deck, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    return _frames(deck / "trajectory.dump")


@pytest.mark.slow
@pytest.mark.mpi
@pytest.mark.parametrize("scene,sets", [("plane-rack", []),
                                        ("magpod-small", ["phase_steps=100", "cycles=1"])])
def test_standalone_deck_runs_the_reference_trajectory(tmp_path, scene, sets):
    """``rackstress deck SCENE`` run by plain ``lmp -in in.lammps`` and ``mpiexec -n 2 lmp``
    writes the trajectory of ``rackstress run --engine reference``, frame by frame, to the
    dump's precision."""
    import shutil

    opts = [x for s in sets for x in ("--set", s)]
    _cli("run", scene, "--engine", "reference", "--out", str(tmp_path / "ref"), "--no-render",
         "--no-progress", *opts)
    ref = _frames(trajectory(tmp_path / "ref"))
    _cli("deck", scene, "--out", str(tmp_path / "deck1"), *opts)
    text = (tmp_path / "deck1" / "in.lammps").read_text()
    assert "rs/" in text and "external" not in text          # the plugin, no Python callback
    shutil.copytree(tmp_path / "deck1", tmp_path / "deck2")
    _same_to_dump_precision(_lmp(tmp_path / "deck1", 1), ref)
    _same_to_dump_precision(_lmp(tmp_path / "deck2", 2), ref)


@pytest.mark.mpi
def test_rs_nve_checks_displacements_as_lammps_does(tmp_path):
    """A plugin deck hands LAMMPS' displacement check to fix rs/nve (``neigh_modify ... check
    no once yes``; the check rides the plugin's reduction of the gathered positions). Against
    the same deck with LAMMPS' own check (``check yes``), serial and on 2 ranks: the same
    number of neighbour-list builds and the same positions to the bit (magpod-small, 1200
    steps: its legs move half a skin many times)."""
    _cli("deck", "magpod-small", "--out", str(tmp_path / "d"), "--set", "phase_steps=300",
         "--set", "cycles=1")
    text = (tmp_path / "d" / "in.lammps").read_text()
    assert "neigh_modify delay 0 every 1 check no once yes" in text
    text = text.replace(" pre no post no", " pre no post yes")       # LAMMPS' build counts
    text = "\n".join("#" + ln if ln.startswith(("dump", "undump")) else ln
                      for ln in text.splitlines())
    text += ("\nwrite_dump all custom final.dump id x y z modify sort id "
             "format float %.17g\n")
    variants = {"rs_nve": text,
                "lammps": text.replace("check no once yes", "check yes")}
    got = {}
    for name, body in variants.items():
        for ranks in (1, 2):
            d = tmp_path / f"{name}{ranks}"
            d.mkdir()
            (d / "in.lammps").write_text(body)
            (d / "particles.data").symlink_to(tmp_path / "d" / "particles.data")
            cmd = [str(BIN / "lmp"), "-in", "in.lammps", "-log", "log.lammps", "-screen", "none"]
            if ranks > 1:
                cmd = [str(BIN / "mpiexec"), "-n", str(ranks), *cmd]
            proc = subprocess.run(cmd, cwd=d, capture_output=True, text=True, timeout=HANG_S)
            assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
            log = (d / "log.lammps").read_text()
            builds = sum(int(n) for n in
                         re.findall(r"Neighbor list builds = (\d+)", log))
            got[name, ranks] = (builds, (d / "final.dump").read_bytes())
    for ranks in (1, 2):
        assert got["rs_nve", ranks][0] == got["lammps", ranks][0] > 10, got
        assert got["rs_nve", ranks][1] == got["lammps", ranks][1]


# ------------------------------------------------------------------ fallback
def test_without_a_compiler_the_callback_runs_and_says_why(tmp_path, monkeypatch, capsys):
    """No plugin built and no compiler: the deck is the Python callback's, and one line says
    why; a plugin built for another LAMMPS is not used."""
    from rackstress.engines.lammps import deck as deckmod

    monkeypatch.setattr(plugin, "PACKAGED", tmp_path / "none")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-compiler"))
    monkeypatch.setattr(plugin.shutil, "which", lambda name: None)
    monkeypatch.delenv("RACKSTRESS_KERNELS", raising=False)
    deckmod._WARNED.clear()
    deck = compile_deck(scenes.build("plane-rack"), "exact", plugin=None)
    assert not deck.plugin and deck.python_ops
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Python callback" in err[0]
    # a plugin whose build.json names another LAMMPS is stale
    other = tmp_path / "other"
    other.mkdir()
    (other / plugin.LIBRARY).write_bytes(b"")
    (other / plugin.STAMP).write_text('{"lammps": "2024.8.29.0.0"}')
    assert not plugin._usable(other, plugin.lammps_version())


def test_switched_off_runs_the_callback(tmp_path, monkeypatch, capsys):
    from rackstress.engines.lammps import deck as deckmod

    monkeypatch.setenv("RACKSTRESS_PLUGIN", "0")
    deckmod._WARNED.clear()
    assert not compile_deck(scenes.build("plane-rack"), "exact", plugin=None).plugin
    monkeypatch.setenv("RACKSTRESS_PLUGIN", "1")
    monkeypatch.setenv("RACKSTRESS_KERNELS", "numba")       # the callback asked for
    assert not compile_deck(scenes.build("plane-rack"), "exact", plugin=None).plugin
    monkeypatch.delenv("RACKSTRESS_KERNELS")
    assert compile_deck(scenes.build("plane-rack"), "exact", plugin=None).plugin
