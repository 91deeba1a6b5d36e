"""MagPod in physical units (rackstress.stress.legs): the quasi-static leg solve, the inertia
relief, the scaling with the mapping, the maximum over the run. Expected values by hand."""
from __future__ import annotations

import numpy as np
import pytest

from rackstress.stress.legs import (LegLattice, PhysicalMapping, leg_stress, over_run, phase_at,
                                    relieve)
from rackstress.stress.tensor import to_output


def _bar(nx=12, nw=3, a=0.01):
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(nw), np.arange(nw), indexing="ij"),
                 -1).reshape(-1, 3) * a
    return g, LegLattice(g, a)


def test_free_bar_under_end_loads_carries_F_over_A_in_its_middle():
    """±F on the end layers of a free 12 × 3 × 3 bar (a = 10 mm): σ_xx = F/A in the middle,
    A = (3a)² = 9e-4 m², F = 90 N → 0.1 MPa; the other components ~0."""
    g, lat = _bar()
    F, a = 90.0, 0.01
    f = np.zeros_like(g)
    f[g[:, 0] == 0, 0] = -F / 9
    f[np.isclose(g[:, 0], 11 * a), 0] = F / 9
    u = lat.solve(f)
    s = to_output(lat.stress(u)) / 1e6
    mid = np.isclose(g[:, 0], 6 * a)
    assert s[mid, 0].mean() == pytest.approx(0.1, rel=0.01)
    assert np.abs(s[mid, 0] / 0.1 - 1).max() < 0.02          # uniform over the section
    assert np.abs(s[mid, 1:].mean(axis=0)).max() < 0.001 * 0.1   # the rest: zero in the mean
    # the bar stretches: ε = σ/E with E = 70 GPa over two spacings (hand: 2.86e-8 m); a
    # section only three particles across reads ~5 % stiff (measured 2.71e-8 m)
    stretch = (u[np.isclose(g[:, 0], 7 * a), 0].mean() - u[np.isclose(g[:, 0], 5 * a), 0].mean())
    assert stretch == pytest.approx(0.1e6 / 70e9 * 2 * a, rel=0.07)
    # the rigid part is removed: no net translation of the solution
    assert np.abs(u.mean(axis=0)).max() < 1e-6 * np.abs(u).max()


def test_a_load_with_a_resultant_is_relieved_to_zero_force_and_moment():
    """A single 10 N sideways push at one end of the bar: relieved by the bar's rigid
    acceleration A = F/M (hand) and its angular acceleration, the result has zero resultant
    and zero moment, and the pinned unknowns then carry no reaction."""
    g, lat = _bar()
    f = np.zeros_like(g)
    f[0] = (0.0, 10.0, 0.0)
    fr, A, alpha = relieve(g, f, lat.m)
    M = lat.m * len(g)
    assert A == pytest.approx([0.0, 10.0 / M, 0.0])
    assert np.abs(fr.sum(axis=0)).max() < 1e-12
    c = g.mean(axis=0)
    assert np.abs(np.cross(g - c, fr).sum(axis=0)).max() < 1e-12
    assert alpha[2] != 0.0                        # the push off the centre turns the bar
    u = lat.solve(fr)
    assert np.abs(lat.reactions(u, fr)).max() < 1e-9 * np.abs(fr).max()


def test_the_mapping_states_its_scales():
    """g/50 m/s² a paper acceleration; t = √(L/accel) s a paper time; 2700·(2L)³ kg a
    particle (L = 5 mm: 0.1962, 0.1596 s, 2.7 g) — by hand."""
    m = PhysicalMapping(unit_length=0.005)
    assert m.accel == pytest.approx(9.81 / 50)
    assert m.time == pytest.approx((0.005 / (9.81 / 50)) ** 0.5)
    assert m.particle_mass == pytest.approx(2700 * 0.01 ** 3)


def _magpod_frames(steps=40, every=20, phase_steps=20):
    from rackstress.engines.reference import Reference
    from rackstress.scenes import build

    sc = build("magpod-physical-small", phase_steps=phase_steps, sediment_nx=20,
               sediment_nz=20)
    ref = Reference(sc)
    frames = [(0, ref.p.copy())]
    n = 0
    for _, ph, _ in sc.schedule():
        for _ in range(ph.steps):
            ref.step(ph.vars)
            n += 1
            if n % every == 0:
                frames.append((n, ref.p.copy()))
            if n >= steps:
                return sc, frames
    return sc, frames


def test_leg_stress_scales_linearly_with_the_acceleration_scale():
    """Doubling g doubles every force in newtons and so every stress (linear elasticity);
    doubling the length a paper unit doubles every stress too; the peak is the largest of the
    per-frame values, at its frame."""
    sc, frames = _magpod_frames()
    one = leg_stress(sc, frames, PhysicalMapping(unit_length=0.005, g=9.81),
                     paper_at_peak=False)
    two = leg_stress(sc, frames, PhysicalMapping(unit_length=0.005, g=2 * 9.81),
                     paper_at_peak=False)
    assert one.von_mises.shape == (len(frames), 764)
    assert np.nanmax(one.von_mises) > 0
    np.testing.assert_allclose(two.von_mises, 2 * one.von_mises, rtol=1e-4,
                               atol=1e-6 * float(np.nanmax(one.von_mises)))
    # twice the length a paper unit: masses 8×, sections 4×, so every stress 2× (hand)
    big = leg_stress(sc, frames, PhysicalMapping(unit_length=0.01, g=9.81),
                     paper_at_peak=False)
    np.testing.assert_allclose(big.von_mises, 2 * one.von_mises, rtol=1e-4,
                               atol=1e-6 * float(np.nanmax(one.von_mises)))
    top = one.von_mises.max()
    assert one.peak["von_mises_mpa"] == pytest.approx(float(top))
    assert one.peak["step"] == frames[int(np.argmax(one.von_mises.max(axis=1)))][0]


def test_max_over_run_is_the_largest_frame_value_and_names_its_frame():
    vm = np.array([[1.0, 5.0, 2.0], [3.0, 4.0, 2.5], [0.5, 6.0, 1.0]], np.float32)
    top, k = over_run(vm)
    assert top.tolist() == [3.0, 6.0, 2.5]
    assert k.tolist() == [1, 2, 1]


def test_phase_at_names_the_phase_whose_iterations_follow_the_step():
    from rackstress.scenes import build

    sc = build("magpod-physical-small", phase_steps=10)
    assert phase_at(sc, 0) == {"r": 4, "l": 6}
    assert phase_at(sc, 9) == {"r": 4, "l": 6}
    assert phase_at(sc, 10) == {"r": 1, "l": 7}
    assert phase_at(sc, 40) == {"r": 3, "l": 5}        # the last step: the last phase


def test_a_run_writes_the_legs_stress_beside_the_dump(tmp_path):
    """``rackstress run magpod-physical-small`` (reference engine, a short walk): the float32
    file holds frames × 764 values; the JSON's per-particle maximum over the run is the
    largest of the file's frames, at the frame and iteration it names; the peak is the
    largest of all."""
    import json

    from click.testing import CliRunner

    from rackstress.cli import main

    out = tmp_path / "mps"
    r = CliRunner().invoke(main, ["run", "magpod-physical-small", "--engine", "reference",
                                  "--set", "phase_steps=10", "--set", "sediment_nx=20",
                                  "--set", "sediment_nz=20", "--dump-every", "5",
                                  "--no-render", "--no-progress", "--out", str(out)],
                           catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "legs in physical units" in r.output
    rec = json.loads((out / "legs_physical.json").read_text())
    vm = np.fromfile(out / "legs_von_mises.f32", "<f4").reshape(rec["shape"])
    assert vm.shape == (len(rec["steps"]), 764) == (9, 764)     # steps 0, 5, …, 40
    top = np.asarray(rec["max_per_particle_mpa"])
    k = np.asarray(rec["max_frame"])
    np.testing.assert_array_equal(top, vm.max(axis=0))
    np.testing.assert_array_equal(vm[k, np.arange(764)], vm.max(axis=0))
    assert rec["max_step"] == [rec["steps"][i] for i in k]
    assert rec["peak"]["von_mises_mpa"] == pytest.approx(float(vm.max()))
    assert rec["peak"]["step"] == rec["steps"][int(np.argmax(vm.max(axis=1)))]


@pytest.mark.parametrize("plain,physical", [("magpod-small", "magpod-physical-small"),
                                            ("magpod", "magpod-physical")])
def test_the_physical_scene_walks_as_its_plain_walk_to_the_bit(plain, physical):
    """magpod-physical-small is magpod-small's scene (groups, operators, phases, dt) under
    another name, and magpod-physical the paper's magpod's: 20 reference-engine steps give the
    same positions exactly."""
    from rackstress.engines.reference import Reference
    from rackstress.scenes import build

    kw = dict(phase_steps=10, sediment_nx=20, sediment_nz=20)
    a, b = build(plain, **kw), build(physical, **kw)
    assert b.name == physical and b.params["physical"] is True
    assert a.operators == b.operators and a.phases == b.phases and a.dt == b.dt
    np.testing.assert_array_equal(a.original_positions(), b.original_positions())
    ra, rb = Reference(a), Reference(b)
    for _, ph, _ in a.schedule():
        for _ in range(ph.steps):
            ra.step(ph.vars)
            rb.step(ph.vars)
        if ra.step_count >= 20:
            break
    np.testing.assert_array_equal(ra.p, rb.p)
