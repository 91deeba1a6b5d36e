"""Each primitive operator of Section 2.3 against hand-computed accelerations.

Tiny scenes are built by hand and evaluated with ``Reference(scene).accelerations(phase)``;
every expected value below is worked out from the paper's equations (with the errata of docs/model.md),
written as plain arithmetic in the test.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from rackstress.errors import SceneError
from rackstress.model.operators import (Attract, Bind, Collide, Const, Contact, Dampen, Force, Matched,
                                  PhaseIn, Within)
from rackstress.model.particles import Group
from rackstress.engines.reference import Reference
from rackstress.model.scene import Phase, Scene


def make(groups: dict, ops: dict, phases=None, dt=0.01) -> Scene:
    """groups: name → (positions, radius[, meta])."""
    gs = {}
    for name, spec in groups.items():
        pos, radius = spec[0], spec[1]
        meta = spec[2] if len(spec) > 2 else {}
        gs[name] = Group(name, np.asarray(pos, dtype=float), radius, meta=dict(meta))
    return Scene("t", gs, ops, phases or [Phase("p", 1)], dt=dt)


def acc(scene: Scene, phase=None, p=None, v=None) -> dict:
    """Accelerations per group, after optionally overriding the state (global arrays)."""
    ref = Reference(scene)
    if p is not None:
        ref.p = np.asarray(p, dtype=float)
    if v is not None:
        ref.v = np.asarray(v, dtype=float)
    a = ref.accelerations(phase or {})
    return {name: a[scene.slice(name)] for name in scene.groups}


# ----------------------------------------------------------------------------- force (Eq. 8)
def test_force_masked_adds_accel_only_where_selected():
    # ‖o‖² = 0, 9, 16, 100: Eq. 15's ⟨‖o‖² < 10⟩ selects the first two.
    pos = [[0, 0, 0], [3, 0, 0], [0, 4, 0], [10, 0, 0]]
    sc = make({"g": (pos, 0.5)},
              {"g": [Force((0.0, 100.0, 0.0), where=(True, True, False, False))]})
    a = acc(sc)["g"]
    np.testing.assert_array_equal(a, [[0, 100, 0], [0, 100, 0], [0, 0, 0], [0, 0, 0]])


def test_force_unmasked_and_forces_sum():
    pos = [[0, 0, 0], [3, 0, 0]]
    sc = make({"g": (pos, 0.5)},
              {"g": [Force((1.0, 2.0, 3.0)), Force((0.0, -50.0, 0.0), where=(False, True))]})
    a = acc(sc)["g"]
    np.testing.assert_allclose(a, [[1, 2, 3], [1, -48, 3]], rtol=0, atol=1e-12)


def test_force_gated_by_phase_condition():
    sc = make({"g": ([[0, 0, 0]], 0.5)},
              {"g": [Force((0.0, 7.0, 0.0), when=(PhaseIn("r", (2, 3)),))]},
              phases=[Phase("a", 1, {"r": 2})])
    np.testing.assert_array_equal(acc(sc, {"r": 2})["g"], [[0, 7, 0]])
    np.testing.assert_array_equal(acc(sc, {"r": 3})["g"], [[0, 7, 0]])
    np.testing.assert_array_equal(acc(sc, {"r": 4})["g"], [[0, 0, 0]])


def test_phase_condition_on_missing_variable_is_a_scene_error():
    sc = make({"g": ([[0, 0, 0]], 0.5)},
              {"g": [Force((0.0, 7.0, 0.0), when=(PhaseIn("r", (2,)),))]})
    with pytest.raises(SceneError, match="'r'"):
        acc(sc, {"l": 2})


# ----------------------------------------------------------------------------- dampen (Eq. 9)
def test_dampen_is_minus_c_v():
    sc = make({"g": ([[0, 0, 0], [5, 0, 0]], 0.5)}, {"g": [Dampen(2.0)]})
    v = [[1.0, -2.0, 0.5], [0.0, 3.0, -4.0]]
    np.testing.assert_allclose(acc(sc, v=v)["g"], [[-2, 4, -1], [0, -6, 8]], rtol=0, atol=1e-12)


def test_dampen_extra_follows_phase_condition():
    # Eq. 28: dampen(10 + 85⟨… ∧ b ∈ {2, 3, 6, 7}⟩), here the phase part only.
    sc = make({"leg": ([[0, 0, 0]], 1.0)},
              {"leg": [Dampen(10.0, extra=85.0, when=(PhaseIn("b", (2, 3, 6, 7)),))]})
    v = [[1.0, 2.0, -1.0]]
    np.testing.assert_allclose(acc(sc, {"b": 6}, v=v)["leg"], [[-95, -190, 95]], atol=1e-12)
    np.testing.assert_allclose(acc(sc, {"b": 1}, v=v)["leg"], [[-10, -20, 10]], atol=1e-12)


def _leg_and_sediment(sed_y: float, extra_when):
    # leg particle at the origin (r = 1), one sediment particle (r = 1) below it at distance
    # |sed_y|; they overlap iff |sed_y| < 1 + 1.
    return make({"leg": ([[0, 0, 0]], 1.0), "sediment": ([[0, sed_y, 0]], 1.0)},
                {"leg": [Dampen(10.0, extra=85.0, when=extra_when)]})


def test_dampen_extra_follows_contact_condition():
    v = [[0.0, -2.0, 0.0], [0.0, 0.0, 0.0]]
    contact = (Contact("sediment"),)
    # d = 1.5 < 2: touching the sediment → 10 + 85
    np.testing.assert_allclose(acc(_leg_and_sediment(-1.5, contact), v=v)["leg"],
                               [[0, 190, 0]], atol=1e-12)
    # d = 2.5: no contact → 10
    np.testing.assert_allclose(acc(_leg_and_sediment(-2.5, contact), v=v)["leg"],
                               [[0, 20, 0]], atol=1e-12)
    # d = 2 exactly: col(p, 1, s) = (s − p)·min(0, 1 − 4/4) = 0, so ‖col‖ > 0 is false → 10
    np.testing.assert_allclose(acc(_leg_and_sediment(-2.0, contact), v=v)["leg"],
                               [[0, 20, 0]], atol=1e-12)


def test_dampen_extra_needs_contact_and_phase_together():
    when = (Contact("sediment"), PhaseIn("b", (2, 3, 6, 7)))
    sc = _leg_and_sediment(-1.5, when)
    v = [[0.0, -2.0, 0.0], [0.0, 0.0, 0.0]]
    np.testing.assert_allclose(acc(sc, {"b": 2}, v=v)["leg"], [[0, 190, 0]], atol=1e-12)
    np.testing.assert_allclose(acc(sc, {"b": 4}, v=v)["leg"], [[0, 20, 0]], atol=1e-12)
    far = _leg_and_sediment(-3.0, when)
    np.testing.assert_allclose(acc(far, {"b": 2}, v=v)["leg"], [[0, 20, 0]], atol=1e-12)


# ----------------------------------------------------------------------------- collide (Eq. 10)
def two(pa, ra, pb, rb, ops):
    return make({"A": ([pa], ra), "B": ([pb], rb)}, ops)


def test_collide_radii_sum_erratum_on_axis():
    # c = 100, R = 1 + 1 = 2, d = 1.5: magnitude c(R²/d − d) = 100·(4/1.5 − 1.5), away from B.
    mag = 100.0 * (4.0 / 1.5 - 1.5)
    assert mag == pytest.approx(116.6666666666, rel=1e-10)
    sc = two([0, 0, 0], 1.0, [1.5, 0, 0], 1.0, {"A": [Collide("B", Const(100.0))]})
    a = acc(sc)
    np.testing.assert_allclose(a["A"], [[-mag, 0, 0]], rtol=1e-12)
    np.testing.assert_array_equal(a["B"], [[0, 0, 0]])  # one-way: no operator on B


def test_collide_off_axis_direction():
    # B at (0.9, 1.2, 0): d = 1.5, unit vector from A to B = (0.6, 0.8, 0).
    mag = 100.0 * (4.0 / 1.5 - 1.5)
    sc = two([0, 0, 0], 1.0, [0.9, 1.2, 0], 1.0, {"A": [Collide("B", Const(100.0))]})
    np.testing.assert_allclose(acc(sc)["A"], [[-0.6 * mag, -0.8 * mag, 0]], rtol=1e-12)


def test_collide_uses_sum_of_unequal_radii():
    # r_A = 0.5, r_B = 1.5 → R = 2 (a per-particle diameter or the printed (u_x + p_x)² would
    # give zero here: 2·0.5 = 1 < 1.5 and (1.5 + 0)² = d²).
    mag = 100.0 * (4.0 / 1.5 - 1.5)
    sc = two([0, 0, 0], 0.5, [1.5, 0, 0], 1.5, {"A": [Collide("B", Const(100.0))]})
    np.testing.assert_allclose(acc(sc)["A"], [[-mag, 0, 0]], rtol=1e-12)
    # r_A = 1, r_B = 0.25, d = 1: R = 1.25, magnitude 100·(1.5625/1 − 1) = 56.25
    sc = two([0, 0, 0], 1.0, [0, 0, 1.0], 0.25, {"A": [Collide("B", Const(100.0))]})
    np.testing.assert_allclose(acc(sc)["A"], [[0, 0, -56.25]], rtol=1e-12)


@pytest.mark.parametrize("d", [2.0, 2.5, 4.0])
def test_collide_zero_when_not_overlapping(d):
    sc = two([0, 0, 0], 1.0, [d, 0, 0], 1.0, {"A": [Collide("B", Const(100.0))]})
    np.testing.assert_array_equal(acc(sc)["A"], [[0, 0, 0]])


def test_collide_directed_coefficients():
    # on A from B: c = 100; on B from A: c = 20. Same geometry (R = 2, d = 1.5).
    k = 4.0 / 1.5 - 1.5
    sc = two([0, 0, 0], 1.0, [1.5, 0, 0], 1.0,
             {"A": [Collide("B", Const(100.0))], "B": [Collide("A", Const(20.0))]})
    a = acc(sc)
    np.testing.assert_allclose(a["A"], [[-100 * k, 0, 0]], rtol=1e-12)
    np.testing.assert_allclose(a["B"], [[20 * k, 0, 0]], rtol=1e-12)


def test_collide_sums_over_sources_and_within_own_group():
    # A at the origin; B0 at (1.5, 0, 0) (d 1.5 → 116.67 along −x), B1 at (0, −1, 0)
    # (d 1 → 100·(4/1 − 1) = 300 along +y); B2 far away.
    sc = make({"A": ([[0, 0, 0]], 1.0),
               "B": ([[1.5, 0, 0], [0, -1, 0], [0, 0, 9]], 1.0)},
              {"A": [Collide("B", Const(100.0))], "B": [Collide("B", Const(10.0))]})
    a = acc(sc)
    np.testing.assert_allclose(a["A"], [[-100 * (4 / 1.5 - 1.5), 300, 0]], rtol=1e-12)
    # inside B: B0–B1 distance √(1.5² + 1) = √3.25 < 2, B2 far from both; never i with i.
    d = math.sqrt(3.25)
    mag = 10.0 * (4.0 / d - d)
    e = np.array([-1.5, -1.0, 0.0]) / d  # unit vector from B0 to B1
    np.testing.assert_allclose(a["B"], [-mag * e, mag * e, [0, 0, 0]], rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------- bind (Eq. 12)
def test_bind_per_pair_original_length():
    # T0 at the origin bound to S0 (o = (3,0,0), L0 = 3) and S1 (o = (0,4,0), L0 = 4), c = 2.
    # Stretch S0 to (4,0,0): 2·(4,0,0)·(1 − 9/16) = (3.5, 0, 0).
    # Compress S1 to (0,2,0): 2·(0,2,0)·(1 − 16/4) = (0, −12, 0).
    sc = make({"T": ([[0, 0, 0]], 0.5), "S": ([[3, 0, 0], [0, 4, 0]], 0.5)},
              {"T": [Bind("S", Const(2.0))], "S": [Bind("T", Const(0.5))]})
    p = [[0, 0, 0], [4, 0, 0], [0, 2, 0]]
    a = acc(sc, p=p)
    np.testing.assert_allclose(a["T"], [[3.5, -12.0, 0]], rtol=1e-12)
    # the reverse operator, c = 0.5: on S0 0.5·(−4,0,0)·(7/16), on S1 0.5·(0,−2,0)·(−3)
    np.testing.assert_allclose(a["S"], [[-0.875, 0, 0], [0, 3.0, 0]], rtol=1e-12)


def test_bind_at_rest_is_zero():
    sc = make({"T": ([[0, 0, 0]], 0.5), "S": ([[3, 0, 0], [0, 4, 0]], 0.5)},
              {"T": [Bind("S", Const(2.0))], "S": [Bind("T", Const(0.5))]})
    a = acc(sc)
    np.testing.assert_allclose(a["T"], 0, atol=1e-12)
    np.testing.assert_allclose(a["S"], 0, atol=1e-12)


def test_bind_within_is_strict_and_never_self():
    # x = 0, 1, 2 with within(2): pairs (0,1) and (1,2) (distance 1); (0,2) is at exactly 2,
    # not < 2. Move particle 2 to x = 3: (1,2) has L0 = 1, d = 2:
    # on 1: 10·(2,0,0)·(1 − 1/4) = (15,0,0); on 2: (−15,0,0); particle 0 stays at rest → 0.
    sc = make({"g": ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], 0.25)},
              {"g": [Bind("g", Within(2.0, 10.0))]})
    a = acc(sc, p=[[0, 0, 0], [1, 0, 0], [3, 0, 0]])["g"]
    np.testing.assert_allclose(a, [[0, 0, 0], [15, 0, 0], [-15, 0, 0]], rtol=1e-12, atol=1e-12)


def test_bind_gated_by_phase():
    sc = make({"T": ([[0, 0, 0]], 0.5), "S": ([[3, 0, 0]], 0.5)},
              {"T": [Bind("S", Const(2.0), when=(PhaseIn("r", (1,)),))]})
    p = [[0, 0, 0], [4, 0, 0]]
    np.testing.assert_allclose(acc(sc, {"r": 1}, p=p)["T"], [[3.5, 0, 0]], rtol=1e-12)
    np.testing.assert_array_equal(acc(sc, {"r": 2}, p=p)["T"], [[0, 0, 0]])


# ----------------------------------------------------------------------------- attract (Eq. 14)
def test_attract_const_has_constant_magnitude():
    # c = 5 towards (3,4,0) (unit (0.6, 0.8, 0)) and (0,0,−2) (unit (0,0,−1)): (3, 4, −5)
    sc = make({"T": ([[0, 0, 0]], 0.5), "S": ([[3, 4, 0], [0, 0, -2]], 0.5)},
              {"T": [Attract("S", Const(5.0))]})
    a = acc(sc)
    np.testing.assert_allclose(a["T"], [[3, 4, -5]], rtol=1e-12)
    np.testing.assert_array_equal(a["S"], [[0, 0, 0], [0, 0, 0]])  # one-way
    # twice as far: same acceleration (magnitude c, not linear in the distance)
    far = acc(sc, p=[[0, 0, 0], [6, 8, 0], [0, 0, -4]])
    np.testing.assert_allclose(far["T"], [[3, 4, -5]], rtol=1e-12)


def _leg_body(when=()):
    leg = ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], 0.5, {"regions": {"mag": [1, 2, 0]}})
    body = ([[1, 4, 0], [3, 4, 0], [0, 0, -5]], 0.5,
            {"regions": {"breg1": [2, 1, 0], "breg2": [0, 0, 1]}})
    return make({"leg": leg, "body": body},
                {"leg": [Attract("body", Matched("mag", "breg{r}", 3.0), when=when)]},
                phases=[Phase("one", 1, {"r": 1}), Phase("two", 1, {"r": 2})])


def test_attract_matched_regions_follow_the_phase():
    sc = _leg_body()
    # r = 1, breg1 = [2, 1, 0]: leg0 (mag 1) ↔ body1 at (3,4,0): 3·(0.6, 0.8, 0);
    # leg1 (mag 2) ↔ body0 at (1,4,0), from (1,0,0): 3·(0, 1, 0); leg2 (mag 0) nothing.
    a1 = acc(sc, {"r": 1})
    np.testing.assert_allclose(a1["leg"], [[1.8, 2.4, 0], [0, 3, 0], [0, 0, 0]], rtol=1e-12,
                               atol=1e-15)
    np.testing.assert_array_equal(a1["body"], np.zeros((3, 3)))
    # r = 2, breg2 = [0, 0, 1]: leg0 (mag 1) ↔ body2 at (0,0,−5): 3·(0,0,−1); others nothing.
    a2 = acc(sc, {"r": 2})
    np.testing.assert_allclose(a2["leg"], [[0, 0, -3], [0, 0, 0], [0, 0, 0]], atol=1e-15)


def test_attract_matched_with_phase_condition_and_missing_region():
    sc = _leg_body(when=(PhaseIn("r", (2,)),))
    np.testing.assert_array_equal(acc(sc, {"r": 1})["leg"], np.zeros((3, 3)))
    np.testing.assert_allclose(acc(sc, {"r": 2})["leg"], [[0, 0, -3], [0, 0, 0], [0, 0, 0]],
                               atol=1e-15)
    with pytest.raises(SceneError, match="breg3"):
        acc(_leg_body(), {"r": 3})


def test_matched_attract_pairs_every_equal_index():
    # two body particles share index 1 with one leg particle: both pull (2 · c · unit vectors)
    leg = ([[0, 0, 0]], 0.5, {"regions": {"mag": [1]}})
    body = ([[0, 2, 0], [0, 0, 7]], 0.5, {"regions": {"breg": [1, 1]}})
    sc = make({"leg": leg, "body": body}, {"leg": [Attract("body", Matched("mag", "breg", 2.0))]})
    np.testing.assert_allclose(acc(sc)["leg"], [[0, 2, 2]], rtol=1e-12)


# ----------------------------------------------------------------------------- composition
def test_operator_order_within_a_group_does_not_change_the_sum():
    # Eqs. 2–3: every operator adds to a; dampen reads v, which no force operator changes.
    pos = {"A": ([[0, 0, 0]], 1.0), "B": ([[1.5, 0, 0]], 1.0)}
    seq = [Force((0.0, 3.0, 0.0)), Collide("B", Const(100.0)), Dampen(2.0)]
    v = [[1.0, 1.0, 0.0], [0.0, 0.0, 0.0]]
    fwd = acc(make(pos, {"A": seq}), v=v)["A"]
    rev = acc(make(pos, {"A": seq[::-1]}), v=v)["A"]
    expected = [[-100 * (4 / 1.5 - 1.5) - 2.0, 3.0 - 2.0, 0.0]]
    np.testing.assert_allclose(fwd, expected, rtol=1e-12)
    np.testing.assert_allclose(rev, expected, rtol=1e-12)


# ----------------------------------------------------------------------------- one home each
def test_every_operator_has_a_kernel_a_realization_and_a_callback_term():
    """Adding an operator is one class plus one entry per engine registry: none is missing —
    the paper's five, the material's volumetric term (model/volume.py registers its kind) and
    the rigid indenter (``[[indenter]]``)."""
    from rackstress.engines.lammps.callback import TERMS
    from rackstress.engines.lammps.deck import REALIZE
    from rackstress.engines.reference import KERNELS
    from rackstress.model.operators import OPERATOR_KINDS, OPERATORS, Indent
    from rackstress.model.volume import Volume

    kinds = set(OPERATOR_KINDS.values())
    assert kinds == set(OPERATORS) | {Volume, Indent}
    for registry in (KERNELS, REALIZE, TERMS):
        assert set(registry) == kinds


@pytest.mark.parametrize("cls,q", [(Bind, 2.0), (Collide, 9.0), (Attract, None)])
def test_jacobian_block_is_minus_the_derivative_of_the_kernel(cls, q):
    """The stability prediction's block B = −∂a_p/∂p of each pair kernel, by central differences
    of the kernel (in a state where collide overlaps and bind is stretched)."""
    p = np.array([[0.1, -0.2, 0.3]])
    u = np.array([[1.3, 0.4, -0.5]])
    c = 7.0
    qa = None if q is None else np.array([q])
    B, norm = cls.jacobian(u - p, np.array([c]), qa)
    h = 1e-6
    num = np.zeros((3, 3))
    for k in range(3):
        e = np.zeros((1, 3))
        e[0, k] = h
        num[:, k] = -(cls.accel(p + e, u, c, qa) - cls.accel(p - e, u, c, qa))[0] / (2 * h)
    np.testing.assert_allclose(B[0], num, rtol=1e-6, atol=1e-6)
    assert norm[0] == pytest.approx(np.linalg.norm(B[0], 2), rel=1e-12)


def test_bind_pairs_carry_each_pair_original_length():
    from rackstress.model.operators import Within as W

    g = Group("g", [[0, 0, 0], [1, 0, 0], [0, 2, 0]], 0.25)
    pl = Bind("g", W(2.5, 3.0)).pairs(g, g)
    # pairs (0,1) L0² 1, (0,2) 4, (1,0) 1, (1,2) 5, (2,0) 4, (2,1) 5; never (i, i)
    assert list(zip(pl.i.tolist(), pl.j.tolist())) == [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0),
                                                       (2, 1)]
    np.testing.assert_array_equal(pl.q, [1, 4, 1, 5, 4, 5])
    np.testing.assert_array_equal(pl.c, [3.0] * 6)


def test_bind_pairs_are_built_once_per_coefficient_and_positions():
    """Every Bind of one coefficient shares its pairs for the same original positions (a run
    asked for them up to seven times); they cannot be changed in place; other positions, or
    forget_pairs (a run's engine holds what it steps with), build them anew, equal to the
    hand count: the three of test_bind_pairs_carry_each_pair_original_length."""
    from rackstress.model.operators import Within as W
    from rackstress.model.operators import forget_pairs

    coeff = W(2.5, 3.0)
    g = Group("g", [[0, 0, 0], [1, 0, 0], [0, 2, 0]], 0.25)
    first = Bind("g", coeff).pairs(g, g)
    assert Bind("g", coeff, when=(("x", 1),)).pairs(g, g) is first
    with pytest.raises(ValueError):
        first.c[0] = 1.0
    moved = Group("g", [[0, 0, 0], [1, 0, 0], [0, 3, 0]], 0.25)    # 2: 3 and √10 away
    pl = Bind("g", coeff).pairs(moved, moved)
    assert pl is not first and list(zip(pl.i.tolist(), pl.j.tolist())) == [(0, 1), (1, 0)]
    forget_pairs()
    again = Bind("g", coeff).pairs(g, g)
    assert again is not first
    np.testing.assert_array_equal(again.q, [1, 4, 1, 5, 4, 5])


def test_rack_forces_and_pull_selection():
    from rackstress.model.operators import norm2_below, rack_forces

    assert rack_forces("body") == [Bind("body", Const(0.5)), Dampen(1.0)]          # Eq. 23
    assert rack_forces("plane", 2.0, 3.0) == [Bind("plane", Const(2.0)), Dampen(3.0)]
    # Eq. 15: ‖o‖² = 0, 9, 9.61, 10, 100 < 10
    o = [[0, 0, 0], [3, 0, 0], [0, 0, 3.1], [1, 3, 0], [10, 0, 0]]
    assert norm2_below(o, 10.0) == (True, True, True, False, False)


def test_reverse_of_finds_the_directed_partner():
    from rackstress.model.operators import reverse_of

    ops = {"A": [Dampen(1.0), Bind("B", Const(100.0)), Collide("B", Const(3.0))],
           "B": [Collide("A", Const(1.0)), Bind("A", Const(0.5)), Bind("B", Within(2.0, 1.0))],
           "C": [Attract("A", Const(1.0))]}
    assert reverse_of(ops, "A", 1) == ("B", 1)          # bind A<-B 100 and B<-A 0.5
    assert reverse_of(ops, "B", 0) == ("A", 2)          # collide, other coefficient
    assert reverse_of(ops, "B", 2) == ("B", 2)          # a group with itself is its own reverse
    assert reverse_of(ops, "C", 0) is None              # one-way attraction


def test_the_same_operator_object_on_two_groups():
    """Engines key what they prepare by an operator's place, so one Bind object may sit on two
    groups: each acts with its own pairs (S0, S1 bound to T with 2; T bound to each)."""
    shared = Bind("T", Const(2.0))
    sc = make({"T": ([[0, 0, 0]], 0.5), "S": ([[3, 0, 0]], 0.5), "U": ([[0, 4, 0]], 0.5)},
              {"S": [shared], "U": [shared]})
    a = acc(sc, p=[[0, 0, 0], [4, 0, 0], [0, 2, 0]])
    # S at 4 (L0 3): 2·(−4,0,0)·(1 − 9/16); U at 2 (L0 4): 2·(0,−2,0)·(1 − 16/4)
    np.testing.assert_allclose(a["S"], [[-3.5, 0, 0]], rtol=1e-12)
    np.testing.assert_allclose(a["U"], [[0, 12.0, 0]], rtol=1e-12)
