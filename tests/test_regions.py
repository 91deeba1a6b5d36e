"""Regions by shape (``rackstress.model.regions``): expected selections from geometry."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rackstress.errors import SceneError
from rackstress.model.regions import (Box, Cylinder, Difference, HalfSpace, Ids, Intersection,
                                      Norm2Below, Sphere, Union, index_vector)


def cube_lattice(n: int, spacing: float = 1.0) -> np.ndarray:
    """n³ points, x fastest, then y, then z (the documented id order)."""
    k, j, i = np.meshgrid(np.arange(n), np.arange(n), np.arange(n), indexing="ij")
    return np.column_stack([i.ravel(), j.ravel(), k.ravel()]) * spacing


O = cube_lattice(10)   # 1000 points, 0..9 in each axis


def test_box_counts_closed_boundaries():
    # 2 ≤ x ≤ 4, 0 ≤ y ≤ 9, 5 ≤ z ≤ 5: 3 × 10 × 1 lattice points, faces included
    m = Box([2, 0, 5], [4, 9, 5]).mask(O)
    assert m.sum() == 30
    assert set(np.unique(O[m][:, 0])) == {2, 3, 4}


def test_box_boundary_survives_round_off():
    o = cube_lattice(4, 0.1)          # 0.1 * 3 = 0.30000000000000004
    assert Box([0, 0, 0], [0.3, 0.3, 0.3]).mask(o).sum() == 64


def test_sphere_count_matches_lattice_count_by_hand():
    # points of Z³ with i² + j² + k² ≤ 4 around (4,4,4): 1 + 6 + 12 + 8 + 6 = 33
    # (norms² 0, 1, 2, 3, 4 occur 1, 6, 12, 8, 6 times)
    assert Sphere([4, 4, 4], 2.0).mask(O).sum() == 33


def test_cylinder_axis_and_caps():
    # axis along z from z=2 to z=6 through (4, 4): radius 1 takes the axis and its 4
    # neighbours (distance 1), not the diagonals (√2): 5 per layer, 5 layers (2..6 closed)
    m = Cylinder([4, 4, 2], [4, 4, 6], 1.0).mask(O)
    assert m.sum() == 25
    assert O[m][:, 2].min() == 2 and O[m][:, 2].max() == 6
    # a slanted axis: every selected point is within the radius of the segment
    c = Cylinder([0, 0, 0], [9, 9, 9], 1.5)
    sel = O[c.mask(O)]
    u = np.ones(3) / math.sqrt(3)
    t = sel @ u
    assert np.all(np.linalg.norm(sel - t[:, None] * u, axis=1) <= 1.5 + 1e-9)
    assert np.all((t >= -1e-9) & (t <= 9 * math.sqrt(3) + 1e-9))


def test_half_space_is_the_side_the_normal_points_to():
    assert HalfSpace([0, 7, 0], [0, 1, 0]).mask(O).sum() == 300    # y ∈ {7, 8, 9}
    assert HalfSpace([0, 7, 0], [0, -1, 0]).mask(O).sum() == 800   # y ≤ 7
    # a slanted plane x + y ≥ 9 (normal not unit): pairs (x, y) with x + y ≥ 9: 55, × 10 z
    assert HalfSpace([9, 0, 0], [2, 2, 0]).mask(O).sum() == 550


def test_norm2_below_is_eq15():
    # the plane experiments' corner: i² + k² < 10 on the plane y = 0 → 11 particles
    plane = O[O[:, 1] == 0]
    assert Norm2Below(10).mask(plane).sum() == 11


def test_ids_and_range_errors():
    m = Ids([0, 9, 999]).mask(O)
    assert np.flatnonzero(m).tolist() == [0, 9, 999]
    # id 9 is x = 9 on the first row: x fastest
    assert O[9].tolist() == [9, 0, 0] and O[10].tolist() == [0, 1, 0]
    with pytest.raises(SceneError, match=r"particle index 1000 is not in the group \(0..999\)"):
        Ids([1000]).mask(O)
    with pytest.raises(SceneError, match="not an integer"):
        Ids([1.5])


def test_combinations_by_inclusion_exclusion():
    a = Box([0, 0, 0], [4, 9, 9])      # 500 points
    b = Box([3, 0, 0], [9, 9, 9])      # 700 points, 200 shared (x ∈ {3, 4})
    assert (a | b).mask(O).sum() == 1000
    assert Union((a, b)).mask(O).sum() == 500 + 700 - 200
    assert (a & b).mask(O).sum() == 200 == Intersection((a, b)).mask(O).sum()
    # a difference is the closed solid a − b = [0, 3] × [0, 9]²: its face x = 3 (b's) included
    assert (a - b).mask(O).sum() == 400 == Difference((a, b)).mask(O).sum()
    # a plate with a hole: a 10×10 slab minus a cylinder of radius 1.5 through (4, 4):
    # points with (x−4)² + (y−4)² ≤ 2.25: 1 + 4 + 4 = 9 per layer
    plate = Box([0, 0, 0], [9, 9, 0]) - Cylinder([4, 4, -1], [4, 4, 1], 1.5)
    assert plate.mask(O).sum() == 100 - 9


def test_difference_keeps_a_hole_rim_the_spacing_meets():
    """A hole of radius 2 through (4, 4): the sites with (x−4)² + (y−4)² < 4 are taken away
    (1 + 4 + 4 = 9 a layer, integer arithmetic), the four on its rim at (4 ± 2, 4), (4, 4 ± 2)
    kept — the closed solid's, as a box keeps its faces; before, they were taken away and the
    hole had a one-site notch where each axis meets it."""
    i, j = np.meshgrid(np.arange(10), np.arange(10), indexing="ij")
    inside = ((i - 4) ** 2 + (j - 4) ** 2 < 4).sum()
    assert inside == 9
    plate = Box([0, 0, 0], [9, 9, 0]) - Cylinder([4, 4, -1], [4, 4, 1], 2.0)
    m = plate.mask(O)
    assert m.sum() == 100 - inside
    for x, y in ((2, 4), (6, 4), (4, 2), (4, 6)):
        assert m[y * 10 + x], (x, y)
    # the same by the fill's own path: the grid of the layer z = 0
    g = plate.grid_mask([0, 0, 0], (1.0, 1.0, 1.0), (10, 10, 1))
    assert g.tolist() == m[:100].tolist()


def test_difference_drops_boundary_points_that_border_nothing_left():
    """A slot through the slab: the sites on its openings in the slab's faces, and on the face
    two touching boxes of a union share, border nothing of the difference and are taken away;
    those on the slot's walls are kept."""
    slab = Box([0, 0, 0], [9, 9, 2])
    slot = Box([3, 3, 0], [5, 5, 2])                 # through z, walls at x, y = 3 and 5
    m = (slab - slot).mask(O)
    opening = (O[:, 0] == 4) & (O[:, 1] == 4) & (O[:, 2] <= 2)
    assert not m[opening].any()
    wall = (O[:, 0] == 3) & (O[:, 1] == 4) & (O[:, 2] <= 2)
    assert m[wall].all()
    halves = Union((Box([3, 3, 0], [4, 5, 2]), Box([4, 3, 0], [5, 5, 2])))   # share x = 4
    assert (slab - halves).mask(O).tolist() == m.tolist()
    # inside the slab: 10 × 10 × 3 sites, the slot's interior (x, y = 4; 3 layers) gone
    assert m.sum() == 300 - 3
    # a part taken away by index is taken away as named
    assert (slab - Ids([0])).mask(O).sum() == 299


def test_bounds_of_combinations():
    a, b = Box([0, 0, 0], [1, 1, 1]), Sphere([3, 0, 0], 1.0)
    lo, hi = (a | b).bounds()
    assert lo.tolist() == [0, -1, -1] and hi.tolist() == [4, 1, 1]
    lo, hi = (a - b).bounds()
    assert hi.tolist() == [1, 1, 1]
    assert HalfSpace([0, 0, 0], [0, 1, 0]).bounds() is None


def test_index_vector_first_region_wins():
    o = O[:10]                                         # x = 0..9 on one row
    idx = index_vector([Box([0, 0, 0], [3, 0, 0]), Box([2, 0, 0], [5, 0, 0])], o)
    assert idx.tolist() == [1, 1, 1, 1, 2, 2, 0, 0, 0, 0]


@pytest.mark.parametrize("make, msg", [
    (lambda: Box([1, 0, 0], [0, 1, 1]), "below its min"),
    (lambda: Sphere([0, 0, 0], -1), "radius must be positive"),
    (lambda: Cylinder([0, 0, 0], [0, 0, 0], 1), "coincide"),
    (lambda: HalfSpace([0, 0, 0], [0, 0, 0]), "normal must not be zero"),
    (lambda: Box([0, 0], [1, 1, 1]), "three finite numbers"),
    (lambda: Union(()), "at least one region"),
])
def test_bad_shapes_are_scene_errors(make, msg):
    with pytest.raises(SceneError, match=msg):
        make()
