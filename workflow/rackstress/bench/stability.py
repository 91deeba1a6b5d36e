"""``rackstress bench stability``: the largest stable time step, measured against the prediction.

For each case a scene is run on the reference engine for ``steps`` (300) iterations of Eq. 5 at a
time step t, from its original positions or from jittered ones, and called **stable** when

1. the watchdog does not stop it (every position and velocity finite, no particle further than
   the scene's bound, 10⁴, from its original position), and
2. nothing grows exponentially: with ``q_n = max_i ‖p_i(n+1) − 2p_i(n) + p_i(n−1)‖`` (the
   step-to-step acceleration, t²·a; Eq. 5's instability is a growing alternation of period 2,
   which dominates q), q never exceeds ``GROWTH`` (10³) times t²·max‖a₀‖, the step the initial
   accelerations give, and its last value is not more than ``GROWTH`` times its smallest over the
   second half of the run. A stable run keeps q of the order of what the initial forces give;
   an unstable mode growing by |μ| per step multiplies q by |μ|^n, which passes 10³ within 300
   steps for |μ| > 1.024: a t within ~0.1 % of the linear threshold (|μ| − 1 ≈ √ε for
   ω²t² = 4 + ε). The first test also catches an unstable mode that the nonlinearity of
   Eq. 12 saturates into a large bounded period-2 oscillation (a softening bond: an isolated
   bound pair does that) before the watchdog's bound is reached.

The largest stable t is found by bisection: from the predicted limit, step by ×1.5 up (or
down) until the result flips, then halve the bracket until it is within ``REL_TOL`` (1 %). The
table sets it beside :func:`rackstress.model.stability.predict` and reports measured / predicted (the
target: within a factor 2 either way).
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from rackstress.errors import DivergenceError
from rackstress.model.operators import Collide, Const
from rackstress.engines.driver import drive
from rackstress.engines.reference import Reference
from rackstress.model.scene import Scene
from rackstress.model.stability import predict
from rackstress.bench import fmt, machine, md_table, out_dir, repository_file, write_json

STEPS = 300
GROWTH = 1.0e3
REL_TOL = 0.01
TWO_BLOBS = repository_file("scenes", "two-blobs.toml")


# ---------------------------------------------------------------------------- one trial
def trial(scene: Scene, dt: float, steps: int = STEPS, p0: np.ndarray | None = None) -> dict:
    """Run ``scene`` at time step ``dt`` for ``steps`` iterations; stable or not, and why."""
    sc = scene.with_steps(steps)
    sc.dt = float(dt)
    ref = Reference(sc)
    if p0 is not None:
        ref.p = np.array(p0, dtype=float)
    first = next(iter(sc.schedule()))[1].vars
    a0 = ref.accelerations(first)
    q0 = float(dt * dt * np.sqrt((a0 * a0).sum(axis=1)).max())
    q = np.zeros(steps)
    prev = [None, ref.p.copy()]

    def observe(eng):      # the second difference of the positions, step by step
        k = eng.step_count - 1
        if prev[0] is not None:
            dd = eng.p - 2.0 * prev[1] + prev[0]
            q[k] = float(np.sqrt((dd * dd).sum(axis=1)).max())
        prev[0], prev[1] = prev[1], eng.p.copy()

    try:
        drive(ref, on_chunk=observe, check_every=1)
        n = ref.step_count
    except (DivergenceError, FloatingPointError) as err:
        n = ref.step_count
        return {"stable": False, "reason": "watchdog", "step": getattr(err, "step", n)}
    if not np.isfinite(ref.p).all():
        return {"stable": False, "reason": "non-finite", "step": n}
    floor = 1e-12 * max(1.0, float(np.abs(ref.p).max()))
    start = max(q0, floor)
    if q.max() > GROWTH * start:
        return {"stable": False, "reason": f"grew x{q.max() / start:.3g}", "step": n}
    half = q[steps // 2:]
    low = max(float(half.min()), floor)
    if half[-1] > GROWTH * low:
        return {"stable": False, "reason": f"growing x{half[-1] / low:.3g}", "step": n}
    return {"stable": True, "reason": "", "step": n}


def measure_t_max(scene: Scene, t_guess: float, steps: int = STEPS, p0=None,
                  rel_tol: float = REL_TOL, max_trials: int = 40) -> dict:
    """Largest stable t by expansion from ``t_guess`` and bisection (module docstring)."""
    def verdict(t):
        r = trial(scene, t, steps, p0)
        return r["stable"], r["reason"]

    return bisect_limit(verdict, t_guess, rel_tol, max_trials)


def bisect_limit(verdict, t_guess: float, rel_tol: float = REL_TOL,
                 max_trials: int = 40) -> dict:
    """Largest t with ``verdict(t)`` = (True, _): from ``t_guess`` step by ×1.5 up (or down)
    until the verdict flips, then halve the bracket (geometrically) to ``rel_tol``."""
    trials = []

    def stable(t):
        ok, why = verdict(t)
        trials.append((t, ok, why))
        return ok

    t = float(t_guess)
    lo = hi = None
    if stable(t):
        lo = t
        while hi is None and len(trials) < max_trials:
            t *= 1.5
            if stable(t):
                lo = t
            else:
                hi = t
    else:
        hi = t
        while lo is None and len(trials) < max_trials:
            t /= 1.5
            if stable(t):
                lo = t
            else:
                hi = t
    if lo is None or hi is None:
        return {"t_measured": lo, "bracket": [lo, hi], "trials": trials, "converged": False}
    while hi / lo > 1.0 + rel_tol and len(trials) < max_trials:
        mid = math.sqrt(lo * hi)
        if stable(mid):
            lo = mid
        else:
            hi = mid
    return {"t_measured": lo, "bracket": [lo, hi], "trials": trials, "converged": True,
            "first_unstable_reason": next((r for t, s, r in trials if t == hi), "")}


# ---------------------------------------------------------------------------- scenes
def jitter(scene: Scene, fraction: float = 0.1, seed: int = 6) -> np.ndarray:
    """Original positions moved by up to ``fraction`` of each particle's radius (uniform in a ball)."""
    rng = np.random.default_rng(seed)
    o = scene.original_positions()
    d = rng.normal(size=o.shape)
    d /= np.linalg.norm(d, axis=1)[:, None]
    r = scene.radii() * fraction * rng.uniform(0, 1, len(o)) ** (1 / 3)
    return o + d * r[:, None]


def replace_ops(scene: Scene, fn) -> Scene:
    """The scene with every operator ``op`` on ``target`` replaced by ``fn(target, op)``."""
    ops = {t: [fn(t, op) for op in seq] for t, seq in scene.operators.items()}
    return Scene(scene.name, scene.groups, ops, scene.phases, scene.dt, scene.cycles,
                 scene.bound, dict(scene.params), scene.report,
                 duration=scene.duration, limit=scene.limit)


def two_blobs(collide: float = 100.0, ratio: float = 0.2) -> Scene:
    """scenes/two-blobs.toml with blob a's collide coefficient ``collide``, b's ``ratio``·that."""
    from rackstress import scenes

    sc = scenes.load(str(TWO_BLOBS))

    def fn(target, op):
        if isinstance(op, Collide):
            c = collide if target == "a" else ratio * collide
            return dataclasses.replace(op, coeff=Const(float(c)))
        return op
    out = replace_ops(sc, fn)
    out.params = {"collide": collide, "ratio": ratio}
    return out


def cases(quick: bool = False) -> list[dict]:
    """The benchmark's cases: dicts with a label, a family, a scene builder and optional jitter."""
    from rackstress import scenes

    out = []

    def add(family, label, make, jitter_fraction=0.0, steps=STEPS):
        out.append({"family": family, "label": label, "make": make,
                    "jitter": jitter_fraction, "steps": steps})

    mags = (20.0, 100.0) if quick else (5.0, 10.0, 20.0, 50.0, 100.0)
    for m in mags:
        add("bind within(100)", f"plane-bound d=100 magnitude={m:g}",
            lambda m=m: scenes.build("plane-bound", d=100.0, magnitude=m))
    if not quick:
        for d in (2.0, 10.0):
            add("bind within(d)", f"plane-bound d={d:g} magnitude=20",
                lambda d=d: scenes.build("plane-bound", d=d))
    for c in ((100.0,) if quick else (20.0, 100.0, 500.0, 2000.0)):
        add("rack bind", f"plane-rack plane_bind={c:g}",
            lambda c=c: scenes.build("plane-rack", plane_bind=c))
    for c in ((100.0,) if quick else (100.0, 1000.0, 10000.0)):
        add("collide", f"two-blobs collide={c:g} (b: {0.2 * c:g})", lambda c=c: two_blobs(c))
    for g in ((50.0,) if quick else (1.0, 10.0, 50.0, 100.0, 150.0)):
        add("damping", f"plane-bound d=2 damping={g:g}",
            lambda g=g: scenes.build("plane-bound", d=2.0, damping=g))
    if not quick:
        add("perturbed", "plane-bound d=10 jitter 10% r",
            lambda: scenes.build("plane-bound", d=10.0), 0.1)
        add("perturbed", "plane-rack jitter 10% r", lambda: scenes.build("plane-rack"), 0.1)
        add("perturbed", "two-blobs jitter 10% r", lambda: two_blobs(100.0), 0.1)
        add("extreme", "plane-bound d=2 magnitude=1e4",
            lambda: scenes.build("plane-bound", d=2.0, magnitude=1e4))
        add("extreme", "plane-rack plane_bind=1e4 rack_bind=50",
            lambda: scenes.build("plane-rack", plane_bind=1e4, rack_bind=50.0))
        add("extreme", "two-blobs collide=1e5", lambda: two_blobs(1e5))
        add("extreme", "plane-bound d=2 damping=1000",
            lambda: scenes.build("plane-bound", d=2.0, damping=1000.0))
        # soft: the pull is 1, not 100 (with 100 the corner flies past the watchdog's bound of
        # 10^4 units within 300 large steps, which is physics, not instability)
        add("extreme", "plane-bound d=2 magnitude=0.01 pull 1 (soft)",
            lambda: scenes.build("plane-bound", d=2.0, magnitude=0.01, pull_accel=1.0))
    # the second-order mode (model/verlet.py): predicted t < 2/ω whatever the damping
    verlet_cases = [("plane-rack", lambda: scenes.build("plane-rack"))]
    if not quick:
        verlet_cases += [
            ("plane-bound d=100 magnitude=20",
             lambda: scenes.build("plane-bound", d=100.0, magnitude=20.0)),
            ("plane-bound d=10 magnitude=20", lambda: scenes.build("plane-bound", d=10.0)),
            ("plane-bound d=2 damping=1", lambda: scenes.build("plane-bound", d=2.0, damping=1.0)),
            ("plane-bound d=2 damping=50",
             lambda: scenes.build("plane-bound", d=2.0, damping=50.0)),
            ("plane-bound d=2 damping=150",
             lambda: scenes.build("plane-bound", d=2.0, damping=150.0)),
            ("plane-bound d=2 damping=1000",
             lambda: scenes.build("plane-bound", d=2.0, damping=1000.0)),
            ("two-blobs collide=100 (b: 20)", lambda: two_blobs(100.0)),
            ("two-blobs collide=10000 (b: 2000)", lambda: two_blobs(1e4))]
    for label, make in verlet_cases:
        # under strong damping the verlet mode's unstable root (|μ| up to 1.07 a step just past
        # 2/ω) grows from round-off only: 300 steps do not show it (damping 1000, t = 0.2: stable
        # for 300 steps, the watchdog at step 759), so the plane-bound d=2 cases (cheap) get 3000
        long = "d=2 damping" in label
        add("verlet mode", f"{label}, verlet" + (" (3000 steps)" if long else ""),
            lambda make=make: _verlet(make()), steps=3000 if long else STEPS)
    if not quick:
        add("magpod", "magpod-small gait cycle", None)
        out[-1]["gait"] = True      # its own criterion: magpod_gait_case
    return out


def _verlet(scene: Scene) -> Scene:
    """The scene run by the second-order mode (:mod:`rackstress.model.verlet`)."""
    scene.integrator = "verlet"
    return scene


def run_case(case: dict) -> dict:
    sc = case["make"]()
    t0 = time.perf_counter()
    pred = predict(sc)
    t_pred_s = time.perf_counter() - t0
    p0 = jitter(sc, case["jitter"]) if case["jitter"] else None
    guess = pred["t_max"] if math.isfinite(pred["t_max"]) else 0.1
    t0 = time.perf_counter()
    meas = measure_t_max(sc, guess, case["steps"], p0)
    wall = time.perf_counter() - t0
    tm = meas["t_measured"]
    return {"family": case["family"], "case": case["label"], "n_particles": sc.n_particles,
            "steps": case["steps"], "jitter": case["jitter"],
            "t_pred": pred["t_max"], "t_pred_gershgorin": pred["t_max_gershgorin"],
            "limit": {k: pred[k] for k in ("group", "particle", "operator", "omega2", "gamma",
                                           "how", "phase")},
            "virtual_contacts": pred["virtual_contacts"],
            "t_measured": tm, "bracket": meas["bracket"], "converged": meas["converged"],
            "ratio": (tm / pred["t_max"]) if tm and math.isfinite(pred["t_max"]) else None,
            "within_2x": bool(tm and 0.5 <= tm / pred["t_max"] <= 2.0),
            "stable_at_0.01": bool(tm is not None and tm >= 0.01),
            "predicted_stable_at_0.01": bool(pred["t_max"] >= 0.01),
            "trials": [{"t": t, "stable": s, "why": r} for t, s, r in meas["trials"]],
            "predict_s": t_pred_s, "wall_s": wall}


#: MagPod gait cycle: usable while the cycle's advance is within this fraction of the t = 0.01 run
GAIT_TOL = 0.05
#: ... and its pitch within this many degrees
GAIT_PITCH_DEG = 2.0


def gait_cycle(t: float) -> dict:
    """One gait cycle of ``magpod-small`` at time step t (phases keep their physical length,
    12 time units), LAMMPS exact mode: the gait report's advance and pitch, or the stop."""
    from rackstress import scenes
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun
    from rackstress.model.scene import PhaseEnd

    sc = scenes.build("magpod-small", dt=t, phase_steps=max(1, round(12.0 / t)), cycles=1)
    records = [PhaseEnd(0, None, {}, 0, sc.original_positions())]
    runner = LammpsRun(compile_deck(sc, "exact"), None, log=False)
    try:
        drive(runner, on_phase_end=records.append)
    except DivergenceError as err:
        return {"stopped": f"watchdog at step {err.step}"}
    finally:
        runner.close()
    cyc = sc.report(sc, records)["cycles"][-1]
    return {"stopped": None, "advance": cyc["advance"], "pitch_deg": cyc["pitch_deg"]}


def magpod_gait_case() -> dict:
    """MagPod's usable limit: the largest t whose gait cycle matches the cycle at t = 0.01.

    The growth test of :func:`trial` cannot see MagPod's failure mode: beyond 2/γ a sole's
    contact damping (γ = 95, Eq. 28) overshoots and throws the sole off the sediment, which
    switches the damping off again, so nothing grows, but the robot no longer walks. So here
    a t is usable when one gait cycle on LAMMPS (exact) is not stopped by the watchdog and its
    advance is within ``GAIT_TOL`` and its pitch within ``GAIT_PITCH_DEG`` of the cycle at
    t = 0.01; bisection as in :func:`measure_t_max`. The growth test over the first 300
    iterations is reported beside it.
    """
    from rackstress import scenes

    sc = scenes.build("magpod-small")
    pred = predict(sc)
    t0 = time.perf_counter()
    base = gait_cycle(0.01)

    def usable(t):
        g = gait_cycle(t)
        if g["stopped"]:
            why = g["stopped"]
        elif abs(g["advance"] - base["advance"]) > GAIT_TOL * abs(base["advance"]):
            why = f"advance {g['advance']:.3g} vs {base['advance']:.3g}"
        elif abs(g["pitch_deg"] - base["pitch_deg"]) > GAIT_PITCH_DEG:
            why = f"pitch {g['pitch_deg']:.3g} vs {base['pitch_deg']:.3g} deg"
        else:
            why = ""
        return not why, why

    meas = bisect_limit(usable, pred["t_max"], max_trials=16)
    wall = time.perf_counter() - t0
    growth = measure_t_max(sc, pred["t_max"])
    tm = meas["t_measured"]
    return {"family": "magpod", "case": "magpod-small gait cycle usable (LAMMPS exact)",
            "n_particles": sc.n_particles, "steps": None, "jitter": 0.0,
            "t_pred": pred["t_max"], "t_pred_gershgorin": pred["t_max_gershgorin"],
            "limit": {k: pred[k] for k in ("group", "particle", "operator", "omega2", "gamma",
                                           "how", "phase")},
            "virtual_contacts": pred["virtual_contacts"],
            "t_measured": tm, "bracket": meas["bracket"], "converged": meas["converged"],
            "ratio": tm / pred["t_max"] if tm else None,
            "within_2x": bool(tm and 0.5 <= tm / pred["t_max"] <= 2.0),
            "stable_at_0.01": True, "predicted_stable_at_0.01": bool(pred["t_max"] >= 0.01),
            "trials": [{"t": t, "stable": s, "why": r} for t, s, r in meas["trials"]],
            "baseline": base, "gait_tol": GAIT_TOL, "gait_pitch_deg": GAIT_PITCH_DEG,
            "growth_test_300": {"t_measured": growth["t_measured"],
                                "ratio": (growth["t_measured"] / pred["t_max"]
                                          if growth["t_measured"] else None)},
            "predict_s": 0.0, "wall_s": wall}


def magpod_case(steps: int = 17480) -> dict:
    """The full MagPod run (LAMMPS, exact mode) for ``steps`` iterations at its dt = 0.01."""
    from rackstress import scenes
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    sc = scenes.build("magpod").with_steps(steps)
    pred = predict(sc)
    t0 = time.perf_counter()
    runner = LammpsRun(compile_deck(sc, "exact"), None, log=False)
    status, why = "stable", ""
    try:
        drive(runner)
        p = runner.gather_positions()
        o = sc.original_positions()
        disp = float(np.linalg.norm(p - o, axis=1).max())
    except DivergenceError as err:
        status, why, disp = "diverged", str(err), None
    finally:
        runner.close()
    return {"family": "magpod", "case": f"magpod LAMMPS exact, {steps} iterations at t=0.01",
            "n_particles": sc.n_particles, "steps": steps, "t_pred": pred["t_max"],
            "t_pred_gershgorin": pred["t_max_gershgorin"],
            "limit": {k: pred[k] for k in ("group", "particle", "operator", "omega2", "gamma",
                                           "how", "phase")},
            "t_run": 0.01, "status": status, "why": why, "max_displacement": disp,
            "dt_over_t_pred": 0.01 / pred["t_max"], "wall_s": time.perf_counter() - t0}


# ---------------------------------------------------------------------------- the command
def run_bench(out: Path | None = None, quick: bool = False, magpod: bool = False,
              magpod_steps: int = 17480, only=None, echo=print) -> dict:
    out = out_dir(out)
    t_start = time.perf_counter()
    rows = []
    for case in cases(quick):
        if only and not any(s in case["label"] for s in only):
            continue
        r = magpod_gait_case() if case.get("gait") else run_case(case)
        rows.append(r)
        echo(f"  {r['case']:45s} predicted {fmt(r['t_pred'], 4):>8s}  measured "
             f"{fmt(r['t_measured'], 4):>8s}  ratio {fmt(r['ratio'], 3)}  ({r['wall_s']:.1f} s)")
    mp = magpod_case(magpod_steps) if magpod else None
    data = {"benchmark": "stability", "machine": machine(), "steps_per_trial": STEPS,
            "criterion": __doc__.split("The largest stable")[0].strip(), "growth": GROWTH,
            "rel_tol": REL_TOL, "cases": rows, "magpod": mp,
            "all_within_2x": all(r["within_2x"] for r in rows),
            "wall_s": time.perf_counter() - t_start}
    write_json(out / "stability.json", data)
    (out / "stability.md").write_text(markdown(data))
    plot(data, out / "stability.png")
    data["files"] = [str(out / f) for f in ("stability.json", "stability.md", "stability.png")]
    return data


def table_rows(data: dict) -> list:
    rows = []
    for r in data["cases"]:
        rows.append([r["family"], r["case"], fmt(r["t_pred"], 4), fmt(r["t_pred_gershgorin"], 4),
                     fmt(r["t_measured"], 4), fmt(r["ratio"], 3),
                     "yes" if r["within_2x"] else "**no**", r["limit"]["operator"]])
    return rows


HEADER = ["family", "case", "t_max predicted", "Gershgorin bound", "t measured (largest stable)",
          "measured / predicted", "within 2×", "limit set by"]


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# Stability of Eq. 5: measured largest stable time step vs the linear prediction",
             "",
             "Regenerate: `rackstress bench stability` (add `--magpod` for the 17,480-iteration "
             "MagPod run on LAMMPS). "
             f"Machine: {m['cores']} cores ({m['cpu']}), shared; Python {m['python']}.",
             "",
             "Prediction: `rackstress.model.stability.predict` (linearization at the original positions; "
             "largest eigenvalues of the pair-operator Jacobian with their damping, "
             "t_max = 4/(γ + √(γ² + 4ω²)); rows 'verlet mode': the second-order mode, whose "
             "limit is t_max = 2/ω whatever the damping). Gershgorin: the row-sum bound on the "
             "same linearization. Measured: reference engine (the run's own integrator), "
             f"{data['steps_per_trial']} steps a trial (more where the case says so), "
             f"bisection to {data['rel_tol']:.0%}; "
             "stable = no watchdog stop and no exponential growth of the step-to-step "
             f"acceleration (last value ≤ {data['growth']:g}× the second half's minimum).",
             "", md_table(HEADER, table_rows(data))]
    mp = data.get("magpod")
    if mp:
        lines += ["", f"**MagPod** ({mp['n_particles']} particles), {mp['case']}: "
                  f"{mp['status']}{(' — ' + mp['why']) if mp['why'] else ''}; predicted limit "
                  f"{fmt(mp['t_pred'], 4)} (t/t_max = {fmt(mp['dt_over_t_pred'], 3)}), set by "
                  f"{mp['limit']['operator']}; max displacement "
                  f"{fmt(mp['max_displacement'], 4)}; {mp['wall_s']:.0f} s.", ""]
    for r in data["cases"]:
        g = r.get("growth_test_300")
        if g:
            lines += ["", f"**{r['case']}**: usable means one gait cycle (phases of 12 time "
                      f"units) not stopped, its advance within {r['gait_tol']:.0%} and pitch "
                      f"within {r['gait_pitch_deg']:g}° of the cycle at t = 0.01 (advance "
                      f"{r['baseline']['advance']:.3g}, pitch {r['baseline']['pitch_deg']:.3g}°). "
                      "Trials: " + "; ".join(f"t={x['t']:.4g} {'ok' if x['stable'] else x['why']}"
                                             for x in r["trials"])
                      + f". The growth test alone (300 iterations of the first phase) measures "
                      f"{fmt(g['t_measured'], 4)} ({fmt(g['ratio'], 3)}× the prediction): beyond "
                      "2/γ a sole's contact damping (γ = 95) overshoots and throws the sole off "
                      "the sediment, which switches the damping off, so nothing grows, but the "
                      "robot stops walking.", ""]
    bad = [r["case"] for r in data["cases"] if not r["within_2x"]]
    lines.append("All cases within a factor 2 of the prediction." if not bad else
                 "Outside a factor 2: " + ", ".join(bad) + ".")
    return "\n".join(lines) + "\n"


def plot(data: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    fams = sorted({r["family"] for r in data["cases"]})
    markers = "osD^v<>p*h"
    xs = []
    for k, fam in enumerate(fams):
        rs = [r for r in data["cases"] if r["family"] == fam and r["t_measured"]]
        x = [r["t_pred"] for r in rs]
        y = [r["t_measured"] for r in rs]
        xs += x + y
        ax.scatter(x, y, marker=markers[k % len(markers)], label=fam, s=40)
    if xs:
        lo, hi = min(xs) / 2, max(xs) * 2
        g = np.array([lo, hi])
        ax.plot(g, g, "k-", lw=1, label="measured = predicted")
        ax.fill_between(g, g / 2, g * 2, color="0.85", alpha=0.6, label="within 2×")
        ax.set_xlim(lo, hi)
        ax.set_ylim(lo, hi)
    ax.axhline(0.01, color="r", lw=0.8, ls=":")
    ax.text(ax.get_xlim()[0] * 1.1, 0.0105, "t = 0.01 (the paper's)", color="r", fontsize=8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("predicted t_max (linear, Eq. 5)")
    ax.set_ylabel("measured largest stable t (reference engine)")
    ax.set_title("Stability of Eq. 5: measured vs predicted")
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
