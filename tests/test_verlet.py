"""The second-order integration mode (Scene.integrator = "verlet") beside Eq. 5."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rackstress import scenes
from rackstress.engines.reference import Reference
from rackstress.errors import DivergenceError
from rackstress.model.operators import Bind, Const, Dampen, Force
from rackstress.model.particles import Group
from rackstress.model.scene import Phase, Scene
from rackstress.model.stability import predict
from rackstress.model.verlet import t_limit_verlet


def _run(scene) -> np.ndarray:
    eng = Reference(scene)
    for _ in range(scene.total_steps):
        eng.step({})
    return eng.p


def _pushed(dt, integrator, T=2.0, a=3.0, gamma=1.5):
    g = Group("p", np.zeros((1, 3)), 0.5)
    ops = {"p": [Force((a, 0.0, 0.0)), Dampen(gamma)]}
    return Scene("pushed", {"p": g}, ops, [Phase("go", int(round(T / dt)))], dt=dt,
                 integrator=integrator)


def _orders(errors):
    e = np.asarray(errors)
    return np.log2(e[:-1] / e[1:])


def test_damped_push_against_its_analytical_solution():
    """x'' = a − γx' from rest: x(T) = (a/γ)(T − (1 − e^{−γT})/γ)."""
    a, gamma, T = 3.0, 1.5, 2.0
    exact = a / gamma * (T - (1 - math.exp(-gamma * T)) / gamma)
    dts = (0.04, 0.02, 0.01, 0.005)
    err = {k: [abs(_run(_pushed(dt, k))[0, 0] - exact) for dt in dts] for k in ("euler", "verlet")}
    assert _orders(err["verlet"]).min() >= 1.9
    assert np.all(np.abs(_orders(err["euler"]) - 1.0) < 0.1)     # Eq. 5: first order
    assert err["verlet"][-1] < err["euler"][-1] / 100


def test_bound_pair_order_two_against_a_converged_run():
    """A damped pair bound by Eq. 12, one end pulled: smooth, nonlinear; reference at dt/16."""
    o = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])

    def pair(dt, integ, T=3.0):
        g = Group("pair", o, 0.5)
        ops = {"pair": [Force((0.0, 20.0, 0.0), where=(False, True)),
                        Bind("pair", Const(50.0)), Dampen(0.7)]}
        return Scene("pair", {"pair": g}, ops, [Phase("go", int(round(T / dt)))], dt=dt,
                     integrator=integ)

    conv = _run(pair(0.01 / 16, "verlet"))
    errs = [np.abs(_run(pair(dt, "verlet")) - conv).max() for dt in (0.04, 0.02, 0.01)]
    assert _orders(errs).min() >= 1.9


def test_verlet_limit_is_two_over_omega_whatever_the_damping():
    for gamma in (0.0, 1.0, 50.0):
        assert t_limit_verlet(400.0, gamma) == pytest.approx(0.1)
    # complex λ (directed couplings) by bisection: reduces to the real case as Im λ → 0
    assert t_limit_verlet(400.0 + 1e-6j, 1.0) == pytest.approx(0.1, rel=1e-4)


def test_predicted_limits_hold_on_a_strongly_damped_bound_pair():
    """A pair bound by Eq. 12 (c = 100 both ways: λ = 4c = 400 for the stretch) damped by 10:
    Eq. 5's limit is 4/(γ + √(γ² + 4λ)) = 0.0781, the verlet mode's 2/√λ = 0.1. At t = 0.09 the
    first grows without bound (until Eq. 12's nonlinearity stops it) and the second settles; at
    0.105 both grow."""
    o = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])

    def pair(dt, integ):
        g = Group("pair", o, 0.5)
        ops = {"pair": [Force((0.01, 0.0, 0.0), where=(False, True)),
                        Bind("pair", Const(100.0)), Dampen(10.0)]}
        return Scene("pair", {"pair": g}, ops, [Phase("go", 400)], dt=dt, integrator=integ)

    assert predict(pair(0.05, "euler"))["t_max"] == pytest.approx(4 / (10 + math.sqrt(1700)),
                                                                   rel=1e-6)
    assert predict(pair(0.05, "verlet"))["t_max"] == pytest.approx(0.1, rel=1e-6)
    def stretch(sc):
        """Largest |d − 1| over the run (an unstable step size makes it grow until Eq. 12's
        nonlinearity bounds it, far above the pull's stretch of 2.5e-5)."""
        eng, worst = Reference(sc), 0.0
        for _ in range(sc.total_steps):
            try:
                eng.step({})
            except DivergenceError:        # past the watchdog's bound: grown without limit
                return math.inf
            worst = max(worst, abs(float(np.linalg.norm(eng.p[1] - eng.p[0])) - 1.0))
        return worst

    assert stretch(pair(0.09, "verlet")) < 1e-4
    assert stretch(pair(0.07, "euler")) < 1e-4
    for integ, t in (("euler", 0.09), ("verlet", 0.105), ("euler", 0.105)):
        assert stretch(pair(t, integ)) > 0.1


@pytest.mark.lammps
def test_lammps_verlet_equals_the_reference_verlet():
    for name, kw in (("plane-rack", {}), ("plane-bound", {"d": 2.0})):
        sc = scenes.build(name, steps=200, **kw)
        sc.integrator = "verlet"
        from rackstress.bench.accuracy import run_engine

        a = run_engine(sc, "reference", "exact")["ends"][-1]
        b = run_engine(sc, "lammps", "exact")["ends"][-1]
        assert np.abs(a - b).max() < 1e-10
        euler = run_engine(scenes.build(name, steps=200, **kw), "reference", "exact")["ends"][-1]
        assert np.abs(a - euler).max() > 1e-4        # a different scheme, not Eq. 5 again


def test_cli_integrator_option(tmp_path):
    from click.testing import CliRunner

    from rackstress.cli import main

    res = CliRunner().invoke(main, ["run", "cantilever", "--set", "nx=6", "--set", "ny=2",
                                    "--engine", "reference", "--steps", "20", "--integrator",
                                    "verlet", "--out", str(tmp_path / "v"), "--no-render",
                                    "--no-progress"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    import json

    summary = json.loads((tmp_path / "v" / "summary.json").read_text())
    assert summary["params"]["integrator"] == "verlet"
    res = CliRunner().invoke(main, ["run", "--resume", str(tmp_path / "v"), "--integrator",
                                    "verlet"])
    # the checkpoint fixes the integrator: giving it again is refused, naming the option
    assert res.exit_code == 2 and "--integrator" in res.output


@pytest.mark.lammps
def test_lammps_verlet_equals_the_reference_verlet_across_phase_switches():
    """Two phases: at the switch LAMMPS must recompute the damping with v_{n-1/2}, the velocity
    the scheme damps with (a switch that used LAMMPS' full-step velocity left 6e-6 after the
    second phase on this scene)."""
    from rackstress import Bind, Const, Dampen, Force, Group, Phase, Scene
    from rackstress.bench.accuracy import run_engine

    a = Group("a", [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], 0.5)
    ops = {"a": [Force((0.0, 3.0, 0.0)), Bind("a", Const(40.0)), Dampen(2.0)]}
    sc = Scene("two-phase", {"a": a}, ops, [Phase("p1", 40, {"k": 1}), Phase("p2", 40, {"k": 2})])
    sc.integrator = "verlet"
    ref = run_engine(sc, "reference", "exact")["ends"]
    lmp = run_engine(sc, "lammps", "exact")["ends"]
    assert len(ref) == len(lmp) >= 2
    moved = np.abs(ref[-1] - sc.original_positions()).max()
    assert moved > 0.1
    for r, m in zip(ref, lmp):
        assert np.abs(r - m).max() <= 1e-10


def test_verlet_on_lammps_warns_of_the_lagged_contact_damping():
    """Eq. 28's contact damping acts on MagPod's two legs only (Section 4): the verlet mode on
    LAMMPS reports exactly those; Eq. 5, the reference engine and scenes without a conditional
    damping get no warning."""
    import dataclasses

    from rackstress import scenes
    from rackstress.engines.guards import verlet_lag

    mp = scenes.build("magpod-small")
    verlet = dataclasses.replace(mp, integrator="verlet")
    (w,) = verlet_lag(verlet, "lammps")
    assert w["kind"] == "verlet_lagged_damping" and w["groups"] == ["leftleg", "rightleg"]
    assert "--engine reference" in w["message"]
    assert verlet_lag(verlet, "reference") == [] and verlet_lag(mp, "lammps") == []
    plane = dataclasses.replace(scenes.build("plane-rack"), integrator="verlet")
    assert verlet_lag(plane, "lammps") == []


def _spring_frequency(integrator, t, c=100.0, steps=400, amp=1e-6):
    """Measured angular frequency θ/t of one particle bound (Eq. 12) to a held partner, started
    along the bond with a small velocity. A sampled rotation by θ per step satisfies
    x_{n+1} + x_{n−1} = 2cos θ·x_n; cos θ is its least-squares fit over the trajectory."""
    w = math.sqrt(2.0 * c)      # linearized Eq. 12 at rest: stiffness 2c along the bond, m = 1
    a = Group("a", np.array([[1.0, 0.0, 0.0]]), 0.1, v0=[amp, 0.0, 0.0])
    b = Group("b", np.zeros((1, 3)), 0.1, held=[True])
    sc = Scene("spring", {"a": a, "b": b}, {"a": [Bind("b", Const(c))]}, [Phase("p", steps)],
               dt=t, integrator=integrator)
    eng = Reference(sc)
    x = np.empty(steps)
    for n in range(steps):
        eng.step({})
        x[n] = eng.p[0, 0] - 1.0
    cos = np.dot(x[1:-1], x[2:] + x[:-2]) / (2.0 * np.dot(x[1:-1], x[1:-1]))
    return math.acos(cos) / t, w


@pytest.mark.parametrize("t", [0.02, 0.01])
def test_eq5_and_verlet_carry_an_undamped_mode_at_the_same_modified_frequency(t):
    """Why the verlet mode's gain over Eq. 5 is capped on lightly damped stiff scenes: both
    rotate an undamped mode by arccos(1 − ω²t²/2) per step (hand calculation from the common
    recursion p_{n+1} − 2p_n + p_{n−1} = t²·a(p_n)), not by ωt."""
    from rackstress.model.verlet import modified_frequency

    f_euler, w = _spring_frequency("euler", t)
    f_verlet, _ = _spring_frequency("verlet", t)
    expected = math.acos(1.0 - 0.5 * (w * t) ** 2) / t
    assert f_euler == pytest.approx(expected, rel=1e-8)
    assert f_verlet == pytest.approx(expected, rel=1e-8)
    # the shift is real: ω²t²/24 relative (8e-4 at t = 0.01), far above the tolerance
    assert abs(f_euler / w - 1.0) > 1e4 * 1e-8
    assert modified_frequency(w, t) == pytest.approx(expected, rel=1e-14)


def _phase_error_script():
    """scripts/phase_error.py, loaded from its file (scripts are not a package)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "phase_error.py"
    spec = importlib.util.spec_from_file_location("phase_error", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_phase_error_scan_matrices_against_closed_forms():
    """The scan's one-step matrices against hand-derived results. Störmer–Verlet's modified
    frequency is arccos(1 − ω²h²/2)/h. Chin's force-gradient scheme 4A (kicks H/6, middle
    2H/3 with ω²·(1 − ω²H²/24), drifts H/2) multiplied out by hand with x = ω²H²:
    trace/2 = 1 − x/2 + x²/24 − x³/864, which is cos(ωH) through x² (fourth order: halving
    the step divides the frequency error by 16) and reaches −1 at (x − 12)³ = 0, so it is
    stable for ωH < 2√3."""
    pe = _phase_error_script()
    for wh in (0.1, 0.5, 1.2):
        want = math.acos(1.0 - wh * wh / 2.0) / wh - 1.0
        assert pe.rel_error(pe.verlet(wh, 1.0), wh) == pytest.approx(abs(want), rel=1e-9)
    for z in (0.3, 1.0, 2.0, 3.0, 3.6):
        x = z * z
        want = 1.0 - x / 2.0 + x * x / 24.0 - x ** 3 / 864.0
        assert np.trace(pe.force_gradient(z, 1.0)) / 2.0 == pytest.approx(want, rel=1e-12)
    e1 = pe.rel_error(pe.force_gradient(0.1, 1.0), 0.1)
    e2 = pe.rel_error(pe.force_gradient(0.05, 1.0), 0.05)
    assert 15.5 < e1 / e2 < 16.5
    limit = 2.0 * math.sqrt(3.0)
    assert abs(np.trace(pe.force_gradient(limit * 0.999, 1.0))) < 2.0
    assert abs(np.trace(pe.force_gradient(limit * 1.001, 1.0))) > 2.0
