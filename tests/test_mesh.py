"""Parts from meshes (``rackstress.scenes.mesh`` + ``rackstress.model.particles.fill``).

Expected values come from geometry: the meshes are built here by CSG (manifold3d) from boxes
and regular polygons whose volumes are known by hand, and containment is checked against the
shapes' equations, not against the inside test under test.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from manifold3d import Manifold

from rackstress.errors import SceneError
from rackstress.model.particles import MAX_PARTICLES, fill, lattice_points
from rackstress.model.regions import Box
from rackstress.scenes.mesh import read_surface

HOLE_N = 48         # sides of the polygonal hole (manifold3d puts vertices at 2πk/n)


def save(solid: Manifold, path: Path) -> Path:
    m = solid.to_mesh()
    trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts)).export(path)
    return path


def l_shape() -> Manifold:
    """Union of a 40×10×20 and a 10×40×20 box sharing a 10×10×20 corner: volume 14,000."""
    return Manifold.cube((40.0, 10.0, 20.0)) + Manifold.cube((10.0, 40.0, 20.0))


def in_l_shape(o, tol=1e-9):
    x, y, z = o.T
    inz = (z >= -tol) & (z <= 20 + tol)
    return inz & (x >= -tol) & (y >= -tol) & (((x <= 40 + tol) & (y <= 10 + tol))
                                              | ((x <= 10 + tol) & (y <= 40 + tol)))


def plate_with_hole(thickness: float = 2.0) -> Manifold:
    """A 30 (x) × thickness (y) × 20 (z) plate with a hole of circumradius 5 along y at
    (x, z) = (15, 10): volume = thickness · (600 − n/2 · 25 · sin(2π/n))."""
    hole = Manifold.cylinder(thickness + 2, 5.0, 5.0, HOLE_N).rotate((-90.0, 0.0, 0.0))
    return Manifold.cube((30.0, thickness, 20.0)) - hole.translate((15.0, -1.0, 10.0))


def plate_volume(thickness: float = 2.0) -> float:
    return thickness * (600.0 - HOLE_N / 2 * 25.0 * math.sin(2 * math.pi / HOLE_N))


def outside_hole(o):
    """Outside the regular n-gon of circumradius 5 around (15, ·, 10): beyond the inradius
    along at least one edge normal (the polygon is the intersection of those half-planes)."""
    dx, dz = o[:, 0] - 15.0, o[:, 2] - 10.0
    # the rotation by −90° about x maps the cylinder's (x, y) to (x, z) with z → −y: vertex k
    # at angle 2πk/n in the cylinder's (x, y) lies at (cos, −sin)·5 in (x, z)
    inr = 5.0 * math.cos(math.pi / HOLE_N)
    mids = (np.arange(HOLE_N) + 0.5) * 2 * math.pi / HOLE_N
    proj = np.outer(dx, np.cos(mids)) + np.outer(dz, -np.sin(mids))
    return (proj > inr - 1e-9).any(axis=1)


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    out = {"L": save(l_shape(), d / "L.stl"), "plate": save(plate_with_hole(), d / "plate.stl"),
           "plate4": save(plate_with_hole(4.0), d / "plate4.stl")}
    tm = trimesh.load(out["L"])
    for ext in ("obj", "ply"):
        tm.export(d / f"L.{ext}")
        out[f"L.{ext}"] = d / f"L.{ext}"
    import pyvista as pv
    pv.read(out["L"]).save(d / "L.vtk")
    out["L.vtk"] = d / "L.vtk"
    # bad meshes: one face missing; two overlapping boxes written as one surface
    box = trimesh.creation.box(extents=(4, 4, 4))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1])
    open_box.export(d / "open.stl")
    out["open"] = d / "open.stl"
    b2 = trimesh.creation.box(extents=(4, 4, 4))
    b2.apply_translation((1.3, 1.7, 2.1))
    trimesh.util.concatenate([box, b2]).export(d / "overlap.stl")
    out["overlap"] = d / "overlap.stl"
    return out


@pytest.mark.parametrize("spacing", [1.0, 0.5, 0.45, 0.37])
def test_l_shape_count_and_containment(meshes, spacing):
    surf = read_surface(meshes["L"])
    assert surf.volume == pytest.approx(14000.0, rel=1e-12)
    o = fill(surf, spacing)
    expected = 14000.0 / spacing ** 3
    assert abs(len(o) / expected - 1) <= 0.05, (len(o), expected)
    assert in_l_shape(o).all()                            # every centre inside the L
    # 40, 10 and 20 are whole multiples of 1 and 0.5: then the count is exact
    if spacing in (1.0, 0.5):
        assert len(o) == round(expected)


def test_hcp_count_is_sqrt2_times_cubic(meshes):
    o = fill(read_surface(meshes["L"]), 0.5, packing="hcp")
    expected = math.sqrt(2) * 14000.0 / 0.5 ** 3
    assert abs(len(o) / expected - 1) <= 0.05
    assert in_l_shape(o).all()
    # nearest neighbours exactly one spacing apart (close packing), none closer
    from scipy.spatial import cKDTree
    d, _ = cKDTree(o).query(o, k=2)
    assert d[:, 1].min() == pytest.approx(0.5, rel=1e-9)
    # an hcp particle has 12 neighbours at the spacing: count them deep inside
    inner = np.all((o > [2, 2, 2]) & (o < [8, 8, 18]), axis=1)
    counts = np.array([len(x) for x in cKDTree(o).query_ball_point(o[inner], 0.5 + 1e-9)]) - 1
    assert (counts == 12).all()


def test_plate_with_hole_count_containment_and_thin_feature(meshes):
    surf = read_surface(meshes["plate"])
    assert surf.volume == pytest.approx(plate_volume(), rel=1e-9)
    o = fill(surf, 1.0)
    assert abs(len(o) / plate_volume() - 1) <= 0.05
    x, y, z = o.T
    assert ((x >= 0) & (x <= 30) & (y >= 0) & (y <= 2) & (z >= 0) & (z <= 20)).all()
    assert outside_hole(o).all()
    # the plate is two spacings thick: every (x, z) column holds exactly two particles, at
    # y = 0.5 and 1.5
    assert sorted(np.unique(np.round(y, 9))) == [0.5, 1.5]
    cols, counts = np.unique(np.round(o[:, [0, 2]], 9), axis=0, return_counts=True)
    assert (counts == 2).all()
    # and the hole is really open: no particle within its inradius of the axis
    r = np.hypot(x - 15, z - 10)
    assert r.min() > 5.0 * math.cos(math.pi / HOLE_N) - 1e-9


def test_formats_give_the_same_part(meshes):
    ref = fill(read_surface(meshes["L"]), 1.0)
    for key in ("L.obj", "L.ply", "L.vtk"):
        o = fill(read_surface(meshes[key]), 1.0)
        np.testing.assert_array_equal(o, ref)


def test_placement_scale_rotate_translate(meshes):
    base = fill(read_surface(meshes["plate4"]), 1.0)
    # scale 2: volume × 8, count within 5 % of the scaled volume
    big = read_surface(meshes["plate4"], scale=2.0)
    assert big.volume == pytest.approx(8 * plate_volume(4.0), rel=1e-9)
    assert abs(len(fill(big, 1.0)) / (8 * plate_volume(4.0)) - 1) <= 0.05
    # rotate 90° about z then translate: (x, y, z) → (−y, x, z) + t; same particle count
    t = np.array([100.0, -50.0, 3.0])
    moved = read_surface(meshes["plate4"], rotate=[0, 0, 90], translate=t.tolist())
    lo, hi = moved.bounds()
    np.testing.assert_allclose(lo, [-4, 0, 0] + t, atol=1e-9)
    np.testing.assert_allclose(hi, [0, 30, 20] + t, atol=1e-9)
    o = fill(moved, 1.0)
    assert len(o) == len(base)
    back = o - t
    assert outside_hole(np.column_stack([back[:, 1], -back[:, 0], back[:, 2]])).all()


def test_id_order_is_x_fastest_then_y_then_z():
    o = fill(Box([0, 0, 0], [3, 2, 2]), 1.0)            # 3 × 2 × 2 cells, centres at .5
    assert len(o) == 12
    assert o[:4].tolist() == [[0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [2.5, 0.5, 0.5], [0.5, 1.5, 0.5]]
    key = o[:, 2] * 1e6 + o[:, 1] * 1e3 + o[:, 0]
    assert np.all(np.diff(key) > 0)


def test_union_of_meshes_fills_the_union_once(meshes, tmp_path):
    from rackstress.model.regions import Union
    a = save(Manifold.cube((10.0, 10.0, 10.0)), tmp_path / "a.stl")
    b = save(Manifold.cube((10.0, 10.0, 10.0)).translate((5.0, 0, 0)), tmp_path / "b.stl")
    o = fill(Union((read_surface(a), read_surface(b))), 1.0)
    assert len(o) == 15 * 10 * 10                    # union volume 1500, no doubled particles
    assert len(np.unique(np.round(o, 9), axis=0)) == len(o)


@pytest.mark.parametrize("key, needles", [
    ("open", ["not closed", "boundary edge"]),
    ("overlap", ["overlaps or intersects itself"]),
])
def test_bad_meshes_name_the_file(meshes, key, needles):
    with pytest.raises(SceneError) as exc:
        read_surface(meshes[key])
    msg = str(exc.value)
    assert str(meshes[key]) in msg
    for n in needles:
        assert n in msg


def test_unit_mistakes_and_spacing_errors_name_the_file(meshes, tmp_path):
    surf = read_surface(meshes["L"], scale=1000.0)       # metres read as millimetres
    with pytest.raises(SceneError) as exc:
        fill(surf, 1.0, name=str(meshes["L"]))
    msg = str(exc.value)
    assert str(meshes["L"]) in msg and "1.4e+13" in msg and f"{MAX_PARTICLES:,}" in msg
    assert "scale" in msg
    # 10^8 particles: refused before anything is allocated
    with pytest.raises(SceneError, match="more than"):
        fill(read_surface(meshes["L"]), (14000.0 / 1e8) ** (1 / 3), name="L")
    # a spacing larger than the part's thinnest extent (the plate is 2 thick)
    with pytest.raises(SceneError) as exc:
        fill(read_surface(meshes["plate"]), 2.5, name=str(meshes["plate"]))
    assert str(meshes["plate"]) in str(exc.value) and "larger than the part" in str(exc.value)
    with pytest.raises(SceneError, match="does not exist"):
        read_surface(tmp_path / "missing.stl")
    (tmp_path / "part.iges").write_text("IGES")
    with pytest.raises(SceneError, match="unknown surface format '.iges'"):
        read_surface(tmp_path / "part.iges")
    # STEP is read by gmsh's OpenCASCADE reader: a file it cannot read is named
    (tmp_path / "part.step").write_text("ISO-10303-21;")
    with pytest.raises(SceneError, match="part.step: gmsh's OpenCASCADE reader cannot read"):
        read_surface(tmp_path / "part.step")
    (tmp_path / "junk.stl").write_bytes(b"\x00" * 10)
    with pytest.raises(SceneError, match="junk.stl"):
        read_surface(tmp_path / "junk.stl")


def test_lattice_points_hcp_layers():
    pts, shape = lattice_points([0, 0, 0], [4, 4, 4], 1.0, "hcp")
    y = np.unique(np.round(pts[:, 1], 12))
    assert np.allclose(np.diff(y), math.sqrt(2 / 3))     # close-packed layers √(2/3) apart


def test_scan_conversion_agrees_with_the_point_test(meshes):
    """Filling uses VTK's scan conversion of whole grids; selecting uses the enclosed-points
    test point by point: on the same grid (off the faces) both give the same points."""
    from rackstress.model.regions import Cylinder, grid_points
    surf = read_surface(meshes["plate4"])
    region = surf - Cylinder([5, -1, 5], [5, 5, 5], 2.0)
    origin, spacing, dims = (0.3, 0.2, 0.1), (0.7, 0.45, 0.6), (44, 10, 34)
    pts = grid_points(origin, spacing, dims)
    np.testing.assert_array_equal(region.grid_mask(origin, spacing, dims), region.mask(pts))
    assert 0 < region.mask(pts).sum() < len(pts)


@pytest.mark.parametrize("make, volume", [
    (lambda: trimesh.creation.icosphere(subdivisions=4, radius=10.0), 4 / 3 * math.pi * 1000),
    (lambda: trimesh.creation.torus(12.0, 4.0, major_sections=64, minor_sections=32),
     2 * math.pi ** 2 * 12.0 * 16.0),
    (lambda: trimesh.creation.cylinder(radius=5.0, height=20.0, sections=64), math.pi * 25 * 20),
])
def test_curved_meshes_are_accepted_and_filled(tmp_path, make, volume):
    """Valid meshes with many slivers and curved faces pass the checks (no false alarm), and
    fill to within 5 % of the true solid's volume/spacing³ (the faceted mesh holds a little
    less: within 2 % here)."""
    path = tmp_path / "curved.stl"
    make().export(path)
    surf = read_surface(path)
    assert abs(surf.volume / volume - 1) < 0.02
    o = fill(surf, 1.0)
    assert abs(len(o) / volume - 1) <= 0.05
