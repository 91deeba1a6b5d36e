"""CPU of each plot of ``rackstress run``'s default render, and of its 3D view, warm.

    python scripts/bench_plots.py [--out docs/benchmarks] [--repeat 7] [--scene magpod-small ...]
                                  [--against GIT-REV]

For each scene: one LAMMPS run (``--no-render``), then in this process, every plot drawn once
first (as the plots' process forked from the head start finds matplotlib): the CPU time
(``time.process_time``) of each plot as ``_plots`` draws it, figure and PNG
(``stress_over_time.png``; ``com_path.png`` with the parts' motion, ``PartMotion``, which
``footprints.png`` then shares), of ``PartMotion`` alone and of ``build_view``
(``view3d.html``); median and least of ``--repeat``. ``--against REV`` times the same with
the plots, the parts' motion and the 3D view as git revision REV had them, interleaved with
this tree's in the same process (the rest of the package is this tree's). The machine's load
average is given with every row: this 2-core machine is shared, compare within a table.
Writes ``OUT/plots.md`` and ``OUT/plots.json``.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = {"magpod-small": [], "plane-rack": ["--steps", "300"],
          "sediment-large": ["--steps", "1200"]}
PARTS = ("stress_over_time", "com_path", "footprints", "PartMotion", "build_view")
FILES = {"pictures": "workflow/rackstress/render/pictures.py",
         "measures": "workflow/rackstress/stress/measures.py",
         "view3d": "workflow/rackstress/render/view3d.py"}


def _variant(rev: str | None) -> dict:
    """The plots' function, PartMotion and build_view: this tree's, or git revision ``rev``'s
    (its three modules loaded under names of their own)."""
    if rev is None:
        from rackstress.render import pictures, view3d
        from rackstress.stress import measures
        return {"plots": pictures._plots, "motion": measures.PartMotion,
                "view": view3d.build_view, "pictures": pictures}
    mods = {}
    tmp = Path(tempfile.mkdtemp(prefix="bench-plots-rev-"))
    for key, path in FILES.items():
        text = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{path}"], check=True,
                              capture_output=True, text=True).stdout
        (tmp / f"{key}.py").write_text(text)
        name = f"bench_rev_{key}"
        spec = importlib.util.spec_from_file_location(name, tmp / f"{key}.py")
        mods[key] = importlib.util.module_from_spec(spec)
        sys.modules[name] = mods[key]
        spec.loader.exec_module(mods[key])
    mods["pictures"].PartMotion = mods["measures"].PartMotion
    return {"plots": mods["pictures"]._plots, "motion": mods["measures"].PartMotion,
            "view": mods["view3d"].build_view, "pictures": mods["pictures"]}


def measure(rundir: Path, repeat: int, variants: dict) -> dict:
    import numpy as np
    from matplotlib.figure import Figure

    from rackstress.render.pictures import RenderReport, find_peak, select_parts
    from rackstress.stress import load_run
    from rackstress.stress.post import compute_fields
    from rackstress.stress.rundata import kept_open

    marks = []
    save = Figure.savefig

    def savefig(self, *a, **k):                 # each plot ends with its PNG
        save(self, *a, **k)
        marks.append(time.process_time())

    got = {name: {k: [] for k in PARTS} for name in variants}
    Figure.savefig = savefig
    try:
        with kept_open():
            run = load_run(rundir)
            coloured, context, _ = select_parts(run, None)
            fields = compute_fields(run, cache=True)
            values, label = fields.values[fields.default], fields.label(fields.default)
            peak = find_peak(run, values, coloured)
            outs = {name: Path(tempfile.mkdtemp(prefix="bench-plots-")) for name in variants}

            def once(name, v, keep):
                rep = RenderReport(None)
                rep.peak = peak
                marks.clear()
                c = time.process_time()
                v["plots"](run, values, label, coloured, context, rep, outs[name])
                t = [c, *marks]
                c = time.process_time()
                v["motion"](run).run()
                t2 = time.process_time()
                v["view"](rundir)
                t3 = time.process_time()
                if keep:
                    for k, (a, b) in zip(PARTS, zip(t, t[1:])):
                        got[name][k].append(b - a)
                    got[name]["PartMotion"].append(t2 - c)
                    got[name]["build_view"].append(t3 - t2)

            names = list(variants)
            for name in names:                  # warm: everything drawn once
                once(name, variants[name], False)
            for r in range(repeat):             # interleaved, the order alternating
                for name in (names if r % 2 == 0 else names[::-1]):
                    once(name, variants[name], True)
    finally:
        Figure.savefig = save
    return {name: {k: {"median_ms": 1e3 * float(np.median(v)), "min_ms": 1e3 * float(min(v))}
                   for k, v in d.items() if v} for name, d in got.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--scene", action="append", choices=sorted(SCENES))
    ap.add_argument("--against", metavar="GIT-REV")
    ap.add_argument("--work", type=Path, default=Path("/tmp/rackstress-bench-plots"))
    args = ap.parse_args(argv)
    exe = Path(sys.executable).with_name("rackstress")
    variants = {"this tree": _variant(None)}
    if args.against:
        variants = {args.against: _variant(args.against), **variants}
    data = {}
    for scene in args.scene or ["magpod-small", "plane-rack"]:
        rundir = args.work / scene
        subprocess.run([str(exe), "run", scene, *SCENES[scene], "--out", str(rundir),
                        "--overwrite", "--no-render", "--no-progress"], check=True,
                       capture_output=True)
        load = os.getloadavg()[0]
        data[scene] = {"load": load, **measure(rundir, args.repeat, variants)}
        for name in variants:
            print(scene, name, f"load {load:.1f}", "  ".join(
                f"{k} {v['median_ms']:.0f} ms" for k, v in data[scene][name].items()))
    rows = ["| scene | code | " + " | ".join(PARTS) + " | plots in all | load |",
            "|---" * (len(PARTS) + 4) + "|"]
    for scene, d in data.items():
        for name in variants:
            m = d[name]
            cells = [f"{m[k]['median_ms']:.0f} ({m[k]['min_ms']:.0f})" if k in m else "—"
                     for k in PARTS]
            total = sum(m[k]["median_ms"] for k in PARTS[:3] if k in m)
            rows.append(f"| {scene} | {name} | " + " | ".join(cells)
                        + f" | {total:.0f} | {d['load']:.1f} |")
    stamp = time.strftime("%Y-%m-%d %H:%M")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "plots.json").write_text(json.dumps(data, indent=2) + "\n")
    against = f" --against {args.against}" if args.against else ""
    text = ("# The plots and the 3D view of the default render\n\n"
            f"`python scripts/bench_plots.py --repeat {args.repeat}{against}` ({stamp}; warm, "
            "in one process; CPU ms: median (least). `com_path` includes the parts' motion, "
            "which `footprints` then shares, `PartMotion` is that motion alone; *plots in "
            "all* is the plots' process's work. 2-core machine shared with other work: the "
            "1-minute load average given)\n\n" + "\n".join(rows) + "\n")
    (args.out / "plots.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
