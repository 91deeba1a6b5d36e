"""``rackstress bench validity --concentrations``: the governing stress at stress
concentrations, against converged FEA and handbook values, at three spacings.

Each case is a part as an engineer has it — an STL (made here with trimesh and manifold3d),
aluminium in mm-N-s, supports and loads, ``analysis = "static"`` — run by ``rackstress run``
and checked by ``rackstress fea`` (:func:`rackstress.validity.solid.check_run`, P2
tetrahedra of the same STL, solved at two FE sizes). The **governing stress** is the largest
von Mises stress at least the zone (2 spacings) away from every singular point (re-entrant
edges, supports fixed in every direction, loads; symmetry planes are not singular), read from
the run's default measure (patch recovery, docs/stress.md) and from the FE's own nodes.

Cases (:data:`CASES`; lengths in mm):

Each planar part is clamped (fixed in every direction) over its first layer at x = 0 and
pulled by a force on its last, 10 MPa on the narrow section's gross area; a symmetry plane is
not used, because a support fixes whole cells (docs/fea.md), not a plane.

* ``plate-hole`` — a plate 40 × 16 × 2.4 with a central hole d = 6.4 (d/D = 0.4) in
  tension. Handbook: Kirsch's infinite plate, 3σ at the hole's edge; finite width: Peterson's
  K_tn = 3 − 3.14(d/D) + 3.667(d/D)² − 1.527(d/D)³ on the net section (Pilkey & Pilkey,
  *Peterson's Stress Concentration Factors*, 3rd ed., Chart 4.1, after Howland).
* ``fillet`` — a flat bar stepped from 16 to 10 wide with fillets r = 2, 2.4 thick, in
  tension; against converged FEA.
* ``notch`` — a flat bar 12 wide with two semicircular edge notches r = 2, 2.4 thick, in
  tension; against converged FEA.
* ``cframe`` — the C-shaped frame with sharp inner corners (60 × 80 × 10, walls 10), held at
  one jaw, pulled open at the other: the 3D re-entrant corner; against converged FEA.
* ``round-shoulder`` — a round bar stepped from D = 8 to d = 5 with a fillet r = 1, in
  tension: a 3D fillet; against converged FEA.

Run in parts: ``--case NAME`` (repeatable) and ``--spacings`` choose; each case writes its
rows into ``validity-concentrations.json`` (merged with the rows already there) and the
Markdown page is rewritten from that file.
"""
from __future__ import annotations

import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from rackstress.bench.parts import FE_CONVERGED

SIGMA = 10.0                          # MPa, the plate's gross tension
#: the three spacings of each case [mm], coarse to fine
SPACINGS = {"plate-hole": (0.8, 0.6, 0.4), "fillet": (0.8, 0.6, 0.4),
            "notch": (0.8, 0.6, 0.4), "cframe": (2.0, 1.0, 0.7),
            "round-shoulder": (0.8, 0.6, 0.4)}
CASES = tuple(SPACINGS)
#: targets: the governing stress within 10 % of converged FEA at the default spacing (the
#: middle one) and within 5 % after --refine (the error bar covering the converged value)
TARGET = {"default": 0.10, "refined": 0.05}


def fea_converged(row: dict) -> bool:
    """Whether the row's FEA governing stress converged (moved at most
    :data:`rackstress.bench.parts.FE_CONVERGED` between its two FE sizes, bench parts' rule;
    a row without the second size counts as converged)."""
    moved = row.get("fea_moved")
    return moved is None or moved <= FE_CONVERGED


def _unconverged(rows) -> str:
    """The rows left out for an FEA that did not converge, in words ("" if none)."""
    off = [r for r in rows if not fea_converged(r)]
    if not off:
        return ""
    return (" Left out, their FEA not converged (moved more than "
            f"{100 * FE_CONVERGED:g} % between its two sizes): "
            + ", ".join(f"{r['case']} at {r['spacing']:g} mm ({100 * r['fea_moved']:.0f} %)"
                        for r in off) + ".")
JSON = "validity-concentrations.json"
ROUTES = ("patch", "continuum", "virial", "completed")
MD = "validity-concentrations.md"

_HEAD = """name = "{name}"
units = "mm-N-s"
analysis = "static"
[params]
spacing = {a}
[[group]]
name = "part"
mesh = "{stl}"
spacing = "$spacing"
material = "aluminium"
"""
_SUPPORT = """[[support]]
on = "part"
where = {{ box = {{ min = {lo}, max = {hi} }} }}
{fix}
"""
_LOAD = """[[load]]
on = "part"
where = {{ box = {{ min = {lo}, max = {hi} }} }}
force = {F}
"""


def _box(lo, hi):
    import trimesh

    return trimesh.creation.box(bounds=[lo, hi])


def _cyl(r, z0, z1, axis="z", at=(0.0, 0.0), sections=256):
    import trimesh

    m = trimesh.creation.cylinder(radius=r, height=z1 - z0, sections=sections)
    m.apply_translation([0, 0, 0.5 * (z0 + z1)])
    if axis == "x":
        m.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))
    m.apply_translation([at[0], at[1], 0] if axis == "z" else [0, at[0], at[1]])
    return m


def _union(ms):
    import trimesh

    return trimesh.boolean.union(ms, engine="manifold")


def _minus(a, bs):
    import trimesh

    return trimesh.boolean.difference([a] + list(bs), engine="manifold")


def _clamp_pull(L: float, F: list, reach: float = 0.6, pad: float = 20.0) -> str:
    """A support fixed in every direction on the particles within ``reach`` of x = 0 and the
    force ``F`` shared by those within ``reach`` of x = L (the first and last layer at any
    spacing up to 2·reach): far enough from the concentration to be Saint-Venant's."""
    return (_SUPPORT.format(lo=[-1, -pad, -pad], hi=[reach, pad, pad], fix="")
            + _LOAD.format(lo=[L - reach, -pad, -pad], hi=[L + 1, pad, pad], F=F))


def part(case: str):
    """(the part as a trimesh, its scene's supports and loads as TOML, handbook dict)."""
    eps = 1e-3
    if case == "plate-hole":
        L, D, t, d = 40.0, 16.0, 2.4, 6.4            # d/D = 0.4, the hole 16.8 from the clamp
        m = _minus(_box([0, 0, 0], [L, D, t]), [_cyl(d / 2, -1, t + 1, at=(L / 2, D / 2))])
        r = d / D
        ktn = 3 - 3.14 * r + 3.667 * r ** 2 - 1.527 * r ** 3
        return m, _clamp_pull(L, [SIGMA * D * t, 0, 0]), {
            "kirsch_MPa": 3 * SIGMA, "peterson_MPa": ktn * SIGMA * D / (D - d),
            "d_over_D": r, "Ktn": ktn}
    if case == "fillet":
        t, H, h, r = 2.4, 16.0, 10.0, 2.0            # 16 wide to 10 wide, fillets r = 2
        c = (H - h) / 2
        parts = [_box([0, 0, 0], [25, H, t]), _box([25 - eps, c, 0], [50, c + h, t])]
        for ylo, yc in ((c + h - eps, c + h + r), (c - r, c - r)):   # above and below
            corner = _box([25 - eps, ylo, 0], [25 + r, ylo + r + eps, t])
            parts.append(_minus(corner, [_cyl(r, -2, t + 2, at=(25 + r, yc))]))
        return _union(parts), _clamp_pull(50.0, [SIGMA * h * t, 0, 0]), {}
    if case == "notch":
        t, H, r = 2.4, 12.0, 2.0                     # 12 wide, two notches r = 2 at x = 25
        m = _minus(_box([0, 0, 0], [50, H, t]),
                   [_cyl(r, -1, t + 1, at=(25, 0)), _cyl(r, -1, t + 1, at=(25, H))])
        return m, _clamp_pull(50.0, [SIGMA * (H - 2 * r) * t, 0, 0]), {}
    if case == "cframe":
        m = _union([_box([0, 0, 0], [10, 80, 10]), _box([0, 0, 0], [60, 10, 10]),
                    _box([0, 70, 0], [60, 80, 10])])
        bc = (_SUPPORT.format(lo=[50, -1, -1], hi=[61, 11, 11], fix="")
              + _LOAD.format(lo=[50, 69, -1], hi=[61, 81, 11], F=[0, 300, 0]))
        return m, bc, {}
    if case == "round-shoulder":
        D, d, r = 8.0, 5.0, 1.0
        import trimesh

        big, small = _cyl(D / 2, 0, 15, axis="x"), _cyl(d / 2, 15 - eps, 30, axis="x")
        ring = trimesh.creation.annulus(r_min=d / 2 - eps, r_max=d / 2 + r, height=r,
                                        sections=256)
        ring.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))
        ring.apply_translation([15 + r / 2, 0, 0])
        m = _union([big, small, _minus(ring, [_torus(d / 2 + r, r, 15 + r)])])
        return m, _clamp_pull(30.0, [SIGMA * math.pi * d * d / 4, 0, 0]), {}
    raise ValueError(f"no concentration case {case!r} (cases: {', '.join(CASES)})")


def _torus(R, r, x):
    import trimesh

    t = trimesh.creation.torus(major_radius=R, minor_radius=r, major_sections=256,
                               minor_sections=64)
    t.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))
    t.apply_translation([x, 0, 0])
    return t


def run_case(case: str, a: float, work: Path, echo=print, refine: bool = False) -> dict:
    """One case at spacing ``a``: the run, its governing stress, the FE check; with
    ``refine``, ``rackstress run --refine``'s second run at a/√2 and its error bar
    (:func:`refined`)."""
    from rackstress.runs.run import run
    from rackstress.scenes import load
    from rackstress.validity import solid

    m, bc, book = part(case)
    stl = work / f"{case}.stl"
    if not stl.exists():
        m.export(stl)
    f = work / f"{case}-{a:g}.toml"
    f.write_text(_HEAD.format(name=case, a=a, stl=stl.name) + bc)
    out = work / f"{case}-{a:g}"
    t0, c0 = time.perf_counter(), time.process_time()
    summary = run(load(str(f)), out, progress=False, overwrite=True)
    t_run = time.perf_counter() - t0
    d = solid.check_run(out, keep=True, echo=lambda *x: None)
    points, values, sing = d["_points"], d["_values"], d["_singular"]
    away = sing.distance(points) >= sing.zone
    k = np.flatnonzero(away)[int(np.nanargmax(values[away]))]
    gov = d["governing"]
    row = {"case": case, "spacing": a, "particles": int(d["particles"]),
           "status": summary.get("status"), "governing_MPa": float(values[k]),
           "governing_at": points[k].tolist(), "fea_governing_MPa": gov["value"],
           "fea_at": gov["position"], "fea_moved": gov.get("moved"),
           "fea_local_MPa": (gov.get("local") or {}).get("value"),
           "fea_local_moved": (gov.get("local") or {}).get("moved"),
           "fea_tetrahedra": d["fe"]["tetrahedra"],
           "ratio": float(values[k] / gov["value"]) if gov["value"] else None,
           "at_fea_point": gov.get("ratio"), "zone": sing.zone,
           "bands": d["bands"], "handbook": book, "refined": None,
           "run_s": t_run, "fea_s": d["wall_s"], "cpu_s": time.process_time() - c0}
    # the run's own headline (summary.json's governing stress): the patch fit's, or the notch
    # reading's where a concave curved face's is the larger (docs/stress.md)
    from rackstress.stress.post import postprocess

    head = postprocess(out, vtk=False, dump=False)["governing"]
    nk = head.get("notch") or {}
    row.update(headline_MPa=head["value"], headline_read=head.get("read"),
               headline_ratio=head["value"] / gov["value"] if gov["value"] else None,
               notch_radius=nk.get("radius"), notch_by=nk.get("by"),
               notch_fit_ratio=nk["fit"] / gov["value"]
               if gov["value"] and nk.get("fit") else None)
    # every route of the measure on the same run: its governing stress over FEA's (the
    # patch route at the recovery points; the others at the particle centres)
    from rackstress.stress.measures import ParticleStress
    from rackstress.stress.rundata import load_run

    centre = sing.distance(d["_o"]) >= sing.zone
    for method in ParticleStress.METHODS:
        v = np.asarray(ParticleStress(load_run(out), method=method).run()
                       .results.von_mises[-1])[d["_slice"]]
        sel = away if method == "patch" else centre
        row.setdefault("routes", {})[method] = float(np.nanmax(v[sel]) / gov["value"]) \
            if gov["value"] else None
    if refine:
        row["refined"] = refined(out, f, gov["value"], echo=echo)
    if book.get("peterson_MPa"):
        row["ratio_peterson"] = row["governing_MPa"] / book["peterson_MPa"]
        row["fea_over_peterson"] = gov["value"] / book["peterson_MPa"]
    echo(f"  {case} a = {a:g} mm: {row['particles']:,} particles, governing "
         f"{row['governing_MPa']:.2f} MPa, FEA {gov['value']:.2f} (moved "
         f"{100 * (gov.get('moved') or 0):.2f} % between FE sizes) → {row['ratio']:.3f}"
         + (f"; Peterson {book['peterson_MPa']:.2f}" if book.get("peterson_MPa") else ""))
    return row


def refined(out: Path, scene: Path, fea: float, echo=print) -> dict:
    """``rackstress run --refine`` on the run ``out`` of ``scene`` as a user runs it
    (:func:`rackstress.stress.refine.refine`: the scene again at spacing/√2, read at the
    first run's zone), against FEA's governing stress ``fea`` (converged, from the first
    run's check): what it reports (the finer run's value), Richardson's extrapolation, the
    band and whether the band covers FEA's value."""
    from rackstress.stress.refine import refine

    err = refine(out, str(scene), echo=lambda *x: None)
    r = {k: err.get(k) for k in ("value", "extrapolated", "low", "high", "order", "spacings",
                                 "particles", "change")}
    fg = err.get("governing_fine") or {}        # how the refined value was read
    r.update(ratio=err["value"] / fea, extrapolated_ratio=err["extrapolated"] / fea,
             covers=bool(err["low"] <= fea <= err["high"]), read=fg.get("read"),
             by=fg.get("notch_by"))
    echo(f"    --refine: {err['value']:.2f} MPa at {err['spacings'][-1]:.3g} mm "
         f"({r['ratio']:.3f} of FEA), extrapolated {err['extrapolated']:.2f} "
         f"({r['extrapolated_ratio']:.3f}), band {err['low']:.2f} … {err['high']:.2f}")
    return r


def run_bench(out: Path | None = None, cases=None, spacings=None, echo=print) -> dict:
    """The cases (all of :data:`CASES` by default) at their spacings (or ``spacings``); rows
    merged into ``JSON`` under ``out`` by (case, spacing), the page rewritten."""
    from rackstress.bench import machine, out_dir

    out = out_dir(out)
    path = out / JSON
    old = json.loads(path.read_text()) if path.is_file() else {"rows": []}
    start = machine()
    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="rs-conc-") as tmp:
        for case in cases or CASES:
            for a in spacings or SPACINGS[case]:
                rows.append(run_case(case, float(a), Path(tmp), echo=echo,
                                     refine=float(a) == SPACINGS[case][1]))
    new = {(r["case"], r["spacing"]) for r in rows}
    kept = [r for r in old["rows"] if (r["case"], r["spacing"]) not in new]
    data = {"rows": sorted(kept + rows, key=lambda r: (CASES.index(r["case"]), -r["spacing"])),
            "target": TARGET, "machine": start, "wall_s": time.perf_counter() - t0,
            "command": "rackstress bench validity --concentrations"}
    from rackstress.bench import write_json

    write_json(path, data)
    (out / MD).write_text(markdown(data))
    return data


def markdown(data: dict) -> str:
    from rackstress.bench import fmt, md_table
    from rackstress.stress.governing import read_label

    rows = []
    for r in data["rows"]:
        b = {x["band"]: x for x in r["bands"]}
        rows.append([r["case"], fmt(r["spacing"]), f"{r['particles']:,}",
                     fmt(r["governing_MPa"], 4), fmt(r["fea_governing_MPa"], 4),
                     fmt(100 * r["fea_moved"], 2) if r.get("fea_moved") is not None else "—",
                     fmt(r["fea_local_MPa"] / r["fea_governing_MPa"], 4)
                     if r.get("fea_local_MPa") and r.get("fea_governing_MPa") else "—",
                     fmt(r["ratio"], 4), fmt(r.get("at_fea_point"), 3),
                     fmt((r["handbook"] or {}).get("peterson_MPa"), 4),
                     fmt((b.get("2-5") or {}).get("peak_ratio")),
                     fmt((b.get(">5") or {}).get("peak_ratio"))]
                    + [fmt((r.get("routes") or {}).get(k), 3) for k in ROUTES]
                    + [fmt(r.get("headline_MPa"), 4),
                       read_label(r.get("headline_read"), r.get("notch_by")),
                       fmt(r.get("headline_ratio"), 3),
                       fmt(r["notch_radius"] / r["spacing"], 2)
                       if r.get("notch_radius") else "—"])
    m = data["machine"]
    return ("# The governing stress at stress concentrations\n\n"
            "Generated by `rackstress bench validity --concentrations` (module "
            "`rackstress.bench.concentrations`; `--case NAME`, `--spacings` run it in parts). "
            "Aluminium parts from STL, static, the run's default von Mises (patch recovery) "
            "against `rackstress fea` (P2 tetrahedra of the same STL, converged: the change "
            "of its governing stress between FE sizes 2 and 2.83 spacings is given, and its "
            "own local refinement about its governing point over it: docs/fea.md). "
            "Governing stress: the largest at least 2 spacings from every re-entrant edge, "
            "support fixed in every direction and load. Targets: within 10 % of converged "
            "FEA at the default (middle) spacing, 5 % after `--refine`.\n\n"
            + md_table(["case", "spacing [mm]", "particles", "governing [MPa]",
                        "FEA governing [MPa]", "FEA moved [%]", "FEA refined locally / FEA",
                        "ratio",
                        "at FEA's point", "Peterson [MPa]", "band 2–5 peak ratio",
                        "band > 5 peak ratio"] + [f"{k} / FEA" for k in ROUTES]
                       + ["headline [MPa]", "read by", "headline / FEA",
                          "notch radius [spacings]"], rows)
            + "\nEach route of the measure (docs/stress.md) on the same run, its governing "
            "stress over FEA's — `patch` (the default) at the recovery points, the others at "
            "the particle centres. The last four: the run's own headline (`summary.json`'s "
            "governing stress), read by the patch fit or, where a concave curved face's is "
            "the larger, by the notch reading (docs/stress.md \"The notch reading\"), and the "
            "radius of the face it read in spacings.\n\n" + notch_summary(data) + "\n"
            + refined_table(data)
            + f"\nMachine: {m.get('cores')} cores, load average "
            f"{' / '.join(f'{x:.1f}' for x in (m.get('load_avg_at_start') or ()))} at the "
            f"start of the last command; {data['wall_s']:.0f} s wall.\n")


def refined_table(data: dict) -> str:
    """The rows refined by ``rackstress run --refine`` (the default, middle, spacing)."""
    from rackstress.bench import fmt, md_table

    rows = [r for r in data["rows"] if r.get("refined")]
    if not rows:
        return ""
    ref = [r for r in rows if fea_converged(r)]
    ok = [r for r in ref if abs(r["refined"]["ratio"] - 1) <= TARGET["refined"]]
    cover = [r for r in ref if r["refined"]["covers"]]
    return ("\n## After `--refine`\n\n`rackstress run --refine` on the default (middle) "
            "spacing's run, as a user runs it: the scene again at spacing/√2, its governing "
            "stress read at the first run's zone. What it reports is the finer run's value, "
            "with Roache's band about it (docs/stress.md \"The error bar\"); Richardson's "
            "extrapolation sets the band's width.\n\n"
            + md_table(["case", "spacing [mm]", "refined at [mm]", "particles",
                        "headline [MPa]", "refined [MPa]", "read by", "refined / FEA",
                        "extrapolated [MPa]", "extrapolated / FEA", "band [MPa]",
                        "covers FEA"],
                       [[r["case"], fmt(r["spacing"]), fmt(r["refined"]["spacings"][-1], 3),
                         f"{r['refined']['particles'][-1]:,}", fmt(r.get("headline_MPa"), 4),
                         fmt(r["refined"]["value"], 4), r["refined"].get("read") or "—",
                         fmt(r["refined"]["ratio"], 3), fmt(r["refined"]["extrapolated"], 4),
                         fmt(r["refined"]["extrapolated_ratio"], 3),
                         f"{fmt(r['refined']['low'], 4)} … {fmt(r['refined']['high'], 4)}",
                         "yes" if r["refined"]["covers"] else "no"] for r in rows])
            + f"\nWithin {100 * TARGET['refined']:g} % of FEA after `--refine`: {len(ok)} of "
            f"{len(ref)}; the band covers FEA's value on {len(cover)} of {len(ref)}."
            + _unconverged(rows) + "\n")


def notch_summary(data: dict) -> str:
    """The notch reading's largest |headline / FEA − 1| over the rows it is the headline of,
    by how it was read: what :data:`rackstress.stress.governing.NOTCH_SUBMODEL_ERROR` (its
    submodel) and :data:`~rackstress.stress.governing.NOTCH_ERROR` (its fit) take."""
    out = []
    rows = [r for r in data["rows"] if fea_converged(r)]
    for by, name in (("submodel", "NOTCH_SUBMODEL_ERROR"), ("fit", "NOTCH_ERROR")):
        got = [(r["case"], r["spacing"], r["headline_ratio"]) for r in rows
               if r.get("headline_read") == "notch" and r.get("headline_ratio")
               and (r.get("notch_by") or "fit") == by]
        refined = [(r["case"], r["refined"]["spacings"][-1], r["refined"]["ratio"])
                   for r in rows if (r.get("refined") or {}).get("read") == "notch"
                   and (r["refined"].get("by") or "fit") == by]
        if not got and not refined:
            continue
        worst = max(got + refined, key=lambda g: abs(g[2] - 1))
        out.append(f"The notch reading by its {by} is the headline of {len(got)} of "
                   f"{len(rows)} rows and of {len(refined)} refined runs, "
                   f"{min(g[2] for g in got + refined):.3f} … "
                   f"{max(g[2] for g in got + refined):.3f} of FEA's governing stress; its "
                   f"largest error {abs(worst[2] - 1):.3f} ({worst[0]} at {worst[1]:.3g} mm), "
                   f"what `stress.governing.{name}` takes.")
    fits = [r for r in rows if r.get("notch_fit_ratio")
            and r.get("headline_read") == "notch"]
    if fits and any(r.get("notch_by") == "submodel" for r in fits):
        out.append("The fit of the particles beneath the same faces (what reads them where "
                   "gmsh is not installed) reads "
                   f"{min(r['notch_fit_ratio'] for r in fits):.3f} … "
                   f"{max(r['notch_fit_ratio'] for r in fits):.3f} of FEA's governing stress.")
    if not out:
        return "The notch reading is the headline of no row." + _unconverged(data["rows"])
    return " ".join(out) + _unconverged(data["rows"])

def table_rows(data) -> list:
    return [[r["case"], r["spacing"], r["ratio"]] for r in data["rows"]]
