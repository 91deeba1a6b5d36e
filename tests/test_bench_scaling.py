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


def test_runner_rows_report_each_rank_outside_mpi(tmp_path):
    """``rackstress run``'s path on 2 ranks (bench.perf's worker, the plugin) with the PMPI shim
    preloaded: each rank reports its CPU time outside MPI, read from the shim; without the shim
    the worker says that its figure is thread CPU time."""
    from rackstress.bench.scaling import _runner, _shim

    shim = _shim(tmp_path)
    assert shim is not None          # cc and the mpich wheel's mpi.h are part of the test set-up
    r = _runner("magpod-small", 20, 2, shim)
    assert r["ranks"] == 2 and r["plugin"] and r["outside_mpi"]
    assert len(r["work_s_per_rank"]) == 2 and all(w > 0 for w in r["work_s_per_rank"])
    assert r["s_per_step"] > 0
    plain = _runner("magpod-small", 20, 1, None)
    assert plain["outside_mpi"] is False and len(plain["work_s_per_rank"]) == 1


#: repeats of a CPU-time measurement in the tests below. CPU time is the work's, but another
#: process on the machine still changes it (the core's shared caches and its sibling
#: hyperthread): while the suite's other worker ran, one E = 600 run's 2E-over-E loop ratio
#: ranged 0.78–1.37 here, at E = 3000 as widely (2026-12-02), and a median of five such ratios
#: fell to 0.83 and rose to 1.25 in two suite runs. A bound of 15 % on them tested the load. So
#: the tests make a wrong bracket show far beyond that: the deck runs PRE steps of its own
#: before the markers, and a bracket that reached back past its loop's first barrier would add
#: them to the E loop's 600 steps (the figure 17× too large); a run's figure divided by the
#: wrong count of steps is 2× off. Each ratio's median over the repeats must lie within a
#: factor :data:`FACTOR` of 1: outside what the load did, inside what either error does.
REPEATS = 3
PRE = 10_000
FACTOR = 1.5


def _pre(deck_dir) -> str:
    """The deck's text with :data:`PRE` steps of its own appended (before compute_cpu's
    markers)."""
    return (deck_dir / "in.lammps").read_text().rstrip("\n") + f"\nrun {PRE} pre no post no\n"


def _within(ratios: list) -> bool:
    import statistics

    return 1 / FACTOR < statistics.median(ratios) < FACTOR


def _loop_ratios(runs: list, k: int = 0) -> list:
    """Rank ``k``'s 2E-loop CPU per step over its E loop's, one per repeat in ``runs``."""
    return [r["halves"][k][1] / r["halves"][k][0] for r in runs]


def test_compute_cpu_times_the_steps_in_one_process(tmp_path):
    """``compute_cpu`` on a 10 × 10 × 10 bound block (1,000 particles, every one bound within
    1.5: the same work each step), 1 rank: the CPU per step is positive, is the mean of its two
    loops' over their 3E steps, and the 2E-step loop costs twice the E-step loop (:data:`PRE`
    steps before both, outside them); a run asked for twice the steps gives the same figure per
    step. Medians over :data:`REPEATS` of ratios measured together (the two loops of one run; a
    run of E = 600 and one of E = 1200 right after it), within :data:`FACTOR`."""
    import sys
    from pathlib import Path

    from rackstress.bench.scaling import _deck, _shim, block_scene, compute_cpu

    shim = _shim(tmp_path)
    assert shim is not None          # cc and the mpich wheel's mpi.h are part of the test set-up
    _deck(block_scene(10, 10, 10), tmp_path / "d")
    bindir, text = Path(sys.executable).parent, _pre(tmp_path / "d")
    pairs = [(compute_cpu(tmp_path / "d", 1, bindir, shim, extra=600, text=text, counts=True),
              compute_cpu(tmp_path / "d", 1, bindir, shim, extra=1200, text=text))
             for _ in range(REPEATS)]
    runs_a, runs_b = [a for a, _ in pairs], [b for _, b in pairs]
    assert runs_a[0]["owned"] == [1000] and runs_a[0]["moving"] == [1000]
    for runs in (runs_a, runs_b):
        for r in runs:
            one, two = r["halves"][0]
            assert one > 0 and two > 0
            assert r["cpu"][0] == pytest.approx((one + 2 * two) / 3, rel=1e-12)
        assert _within(_loop_ratios(runs))                              # 2E = 2x E
    # the total CPU of the timed loops: 3 x 1200 steps against 3 x 600, run after run
    assert _within([3600 * b["cpu"][0] / (2 * 1800 * a["cpu"][0]) for a, b in pairs])


def test_compute_cpu_two_ranks_each_rank_its_own_steps(tmp_path):
    """2 ranks on the same block, split evenly by LAMMPS (500 particles each): each rank's loops
    are found by the barriers' count sent from rank 0 (the marker is rank 0's): on each rank
    the E and 2E loops' CPU per step within :data:`FACTOR` (:data:`PRE` steps before both, so
    a bracket reaching back on either rank would show 17×), each figure positive."""
    import sys
    from pathlib import Path

    from rackstress.bench.scaling import _deck, _shim, block_scene, compute_cpu

    shim = _shim(tmp_path)
    assert shim is not None
    _deck(block_scene(10, 10, 10), tmp_path / "d")
    runs = [compute_cpu(tmp_path / "d", 2, Path(sys.executable).parent, shim, extra=600,
                        text=_pre(tmp_path / "d"), counts=True) for _ in range(REPEATS)]
    assert runs[0]["owned"] == [500, 500]
    assert all(c is not None and c > 0 for r in runs for c in r["cpu"])
    for k in (0, 1):
        assert _within(_loop_ratios(runs, k))


def test_resolve_takes_the_loops_and_the_repeats():
    """A rank's figure is its loops' CPU over their 3E steps, (E·h1 + 2E·h2) / 3E, averaged over
    the repeats; repeats more than SPREAD_MAX (10 %) apart, or a loop without CPU, leave it
    unresolved (None), never a number."""
    v = scaling._resolve({"halves": [[[3e-5, 6e-5], [1e-5, 1e-5], [2e-5, 0.0]],
                                     [[3e-5, 6e-5], [1.2e-5, 1.2e-5], [2e-5, 1e-5]]]})
    assert v["cpu"][0] == pytest.approx(5e-5, rel=1e-12)          # (3 + 12) / 3
    assert v["cpu"][1] is None                                     # 1.0 vs 1.2: 17 % apart
    assert v["cpu"][2] is None                                     # a loop without CPU
    assert v["repeats"][1][1] == pytest.approx(1.2e-5, rel=1e-12)
