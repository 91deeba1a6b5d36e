"""``rackstress bench parts``: every real part of ``examples/parts/`` through the static path.

Each part (a folder with its STL, ``scene.toml`` and ``SOURCE.md``) is loaded as its scene
says — supports and loads by hole and face names, the spacing chosen from its walls within
the particle budget unless the scene gives one — solved to equilibrium on LAMMPS, its stress
measured, and checked against finite elements (``rackstress fea``; ``--no-fea`` skips it).
One row a part: particles, spacing and how it was chosen, Newton steps, residual, solve time
(the solver's wall time, and the CPU time of the whole run), the peak von Mises stress (the
governing stress where the run has one), settled or not, the FE agreement. A part the
static path refuses (exit 2: a mesh it cannot fill) or that does not settle (exit 6) is a row
too, with its reason: nothing is left out. With ``--refine`` each run is ``rackstress run
SCENE --refine`` (the part again at spacing/√2, its governing stress's error bar), and the page
gives the refined governing stress and its bar beside the FE check's (docs/stress.md "The
error bar").

Writes ``docs/benchmarks/parts.json`` and ``parts.md``.
"""
from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from rackstress.bench import fmt, machine, md_table, out_dir, repository_file, write_json
from rackstress.lib.resources import cpu_children
from rackstress.lib.tet import POOR_SLIVERS, SLIVER_Q
from rackstress.render.report import local_is_reference

HEADER = ["part", "particles", "spacing [mm]", "Newton steps", "residual", "solve [s]",
          "run CPU [s]", "peak [MPa]", "settled", "FE slivers", "FE ρ", "FE peak ratio",
          "FE CPU [s]", "FE memory [GB]", "status"]


def parts_dir() -> Path:
    return repository_file("examples", "parts")


def part_names(only=None, corpus: Path | None = None) -> list:
    names = sorted(p.name for p in (corpus or parts_dir()).iterdir()
                   if (p / "scene.toml").is_file())
    if only:
        names = [n for n in names if any(o in n for o in only)]
    return names


#: seconds a part's run may take before the bench stops it (``--timeout``): today's solver can
#: spend hours on a part it will not settle
TIMEOUT_S = 900.0


def _rackstress() -> list:
    """The ``rackstress`` command of this interpreter (its venv's script, else ``-m``)."""
    import sys

    exe = Path(sys.executable).with_name("rackstress")
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "rackstress.cli"]


def _error_of(stderr: str) -> str:
    """The last ``rackstress: error:`` paragraph of a command's stderr."""
    lines = [ln for ln in stderr.splitlines() if ln.startswith("rackstress: error:")]
    return lines[-1].split("rackstress: error:", 1)[1].strip() if lines else \
        (stderr.strip().splitlines() or ["(no message)"])[-1]


def case(name: str, work: Path, fea: bool = True, sets: dict | None = None, echo=print,
         timeout: float = TIMEOUT_S, corpus: Path | None = None, refine: bool = False,
         refine_ratio: float | None = None) -> dict:
    """One part as a user runs it, each command a process of its own: ``rackstress run SCENE
    --no-render`` (LAMMPS; the stress measured; ``refine``: with ``--refine``, and
    ``--refine-ratio`` where ``refine_ratio`` is given, the run's timeout three times
    ``timeout`` for the finer run, nine times at a ratio of 2 or more: 8× the particles), then
    ``rackstress fea``; its row."""
    import json
    import subprocess

    corpus = corpus or parts_dir()
    scene = corpus / name / "scene.toml"
    root = str(corpus.parents[1]) + os.sep
    row = {"part": name, "scene": str(scene).replace(root, "")}
    out = work / name
    # paths in the repository, and the run by its part's name, not this machine's temporary
    short = lambda text: str(text).replace(str(out), name).replace(root, "")  # noqa: E731
    args = [*_rackstress(), "run", str(scene), "--no-render", "--no-progress", "--out",
            str(out), "--overwrite"] + (["--refine"] if refine else []) + (
        ["--refine-ratio", f"{refine_ratio:g}"] if refine and refine_ratio else [])
    for k, v in (sets or {}).items():
        args += ["--set", f"{k}={v}"]
    cpu0, t0 = cpu_children(), time.perf_counter()
    limit = timeout * ((9 if (refine_ratio or 0) >= 2 else 3) if refine else 1)
    try:
        r = subprocess.run(args, capture_output=True, text=True, timeout=limit)
    except subprocess.TimeoutExpired:
        row.update(status=f"stopped after {limit:.0f} s", run_wall_s=limit,
                   reason=f"the run had not ended after {limit:.0f} s (--timeout): today's "
                          "solver had not settled it")
        echo(f"{name}: stopped after {limit:.0f} s")
        return row
    row["run_wall_s"] = time.perf_counter() - t0
    row["run_cpu_s"] = cpu_children() - cpu0
    summary_file = out / "summary.json"
    if r.returncode == 2 or not summary_file.is_file():
        row.update(status=f"refused (exit {r.returncode})", reason=short(_error_of(r.stderr)))
        echo(f"{name}: refused: {row['reason']}")
        return row
    s = json.loads(summary_file.read_text())
    g = next(iter(s["groups"].values()))
    sz = g.get("sizing") or {}
    row.update(particles=s.get("n_particles"), spacing=sz.get("spacing"),
               spacing_how=(sz["chosen"]["limited_by"] if sz.get("chosen") else "given"),
               thin_walls=len(sz.get("thin_walls") or []), settled=bool(s.get("settled")),
               iterations=s.get("iterations"), residual=s.get("residual"),
               solve_s=s.get("solve_s"))
    stress = s.get("stress") or {}
    gov = stress.get("governing")
    peak = (gov or {}).get("value")
    if peak is None:
        peak = (stress.get("peak") or {}).get("value")
    row["peak_mpa"], row["peak_kind"] = peak, ("governing" if gov else "peak")
    row["peak_read"] = (gov or {}).get("read")         # patch fit or notch reading
    ze = (gov or {}).get("zone_edge")                  # set by where the zone ends
    row["zone_edge"] = None if gov is None else bool(ze)
    if ze:
        row.update(zone_edge_kind=ze["kind"], zone_edge_fall=ze["fall"])
    row["status"] = {0: "settled", 6: "not settled (exit 6)"}.get(
        r.returncode, f"failed (exit {r.returncode})")
    if r.returncode not in (0, 6):
        row["reason"] = short(_error_of(r.stderr))
    if refine:
        row.update(_refined(stress, r, short))
    if fea and row["settled"]:
        t0 = time.perf_counter()
        code, err, usage = _timed([*_rackstress(), "fea", str(out)], timeout)
        if usage is not None:     # this process's own CPU time and peak memory
            row.update(fea_cpu_s=usage.ru_utime + usage.ru_stime,
                       fea_rss_gb=usage.ru_maxrss * 1024 / 2 ** 30)
        if code is None:
            row["fea_error"] = f"rackstress fea had not ended after {timeout:.0f} s"
        elif code == 0:
            fj = json.loads((out / "fea.json").read_text())
            ag, gov = fj["agreement"], fj.get("governing") or {}
            row.update(fea_spearman=ag.get("spearman"), fea_top5=ag.get("top5_overlap"),
                       fea_peak_ratio=ag.get("peak_ratio"), fea_mesh=fj.get("mesh"),
                       fea_note=fj.get("note"), fea_tetrahedra=fj["fe"].get("tetrahedra"),
                       fea_governing_ratio=gov.get("ratio"), fea_moved=gov.get("moved"),
                       fea_governing_mpa=gov.get("value"),
                       fea_local_mpa=(gov.get("local") or {}).get("value"),
                       fea_local_moved=(gov.get("local") or {}).get("moved"),
                       # why it did not refine, or its own note (facets kept it from converging)
                       fea_local_note=(gov.get("local_note")
                                       or (gov.get("local") or {}).get("note")),
                       fea_budget=fj.get("fe_budget"), fea_quality=fj.get("fe_quality"),
                       fea_ftetwild_edge=fj["fe"].get("ftetwild_edge"),
                       fea_ftetwild_envelope=fj["fe"].get("ftetwild_envelope"))
        else:
            row["fea_error"] = short(_error_of(err))
        row["fea_s"] = time.perf_counter() - t0
    if refine:
        row.update(refine_comparison(row))
    echo(f"{name}: {row['particles']:,} particles at {fmt(row['spacing'])} "
         f"({row['spacing_how']}), {row['status']} in {row['iterations']} steps, residual "
         f"{fmt(row['residual'])}, solve {fmt(row['solve_s'])} s, peak {fmt(peak)} MPa"
         + (f", FE ρ {fmt(row.get('fea_spearman'))}" if "fea_spearman" in row else ""))
    return row


def _refined(stress: dict, r, short) -> dict:
    """``--refine``'s part of a row: the refined run's governing stress, how it was read, its
    spacing and particles, and the error bar (``summary.json["stress"]["error"]``), or why
    there is none."""
    from rackstress.stress.governing import read_label

    err = stress.get("error")
    if not err or "values" not in err:
        # none, or the first run's own band alone: the refinement failed or did not settle
        # (exit 6), and the first run was kept as it was (stress.refine.refine)
        why = _error_of(r.stderr) if r.returncode else "no error bar in summary.json"
        return {"refine_error": short(why) or "no error bar in summary.json"}
    # how the refined value was read: the error bar's own reading (the first run's rule, or
    # the refined field at the first run's governing point)
    fg = err.get("governing_fine") or {}
    return {"refined_mpa": err["values"][-1], "refined_spacing": err["spacings"][-1],
            "refined_particles": (err.get("particles") or [None, None])[-1],
            "refined_read": read_label(fg.get("read"), fg.get("notch_by"))
            if fg.get("read") else None,
            "refined_rule_mpa": fg.get("rule_value"),
            "bar_low": err["low"], "bar_high": err["high"],
            "bar_extrapolated": err.get("extrapolated"), "bar_order": err.get("order"),
            "first_bar_low": (err.get("first_run") or {}).get("low"),
            "first_bar_high": (err.get("first_run") or {}).get("high")}


#: The FE check's reading is a converged reference where it moved at most this between its
#: two meshes (its local ball's, or its global FE's where the ball was no refinement), and
#: the FE check does not itself say it is not converged (a local reading beside a faceted
#: fillet that moved more than ``validity.solid.LOCAL_MOVED``: it rises with every mesh)
FE_CONVERGED = 0.05


#: the target at the first (default) spacing: the governing stress within this of converged FEA
FIRST_TARGET = 0.10


def _fe_says_not_converged(note) -> bool:
    """Whether the FE check's own note on its local reading (``fea.json`` →
    ``governing.local.note``) says it did not converge (``validity.solid`` writes it so)."""
    return str(note or "").startswith("not converged")


def refine_comparison(row: dict) -> dict:
    """The FE check's governing stress a row's ``--refine`` values are compared with (its local
    refinement's where it has one that was refined: solved at two mesh sizes, ``moved`` given;
    not one gmsh filled inside the file's own facets, ungraded, whose value no second mesh
    checks — the SO-100 upper arm's read 1.29 MPa there, the global FE 0.97), the governing
    and refined values over it and whether the error bar covers it; empty where the row has no
    refined value or no FE value."""
    local = (row.get("fea_local_mpa")
             if local_is_reference({"moved": row.get("fea_local_moved")}) else None)
    fe = local or row.get("fea_governing_mpa")
    if row.get("refined_mpa") is None or not fe:
        return {}
    gov = row.get("peak_mpa") if row.get("peak_kind") == "governing" else None
    moved = row.get("fea_local_moved") if local else row.get("fea_moved")
    facets = bool(local) and _fe_says_not_converged(row.get("fea_local_note"))
    return {"fe_reference_mpa": fe, "fe_reference_local": bool(local),
            "fe_reference_moved": moved, "fe_reference_facets": facets,
            "fe_converged": bool(moved is not None and moved <= FE_CONVERGED and not facets),
            "governing_over_fe": None if gov is None else gov / fe,
            "refined_over_fe": row["refined_mpa"] / fe,
            "bar_covers_fe": bool(row["bar_low"] <= fe <= row["bar_high"]),
            "first_bar_covers_fe": None if row.get("first_bar_low") is None else
            bool(row["first_bar_low"] <= fe <= row["first_bar_high"])}


def _timed(args: list, timeout: float):
    """Run ``args``; (exit status or None if stopped after ``timeout`` s, its stderr, its
    resource usage — CPU time and peak resident memory of that process alone, os.wait4)."""
    import subprocess

    with tempfile.TemporaryFile("w+") as err:
        p = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=err, text=True)
        end = time.monotonic() + timeout
        while True:
            pid, status, usage = os.wait4(p.pid, os.WNOHANG)
            if pid:
                p.returncode = os.waitstatus_to_exitcode(status)
                break
            if time.monotonic() > end:
                p.kill()
                _, status, usage = os.wait4(p.pid, 0)
                p.returncode = None
                break
            time.sleep(0.2)
        err.seek(0)
        return p.returncode, err.read(), usage


def run_bench(out=None, fea: bool = True, only=None, sets: dict | None = None,
              echo=print, timeout: float = TIMEOUT_S, corpus: Path | None = None,
              refine: bool = False, refine_ratio: float | None = None) -> dict:
    """Every part (module doc) of ``corpus`` (default: ``examples/parts/``), each with
    ``--refine`` where ``refine`` (at spacing/``refine_ratio``, √2 unless given); returns the
    data written to ``parts.json``."""
    t0 = time.perf_counter()
    start = machine()
    out = out_dir(out)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rs-parts-") as tmp:
        for name in part_names(only, corpus):
            rows.append(case(name, Path(tmp), fea=fea, sets=sets, echo=echo, timeout=timeout,
                             corpus=corpus, refine=refine, refine_ratio=refine_ratio))
    try:
        load_end = os.getloadavg()
    except OSError:  # pragma: no cover
        load_end = None
    data = {"machine": {**start, "load_avg_at_end": load_end}, "fea": bool(fea),
            "refine": bool(refine),
            **({"refine_ratio": float(refine_ratio)} if refine and refine_ratio else {}),
            "sets": dict(sets or {}), "only": list(only or []), "timeout_s": timeout, "rows": rows,
            "settled": sum(1 for r in rows if r.get("settled")), "parts": len(rows)}
    data["files"] = [str(out / "parts.json"), str(out / "parts.md")]
    data["wall_s"] = time.perf_counter() - t0
    write_json(out / "parts.json", data)
    (out / "parts.md").write_text(markdown(data))
    return data


def table_rows(data) -> list:
    rows = []
    for r in data["rows"]:
        sp = r.get("spacing")
        rows.append([
            r["part"], fmt(r.get("particles"), 6) if r.get("particles") else "—",
            (f"{fmt(sp)} ({r['spacing_how']})" if sp else "—"),
            fmt(r.get("iterations")), fmt(r.get("residual"), 2), fmt(r.get("solve_s")),
            fmt(r.get("run_cpu_s")), fmt(r.get("peak_mpa")),
            {True: "yes", False: "**no**"}.get(r.get("settled"), "—"),
            _slivers(r.get("fea_quality")), fmt(r.get("fea_spearman")),
            fmt(r.get("fea_peak_ratio")), fmt(r.get("fea_cpu_s")), fmt(r.get("fea_rss_gb")),
            r.get("status", "—")])
    return rows


def _slivers(q) -> str:
    """The FE mesh's share of slivers, bold and "poor" where its stress is no reference."""
    if not q:
        return "—"
    share = f"{100 * q['sliver_share']:.1f} %"
    return f"**{share}: poor**" if q.get("poor") else share


def markdown(data) -> str:
    m = data["machine"]
    load = m.get("load_avg_at_start")
    sets = " ".join([f"--set {k}={v}" for k, v in data.get("sets", {}).items()]
                    + [f"--only {o}" for o in data.get("only", [])])
    out = [
        "# Real parts: the static path on parts nobody here drew",
        "",
        "Generated by `rackstress bench parts"
        + ("" if data.get("fea") else " --no-fea") + (" --refine" if data.get("refine") else "")
        + (f" --refine-ratio {data['refine_ratio']:g}" if data.get("refine_ratio") else "")
        + (f" {sets}" if sets else "")
        + (f" --timeout {data['timeout_s']:g}" if data.get("timeout_s") != TIMEOUT_S else "")
        + "` (workflow/rackstress/bench/parts.py); do not edit by hand. Each part of "
        "`examples/parts/` (its `SOURCE.md` says where it comes from and under which licence) "
        "is loaded as its `scene.toml` says — supports and loads by hole and face names, the "
        "spacing chosen from its walls within the particle budget (20,000 unless set) where the "
        "scene gives none — solved to equilibrium on LAMMPS, its stress measured, and checked "
        "by `rackstress fea`" + ("" if data.get("fea") else " (skipped here: `--no-fea`)")
        + ".",
        "",
        f"{data['settled']} of {data['parts']} parts settled. Machine: {m.get('cores')} cores "
        f"({m.get('cpu')}), load average {fmt(load[0] if load else None)} at the start, "
        f"{fmt((m.get('load_avg_at_end') or [None])[0])} at the end; {data['wall_s']:.0f} s "
        f"wall in all; a run still going after {data.get('timeout_s', TIMEOUT_S):g} s is "
        "stopped and says so. Each part is `rackstress run SCENE --no-render` and `rackstress "
        "fea`, processes of their own. *solve* is the static solver's wall time, *run CPU* the "
        "CPU time of the whole `rackstress run` (scene, solve, the engine's check, stress); *spacing* says whether the "
        "walls or the budget set it, or the scene gave it; *peak* is the governing stress "
        "where the run has one, else the largest von Mises stress."
        + (" *FE ρ* is Spearman's rank correlation of the particles' stress with the FE's at "
           "the particles, *FE slivers* the share of the FE mesh's tetrahedra of quality below "
           f"{SLIVER_Q:g} (1: regular; above {100 * POOR_SLIVERS:g} % the mesh is **poor**: its "
           "stress is no reference and its ρ and ratio say nothing of the particles; "
           "docs/fea.md), *FE peak ratio* the particles' largest over the FE's largest at "
           "least the zone away from singular points (docs/fea.md); *FE CPU* and *FE memory* "
           "are `rackstress fea`'s own CPU time and peak resident memory, both FE sizes (the "
           "FE check's target: 60 s and 2 GB for 20,000 particles)." if data.get("fea") else ""),
        "",
        md_table(HEADER, table_rows(data)),
    ]
    meshed = [r for r in data["rows"] if r.get("fea_mesh")]
    if meshed:
        out += ["FE meshes (`fea.json` → `mesh`, `note`, `fe_budget`):", ""]
        for r in meshed:
            b = r.get("fea_budget") or {}
            ref = local_is_reference({"moved": r.get("fea_local_moved")})
            out.append(f"* **{r['part']}**: {r['fea_mesh']}, {fmt(r.get('fea_tetrahedra'), 6)} "
                       "tetrahedra"
                       + (f"; fTetWild's surface at edges of {fmt(r['fea_ftetwild_edge'])} mm "
                          f"(within {fmt(r['fea_ftetwild_envelope'])} mm of the file's), not "
                          "graded" if r.get("fea_ftetwild_edge") else
                          f"; graded to {fmt(b['near_size'])} mm, not {fmt(b['near_size_wanted'])}"
                          f", within the budget of {b['elements']:,}" if b.get("raised") else "")
                       + (f"; the FE's governing stress moved {100 * r['fea_moved']:.1f} % from "
                          "the coarser FE mesh" if r.get("fea_moved") is not None else "")
                       + (f"; the particles at the FE's governing point: "
                          f"{fmt(r['fea_governing_ratio'])} of the FE's"
                          if r.get("fea_governing_ratio") is not None else "")
                       + (f"; the run's governing stress ({r.get('peak_read') or 'patch'} "
                          f"reading) over the FE's: "
                          f"{fmt(r['peak_mpa'] / r['fea_governing_mpa'])}"
                          if r.get("fea_governing_mpa") and r.get("peak_mpa") is not None
                          and r.get("peak_kind") == "governing" else "")
                       + (f"; refined locally (`rackstress fea`'s submodel about its governing "
                          f"point) {fmt(r['fea_local_mpa'])} MPa, moved "
                          f"{100 * r['fea_local_moved']:.1f} % from twice its mesh size; the "
                          f"run's governing stress over it: "
                          f"{fmt(r['peak_mpa'] / r['fea_local_mpa'])}"
                          if r.get("fea_local_mpa") and r.get("peak_mpa") is not None
                          and r.get("peak_kind") == "governing"
                          and ref else "")
                       + (f"; {r['fea_local_note']}" if r.get("fea_local_note") else "")
                       + (f" (its ball read {fmt(r['fea_local_mpa'])} MPa: no reference)"
                          if r.get("fea_local_mpa") and not ref else ""))
        out.append("")
    edge = [r for r in data["rows"] if r.get("zone_edge") is not None]
    if edge:
        at = [r for r in edge if r["zone_edge"]]
        out += [f"At the zone's edge (`summary.json` → `stress.governing.zone_edge`: the "
                "governing stress read within half a spacing beyond the zone, the particles a "
                "spacing farther out reading more than 5 % less; docs/stress.md): "
                f"{len(at)} of {len(edge)} parts"
                + (": " + ", ".join(f"{r['part']} ({r['zone_edge_kind']}, "
                                     f"{100 * r['zone_edge_fall']:.2g} % less a spacing out)"
                                     for r in at) if at else "") + ".", ""]
    if data.get("refine"):
        out += _refine_section(data)
    notes = [r for r in data["rows"] if r.get("reason") or r.get("fea_error")
             or r.get("refine_error")]
    if notes:
        out.append("Why:")
        out.append("")
        for r in notes:
            out.append(f"* **{r['part']}**: "
                       + "; ".join(x for x in (r.get("reason"), r.get("fea_error"),
                                               r.get("refine_error") and "--refine: "
                                               + r["refine_error"]) if x))
        out.append("")
    return "\n".join(out)


REFINE_HEADER = ["part", "spacing [mm]", "governing [MPa]", "its band [MPa]", "refined [MPa]",
                 "read by", "error bar [MPa]", "FE [MPa]", "FE moved", "governing / FE",
                 "refined / FE", "band covers FE", "bar covers FE"]


def _refine_section(data) -> list:
    """The refined governing stress and its error bar against the FE check's governing stress
    (:func:`refine_comparison`), a row per part with both."""
    rows = []
    for r in data["rows"]:
        if r.get("refined_over_fe") is None:
            continue
        rows.append([
            r["part"], f"{fmt(r.get('spacing'))} → {fmt(r['refined_spacing'])}",
            fmt(r.get("peak_mpa")),
            "—" if r.get("first_bar_low") is None else
            f"{fmt(r['first_bar_low'])} … {fmt(r['first_bar_high'])}",
            fmt(r["refined_mpa"]), r.get("refined_read") or "—",
            f"{fmt(r['bar_low'])} … {fmt(r['bar_high'])}",
            fmt(r["fe_reference_mpa"]) + (" (local)" if r["fe_reference_local"] else ""),
            "—" if r.get("fe_reference_moved") is None else
            f"{100 * r['fe_reference_moved']:.1f} %"
            + ("" if r.get("fe_converged") else " (not converged: faceted fillet)"
               if r.get("fe_reference_facets") else " (not converged)"),
            fmt(r.get("governing_over_fe"), 4), fmt(r["refined_over_fe"], 4),
            {None: "—", True: "yes", False: "**no**"}[r.get("first_bar_covers_fe")],
            "yes" if r["bar_covers_fe"] else "**no**"])
    if not rows:
        return []
    done = [r for r in data["rows"] if r.get("refined_over_fe") is not None]
    conv = [r for r in done if r.get("fe_converged")]

    def _other(rs: list) -> str:
        n, faceted = len(rs), sum(1 for r in rs if r.get("fe_reference_facets"))
        why = ("its FE moved more between its meshes" if n == 1 else
               "their FE moved more between their meshes")
        if faceted == n:
            why = ("the FE check says its reading rises with every mesh beside the file's "
                   "faceted fillet" if n == 1 else "the FE check says their readings rise "
                   "with every mesh beside the files' faceted fillets")
        elif faceted:
            why = (f"on {n - faceted} the FE moved more between its two meshes, on {faceted} "
                   "the FE check says its reading rises with every mesh beside the file's "
                   "faceted fillet")
        return ((f"The other one has no converged reference here: {why}" if n == 1 else
                 f"The other {n} have no converged reference here: {why}")
                + ", and fTetWild meshes a file differently from run to run (docs/fea.md).")

    near = lambda rs: [r for r in rs if abs(r["refined_over_fe"] - 1) <= 0.05]  # noqa: E731
    tally = (f"The refined governing stress is within 5 % of the FE check on "
             f"{len(near(done))} of {len(done)} parts; of the {len(conv)} whose FE reading "
             f"converged (moved at most {100 * FE_CONVERGED:g} % between its two meshes, "
             f"and not beside a faceted fillet the FE check says it does not converge at) on "
             f"{len(near(conv))}"
             + (f" ({', '.join(r['part'] for r in near(conv))})" if near(conv) else "")
             + ("; outside 5 %: " + ", ".join(f"{r['part']} {r['refined_over_fe']:.3g}"
                                            for r in conv if r not in near(conv))
                if len(near(conv)) < len(conv) else "")
             + (". " + _other([r for r in done if r not in conv])
                if len(done) > len(conv) else ".")
             )
    first = [r for r in conv if r.get("governing_over_fe") is not None]
    if first:                 # the first run's governing stress against the same references
        ok = [r for r in first if abs(r["governing_over_fe"] - 1) <= FIRST_TARGET]
        tally += (f" At the first spacing the governing stress is within "
                  f"{100 * FIRST_TARGET:g} % of the same converged readings on {len(ok)} of "
                  f"{len(first)}"
                  + ("; outside: " + ", ".join(f"{r['part']} {r['governing_over_fe']:.3g}"
                                               for r in first if r not in ok)
                     if len(ok) < len(first) else "") + ".")
    banded = [r for r in conv if r.get("first_bar_covers_fe") is not None]
    if banded:
        miss = [r for r in banded if not r["first_bar_covers_fe"]]
        tally += (f" The first run's own band covers the converged FE reading on "
                  f"{len(banded) - len(miss)} of {len(banded)}"
                  + (" (not: " + ", ".join(r["part"] for r in miss) + ")" if miss else "")
                  + ".")
    ratio = data.get("refine_ratio")
    how = (f"spacing/{ratio:g} (`rackstress run SCENE --refine --refine-ratio {ratio:g}`)"
           if ratio else "spacing/√2 (`rackstress run SCENE --refine`)")
    return ["## After `--refine`", "",
            f"Each part solved again at {how}: its "
            "governing stress at both spacings, how the refined one was read (the patch fit, "
            "the notch reading, or its field at the first run's governing point: *first "
            "point*, docs/stress.md \"The first run's governing point\"), and the error bar "
            "`summary.json` gives "
            "(`[\"stress\"][\"error\"]`: Richardson from the two values, never narrower than "
            "the refined run's own band; docs/stress.md \"The error bar\"), against the FE "
            "check's governing stress (refined locally where `rackstress fea` could: "
            "*local*). The target: the refined governing stress within 5 % of "
            "converged FEA. *FE moved*: how far that FE reading moved between its two meshes. "
            "*its band*: what the first run alone said its governing stress may be off by "
            "(`[\"stress\"][\"error\"][\"first_run\"]`: the lattice's measured convergence "
            "at its spacing and the part's thickness there, docs/stress.md \"The error bar\"), "
            "before `--refine`.",
            "", md_table(REFINE_HEADER, rows), "", tally, ""]
