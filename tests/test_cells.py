"""lib/cells.py: the pairs of points within r, and their count, by cells (what ``rackstress
run`` uses before its simulation instead of scipy.spatial), against scipy's cKDTree (an
independent path) and hand-placed points."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from rackstress.lib.cells import any_closer, close_pairs, count_within


def _tree_pairs(o, r):
    p = np.sort(cKDTree(o).query_pairs(r, output_type="ndarray").reshape(-1, 2), axis=1)
    return p[np.lexsort((p[:, 1], p[:, 0]))]


@pytest.mark.parametrize("n, r, scale", [(4000, 0.05, 1.0), (20000, 1e-9, 100.0),
                                         (1500, 0.3, 1.0), (3000, 1e-9, 1e6)])
def test_close_pairs_and_counts_are_those_of_a_kd_tree(n, r, scale):
    rng = np.random.default_rng(7)
    o = rng.random((n, 3)) * scale - scale / 3
    o = np.concatenate([o, o[:40] + r / 10, np.round(o[40:60], 1), o[60:61]])  # near, equal
    assert np.array_equal(close_pairs(o, r), _tree_pairs(o, r))
    p = o[:500] + 0.3 * r
    assert count_within(o, o, r) == cKDTree(o).count_neighbors(cKDTree(o), r)
    assert count_within(p, o, r) == cKDTree(p).count_neighbors(cKDTree(o), r)


def test_hand_placed_points():
    """Unit-cube corners, one point 0.5 off a corner and one on another: the pairs at most
    1 apart are the cube's 12 edges, the near one with its corner, the twin with its."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    o = np.concatenate([corners, [[0.0, 0.0, -0.5], [1.0, 1.0, 1.0]]])
    pairs = close_pairs(o, 1.0)
    assert len(pairs) == 12 + 1 + 3 + 1           # the twin of (1,1,1) also has its 3 edges
    assert [0, 8] in pairs.tolist() and [7, 9] in pairs.tolist()
    assert close_pairs(o, 0.1).tolist() == [[7, 9]]
    # every point with itself, the pairs both ways
    assert count_within(o, o, 1.0) == len(o) + 2 * len(pairs)
    assert count_within(o[:1], o, 0.49) == 1 and len(close_pairs(o[:1], 5.0)) == 0


def test_any_closer_is_what_a_kd_tree_query_with_an_upper_bound_finds():
    """``any_closer(a, b, r)`` (MagPod's gait report: does a sole touch the sediment?) against
    ``cKDTree(b).query(a, distance_upper_bound=r)``, strict as it is: a point at exactly r is
    not closer; random sets near and far, and hand-placed ones."""
    rng = np.random.default_rng(11)
    b = rng.random((5000, 3)) * 10.0
    for shift in (0.0, 0.3, 1.0, 10.2, 10.5, 30.0):
        for r in (0.05, 0.2, 0.6):
            a = rng.random((60, 3)) * 2.0 + shift
            tree = np.isfinite(cKDTree(b).query(a, distance_upper_bound=r)[0]).any()
            assert any_closer(a, b, r) == tree, (shift, r)
    one = np.array([[0.0, 0.0, 0.0]])
    assert not any_closer(np.array([[1.0, 0.0, 0.0]]), one, 1.0)         # exactly r: not closer
    assert any_closer(np.array([[1.0, 0.0, 0.0], [0.0, 0.999, 0.0]]), one, 1.0)
    assert not any_closer(one[:0], one, 1.0) and not any_closer(one, one, 0.0)
