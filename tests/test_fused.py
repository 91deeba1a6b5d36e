"""The callback's fused step (``kernels.step``, ``callback.Fused``): one compiled pass a step.

Expected values come from independent paths: the overlapping pairs of a candidate list from
NumPy (d² < R² over every candidate), the trajectories from the callback's term-by-term path
(bit for bit: the fused pass promises the same sums in the same order), its NumPy path and the
reference engine (1e-10).
"""
from __future__ import annotations

import numpy as np
import pytest

from rackstress import (Collide, Const, Contact, Dampen, Group, Phase, Scene, lattice,
                        scenes)
from rackstress.engines.driver import drive
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import LammpsRun
from rackstress.engines.reference import Reference
from rackstress.model import kernels as K
from rackstress.model.operators import contact_candidates

from test_lammps_backend import every_operator_scene


def _step_lists(x, ca, cb, cR2, loff, state, h):
    """kernels.step with no terms: only the contact lists' overlapping pairs (ov, ovn)."""
    n = len(x)
    ov, ovn, near, nnear, valid, urow, uoff, uref = state[:8]
    nR2, reach2 = state[8:] if len(state) > 8 else (np.empty(len(ca)), np.empty(len(ca)))
    out = K.step(x, np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((0, 3)), np.zeros(0),
                 np.zeros((0, 8), np.int64), np.zeros((0, 3)), np.zeros(1, np.int64),
                 np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, np.int64),
                 np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0),
                 np.zeros(0, np.int64), ca, cb, cR2, loff, ov, np.empty((len(ca), 2), np.int64),
                 np.empty((len(ca), 4)), ovn, near, nR2, reach2, nnear, valid, urow, uoff, uref,
                 h, np.zeros((n, 3)), np.zeros(n, np.bool_), np.zeros(n, np.int64),
                 np.zeros(1, np.int64), np.ones(n), np.arange(1, n + 1, dtype=np.int32), n,
                 np.zeros((0, 3)), np.zeros(0), 0, 0)
    return out


def test_near_candidates_find_every_overlap_as_a_full_pass():
    """Particles drifting and jittering (steps from 0.001 to 0.4, some beyond h/2 in one go):
    at every step the overlapping pairs, in list order, are those of NumPy's d² < R² over
    every candidate, though most steps measure only the near candidates."""
    rng = np.random.default_rng(7)
    n = 60
    x = rng.uniform(0.0, 6.0, size=(n, 3))
    # two lists: rows 0-29 against 30-59, and 10-19 against themselves (both orders)
    a1, b1 = np.meshgrid(np.arange(30), np.arange(30, 60), indexing="ij")
    a2, b2 = np.meshgrid(np.arange(10, 20), np.arange(10, 20), indexing="ij")
    keep = a2 != b2
    ca = np.concatenate([a1.ravel(), a2[keep]]).astype(np.int64)
    cb = np.concatenate([b1.ravel(), b2[keep]]).astype(np.int64)
    loff = np.array([0, 900, len(ca)], np.int64)
    cR2 = rng.uniform(0.5, 2.0, size=len(ca)) ** 2
    flag = np.zeros(n, np.bool_)
    rows = [K.members(ca[loff[L]:loff[L + 1]], cb[loff[L]:loff[L + 1]], flag) for L in (0, 1)]
    assert sorted(rows[1]) == list(range(10, 20)) and not flag.any()
    state = (np.empty(len(ca), np.int64), np.zeros(2, np.int64),
             np.empty((len(ca), 3), np.int64),
             np.zeros(2, np.int64), np.zeros(2, np.int64),
             np.concatenate(rows).astype(np.int64),
             np.array([0, len(rows[0]), len(rows[0]) + len(rows[1])], np.int64),
             np.zeros((len(rows[0]) + len(rows[1]), 3)), np.empty(len(ca)), np.empty(len(ca)))
    h = 0.5
    reused = remeasured = seen = 0
    for step in range(400):
        scale = rng.choice([0.001, 0.01, 0.05, 0.4], p=[0.4, 0.3, 0.25, 0.05])
        x = x + rng.normal(scale=scale, size=x.shape)
        before = state[3].copy()
        nrows, L, k = _step_lists(x, ca, cb, cR2, loff, state, h)
        assert L == -1
        d2 = ((x[cb] - x[ca]) ** 2).sum(axis=1)
        for L in (0, 1):
            expect = np.flatnonzero(d2[loff[L]:loff[L + 1]] < cR2[loff[L]:loff[L + 1]])
            got = state[0][loff[L]:loff[L] + state[1][L]] - loff[L]
            np.testing.assert_array_equal(got, expect)
            seen += len(expect)
        # the near lists were chosen again (their sizes changed) on some steps, not on all
        changed = int((before != state[3]).any())
        remeasured += changed
        reused += 1 - changed
    assert seen > 100 and remeasured > 10 and reused > 10


def test_near_sets_kept_while_a_list_moves_as_one():
    """Two groups carried together (a body and its legs) by 0.6 a step, more than h/2 = 0.25,
    with a small relative jitter: the near candidates are not measured again (their reference
    positions stay), and the overlapping pairs are still NumPy's d² < R² over every
    candidate, in list order; a relative move past h/2 does measure them again."""
    rng = np.random.default_rng(11)
    n = 40
    x = rng.uniform(0.0, 5.0, size=(n, 3))
    a, b = np.meshgrid(np.arange(20), np.arange(20, 40), indexing="ij")
    ca, cb = a.ravel().astype(np.int64), b.ravel().astype(np.int64)
    loff = np.array([0, len(ca)], np.int64)
    cR2 = rng.uniform(0.8, 2.0, size=len(ca)) ** 2
    state = (np.empty(len(ca), np.int64), np.zeros(1, np.int64),
             np.empty((len(ca), 3), np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64),
             np.arange(n, dtype=np.int64), np.array([0, n], np.int64), np.zeros((n, 3)),
             np.empty(len(ca)), np.empty(len(ca)))
    _step_lists(x, ca, cb, cR2, loff, state, 0.5)
    ref = state[7].copy()
    for step in range(30):
        x = x + np.array([0.6, -0.3, 0.2]) + rng.normal(scale=0.002, size=x.shape)
        assert _step_lists(x, ca, cb, cR2, loff, state, 0.5)[1] == -1
        np.testing.assert_array_equal(state[7], ref)          # not measured again
        expect = np.flatnonzero(((x[cb] - x[ca]) ** 2).sum(axis=1) < cR2)
        np.testing.assert_array_equal(state[0][:state[1][0]], expect)
    assert len(expect) > 5
    x[3] += 0.3         # one particle, relative to the others: measured again
    _step_lists(x, ca, cb, cR2, loff, state, 0.5)
    np.testing.assert_array_equal(state[7], x)


def test_relist_keeps_the_lists_not_renewed():
    """kernels.relist after one list of two was renewed and the other moved to a new place:
    the kept list's near candidates (their indices shifted by its move), reference positions,
    (R + h)² and near count are the old ones, the new list is to be measured in full and has
    its distinct rows in order of first appearance; the next step's overlapping pairs are
    NumPy's d² < R² over every candidate."""
    rng = np.random.default_rng(5)
    n = 50
    x = rng.uniform(0.0, 5.0, size=(n, 3))

    def pairs(ra, rb):
        a, b = np.meshgrid(ra, rb, indexing="ij")
        return a.ravel().astype(np.int64), b.ravel().astype(np.int64)

    lists = [pairs(np.arange(0, 10), np.arange(10, 25)), pairs(np.arange(25, 35),
                                                              np.arange(35, 50))]
    R2 = [rng.uniform(0.8, 2.0, size=len(a)) ** 2 for a, _ in lists]
    ca, cb = np.concatenate([a for a, _ in lists]), np.concatenate([b for _, b in lists])
    cR2 = np.concatenate(R2)
    loff = np.array([0, len(lists[0][0]), len(ca)], np.int64)
    flag = np.zeros(n, np.bool_)
    rows = [K.members(a, b, flag) for a, b in lists]
    N = len(ca)
    state = (np.empty(N, np.int64), np.zeros(2, np.int64), np.empty((N, 3), np.int64),
             np.zeros(2, np.int64), np.zeros(2, np.int64), np.concatenate(rows),
             np.array([0, len(rows[0]), len(rows[0]) + len(rows[1])], np.int64),
             np.zeros((len(rows[0]) + len(rows[1]), 3)), np.empty(N), np.empty(N))
    _step_lists(x, ca, cb, cR2, loff, state, 0.5)
    x = x + rng.normal(scale=0.01, size=x.shape)
    # list 0 renewed (fewer candidates, its rows in another order), list 1 kept: [new, old 1]
    na, nb = pairs(np.arange(9, -1, -1), np.arange(12, 25))
    nR2_ = rng.uniform(0.8, 2.0, size=len(na)) ** 2
    ca2, cb2 = np.concatenate([na, lists[1][0]]), np.concatenate([nb, lists[1][1]])
    cR22 = np.concatenate([nR2_, R2[1]])
    loff2 = np.array([0, len(na), len(ca2)], np.int64)
    N2 = len(ca2)
    near, nR2, reach2 = np.empty((N2, 3), np.int64), np.empty(N2), np.empty(N2)
    ov, ovn, o_near, o_nnear, o_valid, o_urow, o_uoff, o_uref, o_nR2, o_reach2 = state
    # the new list's candidates in place, the kept one's left for relist to move
    ja, jb, jR2 = np.zeros(N2, np.int64), np.zeros(N2, np.int64), np.zeros(N2)
    ja[:len(na)], jb[:len(na)], jR2[:len(na)] = na, nb, nR2_
    urow, uoff, uref, nnear, valid = K.relist(
        ja, jb, jR2, loff2, np.array([-1, 1], np.int64), flag, ca, cb, cR2, loff, o_near,
        o_nR2, o_reach2, o_nnear, o_valid, o_urow, o_uoff, o_uref, near, nR2, reach2)
    np.testing.assert_array_equal(ja, ca2)
    np.testing.assert_array_equal(jb, cb2)
    np.testing.assert_array_equal(jR2, cR22)
    assert list(valid) == [0, 1] and nnear[1] == o_nnear[1] > 5 and not flag.any()
    first = list(dict.fromkeys(np.concatenate([na, nb]).tolist()))
    assert urow[:uoff[1]].tolist() == first
    np.testing.assert_array_equal(urow[uoff[1]:], o_urow[o_uoff[1]:])
    np.testing.assert_array_equal(uref[uoff[1]:], o_uref[o_uoff[1]:])
    k, o0 = loff2[1], loff[1]
    m = nnear[1]
    np.testing.assert_array_equal(near[k:k + m, :2], o_near[o0:o0 + m, :2])
    np.testing.assert_array_equal(near[k:k + m, 2], o_near[o0:o0 + m, 2] - o0 + k)
    np.testing.assert_array_equal(nR2[k:k + m], o_nR2[o0:o0 + m])
    np.testing.assert_array_equal(reach2[k:], o_reach2[o0:])
    state2 = (np.empty(N2, np.int64), np.zeros(2, np.int64), near, nnear, valid, urow, uoff,
              uref, nR2, reach2)
    _step_lists(x, ca2, cb2, cR22, loff2, state2, 0.5)
    d2 = ((x[cb2] - x[ca2]) ** 2).sum(axis=1)
    for L in (0, 1):
        expect = np.flatnonzero(d2[loff2[L]:loff2[L + 1]] < cR22[loff2[L]:loff2[L + 1]])
        got = state2[0][loff2[L]:loff2[L] + state2[1][L]] - loff2[L]
        np.testing.assert_array_equal(got, expect)
    assert state2[1].sum() > 5


def test_step_reports_a_coincident_pair():
    """A candidate pair at d = 0 stops the step (nothing written) and names the list and the
    candidate: the first coincident one in list order."""
    x = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [5.0, 0, 0]])
    ca, cb = np.array([0, 1, 0], np.int64), np.array([1, 2, 3], np.int64)
    loff = np.array([0, 3], np.int64)
    state = (np.empty(3, np.int64), np.zeros(1, np.int64), np.empty((3, 3), np.int64),
             np.zeros(1, np.int64), np.zeros(1, np.int64), np.arange(4, dtype=np.int64),
             np.array([0, 4], np.int64), np.zeros((4, 3)))
    assert tuple(_step_lists(x, ca, cb, np.full(3, 4.0), loff, state, 0.5))[1:] == (0, 1)


def _final(scene, fuse: bool, monkeypatch, kernels="numba"):
    monkeypatch.setenv("RACKSTRESS_KERNELS", kernels)
    run = LammpsRun(compile_deck(scene, "exact"), None)
    try:
        run.py.fuse = fuse and run.py.fuse
        run.run_schedule()
        used = [p is not None for p in run.py._plans.values()]
        return run.gather_positions(), run.gather_velocities(), used
    finally:
        run.close()


@pytest.mark.lammps
@pytest.mark.parametrize("name", ["every-operator", "magpod-small"])
def test_fused_pass_equals_the_term_by_term_path(name, monkeypatch):
    """Every operator kind through two phase switches (contact-conditioned damping, one-way
    and reciprocal collides, binds folded and within(d), attraction by phase, a force), and 300
    MagPod iterations with the soles landing on the resting sediment: the fused pass gives the
    term-by-term path's trajectory bit for bit, and the reference engine's to 1e-10."""
    scene = (every_operator_scene(steps=60) if name == "every-operator"
             else scenes.build("magpod-small").with_steps(300))
    p, v, used = _final(scene, True, monkeypatch)
    p0, v0, unused = _final(scene, False, monkeypatch)
    assert used and all(used) and not unused        # every phase fused, then none
    assert np.abs(p - scene.original_positions()).max() > 0.1      # it moved
    np.testing.assert_array_equal(p, p0)
    np.testing.assert_array_equal(v, v0)
    if name == "every-operator":
        ref = Reference(scene)
        drive(ref)
        assert np.abs(p - ref.p).max() <= 1e-10


@pytest.mark.lammps
def test_fused_contact_damping_follows_the_contact():
    """A block thrown at a loose bed (a layer held by nothing but its damping) meets it and
    partly passes through it; its damping extra holds only while it touches the bed (Eq. 28's
    ⟨contact⟩): the fused pass equals the reference engine to 1e-10, through a contact that
    began and ended."""
    block = Group("block", lattice((2, 2, 2), 1.0, origin=(1.0, 3.0, 1.0)), 0.5, kind="body")
    block.v0 = np.tile([0.0, -20.0, 0.0], (8, 1))
    bed = Group("bed", lattice((5, 1, 5), 1.0), 0.5, kind="leg")
    ops = {"block": [Collide("bed", Const(400.0)), Dampen(0.0, extra=3.0, when=(Contact("bed"),))],
           "bed": [Collide("block", Const(400.0)), Dampen(0.5)]}
    sc = Scene("through", {"block": block, "bed": bed}, ops, [Phase("fall", 120, {})], dt=0.01)
    run = LammpsRun(compile_deck(sc, "exact"), None)
    try:
        assert run.py.fuse
        run.run_schedule()
        assert all(p is not None for p in run.py._plans.values())
        p = run.gather_positions()
    finally:
        run.close()
    ref = Reference(sc)
    drive(ref)
    assert np.abs(p - ref.p).max() <= 1e-10
    # the block started 3 units above the bed (no contact); only a touch can slow it (its one
    # force is the collide, its damping holds only in contact), and it ended well short of
    # free flight (y0 − 20·1.2); at the end no block particle touches a bed particle (d ≥ 1)
    o = sc.original_positions()
    assert o[:8, 1].min() - o[8:, 1].max() == pytest.approx(3.0)
    assert np.all(ref.p[:8, 1] > o[:8, 1] - 20.0 * 1.2 + 1.0)
    d = np.linalg.norm(ref.p[:8, None] - ref.p[None, 8:], axis=2)
    assert d.min() > 1.0


def _block_in_order(x, t0, m, s0, n, q, cI, cJ, fold, acc):
    """Eq. 12 over every (target, source) pair of a block in plain Python floats, in the order
    the kernels document: a target's sum over its sources in source order, a source's reverse
    sum over its targets in target order from 0, added to its row after the block."""
    out = acc.copy()
    rev = np.zeros((n, 3))
    for s in range(n):
        for t in range(m):
            d = [float(x[s0 + s, k]) - float(x[t0 + t, k]) for k in range(3)]
            w = 1.0 - float(q[s][t]) / (d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            ct, e = float(cI[s][t]) * w, float(cJ[s][t]) * w
            for k in range(3):
                out[t0 + t, k] = float(out[t0 + t, k]) + ct * d[k]
                rev[s, k] = float(rev[s, k]) - e * d[k]
    if fold:
        out[s0:s0 + n] += rev
    return out


@pytest.mark.parametrize("m,n", [(1, 1), (5, 3), (127, 4), (128, 5), (129, 9), (300, 6)])
def test_bind_blocks_sum_in_the_documented_order(m, n):
    """kernels.bind_block and bind_block_const (targets taken a tile at a time, four sources'
    reverse sums at once) give, bit for bit, the plain sequential sums of every pair in the
    order they document, on blocks smaller than, equal to and across the tile size."""
    rng = np.random.default_rng(m * 31 + n)
    x = rng.normal(scale=3.0, size=(m + n + 4, 3))
    o = x + rng.normal(scale=0.3, size=x.shape)        # original positions
    t0, s0 = 2, 2 + m + 1
    # L0² as Bind.pairs has it: (u_o − p_o)·(u_o − p_o) in the order x, y, z
    e = [o[s0:s0 + n, k][:, None] - o[t0:t0 + m, k][None, :] for k in range(3)]
    q = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
    cI, cJ = rng.uniform(0.5, 3.0, size=(n, m)), rng.uniform(0.5, 3.0, size=(n, m))
    acc = rng.normal(size=(len(x), 3))
    for fold in (True, False):
        got = acc.copy()
        K.bind_block(x, t0, m, s0, n, q, cI, cJ, fold, got)
        np.testing.assert_array_equal(got, _block_in_order(x, t0, m, s0, n, q, cI, cJ, fold,
                                                           acc))
        got = acc.copy()
        oc = np.concatenate([o[t0:t0 + m].T.ravel(), o[s0:s0 + n].ravel()])
        K.bind_block_const(x, t0, m, s0, n, oc, 2.5, 0.75, fold, got)
        full = np.full((n, m), 2.5), np.full((n, m), 0.75)
        np.testing.assert_array_equal(got, _block_in_order(x, t0, m, s0, n, q, *full, fold,
                                                           acc))


def test_compiled_watchdog_pass_agrees_with_the_watchdog():
    """The LAMMPS runner's one-pass watchdog test (rows in any order, by atom id) is true
    exactly when the NumPy watchdog finds nothing: in bound, beyond it, NaN and infinite
    positions or velocities, and a finite velocity so large that NumPy's sum overflows."""
    from rackstress.engines.watchdog import find_divergence

    sc = scenes.build("plane-bound", d=2.0)
    o = sc.original_positions()
    n = len(o)
    rng = np.random.default_rng(3)
    bound2 = float(sc.bound) ** 2
    cases = []
    for kind in ("ok", "far", "nan-x", "inf-v", "nan-v", "huge-v", "edge"):
        x = o + rng.normal(scale=2.0, size=o.shape)
        v = rng.normal(size=o.shape)
        k = int(rng.integers(n))
        if kind == "far":
            x[k, 1] = o[k, 1] + 1.0001 * sc.bound
        elif kind == "nan-x":
            x[k, 2] = np.nan
        elif kind == "inf-v":
            v[k, 0] = -np.inf
        elif kind == "nan-v":
            v[k, 1] = np.nan
        elif kind == "huge-v":
            v[:, 0] = 1e308           # finite, but their sum is not
        elif kind == "edge":
            x[k] = o[k] + np.array([sc.bound, 0.0, 0.0])       # exactly at the bound: inside
        cases.append((kind, x, v))
    for kind, x, v in cases:
        perm = rng.permutation(n)              # LAMMPS' rows in another order
        tag = (perm + 1).astype(np.int64)
        fast = K.within_bound(np.ascontiguousarray(x[perm]), np.ascontiguousarray(v[perm]), o,
                              tag, bound2)
        with np.errstate(over="ignore"):       # huge-v: the sum overflows, as meant
            slow = find_divergence(sc, x[perm], v[perm], o[perm], perm)
        assert fast == (slow is None), kind
        assert fast == (kind in ("ok", "huge-v", "edge")), kind


def test_candidate_search_equals_a_full_search():
    """kernels.candidates (cell grid over the joint region only, pairs put in particle order
    as found) gives the pairs of the NumPy path's cKDTree search (operators.contact_candidates)
    over every particle, in the order of a full sort by particles: two bodies touching at a
    joint, random clouds, one group against itself, rows not in particle order, a wider
    near radius; and the near rows of both sides are those of a distance matrix."""
    rng = np.random.default_rng(11)
    # a body and a leg meeting at a hip (lattices of spacing 2, as MagPod's)
    g = np.stack(np.meshgrid(np.arange(20), np.arange(6), np.arange(8), indexing="ij"),
                 -1).reshape(-1, 3)[:, [0, 1, 2]] * 2.0
    leg = np.stack(np.meshgrid(np.arange(3), np.arange(15), np.arange(3), indexing="ij"),
                   -1).reshape(-1, 3) * 2.0 + [3.1, -29.0, 4.3]
    cases = [(np.concatenate([g, leg]), len(g), False, 6.0, 6.0, False)]
    for trial in range(60):
        n = int(rng.integers(2, 250))
        x = rng.uniform(0.0, rng.uniform(2.0, 25.0), size=(n, 3))
        x[: n // 3] += [rng.uniform(0.0, 30.0), 0.0, 0.0]
        cut = rng.uniform(0.5, 5.0)
        cases.append((x, int(rng.integers(1, n)), trial % 4 == 0, cut,
                      cut + rng.choice([0.0, rng.uniform(0.0, 3.0)]), trial % 2 == 1))
    found, first = 0, None
    for x, k, same, cut, wide, shuffle in cases:
        n = len(x)
        tag = (rng.permutation(n) + 1 if shuffle else np.arange(1, n + 1)).astype(np.int32)
        if same:
            ia = ib = rng.permutation(n)[: n // 2 + 1].astype(np.int64)
        else:
            ia, ib = np.arange(k, dtype=np.int64), rng.permutation(np.arange(k, n))
        a, b, near_a, near_b = K.candidates(x, ia, ib, cut, same, tag, wide)
        ea, eb = contact_candidates(x[ia], x[ib], cut, same=same)
        ea, eb = ia[ea], ib[eb]
        order = np.lexsort((tag[eb], tag[ea]))
        np.testing.assert_array_equal(a, ea[order])
        np.testing.assert_array_equal(b, eb[order])
        d2 = ((x[ib][None, :, :] - x[ia][:, None, :]) ** 2).sum(-1)
        w = d2 <= wide * wide
        if same:
            w[ia[:, None] == ib[None, :]] = False
        np.testing.assert_array_equal(near_a, ia[w.any(1)])
        np.testing.assert_array_equal(near_b, ib[w.any(0)])
        found += len(a)
        first = len(a) if first is None else first
    assert found > 1000 and first > 20


def test_bed_join_equals_sorting_the_joined_pairs():
    """kernels.bed_join (the resting bed's two searches merged in compiled code) gives what
    sorting the joined pairs by particles (np.lexsort) and uniting the near rows (np.union1d,
    np.unique) gives: searching rows in particle order, resting partners in any order (a
    grid's cells), activated ones sorted, rows not in particle order on the bed's side."""
    rng = np.random.default_rng(3)
    for trial in range(200):
        n = int(rng.integers(5, 120))
        na = int(rng.integers(1, n))
        tag = np.concatenate([np.arange(1, na + 1), na + 1 + rng.permutation(n - na)])
        tag = tag.astype(np.int32)
        ia = np.arange(na, dtype=np.int64)
        bed = np.arange(na, n)
        sa, sb, da, db = [], [], [], []
        for a in ia:                       # grouped by searching row, in ia's order
            part = rng.permutation(bed)[: int(rng.integers(0, 6))]
            k = int(rng.integers(0, len(part) + 1))
            sa += [a] * k
            sb += list(part[:k])                                # resting: cell order
            act = part[k:]
            act = act[np.argsort(tag[act])]
            da += [a] * len(act)
            db += list(act)                                     # activated: sorted
        sa, sb, da, db = (np.array(v, np.int64) for v in (sa, sb, da, db))
        snear_a = rng.random(na) < 0.3
        snear_b = rng.choice(bed, size=int(rng.integers(0, 30)))
        dnear_a = np.unique(rng.choice(ia, size=int(rng.integers(0, 5)))).astype(np.int64)
        dnear_b = rng.choice(bed, size=int(rng.integers(0, 5))).astype(np.int64)
        flag = np.zeros(n, np.bool_)
        a, b, near_a, near_b = K.bed_join(ia, sa, sb, snear_a, snear_b, da, db, dnear_a,
                                          dnear_b, tag, flag)
        ja, jb = np.concatenate([sa, da]), np.concatenate([sb, db])
        order = np.lexsort((tag[jb], tag[ja]))
        np.testing.assert_array_equal(a, ja[order])
        np.testing.assert_array_equal(b, jb[order])
        np.testing.assert_array_equal(near_a, np.union1d(ia[snear_a], dnear_a))
        np.testing.assert_array_equal(near_b, np.concatenate([np.unique(snear_b), dnear_b]))
        assert not flag.any()


def test_relative_motion_check():
    """kernels.moved_below_shifted: a translation common to both groups is not motion (a body
    and a leg walking together keep their list); a displacement of one particle relative to
    the others beyond the bound is; and whenever it says "below", every pairwise distance
    has changed by at most twice the bound (the list's guarantee)."""
    rng = np.random.default_rng(5)
    x0 = rng.uniform(0.0, 10.0, size=(40, 3))
    far = x0 + [7.0, -3.0, 2.5]
    assert K.moved_below_shifted(far, 0, 25, 25, 15, x0, 0.01)
    assert (np.linalg.norm(far - x0, axis=1) > 0.1).all()      # though every particle moved
    bump = far.copy()
    bump[30] += [0.0, 0.21, 0.0]          # 0.21 beyond the others: more than 2 × 0.1 apart
    assert not K.moved_below_shifted(bump, 0, 25, 25, 15, x0, 0.01)
    bump[30] -= [0.0, 0.02, 0.0]          # 0.19: the midpoint shift brings all within 0.1
    assert K.moved_below_shifted(bump, 0, 25, 25, 15, x0, 0.01)
    below = 0
    for trial in range(300):
        x = x0 + rng.normal(scale=3.0, size=3) + rng.normal(
            scale=rng.choice([0.01, 0.02, 0.05]), size=x0.shape)
        if K.moved_below_shifted(x, 0, 10, 20, 20, np.concatenate([x0[:10], x0[20:]]), 0.01):
            below += 1
            sub0, sub = np.concatenate([x0[:10], x0[20:]]), np.concatenate([x[:10], x[20:]])
            d0 = np.linalg.norm(sub0[:, None] - sub0[None], axis=-1)
            d = np.linalg.norm(sub[:, None] - sub[None], axis=-1)
            assert np.abs(d - d0).max() <= 0.2 + 1e-12
    assert 10 < below < 300


class _CountingSearch:
    """The compiled kernels, counting the contact candidate searches (kernels.candidates)."""

    def __init__(self, k):
        self.k, self.searches = k, 0

    def __getattr__(self, name):
        if name == "candidates":
            self.searches += 1
        return getattr(self.k, name)


class _NothingKept(dict):
    """Overlaps' kept lists, never kept: every list is searched again at every renewal."""

    def get(self, key, default=None):
        return default


def _search_every_step(overlaps):
    """Overlaps.renew replaced by dropping every list at every step: each step searches every
    list afresh (the brute-force reference of the callback's own renewal)."""
    def renew(fr):
        for key in [k for k in fr.memo if k[0] == "cand"]:
            del fr.memo[key]
    overlaps.renew = renew


@pytest.mark.lammps
@pytest.mark.parametrize("active_only", [True, False])
def test_lists_kept_by_relative_motion_equal_fresh_searches(monkeypatch, active_only):
    """The lists kept while their own particles have not moved half a skin (the body–leg lists
    judged by the groups' relative motion, kernels.moved_below_shifted) give the trajectory of
    searching every list afresh, bit for bit, over a phase switch of magpod-small, with fewer
    searches. Active only (the callback renews each list itself, Overlaps.renew): against a
    search of every list at every step. Every particle integrated (LAMMPS' reneighbouring
    renews the lists): against searching every list again at every reneighbouring."""
    monkeypatch.setenv("RACKSTRESS_KERNELS", "numba")
    scene = scenes.build("magpod-small", phase_steps=200, cycles=1).with_steps(400)
    out = []
    for keep in (True, False):
        run = LammpsRun(compile_deck(scene, "exact", active_only=active_only), None)
        try:
            assert (run.py.overlaps.own is not None) == active_only
            count = run.py.overlaps.k = _CountingSearch(run.py.overlaps.k)
            if not keep and active_only:
                _search_every_step(run.py.overlaps)
            elif not keep:
                run.py.overlaps._kept = _NothingKept()
            run.run_schedule()
            out.append((run.gather_positions(), run.gather_velocities(), count.searches))
        finally:
            run.close()
    (p, v, n), (p0, v0, n0) = out
    assert np.abs(p - scene.original_positions()).max() > 0.1
    np.testing.assert_array_equal(p, p0)
    np.testing.assert_array_equal(v, v0)
    assert 0 < n < n0
    if active_only:
        assert n0 >= 2 * 400 and n < n0 / 4


def test_warm_halves_compile_the_kernels_between_them():
    """``kernels.warm("step")`` and ``warm("rest")`` (the suite's two warm-up processes) load
    disjoint halves whose union is every kernel ``warm()`` loads: each counted in a fresh
    process by the dispatchers holding a signature. An unknown half is refused."""
    import subprocess
    import sys

    code = ("import sys; from rackstress.model import kernels as k; k.warm(sys.argv[1]); "
            "print(' '.join(sorted(n for n in dir(k) if getattr(getattr(k, n), 'signatures', "
            "None))))")
    got = {part: set(subprocess.run([sys.executable, "-c", code, part], capture_output=True,
                                    text=True, check=True).stdout.split())
           for part in ("all", "step", "rest")}
    assert {"step", "bind_block", "bed_join"} == got["step"]
    assert not got["step"] & got["rest"] and got["step"] | got["rest"] == got["all"]
    assert {"candidates", "collide_add", "collide_friction", "grid_candidates",
            "relist"} <= got["rest"]
    with pytest.raises(ValueError, match="unknown part 'both'"):
        K.warm("both")
