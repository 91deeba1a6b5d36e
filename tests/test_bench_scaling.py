"""The scaling model of ``rackstress bench scaling`` (bench/scaling.py) against hand calculation:
the two one-rank costs recovered from two scenes, and the robot-and-rest model's step time."""
from __future__ import annotations

import math

import pytest

from rackstress.bench import scaling


def _runs(cpu_per_step: float, moving: int) -> list:
    return [{"ranks": 1, "cpu_s": cpu_per_step * 100, "steps": 100, "moving": [moving]}]


def test_moving_costs_solve_the_two_scenes():
    """t = a·M + b·(N − M) on two scenes with the same robot: a and b back exactly."""
    a, b = 25e-9, 7e-9
    data = {"scenes": {
        "magpod": {"n_particles": 33_689, "moving": 4_061,
                   "runs": _runs(a * 4_061 + b * (33_689 - 4_061), 4_061)},
        "sediment-large": {"n_particles": 1_004_689, "moving": 4_056,
                           "runs": _runs(a * 4_056 + b * (1_004_689 - 4_056), 4_056)}}}
    got = scaling._moving_costs(data)
    assert got == pytest.approx((a, b), rel=1e-9)
    data["scenes"].pop("magpod")
    assert scaling._moving_costs(data) is None      # one scene: two unknowns stay unknown


def test_model_moving_by_hand():
    """1,000 moving particles at 10 ns, 100,000 resting at 1 ns: 0.11 ms on one rank. On two,
    the rest of the work spreads (0.055 ms) and the robot's whole piece (0.01 ms) is smaller, so
    a step is 0.055 ms + 3 collectives × 5 µs × log2 2 = 0.070 ms."""
    rows = scaling.model_moving(101_000, 1_000, 10e-9, 1e-9, cutoff=13.0,
                                robot_density=0.125, collectives=3)
    one, two = rows[0], rows[1]
    assert one["ranks"] == 1 and one["ms_per_step"] == pytest.approx(0.11)
    assert two["ranks"] == 2 and two["ms_per_step"] == pytest.approx(0.055 + 0.015)
    assert two["speed_up"] == pytest.approx(0.11 / 0.070)
    # 1,024 ranks: the even share is 0.107 µs, below the robot's best piece, which sets the
    # floor: a piece of M/p particles and its ghost shell (cube of side s, shell 13 thick)
    last = rows[-1]
    p = last["robot_pieces"]
    n = 1_000 / p
    s = (n / 0.125) ** (1 / 3)
    ghosts = 0.0 if p == 1 else 0.125 * ((s + 26.0) ** 3 - s ** 3)
    piece = 10e-9 * n + ghosts * 24.0 / 5e9
    assert last["ms_per_step"] == pytest.approx(1e3 * (piece + 3 * 5e-6 * math.log2(1024)))
    for q in range(1, 1025):            # and no other number of pieces makes a faster piece
        nq = 1_000 / q
        sq = (nq / 0.125) ** (1 / 3)
        gq = 0.0 if q == 1 else 0.125 * ((sq + 26.0) ** 3 - sq ** 3)
        assert 10e-9 * nq + gq * 24.0 / 5e9 >= piece - 1e-18


def test_moving_costs_from_the_cpu_split_by_least_squares():
    """Each rank of each configuration is one equation t = a·moving + b·(owned − moving): with
    times made from a and b, least squares gives them back (a CPU split takes precedence over
    the two-scene solve)."""
    a, b = 66e-9, 4.2e-9

    def rank(owned, moving):
        return a * moving + b * (owned - moving)

    split = {"1": {"cpu": [rank(33_689, 4_055)], "owned": [33_689], "moving": [4_055]},
             "2": {"cpu": [rank(16_908, 2_090), rank(16_781, 1_965)],
                   "owned": [16_908, 16_781], "moving": [2_090, 1_965]},
             "2 even split": {"cpu": [rank(18_689, 4_055), rank(15_000, 0)],
                              "owned": [18_689, 15_000], "moving": [4_055, 0]}}
    data = {"scenes": {"magpod": {"cpu_split": split, "runs": []}}}
    assert scaling._moving_costs(data) == pytest.approx((a, b), rel=1e-9)
    assert data["costs_from"].startswith("the CPU split")
    # an unresolved rank (None) is no equation: the other four still give a and b back
    split["2"]["cpu"][1] = None
    assert scaling._moving_costs(data) == pytest.approx((a, b), rel=1e-9)


def test_the_page_prints_an_unresolved_figure_as_such():
    """A CPU figure compute_cpu could not resolve prints as ``unresolved`` and its bound as a
    dash, never as a number."""
    split = {"1": {"cpu": [None], "owned": [100], "moving": [10]},
             "2": {"cpu": [2e-5, None], "owned": [50, 50], "moving": [5, 5],
                   "repeats": [[2e-5, None], [2.1e-5, None]]}}
    rows = scaling.cpu_split_rows([("x", split)])
    assert rows[0][2] == "unresolved" and rows[0][6] == "—"
    assert rows[1][2] == "0.020 / unresolved" and rows[1][6] == "—"
    assert rows[1][3] == "4.8 %"            # |2.0 - 2.1| / 2.1 of the resolved rank
