"""``rackstress bench accuracy [--quick]``: work-precision of every engine and mode.

For each scene (plane-bound d = 10, plane-rack, magpod-small) and each time step t in
``T_STEPS`` the scene is run to the same physical time T (steps = T/t; MagPod's phases keep
their physical length, phase_steps = T_phase/t) on

* the reference engine (NumPy, Eq. 5 exactly),
* LAMMPS exact mode and LAMMPS fast mode (one rank),
* the second-order ``verlet`` mode (:mod:`rackstress.model.verlet`) on the reference engine and
  on LAMMPS exact mode,

and compared with a **converged reference**: the reference engine in the verlet mode at t/8 of
the smallest t (``t_conv`` = 0.0025/8 = 0.0003125; Eq. 5 there is itself ~1e-3 off on the
planes, the verlet mode ~1e-6), at the same physical times (the end of the run, and for
MagPod every phase end). Errors:

* positions: RMS and max over all particles of ‖p − p_conv‖ (max over the compared times);
* ``max_deformation`` of each part: |value − converged value|, largest over the parts;
* the stress field of the paper's measure (distance from the desired position,
  :func:`rackstress.lib.rigid.deformation` per group): max over particles of the difference.
  Both use the plain Kabsch fit, which is smooth in the positions (a convergence study needs
  that); ``summary.json`` and the pictures use the robust fit, whose outlier cut can switch
  between two nearby runs;
* MagPod: the distance walked (the body's centre-of-mass advance along +x): |difference|.

A t the stability prediction refuses (t > t_max, :mod:`rackstress.model.stability`) is skipped and
reported; a run the watchdog stops is reported as diverged. Wall time is the stepping only
(:func:`rackstress.engines.driver.drive`; setup is reported apart). ``--quick``: T = 3 for the planes and
20-iteration (at t = 0.01) phases for MagPod (one cycle, T = 0.8); full: T = 12 and 300-iteration
phases (T = 12).
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from rackstress.lib import rigid
from rackstress import scenes
from rackstress.errors import DivergenceError, RackstressError
from rackstress.engines.driver import drive
from rackstress.engines.reference import Reference
from rackstress.model.stability import predict
from rackstress.bench import fmt, machine, md_table, out_dir, write_json

T_STEPS = (0.02, 0.01, 0.005, 0.0025)
#: A fast-mode run counts as on the work-precision front when it is at least this much faster
#: than the cheapest exact-mode run that is at least as accurate (timings here drift ±20 %).
FRONT_MARGIN = 1.2
REFINE = 8
#: (engine, deck mode, integrator): Eq. 5 on every engine and mode, and the second-order
#: "verlet" mode (:mod:`rackstress.model.verlet`) on the reference engine and LAMMPS.
ENGINES = (("reference", "exact", "euler"), ("lammps", "exact", "euler"),
           ("lammps", "fast", "euler"), ("reference", "exact", "verlet"),
           ("lammps", "exact", "verlet"))
#: The integrator of the converged solution: the second-order mode at t_conv (its own error
#: there is ~1e-6 on the planes, Eq. 5's ~1e-3).
CONV_INTEGRATOR = "verlet"


def scene_at(name: str, t: float, quick: bool, integrator: str = "euler"):
    """The benchmark's scene ``name`` at time step t, run to its fixed physical time."""
    if name == "magpod-small":
        tp = 0.2 if quick else 3.0
        sc = scenes.build("magpod-small", phase_steps=int(round(tp / t)), dt=t, cycles=1)
    else:
        T = 3.0 if quick else 12.0
        kw = {"d": 10.0} if name == "plane-bound" else {}
        sc = scenes.build(name, dt=t, steps=int(round(T / t)), **kw)
    sc.integrator = integrator
    return sc


def run_engine(scene, engine: str, mode: str) -> dict:
    """Run; return the states at every phase end, wall time of the stepping, setup time."""
    ends = []
    t0 = time.perf_counter()
    if engine == "reference":
        ref = Reference(scene)
        setup = time.perf_counter() - t0
        t0 = time.perf_counter()
        drive(ref, on_phase_end=lambda rec: ends.append(rec.p))
        wall = time.perf_counter() - t0
    else:
        from rackstress.engines.lammps.deck import compile_deck
        from rackstress.engines.lammps.runner import LammpsRun

        runner = LammpsRun(compile_deck(scene, mode, measure_fast=True), None, log=False)
        setup = time.perf_counter() - t0
        try:
            t0 = time.perf_counter()
            drive(runner, on_phase_end=lambda rec: ends.append(rec.p))
            wall = time.perf_counter() - t0
        finally:
            runner.close()
    return {"ends": ends, "wall_s": wall, "setup_s": setup}


def walked(scene, p: np.ndarray) -> float:
    body = scene.slice("body")
    return float(p[body, 0].mean() - scene.original_positions()[body, 0].mean())


def errors(scene, ends: list, conv: list) -> dict:
    """The error measures of the module docstring, max over the compared phase ends."""
    e = {"pos_rms": 0.0, "pos_max": 0.0, "maxdef": 0.0, "stress_max": 0.0, "stress_rms": 0.0}
    if "body" in scene.groups:
        e["walk"] = 0.0
    for p, q in zip(ends, conv):
        d = np.linalg.norm(p - q, axis=1)
        e["pos_rms"] = max(e["pos_rms"], float(np.sqrt((d * d).mean())))
        e["pos_max"] = max(e["pos_max"], float(d.max()))
        sd = []
        for name, g in scene.groups.items():
            if g.kind in ("rack", "sediment"):
                continue   # racks are 6 points; the sediment has no rest shape (README)
            sl = scene.slice(name)
            a, b = rigid.deformation(g.o, p[sl]), rigid.deformation(g.o, q[sl])
            e["maxdef"] = max(e["maxdef"], abs(float(a.max()) - float(b.max())))
            sd.append(np.abs(a - b))
        sd = np.concatenate(sd)
        e["stress_max"] = max(e["stress_max"], float(sd.max()))
        e["stress_rms"] = max(e["stress_rms"], float(np.sqrt((sd * sd).mean())))
        if "walk" in e:
            e["walk"] = max(e["walk"], abs(walked(scene, p) - walked(scene, q)))
    return e


def bench_scene(name: str, quick: bool, echo=print) -> dict:
    t_conv = min(T_STEPS) / REFINE
    conv_scene = scene_at(name, t_conv, quick, CONV_INTEGRATOR)
    t0 = time.perf_counter()
    conv = run_engine(conv_scene, "reference", "exact")
    echo(f"  {name}: converged reference t = {t_conv:g}, {conv_scene.total_steps} steps, "
         f"{time.perf_counter() - t0:.1f} s")
    T = conv_scene.total_steps * t_conv
    rows = []
    for t in T_STEPS:
        ref_ends = {}
        for engine, mode, integ in ENGINES:
            sc = scene_at(name, t, quick, integ)
            pred = predict(sc)
            row = {"scene": name, "t": t, "engine": engine, "mode": mode, "integrator": integ,
                   "steps": sc.total_steps,
                   "T": sc.total_steps * t, "t_pred": pred["t_max"], "status": "ok"}
            if t > pred["t_max"]:
                row["status"] = "refused (t > predicted t_max)"
                rows.append(row)
                continue
            try:
                r = run_engine(sc, engine, mode)
            except DivergenceError as err:
                row["status"] = f"diverged at step {err.step}"
                rows.append(row)
                continue
            except RackstressError as err:
                row["status"] = f"failed: {err}"
                rows.append(row)
                continue
            row.update(wall_s=r["wall_s"], setup_s=r["setup_s"],
                       particle_steps_per_s=sc.n_particles * sc.total_steps / r["wall_s"],
                       **errors(sc, r["ends"], conv["ends"]))
            if engine == "reference":
                ref_ends[integ] = r["ends"]
            elif ref_ends.get(integ) is not None:
                row["vs_reference_same_t"] = max(float(np.abs(a - b).max())
                                                 for a, b in zip(r["ends"], ref_ends[integ]))
            rows.append(row)
            echo(f"    t={t:<7g} {engine:9s} {mode:5s} {integ:6s} pos_max {fmt(row['pos_max'])}  "
                 f"stress_max {fmt(row['stress_max'])}  wall {r['wall_s']:.2f} s")
    # observed order of the reference engine (position max error between successive t)
    def orders(integ):
        refs = [r for r in rows if r["engine"] == "reference" and "pos_max" in r
                and r["integrator"] == integ]
        out = []
        for a, b in zip(refs, refs[1:]):
            if a["pos_max"] > 0 and b["pos_max"] > 0:
                out.append(math.log(a["pos_max"] / b["pos_max"]) / math.log(a["t"] / b["t"]))
        return out

    return {"scene": name, "T": T, "t_conv": t_conv, "conv_steps": conv_scene.total_steps,
            "conv_integrator": CONV_INTEGRATOR,
            "conv_wall_s": conv["wall_s"], "n_particles": conv_scene.n_particles,
            "observed_order_reference": orders("euler"),
            "observed_order_verlet": orders("verlet"), "rows": rows,
            "fast_front": fast_front(rows), "verlet_front": verlet_front(rows),
            "error_constants": error_constants(rows, orders("verlet"))}


def verlet_front(rows: list) -> dict:
    """The second-order mode against Eq. 5 at equal wall time, per engine: for each verlet run,
    Eq. 5's error at the same wall time (log-log interpolation of the same engine's Eq. 5 runs,
    exact mode; extrapolated from the nearest two beyond their range) over the verlet error."""
    out = {}
    for engine in ("reference", "lammps"):
        eu = sorted(((r["wall_s"], r["pos_max"]) for r in rows if r["engine"] == engine
                     and r["mode"] == "exact" and r.get("integrator") == "euler"
                     and r.get("pos_max", 0) > 0))
        pts = []
        for r in rows:
            if r["engine"] != engine or r.get("integrator") != "verlet" or "pos_max" not in r:
                continue
            if len(eu) < 2 or r["pos_max"] <= 0:
                continue
            lw = np.log([w for w, _ in eu])
            le = np.log([e for _, e in eu])
            x = math.log(r["wall_s"])
            k = int(np.clip(np.searchsorted(lw, x) - 1, 0, len(lw) - 2))
            slope = (le[k + 1] - le[k]) / (lw[k + 1] - lw[k]) if lw[k + 1] != lw[k] else 0.0
            e_euler = math.exp(le[k] + slope * (x - lw[k]))
            pts.append({"t": r["t"], "wall_s": r["wall_s"], "pos_max": r["pos_max"],
                        "euler_pos_max_same_wall": e_euler, "ratio": e_euler / r["pos_max"]})
        out[engine] = {"points": pts,
                       "min_ratio": min((p["ratio"] for p in pts), default=None)}
    return out


def equal_t_ratios(rows: list) -> list:
    """Eq. 5's error over the verlet mode's at the same t (equal work: a verlet step costs an
    Eq. 5 step), per engine (exact mode) and t, in both norms: the worst particle (pos max) and
    the field as a whole (pos RMS). Free of timing noise, unlike :func:`verlet_front`."""
    out = []
    for engine in ("reference", "lammps"):
        for r in rows:
            if (r["engine"] != engine or r["mode"] != "exact" or r.get("integrator") != "verlet"
                    or not r.get("pos_max")):
                continue
            e = next((q for q in rows if q["engine"] == engine and q["mode"] == "exact"
                      and q.get("integrator") == "euler" and q["t"] == r["t"]
                      and q.get("pos_max")), None)
            if e is not None:
                out.append({"engine": engine, "t": r["t"], "max": e["pos_max"] / r["pos_max"],
                            "rms": e["pos_rms"] / r["pos_rms"]})
    return out


#: The target ratio of Eq. 5's error to the verlet mode's at equal work.
VERLET_GAIN = 10.0


def error_constants(rows: list, orders_verlet: list) -> dict:
    """Eq. 5's and the verlet mode's error constants, and where the verlet mode gains 10×.

    Eq. 5 is first order, its position error e₁ ≈ A·t; the verlet mode second order,
    e₂ ≈ B·t². A verlet step costs what an Eq. 5 step costs (the same force evaluations), so
    at equal work (equal t) the ratio is e₁/e₂ = A/(B·t): it falls as 1/t, and reaches
    ``VERLET_GAIN`` only for t ≤ t* = A/(10·B). At equal accuracy ε the verlet mode needs
    A/√(ε·B) times fewer steps. Per engine (exact mode): A = median of e₁/t, B = median of
    e₂/t² over the runs; None where the verlet mode's observed order is below 1.9 (contact
    switching: no B).
    """
    out = {}
    for engine in ("reference", "lammps"):
        eu = [r for r in rows if r["engine"] == engine and r["mode"] == "exact"
              and r.get("integrator") == "euler" and r.get("pos_max", 0) > 0]
        ve = [r for r in rows if r["engine"] == engine and r["mode"] == "exact"
              and r.get("integrator") == "verlet" and r.get("pos_max", 0) > 0]
        if not eu or not ve or not orders_verlet or min(orders_verlet) < 1.9:
            out[engine] = None
            continue
        A = float(np.median([r["pos_max"] / r["t"] for r in eu]))
        B = float(np.median([r["pos_max"] / r["t"] ** 2 for r in ve]))
        t_pred = min(r["t_pred"] for r in eu)
        out[engine] = {"A": A, "B": B, "t_star": A / (VERLET_GAIN * B),
                       "t_star_over_t_max": A / (VERLET_GAIN * B) / t_pred, "t_max": t_pred,
                       "steps_saved_at": {str(eps): A / math.sqrt(eps * B)
                                          for eps in (1e-2, 1e-3, 1e-4)}}
    return out


#: The gain sweep: plane-rack variants (scene overrides) whose error constants show what sets
#: the verlet mode's gain — damping (none, the default 1, 10) and binding stiffness.
GAIN_SWEEP = (("default (damping 1, plane_bind 100)", {}),
              ("no damping", {"damping": 0.0, "rack_damping": 0.0}),
              ("damping 10", {"damping": 10.0}),
              ("plane_bind 20", {"plane_bind": 20.0}),
              ("plane_bind 500", {"plane_bind": 500.0}))


def gain_sweep(echo=print, T: float = 3.0, ts=(0.01, 0.005)) -> list:
    """A and B (:func:`error_constants`) of plane-rack variants on the reference engine (T = 3,
    converged: the verlet mode at 0.0025/8): what makes t* = A/(10B) small or large."""
    out = []
    for label, kw in GAIN_SWEEP:
        def make(t, integ):
            sc = scenes.build("plane-rack", dt=t, steps=int(round(T / t)), **kw)
            sc.integrator = integ
            return sc
        conv = run_engine(make(min(T_STEPS) / REFINE, CONV_INTEGRATOR), "reference",
                          "exact")["ends"][-1]
        A, B = [], []
        for t in ts:
            for integ, store, power in (("euler", A, 1), ("verlet", B, 2)):
                p = run_engine(make(t, integ), "reference", "exact")["ends"][-1]
                store.append(float(np.linalg.norm(p - conv, axis=1).max()) / t ** power)
        a, b = float(np.median(A)), float(np.median(B))
        t_max = predict(make(ts[0], "euler"))["t_max"]
        out.append({"label": label, "overrides": kw, "A": A, "B": B, "t_star": a / (VERLET_GAIN * b),
                    "t_max": t_max, "t_star_over_t_max": a / (VERLET_GAIN * b) / t_max,
                    "t": list(ts)})
        echo(f"  gain sweep, plane-rack {label}: A {a:.3g} B {b:.3g} t* {a / (10 * b):.3g}")
    return out


def fast_front(rows: list) -> dict:
    """Is fast mode on the work-precision front? For each fast run: the speed-up over the
    cheapest exact run with a position error no larger (None: no exact run is that accurate,
    so the fast run is on the front by default)."""
    ok = [r for r in rows if "pos_max" in r and r["engine"] == "lammps"
          and r.get("integrator", "euler") == "euler"]
    exact = [r for r in ok if r["mode"] == "exact"]
    points = []
    for f in (r for r in ok if r["mode"] == "fast"):
        better = [e["wall_s"] for e in exact if e["pos_max"] <= f["pos_max"]]
        points.append({"t": f["t"], "pos_max": f["pos_max"],
                       "speedup": min(better) / f["wall_s"] if better else None})
    on = [p for p in points if p["speedup"] is None or p["speedup"] >= FRONT_MARGIN]
    best = max((p["speedup"] for p in points if p["speedup"] is not None), default=None)
    return {"points": points, "on_front": bool(on), "best_speedup": best,
            "margin": FRONT_MARGIN}


def run_bench(out: Path | None = None, quick: bool = False, scenes_=None, echo=print) -> dict:
    out = out_dir(out)
    t0 = time.perf_counter()
    names = scenes_ or ("plane-bound", "plane-rack", "magpod-small")
    results = [bench_scene(n, quick, echo) for n in names]
    sweep = gain_sweep(echo) if scenes_ is None else []
    data = {"benchmark": "accuracy", "quick": quick, "machine": machine(),
            "converged_reference": f"reference engine, {CONV_INTEGRATOR} mode, at t = "
                                   f"{min(T_STEPS)}/{REFINE}",
            "t_values": list(T_STEPS), "scenes": results, "gain_sweep": sweep,
            "wall_s": time.perf_counter() - t0}
    write_json(out / "accuracy.json", data)
    (out / "accuracy.md").write_text(markdown(data))
    plot(data, out / "accuracy.png")
    data["files"] = [str(out / f) for f in ("accuracy.json", "accuracy.md", "accuracy.png")]
    return data


HEADER = ["scene", "t", "engine", "integrator", "steps", "status", "pos RMS", "pos max", "max_deformation",
          "stress field max", "walk", "vs reference (same t)", "wall s", "particle-steps/s"]


def table_rows(data: dict) -> list:
    out = []
    for s in data["scenes"]:
        for r in s["rows"]:
            eng = r["engine"] if r["engine"] == "reference" else f"lammps {r['mode']}"
            out.append([s["scene"], f"{r['t']:g}", eng, r.get("integrator", "euler"), r["steps"],
                        r["status"],
                        fmt(r.get("pos_rms")), fmt(r.get("pos_max")), fmt(r.get("maxdef")),
                        fmt(r.get("stress_max")), fmt(r.get("walk")) if "walk" in r else "",
                        fmt(r.get("vs_reference_same_t")) if r["engine"] != "reference" else "",
                        fmt(r.get("wall_s")), fmt(r.get("particle_steps_per_s"))])
    return out


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# Work-precision: error against a converged reference vs wall time", "",
             f"Regenerate: `rackstress bench accuracy{' --quick' if data['quick'] else ''}`. "
             f"Machine: {m['cores']} cores ({m['cpu']}), shared with other work: wall times "
             "are comparable within this table, as ratios.", "",
             f"Converged solution: the {data['converged_reference']}, compared at the same "
             "physical time (end of the run; for MagPod every phase end, the largest error "
             "taken). Errors in length units; 'stress field' is the largest per-particle "
             "difference of the paper's measure (distance from the desired position); "
             "'walk' is MagPod's body centre-of-mass advance; 'vs reference' is LAMMPS against "
             "the reference engine at the same t (exact mode: round-off).", ""]
    for s in data["scenes"]:
        lines.append(f"- {s['scene']}: {s['n_particles']} particles, T = {s['T']:g}, converged "
                     f"run {s['conv_steps']} steps ({s['conv_wall_s']:.1f} s); observed order "
                     "of the reference engine (pos max), Eq. 5: "
                     + ", ".join(f"{o:.2f}" for o in s["observed_order_reference"])
                     + "; verlet mode: "
                     + ", ".join(f"{o:.2f}" for o in s.get("observed_order_verlet", [])))
    lines += ["", md_table(HEADER, table_rows(data)), "",
              "Fast mode against the work-precision front (speed-up over the cheapest exact run "
              f"at least as accurate; on the front from {FRONT_MARGIN:g}×, the noise margin "
              "here):", ""]
    for s in data["scenes"]:
        ff = s.get("fast_front") or {}
        if not ff.get("points"):
            continue
        pts = ", ".join(f"t={p['t']:g}: {fmt(p['speedup'], 3) if p['speedup'] else 'none as accurate'}"
                        for p in ff["points"])
        lines.append(f"- {s['scene']}: **{'on' if ff['on_front'] else 'off'} the front** "
                     f"({pts})")
    lines += ["", "The second-order (verlet) mode against Eq. 5 at equal wall time (Eq. 5's error "
              "interpolated at the verlet run's wall time, same engine, over the verlet error):",
              ""]
    for s in data["scenes"]:
        vf = s.get("verlet_front") or {}
        for engine, v in vf.items():
            if not v["points"]:
                continue
            pts = ", ".join(f"t={p['t']:g}: {p['ratio']:.3g}×" for p in v["points"])
            lines.append(f"- {s['scene']}, {engine}: smallest ratio "
                         f"{fmt(v['min_ratio'], 3)}× ({pts})")
    lines += ["", "The same at equal t (equal work), by the two norms: Eq. 5's error over the "
              "verlet mode's for the worst particle (pos max) / for the field as a whole "
              "(pos RMS):", ""]
    for s in data["scenes"]:
        for engine in ("reference", "lammps"):
            pts = [p for p in equal_t_ratios(s["rows"]) if p["engine"] == engine]
            if pts:
                lines.append(f"- {s['scene']}, {engine}: " + ", ".join(
                    f"t={p['t']:g}: {p['max']:.3g}× / {p['rms']:.3g}×" for p in pts))
    lines += ["", "Where the verlet mode's error is 10× smaller than Eq. 5's at equal work "
              "(`error_constants`: e₁ ≈ A·t, e₂ ≈ B·t², so the ratio at equal t is A/(B·t) and "
              "reaches 10 for t ≤ t* = A/(10·B); at equal accuracy ε the verlet mode takes "
              "A/√(ε·B) times fewer steps):", ""]
    for s in data["scenes"]:
        for engine, c in (s.get("error_constants") or {}).items():
            if c is None:
                lines.append(f"- {s['scene']}, {engine}: no second-order constant (observed "
                             "verlet order below 1.9)")
                continue
            sv = ", ".join(f"ε = {float(e):g}: {v:.3g}×" for e, v in c["steps_saved_at"].items())
            lines.append(f"- {s['scene']}, {engine}: A = {c['A']:.3g}, B = {c['B']:.3g}; "
                         f"t* = {c['t_star']:.2g} ({c['t_star_over_t_max']:.2f} of Eq. 5's "
                         f"predicted limit {c['t_max']:.3g}); fewer steps at equal accuracy: "
                         f"{sv}")
    if data.get("gain_sweep"):
        lines += ["", "What sets the gain (plane-rack variants, reference engine, T = 3; A and "
                  "B at t = 0.01 and 0.005; t* = A/(10·B)):", "",
                  md_table(["plane-rack", "A (Eq. 5: e₁/t)", "B (verlet: e₂/t²)", "t*",
                            "Eq. 5's predicted limit", "t* / limit"],
                           [[g["label"], ", ".join(f"{x:.3g}" for x in g["A"]),
                             ", ".join(f"{x:.3g}" for x in g["B"]), f"{g['t_star']:.2g}",
                             f"{g['t_max']:.3g}", f"{g['t_star_over_t_max']:.2g}"]
                            for g in data["gain_sweep"]])]
    return "\n".join(lines) + "\n"


def plot(data: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(data["scenes"])
    fig, axes = plt.subplots(1, n, figsize=(5 * n, 4.5), squeeze=False)
    styles = {("reference", "exact", "euler"): ("k", "o", "reference"),
              ("lammps", "exact", "euler"): ("tab:blue", "s", "LAMMPS exact"),
              ("lammps", "fast", "euler"): ("tab:red", "^", "LAMMPS fast"),
              ("reference", "exact", "verlet"): ("tab:green", "D", "reference verlet"),
              ("lammps", "exact", "verlet"): ("tab:olive", "v", "LAMMPS verlet")}
    for ax, s in zip(axes[0], data["scenes"]):
        for key, (col, mk, lab) in styles.items():
            rs = [r for r in s["rows"] if (r["engine"], r["mode"], r.get("integrator", "euler"))
                  == key and "pos_max" in r]
            if not rs:
                continue
            x = [r["wall_s"] for r in rs]
            y = [max(r["pos_max"], 1e-16) for r in rs]
            ax.plot(x, y, marker=mk, color=col, label=lab,
                    ls="--" if key[0] == "lammps" and key[1] == "exact" else "-")
            for r, xi, yi in zip(rs, x, y):
                ax.annotate(f"{r['t']:g}", (xi, yi), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time of the run (s)")
        ax.set_ylabel("max position error at T (vs converged)")
        ax.set_title(f"{s['scene']} (T = {s['T']:g})")
        ax.legend(fontsize=8)
    fig.suptitle("Work-precision (labels: time step t)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
