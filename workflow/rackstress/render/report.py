"""``RUNDIR/report.html``: one page to explore a run in a browser.

The page holds, from ``summary.json``, ``scene.json``, ``stress.json`` and ``figures/``: the run's
facts (scene, engine, mode, status, iterations, t, particles, wall times of the run, the
post-processing and the pictures), the peak — where and when the design was most stressed —
and the table of peaks of every group and measure (the very numbers of ``summary.json``), the
Fig. 12-like sheet and the plots, the sheets of other measures rendered into ``figures/MEASURE``,
the scene's parameters and groups, the stability margin of Eq. 5 (the predicted largest stable
t against the t used), and links to the files to open elsewhere (``vtk/run.pvd`` for ParaView and
OVITO, ``stress.dump``, the trajectory, the movie).

It is self-contained as a folder: the images are the PNG files beside it (relative links into
``figures/``), and the 3D view of the peak frame is ``view3d.html`` beside it in an
``<iframe>`` (vtk.js inlined, :mod:`rackstress.render.view3d`); nothing comes from the network,
so it opens from the file system in any browser. Written atomically.
"""
from __future__ import annotations

import html
import json
import os
import time
from pathlib import Path

from rackstress.engines.dumpio import dump_path, final_name
from rackstress.errors import storage_error
from rackstress.lib.runfiles import REPORT, STABILITY, STRESS_JSON

FIGURES = "figures"
PLOTS = (("stress_over_time.png", "The measure per part over time (max solid, mean dashed; "
                                  "★ the peak)"),
         ("com_path.png", "Centre-of-mass paths"),
         ("footprints.png", "Footprints in the sediment"))
CSS = """
body{font-family:DejaVu Sans,Helvetica,Arial,sans-serif;margin:1.5em auto;max-width:1200px;
color:#222;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{font-size:1.25em;border-bottom:1px solid #ccc;
padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.5em 0;font-size:.92em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#f0f0f0}td.num{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:100%;height:auto;border:1px solid #ddd;margin:.3em 0}
.headline{font-size:1.15em;background:#fff3f0;border-left:4px solid #c00;padding:.6em 1em}
.note{color:#666;font-size:.9em}figure{margin:1em 0}figcaption{color:#555;font-size:.9em}
.ok{color:#060}.bad{color:#b00}
.banner{font-size:1.1em;padding:.6em 1em;margin:.8em 0;border-left:6px solid}
.banner.settled{background:#eef8ee;border-color:#080}
.banner.unsettled{background:#fde8e8;border-color:#c00;color:#900}
.withheld{color:#888;background:#f4f4f4;border-left-color:#aaa}
td.sum{font-weight:bold}
"""


def _e(x) -> str:
    return html.escape(str(x), quote=True)


def _warnings(w, warns: list) -> None:
    """The run's warnings as the report's ``#warnings`` list (nothing when there are none)."""
    if warns:
        w('<ul id="warnings">')
        for wr in warns:
            w(f'<li class="warning" data-kind="{_e(wr.get("kind", ""))}">Warning: '
              f"{_e(wr.get('message', ''))}</li>")
        w("</ul>")


def _num(v, digits: int = 4) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def local_is_reference(lc: dict | None) -> bool:
    """Whether the FE check's local refinement (``fea.json`` → ``governing.local``) is a
    reference: solved at two mesh sizes, ``moved`` given. A ball gmsh could only fill inside
    the file's own facets, ungraded, is not — no second mesh checks it (the SO-100 upper arm's
    read 1.29 MPa there, its global FE 0.97). The one rule the report, ``rackstress fea`` and
    ``bench parts`` apply.

    >>> local_is_reference({"moved": 0.01}), local_is_reference({"moved": None}), local_is_reference(None)
    (True, False, False)
    """
    return bool(lc) and lc.get("moved") is not None


def local_refinement(lc: dict, unit: str, length_digits: int = 4) -> str:
    """The FE check's local refinement (``fea.json`` → ``governing.local``) in one sentence,
    without its final stop: what ``rackstress fea`` prints and the report shows. A ball gmsh
    could only fill inside the file's own facets, ungraded (no second mesh: ``moved`` None),
    is said to be no refinement, its value given as what it is, not as the FE's answer (the
    round shoulder's read 58 MPa where the FE's governing stress is 11.3).

    >>> local_refinement({"radius": 2.0, "fine": 0.2, "value": 5.0, "position": [0, 0, 1],
    ...                   "moved": 0.01, "note": None}, "MPa")
    'refined locally (a ball of 2 about it, graded to 0.2): 5 MPa at [0, 0, 1]; it moved 1.0 % from twice that mesh size'
    >>> local_refinement({"radius": 2.0, "fine": None, "value": 58.0, "position": [0, 0, 1],
    ...                   "moved": None, "note": "not refined: gmsh could not remesh"}, "MPa")
    'not refined locally: gmsh could not remesh (the ball of 2, filled ungraded, read 58 MPa at [0, 0, 1]: no reference)'
    """
    if not local_is_reference(lc):
        why = str(lc.get("note") or "the ball could not be remeshed")
        why = why[len("not refined: "):] if why.startswith("not refined: ") else why
        return (f"not refined locally: {why} (the ball of {_num(lc['radius'], length_digits)}, "
                f"filled ungraded, read {_num(lc['value'])} {unit} at "
                f"{[round(x, 2) for x in lc['position']]}: no reference)")
    return (f"refined locally (a ball of {_num(lc['radius'], length_digits)} about it"
            + (f", graded to {_num(lc['fine'], length_digits)}" if lc.get("fine") else "")
            + f"): {_num(lc['value'])} {unit} at {[round(x, 2) for x in lc['position']]}"
            + (f"; it moved {100 * lc['moved']:.1f} % from twice that mesh size"
               if lc.get("moved") is not None else "")
            + (f"; {lc['note']}" if lc.get("note") else ""))


def _load(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}


def stability_margin(rundir: Path, scene: dict, summary: dict) -> dict | None:
    """Predicted stability limit of Eq. 5 for the run's scene (rebuilt from ``scene.json``), or
    the one ``summary.json`` already records; None when the scene cannot be rebuilt."""
    rec = summary.get("stability")
    if isinstance(rec, dict) and rec.get("t_max"):
        return rec
    cache = rundir / STABILITY
    try:
        rec = json.loads(cache.read_text())
        if rec.get("scene") == scene.get("scene") and rec.get("params") == scene.get("params") \
                and rec.get("dt") == scene.get("dt"):
            return rec
    except (OSError, json.JSONDecodeError, AttributeError):
        pass
    try:
        from rackstress import scenes
        from rackstress.model.stability import describe_limit, predict

        name, params = scene.get("scene"), scene.get("params") or {}
        if name not in scenes.BUILDERS:
            return None
        known = scenes.parameters(name)
        sc = scenes.build(name, **{k: v for k, v in params.items() if k in known})
        if scene.get("dt"):
            sc.dt = float(scene["dt"])
        sc.integrator = params.get("integrator", "euler")   # each integrator has its own limit
        pred = predict(sc)
        rec = {"t_max": pred["t_max"], "dt": sc.dt, "ratio": pred["ratio"],
               "set_by": describe_limit(pred), "scene": name, "params": params}
    except Exception:  # noqa: BLE001 - the report still shows everything else
        return None
    try:
        from rackstress.lib.jsonio import write_json

        write_json(cache, rec)              # computed once per run directory
    except OSError:
        pass
    return rec


def _phase_runs(phases, steps) -> list:
    """Each phase with its length, and how much of it ran when ``--steps`` cut the run short."""
    out, start, total = [], 0, sum(int(p["steps"]) for p in phases)
    for p in phases:
        n, label = int(p["steps"]), _e(p["name"])
        ran = n if steps is None or steps >= total else min(max(int(steps) - start, 0), n)
        if ran == n:
            out.append(f"{label} ({n} iterations)")
        elif ran == 0:
            out.append(f"{label} ({n} iterations, not reached: the run stopped at iteration "
                       f"{steps})")
        else:
            out.append(f"{label} ({ran} of its {n} iterations run: the run stopped at "
                       f"iteration {steps})")
        start += n
    return out


def fea_section(fea: dict) -> str:
    """The report's "Finite-element check" (``fea.json`` of ``rackstress fea``): the
    agreement of the particle measure with linear-elastic FEA of the same part."""
    ag = fea.get("agreement") or {}
    tg = fea.get("target") or {}
    ratio = ag.get("peak_ratio")
    rows = [("Spearman ρ", _num(ag.get("spearman")), f"≥ {tg.get('spearman', 0.8)}"),
            ("top-5 % overlap", _num(ag.get("top5_overlap")), f"≥ {tg.get('top5_overlap', 0.5)}"),
            ("peak ratio (away from singular points)",
             "pending (no stress measure)" if ratio is None else _num(ratio),
             f"1 ± {tg.get('peak_ratio_error', 0.15)}")]
    out = ['<h2 id="fea">Finite-element check</h2>',
           f"<p>Linear-elastic FEA of part <b>{_e(fea.get('group'))}</b> "
           f"({_e(fea.get('mesh'))}; {_e((fea.get('fe') or {}).get('tetrahedra'))} quadratic "
           f"tetrahedra; E = {_num((fea.get('material') or {}).get('E'))}, ν = "
           f"{_num((fea.get('material') or {}).get('nu'))}; supports and loads from "
           f"{_e(fea.get('boundary'))}) against the particle measure "
           f"<code>{_e(fea.get('measure'))}</code>.</p>",
           '<table id="fea-agreement"><thead><tr><th>figure</th><th>value</th><th>target</th>'
           "</tr></thead><tbody>"]
    out += [f'<tr><td>{_e(a)}</td><td class="num">{_e(b)}</td><td>{_e(c)}</td></tr>'
            for a, b, c in rows]
    out.append("</tbody></table>")
    fq = fea.get("fe_quality") or {}
    if fq.get("poor"):
        out.append(f'<p id="fea-poor" class="warn"><b>Poor FE mesh</b>: {_e(fq.get("why"))}.'
                   "</p>")
    if fea.get("compared"):
        out.append(f"<p>Compared: {_e(fea['compared'])}.</p>")
    gv, zone, unit = fea.get("governing") or {}, fea.get("zone") or {}, fea.get("stress_unit", "")
    if zone.get("rule"):
        src = ({"singular.npz": " (the run's singular points, singular.npz: the headline's "
                                "rule)",
                "fe surface": " (the FE surface's own edges, supports and loads: this run "
                              "recorded no singular.npz)"}.get(zone.get("source"), ""))
        out.append(f'<p id="fea-zone" data-source="{_e(zone.get("source", ""))}">Zone: '
                   f"{_e(zone['rule'])}{_e(src)}.</p>")
    if gv.get("value") is not None:
        moved = ("" if gv.get("moved") is None else
                 f"; it moved {100 * gv['moved']:.1f} % from FE size "
                 f"{_num((gv.get('coarser') or {}).get('size'))}")
        there = ("" if gv.get("ratio") is None else
                 f" The particles there: {_num(gv.get('particle_value'))} {_e(unit)} (ratio "
                 f"{_num(gv['ratio'])}); their own governing stress "
                 f"{_num(gv.get('particles_governing'))} {_e(unit)} (ratio "
                 f"{_num(gv.get('particles_governing_ratio'))}).")
        lc = gv.get("local")
        said = local_refinement(lc, unit) if lc else ""
        local = "" if not lc else " " + said[:1].upper() + said[1:] + "."
        out.append(f"<p>FE's governing stress: {_num(gv['value'])} {_e(unit)} at "
                   f"{_e([round(x, 2) for x in gv['position']])}{_e(moved)}.{_e(local)}"
                   f"{_e(there)}</p>")
    if fea.get("bands"):
        out.append('<table id="fea-bands"><thead><tr><th>spacings from a singular point</th>'
                   "<th>particles</th><th>Spearman ρ</th><th>peak ratio</th>"
                   "<th>median error</th></tr></thead><tbody>")
        out += [f"<tr><td>{_e(b['band'])}</td><td class=\"num\">{b['n']}</td>"
                f"<td class=\"num\">{_num(b['spearman'])}</td>"
                f"<td class=\"num\">{_num(b['peak_ratio'])}</td>"
                f"<td class=\"num\">{_num(b['median_error'])}</td></tr>" for b in fea["bands"]]
        out.append("</tbody></table>")
    if fea.get("note"):
        out.append(f"<p>{_e(fea['note'])}</p>")
    out.append(f'<figure><img src="{FIGURES}/fea.png" alt="particles and FEA side by side">'
               "<figcaption>The particle measure (left) and FEA's von Mises stress (right) "
               "at the particles, on one colour scale; <code>vtk/fea.vtp</code> holds both as point arrays "
               "(<code>fea_von_mises</code>, <code>fea_displacement</code>)</figcaption>"
               "</figure>")
    return "\n".join(out)


def _pos(rec: dict) -> str:
    pos = ", ".join(f"{x:.4g}" for x in rec.get("position", []))
    return f"particle {rec['particle']} at ({_e(pos)})" + (
        f", {_e(rec['near'])}" if rec.get("near") else "")


def governing_section(stress: dict, headline: bool = True) -> str:
    """The headline of a part with a material: the governing stress (away from singular
    points) with its factor of safety and zone (``headline`` False: said already, by a static
    report's headline), the singular peak beside it (spacing-dependent, with advice), and the
    error bar: ``--refine``'s small table, or a single run's estimate. Empty when ``stress``
    (``summary.json["stress"]``) has no governing stress."""
    gov = stress.get("governing")
    if not gov:
        return ""
    out = []
    w = out.append
    sf = (f", factor of safety against yield <b>{_num(gov['safety'], 3)}</b>"
          if gov.get("safety") else "")
    if headline:
        w(f'<p class="headline" id="headline" data-governing="{gov["value"]!r}">The governing '
          f"von Mises stress is <b>{_num(gov['value'])}</b> {_e(gov['units'])} in "
          f"<b>{_e(gov['group'])}</b>{sf}: {_pos(gov)}, iteration {gov['iteration']}.</p>")
        w(f'<p class="note" id="rule">The governing stress is {_e(gov["rule"])} '
          "(docs/stress.md).</p>")
        if gov.get("read") == "notch":
            nk = gov["notch"]
            from rackstress.stress.governing import notch_how

            w(f'<p class="note" id="notch" data-by="{_e(nk.get("by", "fit"))}">Read on a '
              f"concave curved face of radius {_num(nk['radius'], 3)} "
              f"{_e(gov.get('length_units', ''))} {_e(notch_how(nk))} (docs/stress.md \"The "
              f"notch reading\"); the patch fit of the particles reads "
              f"{_num(gov['patch_value'])} {_e(gov['units'])}.</p>")
    if gov.get("zone_edge"):
        from rackstress.stress.governing import zone_edge_sentence

        t = zone_edge_sentence(gov)
        w(f'<p class="note" id="zone-edge">{_e(t[0].upper() + t[1:])}.</p>')
    sing = stress.get("singular")
    if sing:
        from rackstress.stress.governing import SINGULAR_SAID, a_kind

        said = SINGULAR_SAID.get(sing["kind"], SINGULAR_SAID[None])
        w(f'<p class="singular" id="singular" data-kind="{_e(sing["kind"])}">Singular peak: '
          f"<b>{_num(sing['value'])}</b> {_e(sing['units'])} at {_e(a_kind(sing['kind']))}, "
          f"{_pos(sing)} — <b>{_e(said[0])}</b>{_e(said[1])}: {_e(sing['advice'])}.</p>")
    err = stress.get("error")
    if err and err.get("extrapolated") is not None:
        u = _e(err.get("units", gov["units"]))
        rows = [(f"{h:.4g}", f"{n:,}" if n else "–", _num(v))
                for h, v, n in zip(err["spacings"], err["values"],
                                   err.get("particles") or [None] * len(err["values"]))]
        w('<table id="error-bar"><thead><tr><th>spacing</th><th>particles</th>'
          f"<th>governing [{u}]</th></tr></thead><tbody>")
        for r in rows:
            w("<tr>" + "".join(f"<td class=num>{c}</td>" for c in r) + "</tr>")
        w(f"<tr><td>extrapolated (order {_num(err['order'], 2)}), sets the band</td><td></td>"
          f"<td class=num>{_num(err['extrapolated'])}</td></tr>")
        w(f'<tr id="refined"><td><b>refined: the finer run\'s value</b></td><td></td>'
          f"<td class=num><b>{_num(err['values'][-1])}</b></td></tr>")
        w(f"<tr><td>converged value within</td><td></td><td class=num>{_num(err['low'])} … "
          f"{_num(err['high'])}</td></tr></tbody></table>")
        w(f'<p class="note">{_e(err["method"])}. The refined run is in '
          f"<code>{_e(err.get('refine_dir', 'refine'))}/</code>.</p>")
        if err.get("converging") is False:
            w(f'<p class="warning" id="not-converged">Not converged: the governing stress moved '
              f"by {_num(100 * err['change'], 2)} % between the two spacings; refine further, "
              "or check it by FE (<code>rackstress fea</code>).</p>")
        from rackstress.stress.governing import first_point_sentence

        fp = first_point_sentence(err.get("governing_fine"), err.get("units", gov["units"]))
        if fp:
            w(f'<p class="note" id="first-point">{_e(fp[0].upper() + fp[1:])}.</p>')
        if err.get("fine_own"):
            from rackstress.stress.governing import fine_alone_sentence

            t = fine_alone_sentence(err["fine_own"], err.get("units", gov["units"]),
                                    gov.get("length_units", ""))
            w(f'<p class="warning" id="fine-alone">{_e(t[0].upper() + t[1:])}.</p>')
    elif err:
        w(f'<p class="note" id="error-estimate">Error bar: ± '
          f"{_num(100 * abs(err['relative']), 2)} %, {_num(err.get('low'))} … "
          f"{_num(err.get('high'))} {_e(gov['units'])} ({_e(err['method'])}).</p>")
    off = stress.get("offsets")
    if off and off.get("values"):
        from rackstress.stress.offsets import offsets_sentence

        u = _e(off.get("units") or gov["units"])
        w('<table id="offsets"><thead><tr><th>lattice moved by [spacings]</th><th>particles'
          f"</th><th>governing [{u}]</th><th>run</th></tr></thead><tbody>")
        for r in off["rows"]:
            v = (_num(r["value"]) if r["value"] is not None else
                 "refused by the part check" if r.get("refused") else
                 "every particle within the zone" if r.get("unread") else "did not settle")
            w("<tr>" + "".join(f"<td class=num>{c}</td>" for c in (
                ", ".join(f"{x:.3f}" for x in r["offset"]), f"{r['particles']:,}", v))
              + f"<td><code>{_e(r['dir'])}</code></td></tr>")
        w("</tbody></table>")
        t = offsets_sentence(off)
        w(f'<p class="note" id="offsets-spread">{_e(t[0].upper() + t[1:])}.</p>')
    return "\n".join(out)


def write_report(rundir, stability: bool = True, view: bool = True,
                 built_view: dict | None = None, allow_unsettled: bool | None = None) -> Path:
    """Write ``RUNDIR/report.html`` from what the run directory holds; return its path.

    ``view``: also write ``RUNDIR/view3d.html``, the peak frame in 3D, and embed it
    (:mod:`rackstress.render.view3d`); ``built_view``: it was built already
    (:func:`rackstress.render.view3d.section`'s ``built``). A static run's page is its own
    (:func:`_static_body`); ``allow_unsettled``: show the headline of one that did not settle
    (recorded in ``summary.json``'s ``render``; None: as recorded, else withheld).

    Example
    -------
    >>> write_report("runs/plane-rack")          # doctest: +SKIP
    PosixPath('runs/plane-rack/report.html')
    """
    rundir = Path(rundir)
    summary = _load(rundir / "summary.json")
    scene = _load(rundir / "scene.json")
    post = _load(rundir / STRESS_JSON)
    render = _load(rundir / FIGURES / "render.json")
    name = summary.get("scene") or scene.get("scene") or rundir.name
    out = []
    w = out.append
    w("<!DOCTYPE html>")
    w('<html lang="en"><head><meta charset="utf-8">')
    w(f"<title>rackstress report: {_e(name)}</title><style>{CSS}</style></head><body>")
    static = summary.get("analysis") == "static" or scene.get("analysis") == "static"
    w(f"<h1>{_e(name)}: " + ("static analysis" if static else "run report") + "</h1>")
    w(f'<p class="note">{_e(rundir.resolve())} — written {_e(time.strftime("%Y-%m-%d %H:%M:%S"))}'
      "</p>")

    if static:
        _static_body(w, rundir, summary, scene, post, render, name, view, built_view,
                     allow_unsettled)
    else:
        _dynamic_body(w, rundir, summary, scene, post, render, name, stability, view,
                      built_view)

    # ---- files
    w('<h2 id="files">Files to open elsewhere</h2><ul>')
    if (rundir / "vtk" / "surface.vtp").is_file():
        w('<li><a href="vtk/surface.vtp">vtk/surface.vtp</a> — the part\'s surface, undeformed, '
          "with the values carried onto it from the particles (point data named as theirs: "
          "von_mises, displacement, strain; group_id); in ParaView, Warp By Vector on "
          "displacement draws it deformed</li>")
    links = [("vtk/run.pvd", "VTK time series: open in ParaView or pyvista (point data: "
                             "group_id and group_NAME, type, radius, displacement, every "
                             "measure; time = iteration; for OVITO: rackstress stress RUNDIR "
                             "--vtk-format ovito)"),
             ("stress.dump", "LAMMPS dump with the measures as named columns (OVITO)"),
             ("summary.json", "the run's summary, peaks included"),
             ("stress.json", "the post-processing record"),
             (final_name(rundir), "the trajectory (dump custom id type mol x y z, gzip once "
                                  "the run has finished; with a resting sediment the "
                                  "particles that moved, the others as in particles.data)"),
             ("particles.data", "LAMMPS data file (original positions)"),
             ("in.lammps", "the LAMMPS input deck"),
             (f"{FIGURES}/render.json", "what the pictures show")]
    for rel, what in links:
        if (rundir / rel).is_file() or rel == final_name(rundir) != dump_path(rundir).name:
            w(f'<li><a href="{_e(rel)}">{_e(rel)}</a> — {_e(what)}</li>')
    w("</ul></body></html>")
    path = rundir / REPORT
    tmp = rundir / f".{REPORT}.tmp{os.getpid()}"
    try:
        tmp.write_text("\n".join(out) + "\n", encoding="utf-8")
        os.replace(tmp, path)
    except OSError as exc:          # a full disk: no half report left
        tmp.unlink(missing_ok=True)
        raise storage_error(exc, "write", path) from None
    return path


def _dynamic_body(w, rundir: Path, summary: dict, scene: dict, post: dict, render: dict,
                  name: str, stability: bool, view: bool, built_view) -> None:
    """A dynamic run's sections: the peak over the run, the peak frame in 3D, the pictures
    and plots over time, the run's facts, the scene, the stability margin of Eq. 5."""
    # ---- the governing stress, the headline (docs/stress.md), else the peak in one sentence
    peak = (summary.get("stress") or {}).get("peak") or post.get("peak")
    w('<h2 id="peak">Where and when it was most stressed</h2>')
    gov_html = governing_section(summary.get("stress") or {})
    if gov_html:
        w(gov_html)
    elif peak:
        pos = ", ".join(f"{x:.4g}" for x in peak.get("position", []))
        what = ("The largest von Mises stress (from the bindings' forces, docs/stress.md)"
                if peak.get("measure") == "von_mises" else
                "The largest distance from the desired position (the paper's measure, robust "
                "fit)")
        w(f'<p class="headline" id="headline">{what} is <b>{_num(peak["value"])}</b> '
          f"{_e(peak['units'])} in <b>{_e(peak['group'])}</b> at <b>iteration "
          f"{peak['iteration']}</b>, particle {peak['particle']} (atom id) at ({_e(pos)}).</p>")
    else:
        w('<p class="headline">No peaks yet: run <code>rackstress stress '
          f"{_e(rundir)}</code>.</p>")
    for gname, sf in ((summary.get("stress") or {}).get("safety") or {}).items():
        if sf.get("rule") == "governing":
            continue                            # said with the governing stress
        w(f'<p class="safety" data-group="{_e(gname)}">Smallest factor of safety of '
          f"<b>{_e(gname)}</b> (yield / von Mises): <b>{_num(sf['min'])}</b> at iteration "
          f"{sf['iteration']}, particle {sf['particle']}.</p>")
    warns = summary.get("warnings") or []
    _warnings(w, warns)
    groups = summary.get("groups") or {}
    rows = [(g, m, rec) for g, grec in groups.items()
            for m, rec in ((grec or {}).get("peak") or {}).items()]
    if rows:
        w('<table id="peaks"><thead><tr><th>group</th><th>measure</th><th>peak</th>'
          "<th>units</th><th>iteration</th><th>particle</th><th>position (x, y, z)</th>"
          "</tr></thead><tbody>")
        for g, m, rec in rows:
            if rec is None:
                w(f'<tr data-group="{_e(g)}" data-measure="{_e(m)}"><td>{_e(g)}</td>'
                  f"<td>{_e(m)}</td><td colspan=5>undefined</td></tr>")
                continue
            pos = ", ".join(f"{x:.4g}" for x in rec.get("position", []))
            w(f'<tr data-group="{_e(g)}" data-measure="{_e(m)}" data-value="{rec["value"]!r}" '
              f'data-iteration="{rec["iteration"]}" data-particle="{rec["particle"]}">'
              f"<td>{_e(g)}</td><td>{_e(m)}</td><td class=num>{_num(rec['value'], 6)}</td>"
              f"<td>{_e(rec.get('units', ''))}</td><td class=num>{rec['iteration']}</td>"
              f"<td class=num>{rec['particle']}</td><td>{_e(pos)}</td></tr>")
        w("</tbody></table>")
        w('<p class="note">The same numbers as <code>summary.json</code> '
          "(<code>groups.NAME.peak.MEASURE</code>), the pictures' colour scale and the VTK files' "
          "point data. paper: distance from the desired position; accumulated: its time "
          "integral; strain: von Mises shear strain; d2min: non-affine D²min; von_mises: von "
          "Mises stress from the bindings' forces per particle volume.</p>")

    # ---- the peak frame in 3D
    if view:
        from rackstress.render.view3d import section

        w(section(rundir, built_view))

    # ---- pictures
    w('<h2 id="pictures">Pictures</h2>')
    fig = rundir / FIGURES
    if (fig / "sheet.png").is_file():
        frames = ", ".join(str(f["iteration"]) + (" (peak)" if f.get("peak") else "")
                           for f in render.get("frames", []))
        w(f'<figure><img src="{FIGURES}/sheet.png" alt="stress pictures, one row per view">'
          f"<figcaption>{_e(render.get('label', ''))}; iterations {_e(frames)}; colour scale "
          f"0..{_num(render.get('vmax'))}</figcaption></figure>")
        for note in render.get("notes", []):
            w(f'<p class="note">{_e(note)}</p>')
    else:
        w(f'<p class="note">No pictures: run <code>rackstress render {_e(rundir)}</code>.</p>')
    for fname, caption in PLOTS:
        if (fig / fname).is_file():
            w(f'<figure><img src="{FIGURES}/{fname}" alt="{_e(caption)}">'
              f"<figcaption>{_e(caption)}</figcaption></figure>")
    others = sorted(p for p in fig.glob("*/sheet.png")) if fig.is_dir() else []
    for p in others:
        rel = p.relative_to(rundir).as_posix()
        w(f'<figure><img src="{_e(rel)}" alt="sheet of {_e(p.parent.name)}">'
          f"<figcaption>measure {_e(p.parent.name)}</figcaption></figure>")
    if (fig / "movie.mp4").is_file():
        w(f'<p><a href="{FIGURES}/movie.mp4">movie.mp4</a> (every frame, '
          f"{_e(render.get('movie_view') or '')} view)</p>")

    # ---- the finite-element check (rackstress fea RUNDIR)
    fea = _load(rundir / "fea.json")
    if fea:
        w(fea_section(fea))

    # ---- run facts
    w('<h2 id="facts">The run</h2><table id="run-facts"><tbody>')
    timings = post.get("timings") or {}
    rtime = (summary.get("render") or {}).get("wall_s")
    facts = [("scene", name), ("status", summary.get("status")),
             ("engine", summary.get("engine")), ("mode", summary.get("mode")),
             ("iterations", summary.get("steps")), ("time step t", summary.get("dt")),
             ("particles", summary.get("n_particles")),
             ("frames dumped", post.get("frames")),
             ("run wall time [s]", _num(summary.get("wall_s"), 3)),
             ("stress post-processing [s]", _num(timings.get("total_s"), 3)),
             ("pictures [s]", _num(rtime, 3))]
    if summary.get("analysis") == "static":      # the equilibrium and how well it holds
        facts += [("analysis", "static"), ("settled", "yes" if summary.get("settled") else
                                           "NO: not an equilibrium"),
                  ("Newton iterations", summary.get("iterations")),
                  ("residual (largest unbalanced force / applied load)",
                   _num(summary.get("residual"), 3)),
                  ("settled below", summary.get("tolerance"))]
    if summary.get("units"):
        facts.append(("units", summary["units"]))
    if summary.get("error"):
        facts.append(("error", summary["error"].get("message")))
    for k, v in facts:
        if v is not None:
            w(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>")
    w("</tbody></table>")
    cycles = (summary.get("report") or {}).get("cycles")
    if cycles:
        keys = [k for k in cycles[0] if isinstance(cycles[0][k], (int, float, str))]
        w('<table id="cycles"><thead><tr>' + "".join(f"<th>{_e(k)}</th>" for k in keys)
          + "</tr></thead><tbody>")
        for c in cycles:
            w("<tr>" + "".join(f"<td class=num>{_e(_num(c.get(k)))}</td>" for k in keys) + "</tr>")
        w("</tbody></table>")

    # ---- scene
    w('<h2 id="scene">Scene and parameters</h2><table id="params"><tbody>')
    for k, v in (summary.get("params") or scene.get("params") or {}).items():
        w(f"<tr><th>{_e(k)}</th><td>{_e(json.dumps(v))}</td></tr>")
    w("</tbody></table>")
    if scene.get("groups"):
        w('<table id="groups"><thead><tr><th>group</th><th>kind</th><th>host</th><th>n</th>'
          "<th>type</th><th>molecule</th><th>max. deformation at the end</th></tr></thead><tbody>")
        for g in scene["groups"]:
            md = (groups.get(g["name"]) or {}).get("max_deformation")
            w(f"<tr><td>{_e(g['name'])}</td><td>{_e(g.get('kind'))}</td>"
              f"<td>{_e(g.get('host') or '')}</td><td class=num>{g.get('n')}</td>"
              f"<td class=num>{g.get('type')}</td><td class=num>{g.get('mol')}</td>"
              f"<td class=num>{_num(md)}</td></tr>")
        w("</tbody></table>")
    if scene.get("phases"):
        w("<p>Phases: " + "; ".join(_phase_runs(scene["phases"], summary.get("steps")))
          + "</p>")

    # ---- stability
    w('<h2 id="stability">Stability margin (Eq. 5)</h2>')
    st = stability_margin(rundir, scene, summary) if stability else None
    if st:
        ok = st["ratio"] <= 1.0
        w(f'<p id="stability-margin">Predicted largest stable time step t<sub>max</sub> = '
          f"{_num(st['t_max'])}; this run used t = {_num(st['dt'])}: "
          f'<span class="{"ok" if ok else "bad"}">{_num(1.0 / st["ratio"] if st["ratio"] else None, 3)}'
          f"× margin</span> ({'within' if ok else 'beyond'} the limit). "
          f"{_e(st.get('set_by', ''))}</p>")
    else:
        w('<p class="note">Not available for this scene.</p>')


def _vec(v, digits: int = 4, scale: float | None = None) -> list:
    """Table cells of a vector; below ``scale`` (the settle tolerance × the load's size) a
    value is what the solve leaves, shown as 0 (the exact value in the cell's title and the
    row's data-*)."""
    out = []
    for x in v:
        x = float(x)
        if scale and abs(x) < scale:
            out.append(f'<td class="num" title="{x!r}">0</td>')
        else:
            out.append(f'<td class="num">{_num(x, digits)}</td>')
    return out


def _static_body(w, rundir: Path, summary: dict, scene: dict, post: dict, render: dict,
                 name: str, view: bool, built_view, allow_unsettled: bool | None) -> None:
    """A static analysis's sections, as an FE post-processor's report reads: settled or NOT
    SETTLED first; the headline stress (governing, else the peak) with the factor of safety of
    the same rule, where in the part's own coordinates; the support reactions against the
    applied load; the part in 3D and its pictures (the surface, deformed, and the particles);
    the largest values per part; the solve's facts. Nothing over time."""
    from rackstress.stress.headline import headline, unsettled_advice

    settled = summary.get("settled", True) is not False
    rec = summary.get("render") or {}
    if allow_unsettled is None:
        allow_unsettled = bool(rec.get("allow_unsettled"))
    elif (rundir / "summary.json").is_file():       # kept for the next report of this run
        from rackstress.lib.jsonio import write_json

        summary.setdefault("render", {})["allow_unsettled"] = bool(allow_unsettled)
        write_json(rundir / "summary.json", summary)
    tol = summary.get("tolerance")
    if settled:
        w(f'<div class="banner settled" id="status" data-status="settled"><b>Settled</b>: an '
          f"equilibrium, the largest unbalanced force {_num(summary.get('residual'), 2)} of the "
          f"applied load (at most {_e(tol)}) after {_e(summary.get('iterations'))} Newton "
          "steps.</div>")
    else:
        w(f'<div class="banner unsettled" id="status" data-status="not settled"><b>NOT SETTLED '
          f"— do not use these numbers.</b> The largest unbalanced force is "
          f"{_num(summary.get('residual'), 3)} of the applied load after "
          f"{_e(summary.get('iterations'))} Newton steps (settled means at most {_e(tol)}): "
          "the state below is not an equilibrium, and its stresses, displacements and "
          f"reactions are not the part's. What to do: {_e(unsettled_advice(summary))}.</div>")

    # ---- the headline
    w('<h2 id="peak">Result</h2>')
    head = headline(summary, scene, rundir)
    if head is None:
        w('<p class="headline" id="headline">No stress yet: run <code>rackstress stress '
          f"{_e(rundir)}</code>.</p>")
    elif not settled and not allow_unsettled:
        w('<p class="headline withheld" id="headline" data-withheld="true">No stress or factor '
          "of safety is shown: the state is not an equilibrium. <code>rackstress render "
          f"{_e(rundir)} --allow-unsettled</code> shows them here, marked as such "
          "(<code>summary.json</code> keeps them).</p>")
    else:
        rule = head.get("rule") or ""
        cls = "headline" if settled else "headline withheld"
        pos = ", ".join(f"{x:.4g}" for x in head.get("position") or [])
        w(f'<p class="{cls}" id="headline" data-kind="{_e(head["kind"])}" '
          f'data-value="{head["value"]!r}" data-particle="{_e(head["particle"])}" '
          f'data-safety="{head["safety"]!r}" data-position="{_e(pos)}">'
          + ("" if settled else "<b>Not an equilibrium (shown on request):</b> ")
          + ("Governing von Mises stress" if head["kind"] == "governing" else
             "Largest von Mises stress" if head.get("measure") == "von_mises" else
             f"Largest {_e(head.get('measure'))}")
          + f" <b>{_num(head['value'])} {_e(head.get('units', ''))}</b> in "
          f"<b>{_e(head['group'])}</b> at ({_e(pos)}) in the part's own undeformed coordinates"
          + (f", near <b>{_e(head['near'])}</b>" if head.get("near") else "")
          + f", particle {_e(head['particle'])}"
          + (f"; smallest factor of safety <b>{_num(head['safety'], 3)}</b> (yield / that "
             "stress)" if head.get("safety") else "")
          + ".</p>")
        if rule:
            w(f'<p class="note" id="headline-rule">{_e(rule[0].upper() + rule[1:])}.</p>')
        if settled and head["kind"] == "governing":     # the singular peak, the error bar
            w(governing_section(summary.get("stress") or {}, headline=False))
    for gname, g in (summary.get("groups") or {}).items():
        md, at = g.get("max_deformation"), g.get("max_deformation_at")
        if md is None or at is None:
            continue
        unit = (scene.get("units") or {}).get("length", "")
        pos = ", ".join(f"{x:.4g}" for x in at)
        w(f'<p class="displacement" data-group="{_e(gname)}" data-value="{md!r}" '
          f'data-particle="{_e(g.get("max_deformation_particle"))}" data-position="{_e(pos)}">'
          f"Largest displacement of <b>{_e(gname)}</b>: <b>{_num(md)} {_e(unit)}</b>, particle "
          f"{_e(g.get('max_deformation_particle'))} at ({_e(pos)}).</p>")
    warns = [wr for wr in summary.get("warnings") or []       # no stress of a non-equilibrium
             if settled or allow_unsettled or wr.get("kind") not in ("large_strain",
                                                                     "yield_exceeded")]
    _warnings(w, warns)

    # ---- the reactions
    _reactions(w, summary, scene, settled)

    # ---- the part in 3D and its pictures
    if view:
        from rackstress.render.view3d import section

        w(section(rundir, built_view))
    w('<h2 id="pictures">Pictures</h2>')
    fig = rundir / FIGURES
    if (fig / "sheet.png").is_file() and render.get("static"):
        mag = render.get("magnification")
        mag = 1 if mag is None else mag
        unit = render.get("length_unit", "")
        src = ", ".join(f"{s['group']}: {s['source']}" for s in render.get("surfaces", []))
        w(f'<figure id="surface-picture" data-magnification="{mag:g}"><img src="{FIGURES}/'
          'sheet.png" alt="the part\'s surface, deformed, coloured by the stress">'
          f"<figcaption>{_e(render.get('label', ''))} on the part's surface ({_e(src)}), "
          f"colour scale 0..{_num(render.get('vmax'))}; "
          + (f"displacements × {mag:g} (the largest, "
             f"{_num(render.get('max_displacement'), 3)} {_e(unit)}, drawn as "
             f"{_num(mag * (render.get('max_displacement') or 0), 3)} {_e(unit)})"
             if mag > 1 else "displacements to scale" if mag == 1 else
             "drawn undeformed: the displacements exceed the part's size")
          + "; dark outline: the undeformed shape; ring: the headline's point. The surface's "
          "values are fitted to the nearest particles (linear, docs/picture.md).</figcaption>"
          "</figure>")
        if (fig / "particles.png").is_file():
            w(f'<figure id="particles-picture"><img src="{FIGURES}/particles.png" '
              'alt="the particles, coloured by the stress"><figcaption>The particles the '
              "surface was fitted to, each coloured by its own value, at the same "
              "magnification.</figcaption></figure>")
        for note in render.get("notes", []):
            w(f'<p class="note">{_e(note)}</p>')
    else:
        w(f'<p class="note">No pictures: run <code>rackstress render {_e(rundir)}</code>.</p>')

    # ---- the largest values per part (no measure of motion: a static run has none)
    rows = [(g, m, r) for g, grec in (summary.get("groups") or {}).items()
            for m, r in ((grec or {}).get("peak") or {}).items()
            if m not in ("paper", "accumulated")]
    if rows and (settled or allow_unsettled):
        w('<table id="peaks"><thead><tr><th>group</th><th>measure</th><th>largest</th>'
          "<th>units</th><th>particle</th><th>position (undeformed)</th></tr></thead><tbody>")
        for g, m, r in rows:
            if r is None:
                w(f'<tr data-group="{_e(g)}" data-measure="{_e(m)}"><td>{_e(g)}</td>'
                  f"<td>{_e(m)}</td><td colspan=4>undefined</td></tr>")
                continue
            pos = ", ".join(f"{x:.4g}" for x in r.get("original") or r.get("position", []))
            w(f'<tr data-group="{_e(g)}" data-measure="{_e(m)}" data-value="{r["value"]!r}" '
              f'data-particle="{r["particle"]}" data-position="{_e(pos)}"><td>{_e(g)}</td>'
              f"<td>{_e(m)}</td><td class=num>{_num(r['value'], 6)}</td>"
              f"<td>{_e(r.get('units', ''))}</td><td class=num>{r['particle']}</td>"
              f"<td>{_e(pos)}</td></tr>")
        w("</tbody></table>")
        w('<p class="note">The same numbers as <code>summary.json</code> '
          "(<code>groups.NAME.peak.MEASURE</code>) and the particles' point data in "
          "<code>vtk/run.pvd</code>. von_mises: von Mises stress from the bindings' forces per "
          "particle volume; strain: von Mises shear strain; d2min: non-affine D²min.</p>")

    # ---- the finite-element check
    fea = _load(rundir / "fea.json")
    if fea:
        w(fea_section(fea))

    # ---- the solve
    timings = post.get("timings") or {}
    facts = [("scene", name), ("analysis", "static"), ("status", summary.get("status")),
             ("Newton iterations", summary.get("iterations")),
             ("residual (largest unbalanced force / applied load)",
              _num(summary.get("residual"), 3)),
             ("settled below", summary.get("tolerance")),
             ("engine", summary.get("engine")), ("particles", summary.get("n_particles")),
             ("ranks", summary.get("ranks")),
             ("solve wall time [s]", _num(summary.get("solve_s"), 3)),
             ("run wall time [s]", _num(summary.get("wall_s"), 3)),
             ("stress post-processing [s]", _num(timings.get("total_s"), 3)),
             ("pictures [s]", _num((summary.get("render") or {}).get("wall_s"), 3)),
             ("units", summary.get("units"))]
    if summary.get("error"):
        facts.append(("error", summary["error"].get("message")))
    w('<h2 id="facts">The solve</h2><table id="run-facts"><tbody>')
    for k, v in facts:
        if v is not None:
            w(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>")
    w("</tbody></table>")
    w('<h2 id="scene">Scene and parameters</h2><table id="params"><tbody>')
    for k, v in (summary.get("params") or scene.get("params") or {}).items():
        w(f"<tr><th>{_e(k)}</th><td>{_e(json.dumps(v))}</td></tr>")
    w("</tbody></table>")
    if scene.get("groups"):
        unit = (scene.get("units") or {}).get("length", "")
        w('<table id="groups"><thead><tr><th>group</th><th>kind</th><th>n</th><th>material</th>'
          f"<th>largest displacement [{_e(unit)}]</th></tr></thead><tbody>")
        for g in scene["groups"]:
            md = ((summary.get("groups") or {}).get(g["name"]) or {}).get("max_deformation")
            w(f"<tr><td>{_e(g['name'])}</td><td>{_e(g.get('kind'))}</td>"
              f"<td class=num>{g.get('n')}</td>"
              f"<td>{_e((g.get('material') or {}).get('name', ''))}</td>"
              f"<td class=num>{_num(md)}</td></tr>")
        w("</tbody></table>")


def _reactions(w, summary: dict, scene: dict, settled: bool) -> None:
    """The support reactions per support, their sum and the applied load (force and moment
    about the origin), and how far they are from balancing: an engineer's first check."""
    reactions, applied = summary.get("reactions"), summary.get("applied_load")
    w('<h2 id="reactions">Support reactions</h2>')
    if not reactions or not applied:
        w('<p class="note">No reactions recorded for this run (a run made before they were '
          "recorded: run it again).</p>")
        return
    u = scene.get("units") or {}
    fu, lu = u.get("force", "force units"), u.get("length", "length units")
    w('<table id="reaction-table"><thead><tr><th>support</th><th>part</th><th>particles</th>'
      f"<th>F<sub>x</sub> [{_e(fu)}]</th><th>F<sub>y</sub></th><th>F<sub>z</sub></th>"
      f"<th>M<sub>x</sub> [{_e(fu)}·{_e(lu)}]</th><th>M<sub>y</sub></th><th>M<sub>z</sub></th>"
      "</tr></thead><tbody>")
    import math

    F = [sum(r["force"][k] for r in reactions) for k in range(3)]
    M = [sum(r["moment"][k] for r in reactions) for k in range(3)]
    tol = float(summary.get("tolerance") or 1e-6) if settled else 0.0
    fs = tol * max(math.sqrt(sum(x * x for x in F)),
                   math.sqrt(sum(x * x for x in applied["force"])))
    ms = tol * max(math.sqrt(sum(x * x for x in M)),
                   math.sqrt(sum(x * x for x in applied["moment"])))
    for r in reactions:
        w(f'<tr class="reaction" data-support="{_e(r["support"])}" '
          f'data-force="{_e(json.dumps(r["force"]))}" data-moment="{_e(json.dumps(r["moment"]))}">'
          f"<td>{_e(r['support'])}</td><td>{_e(r.get('group', ''))}</td>"
          f"<td class=num>{_e(r.get('particles', ''))}</td>"
          + "".join(_vec(r["force"], scale=fs) + _vec(r["moment"], scale=ms)) + "</tr>")
    w('<tr id="reaction-sum"><td class="sum">sum of the reactions</td><td></td><td></td>'
      + "".join(_vec(F, scale=fs) + _vec(M, scale=ms)) + "</tr>")
    w('<tr id="applied-load"><td class="sum">applied load</td><td></td><td></td>'
      + "".join(_vec(applied["force"], scale=fs) + _vec(applied["moment"], scale=ms))
      + "</tr>")
    dF = [a + b for a, b in zip(F, applied["force"])]
    dM = [a + b for a, b in zip(M, applied["moment"])]
    w('<tr id="reaction-balance"><td class="sum">reactions + load (0 at equilibrium)</td>'
      "<td></td><td></td>" + "".join(_vec(dF, 2) + _vec(dM, 2)) + "</tr>")
    w("</tbody></table>")
    nF = math.sqrt(sum(x * x for x in applied["force"]))
    off = math.sqrt(sum(x * x for x in dF)) / nF if nF > 0 else None
    w('<p class="note" id="reaction-note">Each reaction is what its support pushes on the '
      "particles it holds (minus the net force of the bindings and loads there), moments "
      "about the origin at the deformed positions; the sum balances the applied load up to "
      "the unbalanced forces left on the free particles"
      + (f" (here {_num(off, 2)} of the load)" if off is not None else "")
      + ("." if settled else ": this run did not settle, so they do not balance it.")
      + "</p>")

