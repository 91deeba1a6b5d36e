"""Validity: FEA references against analytical solutions, the measures on known deformations,
and the validity pipeline on tiny bodies."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rackstress.scenes import validation as cases
from rackstress.validity import compare, fea


def test_cantilever_fea_matches_euler_bernoulli_and_timoshenko():
    L, h, P, E, nu = 20.0, 1.0, 1e-3, 1.0, 0.3
    r = fea.cantilever(L, h, P, density=4, E=E, nu=nu)
    I = h ** 3 / 12
    bending = P * L ** 3 / (3 * E * I)                    # PL³/3EI
    shear = P * L / (5 / 6 * E / (2 * (1 + nu)) * h)      # Timoshenko, κ = 5/6
    tip = -r.at(np.array([[L, h / 2]]))["uy"][0]
    assert tip == pytest.approx(bending + shear, rel=0.01)
    # bending stress at mid-span, top and bottom fibres: ±M c / I = ±6 P (L/2) / h²
    s = r.at(np.array([[L / 2, h], [L / 2, 0.0]]))["sxx"]
    assert s[0] == pytest.approx(6 * P * (L / 2) / h ** 2, rel=0.01)
    assert s[1] == pytest.approx(-6 * P * (L / 2) / h ** 2, rel=0.01)


def test_plate_with_hole_fea_matches_kirsch():
    a, W, sigma = 1.0, 40.0, 1.0            # a wide plate: Kirsch's infinite one within 1 %
    r = fea.plate_with_hole(a, W, sigma, density=8)
    v = r.at(np.array([[0.0, a], [a, 0.0], [0.0, 2 * a], [0.0, -a], [-a, 0.0]]))
    assert v["sxx"][0] == pytest.approx(3 * sigma, rel=0.01)     # the factor 3, across the load
    assert v["sxx"][3] == pytest.approx(3 * sigma, rel=0.01)     # mirrored side
    assert v["syy"][1] == pytest.approx(-sigma, rel=0.01)        # along the load: −σ
    assert v["syy"][4] == pytest.approx(-sigma, rel=0.01)
    # σ_xx on the section x = 0 at r = 2a: σ(1 + a²/2r² + 3a⁴/2r⁴)
    assert v["sxx"][2] == pytest.approx(sigma * (1 + 1 / 8 + 3 / 32), rel=0.01)


def test_l_bracket_fea_converges_at_the_particle_positions():
    sc = cases.l_bracket(body="bind", w=4, H=12, lx=10)
    solver, kw, to_fea = compare.fea_case(sc)
    pts = to_fea(sc.groups["body"].o[cases.free_mask(sc)])
    study = fea.refinement_study(solver, pts, (2, 4, 8), **kw)
    assert study["change"] <= fea.CONVERGED
    # the peak is at the re-entrant corner's nearest particle (0.71 spacings from it)
    vm = study["result"].at(pts)["von_mises_stress"]
    corner = np.array(kw and (kw["w"], kw["H"] - kw["w"]))
    assert np.linalg.norm(pts[np.argmax(vm)] - corner) == pytest.approx(math.sqrt(0.5))


def test_affine_fit_on_a_uniform_stretch_and_a_rigid_motion():
    i, j = np.meshgrid(np.arange(6.0), np.arange(5.0), indexing="ij")
    o = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1)
    e = 0.01
    p = o * np.array([1 + e, 1.0, 1.0])
    eta, d2 = compare.affine_fit(o, p)
    Exx = ((1 + e) ** 2 - 1) / 2                         # Green–Lagrange
    assert np.allclose(eta, Exx / math.sqrt(3), rtol=1e-10)   # √((Exx² + Exx²)/6)
    assert np.allclose(d2, 0.0, atol=1e-20)
    c, s = math.cos(0.3), math.sin(0.3)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    eta, d2 = compare.affine_fit(o, o @ R.T + 2.0)
    assert np.allclose(eta, 0.0, atol=1e-12) and np.allclose(d2, 0.0, atol=1e-20)


def test_agreement_figures_by_hand():
    x = np.stack([np.arange(40.0), np.zeros(40)], axis=1)
    ref = np.arange(40.0)
    same = compare.agreement(ref ** 2, ref, x)              # monotone: ρ = 1, same top 2
    assert same["spearman"] == pytest.approx(1.0)
    assert same["k"] == 2 and same["top5_overlap"] == 1.0 and same["max_distance"] == 0.0
    rev = compare.agreement(-ref, ref, x)
    assert rev["spearman"] == pytest.approx(-1.0)
    assert rev["top5_overlap"] == 0.0 and rev["max_distance"] == 39.0


def test_clamp_is_held_and_loads_sum_to_the_fea_load():
    sc = cases.cantilever(body="rack+bind", nx=8, ny=3, steps=200)
    p, info = compare.equilibrate(sc, max_steps=200)
    body = sc.groups["body"]
    held = ~cases.free_mask(sc)
    assert held.sum() == 2 * 3                                # n_clamp columns × ny
    assert np.array_equal(p[sc.slice("body")][held], body.o[held])   # held exactly
    assert np.abs(p[sc.slice("body")][~held] - body.o[~held]).max() > 1e-6   # the rest moved
    f = sc.operators["body"][0]
    total = np.asarray(f.accel) * sum(f.where)
    assert total[1] == pytest.approx(-sc.params["load"])
    ph = cases.plate_hole(n=5, a=2.0, sigma=0.1)
    forces = [op for op in ph.operators["body"] if type(op).__name__ == "Force"]
    assert sum(np.asarray(op.accel) * sum(op.where) for op in forces)[0] == pytest.approx(0.0)
    assert sum(forces[0].where) == 2 * 5 + 1                 # one edge column: σ·(2W)


@pytest.mark.slow
@pytest.mark.lammps
def test_validity_pipeline_on_tiny_bodies(tmp_path):
    from rackstress.bench import validity as bench

    row, ref = bench.run_case("cantilever", "bind", quick=True, echo=lambda *a: None)
    assert ref["converged"]
    # a lattice bound to its 8 neighbours is a discretized elastic sheet: its strain ranks
    # like the continuum's
    a = row["agreement"]["strain"]
    assert a["spearman"] >= 0.8 and a["max_distance"] <= 2.0
    rack_row, _ = bench.run_case("cantilever", "rack", quick=True, fea_ref=ref,
                                 echo=lambda *a: None)
    assert rack_row["agreement"]["paper"]["n"] == a["n"]


@pytest.mark.slow
@pytest.mark.lammps
def test_bench_validity_cli_quick(tmp_path):
    import json

    from click.testing import CliRunner

    from rackstress.cli import main

    res = CliRunner().invoke(main, ["bench", "validity", "--quick", "--out", str(tmp_path)],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "validity.json").read_text())
    assert {(r["case"], r["body"]) for r in data["results"]} == {
        (c, b) for c in ("cantilever", "plate-hole", "l-bracket")
        for b in ("rack", "rack+bind", "rack(1)+bind", "bind", "bind-inside")}
    # LAMMPS repeats the reference engine's runs (round-off apart) and records its virial
    assert all(r["equilibrium"]["vs_reference"] < 1e-10 for r in data["results"])
    assert all(np.isfinite(r["agreement"]["lammps_virial"]["spearman"])
               for r in data["results"] if r["body"] in ("bind", "bind-inside"))
    assert all(s["converged"] for s in data["fea"].values())
    assert (tmp_path / "validity.png").stat().st_size > 10000
    assert "Spearman" in (tmp_path / "validity.md").read_text()
    # the planar cases in absolute terms: FEA's peak is the largest σ_vm at the particles
    for r in data["results"]:
        if r["body"] == "bind-inside" and r["case"] != "l-bracket":
            fea_vm = data["fea"][r["case"]]["fields"]["von_mises_stress"]
            assert r["absolute"]["fea"] == pytest.approx(max(fea_vm), rel=1e-12)
            assert r["absolute"]["ratio"] == pytest.approx(
                r["absolute"]["particles"] / r["absolute"]["fea"], rel=1e-12)
    assert "Peak von Mises stress in absolute terms" in (tmp_path / "validity.md").read_text()
