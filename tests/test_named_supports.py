"""Supports by name and by type (``[[support]] type``, ``where = { hole = ... }``), solved.

Expected values by hand (statics) and by an independent path:

* a bar pinned in one hole and held in the other by a cylindrical support, loaded across at
  mid-span: neither carries a moment about its axis, so each carries half the load (moments
  about the pin); held fixed instead, the first hole carries a moment (the contrast);
* a box turned 30° about z rests on rollers on two of its faces and carries P straight down:
  each roller's reaction lies along its face's normal, λ1 = P·cos 30° on the bottom, λ2 = P·sin
  30° on the side (equilibrium of three forces);
* a plate with a hole pulled along its length, whole and halved by a symmetry plane through
  the hole: the same stress around the hole (the whole part is the independent path);
* an eighth of a bar on three symmetry planes (the lattice half a spacing off each plane),
  pulled by F: σ_xx = F/A on the layer held on the plane as inside (statics; the plain virial
  reads half there by hand: the bindings beyond the plane are gone);
* scenes with bad names and dynamic runs with supports the engines cannot hold, as real
  ``rackstress run`` processes: exit 2 naming the file and field.
"""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from manifold3d import Manifold

from rackstress import scenes
from rackstress.engines.static import _bind_pairs, external_forces, forces, solve
from rackstress.model.constraints import ConstraintMap

RACKSTRESS = Path(sys.executable).with_name("rackstress")


def save(solid: Manifold, path: Path) -> Path:
    m = solid.to_mesh()
    trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts)).export(path)
    return path


def reactions(sc, p):
    """The supports' force on each particle at p (n×3): minus the part of the net force the
    supports take (f − P·f, model.constraints)."""
    f = forces(sc, p, _bind_pairs(sc), external_forces(sc), sc.masses())
    return -(f - ConstraintMap.of_scene(sc).unbalanced(f))


def bar_scene(tmp_path, first: str, spacing: float = 1.5) -> Path:
    """A 100 × 10 × 6 aluminium bar with holes of r 2.5 (axis z) at x = 10 and 90 (particles
    ``spacing`` apart), the first held as ``first``, the second by a cylindrical support,
    100 N in −y at mid-span."""
    bar = Manifold.cube((100.0, 10.0, 6.0))
    for x in (10.0, 90.0):
        bar -= Manifold.cylinder(10.0, 2.5, 2.5, 48).translate((x, 5.0, -2.0))
    save(bar, tmp_path / "bar.stl")
    (tmp_path / "bar.toml").write_text(f'''
name = "bar"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "bar"
mesh = "bar.stl"
spacing = {spacing}
material = "aluminium"
[[support]]
on = "bar"
where = {{ hole = "H1" }}
type = "{first}"
[[support]]
on = "bar"
where = {{ hole = {{ near = [90, 5, 3] }} }}
type = "cylindrical"
[[load]]
on = "bar"
where = {{ box = {{ min = [48.9, -1, -1], max = [51.1, 11, 7] }} }}
force = [0, -100, 0]
''')
    return tmp_path / "bar.toml"


def test_pinned_hole_carries_no_moment(tmp_path):
    from rackstress.runs.run import singular_of

    P, L = 100.0, 80.0
    moments, edges = {}, {}
    for first in ("pinned", "fixed"):
        sc = scenes.load(str(bar_scene(tmp_path, first)))
        # the support's edge on the first bore: singular points, whether it turns or not
        points = singular_of(sc)["bar"][2]
        sup = points.points[points.kind == 1]
        edges[first] = sup[np.hypot(sup[:, 0] - 10, sup[:, 1] - 5) < 4.5]
        res = solve(sc)
        assert res.settled, (first, res.residual)
        R = reactions(sc, res.p)
        o = sc.original_positions()
        near_a = np.hypot(o[:, 0] - 10, o[:, 1] - 5) < 4.5
        near_b = np.hypot(o[:, 0] - 90, o[:, 1] - 5) < 4.5
        held = np.linalg.norm(R, axis=1) > 0
        assert not np.any(held & ~near_a & ~near_b)        # only the two bores hold
        RA, RB = R[near_a].sum(axis=0), R[near_b].sum(axis=0)
        # every reaction, both supports: equal and opposite to the load
        np.testing.assert_allclose(RA + RB, [0, P, 0], atol=1e-4 * P)
        MA = np.cross(o[near_a] - [10, 5, 3], R[near_a])[:, 2].sum()
        moments[first] = MA
        if first == "pinned":
            assert abs(MA) <= 1e-5 * P * L                  # free to turn: no moment
            # moments about the pin's axis: RB,y · 80 = P · 40, so each carries P/2
            assert RA[1] == pytest.approx(P / 2, abs=1e-3 * P)
            assert RB[1] == pytest.approx(P / 2, abs=1e-3 * P)
    # held fixed, the same hole takes a share of the bending moment
    assert abs(moments["fixed"]) > 0.01 * P * L
    # a pinned bore's edge is a support's edge as the fixed bore's (the independent path)
    assert len(edges["pinned"]) > 0
    np.testing.assert_array_equal(edges["pinned"], edges["fixed"])


def test_roller_on_a_sloped_face(tmp_path):
    box = trimesh.creation.box((20.0, 10.0, 10.0))
    box.apply_translation((10.0, 5.0, 5.0))
    box.export(tmp_path / "box.stl")
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    rot = lambda x, y, z: [c * x - s * y, s * x + c * y, z]      # noqa: E731
    (tmp_path / "box.toml").write_text(f'''
name = "wedge"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "box"
mesh = "box.stl"
rotate = [0, 0, 30]
spacing = 1.0
material = "aluminium"
[[support]]
on = "box"
where = {{ face = {{ near = {rot(10, 0, 5)} }} }}
type = "roller"
[[support]]
on = "box"
where = {{ face = {{ near = {rot(0, 5, 5)} }} }}
type = "roller"
[[support]]
on = "box"
where = {{ face = {{ near = {rot(10, 5, 0)} }} }}
fix = ["z"]
[[load]]
on = "box"
where = {{ face = {{ near = {rot(10, 10, 5)} }} }}
force = [0, -100, 0]
''')
    sc = scenes.load(str(tmp_path / "box.toml"))
    g = sc.groups["box"]
    bottom, side = g.constraints
    n1, n2 = bottom.normals[0], side.normals[0]
    np.testing.assert_allclose(n1, [s, -c, 0], atol=1e-9)     # the faces' outward normals
    np.testing.assert_allclose(n2, [-c, -s, 0], atol=1e-9)
    res = solve(sc)
    assert res.settled, res.residual
    R = reactions(sc, res.p)
    only_bottom = np.setdiff1d(bottom.ids, side.ids)
    # a particle on the bottom roller alone (z free): its reaction along n1 only
    tang = R[only_bottom] - np.outer(R[only_bottom] @ n1, n1)
    assert np.abs(tang[:, :2]).max() <= 1e-9 * np.abs(R[only_bottom]).max()
    lam1 = -float((R[bottom.ids] @ n1).sum())
    lam2 = -float((R[side.ids] @ n2).sum())
    assert lam1 == pytest.approx(100 * c, rel=1e-4)
    assert lam2 == pytest.approx(100 * s, rel=1e-4)


def plate_toml(half: bool) -> str:
    """A 40 × 20 × 4 aluminium plate with a hole of r 4 at its centre (20, 10), clamped at
    x = 0, pulled by 200 N at x = 40; half: y ≥ 10, a symmetry plane y = 10, 100 N."""
    y0 = 10 if half else 0
    sym = '''
[[support]]
on = "plate"
type = "symmetry"
plane = { point = [0, 10, 0], normal = [0, -1, 0] }
''' if half else ""
    return f'''
name = "plate-{'half' if half else 'whole'}"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "plate"
fill = {{ difference = [ {{ box = {{ min = [0, {y0}, 0], max = [40, 20, 4] }} }},
                        {{ cylinder = {{ start = [20, 10, -1], end = [20, 10, 5], radius = 4 }} }} ] }}
spacing = 1.0
origin = [0, 0, 0.5]
material = "aluminium"
[[support]]
on = "plate"
where = {{ box = {{ min = [-0.01, -1, -1], max = [0.01, 21, 5] }} }}
{sym}
[[load]]
on = "plate"
where = {{ box = {{ min = [39.99, -1, -1], max = [40.01, 21, 5] }} }}
force = [{100 if half else 200}, 0, 0]
'''


def test_symmetry_plane_halves_the_part(tmp_path):
    from rackstress.runs.run import run
    from rackstress.stress import load_run
    from rackstress.stress.measures import ParticleStress

    vm, pos = {}, {}
    for half in (False, True):
        (tmp_path / f"p{half}.toml").write_text(plate_toml(half))
        sc = scenes.load(str(tmp_path / f"p{half}.toml"))
        out = tmp_path / f"run{half}"
        summary = run(sc, out, engine="reference", progress=False)
        assert summary["settled"]
        # summary.json's reactions: one per [[support]], summing to minus the load
        rows = summary["reactions"]
        assert [r["support"] for r in rows] == ["[[support]] #1"] + (
            ["[[support]] #2 (symmetry)"] if half else [])
        total = np.sum([r["force"] for r in rows], axis=0)
        np.testing.assert_allclose(total, -np.asarray(summary["applied_load"]["force"]),
                                   atol=1e-5 * (100 if half else 200))
        if half:        # the plane pushes along its normal (y) only
            assert rows[1]["force"][0] == 0 and rows[1]["force"][2] == 0
        vm[half] = ParticleStress(load_run(out)).run().results.von_mises[-1]
        pos[half] = sc.original_positions()
    # the half's particles are the whole's with y ≥ 10 (one lattice, a layer on the plane)
    key = lambda o: [tuple(np.round(x, 6)) for x in o]          # noqa: E731
    index = {k: i for i, k in enumerate(key(pos[False]))}
    match = np.array([index[k] for k in key(pos[True])])
    whole, half = vm[False][match], vm[True]
    # compared around the hole (10 < x < 30), ten spacings from the clamp and the loaded end:
    # the end's load is shared by its particles, and the half's row on the plane takes a whole
    # share (100 N over 11 rows against 200 N over 21: 4.5 % less a particle), so at the loaded
    # face the two differ by how the load is spread, not by the plane
    o = pos[True]
    hole = (o[:, 0] > 10) & (o[:, 0] < 30)
    # the peak there (at the hole's side, y = 14) and the field two spacings from the plane on
    assert half[hole].max() == pytest.approx(whole[hole].max(), rel=0.02)
    away = hole & (o[:, 1] >= 12)
    rel = np.abs(half[away] - whole[away]) / whole[hole].max()
    assert np.median(rel) < 0.01 and rel.max() < 0.05


def run_cli(args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([str(RACKSTRESS), *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


def test_unknown_hole_is_exit_2(tmp_path):
    toml = bar_scene(tmp_path, "pinned")
    toml.write_text(toml.read_text().replace('hole = "H1"', 'hole = "H9"'))
    out = run_cli(["run", str(toml), "--engine", "reference", "--no-render",
                   "--out", str(tmp_path / "r")], tmp_path)
    assert out.returncode == 2
    err = out.stderr
    assert str(toml) in err and "[[support]] #1" in err and "where.hole" in err
    assert "no hole 'H9'" in err and "H1 (diameter 5" in err and "H2 (diameter 5" in err
    assert not (tmp_path / "r").exists()


def test_dynamic_pin_is_exit_2(tmp_path):
    toml = bar_scene(tmp_path, "pinned")
    toml.write_text(toml.read_text().replace('analysis = "static"', 'analysis = "dynamic"'))
    out = run_cli(["run", str(toml), "--engine", "reference", "--no-render",
                   "--out", str(tmp_path / "r")], tmp_path)
    assert out.returncode == 2
    assert "[[support]] #1 (pinned)" in out.stderr and 'analysis = "static"' in out.stderr
    assert not (tmp_path / "r").exists()


def test_spacing_chosen_and_set(tmp_path):
    toml = bar_scene(tmp_path, "pinned")
    text = toml.read_text().replace("spacing = 1.5\n", "")
    toml.write_text(text)
    sc = scenes.load(str(toml))
    geo = sc.groups["bar"].meta["part"]
    # walls: 10 × 6 × 100 with bores of r 2.5: the thin walls are 2.5 (10/2 − 2.5) beside the
    # holes, the 6 mm thickness elsewhere; a budget of 20,000 allows (5,600 / 20,000)^⅓ = 0.65
    assert geo.choice["limited_by"] == "walls"
    assert 2.5 - 1e-6 <= geo.choice["wall"] <= 6 + 1e-6
    assert 0.83 <= geo.spacing <= 2.0 and sc.n_particles <= 20_000
    # --set spacing works on any mesh part, without [params]
    sc2 = scenes.load(str(toml), {"spacing": 2.0})
    assert sc2.groups["bar"].meta["part"].spacing == 2.0
    volume = 6000 - 2 * math.pi * 2.5 ** 2 * 6
    assert abs(sc2.n_particles - volume / 8) < 0.15 * volume / 8
    out = run_cli(["scenes", str(toml)], tmp_path)
    assert out.returncode == 0 and "spacing" in out.stdout and "budget" in out.stdout



@pytest.mark.slow
def test_pinned_run_on_lammps_then_fea_models_the_pin(tmp_path):
    """The whole path as a user runs it: the pinned bar on LAMMPS (its engine checks the
    settled state through the constraint map), then ``rackstress fea``, which holds the bore as
    a rigid ring turning about its axis (and the cylindrical bore radially and axially): the
    ring turns by the simply supported beam's end slope P·L²/(16·E·I) (L = 80 between the
    holes, I = 6·10³/12 about z), to 3 % (3D effects at the bores and the load; a coarse FE
    size, once, to keep the test short)."""
    import json

    toml = bar_scene(tmp_path, "pinned")
    out = run_cli(["run", str(toml), "--no-render", "--out", str(tmp_path / "r")], tmp_path)
    assert out.returncode == 0, out.stderr
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["settled"] and summary["residual_engine"] <= summary["tolerance"]
    # a reaction per [[support]]: each hole carries half the 100 N (moments about the pin)
    pin, cyl = summary["reactions"]
    assert pin["support"] == "[[support]] #1 (pinned)"
    assert cyl["support"] == "[[support]] #2 (cylindrical)"
    assert pin["force"][1] == pytest.approx(50, abs=0.1) and cyl["force"][1] == pytest.approx(
        50, abs=0.1)
    # no moment about the pin's axis (z through (10, 5)): M_z − (x·F_y − y·F_x) at the pin
    about_pin = pin["moment"][2] - (10 * pin["force"][1] - 5 * pin["force"][0])
    assert abs(about_pin) <= 1e-4 * 100 * 80
    fea = run_cli(["fea", str(tmp_path / "r"), "--no-converge", "--size", "6"], tmp_path)
    assert fea.returncode == 0, fea.stderr
    got = json.loads((tmp_path / "r" / "fea.json").read_text())
    assert [c["kind"] for c in got["constrained"]] == ["ring", "normals"]
    (ring,) = got["rings"]
    E, I, L = got["material"]["E"], 6 * 10 ** 3 / 12, 80.0
    assert abs(ring["turn_rad"]) == pytest.approx(100 * L ** 2 / (16 * E * I), rel=0.03)


EIGHTH_BAR = """
name = "eighth"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "bar"
fill = { box = { min = [0, 0, 0], max = [20, 6, 6] } }
spacing = 1.0
material = "aluminium"
[[support]]
type = "symmetry"
on = "bar"
plane = { point = [0, 0, 0], normal = [1, 0, 0] }
[[support]]
type = "symmetry"
on = "bar"
plane = { point = [0, 0, 0], normal = [0, 1, 0] }
[[support]]
type = "symmetry"
on = "bar"
plane = { point = [0, 0, 0], normal = [0, 0, 1] }
[[load]]
on = "bar"
where = { box = { min = [19.4, -1, -1], max = [21, 7, 7] } }
force = [36, 0, 0]
"""


def test_the_layer_on_a_symmetry_plane_reads_the_stress_across_it(tmp_path):
    """σ_xx = F/A = 36 N / 36 mm² = 1 MPa in the bar; the layer held on the plane x = 0
    (particles at x = 0.5) reads it too: the plane's force on the cells' face counts (the plain
    virial: half there, by hand — the bindings beyond the plane are gone)."""
    from rackstress.runs.run import run
    from rackstress.stress import load_run
    from rackstress.stress.measures import ParticleStress

    (tmp_path / "e.toml").write_text(EIGHTH_BAR)
    out = tmp_path / "run"
    assert run(scenes.load(str(tmp_path / "e.toml")), out, engine="reference",
               progress=False)["settled"]
    rd = load_run(out)
    x = rd.o[:, 0]
    for method, tol in (("continuum", 0.01), ("patch", 0.03)):
        sxx = ParticleStress(rd, method=method).run().results.stress[-1][:, 0]
        for layer in (0.5, 1.5, 10.5):
            assert np.mean(sxx[np.isclose(x, layer)]) == pytest.approx(1.0, rel=tol), \
                (method, layer)
    sxx = ParticleStress(rd, method="virial").run().results.stress[-1][:, 0]
    assert np.mean(sxx[np.isclose(x, 0.5)]) == pytest.approx(0.5, rel=0.01)
    assert np.mean(sxx[np.isclose(x, 10.5)]) == pytest.approx(1.0, rel=0.01)
