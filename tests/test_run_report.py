"""A scene's ``report`` sees the state at every phase end, on both engines, in the summary."""
from __future__ import annotations

import numpy as np
import pytest

from rackstress import Dampen, Force, Group, Phase, PhaseIn, Scene
from rackstress.runs.run import run


def com_report(scene, records):
    return [{"step": r.step, "phase": r.phase, "cycle": r.cycle,
             "x": float(r.p[:, 0].mean())} for r in records]


def pushed_scene():
    """One particle, unit mass, pushed with a = 1 in phase 'push' only; no damping.

    Eq. 5 by hand, t = 0.1: after n pushed steps from rest, v = n·t, x = t²·n(n+1)/2.
    """
    g = Group("p", [[0.0, 0.0, 0.0]], 0.5)
    ops = {"p": [Force((1.0, 0.0, 0.0), when=(PhaseIn("on", (1,)),)), Dampen(0.0)]}
    phases = [Phase("push", 4, {"on": 1}), Phase("coast", 2, {"on": 0})]
    return Scene("pushed", {"p": g}, ops, phases, dt=0.1, cycles=2, report=com_report)


@pytest.mark.parametrize("engine", ["reference", "lammps"])
def test_report_at_phase_ends(tmp_path, engine):
    summary = run(pushed_scene(), tmp_path / engine, engine=engine, progress=False)
    rep = summary["report"]
    assert [r["step"] for r in rep] == [0, 4, 6, 10, 12]
    assert [r["phase"] for r in rep] == [None, "push", "coast", "push", "coast"]
    assert [r["cycle"] for r in rep] == [0, 0, 0, 1, 1]
    # hand iteration of Eq. 5: pushes 1..4 give v = 0.4, x = 0.01·10 = 0.1; coasting 2 steps
    # adds 2·0.04 = 0.08 → 0.18; pushing 4 more: v 0.5..0.8, x += 0.1·(0.5+0.6+0.7+0.8) = 0.26
    # → 0.44; coasting 2 steps at 0.8: → 0.6
    np.testing.assert_allclose([r["x"] for r in rep], [0.0, 0.1, 0.18, 0.44, 0.6], atol=1e-12)
    assert summary["groups"]["p"]["com_end"][0] == pytest.approx(0.6, abs=1e-12)


def test_report_stability_margin_of_a_scene_built_in_python(tmp_path):
    """A scene made in Python cannot be rebuilt from its name by the report, which used to say
    'not available'; the prediction the run's time step was checked with is recorded instead.
    Hand value: two particles bound to each other (bind c = 25 both ways, Eq. 12) linearize at
    rest to r̈ = −4c·r along their axis (2c·nnᵀ each), so ω² = 100, and with dampen γ = 1 Eq. 5
    is stable for t < 4/(γ + √(γ² + 4ω²)) = 4/(1 + √401)."""
    import json

    from rackstress import Bind, Const
    from rackstress.render.report import stability_margin

    groups = {"a": Group("a", [[0.0, 0.0, 0.0]], 0.5), "b": Group("b", [[1.0, 0.0, 0.0]], 0.5)}
    ops = {"a": [Bind("b", Const(25.0)), Dampen(1.0)], "b": [Bind("a", Const(25.0)), Dampen(1.0)]}
    sc = Scene("pair", groups, ops, [Phase("hold", 10, {})], dt=0.01)
    out = tmp_path / "pair"
    run(sc, out, engine="reference", progress=False)
    scene = json.loads((out / "scene.json").read_text())
    st = stability_margin(out, scene, {})
    assert st is not None
    assert st["t_max"] == pytest.approx(4.0 / (1.0 + np.sqrt(401.0)), rel=1e-9)
    assert st["ratio"] == pytest.approx(0.01 / st["t_max"], rel=1e-12)
