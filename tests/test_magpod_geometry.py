"""Geometry of the MagPod scenes (Section 4): counts, regions, and the initial pose."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from rackstress.model.operators import Attract, Collide, Dampen, Force, Matched, PhaseIn
from rackstress.scenes import BUILDERS, build

ORDER = ["body", "rightleg", "leftleg", "bodyrack", "rightrack", "leftrack", "sediment"]


@pytest.fixture(scope="module")
def full():
    return build("magpod")


@pytest.fixture(scope="module")
def small():
    return build("magpod-small")


def test_registered():
    assert "magpod" in BUILDERS and "magpod-small" in BUILDERS


def test_counts_full(full):
    assert list(full.groups) == ORDER
    n = {k: g.n for k, g in full.groups.items()}
    assert n == {"body": 2907, "rightleg": 382, "leftleg": 382, "bodyrack": 6, "rightrack": 6,
                 "leftrack": 6, "sediment": 30000}
    assert full.n_particles == 33689                     # Section 4.4
    kinds = [full.groups[k].kind for k in ORDER]
    assert kinds == ["body", "leg", "leg", "rack", "rack", "rack", "sediment"]
    assert [full.groups[k].host for k in ("bodyrack", "rightrack", "leftrack")] == \
        ["body", "rightleg", "leftleg"]


def test_radii_and_schedule(full, small):
    for sc in (full, small):
        assert np.all(sc.groups["body"].r == 1) and np.all(sc.groups["rightleg"].r == 1)
        assert np.all(sc.groups["sediment"].r == 2)
        assert [(p.vars["r"], p.vars["l"]) for p in sc.phases] == [(4, 6), (1, 7), (2, 8), (3, 5)]
        assert sc.dt == 0.01
    assert all(p.steps == 1200 for p in full.phases)
    assert all(p.steps == 300 for p in build("magpod-small", phase_steps=300).phases)
    assert build("magpod-small", cycles=3).cycles == 3


def test_small_sediment(small):
    assert small.groups["sediment"].n == 56 * 36
    assert build("magpod-small", sediment_nx=30, sediment_nz=25).groups["sediment"].n == 750
    assert small.groups["body"].n == 2907 and small.groups["leftleg"].n == 382


@pytest.mark.parametrize("which", ["full", "small"])
def test_regions_nonempty_and_matching(which, full, small):
    sc = full if which == "full" else small
    breg = sc.groups["body"].meta["regions"]
    assert sorted(breg) == [f"breg{k}" for k in range(1, 9)]
    for leg, key, rows in (("rightleg", "rreg", (1, 2, 3, 4)), ("leftleg", "lreg", (5, 6, 7, 8))):
        mag = sc.groups[leg].meta["regions"][key]
        assert len(mag) == 382 and (mag > 0).any()
        leg_values = set(np.unique(mag[mag > 0]))
        for k in rows:
            b = breg[f"breg{k}"]
            assert len(b) == 2907 and (b > 0).any()
            assert set(np.unique(b[b > 0])) == leg_values       # every index has a partner
        # the same index sits at the same place (column, row) of body patch and leg patch
        for k in rows:
            b = breg[f"breg{k}"]
            bo, lo = sc.groups["body"].o, sc.groups[leg].o
            for v in leg_values:
                db = bo[b == v].mean(axis=0) - bo[b > 0].mean(axis=0)
                dl = lo[mag == v].mean(axis=0) - lo[mag > 0].mean(axis=0)
                assert np.allclose(db[:2], dl[:2])               # x (along walk) and y (up)
    # right regions on the right (+z) side, left ones on the left
    bo = sc.groups["body"].o
    for k in range(1, 5):
        assert bo[breg[f"breg{k}"] > 0][:, 2].min() > 0
        assert bo[breg[f"breg{k + 4}"] > 0][:, 2].max() < 0
    # motion principle: 1 front, 2 middle, 3 rear (x); 4 above 3 (y)
    cx = {k: bo[breg[f"breg{k}"] > 0].mean(axis=0) for k in range(1, 9)}
    assert cx[1][0] > cx[2][0] > cx[3][0] and cx[5][0] > cx[6][0] > cx[7][0]
    assert cx[4][1] > cx[3][1] and cx[8][1] > cx[7][1]


@pytest.mark.parametrize("which", ["full", "small"])
def test_no_coincident_particles(which, full, small):
    sc = full if which == "full" else small
    o = sc.original_positions()
    assert len(cKDTree(o).query_pairs(1e-6)) == 0


def _min_gap(a, ra, b, rb):
    d, _ = cKDTree(b).query(a)
    return float((d - ra - rb).min())


@pytest.mark.parametrize("which", ["full", "small"])
def test_initial_pose(which, full, small):
    sc = full if which == "full" else small
    g = sc.groups
    sed = g["sediment"].o
    for leg in ("rightleg", "leftleg"):
        L = g[leg].o
        # stands on the sediment: never overlapping; the sole at y = 1 lies on the sediment's
        # top (y = 0) where it is above a sediment centre, and the sediment lattice (spacing 3)
        # does not line up with the sole's (spacing 2), so the smallest gap is a small positive
        gap = _min_gap(L, 1.0, sed, 2.0)
        assert 0.0 <= gap < 0.1
        # every particle within the foot's footprint has sediment below it
        assert L[:, 1].min() == pytest.approx(1.0)
        # does not overlap the body (the R region touches the body's side face)
        assert _min_gap(L, 1.0, g["body"].o, 1.0) >= -1e-9
        assert _min_gap(L, 1.0, g["body"].o, 1.0) == pytest.approx(0.0, abs=1e-9)
    # body floats above the sediment and above the feet
    assert g["body"].o[:, 1].min() - 1 > g["rightleg"].o[:, 1].min() + 10
    # legs stand on the sediment patch, not off its edge
    for leg in ("rightleg", "leftleg"):
        L = g[leg].o
        assert L[:, 0].min() > sed[:, 0].min() and L[:, 0].max() < sed[:, 0].max()
        assert L[:, 2].min() > sed[:, 2].min() and L[:, 2].max() < sed[:, 2].max()


def test_operators_follow_the_paper(full):
    ops = full.operators
    body = ops["body"]
    att = [o for o in body if isinstance(o, Attract)]
    assert [(o.source, o.coeff, o.when) for o in att] == [
        ("rightleg", Matched("breg{r}", "rreg", 200.0), (PhaseIn("r", (2, 3)),)),
        ("leftleg", Matched("breg{l}", "lreg", 200.0), (PhaseIn("l", (6, 7)),))]
    col = [o for o in body if isinstance(o, Collide)]
    assert [(o.source, o.coeff.c) for o in col] == [("rightleg", 100.0), ("leftleg", 100.0)]
    leg = ops["rightleg"]
    assert [o.coeff.c for o in leg if isinstance(o, Collide)] == [100.0, 5.0, 50.0]
    assert [o.accel for o in leg if isinstance(o, Force)] == [(0.0, -50.0, 0.0)]
    d = [o for o in leg if isinstance(o, Dampen)][0]
    assert (d.c, d.extra) == (10.0, 85.0)
    assert [o.coeff.c for o in ops["sediment"] if isinstance(o, Collide)] == [1.0, 1.0]
    assert [o.c for o in ops["sediment"] if isinstance(o, Dampen)] == [50.0]
    for r in ("bodyrack", "rightrack", "leftrack"):
        assert ops[r][0].coeff.c == 0.5 and ops[r][1].c == 1.0


@pytest.mark.parametrize("which", ["full", "small"])
def test_lifted_foot_clears_the_body(which, full, small):
    """Aligned with the lift region (4/8), a leg's foot stays below the floating body."""
    sc = full if which == "full" else small
    g = sc.groups
    breg = g["body"].meta["regions"]
    bo = g["body"].o
    for leg, key, low, lift in (("rightleg", "rreg", 3, 4), ("leftleg", "lreg", 5, 8)):
        rise = bo[breg[f"breg{lift}"] > 0][:, 1].mean() - bo[breg[f"breg{low}"] > 0][:, 1].mean()
        assert rise >= 4.0                      # the lift raises a leg by two particle rows
        R = g[leg].meta["regions"][key] > 0
        foot = g[leg].o[~R]
        under = (np.abs(foot[:, 2]) < np.abs(bo[:, 2]).max() + 1)
        if under.any():
            assert foot[under][:, 1].max() + 1 + rise < bo[:, 1].min() - 1
