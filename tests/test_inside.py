"""The fast inside test of ``bind … within … inside`` (model/inside.py) against the sampling
test it replaces and against geometry: cells touched by hand, the re-entrant corners of the
validation L-bracket and of the bracket mesh, convex parts, curved and sloped mesh faces."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rackstress.model.inside import lattice_of, sampled, segments_inside, touched_cells
from rackstress.model.operators import Bind
from rackstress.model.particles import fill
from rackstress.model.regions import Box, Sphere
from rackstress.scenes import validation as cases
from rackstress.scenes.mesh import read_surface
from conftest import HANG_S

STL = Path(__file__).resolve().parents[1] / "examples" / "bracket" / "bracket.stl"


def _pairs(o, d):
    ij = cKDTree(o).query_pairs(d, output_type="ndarray")
    diff = o[ij[:, 1]] - o[ij[:, 0]]
    return ij[np.einsum("ij,ij->i", diff, diff) < d * d]


def _cells(offset):
    return {tuple(int(x) for x in c) for c in touched_cells(offset)}


def test_cells_a_segment_touches_by_hand():
    # a face neighbour passes through the shared face's centre: its two cells only
    assert _cells((1, 0, 0)) == {(0, 0, 0), (1, 0, 0)}
    # an edge diagonal through the shared edge's midpoint: the four cells around that edge
    assert _cells((1, 1, 0)) == {(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)}
    # the body diagonal through the shared corner: all eight cells of the 2×2×2 block
    assert _cells((1, 1, 1)) == {(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)}
    # y = x/2 from (0,0) to (2,1): through (0.5, 0.25), (1, 0.5) (an edge), (1.5, 0.75)
    assert _cells((2, 1, 0)) == {(0, 0, 0), (1, 0, 0), (1, 1, 0), (2, 1, 0)}
    assert _cells((-1, 1, 0)) == {(0, 0, 0), (-1, 0, 0), (0, 1, 0), (-1, 1, 0)}


def test_lattice_is_found_and_refused():
    a = np.array([[0.25, 1.0, 3.0], [1.25, 1.0, 3.0]])
    b = a + [0.5, 0.5, 0.0]
    lo, s, ijk = lattice_of(np.concatenate([a, b]), a, b)
    assert s == pytest.approx(0.5) and (ijk[2:] - ijk[:2]).tolist() == [[1, 1, 0], [1, 1, 0]]
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, 1, (50, 3)), rng.uniform(0, 1, (50, 3))
    assert lattice_of(np.concatenate([a, b]), a, b) is None


@pytest.mark.parametrize("make,kw,dropped", [
    (cases.l_bracket, dict(w=4, H=12, lx=10), 1),     # the diagonal through the inner corner
    (cases.l_bracket, {}, 1),
    (cases.cantilever, dict(nx=9, ny=4), 0),            # convex: nothing to drop
    (cases.cantilever, {}, 0),
    (cases.plate_hole, {}, 0),                          # the hole's staircase: all inside
])
def test_validation_cases_match_the_sampling_test(make, kw, dropped):
    sc = make(body="bind-inside", **kw)
    coeff = next(o for o in sc.operators["body"] if isinstance(o, Bind)).coeff
    o = sc.groups["body"].o
    ij = _pairs(o, coeff.d)
    fast = segments_inside(coeff.region, o[ij[:, 0]], o[ij[:, 1]], coeff.d, report=False)
    old = sampled(coeff.region, o[ij[:, 0]], o[ij[:, 1]], coeff.d)
    assert fast.tolist() == old.tolist()
    assert int((~fast).sum()) == dropped
    if make is cases.l_bracket:                  # by geometry: its midpoint is the corner
        (a, b), = ij[~fast]
        g = sc.params
        corner = (g["w"] - 0.5, g["H"] - g["w"] - 0.5)
        assert np.allclose(((o[a] + o[b]) / 2)[:2], corner)


def _slab(o, ij, lo, hi):
    z = np.minimum(o[ij[:, 0], 2], o[ij[:, 1], 2]), np.maximum(o[ij[:, 0], 2], o[ij[:, 1], 2])
    return ij[(z[0] >= lo) & (z[1] <= hi)]


def test_bracket_mesh_drops_its_re_entrant_edge_as_sampling_does():
    """At spacing 1 the lattice's sites are half a spacing inside the bracket's flat faces: the
    only bindings across free space are the diagonals through the re-entrant edge x = 3,
    y = 27 (one per z layer, 16 layers); the holes' staircase keeps all of its bindings."""
    surf = read_surface(STL)
    o = fill(surf, 1.0)
    ij = _pairs(o, 1.5)
    fast = segments_inside(surf, o[ij[:, 0]], o[ij[:, 1]], 1.5, report=False)
    gone = ij[~fast]
    mid = (o[gone[:, 0]] + o[gone[:, 1]]) / 2
    assert len(gone) == 16 and np.allclose(mid[:, :2], [3.0, 27.0])
    assert sorted(mid[:, 2]) == [k + 0.5 for k in range(16)]
    # the sampling test on the layers through the holes (z 5.5 … 10.5) and the corner
    part = _slab(o, ij, 5.0, 11.0)
    want = sampled(surf, o[part[:, 0]], o[part[:, 1]], 1.5)
    got = segments_inside(surf, o[part[:, 0]], o[part[:, 1]], 1.5, report=False)
    assert got.tolist() == want.tolist() and int((~want).sum()) == 6


def test_a_turned_mesh_matches_sampling_on_its_sloped_faces():
    """Turned 30° about z the bracket's faces are sloped to the lattice: a staircase of
    diagonals along every face, decided by the ray test; the sampling test agrees on each."""
    surf = read_surface(STL, rotate=[0, 0, 30])
    o = fill(surf, 0.8)
    ij = _slab(o, _pairs(o, 1.2), 6.0, 9.0)
    want = sampled(surf, o[ij[:, 0]], o[ij[:, 1]], 1.2)
    got = segments_inside(surf, o[ij[:, 0]], o[ij[:, 1]], 1.2, report=False)
    assert (~want).sum() > 0
    assert got.tolist() == want.tolist()


def test_points_off_a_lattice_are_sampled():
    rng = np.random.default_rng(2)
    ball = Sphere((0, 0, 0), 1.0) - Sphere((0.9, 0, 0), 0.5)
    a, b = rng.uniform(-1, 1, (300, 3)), rng.uniform(-1, 1, (300, 3))
    got = segments_inside(ball, a, b, 3.0, report=False)
    assert got.tolist() == sampled(ball, a, b, 3.0).tolist() and 0 < got.sum() < 300


def test_one_line_when_not_a_terminal(capfd):
    box = Box((-.5, -.5, -.5), (3.5, .5, .5))
    o = np.column_stack([np.arange(4.0), np.zeros(4), np.zeros(4)])
    segments_inside(box, o[:-1], o[1:], 1.5, name="beam", report=True)
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bind inside beam: 3 bindings" in err[0]


@pytest.mark.slow
def test_bench_inside_writes_its_table(tmp_path):
    from rackstress.bench import inside as bench

    data = bench.run_bench(tmp_path, sizes=(1500,), echo=lambda *a: None)
    (row,) = data["sizes"]
    assert row["old_tested"] == row["bindings"] and row["differ"] == 0
    assert (tmp_path / "inside.md").read_text().count("|") > 20
    assert (tmp_path / "inside.json").is_file()


def test_a_binding_on_the_parts_own_face_is_inside():
    """A lattice layer on the part's face (the bracket's 3 mm leg at spacing 0.4: sites at
    x = 0.2 … 3.0) is bound along the face: a segment on the closed part crosses no free space
    (was dropped: 20,377 of the bracket's 361,620 bindings at 0.4, the whole face layer held by
    the interior alone). By the bracket's geometry (leg x 0..3, arm y 27..30, holes r = 2
    about (y, z) = (6, 8) and (16, 8)): on the leg's face x = 3 and on the arm's face y = 27
    inside; across the re-entrant edge x = 3, y = 27 (its midpoint at x 3.2, y 26.8 in free
    space) and through a hole not; on the L of two boxes, the face x = −0.5 inside and the
    diagonal through its re-entrant corner not."""
    surf = read_surface(STL)
    a = np.array([[3.0, 1.0, 0.6], [3.0, 1.0, 0.6], [10.0, 27.0, 0.6], [2.6, 1.0, 0.6],
                  [3.0, 26.6, 0.6], [2.2, 6.2, 8.2], [3.0, 12.0, 8.0]])
    b = np.array([[3.0, 1.4, 0.6], [3.0, 1.4, 1.0], [10.4, 27.0, 1.0], [2.6, 1.4, 0.6],
                  [3.4, 27.0, 0.6], [2.2, 6.2, 8.6], [3.0, 12.4, 8.0]])
    want = [True, True, True, True, False, False, True]
    assert sampled(surf, a, b, 0.6).tolist() == want
    assert segments_inside(surf, a, b, 0.6).tolist() == want
    L = Box((-.5, -.5, -.5), (.5, 1.5, .5)) | Box((-.5, .5, -.5), (1.5, 1.5, .5))
    a2 = np.array([[-0.5, 0, 0], [0, 0, 0], [0.5, 0, 0]])
    b2 = np.array([[-0.5, 1, 0], [1, 1, 0], [1.5, 1, 0]])
    assert sampled(L, a2, b2, 1.5).tolist() == [True, False, False]


def test_a_solids_own_pairs_are_tested_once_per_run(tmp_path):
    """The scene's memory estimate, the deck and the static solver each ask a solid for its
    own pairs' inside test (at spacing 0.4 the bracket's run printed 'bind inside' 4 times,
    11–18 s each): the answer is remembered for the same positions and pairs, asked again for
    others. A real run of the bracket with the test's report forced prints it once."""
    import subprocess
    import sys

    from rackstress.scenes import load

    sc = load(str(STL.parent / "static.toml"), {"spacing": 1.0})
    sol = next(op for op in sc.operators["bracket"] if isinstance(op, Bind)).coeff
    o = sc.groups["bracket"].o
    ij = _pairs(o, 1.5)
    first = sol.inside_pairs(o, ij[:, 0], ij[:, 1])
    assert sol.inside_pairs(o, ij[:, 0], ij[:, 1]) is first
    again = sol.inside_pairs(o, ij[:-1, 0], ij[:-1, 1])
    assert again is not first and np.array_equal(again, first[:-1])
    code = ("import sys, rackstress.model.inside as m; m.REPORT_AT = 0; "
            "from rackstress.cli import main; sys.argv = ['rackstress', 'run', "
            f"'{STL.parent / 'static.toml'}', '--out', '{tmp_path / 'run'}', '--no-render']; "
            "main()")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("bind inside bracket") == 1, r.stderr


def test_a_solids_remembered_answers_die_with_it():
    """Solid remembers its inside test, its own pairs' test and its boundary fractions by
    ``id(self)``. Two shapes, the same segments (by hand): in an L of three unit cells the
    diagonal (0,0)–(1,1) crosses the missing corner cell, so it is outside; in the square of all
    four it is inside. A Solid of the L asked, then collected: its entries are gone from all
    three stores, so a Solid of the square made after it (CPython may give it the L's address)
    reads its own shape, not the L's answer."""
    import gc

    from rackstress.model import solid as S

    a = np.array([[0.0, 0, 0], [0, 0, 0]])
    b = np.array([[0.0, 1, 0], [1, 1, 0]])
    L = Box((-.5, -.5, -.5), (.5, 1.5, .5)) | Box((-.5, .5, -.5), (1.5, 1.5, .5))
    square = Box((-.5, -.5, -.5), (1.5, 1.5, .5))
    o = np.array([[0.0, 0, 0], [0, 1, 0], [1, 1, 0]])
    first = S.Solid(1.5, 20.0, L, spacing=1.0, part=L)
    assert first.inside(a, b).tolist() == [True, False]
    first.inside_pairs(o, np.array([0, 0]), np.array([1, 2]))
    first.fractions(o)
    gone = id(first)
    assert all(gone in store for store in (S._INSIDE, S._PAIRS, S._FRACTIONS))
    del first
    gc.collect()
    assert not any(gone in store for store in (S._INSIDE, S._PAIRS, S._FRACTIONS))
    second = S.Solid(1.5, 20.0, square, spacing=1.0, part=square)
    assert second.inside(a, b).tolist() == [True, True]
