"""Named features of parts (``rackstress.scenes.features``) and ``rackstress inspect``.

Expected values come from construction and hand geometry: a plate built here by CSG
(manifold3d) with holes of known radius, axis and depth, a chamfer and a round, whose face
areas follow from its dimensions and the regular polygons' areas; and a real part nobody here
drew (the SO-ARM100 upper arm of examples/parts/, in metres), whose M3 clearance hole is
measured independently by a least-squares circle fit (numpy's lstsq) to the vertices picked
by position round it.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from manifold3d import Manifold

from rackstress.errors import SceneError
from rackstress.scenes import features as ft

ROOT = Path(__file__).resolve().parents[1]
ARM = ROOT / "examples" / "parts" / "so100-upper-arm" / "Upper_Arm.stl"
RACKSTRESS = Path(sys.executable).with_name("rackstress")


def polygon_area(r: float, n: int) -> float:
    """Area of the regular n-gon inscribed in a circle of radius r (manifold3d's cylinders)."""
    return 0.5 * n * r * r * math.sin(2 * math.pi / n)


def save(solid: Manifold, path: Path) -> Path:
    m = solid.to_mesh()
    trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts)).export(path)
    return path


def cylinder(r, h, n, at=(0, 0, 0), axis="z") -> Manifold:
    c = Manifold.cylinder(h, r, r, n)
    if axis == "x":
        c = c.rotate((0, 90, 0))
    return c.translate(at)


def plate() -> Manifold:
    """60 × 30 × 6 with: H1 through (r 4, 48 sides, axis z at (15, 15)); H2 blind (r 2.5,
    24 sides, 3 deep from the top at (45, 15)); H3 through along x (r 1.5, 16 sides, at y 24,
    z 3); a 2 mm 45° chamfer on the top front edge (y 0, z 6); a round of r 3 (24 sides) on
    the top back edge (y 30, z 6)."""
    p = Manifold.cube((60.0, 30.0, 6.0))
    p -= cylinder(4.0, 10.0, 48, (15, 15, -2))
    p -= cylinder(2.5, 5.0, 24, (45, 15, 3))
    p -= cylinder(1.5, 80.0, 16, (-10, 24, 3), axis="x")
    # chamfer: a square prism along x, turned 45°, its edge 2 mm into the corner
    p -= Manifold.cube((80.0, 2 * math.sqrt(2), 2 * math.sqrt(2)), center=True).rotate(
        (45, 0, 0)).translate((30, 0, 6))
    # round: the corner 3 × 3 minus a quarter of the cylinder r 3 about the line y 27, z 3
    corner = Manifold.cube((80.0, 3.0, 3.0)).translate((-10, 27, 3))
    p -= corner - cylinder(3.0, 80.0, 24, (-10, 27, 3), axis="x")
    return p


@pytest.fixture(scope="module")
def plate_features(tmp_path_factory):
    path = save(plate(), tmp_path_factory.mktemp("plate") / "plate.stl")
    return path, ft.part_features(trimesh.load(path, force="mesh"))


def test_plate_holes_by_construction(plate_features):
    _, f = plate_features
    assert [h.name for h in f.holes] == ["H1", "H2", "H3"]      # by radius
    h1, h2, h3 = f.holes
    assert h1.radius == pytest.approx(4.0, abs=1e-5) and h1.through
    assert abs(h1.axis[2]) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(h1.centre, [15, 15, 3], atol=1e-5)
    assert h1.depth == pytest.approx(6.0, abs=1e-5) and h1.segments == 48
    assert h2.radius == pytest.approx(2.5, abs=1e-5) and not h2.through
    np.testing.assert_allclose(h2.centre, [45, 15, 4.5], atol=1e-5)
    assert h2.depth == pytest.approx(3.0, abs=1e-5)
    assert h3.radius == pytest.approx(1.5, abs=1e-5) and h3.through
    assert abs(h3.axis[0]) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(h3.centre[1:], [24, 3], atol=1e-5)
    assert h3.depth == pytest.approx(60.0, abs=1e-5)
    # the round (a quarter of a convex cylinder) is no hole and no face
    assert f.fillets == 1


def test_plate_faces_by_construction(plate_features):
    _, f = plate_features
    a1, a2, a3 = polygon_area(4, 48), polygon_area(2.5, 24), polygon_area(1.5, 16)
    # the round's 24-gon quarter: the 3 × 3 corner less the polygon's quarter (6 of its sides)
    round_cut = 9.0 - 6 * 0.5 * 9.0 * math.sin(2 * math.pi / 24)
    expected = {
        "bottom": (1800.0 - a1, [0, 0, -1]),
        "top": (60.0 * (30 - 2 - 3) - a1 - a2, [0, 0, 1]),      # less chamfer and round strips
        "front": (60.0 * 4, [0, -1, 0]),                          # below the chamfer
        "back": (60.0 * 3, [0, 1, 0]),                            # below the round
        "left": (180.0 - 2.0 - round_cut - a3, [-1, 0, 0]),
        "right": (180.0 - 2.0 - round_cut - a3, [1, 0, 0]),
        "blind bottom": (a2, [0, 0, 1]),
    }
    assert len(f.faces) == len(expected)        # the chamfer is no face
    names = [x.name for x in f.faces]
    assert names == [f"F{i}" for i in range(1, 8)]
    got = sorted(f.faces, key=lambda x: -x.area)
    for (what, (area, normal)), x in zip(sorted(expected.items(), key=lambda kv: -kv[1][0]), got):
        assert x.area == pytest.approx(area, rel=1e-6), what
        np.testing.assert_allclose(x.normal, normal, atol=1e-9, err_msg=what)
    top = f.faces[1]
    assert top.extent[0] == pytest.approx(60.0, abs=1e-6)
    assert top.extent[1] == pytest.approx(25.0, abs=1e-6)


def test_plate_nearest_and_placed(plate_features):
    _, f = plate_features
    assert f.nearest([15 + 3.9, 15, 3]) == "hole H1"          # inside the bore, by its wall
    assert f.nearest([30, 10, 0.1]) == "face F1"               # above the bottom
    assert f.nearest([30, 10, 500]) is None                    # nothing within 5 % of the size
    moved = f.placed(rotate=(0, 0, 90), translate=(100, 0, 0))
    np.testing.assert_allclose(moved.get("H1").centre, [100 - 15, 15, 3], atol=1e-9)
    assert moved.get("H3").axis[1] == pytest.approx(1.0, abs=1e-9) or \
        moved.get("H3").axis[1] == pytest.approx(-1.0, abs=1e-9)


def test_plate_walls(plate_features):
    path, _ = plate_features
    w = ft.wall_thickness(trimesh.load(path, force="mesh"))
    # the thinnest walls: 1.5 mm above and below H3 (6 − 3 − 1.5; its 16-gon has a vertex at
    # the top and bottom), measured within the rays' spread
    assert 1.5 - 1e-6 <= np.nanmin(w.thickness) <= 1.6
    thin = w.thinner_than(1.6)
    assert thin and all(1.5 - 1e-6 <= t["thickness"] < 1.6 for t in thin)
    assert all(abs(t["position"][1] - 24) < 1.6 for t in thin)  # over and under H3
    # a limit larger than the part (a spacing the size of the part): every thin sample is
    # within it of every other, so one place — the thinnest sample over the whole surface
    # (by hand: the minimum), all of it (share 1)
    (one,) = w.thinner_than(1e3)
    ok = np.isfinite(w.thickness)
    assert one["thickness"] == np.nanmin(w.thickness)
    assert one["share"] == pytest.approx(w.weight[ok].sum() / w.weight.sum())


def test_so_arm_hole_by_independent_fit():
    """The upper arm's M3 clearance hole (3.2 mm) by a circle fit of its own."""
    tm = trimesh.load(ARM, force="mesh")
    f = ft.part_features((tm.vertices * 1000.0, tm.faces))
    V = tm.vertices * 1000.0
    # by hand: the bore's vertices lie 1.5-1.7 mm from the line y = z = 0 across x ∈ [-35, -20]
    near = (V[:, 0] > -35.2) & (V[:, 0] < -19.5) & (np.hypot(V[:, 1], V[:, 2]) < 1.8)
    y, z = V[near, 1], V[near, 2]
    A = np.column_stack([2 * y, 2 * z, np.ones_like(y)])
    (cy, cz, c), *_ = np.linalg.lstsq(A, y * y + z * z, rcond=None)
    r = math.sqrt(c + cy * cy + cz * cz)
    assert r == pytest.approx(1.6, abs=0.01)                      # the M3 clearance, 3.2 mm
    hole = [h for h in f.holes if abs(h.centre[1]) < 0.1 and abs(h.centre[2]) < 0.1]
    assert len(hole) == 1
    assert hole[0].radius == pytest.approx(r, abs=1e-3)
    assert abs(hole[0].axis[0]) == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(hole[0].centre[1:], [cy, cz], atol=1e-3)
    # its bore ends at x = -35.1 (the fork's outside) and x = -19.8 (its inner face)
    assert hole[0].through


def test_choose_spacing_by_hand():
    assert ft.nice_up(0.2463) == 0.25 and ft.nice_down(0.2467) == 0.24
    walls = ft.Walls(np.zeros((4, 3)), np.array([3.0, 3.0, 3.0, 3.0]), np.ones(4),
                     np.zeros((4, 3)))
    # 3 across walls of 3 → 1.0; 1000 mm³ at 1.0 → 1,000 particles, within 20,000
    c = ft.choose_spacing(1000.0, walls)
    assert (c["spacing"], c["particles"], c["limited_by"]) == (1.0, 1000, "walls")
    # a budget of 100: (1000 / 100)^(1/3) = 2.154 → 2.2 (rounded up): 1000 / 2.2³ = 93.9
    c = ft.choose_spacing(1000.0, walls, budget=100)
    assert (c["spacing"], c["particles"], c["limited_by"]) == (2.2, 94, "budget")


def test_inspect_cli(plate_features, tmp_path):
    path, _ = plate_features
    out = subprocess.run([str(RACKSTRESS), "inspect", str(path), "--json", "--png",
                          str(tmp_path / "names.png")], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert [h["name"] for h in info["holes"]] == ["H1", "H2", "H3"]
    assert info["holes"][0]["diameter"] == pytest.approx(8.0, abs=1e-4)
    assert info["watertight"] and info["bodies"] == 1
    assert info["walls"]["thinnest"] == pytest.approx(1.5, abs=0.1)
    assert (tmp_path / "names.png").stat().st_size > 10_000
    text = subprocess.run([str(RACKSTRESS), "inspect", str(path), "--scale", "0.001"],
                          capture_output=True, text=True, timeout=300)
    assert text.returncode == 0
    assert "H1" in text.stdout and "scale = 1000" in text.stdout      # metres? says so


def test_inspect_unreadable_is_exit_2(tmp_path):
    bad = tmp_path / "broken.stl"
    bad.write_text("solid nothing\nendsolid nothing\n")
    out = subprocess.run([str(RACKSTRESS), "inspect", str(bad)], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2
    assert str(bad) in out.stderr and out.stderr.count("\n") == 1


def test_step_box_with_hole(tmp_path):
    """A STEP written here by gmsh's OCC kernel: a 40 × 20 × 5 box less a cylinder of r 3."""
    import gmsh

    from rackstress.scenes.mesh import read_surface

    step = tmp_path / "box.step"
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        box = gmsh.model.occ.addBox(0, 0, 0, 40, 20, 5)
        hole = gmsh.model.occ.addCylinder(20, 10, -1, 0, 0, 7, 3)
        gmsh.model.occ.cut([(3, box)], [(3, hole)])
        gmsh.model.occ.synchronize()
        gmsh.write(str(step))
    finally:
        gmsh.finalize()
    s = read_surface(step)
    # the surface mesh's hole is a polygon inscribed in the circle: a little more volume
    exact = 40 * 20 * 5 - math.pi * 9 * 5
    assert exact < s.volume < exact + 5 * (math.pi * 9 - polygon_area(3, 36))
    f = ft.surface_features(s)
    assert [h.name for h in f.holes] == ["H1"]
    assert f.holes[0].radius == pytest.approx(3.0, abs=1e-4) and f.holes[0].through
    np.testing.assert_allclose(f.holes[0].centre, [20, 10, 2.5], atol=1e-4)
    # top and bottom: 40 × 20 less the hole's polygon (36 sides or more), then the sides
    for x in f.faces[:2]:
        assert 800 - math.pi * 9 <= x.area <= 800 - polygon_area(3, 36)
        assert abs(x.normal[2]) == pytest.approx(1.0, abs=1e-9)
    assert [round(x.area, 6) for x in f.faces[2:]] == [200.0, 200.0, 100.0, 100.0]
    bad = tmp_path / "empty.step"
    bad.write_text("ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n")
    with pytest.raises(SceneError, match="empty.step"):
        read_surface(bad)


def test_inspect_names_no_hole_it_did_not_find(tmp_path):
    """A solid block has no hole: ``inspect`` says so and does not offer ``hole = "H1"``, which
    the scene would refuse (a public string-light bracket printed "holes (0): hold one with
    where = { hole = "H1" }"); a sphere has no flat face, likewise."""
    from rackstress.scenes import inspect as insp

    for name, mesh, none in (("block", trimesh.creation.box([20, 10, 5]), "holes (0): none"),
                             ("ball", trimesh.creation.icosphere(4, 5.0), "flat faces (0): none")):
        path = tmp_path / f"{name}.stl"
        mesh.export(path)
        report = insp.text(insp.inspect_part(path))
        assert none in report, report
        (line,) = [ln for ln in report.splitlines() if ln.startswith(none.split(":")[0])]
        assert '"H1"' not in line and '"F1"' not in line, line
