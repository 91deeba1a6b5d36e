"""What a static run's post-processing costs: this checkout against a baseline revision.

    python scripts/bench_static_report.py [RUNDIR] [--baseline main] [--repeat 2]

RUNDIR is a finished static run (``rackstress run SCENE --no-render``); without it the script
runs ``examples/cantilever/scene.toml --set spacing=0.8`` (21,294 particles; named ``bar-0.8``:
the report before took a run named like a built-in scene for that scene) first. Each repeat
copies its inputs (scene.json, particles.data, the trajectory, bindings.npz, boundary.npz,
summary.json) into a fresh directory and post-processes
the copy as ``rackstress run`` does at its end (``rackstress.cli._post_and_render``: the
measures, the peaks, the VTK files in a forked writer, the pictures, the 3D view, report.html),
in a fresh process, once with this checkout's code and once with the baseline's
(``git archive BASELINE workflow``, first on ``PYTHONPATH``), alternating. Each process reports
its CPU time and its children's (the forked VTK writer, plots, 3D view) and its wall time; two
warm-ups of each first (numba's caches). The machine's load average is printed with every
figure: on a shared machine compare CPU times.

Then how well the surface carries the particles' values (:mod:`rackstress.stress.surface`):
the cantilever (``examples/cantilever``, 100 N on a 100 × 10 × 10 mm aluminium bar) at spacings
2, 1 and 0.8 mm, against beam theory: the von Mises stress on the top face (z = 5 mm) at x =
25, 50, 75 mm, M·c/I = P·(L − x)·5/(10⁴/12), the particles' top layer beside it (z = 5 − a/2),
where the surface lies (its largest z), the free end's deflection (P·L³/(3EI) plus shear:
0.576 mm), and the fit's error on a linear field at the surface's points.
Writes ``OUT/static-report.json`` and ``OUT/static-report.md``, :func:`markdown` of it.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHILD = r"""
import json, resource, sys, time
rundir = sys.argv[1]
t, c = time.perf_counter(), time.process_time()
import rackstress
from rackstress.cli import _post_and_render
from rackstress.stress.rundata import kept_open
with kept_open():
    _post_and_render(rundir, True, False, True)
wall, cpu = time.perf_counter() - t, time.process_time() - c
ch = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"wall_s": wall, "cpu_s": cpu, "cpu_children_s": ch.ru_utime + ch.ru_stime,
                  "code": rackstress.__file__}))
"""
INPUTS = ("scene.json", "particles.data", "trajectory.dump.gz", "trajectory.dump",
          "bindings.npz", "boundary.npz", "summary.json", "in.lammps")


def fresh(rundir: Path, work: Path) -> Path:
    """A copy of the run's inputs, nothing derived, summary.json without post-processing's
    keys (as the run left it)."""
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    for name in INPUTS:
        if (rundir / name).is_file():
            shutil.copy2(rundir / name, work / name)
    s = json.loads((work / "summary.json").read_text())
    for k in ("stress", "render"):
        s.pop(k, None)
    for g in (s.get("groups") or {}).values():
        g.pop("peak", None)
    (work / "summary.json").write_text(json.dumps(s))
    return work


def post(work: Path, pythonpath: str | None) -> dict:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath + os.pathsep + env.get("PYTHONPATH", "")
    r = subprocess.run([sys.executable, "-c", CHILD, str(work)], capture_output=True, text=True,
                       env=env)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-3000:])
    got = json.loads(r.stdout.strip().splitlines()[-1])
    got["load"] = os.getloadavg()[0]
    return got


def accuracy(rundir: Path) -> dict:
    """The cantilever's surface against beam theory (module docstring)."""
    import numpy as np
    import pyvista as pv

    from rackstress.stress.surface import interpolate

    m = pv.read(rundir / "vtk" / "surface.vtp")
    parts = pv.read(sorted((rundir / "vtk").glob("frame_*.vtp"))[-1])
    P, vm, u = np.asarray(m.points), np.asarray(m["von_mises"]), np.asarray(m["displacement"])
    o, pv_vm = np.asarray(parts["original"], float), np.asarray(parts["von_mises"])
    a = float(np.median(np.diff(np.unique(np.round(o[:, 0], 6)))))
    top_o = o[:, 2].max()
    rows = []
    for x in (25.0, 50.0, 75.0):
        near = a / 2 + 1e-3 * a         # vtk/run.pvd keeps positions in float32
        face = (np.abs(P[:, 0] - x) <= near) & (P[:, 2] > 4.9) & (np.abs(P[:, 1]) < 3)
        layer = ((np.abs(o[:, 0] - x) <= near) & (o[:, 2] > top_o - a / 2)
                 & (np.abs(o[:, 1]) < 3))
        z = float(o[layer, 2].mean())
        rows.append({"x": x, "surface": float(vm[face].mean()),
                     "beam_surface": 100 * (100 - x) * 5 / (1e4 / 12),
                     "particles": float(pv_vm[layer].mean()), "z_particles": z,
                     "beam_particles": 100 * (100 - x) * z / (1e4 / 12)})
    tip = P[:, 0] > P[:, 0].max() - a / 4
    lin = 3 + 2 * o[:, 0] - o[:, 1] + 0.5 * o[:, 2]
    exact = 3 + 2 * P[:, 0] - P[:, 1] + 0.5 * P[:, 2]
    err = float(np.abs(interpolate(o, lin, P, a) - exact).max() / np.abs(exact).max())
    return {"spacing": a, "particles": int(len(o)), "surface_points": int(m.n_points),
            "triangles": int(m.n_cells), "z_max": float(P[:, 2].max()),
            "tip_deflection": float(-u[tip, 2].mean()), "linear_error": err, "rows": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rundir", type=Path, nargs="?")
    ap.add_argument("--baseline", default="main")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="rackstress-bench-static-"))
    command = "python scripts/bench_static_report.py" + (f" {args.rundir}" if args.rundir
                                                          else "")
    own = args.rundir is None
    if own:
        # the example under another name: a report before this one took a run named like a
        # built-in scene for that scene, and computed Eq. 5's margin of the built-in
        # "cantilever" (a dense eigenproblem, ~10 s of CPU) — not what is measured here
        text = (ROOT / "examples" / "cantilever" / "scene.toml").read_text()
        (tmp / "bar.toml").write_text(text.replace('name = "cantilever"', 'name = "bar-0.8"'))
        args.rundir = tmp / "bar-0.8"
        subprocess.run([str(Path(sys.executable).with_name("rackstress")), "run",
                        str(tmp / "bar.toml"), "--set", "spacing=0.8", "--out",
                        str(args.rundir), "--no-render", "--no-progress"], check=True,
                       capture_output=True)
    rundir = args.rundir.resolve()
    summary = json.loads((rundir / "summary.json").read_text())
    if summary.get("analysis") != "static":
        ap.error(f"{rundir} is not a static run")
    try:
        base = tmp / "baseline"
        base.mkdir()
        rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", args.baseline],
                             capture_output=True, text=True, check=True).stdout.strip()
        tar = subprocess.run(["git", "-C", str(ROOT), "archive", args.baseline, "workflow"],
                             capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(base)], input=tar, check=True)
        lib = ROOT / "workflow" / "rackstress" / "engines" / "lammps" / "plugin_lib"
        if lib.is_dir():            # the compiled plugin is built, not archived
            shutil.copytree(lib, base / "workflow" / "rackstress" / "engines" / "lammps"
                            / "plugin_lib")
        codes = {f"baseline {rev}": str(base / "workflow"), "this checkout": None}
        rows = {k: [] for k in codes}
        for name, path in codes.items():           # warm-up: numba's caches (a first
            for _ in range(2):                      # run compiles them beside, the next
                post(fresh(rundir, tmp / "run"), path)      # finds them), the OS's
        for _ in range(args.repeat):
            for name, path in codes.items():
                rows[name].append(post(fresh(rundir, tmp / "run"), path))
                r = rows[name][-1]
                print(f"{name}: CPU {r['cpu_s']:.2f} s + children {r['cpu_children_s']:.2f} s, "
                      f"wall {r['wall_s']:.2f} s (load {r['load']:.1f})", flush=True)
        acc = []
        if own:
            rs = str(Path(sys.executable).with_name("rackstress"))
            for a in (2.0, 1.0):
                d = tmp / f"cantilever-{a:g}"
                subprocess.run([rs, "run", str(ROOT / "examples" / "cantilever" / "scene.toml"),
                                "--set", f"spacing={a:g}", "--out", str(d), "--no-progress"],
                               check=True, capture_output=True)
                acc.append(accuracy(d))
            acc.append(accuracy(tmp / "run"))        # this checkout's, post-processed last
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    best = {k: min(v, key=lambda r: r["cpu_s"] + r["cpu_children_s"]) for k, v in rows.items()}
    data = {"command": f"{command} --baseline {args.baseline}", "date": time.strftime("%Y-%m-%d"),
            "repeat": args.repeat, "rundir": str(args.rundir), "scene": summary.get("scene"),
            "particles": summary.get("n_particles"), "baseline": args.baseline, "runs": rows,
            "best": best, "accuracy": acc}
    shutil.rmtree(tmp, ignore_errors=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "static-report.json").write_text(json.dumps(data, indent=1))
    text = markdown(data)
    (args.out / "static-report.md").write_text(text)
    print(text)
    return 0


def markdown(data: dict) -> str:
    """The page, from the data :func:`main` writes to static-report.json (a record without the
    command, date or repeat count, as the first one, prints what it holds)."""
    best, acc, n = data["best"], data["accuracy"], data["particles"]
    command = data.get("command", f"python scripts/bench_static_report.py --baseline "
                                  f"{data['baseline']}")
    repeat = data.get("repeat", min(len(v) for v in data["runs"].values()))
    when = f" ({data['date']})" if data.get("date") else ""
    lines = ["# A static run's post-processing: before and after the static report", "",
             f"`{command}`{when}: `{data.get('scene')}`, {n:,} particles, "
             f"post-processed as `rackstress run` does at its end (measures, VTK files, "
             f"pictures, 3D view, report), best of {repeat} by CPU time, in one run of "
             "this script (alternating; the figures are in `static-report.json`).", "",
             "| code | CPU (process) [s] | CPU (forked children) [s] | CPU total [s] | wall [s] "
             "| load |", "|---|---|---|---|---|---|"]
    for k, r in best.items():
        lines.append(f"| {k} | {r['cpu_s']:.2f} | {r['cpu_children_s']:.2f} | "
                     f"{r['cpu_s'] + r['cpu_children_s']:.2f} | {r['wall_s']:.2f} | "
                     f"{r['load']:.1f} |")
    (a, ra), (b, rb) = best.items()
    ta, tb = ra["cpu_s"] + ra["cpu_children_s"], rb["cpu_s"] + rb["cpu_children_s"]
    lines += ["", f"The static report adds {tb - ta:+.2f} s of CPU ({tb / ta:.2f}×): the part's "
              "surface and its fit, the surface pictures and the surface in the 3D view, less "
              "the plots over time it no longer draws.", ""]
    if acc:
        lines += ["## The surface's values against beam theory", "",
                  "The cantilever (`examples/cantilever`), von Mises stress on the top face "
                  "(z = 5 mm) from `vtk/surface.vtp` and on the particles' top layer from "
                  "`vtk/run.pvd`, each beside beam theory's M·z/I at its height; the largest z "
                  "of the surface (the bar's face: 5 mm); the free end's deflection on the "
                  "surface (beam theory with shear: 0.576 mm); the fit's largest error on the "
                  "linear field 3 + 2x − y + 0.5z at the surface's points, relative.", "",
                  "| spacing [mm] | particles | x [mm] | surface [MPa] | beam at z = 5 | "
                  "particles' layer [MPa] | beam there | surface's z max [mm] | tip "
                  "deflection [mm] | linear-field error |", "|---|---|---|---|---|---|---|---|"
                  "---|---|"]
        for r in acc:
            for k, row in enumerate(r["rows"]):
                first = k == 0
                lines.append(
                    f"| {r['spacing']:g} | {r['particles']:,} | {row['x']:g} | "
                    f"{row['surface']:.2f} | {row['beam_surface']:.2f} | {row['particles']:.2f}"
                    f" (z = {row['z_particles']:.3g}) | {row['beam_particles']:.2f} | "
                    + (f"{r['z_max']:.3f} | {r['tip_deflection']:.4f} | "
                       f"{r['linear_error']:.1e} |" if first else "| | |"))
        lines.append("")
    return "\n".join(lines)

if __name__ == "__main__":
    sys.exit(main())
