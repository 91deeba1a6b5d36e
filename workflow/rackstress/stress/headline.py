"""What a static run leads with: settled or not, and its headline stress.

``summary.json`` says whether the equilibrium was found (``settled``) and holds the stress
post-processing found: ``stress.governing`` (the stress away from singular points, with its
rule) when it was computed, else ``stress.peak``. The printed end-of-run lines, the pictures
and ``report.html`` all take their headline from :func:`headline`, so they name the same
number, particle and place (undeformed, in the part's own coordinates), and beside it the
factor of safety of the same rule (yield / that stress).
"""
from __future__ import annotations

import json
from pathlib import Path


def is_static(rundir) -> bool:
    """Whether the run in ``rundir`` is a static analysis (``summary.json`` or ``scene.json``)."""
    for name in ("summary.json", "scene.json"):
        try:
            if json.loads((Path(rundir) / name).read_text()).get("analysis") == "static":
                return True
        except (OSError, ValueError, AttributeError):
            continue
    return False


def headline(summary: dict, scene: dict | None = None, rundir=None) -> dict | None:
    """The number a static report leads with: ``stress.governing`` when post-processing found
    it (the stress away from singular points), else the overall peak; with the smallest factor
    of safety of the same rule (yield / that stress, the same particle), the position in the
    part's own undeformed coordinates and the named feature near it (when known).

    Returns ``{"kind" ("governing" | "peak"), "value", "units", "group", "particle",
    "position", "near", "safety", "rule", "measure"}`` or None. Given ``rundir``, a position
    without a named feature is given the nearest one of the part's mesh, where the features
    are known (:func:`rackstress.stress.surface.nearest_feature`)."""
    st = summary.get("stress") or {}
    gov, pk = st.get("governing"), st.get("peak")
    groups = {g["name"]: g for g in (scene or {}).get("groups", [])}
    if gov:
        group = gov.get("group") or (pk or {}).get("group")
        rec = {"kind": "governing", "value": gov.get("value"),
               "units": gov.get("units") or (pk or {}).get("units", ""), "group": group,
               "particle": gov.get("particle"), "position": gov.get("position"),
               "near": gov.get("near"), "safety": gov.get("safety"),
               "rule": gov.get("rule"), "measure": gov.get("measure", "von_mises")}
    elif pk:
        rec = {"kind": "peak", "value": pk.get("value"), "units": pk.get("units", ""),
               "group": pk.get("group"), "particle": pk.get("particle"),
               "position": pk.get("original") or pk.get("position"), "near": pk.get("near"),
               "safety": None, "rule": "the largest value over the part's particles",
               "measure": pk.get("measure")}
    else:
        return None
    if rec["near"] is None and rundir is not None and rec["position"] is not None:
        from rackstress.stress.surface import nearest_feature

        rec["near"] = nearest_feature(rundir, rec["group"], rec["position"])
    if rec["safety"] is None and rec["measure"] == "von_mises" and rec["value"]:
        y = ((groups.get(rec["group"]) or {}).get("material") or {}).get("yield")
        if y:
            rec["safety"] = float(y) / float(rec["value"])
    return rec


def headline_text(h: dict) -> str:
    """One line: value, units, where (undeformed), the feature near it, safety."""
    pos = ", ".join(f"{x:.4g}" for x in h.get("position") or [])
    what = "governing von Mises stress" if h["kind"] == "governing" else (
        "peak von Mises stress" if h.get("measure") == "von_mises" else f"peak {h['measure']}")
    near = f" near {h['near']}" if h.get("near") else ""
    sf = f"; smallest factor of safety {h['safety']:.3g}" if h.get("safety") else ""
    return (f"{what} {h['value']:.4g} {h.get('units', '')} in {h['group']} at ({pos}){near}, "
            f"particle {h['particle']}{sf}")


def unsettled_text(summary: dict, short: bool = False) -> str:
    """The red line of a run that did not settle (``short``: one a picture's header holds)."""
    if short:
        return (f"NOT SETTLED: not an equilibrium, do not use these numbers (residual "
                f"{summary.get('residual', float('nan')):.2g}, {summary.get('iterations')} "
                "Newton steps)")
    return (f"NOT SETTLED: not an equilibrium (largest unbalanced force "
            f"{summary.get('residual', float('nan')):.2g} of the applied load after "
            f"{summary.get('iterations')} Newton steps): do not use these numbers")


def unsettled_advice(summary: dict) -> str:
    """What to do about a run that did not settle, from what its summary says."""
    floor = summary.get("rounding_floor")
    if floor is not None and floor >= 0.1 * summary.get("tolerance", 1e-6):
        return ("the rounding of the positions alone leaves about "
                f"{floor:.2g} of the load unbalanced: the load deforms the part too little "
                "to resolve; a larger load settles it")
    lost = [w for w in summary.get("warnings") or [] if w.get("kind") == "load_path"]
    if lost:
        return (lost[0].get("message", "a load reaches no support")
                + ": hold that part, or bind it to one that is held")
    return ("check that the supports hold every part against every rigid motion (a part held "
            "on one line of particles turns about it; a part held by nothing floats), that "
            "every load reaches a support, and that thin walls have at least three particles "
            "across (a finer spacing); 'rackstress run' on a terminal shows the residual of "
            "each Newton step")
