#!/usr/bin/env python
"""Phase error per unit cost of one-step schemes on an undamped mode x'' = −ω²x.

    python scripts/phase_error.py [--out docs/benchmarks/phase-error.md]   # and phase-error.json

Why the verlet mode's gain over Eq. 5 is capped on lightly damped stiff scenes (README, "What
the picture means"): Eq. 5 and the verlet mode carry such a mode at the same modified frequency
arccos(1 − ω²t²/2)/t (``rackstress.model.verlet.modified_frequency``; a test measures it on both),
so their errors share a term B·t² that grows with the run's length, and Eq. 5's error over the
verlet mode's is at most about 1 + A/(B·t). A scheme with a smaller phase error at the *same
cost* (force evaluations per unit time, h = time per evaluation) would lower B. This script
scans the candidates exactly (2×2 one-step matrices, no simulation):

* Störmer–Verlet = Eq. 5 = the verlet mode: one evaluation a step, step h;
* every symmetric two-stage splitting e^{λHB} e^{HA/2} e^{(1−2λ)HB} e^{HA/2} e^{λHB}, 0 < λ ≤ ¼
  (λ ≈ 0.1932 is the "minimum error" scheme of Omelyan et al. 2002; λ = ¼ is two Verlet steps),
  two evaluations a step, step H = 2h;
* Yoshida's fourth-order triple jump of Verlet, three evaluations a step, step H = 3h;
* Chin's fourth-order force-gradient scheme 4A, e^{H/6 V} e^{H/2 T} e^{2H/3 Ṽ} e^{H/2 T}
  e^{H/6 V} with the middle kick's force F̃ = F + (H²/48)·∇|F|² (unit mass; here
  −ω²x·(1 − ω²H²/24)): two force evaluations a step (the outer kicks of two steps merge) and
  the gradient term ∇|F|² = 2·(∂F/∂x)·F, a Hessian-vector product. Counted free (step H = 2h: a
  bound no implementation reaches) and as one more evaluation (step H = 3h: what a finite
  difference (F(x + δF) − F(x))/δ, or a second pass over the pairs, costs).

For a scene whose modes reach ω_max, the worst relative frequency error |ω̃/ω − 1| over its
modes 0 < ω ≤ ω_max, for each ω_max·h, and whether every mode is stable.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

#: ω_max·h up to 1.4: beyond it a two-stage step (2h) turns a mode by more than π, and the
#: angle read from its matrix aliases.
OMEGA_H = (0.05, 0.1, 0.25, 0.5, 0.84, 1.0, 1.4)


def kick(h, w):
    return np.array([[1.0, 0.0], [-w * w * h, 1.0]])


def drift(h):
    return np.array([[1.0, h], [0.0, 1.0]])


def verlet(H, w):
    return kick(H / 2, w) @ drift(H) @ kick(H / 2, w)


def two_stage(H, w, lam):
    return (kick(lam * H, w) @ drift(H / 2) @ kick((1 - 2 * lam) * H, w) @ drift(H / 2)
            @ kick(lam * H, w))


def yoshida(H, w):
    a = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
    b = 1.0 - 2.0 * a
    return verlet(a * H, w) @ verlet(b * H, w) @ verlet(a * H, w)


def force_gradient(H, w):
    """Chin's scheme 4A on x'' = −ω²x: its middle kick (2H/3) with F̃ = F + (H²/48)∇|F|²."""
    mid = np.array([[1.0, 0.0], [-(2 * H / 3) * (w * w - H * H * w ** 4 / 24.0), 1.0]])
    return kick(H / 6, w) @ drift(H / 2) @ mid @ drift(H / 2) @ kick(H / 6, w)


def rel_error(M, H, w=1.0):
    """|ω̃/ω − 1| of a one-step matrix of step H (NaN when it is unstable: |trace| ≥ 2)."""
    c = np.trace(M) / 2.0
    if not -1.0 < c < 1.0:
        return math.nan
    return abs(math.acos(c) / H / w - 1.0)


def band_error(scheme, wh_max, n=200):
    """Largest |ω̃/ω − 1| over the modes 0 < ω·h ≤ wh_max (a scene has a spectrum up to its
    stiffest mode); NaN if any of them is unstable."""
    worst = 0.0
    for wh in np.linspace(wh_max / n, wh_max, n):
        e = scheme(wh)
        if math.isnan(e):
            return math.nan
        worst = max(worst, e)
    return worst


def table():
    lams = np.linspace(0.01, 0.25, 97)
    rows = []
    for wh in OMEGA_H:
        ev = band_error(lambda x: rel_error(verlet(x, 1.0), x), wh)
        ok = []
        for lam in lams:
            e = band_error(lambda x: rel_error(two_stage(2 * x, 1.0, lam), 2 * x), wh)
            if not math.isnan(e):
                ok.append((e, lam))
        best = min(ok) if ok else (math.nan, math.nan)
        om = band_error(lambda x: rel_error(two_stage(2 * x, 1.0, 0.1931833275037836), 2 * x),
                        wh)
        y4 = band_error(lambda x: rel_error(yoshida(3 * x, 1.0), 3 * x), wh)
        fg2 = band_error(lambda x: rel_error(force_gradient(2 * x, 1.0), 2 * x), wh)
        fg3 = band_error(lambda x: rel_error(force_gradient(3 * x, 1.0), 3 * x), wh)
        rows.append((wh, ev, best[0], best[1], om, y4, fg2, fg3))
    return rows


def stability_limit(one_step, hi=4.0, n=4000):
    """The first ω·H at which a scheme's one-step matrix (step H, ω = 1) turns unstable
    (|trace| ≥ 2), scanned on a grid up to ``hi`` and refined by bisection; None if none."""
    def stable(x):
        return abs(np.trace(one_step(x))) < 2.0
    grid = np.linspace(hi / n, hi, n)
    for a, b in zip(grid[:-1], grid[1:]):
        if stable(a) and not stable(b):
            for _ in range(60):
                m = 0.5 * (a + b)
                a, b = (m, b) if stable(m) else (a, m)
            return float(0.5 * (a + b))
    return None


#: the plane-bound figures the reading quotes, from ``rackstress bench accuracy``'s JSON
ACCURACY = Path(__file__).resolve().parents[1] / "docs/benchmarks/accuracy.json"


def plane_bound(path: Path = ACCURACY) -> dict | None:
    """plane-bound's error constants (Eq. 5's error ≈ A·t, the verlet mode's ≈ B·t²) and Eq. 5's
    predicted stability limit, as ``rackstress bench accuracy`` measured them."""
    import json

    try:
        data = json.loads(path.read_text())
        ec = next(s for s in data["scenes"] if s["scene"] == "plane-bound")["error_constants"]
    except (OSError, ValueError, KeyError, StopIteration):
        return None
    ref = ec["reference"]
    return {"source": "docs/benchmarks/accuracy.json, plane-bound, error_constants.reference",
            "A": ref["A"], "B": ref["B"], "t_max": ref["t_max"]}


def measure() -> dict:
    """Everything the page prints: the table, the orders, the reading's figures."""
    rows = [{"omega_h": wh, "verlet": _nan(ev), "best_two_stage": _nan(best),
             "best_lambda": _nan(lam), "omelyan": _nan(om), "yoshida": _nan(y4),
             "force_gradient_free": _nan(fg2), "force_gradient_one_evaluation": _nan(fg3)}
            for wh, ev, best, lam, om, y4, fg2, fg3 in table()]
    orders = {name: math.log2(rel_error(f(0.1, 1.0), 0.1) / rel_error(f(0.05, 1.0), 0.05))
              for name, f in (("Störmer–Verlet", verlet), ("Yoshida", yoshida),
                              ("force-gradient 4A", force_gradient))}
    at = next(r for r in rows if r["omega_h"] == 0.84)
    return {"omega_h": list(OMEGA_H), "rows": rows, "orders": orders,
            "yoshida_limit_omega_H": stability_limit(lambda x: yoshida(x, 1.0)),
            "verlet_error_at_1_5": rel_error(verlet(1.5, 1.0), 1.5),
            "force_gradient_limit_omega_h": 2.0 * math.sqrt(3.0) / 3.0,
            "at_0_84": {"free": at["verlet"] / at["force_gradient_free"],
                        "one_evaluation": at["verlet"] / at["force_gradient_one_evaluation"]},
            "plane_bound": plane_bound()}


def _nan(x):
    return None if x is None or math.isnan(x) else float(x)


def fmt(x):
    return "unstable" if x is None else f"{x:.3g}"


def markdown(data) -> str:
    """The page, from :func:`measure`'s data (as written to phase-error.json)."""
    out = ["# Phase error per unit cost on an undamped mode", "",
           "Regenerate: `python scripts/phase_error.py` (exact 2×2 one-step matrices of "
           "x'' = −ω²x; h = time per force evaluation, so every column costs the same per unit "
           "time; the figures are in `phase-error.json`). Entries: the worst relative "
           "frequency error |ω̃/ω − 1| over all modes "
           "0 < ω ≤ ω_max (a scene's spectrum up to its stiffest mode); 'unstable' where one of "
           "them diverges.", "",
           "| ω_max·h | Störmer–Verlet = Eq. 5 = verlet mode (step h) | best two-stage splitting "
           "(step 2h) | its λ | Omelyan λ = 0.1932 (step 2h) | Yoshida 4th order (step 3h) "
           "| force-gradient 4A, gradient free (step 2h) | force-gradient 4A, gradient = one "
           "evaluation (step 3h) |",
           "|---|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        lam = "—" if r["best_lambda"] is None else f"{r['best_lambda']:.3f}"
        out.append(f"| {r['omega_h']:g} | {fmt(r['verlet'])} | {fmt(r['best_two_stage'])} "
                   f"| {lam} | {fmt(r['omelyan'])} | {fmt(r['yoshida'])} "
                   f"| {fmt(r['force_gradient_free'])} "
                   f"| {fmt(r['force_gradient_one_evaluation'])} |")
    ylim = data["yoshida_limit_omega_H"]
    free, one = data["at_0_84"]["free"], data["at_0_84"]["one_evaluation"]
    out += ["", "Check of the formulas: observed order of the frequency error on one mode "
            "(ω·H = 0.1 → 0.05): " + ", ".join(f"{k} {v:.2f}" for k, v in data["orders"].items())
            + " (the relative frequency error is of order p for a scheme of order p).", ""]
    reading = ("Reading: no two-stage splitting beats Störmer–Verlet at equal cost (the best "
               "λ is ¼: two Verlet half-size steps, the same scheme); Yoshida's fourth order "
               f"wins only for small ω·h and is unstable from ω·h ≈ {ylim / 3:.2f} (its step 3h "
               f"reaches its limit ≈ {ylim:.2f}). ")
    pb = data.get("plane_bound")
    if pb:
        w = 2.0 / pb["t_max"]
        reading += (f"On plane-bound (d = 10) the stiffest mode has ω ≈ {w:.0f} (Eq. 5's "
                    f"predicted limit {pb['t_max']:.3g} ≈ 2/ω, `accuracy.json`), so "
                    f"ω·t = {w * 0.01:.2f} at the default t = 0.01 and {w * 0.02:.2f} "
                    "at t = 0.02 (beyond this table, where Verlet's error is already "
                    f"{100 * data['verlet_error_at_1_5']:.0f} % at ω·h = 1.5). ")
    reading += ("The force-gradient scheme is the one candidate that beats Störmer–Verlet there: "
                f"at ω_max·h = 0.84 by {free:.0f}× if its gradient term cost nothing, but by "
                f"{one:.1f}× once the "
                "gradient costs one evaluation, as a Hessian-vector product does (a finite "
                "difference of two forces, or a second pass over the pairs), and it is unstable "
                f"from ω_max·h = 2√3/3 ≈ {data['force_gradient_limit_omega_h']:.2f} then (its "
                "trace/2 = 1 − x/2 + x²/24 − x³/864, "
                "x = ω²H², reaches −1 at (x − 12)³ = 0). Eq. 5's error is about A·t + B·t² "
                "against the verlet mode's B·t²")
    if pb:
        now = pb["A"] / (pb["B"] * 0.01)
        best = now * one
        reading += (f" (plane-bound: A = {pb['A']:.2g}, B = {pb['B']:.0f}, `accuracy.json`); "
                    f"replacing B·t² by a {one:.1f}× smaller phase error lifts the ratio A/(B·t) "
                    f"at plane-bound's t = 0.01 from ~{now:.0f} to ~{best:.0f} in the best case, "
                    + ("still short of 10" if best < 10 else "past 10")
                    + ", for a fourth-order scheme whose damping terms (velocity-dependent, not "
                    "a splitting of T and V) would need their own treatment.")
    else:
        reading += "."
    out += [reading, ""]
    return "\n".join(out)


def main():
    import json

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path,
                    default=Path(__file__).resolve().parents[1] / "docs/benchmarks/phase-error.md",
                    help="the page; its figures go to the .json beside it")
    args = ap.parse_args()
    data = measure()
    args.out.with_suffix(".json").write_text(json.dumps(data, indent=1, ensure_ascii=False)
                                             + "\n")
    text = markdown(data)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
