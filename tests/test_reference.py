"""The reference engine's model of motion: Eq. 5 and Eqs. 6–7 iterated by hand.

motion = netForce • integrate(t): every group's operators are evaluated on the *same* state,
then v += t·a and p += t·v (forward error correction), and a starts from zero again.
"""
from __future__ import annotations

import numpy as np
import pytest

from rackstress.errors import DivergenceError
from rackstress.model.operators import Bind, Collide, Const, Dampen, Force
from rackstress.model.particles import Group
from rackstress.engines.reference import Reference, integrate
from rackstress.model.scene import Phase, Scene


def test_integrate_is_eq5():
    # v' = v + t·a = (0,1,0) + 0.5·(2,0,0) = (1,1,0); p' = p + t·v' = (1,2,3) + 0.5·(1,1,0)
    p, v = integrate(np.array([[1.0, 2.0, 3.0]]), np.array([[0.0, 1.0, 0.0]]),
                     np.array([[2.0, 0.0, 0.0]]), 0.5)
    np.testing.assert_array_equal(v, [[1.0, 1.0, 0.0]])
    np.testing.assert_array_equal(p, [[1.5, 2.5, 3.0]])


def _pair(dt=0.1):
    # A at x = 0, B at x = 2 (L0 = 2). A: force 10 along x, bind to B (c = 1), dampen 1.
    # B: bind to A with a different coefficient (0.5).
    groups = {"A": Group("A", [[0.0, 0.0, 0.0]], 0.25), "B": Group("B", [[2.0, 0.0, 0.0]], 0.25)}
    ops = {"A": [Force((10.0, 0.0, 0.0)), Bind("B", Const(1.0)), Dampen(1.0)],
           "B": [Bind("A", Const(0.5))]}
    return Scene("pair", groups, ops, [Phase("p", 3)], dt=dt)


def test_first_step_literal_values():
    ref = Reference(_pair())
    ref.step({})
    # a_A = 10 (B at rest distance, v = 0); v_A = 0.1·10 = 1; p_A = 0 + 0.1·1 = 0.1
    # (the classical p + t·v + t²a/2 would give 0.05).
    np.testing.assert_allclose(ref.v[0], [1.0, 0, 0], rtol=1e-15)
    np.testing.assert_allclose(ref.p[0], [0.1, 0, 0], rtol=1e-15)
    # B's force was evaluated on the old state (A still at 0, d = L0): B has not moved.
    np.testing.assert_array_equal(ref.p[1], [2.0, 0, 0])
    np.testing.assert_array_equal(ref.v[1], [0.0, 0, 0])


def test_hand_iterated_pair_three_steps():
    t, L0 = 0.1, 2.0
    pA, pB, vA, vB = 0.0, 2.0, 0.0, 0.0
    expected = []
    for _ in range(3):
        # Eq. 7: all accelerations from the current state, then velocities, then positions.
        d = pB - pA
        factor = 1.0 - L0 ** 2 / d ** 2
        aA = 10.0 + 1.0 * d * factor - 1.0 * vA      # force • bind(B, 1) • dampen(1)
        aB = 0.5 * (-d) * factor                      # bind(A, 0.5)
        vA, vB = vA + t * aA, vB + t * aB
        pA, pB = pA + t * vA, pB + t * vB
        expected.append((pA, pB, vA, vB))
    # step 2 by hand: d = 1.9, factor = 1 − 4/3.61; a_A = 9 + 1.9·factor
    f2 = 1.0 - 4.0 / 3.61
    assert expected[1][2] == pytest.approx(1.0 + 0.1 * (9.0 + 1.9 * f2), rel=1e-14)
    assert expected[1][3] == pytest.approx(0.1 * 0.5 * (-1.9) * f2, rel=1e-14)

    ref = Reference(_pair(t))
    for k in range(3):
        ref.step({})
        pA, pB, vA, vB = expected[k]
        np.testing.assert_allclose(ref.p[:, 0], [pA, pB], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(ref.v[:, 0], [vA, vB], rtol=1e-13, atol=1e-15)
        np.testing.assert_array_equal(ref.p[:, 1:], 0.0)
    assert ref.step_count == 3


def test_acceleration_does_not_accumulate_between_steps():
    # a constant force of 2 from rest with t = 0.5: v_n = n, p_n = 0.5·n(n+1)/2 (Eq. 5 zeroes a).
    sc = Scene("f", {"g": Group("g", [[0.0, 0.0, 0.0]], 1.0)}, {"g": [Force((2.0, 0.0, 0.0))]},
               [Phase("p", 4)], dt=0.5)
    ref = Reference(sc)
    for n in range(1, 5):
        ref.step({})
        assert ref.v[0, 0] == pytest.approx(n, rel=1e-15)
        assert ref.p[0, 0] == pytest.approx(0.5 * n * (n + 1) / 2, rel=1e-15)


def test_watchdog_stops_at_the_hand_computed_step():
    # a = 100, t = 0.1: p_n = t²·a·n(n+1)/2 = n(n+1)/2 → p_1 = 1 (= bound, allowed), p_2 = 3.
    sc = Scene("w", {"g": Group("g", [[0.0, 0.0, 0.0]], 1.0), "h": Group("h", [[0, 5.0, 0]], 1.0)},
               {"h": [Force((100.0, 0.0, 0.0))]}, [Phase("p", 5)], dt=0.1, bound=1.0)
    ref = Reference(sc)
    ref.step({})
    with pytest.raises(DivergenceError) as exc:
        ref.step({})
    err = exc.value
    assert (err.step, err.group, err.local, err.index) == (2, "h", 0, 1)
    assert err.value == pytest.approx(3.0, rel=1e-12)


def test_coincident_particles_in_a_collision_are_an_error():
    sc = Scene("c", {"A": Group("A", [[0.0, 0.0, 0.0]], 1.0),
                     "B": Group("B", [[1.0, 0.0, 0.0]], 1.0)},
               {"A": [Collide("B", Const(1.0))]}, [Phase("p", 1)])
    ref = Reference(sc)
    ref.p[1] = ref.p[0]
    with pytest.raises(DivergenceError, match="coincide") as exc:
        ref.accelerations({})
    assert exc.value.group == "A"


def test_schedule_and_with_steps():
    g = {"g": Group("g", [[0.0, 0.0, 0.0]], 1.0)}
    sc = Scene("s", g, {}, [Phase("a", 3, {"r": 1}), Phase("b", 2, {"r": 2})], cycles=2)
    assert sc.total_steps == 10
    assert [(s, p.name, c) for s, p, c in sc.schedule()] == [
        (0, "a", 0), (3, "b", 0), (5, "a", 1), (8, "b", 1)]
    cut = sc.with_steps(7)  # a3 b2 a2, generated lazily (the cycle's phases are kept as they are)
    assert [(s, p.name, p.steps, c) for s, p, c in cut.schedule()] == [
        (0, "a", 3, 0), (3, "b", 2, 0), (5, "a", 2, 1)]
    assert [(p.name, p.steps) for p in cut.phases] == [("a", 3), ("b", 2)]
    assert cut.total_steps == 7
    huge = sc.with_steps(10**12)       # nothing is built per phase
    assert huge.total_steps == 10**12 and len(huge.phases) == 2
