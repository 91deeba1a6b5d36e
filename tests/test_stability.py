"""The linear stability limit of Eq. 5 (docs/model.md, "Stability") and the run-time refusal built on it.

Hand values: Eq. 5 on x'' = −ω²x − γx' has the amplification matrix
[[1 − ω²t², t(1 − γt)], [−ω²t, 1 − γt]]; Jury's test gives ω²t² < 4 − 2γt, i.e.
t < 4/(γ + √(γ² + 4ω²)) (2/ω undamped, 2/γ for damping alone). A pair bound both ways with c
(Eq. 12, unit masses): the relative coordinate r obeys r'' = −2c·(r − L0²/r), whose slope at
r = L0 is 2, so ω² = 4c. A particle bound one way to a particle that does not move: ω² = 2c.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from rackstress import Bind, Const, Dampen, Group, Phase, Scene, scenes
from rackstress.bench.stability import measure_t_max, trial
from rackstress.cli import main
from rackstress.errors import SceneError
from rackstress.model.stability import check_dt, predict, t_limit


def pair(c: float, damping: float = 0.0, one_way: bool = False) -> Scene:
    a, b = Group("a", [[0.0, 0.0, 0.0]], 0.5), Group("b", [[1.0, 0.0, 0.0]], 0.5)
    ops = {"a": [Bind("b", Const(c))] + ([Dampen(damping)] if damping else [])}
    if not one_way:
        ops["b"] = [Bind("a", Const(c))] + ([Dampen(damping)] if damping else [])
    return Scene("pair", {"a": a, "b": b}, ops, [Phase("run", 300)])


def nudged(scene: Scene, dx: float = 1e-4) -> np.ndarray:
    p = scene.original_positions().copy()
    p[0, 0] -= dx   # stretch the bond a little: the only thing that sets the pair moving
    return p


def test_scalar_limit_by_hand():
    assert t_limit(400.0) == pytest.approx(0.1)                 # 2/ω, ω = 20
    assert t_limit(0.0, 50.0) == pytest.approx(0.04)            # 2/γ
    assert t_limit(1600.0, 10.0) == pytest.approx(4.0 / (10.0 + math.sqrt(100.0 + 6400.0)))
    assert t_limit(0.0, 0.0) == math.inf
    # a complex λ (directed coupling) is handled by the exact root test; real part alone
    # would give 2/√400 = 0.1; the imaginary part only lowers it
    assert 0.0 < t_limit(400.0 + 100.0j) < 0.1


def test_bound_pair_prediction_is_the_hand_value():
    c = 100.0
    pred = predict(pair(c))
    assert pred["omega2"] == pytest.approx(4 * c, rel=1e-9)
    assert pred["t_max"] == pytest.approx(1.0 / math.sqrt(c), rel=1e-9)      # 2/√(4c) = 0.1
    # the Gershgorin row sum is exact for the symmetric pair (|K_aa| + |K_ab| = 2c + 2c)
    assert pred["t_max_gershgorin"] == pytest.approx(0.1, rel=1e-9)
    assert pred["group"] in ("a", "b") and "bind" in pred["operator"]
    one = predict(pair(c, one_way=True))
    assert one["omega2"] == pytest.approx(2 * c, rel=1e-9)                   # b does not move
    assert one["t_max"] == pytest.approx(2.0 / math.sqrt(2 * c), rel=1e-9)


def test_bound_pair_measured_threshold_matches_within_a_few_percent():
    sc = pair(100.0)
    p0 = nudged(sc)
    assert trial(sc, 0.097, 300, p0)["stable"]
    assert not trial(sc, 0.103, 300, p0)["stable"]
    m = measure_t_max(sc, 0.08, 300, p0)
    assert m["converged"] and m["t_measured"] == pytest.approx(0.1, rel=0.03)


def test_damped_pair_and_damped_particle():
    c, g = 100.0, 10.0
    pred = predict(pair(c, damping=g))
    hand = 4.0 / (g + math.sqrt(g * g + 16.0 * c))                          # 0.0781
    assert pred["t_max"] == pytest.approx(hand, rel=1e-9) and pred["gamma"] == pytest.approx(g)
    m = measure_t_max(pair(c, damping=g), hand, 300, nudged(pair(c, damping=g)))
    assert m["t_measured"] == pytest.approx(hand, rel=0.03)
    # one free particle damped by 50: the limit is γt < 2
    lone = Scene("lone", {"p": Group("p", [[0.0, 0.0, 0.0]], 0.5)}, {"p": [Dampen(50.0)]},
                 [Phase("run", 10)])
    assert predict(lone)["t_max"] == pytest.approx(0.04)


def test_within100_magnitude20_stable_and_100_unstable_at_001():
    """Section 3.1 / docs/model.md, "Stability": magnitude 20 usable at t = 0.01, magnitude 100 diverges."""
    p20 = predict(scenes.build("plane-bound", d=100.0, magnitude=20.0))
    p100 = predict(scenes.build("plane-bound", d=100.0, magnitude=100.0))
    assert p20["t_max"] > 0.01 > p100["t_max"]
    # all 400 particles bound to all: ω² = 2·N·c = 800c (the largest eigenvalue), with γ = 1
    assert p100["omega2"] == pytest.approx(800 * 100.0, rel=1e-6)
    assert p100["t_max"] == pytest.approx(4.0 / (1.0 + math.sqrt(1.0 + 4 * 80000.0)), rel=1e-6)


@pytest.mark.parametrize("name,kw", [("plane-bound", {"d": 2.0}), ("plane-bound", {"d": 10.0}),
                                     ("plane-bound", {"d": 100.0}), ("plane-rack", {}),
                                     ("magpod", {}), ("magpod-small", {})])
def test_builtin_scenes_predicted_stable_at_their_defaults(name, kw):
    sc = scenes.build(name, **kw)
    assert sc.dt == 0.01
    pred = check_dt(sc)          # does not raise
    assert pred["t_max"] > 0.01


def test_refusal_names_dt_the_limit_and_the_operator(tmp_path):
    from rackstress.runs.run import run

    sc = scenes.build("plane-bound", d=100.0, magnitude=100.0, steps=10)
    with pytest.raises(SceneError) as info:
        run(sc, tmp_path / "r", engine="reference", progress=False)
    msg = str(info.value)
    assert "time step 0.01 exceeds the predicted stability limit 0.007059" in msg
    assert "'plane' bind(plane, within(100) magnitude 100)" in msg
    assert "--allow-unstable" in msg
    assert not (tmp_path / "r").exists()            # refused before anything was written
    # the flag overrides it (10 steps do not reach the divergence yet)
    s = run(sc, tmp_path / "r", engine="reference", progress=False, allow_unstable=True)
    assert s["status"] == "ok"


def test_cli_refuses_with_exit_2_and_flag_overrides(tmp_path):
    runner = CliRunner()
    args = ["run", "plane-bound", "--engine", "reference", "--set", "d=100", "--steps", "5",
            "--no-progress", "--no-render", "--dt", "0.02"]
    res = runner.invoke(main, args + ["--out", str(tmp_path / "a")])
    assert res.exit_code == 2
    assert "time step 0.02 exceeds the predicted stability limit 0.01575" in res.output
    res = runner.invoke(main, args + ["--out", str(tmp_path / "b"), "--allow-unstable"])
    assert res.exit_code == 0, res.output


@pytest.mark.slow
def test_magpod_gait_breaks_just_beyond_the_predicted_limit():
    """MagPod's predicted limit (a sole's rack bind under contact damping γ = 95) is where the
    gait really stops working: one cycle at 0.93× the prediction walks as at t = 0.01, at
    1.1× it does not (stopped or off by more than the benchmark's 5 %)."""
    from rackstress.bench.stability import GAIT_TOL, gait_cycle

    t_max = predict(scenes.build("magpod-small"))["t_max"]
    base, below, above = gait_cycle(0.01), gait_cycle(0.93 * t_max), gait_cycle(1.1 * t_max)
    assert base["stopped"] is None and base["advance"] > 10.0
    assert below["stopped"] is None
    assert abs(below["advance"] - base["advance"]) <= GAIT_TOL * base["advance"]
    assert above["stopped"] or abs(above["advance"] - base["advance"]) > GAIT_TOL * base["advance"]


def test_the_stiffness_matrix_sums_repeated_pairs_block_by_block():
    """K[p, p] += B and K[p, u] −= B for every listed pair (``stability.stiffness_matrix``),
    a pair listed twice adding both blocks; a particle that is only ever a partner keeps an
    empty row (``_top_eigen`` drops those rows). By hand, with blocks A, C on pair (0, 2)
    twice and D on (2, 0): rows of 0 are [A + C, 0, −(A + C)], of 2 [−D, 0, D], of 1 empty."""
    from rackstress.model.stability import stiffness_matrix

    A = np.arange(9.0).reshape(3, 3)
    C, D = np.eye(3) * 5.0, -np.ones((3, 3))
    K = stiffness_matrix({"I": np.array([0, 0, 2]), "J": np.array([2, 2, 0]),
                          "B": np.stack([A, C, D])}, 3)
    want = np.zeros((9, 9))
    want[0:3, 0:3], want[0:3, 6:9] = A + C, -(A + C)
    want[6:9, 6:9], want[6:9, 0:3] = D, -D
    assert K.format == "csr" and np.array_equal(K.toarray(), want)
    assert list(np.diff(K.indptr)[3:6]) == [0, 0, 0]
