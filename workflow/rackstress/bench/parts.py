"""``rackstress bench parts``: every real part of ``examples/parts/`` through the static path.

Each part (a folder with its STL, ``scene.toml`` and ``SOURCE.md``) is loaded as its scene
says — supports and loads by hole and face names, the spacing chosen from its walls within
the particle budget unless the scene gives one — solved to equilibrium on LAMMPS, its stress
measured, and checked against finite elements (``rackstress fea``; ``--no-fea`` skips it).
One row a part: particles, spacing and how it was chosen, Newton steps, residual, solve time
(the solver's wall time, and the CPU time of the whole run), the peak von Mises stress (the
governing stress where the run has one), settled or not, the FE agreement. A part the
static path refuses (exit 2: a mesh it cannot fill) or that does not settle (exit 6) is a row
too, with its reason: nothing is left out.

Writes ``docs/benchmarks/parts.json`` and ``parts.md``.
"""
from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from rackstress.bench import fmt, machine, md_table, out_dir, repository_file, write_json

HEADER = ["part", "particles", "spacing [mm]", "Newton steps", "residual", "solve [s]",
          "run CPU [s]", "peak [MPa]", "settled", "FE ρ", "FE peak ratio", "status"]


def parts_dir() -> Path:
    return repository_file("examples", "parts")


def part_names(only=None) -> list:
    names = sorted(p.name for p in parts_dir().iterdir() if (p / "scene.toml").is_file())
    if only:
        names = [n for n in names if any(o in n for o in only)]
    return names


def case(name: str, work: Path, fea: bool = True, sets: dict | None = None, echo=print) -> dict:
    """One part: load, solve (LAMMPS), stress, and the FE check; its row."""
    import json

    from rackstress.errors import RackstressError
    from rackstress.runs.run import mesh_sizing, run
    from rackstress.scenes import load
    from rackstress.stress.post import postprocess

    scene = parts_dir() / name / "scene.toml"
    root = str(parts_dir().parents[1]) + os.sep
    row = {"part": name, "scene": str(scene).replace(root, "")}
    short = lambda exc: str(exc).replace(root, "")     # noqa: E731 - paths in the repository
    t0 = time.process_time()
    try:
        sc = load(str(scene), dict(sets or {}))
    except RackstressError as exc:
        row.update(status="refused (exit 2)", reason=short(exc))
        echo(f"{name}: refused: {short(exc)}")
        return row
    row["load_cpu_s"] = time.process_time() - t0
    g = next(iter(sc.groups.values()))
    sz = mesh_sizing(g) or {}
    row["particles"] = sc.n_particles
    row["spacing"] = sz.get("spacing")
    row["spacing_how"] = (sz["chosen"]["limited_by"] if sz.get("chosen") else "given")
    row["thin_walls"] = len(sz.get("thin_walls") or [])
    out = work / name
    t0 = time.process_time()
    try:
        summary = run(sc, out, progress=False, overwrite=True)
    except RackstressError as exc:
        row.update(status=f"failed (exit {exc.exit_code})", reason=short(exc))
        echo(f"{name}: failed: {short(exc)}")
        return row
    row["run_cpu_s"] = time.process_time() - t0
    row.update(settled=bool(summary.get("settled")), iterations=summary.get("iterations"),
               residual=summary.get("residual"), solve_s=summary.get("solve_s"))
    info = postprocess(out)
    stress = json.loads((out / "summary.json").read_text()).get("stress", {}) or info or {}
    gov = stress.get("governing")
    peak = (gov or {}).get("value")
    if peak is None:
        peak = (stress.get("peak") or {}).get("value")
    row["peak_mpa"] = peak
    row["peak_kind"] = "governing" if gov else "peak"
    row["status"] = "settled" if row["settled"] else "not settled (exit 6)"
    if fea and row["settled"]:
        from rackstress.validity.solid import check_run

        t0 = time.perf_counter()
        try:
            data = check_run(out, echo=lambda *a, **k: None)
            ag = data["agreement"]
            row.update(fea_spearman=ag.get("spearman"), fea_top5=ag.get("top5_overlap"),
                       fea_peak_ratio=ag.get("peak_ratio"), fea_s=time.perf_counter() - t0)
        except (ValueError, RackstressError) as exc:
            row["fea_error"] = short(exc)
    echo(f"{name}: {row['particles']:,} particles at {fmt(row['spacing'])} "
         f"({row['spacing_how']}), {row['status']} in {row['iterations']} steps, residual "
         f"{fmt(row['residual'])}, solve {fmt(row['solve_s'])} s, peak {fmt(peak)} MPa"
         + (f", FE ρ {fmt(row.get('fea_spearman'))}" if "fea_spearman" in row else ""))
    return row


def run_bench(out=None, fea: bool = True, only=None, sets: dict | None = None,
              echo=print) -> dict:
    """Every part (module doc); returns the data written to ``parts.json``."""
    t0 = time.perf_counter()
    start = machine()
    out = out_dir(out)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rs-parts-") as tmp:
        for name in part_names(only):
            rows.append(case(name, Path(tmp), fea=fea, sets=sets, echo=echo))
    try:
        load_end = os.getloadavg()
    except OSError:  # pragma: no cover
        load_end = None
    data = {"machine": {**start, "load_avg_at_end": load_end}, "fea": bool(fea),
            "sets": dict(sets or {}), "rows": rows,
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
            fmt(r.get("fea_spearman")), fmt(r.get("fea_peak_ratio")), r.get("status", "—")])
    return rows


def markdown(data) -> str:
    m = data["machine"]
    load = m.get("load_avg_at_start")
    sets = ", ".join(f"--set {k}={v}" for k, v in data.get("sets", {}).items())
    out = [
        "# Real parts: the static path on parts nobody here drew",
        "",
        "Generated by `rackstress bench parts"
        + ("" if data.get("fea") else " --no-fea") + (f" {sets}" if sets else "")
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
        "wall in all. *solve* is the static solver's wall time, *run CPU* the CPU time of the "
        "whole run (scene, solve, the engine's check, output); *spacing* says whether the "
        "walls or the budget set it, or the scene gave it; *peak* is the governing stress "
        "where the run has one, else the largest von Mises stress.",
        "",
        md_table(HEADER, table_rows(data)),
    ]
    notes = [r for r in data["rows"] if r.get("reason") or r.get("fea_error")]
    if notes:
        out.append("Why:")
        out.append("")
        for r in notes:
            out.append(f"* **{r['part']}**: {r.get('reason') or r.get('fea_error')}")
        out.append("")
    return "\n".join(out)
