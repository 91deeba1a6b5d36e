"""Stress per particle in the scene's units: expected values from hand
calculation and analytical fields — a pulled pair, uniform tension σ = F/A, pure bending M·z/I."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rackstress.model.materials import material
from rackstress.model.operators import Bind, Const, Dampen, Force, Within
from rackstress.model.particles import Group
from rackstress.model.scene import Phase, Scene
from rackstress.model.stability import predict
from rackstress.model.units import SYSTEMS
from rackstress.runs.run import run
from rackstress.stress import load_run
from rackstress.stress import tensor as T
from rackstress.stress.measures import ParticleStress
from rackstress.stress.post import STRAIN_LIMIT, postprocess
from conftest import HANG_S

MM = SYSTEMS["mm-N-s"]
AL = material("aluminium")                         # E 70 GPa, ν 0.33, 2700 kg/m³, yield 276 MPa
RHO = 2.7e-9                                       # t/mm³, by hand from 2700 kg/m³
YIELD = 276.0                                      # MPa


def _scene(name, o, loads, c, damping, steps, held=None, mat=AL, volume=1.0):
    """One aluminium part at spacing 1 mm (volume 1 mm³ a particle, mass ρV) with hand-chosen
    bind coefficient c; loads: [(mask, force in N per particle)], turned into accelerations."""
    m = RHO * volume
    g = Group("part", o, 0.5, material=mat, volume=volume, held=held)
    ops = [Force(tuple(float(x) / m for x in f), where=tuple(bool(b) for b in mask))
           for mask, f in loads]
    ops += [Bind("part", Within(1.5, c)), Dampen(damping)]
    sc = Scene(name, {"part": g}, {"part": ops}, [Phase("load", steps)], dt=1.0, units=MM)
    dt = 0.5 * predict(sc)["t_max"]
    return Scene(name, {"part": g}, {"part": ops}, [Phase("load", steps)], dt=dt, units=MM)


def _pair(F, c, tmp_path, mat=AL, engine="reference"):
    """Particle 1 pulled along +x by F [N], bound to particle 0 (held) 1 mm away."""
    o = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    omega = np.sqrt(2 * c)                          # the pair's stiffness 2mc over its mass m
    sc = _scene("pair", o, [([False, True], (F, 0.0, 0.0))], c, 2.0 * omega, 400,
                held=np.array([True, False]), mat=mat)
    out = tmp_path / "pair"
    run(sc, out, engine=engine, progress=False, dump_every=100)
    return out, RHO * 1.0


def _pair_by_hand(F, m, c, L0=1.0):
    """Equilibrium of Eq. 12: F = m·c·(d − L0²/d) → d; the virial stress ½·d·F / V (V = 1)."""
    q = F / (m * c)
    d = 0.5 * (q + np.sqrt(q * q + 4 * L0 * L0))
    return d, 0.5 * d * F


def test_pulled_pair_by_hand(tmp_path):
    F, c = 1.0, 1.0e10                              # 1 N; strain ≈ F/(2mc) ≈ 1.9 %
    out, m = _pair(F, c, tmp_path)
    d, sigma = _pair_by_hand(F, m, c)
    info = postprocess(out)
    s = ParticleStress(load_run(out)).run().results
    last = -1
    # both ends carry ½·d·F: the held end through its own binding to the pulled one
    np.testing.assert_allclose(s.stress[last][:, 0], [sigma, sigma], rtol=1e-6)
    np.testing.assert_allclose(s.stress[last][:, 1:], 0.0, atol=1e-9 * sigma)
    np.testing.assert_allclose(s.von_mises[last], [sigma, sigma], rtol=1e-6)
    np.testing.assert_allclose(s.principal[last], [[sigma, 0, 0]] * 2, rtol=1e-6,
                               atol=1e-9 * sigma)
    np.testing.assert_allclose(s.safety[last], YIELD / sigma, rtol=1e-6)
    np.testing.assert_allclose(s.bind_strain[last], d - 1.0, rtol=1e-6)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stress"]["default_measure"] == "von_mises"
    assert summary["stress"]["peak"]["measure"] == "von_mises"
    assert summary["stress"]["peak"]["units"] == "MPa"
    assert summary["groups"]["part"]["peak"]["von_mises"]["value"] >= sigma * (1 - 1e-6)
    assert summary["stress"]["safety"]["part"]["min"] <= YIELD / sigma * (1 + 1e-6)
    assert info["warnings"] == [] and summary["warnings"] == []
    scene = json.loads((out / "scene.json").read_text())
    assert scene["units"]["stress"] == "MPa"
    assert scene["groups"][0]["material"]["E"] == pytest.approx(70000.0)
    assert scene["groups"][0]["mass"] == pytest.approx(RHO)


def test_warnings_large_strain_and_yield(tmp_path):
    weak = material({"E": 70e9, "nu": 0.33, "density": 2700.0, "yield": 10e6, "name": "weak"})
    F, c = 4.0, 1.0e10                              # strain ≈ 7 %, σ ≈ 2.1 MPa at rest
    out, m = _pair(F, c, tmp_path, mat=weak)
    d, sigma = _pair_by_hand(F, m, c)
    assert d - 1 > STRAIN_LIMIT
    postprocess(out)
    summary = json.loads((out / "summary.json").read_text())
    kinds = {w["kind"]: w for w in summary["warnings"]}
    big = kinds["large_strain"]
    assert big["group"] == "part" and big["value"] >= (d - 1) * (1 - 1e-6)
    assert "small-strain" in big["message"] and "part 'part'" in big["message"]
    assert "yield_exceeded" not in kinds            # σ ≈ 2.2 MPa, below the 10 MPa yield
    low = material({"E": 70e9, "nu": 0.33, "density": 2700.0, "yield": sigma / 2 * 1e6,
                    "name": "soft"})        # SI: Pa
    (tmp_path / "b").mkdir()
    out2, _ = _pair(F, c, tmp_path / "b", mat=low)
    postprocess(out2)
    summary = json.loads((out2 / "summary.json").read_text())
    y = {w["kind"]: w for w in summary["warnings"]}["yield_exceeded"]
    assert y["group"] == "part" and y["yield"] == pytest.approx(sigma / 2)
    assert y["value"] >= sigma * (1 - 1e-6) and y["units"] == "MPa"
    assert f"iteration {y['iteration']}" in y["message"] and "soft" in y["message"]
    from rackstress.render.report import write_report

    html = write_report(out2).read_text()
    assert 'data-kind="yield_exceeded"' in html and 'data-kind="large_strain"' in html


def _bar(nx, ny, nz):
    o = np.mgrid[0:nx, 0:ny, 0:nz].reshape(3, -1).T.astype(float)
    o[:, 1] -= (ny - 1) / 2
    o[:, 2] -= (nz - 1) / 2
    return o


def _c(m=RHO):
    """c from E on the simple cubic lattice: E = 2.5·k/a with k = 2·m·c (docs/stress.md)."""
    return 70000.0 / (5.0 * m)


@pytest.mark.parametrize("engine", ["lammps"])
def test_uniform_tension_and_vtk(tmp_path, engine):
    """A bar pulled by ±F on its end faces: every cross-section carries σ_xx = F/A on average
    (equilibrium), nothing else; VTK frames carry displacement and von_mises in mm and MPa."""
    import pyvista as pv

    nx, ny, nz, F = 10, 4, 4, 100.0
    o = _bar(nx, ny, nz)
    face = ny * nz
    c = _c()
    omega = np.pi / (2 * nx) * np.sqrt(70000.0 / RHO)
    sc = _scene("bar", o, [(o[:, 0] == nx - 1, (F / face, 0, 0)), (o[:, 0] == 0, (-F / face, 0, 0))],
                c, 2 * omega, 3000)
    out = tmp_path / "bar"
    run(sc, out, engine=engine, progress=False, dump_every=500)
    info = postprocess(out)
    s = ParticleStress(load_run(out), method="virial").run().results   # exact section sums
    A = ny * nz * 1.0                              # the cells' union: 4 mm × 4 mm
    for x in (3, 4, 5, 6):
        sel = o[:, 0] == x
        sec = s.stress[-1][sel]
        assert sec[:, 0].mean() == pytest.approx(F / A, rel=1e-3)        # Σ = F exactly
        assert np.abs(sec[:, 1:].mean(axis=0)).max() < 0.01 * F / A
        # principal stresses: the largest is the axial stress, the others near zero
        pr = s.principal[-1][sel]
        assert np.all(pr[:, 0] >= sec[:, 0] - 1e-9)
    # the virial theorem at rest: Σ_i V_i σ_i = Σ x ⊗ F over the loads = F·(nx − 1) along x only
    total = s.stress[-1].sum(axis=0)
    assert total[0] == pytest.approx(F * (nx - 1), rel=1e-3)
    assert np.abs(total[1:]).max() < 1e-3 * F * (nx - 1)
    # VTK: every frame has displacement (vector, mm) and von_mises (scalar, MPa)
    reader = pv.get_reader(str(out / "vtk" / "run.pvd"))
    dumped = load_run(out)
    s = ParticleStress(dumped).run().results             # the measure's default route
    assert len(reader.time_values) == len(dumped.steps)
    for k, t in enumerate(reader.time_values):
        reader.set_active_time_value(t)
        mesh = reader.read()[0]
        disp, vm = mesh.point_data["displacement"], mesh.point_data["von_mises"]
        assert disp.shape == (len(o), 3) and vm.shape == (len(o),)
        p = np.asarray(dumped.trajectory[k].positions, dtype=float)
        np.testing.assert_allclose(disp, p - o, atol=1e-6)
        np.testing.assert_allclose(vm, s.von_mises[k], rtol=1e-12)
        assert mesh.point_data["stress"].shape == (len(o), 6)
    assert info["peak"]["measure"] == "von_mises" and info["peak"]["units"] == "MPa"
    assert info["measures"]["von_mises"]["units"] == "MPa"
    assert info["measures"]["paper"]["units"] == "mm"


def test_pure_bending_top_fibre(tmp_path):
    """Equal and opposite couples M on the ends of a 16 × 6 × 6 mm beam: at mid-span the section
    carries the moment M (Σ σ_xx·z·a² = M, equilibrium) and the top fibre's von Mises stress is
    within 10 % of beam theory M·z/I at the top particle centres (z = 2.5, I = b·h³/12)."""
    nx, ny, nz = 16, 6, 6
    o = _bar(nx, ny, nz)
    s0 = 1.0                                        # N per mm of height, per particle
    loads = []
    for zk in np.unique(o[:, 2]):
        loads.append(((o[:, 0] == nx - 1) & (o[:, 2] == zk), (s0 * zk, 0, 0)))
        loads.append(((o[:, 0] == 0) & (o[:, 2] == zk), (-s0 * zk, 0, 0)))
    M = s0 * ny * float((np.unique(o[:, 2]) ** 2).sum())     # Σ f·z over the end face
    I = ny * nz ** 3 / 12.0
    omega = np.pi / (2 * nx) * np.sqrt(70000.0 / RHO)
    sc = _scene("beam", o, loads, _c(), 2 * omega, 4000)
    out = tmp_path / "beam"
    run(sc, out, engine="reference", progress=False, dump_every=1000)
    v = ParticleStress(load_run(out), method="virial").run().results
    mid = o[:, 0] == nx // 2
    sxx = v.stress[-1][mid, 0]
    assert float((sxx * o[mid, 2]).sum()) == pytest.approx(M, rel=2e-3)   # the virial's sum
    top = mid & (o[:, 2] == o[:, 2].max())
    beam = M * o[:, 2].max() / I
    assert v.von_mises[-1][mid].max() == pytest.approx(beam, rel=0.10)
    assert float(np.abs(v.stress[-1][top, 0]).mean()) == pytest.approx(beam, rel=0.10)
    # the default (patch recovery) reads a face particle on its face, z = 2.5 + ½: M·3/I
    s = ParticleStress(load_run(out)).run().results
    face = M * (o[:, 2].max() + 0.5) / I
    assert s.von_mises[-1][mid].max() == pytest.approx(face, rel=0.10)
    assert float(np.abs(s.stress[-1][top, 0]).mean()) == pytest.approx(face, rel=0.10)


def test_thin_beam_cells_own_moment(tmp_path):
    """A material solid 3 layers thick (30 × 3 × 3 mm, face-compensated bindings) in pure
    bending: the plain virial puts each layer's force at its particles, so its top layer reads
    N²/(N² − 1) = 9/8 of M·z/I (z = 1 mm, I = 3·3³/12 — hand calculation, docs/stress.md);
    the continuum route (each free face's cell moment restored) reads beam theory within 4 %,
    and the default (patch recovery) the face fibre's M·1.5/I within 4 %."""
    from rackstress.model.solid import Solid, bind_coefficient

    nx, ny, nz = 30, 3, 3
    o = _bar(nx, ny, nz)
    s0 = 1.0
    loads = []
    for zk in np.unique(o[:, 2]):
        loads.append(((o[:, 0] == nx - 1) & (o[:, 2] == zk), (s0 * zk, 0, 0)))
        loads.append(((o[:, 0] == 0) & (o[:, 2] == zk), (-s0 * zk, 0, 0)))
    M = s0 * ny * float((np.unique(o[:, 2]) ** 2).sum())
    I = ny * nz ** 3 / 12.0
    c = bind_coefficient(AL, MM, 1.0)
    m = RHO
    g = Group("part", o, 0.5, material=AL, volume=1.0)
    ops = [Force(tuple(float(x) / m for x in f), where=tuple(bool(b) for b in mask))
           for mask, f in loads]
    omega = np.pi / (2 * nx) * np.sqrt(70000.0 / RHO)
    ops += [Bind("part", Solid(1.5, c, None, spacing=1.0, material="aluminium")),
            Dampen(2 * omega)]
    sc = Scene("thin", {"part": g}, {"part": ops}, [Phase("load", 1)], dt=1.0, units=MM)
    dt = 0.5 * predict(sc)["t_max"]
    sc = Scene("thin", {"part": g}, {"part": ops}, [Phase("load", 12000)], dt=dt, units=MM)
    out = tmp_path / "thin"
    run(sc, out, engine="reference", progress=False, dump_every=12000)
    mid = (o[:, 0] >= 12) & (o[:, 0] <= 17)
    top = mid & (o[:, 2] == o[:, 2].max())
    beam = M * o[:, 2].max() / I
    v = ParticleStress(load_run(out), method="virial").run().results
    s = ParticleStress(load_run(out)).run().results
    assert float(v.stress[-1][top, 0].mean()) == pytest.approx(beam * 9 / 8, rel=0.03)
    c = ParticleStress(load_run(out), method="continuum").run().results
    assert float(c.stress[-1][top, 0].mean()) == pytest.approx(beam, rel=0.04)
    # the default reads the top face, z = 1.5 (M·1.5/I): the continuum values fitted by a
    # linear patch and evaluated half a spacing out
    assert float(s.stress[-1][top, 0].mean()) == pytest.approx(M * 1.5 / I, rel=0.04)


def test_paper_scene_keeps_paper(tmp_path):
    """A scene without a material: no bindings file, no von_mises, the paper's measure leads."""
    g = Group("body", np.array([[0.0, 0, 0], [1.0, 0, 0]]), 0.5)
    sc = Scene("paperpair", {"body": g}, {"body": [Force((0.1, 0, 0), where=(False, True)),
                                                    Bind("body", Const(10.0)), Dampen(5.0)]},
               [Phase("load", 50)], dt=0.01)
    out = tmp_path / "pp"
    run(sc, out, engine="reference", progress=False)
    info = postprocess(out)
    assert not (out / "bindings.npz").exists()
    assert "von_mises" not in info["measures"]
    assert info["default_measure"] == "paper" and info["peak"]["measure"] == "paper"
    assert info["measures"]["paper"]["units"] == "length units"
    from rackstress.render.pictures import render
    from rackstress.stress import StressInputError

    with pytest.raises(StressInputError, match="material"):
        render(out, measure="von_mises")
    assert not (out / "figures").exists()           # nothing half-written


def test_bench_stress_quick(tmp_path):
    """``rackstress bench stress --quick``: the virial route's section sums are the load's force
    and moment (equilibrium), and the files are written."""
    from click.testing import CliRunner

    from rackstress.cli import main

    res = CliRunner().invoke(main, ["bench", "stress", "--quick", "--out", str(tmp_path)],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "stress.json").read_text())
    assert {t["lattice"] for t in data["tension"]} == set(data["lattices"]) >= {"plain"}
    for t, b in zip(data["tension"], data["bending"]):   # every lattice: equilibrium holds
        assert t["at_rest"] and b["at_rest"]
        assert t["routes"]["virial"]["mean_sxx"] == pytest.approx(1.0, rel=1e-3)
        assert b["routes"]["virial"]["moment"] == pytest.approx(1.0, rel=2e-3)
        assert 0.2 < t["nu_lattice"] < 0.33              # a central-force lattice: 1/4 in bulk
    assert "hooke(ν=0.33)" in (tmp_path / "stress.md").read_text()


_MPI = """
import sys
sys.path.insert(0, sys.argv[2])
from test_particle_stress import _tension_scene
from rackstress.lib.mpi import world
from rackstress.runs.run import run
from rackstress.stress.post import postprocess
run(_tension_scene(), sys.argv[1], engine="lammps", progress=False, dump_every=500)
if world().Get_rank() == 0:
    postprocess(sys.argv[1])
"""


def _tension_scene():
    nx, ny, nz, F = 8, 3, 3, 90.0
    o = _bar(nx, ny, nz)
    omega = np.pi / (2 * nx) * np.sqrt(70000.0 / RHO)
    return _scene("bar", o, [(o[:, 0] == nx - 1, (F / 9, 0, 0)), (o[:, 0] == 0, (-F / 9, 0, 0))],
                  _c(), 2 * omega, 1500)


@pytest.mark.mpi
def test_lammps_on_two_ranks_matches_the_reference_engine(tmp_path):
    """``mpiexec -n 2``: the run writes its bindings once, and the stress field of its run
    directory equals the reference engine's (an independent engine) to round-off."""
    import subprocess
    import sys
    from pathlib import Path

    from conftest import MPIEXEC

    script = tmp_path / "mpi_stress.py"
    script.write_text(_MPI)
    out = tmp_path / "mpi"
    proc = subprocess.run([MPIEXEC, "-n", "2", sys.executable, str(script), str(out),
                           str(Path(__file__).parent)], capture_output=True, text=True,
                          timeout=HANG_S)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads((out / "summary.json").read_text())["ranks"] == 2
    ref = tmp_path / "ref"
    run(_tension_scene(), ref, engine="reference", progress=False, dump_every=500)
    a = ParticleStress(load_run(out)).run().results.von_mises
    b = ParticleStress(load_run(ref)).run().results.von_mises
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.nanmax(b))
    assert np.nanmax(a[-1]) > 0


def test_coinciding_bound_particles_give_no_numpy_warning():
    """A part that did not settle can collapse two bound particles onto one point (the
    'loose' part of tests/test_faults_static.py): their binding's virial is undefined; the
    stress there is non-finite, and the terminal gets no NumPy "divide by zero" warning.
    A pair 2 apart with rest length 1 (k = 1): W = ½·k·(1 − 1/4)·d⊗d = 1.5 in xx (hand)."""
    import warnings

    from rackstress.stress import tensor as T

    p = np.array([[0.0, 0, 0], [0.0, 0, 0], [2.0, 0, 0]])
    i, j = np.array([0, 2]), np.array([1, 0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        W = T.virial(p, i, j, np.ones(2), np.ones(2), n=3)
    assert not np.isfinite(W[0]).all()
    assert W[2][0] == pytest.approx(0.5 * (1 - 1 / 4) * 4) and np.all(W[2][1:] == 0)
    assert np.all(W[1] == 0)


def test_a_surface_particles_recovery_point_outside_a_curved_face_is_read_on_it():
    """stress.tensor.onto_surface: a cylinder of radius 5 and height 6 along z (128 facets
    round), particles on a lattice of spacing 1 inside it, each surface particle's recovery
    point its free faces' reaches summed (stress.tensor.recovery_points, each reach the exact
    distance to the surface along that axis). Where x and y are both free on the round face,
    the sum lies outside the cylinder (geometry: (x + ex, y + ey) beyond radius 5); moved, every
    point lies within the facets (radius ≤ 5, |z| ≤ 3), the moved ones on them (radius at
    least the facets' inscribed 5·cos(π/128) on the round face), and those inside stay put."""
    import trimesh

    R, H, a = 5.0, 6.0, 1.0
    cyl = trimesh.creation.cylinder(radius=R, height=H, sections=128)
    g = np.arange(-4.5, 5.0, a)
    o = np.array([[x, y, z] for x in g for y in g for z in (-2.5, -1.5, -0.5, 0.5, 1.5, 2.5)])
    o = o[np.hypot(o[:, 0], o[:, 1]) < R * math.cos(math.pi / 128)]
    faces = T.free_faces(o, a)
    reach = np.zeros(o.shape)
    for k in (0, 1):                                   # along x, y: to the round face
        other = o[:, 1 - k]
        reach[:, k] = (np.sqrt(R ** 2 - other ** 2) - np.abs(o[:, k])) / a
    reach[:, 2] = (H / 2 - np.abs(o[:, 2])) / a
    pts = T.recovery_points(o, a, faces, reach)
    r = np.hypot(pts[:, 0], pts[:, 1])
    assert (r > R + 0.1 * a).sum() >= 8               # outside the part: the flaw
    moved = T.onto_surface(pts, (cyl.vertices, cyl.faces), o)
    rm = np.hypot(moved[:, 0], moved[:, 1])
    assert rm.max() <= R + 1e-6 and np.abs(moved[:, 2]).max() <= H / 2 + 1e-6
    inscribed = R * math.cos(math.pi / 128)
    inside = (r < inscribed - 1e-6) & (np.abs(pts[:, 2]) < H / 2 - 1e-6)
    assert np.array_equal(moved[inside], pts[inside])
    out = r > R + 1e-6
    assert (rm[out] >= inscribed - 1e-6).all()
