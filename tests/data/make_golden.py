"""Write ``golden_accel.json``: per-operator accelerations of small hand-made configurations.

This script is the derivation of the golden file and is deliberately independent of rackstress:
plain Python, the ``math`` module, and the paper's equations written out once more, directly
from the text (every particle has unit mass, every operator adds an acceleration):

* force  (Eq. 8):  â on the selected particles; Eq. 15's selection is ‖o‖² < 10.
* dampen (Eq. 9):  −c·v; Eq. 28's conditional damping adds ``extra`` while its condition holds.
* col    (Eq. 10): Σ_u c·(u−p)·min(0, 1 − (r_p + r_u)²/‖u−p‖²). The printed equation squares the
  sum of two *x coordinates*; the prose ("their distance is greater than the sum of their
  radii") fixes it: R = r_p + r_u.
* bin    (Eq. 12): Σ_u c·(u−p)·(1 − ‖u_o − p_o‖²/‖u−p‖²), the original length per pair.
* attract (Eq. 14): Σ_u c·(u−p)/‖u−p‖, constant magnitude c per pair.
* within(d) (Eq. 16): c for pairs whose original distance is below d, never a particle with
  itself; index-matched regions (Eqs. 27–28): c when the two particles' region indices are equal
  and non-zero.

Coefficients are directed: the operator on p's group from u's group carries its own c. Every
configuration lists its groups (original positions o, radius r, region indices), the current
positions p and velocities v, the operators on each group, the phase, and the accelerations
``accel`` those imply. For bind, ``harmonic_bound`` is Σ c·(d − L0)²/d per particle: a harmonic
bond of stiffness K = c (LAMMPS E = K(d − L0)², force 2K(d − L0)) differs from Eq. 12's
c·(d² − L0²)/d by exactly c·(d − L0)²/d per pair, so a fast-mode deck must lie within it.

Run ``python tests/data/make_golden.py`` to rewrite the file (the test reads only the JSON).
"""
from __future__ import annotations

import json
import math
from pathlib import Path


def sub(a, b):
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def scaled(s, a):
    return [s * a[0], s * a[1], s * a[2]]


def add_to(acc, a):
    for k in range(3):
        acc[k] += a[k]


def plus(base, delta):
    return [[x + dx for x, dx in zip(row, drow)] for row, drow in zip(base, delta)]


# ----------------------------------------------------------------------- the equations, again
def col(p, u, r_p, r_u, c):
    """Eq. 10 (radii erratum) for one pair: acceleration on p from u."""
    diff = sub(u, p)
    d2 = dot(diff, diff)
    return scaled(c * min(0.0, 1.0 - (r_p + r_u) ** 2 / d2), diff)


def bin_(p, u, p_o, u_o, c):
    """Eq. 12 for one pair: acceleration on p from u."""
    diff = sub(u, p)
    L0 = sub(u_o, p_o)
    return scaled(c * (1.0 - dot(L0, L0) / dot(diff, diff)), diff)


def attraction(p, u, c):
    """Eq. 14 for one pair: acceleration on p from u."""
    diff = sub(u, p)
    return scaled(c / math.sqrt(dot(diff, diff)), diff)


# ----------------------------------------------------------------------- evaluation
def holds(when, case, target):
    """⟨P⟩ (Eq. 4): a phase condition on the case's phase, or a contact of target with a group."""
    for cond in when:
        if "phase" in cond:
            var, values = cond["phase"]
            if case["phase"][var] not in values:
                return False
        else:
            other = cond["contact"]
            g_t, g_s = case["groups"][target], case["groups"][other]
            touching = any(
                dot(sub(q, pp), sub(q, pp)) < (g_t["r"] + g_s["r"]) ** 2
                for a, pp in enumerate(case["p"][target]) for b, q in enumerate(case["p"][other])
                if not (other == target and a == b))
            if not touching:
                return False
    return True


def coefficient(spec, case, target, source, i, j):
    """ĉ_ij of a pair operator (0 when the pair is not in the matrix)."""
    if target == source and i == j:
        return 0.0
    if "const" in spec:
        return spec["const"]
    if "within" in spec:
        d, c = spec["within"]
        o_t, o_s = case["groups"][target]["o"], case["groups"][source]["o"]
        L = sub(o_s[j], o_t[i])
        return c if math.sqrt(dot(L, L)) < d else 0.0
    t_name, s_name, c = spec["matched"]
    t_idx = case["groups"][target]["regions"][t_name.format(**case["phase"])]
    s_idx = case["groups"][source]["regions"][s_name.format(**case["phase"])]
    return c if (t_idx[i] == s_idx[j] and t_idx[i] != 0) else 0.0


def evaluate(case):
    accel, bound = {}, {}
    for target, g in case["groups"].items():
        n = len(g["o"])
        acc = [[0.0, 0.0, 0.0] for _ in range(n)]
        hb = [0.0] * n
        for op in case["operators"].get(target, []):
            when = op.get("when", [])
            kind = op["op"]
            if kind == "dampen":
                c = op["c"] + (op.get("extra", 0.0) if holds(when, case, target) else 0.0)
                for i in range(n):
                    add_to(acc[i], scaled(-c, case["v"][target][i]))
                continue
            if not holds(when, case, target):
                continue
            if kind == "force":
                for i in range(n):
                    o = g["o"][i]
                    if "norm2_lt" not in op or dot(o, o) < op["norm2_lt"]:
                        add_to(acc[i], op["accel"])
                continue
            source = op["source"]
            g_s = case["groups"][source]
            for i in range(n):
                p = case["p"][target][i]
                for j in range(len(g_s["o"])):
                    c = coefficient(op["coeff"], case, target, source, i, j)
                    if c == 0.0:
                        continue
                    u = case["p"][source][j]
                    if kind == "collide":
                        add_to(acc[i], col(p, u, g["r"], g_s["r"], c))
                    elif kind == "bind":
                        add_to(acc[i], bin_(p, u, g["o"][i], g_s["o"][j], c))
                        diff, L = sub(u, p), sub(g_s["o"][j], g["o"][i])
                        d, L0 = math.sqrt(dot(diff, diff)), math.sqrt(dot(L, L))
                        hb[i] += c * (d - L0) ** 2 / d
                    else:
                        add_to(acc[i], attraction(p, u, c))
        accel[target] = acc
        if any(op["op"] == "bind" for op in case["operators"].get(target, [])):
            bound[target] = hb
    return accel, bound


# ----------------------------------------------------------------------- the configurations
def cases():
    out = []
    # force (Eqs. 8, 15): ‖o‖² = 0, 9, 9.61, 100 -> the pull selects the first three
    g = {"o": [[0, 0, 0], [3, 0, 0], [0, 0, 3.1], [10, 0, 0]], "r": 0.5}
    out.append({"name": "force", "groups": {"g": g}, "phase": {"r": 2},
                "p": {"g": g["o"]}, "v": {"g": [[0, 0, 0]] * 4},
                "operators": {"g": [
                    {"op": "force", "accel": [0.0, 100.0, 0.0], "norm2_lt": 10.0},
                    {"op": "force", "accel": [1.0, -2.0, 0.5]},
                    {"op": "force", "accel": [0.0, 0.0, 3.0], "when": [{"phase": ["r", [2]]}]},
                    {"op": "force", "accel": [9.0, 9.0, 9.0], "when": [{"phase": ["r", [1]]}]}]}})
    # dampen (Eqs. 9, 28): plain, phase-conditioned extra, contact-conditioned extra; a force
    # conditioned on the same contact. h (r 1) overlaps k (r 1) at distance 1.5 < 2.
    out.append({"name": "dampen", "phase": {"r": 1},
                "groups": {"g": {"o": [[0, 0, 0], [4, 0, 0], [0, 4, 0]], "r": 0.5},
                           "h": {"o": [[10, 0, 0]], "r": 1.0},
                           "k": {"o": [[10, -1.5, 0]], "r": 1.0}},
                "p": {"g": [[0, 0, 0], [4, 0, 0], [0, 4, 0]], "h": [[10, 0, 0]],
                      "k": [[10, -1.5, 0]]},
                "v": {"g": [[1.0, -2.0, 0.5], [0.0, 3.0, -4.0], [-0.25, 0.5, 2.0]],
                      "h": [[0.5, -2.0, 1.0]], "k": [[0.0, 0.0, 0.0]]},
                "operators": {
                    "g": [{"op": "dampen", "c": 2.0},
                          {"op": "dampen", "c": 0.5, "extra": 3.0, "when": [{"phase": ["r", [1]]}]},
                          {"op": "dampen", "c": 0.25, "extra": 7.0, "when": [{"phase": ["r", [2]]}]}],
                    "h": [{"op": "dampen", "c": 1.0, "extra": 4.0, "when": [{"contact": "k"}]},
                          {"op": "force", "accel": [0.0, 5.0, 0.0], "when": [{"contact": "k"}]}],
                    "k": [{"op": "dampen", "c": 1.0}]}})
    # collide (Eq. 10): A <- B 30 and B <- A 10 (reciprocal, directed), C <- B 4 (one-way, other
    # radii), D with itself 7. Overlaps: A1-B0 (0.735 < 1.2), A0-B1 (0.911), C-B0 (0.831 < 1.4),
    # all three D pairs (0.8, 0.7, 0.806 < 1.0); A0-B0 (1.22) and A1-B1 (1.73) do not.
    p = {"A": [[0, 0, 0], [1.0, 0.1, 0]], "B": [[0.9, 0.8, 0.2], [-0.5, -0.7, 0.3]],
         "C": [[1.3, 1.5, 0.4]], "D": [[5, 5, 5], [5.8, 5, 5], [5.3, 5.6, 5.2]]}
    out.append({"name": "collide", "phase": {},
                "groups": {"A": {"o": p["A"], "r": 0.6}, "B": {"o": p["B"], "r": 0.6},
                           "C": {"o": p["C"], "r": 0.8}, "D": {"o": p["D"], "r": 0.5}},
                "p": p, "v": {k: [[0, 0, 0]] * len(x) for k, x in p.items()},
                "operators": {"A": [{"op": "collide", "source": "B", "coeff": {"const": 30.0}}],
                              "B": [{"op": "collide", "source": "A", "coeff": {"const": 10.0}}],
                              "C": [{"op": "collide", "source": "B", "coeff": {"const": 4.0}}],
                              "D": [{"op": "collide", "source": "D", "coeff": {"const": 7.0}}]}})
    # bind (Eqs. 12, 16, 23): a host H bound to its "rack" K with 100, K bound back with 0.5
    # (directed), and P bound to itself within(1.5) with 20 (the 2x2 square's sides and
    # diagonals, and P4 to P1 at 1.2; P4-P3 at 1.56 is outside). Strains of a few per cent.
    o = {"H": [[0, 0, 0], [1, 0, 0], [0.5, 0.8, 0]], "K": [[-3, 0.4, 0], [3.5, 0.4, 0.2]],
         "P": [[0, 0, 20], [1, 0, 20], [0, 1, 20], [1, 1, 20], [2.2, 0, 20]]}
    dp = {"H": [[0.03, -0.02, 0.01], [-0.01, 0.04, 0.0], [0.0, 0.02, -0.03]],
          "K": [[0.05, 0.0, -0.02], [-0.04, 0.03, 0.01]],
          "P": [[0.02, 0.01, -0.01], [-0.03, 0.0, 0.02], [0.0, -0.02, 0.01], [0.01, 0.03, 0.0],
                [0.04, -0.01, 0.02]]}
    out.append({"name": "bind", "phase": {},
                "groups": {"H": {"o": o["H"], "r": 0.5}, "K": {"o": o["K"], "r": 1.0},
                           "P": {"o": o["P"], "r": 0.5}},
                "p": {k: plus(o[k], dp[k]) for k in o}, "v": {k: [[0, 0, 0]] * len(x) for k, x in o.items()},
                "operators": {"H": [{"op": "bind", "source": "K", "coeff": {"const": 100.0}}],
                              "K": [{"op": "bind", "source": "H", "coeff": {"const": 0.5}}],
                              "P": [{"op": "bind", "source": "P", "coeff": {"within": [1.5, 20.0]}}]}})
    # attract (Eq. 14, index-matched regions of Eqs. 27-28 with a phase-filled name), one-way
    # in each direction with its own coefficient: A <- C 7<ra{r} = rc != 0> while r in {1, 2},
    # C <- A 2 for every pair. r = 1: A0<->C1 (index 1), A1<->C0 (index 2); r = 2: A2<->C1.
    for r in (1, 2):
        p = {"A": [[0, 0, 0], [1, 0.2, 0], [0.4, 1.1, -0.3]], "C": [[2.5, 3.0, 1.0], [-1.5, 2.0, 0.5]]}
        out.append({"name": f"attract-r{r}", "phase": {"r": r},
                    "groups": {"A": {"o": p["A"], "r": 0.5,
                                     "regions": {"ra1": [1, 2, 0], "ra2": [0, 0, 1]}},
                               "C": {"o": p["C"], "r": 0.5, "regions": {"rc": [2, 1]}}},
                    "p": p, "v": {k: [[0, 0, 0]] * len(x) for k, x in p.items()},
                    "operators": {
                        "A": [{"op": "attract", "source": "C",
                               "coeff": {"matched": ["ra{r}", "rc", 7.0]},
                               "when": [{"phase": ["r", [1, 2]]}]}],
                        "C": [{"op": "attract", "source": "A", "coeff": {"const": 2.0}}]}})
    return out


def main():
    data = []
    for case in cases():
        accel, bound = evaluate(case)
        case["accel"] = accel
        if bound:
            case["harmonic_bound"] = bound
        data.append(case)
    path = Path(__file__).with_name("golden_accel.json")
    path.write_text(json.dumps({"cases": data}, indent=1) + "\n")
    print(f"wrote {path} ({len(data)} configurations)")


if __name__ == "__main__":
    main()
