"""``rackstress bench governing``: the governing stress, the singular peak and the error bar of
``--refine``, at three spacings, against converged FEA.

Four static parts, each at spacings h, h/√2 and h/2 (``rackstress run``'s spacing_scale, the
refinement of ``--refine``):

* ``cframe`` — ``examples/cframe/static.toml``: an aluminium C frame with sharp inner corners,
  bolted at one jaw, pulled open by 1 kN at the other (h = 1 mm);
* ``cframe-filleted`` — ``examples/cframe/filleted.toml``: the same with 2 mm fillets;
* ``bracket`` — ``examples/bracket/static.toml``: the shelf bracket, 3 mm walls (h = 1 mm);
* ``so100-moving-jaw`` — a real part nobody here drew: the SO-ARM100's moving jaw (PLA, from
  the example-robot-data wheel, in metres, scaled to mm), held at its eight screw holes,
  gripping with 10 N on its jaw face (h = 2 mm).

For each: the governing stress (:mod:`rackstress.stress.governing`) at every spacing read at
the coarsest run's zone and singular points (the same quantity at every spacing; the finer
ones also at the coarsest run's governing point, as ``--refine`` reads), the singular
peak beside it, the error bar ``--refine`` gives (h and h/√2, the lattice's order), the
three-spacing Richardson extrapolation with its measured order, and **converged FEA**: P2
tetrahedra graded toward the re-entrant edges and the loaded particles
(:mod:`rackstress.validity.graded`), with the supports and loads of the finest run, solved at
two mesh sizes, the second 0.8 × the first (how converged: the change of its governing stress
between them). Also the particles against FEA at their own centres by
distance from the singular points in spacings — where the singular field's influence on the
lattice decays (the zone's two spacings).

``--quick``: every part at h and h/√2 only (``--refine``'s pair) and one FE size — no
three-spacing order, no FE convergence figure.

Outputs ``governing.json`` and ``governing.md`` (docs/benchmarks/).
"""
from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from rackstress.bench import fmt, machine, md_table, out_dir, repository_file, write_json

#: the levels: spacing × these (the refinement of --refine, then once more)
LEVELS = (1.0, 1.0 / math.sqrt(2.0), 0.5)
#: the FE's second mesh: every size times this (how converged the reference is)
FE_REFINE = 0.8
#: distance bands from the singular points, in spacings
BANDS = ((0, 1), (1, 2), (2, 3), (3, 5), (5, math.inf))
HEADER = ["part", "spacing", "particles", "zone", "governing (particles)", "read by",
          "singular peak", "FEA governing", "particles / FEA", "s/t at the governing point",
          "at a curved face", "|error| / (s/t)", "single-run band", "covers FEA"]


def _jaw_stl() -> Path | None:
    """The SO-ARM100 moving jaw's STL: the repository's real-part corpus, else the unpacked
    example-robot-data wheel."""
    for p in (repository_file("examples", "parts", "so100-moving-jaw", "Moving_Jaw.stl"),
              Path("/work/parts/example-robot-data/so_arm_description/meshes/so100/"
                   "Moving_Jaw.stl")):
        if p.is_file():
            return p
    try:
        import example_robot_data  # noqa: F401 - the wheel, where it is installed
        base = Path(example_robot_data.__file__).parent
        for p in base.rglob("Moving_Jaw.stl"):
            return p
    except ImportError:
        pass
    return None


JAW_TOML = """
name = "so100-moving-jaw"
units = "mm-N-s"
analysis = "static"

[params]
spacing = 2.0

[[group]]
name = "jaw"
mesh = "{stl}"
scale = 1000
spacing = "$spacing"
material = "PLA"

[[support]]        # the eight M3 screws into the servo horn: 3 mm around each hole's axis
on = "jaw"
where = {{ union = [{holes}] }}

[[load]]           # 10 N gripping, against the jaw face's outward normal, on its 2 mm skin
on = "jaw"
where = {{ intersection = [{{ plane = {{ point = [4.476, -33.68, 0.83], normal = [0.994, -0.105, 0] }} }}, {{ box = {{ min = [-1, -66, -17], max = [12, -2, 18] }} }}] }}
force = [-9.94, 1.05, 0]
"""


def _jaw_scene(work: Path) -> Path | None:
    stl = _jaw_stl()
    if stl is None:
        return None
    holes = []
    for x in (-4.95, 4.95):
        for y in (-4.95, 4.95):
            for zc in (-20.55, 19.35):
                holes.append(f"{{ cylinder = {{ start = [{x}, {y}, {zc - 2.5}], end = [{x}, {y}, "
                             f"{zc + 2.5}], radius = 3 }} }}")
    path = work / "so100-moving-jaw.toml"
    path.write_text(JAW_TOML.format(stl=str(stl), holes=", ".join(holes)))
    return path


#: name → (scene file, base spacing [mm], FE size away from / at the re-entrant edges [mm])
def cases(work: Path) -> list:
    out = [("cframe", repository_file("examples", "cframe", "static.toml"), 1.0, 1.0, 0.2),
           ("cframe-filleted", repository_file("examples", "cframe", "filleted.toml"), 1.0,
            1.0, 0.2),
           ("bracket", repository_file("examples", "bracket", "static.toml"), 1.0, 0.75, 0.15)]
    jaw = _jaw_scene(work)
    if jaw is not None:
        out.append(("so100-moving-jaw", jaw, 2.0, 1.5, 0.3))
    return out


def _level(scene: Path, spacing: float, scale: float, out: Path) -> dict:
    from rackstress.runs.run import run
    from rackstress.scenes import load
    from rackstress.stress.post import postprocess

    t0 = time.process_time()
    sc = load(str(scene), {"spacing": spacing}, spacing_scale=scale)
    summary = run(sc, out, progress=False, overwrite=True)
    postprocess(out, vtk=False, dump=False)
    return {"dir": out, "particles": sc.n_particles, "settled": summary.get("settled"),
            "spacing": spacing * scale, "cpu_s": time.process_time() - t0}


def case(name: str, scene: Path, spacing: float, h_far: float, h_near: float, work: Path,
         levels=LEVELS, fe_levels: int = 2, echo=print) -> dict:
    """One part through the levels, the error bars and the FE reference (module docstring)."""
    from rackstress.model.singular import chords
    from rackstress.stress.governing import (LATTICE_ORDER, default_error, error_bar,
                                             near_curved, record, with_first_point,
                                             read_singular, zone as zone_of)
    from rackstress.stress.governing import curved_near as curved_near_of, with_single_run
    from rackstress.stress.post import compute_fields
    from rackstress.stress.rundata import load_run
    from rackstress.stress.measures import recovery_points_of
    from rackstress.validity.graded import governing_fe, reference

    runs = []
    for k, f in enumerate(levels):
        r = _level(scene, spacing, f, work / f"{name}-{k}")
        echo(f"{name}: spacing {r['spacing']:.4g}: {r['particles']:,} particles, "
             f"{r['cpu_s']:.0f} s CPU")
        runs.append(r)
    coarse = read_singular(runs[0]["dir"])
    part = next(iter(coarse))
    sp0, wall, sing = coarse[part]
    z = zone_of(sp0, wall)
    rows, first = [], None
    for r in runs:
        rd = load_run(r["dir"])
        fields = compute_fields(rd)
        rec = record(rd, fields, zone_override=z, singular=coarse)
        at = rec["parts"][part]
        # the finer levels as --refine reads them: also at the first level's governing point
        # (stress.governing.with_first_point)
        gov = at["governing"] if first is None else with_first_point(rd, fields,
                                                                     at["governing"], first)
        first = first or gov
        own = record(rd, fields)["parts"][part]
        o_part = rd.o[rd.parts[part].index]
        t_gov = float(chords(o_part, r["spacing"])[gov["index"]])
        curved = near_curved(r["dir"], part, gov["position"], r["spacing"])
        rows.append({"spacing": r["spacing"], "particles": r["particles"],
                     "settled": r["settled"], "cpu_s": r["cpu_s"],
                     "governing": gov["value"],
                     "governing_at": gov["position"],
                     "read": gov.get("read", "patch"),
                     "notch_by": (gov.get("notch") or {}).get("by"),
                     # the particles' patch fit's own governing stress (the notch reading may
                     # be the headline instead: stress.governing.notch_peak)
                     "patch_governing": gov.get("patch_value", gov["value"]),
                     "curved_face": gov.get("curved_face"),
                     # what a single run at this spacing says it may be off by
                     "single_run": {k: (rec["error"] if gov is at["governing"]
                                        else default_error(rd, gov))[k] for k in
                                    ("low", "high", "relative", "curved_face_bound")},
                     "governing_own_zone": own["governing"]["value"], "own_zone": own["zone"],
                     "thickness_at_governing": t_gov, "at_curved_face": curved,
                     "s_over_t": r["spacing"] / t_gov,
                     "singular_peak": (at["singular"] or {}).get("value"),
                     "singular_kind": (at["singular"] or {}).get("kind"),
                     "_vm": fields.values["von_mises"][-1][rd.parts[part].index],
                     # the particles within two spacings of a concave curved face (fillets,
                     # holes) and the zone away from the singular points
                     "_curved": curved_near_of(r["dir"], part,
                                               recovery_points_of(rd, rd.parts[part]),
                                               r["spacing"]),
                     # where each value is read: its recovery point (patch recovery)
                     "_o": recovery_points_of(rd, rd.parts[part])})
    g = [r["governing"] for r in rows]
    h = [r["spacing"] for r in rows]
    # the bands as --refine gives them: never narrower than the finer run's own single-run
    # band (stress.governing.with_single_run); the three-spacing band likewise
    refine = with_single_run(error_bar(g[:2], h[:2], order=LATTICE_ORDER),
                             rows[1]["single_run"])
    three = with_single_run(error_bar(g, h), rows[-1]["single_run"]) if len(g) >= 3 else None
    # converged FEA: the finest run's supports and loads, graded P2 at two sizes
    fes = []
    for k in range(fe_levels):
        f = FE_REFINE ** k
        t0 = time.perf_counter()
        ref = reference(runs[-1]["dir"], h_far * f, h_near * f, singular=sing)
        gv = governing_fe(ref, z)
        fes.append({"h_far": h_far * f, "h_near": h_near * f, **ref["fe"], "cpu_s": ref["cpu_s"],
                    "wall_s": time.perf_counter() - t0, "governing": gv["value"],
                    "governing_at": gv["position"]})
        echo(f"{name}: FEA h {h_far * f:.3g}/{h_near * f:.3g}: {ref['fe']['tetrahedra']:,} "
             f"tetrahedra, governing {gv['value']:.4g}")
        last = ref
    fe_g = fes[-1]["governing"]
    fe_curved = _fea_curved_peak(last, runs[0]["dir"], part, sing, z, runs[-1]["spacing"])
    # the particles against FEA where their stress is read, by distance from the singular points
    sol = last["solution"]
    for r in rows:
        fe_at = sol.at(r["_o"])["von_mises"]
        d, _ = sing.distance(r["_o"])
        bands = []
        for lo, hi in BANDS:
            m = (d >= lo * r["spacing"]) & (d < hi * r["spacing"])
            if m.any():
                ratio = r["_vm"][m] / fe_at[m]
                bands.append({"band": [lo, None if hi == math.inf else hi], "n": int(m.sum()),
                              "median_ratio": float(np.median(ratio)),
                              "peak_ratio": float(r["_vm"][m].max() / fe_at[m].max())})
        r["bands"] = bands
        # at the concave curved faces: the particles' largest value against FEA's largest at
        # the same points and FEA's own largest nodal value within the same distance
        cm = r["_curved"] & (d >= z)
        if cm.any():
            r["curved_peak"] = float(r["_vm"][cm].max())
            r["fea_curved_at_points"] = float(fe_at[cm].max())
        del r["_curved"]
        r["governing_over_fea"] = r["governing"] / fe_g
        r["patch_over_fea"] = r["patch_governing"] / fe_g
        # what a single run's default estimate would need: |error| per s/t
        r["error_per_s_over_t"] = abs(r["governing_over_fea"] - 1) / r["s_over_t"]
        r["single_run"]["covers_fea"] = bool(r["single_run"]["low"] <= fe_g
                                             <= r["single_run"]["high"])
        del r["_vm"], r["_o"]
    covered = {"refine": bool(refine["low"] <= fe_g <= refine["high"]),
               "three": None if three is None else bool(three["low"] <= fe_g <= three["high"])}
    return {"name": name, "scene": str(scene), "part": part, "spacing": spacing, "wall": wall,
            "zone": z, "singular_points": sing.counts(), "singular_source": sing.source,
            "rows": rows, "refine": refine, "three": three, "fea": fes, "fea_governing": fe_g,
            "fea_curved_peak": fe_curved,
            "fea_converged": abs(fes[-1]["governing"] / fes[0]["governing"] - 1)
            if len(fes) > 1 else None, "covered": covered}


def _fea_curved_peak(ref: dict, rundir, part: str, sing, zone: float, spacing: float):
    """FEA's largest nodal von Mises stress within two (finest) spacings of a concave curved
    face of the part (a fillet, a hole) and at least the zone from every singular point: the
    peak the particles' recovery has to reach there; None where the part has no such face."""
    from rackstress.stress.governing import curved_near

    nodes = np.asarray(ref["solution"].mesh.p)
    if "_nodal_vm" not in ref:
        ref["_nodal_vm"] = ref["solution"].nodal()["von_mises"][:len(nodes)]
    near = curved_near(rundir, part, nodes, spacing)
    d, _ = sing.distance(nodes)
    m = near & (d >= zone)
    return float(ref["_nodal_vm"][m].max()) if m.any() else None


def single_run_errors(cases: list) -> tuple:
    """What a single run's error estimate takes, from every part and spacing: the largest
    |governing / FEA − 1| per s/t where the governing particle lies on flat faces, and the
    largest |governing / FEA − 1| where it lies within two spacings of a concave curved face
    (the steps' error does not shrink with s/t), or |particles' peak there / FEA's peak there
    − 1|. None where no row is of that kind."""
    rows = [r for c in cases for r in c["rows"]]
    flat = [r["error_per_s_over_t"] for r in rows if not r.get("at_curved_face")]
    curved = [abs(r["governing_over_fea"] - 1) for r in rows if r.get("at_curved_face")]
    # ... and how far the particles' peak at a concave curved face falls from FEA's there
    curved += [abs(r["curved_peak"] / c["fea_curved_peak"] - 1) for c in cases
               for r in c["rows"] if r.get("curved_peak") and c.get("fea_curved_peak")]
    return (max(flat) if flat else None), (max(curved) if curved else None)


def notch_errors(cases: list) -> float | None:
    """The largest |governing / FEA − 1| over the rows whose governing stress is the notch
    reading (stress.governing.notch_peak): the check of NOTCH_ERROR; None where there is none."""
    e = [abs(r["governing_over_fea"] - 1) for c in cases for r in c["rows"]
         if r.get("read") == "notch"]
    return max(e) if e else None


def table_rows(data) -> list:
    from rackstress.stress.governing import read_label

    out = []
    for c in data["cases"]:
        for r in c["rows"]:
            out.append([c["name"], fmt(r["spacing"], 4), f"{r['particles']:,}", fmt(c["zone"]),
                        fmt(r["governing"], 4),
                        read_label(r.get("read", "patch"), r.get("notch_by")),
                        fmt(r["singular_peak"], 4),
                        fmt(c["fea_governing"], 4), fmt(r["governing_over_fea"]),
                        fmt(r["s_over_t"]), "yes" if r["at_curved_face"] else "no",
                        fmt(r["error_per_s_over_t"]),
                        f"{fmt(r['single_run']['low'], 4)} … {fmt(r['single_run']['high'], 4)}",
                        "yes" if r["single_run"]["covers_fea"] else "no"])
    return out


def run_bench(out=None, quick: bool = False, echo=print) -> dict:
    """Run the benchmark (module docstring); returns the data written to governing.json."""
    t0 = time.perf_counter()
    start = machine()
    out = out_dir(out)
    results = []
    with tempfile.TemporaryDirectory(prefix="rs-governing-") as tmp:
        work = Path(tmp)
        todo = cases(work)
        failed = []
        for name, scene, spacing, h_far, h_near in todo:
            try:
                results.append(case(name, scene, spacing, h_far, h_near, work,
                                    levels=LEVELS[:2] if quick else LEVELS,
                                    fe_levels=1 if quick else 2, echo=echo))
            except Exception as e:  # noqa: BLE001 - one part's failure (gmsh's mesh) is recorded
                echo(f"{name}: not measured: {type(e).__name__}: {e}")
                failed.append({"name": name, "error": f"{type(e).__name__}: {e}"})
            write_json(out / "governing.partial.json", {"cases": results})   # kept if cut short
    from rackstress.stress.governing import (CURVED_ERROR, DEFAULT_ERROR_SLOPE,
                                             LATTICE_ORDER, NOTCH_ERROR, REFINE_RATIO,
                                             ZONE_SPACINGS, ZONE_WALLS)

    orders = [c["three"]["order"] for c in results
              if c["three"] and c["three"]["order_from"].startswith("measured")]
    slope, curved = single_run_errors(results)
    data = {"machine": {**start, "load_avg_at_end": machine().get("load_avg_at_start")},
            "quick": bool(quick), "levels": list(LEVELS[:2] if quick else LEVELS),
            "rule": {"zone_spacings": ZONE_SPACINGS, "zone_walls": ZONE_WALLS,
                     "refine_ratio": REFINE_RATIO, "lattice_order": LATTICE_ORDER,
                     "default_error_slope": DEFAULT_ERROR_SLOPE,
                     "curved_error": CURVED_ERROR, "notch_error": NOTCH_ERROR},
            "failed": failed,
            "measured_orders": orders, "measured_error_slope": slope,
            "measured_error_curved": curved, "measured_error_notch": notch_errors(results),
            "cases": results,
            "lattice": "the simple-cubic bind lattice with face compensation and boundary "
                       "fractions; the default stress route, patch recovery (each particle "
                       "read at its recovery point: the surface point of its cell on the "
                       "surface, docs/stress.md); the lattice's own Poisson's ratio 1/4 (FEA: the "
                       "material's ν)"}
    data["wall_s"] = time.perf_counter() - t0
    (out / "governing.partial.json").unlink(missing_ok=True)
    data["files"] = [str(out / "governing.json"), str(out / "governing.md")]
    write_json(out / "governing.json", data)
    (out / "governing.md").write_text(markdown(data))
    return data


#: what the page says where no order was measured: --quick has two spacings; a full run's
#: three values gave none between 0.3 and 4 (not monotone, or not converging)
NO_ORDER = {True: "— (--quick)",
            False: "none (no part's three values converge monotonically at an order between "
                   "0.3 and 4)"}


def markdown(data) -> str:
    m = data["machine"]
    lines = ["# The governing stress, its singular peak and its error bar",
             "",
             *([f"**Cut short**: {data['cut_short']}", ""] if data.get("cut_short") else []),
             "Generated by `rackstress bench governing` (workflow/rackstress/bench/governing.py)"
             + (" with `--quick`" if data["quick"] else "") + f"; load average "
             f"{fmt(m.get('load_avg_at_start', [None])[0] if m.get('load_avg_at_start') else None)}"
             f" at the start" + (f", {data['wall_s']:.0f} s" if data.get("wall_s") else "")
             + f". Lattice: {data['lattice']}.",
             "",
             "Each part at spacings h, h/√2, h/2; every spacing's governing stress read at the "
             "coarsest run's zone and singular points (the finer ones, as `--refine` reads "
             "its finer run, also at the coarsest run's governing point where that reads more: "
             "*first point*, docs/stress.md \"The first run's governing point\"). FEA: P2 "
             "tetrahedra graded toward the "
             "re-entrant edges, the concave curved faces and the loads (validity/graded.py), "
             "the finest run's supports and loads; its "
             "governing stress is the largest nodal von Mises stress (surface included) at least "
             "the zone from every singular point.",
             "",
             md_table(HEADER, table_rows(data)),
             *([("Not measured: " + "; ".join(f"{f['name']} ({f['error']})"
                                             for f in data["failed"]) + "."), ""]
               if data.get("failed") else []),
             f"The lattice's order of convergence, measured on each part from its three "
             f"spacings: {', '.join(fmt(p) for p in data['measured_orders']) or NO_ORDER[data['quick']]}"
             f"; the error bars below use order {fmt(data['rule']['lattice_order'])}. A single "
             f"run's error per "
             f"s/t (s the spacing, t the shortest chord through the part at the governing "
             f"particle), the largest over every part and spacing: "
             f"{fmt(single_run_errors(data['cases'])[0])} where the governing particle lies "
             "on flat faces; where it lies within two spacings of a concave curved face (a "
             "fillet, a hole: steps to the lattice), the largest |error| whatever s/t: "
             f"{fmt(single_run_errors(data['cases'])[1])}. What a single run's error estimate "
             "takes (stress.governing's DEFAULT_ERROR_SLOPE, CURVED_ERROR). Where the governing "
             "stress is the notch reading (a concave curved face's peak fitted to the particles "
             "beneath it, docs/stress.md), its largest |error|: "
             f"{fmt(notch_errors(data['cases']))} (stress.governing's NOTCH_ERROR: "
             f"{fmt(data['rule'].get('notch_error'))}).",
             "",
             "## Error bars", "",
             "What `--refine` reports: the finer run's value (h/√2), with Roache's grid "
             "convergence index about it (safety factor 3 with the assumed order, 1.25 with a "
             "measured one) from Richardson's extrapolation, the band never narrower than "
             "the finer run's own single-run band: ± the measured error per s/t, or at a "
             "concave curved face ± CURVED_ERROR and up to the face's largest value over "
             f"1 − CURVED_ERROR ({fmt(data['rule'].get('curved_error'))}; "
             "stress.governing.with_single_run, default_error).", "",
             md_table(["part", "--refine: refined", "refined / FEA", "extrapolated",
                       "extrapolated / FEA", "band", "covers FEA",
                       "3 spacings: order", "extrapolated", "band", "covers FEA", "FEA",
                       "FEA change between its two sizes"],
                      [[c["name"], fmt(c["refine"]["values"][-1], 4),
                        fmt(c["refine"]["values"][-1] / c["fea_governing"], 3),
                        fmt(c["refine"]["extrapolated"], 4),
                        fmt(c["refine"]["extrapolated"] / c["fea_governing"], 3),
                        f"{fmt(c['refine']['low'], 4)} … {fmt(c['refine']['high'], 4)}",
                        "yes" if c["covered"]["refine"] else "no",
                        fmt(c["three"]["order"]) if c["three"] else "—",
                        fmt(c["three"]["extrapolated"], 4) if c["three"] else "—",
                        (f"{fmt(c['three']['low'], 4)} … {fmt(c['three']['high'], 4)}"
                         if c["three"] else "—"),
                        ("yes" if c["covered"]["three"] else "no") if c["three"] else "—",
                        fmt(c["fea_governing"], 4),
                        fmt(c["fea_converged"]) if c["fea_converged"] is not None else "—"]
                       for c in data["cases"]]),
             "## At the concave curved faces (fillets, holes)", "",
             "The particles' largest value within two spacings of a concave curved face of the "
             "part and at least the zone from the singular points, against FEA's at the same "
             "points and FEA's largest nodal value there (the peak to be recovered):", "",
             md_table(["part", "spacing", "particles", "FEA at the same points",
                       "FEA's peak there", "particles / FEA's peak"],
                      [[c["name"], fmt(r["spacing"], 4), fmt(r.get("curved_peak"), 4),
                        fmt(r.get("fea_curved_at_points"), 4), fmt(c.get("fea_curved_peak"), 4),
                        fmt(r["curved_peak"] / c["fea_curved_peak"])
                        if r.get("curved_peak") and c.get("fea_curved_peak") else "—"]
                       for c in data["cases"] for r in c["rows"]]),
             "## The particles against FEA where their stress is read (recovery points), by "
             "distance from the singular points", "",
             "Peak of the particles over FEA's peak (median ratio) within each band, in spacings:",
             ""]
    rows = []
    for c in data["cases"]:
        for r in c["rows"]:
            cells = {tuple(b["band"]): f"{b['peak_ratio']:.3f} ({b['median_ratio']:.3f})"
                     for b in r["bands"]}
            rows.append([c["name"], fmt(r["spacing"], 4)]
                        + [cells.get((lo, None if hi == math.inf else hi), "—")
                           for lo, hi in BANDS])
    lines.append(md_table(["part", "spacing"] + [f"{lo}–{hi if hi != math.inf else '∞'}"
                                                  for lo, hi in BANDS], rows))
    lines.append("## FEA\n")
    lines.append(md_table(["part", "h far / near", "tetrahedra", "dofs", "governing", "CPU s"],
                          [[c["name"], f"{fmt(f['h_far'])} / {fmt(f['h_near'])}",
                            f"{f['tetrahedra']:,}", f"{f['dofs']:,}", fmt(f["governing"], 4),
                            fmt(f["cpu_s"])] for c in data["cases"] for f in c["fea"]]))
    return "\n".join(lines) + "\n"
