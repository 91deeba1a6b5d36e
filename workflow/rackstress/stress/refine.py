"""``rackstress run --refine``: the same scene at spacing/√2, and the governing stress's error bar.

After a run at its spacing h (the run directory ``RUN``), :func:`refine` runs the scene again
with every part filled at h/√2 (:data:`~rackstress.stress.governing.REFINE_RATIO`) into
``RUN/refine`` — a run directory of its own, locked, resumable and overwritten only by this
step —, reads its governing stress at the first run's zone and singular points (the same
quantity at both spacings: :func:`rackstress.stress.governing.record` with the coarse run's
``singular`` and ``zone_override``; its field at the first run's governing point where that
is the larger, :func:`rackstress.stress.governing.with_first_point`), and writes into
``RUN/summary.json["stress"]["error"]`` Richardson's extrapolation and the error band
(:func:`rackstress.stress.governing.error_bar`, the lattice's measured order). ``RUN`` is
complete before the refined run starts: a refined run that is interrupted leaves it as it was
(``--resume RUN --refine`` does the refinement again).

Example
-------
>>> refine("runs/cframe", "examples/cframe/static.toml")["extrapolated"]   # doctest: +SKIP
99.2
"""
from __future__ import annotations

import json
from pathlib import Path

from rackstress.errors import EXIT_UNSETTLED, RackstressError
from rackstress.stress.governing import (REFINE_RATIO, default_error, error_bar, record,
                                         singular_set, with_contact_edges, with_first_point,
                                         with_single_run)
from rackstress.stress.measures import read_contacts

#: the refined run's directory inside the run
REFINE_DIR = "refine"


class RefineError(RackstressError):
    """The refinement cannot be made (no governing stress, a run that did not settle): exit 2,
    or 6 (``EXIT_UNSETTLED``) when the refined run did not settle."""


def finished_summary(rundir: Path) -> dict | None:
    """A run directory's ``summary.json``, or None while it has none (or an unreadable one)."""
    try:
        return json.loads((rundir / "summary.json").read_text())
    except (OSError, ValueError):
        return None


def first_run(rundir: Path, error, doing: str, no_equilibrium: str, no_governing: str):
    """What filling a finished run again reads against (``--refine``, ``--offsets``): its
    summary, governing stress, singular points (its contact edges included, found from its
    result: its measures, only for a run with parts in contact), ``spacing_scale`` and the
    zone of the governing part. ``error`` (a :class:`RackstressError`) refuses a run that is
    not finished, did not settle or has no governing stress, its message ending as given."""
    from rackstress.stress.post import compute_fields
    from rackstress.stress.rundata import load_run

    summary = finished_summary(rundir)
    if summary is None:
        raise error(f"{rundir}: no finished run to {doing} (no summary.json)")
    if summary.get("settled") is False or summary.get("status") in ("diverged", "not settled"):
        raise error(f"{rundir}: the run did not settle ({summary.get('status')}): its stress "
                    f"is not an equilibrium's, {no_equilibrium}")
    gov = (summary.get("stress") or {}).get("governing")
    if not gov:
        raise error(f"{rundir}: no governing stress (a part with a material and its von Mises "
                    f"stress) {no_governing}")
    run = load_run(rundir)
    sing = singular_set(run)
    if read_contacts(run) is not None:
        sing = with_contact_edges(run, compute_fields(run), sing)
    scale = float(json.loads((rundir / "scene.json").read_text()).get("params", {})
                  .get("spacing_scale", 1.0))
    parts = (summary.get("stress") or {}).get("zone_parts") or {}
    zone = (parts.get(gov["group"]) or {}).get("zone", gov["zone"])
    return summary, gov, sing, scale, zone


def check_refinable(scene, option: str = "--refine") -> None:
    """Refuse, before anything runs, a scene ``--refine`` cannot refine (nor ``--offsets``
    move, ``option``): a dynamic analysis (its peak is a time's, and the time step changes
    with the spacing) or one without a part with a material (no von Mises stress, no
    governing stress)."""
    if getattr(scene, "analysis", None) != "static":
        raise RefineError(f"scene '{scene.name}' is not a static analysis (analysis = "
                          f"\"static\"): {option} reads a static part's governing stress "
                          "again on another lattice")
    if not any(g.material is not None for g in scene.groups.values()):
        raise RefineError(f"scene '{scene.name}' has no part with a material: {option} "
                          "reads the governing von Mises stress of a material part")


def fine_alone(fine_dir: Path, fg: dict, zone: float) -> dict | None:
    """The refined run's own governing stress (``RUN/refine/summary.json``: its own singular
    points and zone) where it reads more than :data:`~rackstress.stress.governing.CONVERGING`
    above the same-rule reading ``fg`` (the coarse run's points and zone), else None. At the
    finer spacing a concave edge that turned sharply within the coarse run's window may turn
    gently within its own — a fillet the coarse spacing took for a sharp edge — and the points
    beside it are read: the SO-100 shoulder bracket's refined run read 0.332 MPa there on its
    own, 0.219 by the coarse run's rule (its FE check's local refinement about that point:
    0.312, still rising). The error bar keeps the same rule at both spacings; this says what
    it leaves out; ``why`` says which of the two differs: its zone (smaller than the first
    run's ``zone``: it reads nearer the singular points) or its singular points."""
    from rackstress.stress.governing import CONVERGING

    own = ((finished_summary(fine_dir) or {}).get("stress") or {}).get("governing")
    if not own or own.get("group") != fg.get("group", own.get("group")):
        return None
    if not own["value"] > (1.0 + CONVERGING) * fg["value"]:
        return None
    out = {k: own.get(k) for k in ("value", "particle", "position", "near", "zone", "read")}
    out["why"] = ("zone" if float(own.get("zone") or zone) < (1.0 - 1e-6) * float(zone)
                  else "singular points")
    return out


def refine(rundir, spec: str, overrides: dict | None = None, engine: str = "lammps",
           mode: str = "exact", progress: bool = False, echo=print,
           ratio: float = REFINE_RATIO) -> dict:
    """Run ``spec`` at spacing/``ratio`` into ``RUNDIR/refine`` and write the error bar.

    Parameters
    ----------
    rundir : path
        A finished run of ``spec`` (its ``summary.json`` with a governing stress).
    spec : str
        The scene file the run was made from; ``overrides`` its ``--set`` values.

    Returns
    -------
    dict
        The error bar, as written into ``summary.json["stress"]["error"]``.

    Raises
    ------
    RefineError
        The run has no governing stress (no part with a material) or did not settle.
    """
    from rackstress.lib.jsonio import write_json
    from rackstress.runs.run import run as run_scene
    from rackstress.scenes import load
    from rackstress.stress.post import compute_fields, postprocess
    from rackstress.stress.rundata import load_run

    rundir = Path(rundir)
    summary, gov, sing, scale, z = first_run(rundir, RefineError, "refine",
                                             "so it has no error bar to refine", "to refine")
    fine_dir = rundir / REFINE_DIR
    fine_summary = finished_summary(fine_dir)
    sc = load(spec, overrides, spacing_scale=scale / ratio)
    done = (fine_summary is not None and fine_summary.get("settled") is not False
            and fine_summary.get("n_particles") == sc.n_particles
            and (fine_summary.get("params") or {}).get("spacing_scale") == scale / ratio)
    if not done:
        echo(f"refine: {sc.name} at spacing / {ratio:.4g} ({sc.n_particles:,} particles) into "
             f"{fine_dir}")
        run_scene(sc, fine_dir, engine=engine, mode=mode, progress=progress, overwrite=True)
        fine_summary = finished_summary(fine_dir)
        if fine_summary.get("settled") is False:
            err = RefineError(f"{fine_dir}: the refined run did not settle (residual "
                              f"{fine_summary.get('residual'):.3g} of the load); the first "
                              f"run in {rundir} is kept as it was, without an error bar")
            err.exit_code = EXIT_UNSETTLED
            raise err
        postprocess(fine_dir, vtk=False, dump=False)
    else:
        echo(f"refine: {fine_dir} holds the refined run already")
    fine_run = load_run(fine_dir)
    fields = compute_fields(fine_run)
    fine = record(fine_run, fields, zone_override=z, singular=sing)
    fg = with_first_point(fine_run, fields,
                          (fine.get("parts") or {}).get(gov["group"], {}).get("governing"), gov)
    if fg is None:
        raise RefineError(f"{fine_dir}: every particle of '{gov['group']}' lies within the "
                          f"zone ({z:.3g}) of a singular point")
    h = float(gov["spacing"])
    # never narrower than the refined run's own single-run band (a fillet's or hole's peak
    # the lattice does not resolve, two values agreeing by chance)
    err = with_single_run(error_bar([gov["value"], fg["value"]], [h, h / ratio]),
                          default_error(fine_run, fg))
    err.update(refine_dir=REFINE_DIR, group=gov["group"], zone=z, units=gov["units"],
               governing_fine={**{k: fg[k] for k in ("value", "particle", "position",
                                                     "iteration")},
                               "read": fg.get("read"), "read_at": fg.get("read_at"),
                               "rule_value": fg.get("rule_value", fg["value"]),
                               "notch_by": (fg.get("notch") or {}).get("by")},
               particles=[int(summary.get("n_particles", 0)),
                          int(fine_summary.get("n_particles", 0))])
    own = fine_alone(fine_dir, fg, z)
    if own is not None:
        err["fine_own"] = own
    summary = finished_summary(rundir)    # as it is now (post-processing may have added to it)
    # the first run's own band (default_error), what it said before --refine; kept when a
    # refinement is done again
    first = (summary.get("stress") or {}).get("error") or {}
    first = first.get("first_run") if "values" in first else first
    if first:
        err["first_run"] = {k: first.get(k) for k in ("low", "high", "relative")}
    summary.setdefault("stress", {})["error"] = err
    write_json(rundir / "summary.json", summary)
    return err
