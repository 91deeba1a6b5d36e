"""``rackstress bench e2e``: README's first command end to end, warm and cold, and what it leaves.

For each scene, ``rackstress run SCENE --out DIR --overwrite`` runs as a user runs it (a new
process, the package's bytecode written first: :func:`bytecode`), once with the user's cache (warm) and once with an empty one (cold:
``XDG_CACHE_HOME`` pointed at a new directory, so every compiled loop is compiled and Eq. 5's
limit predicted again),
interleaved ``repeat`` times. Its phases come from the run's own records: the simulation
(``summary.json`` ``wall_s``), the measures (``stress.json``), the pictures (``summary.json``
``render``; the VTK files are written by a second process meanwhile, their time shown apart),
and the rest of the wall time (start-up, the deck, the data file, the guards, the report).
The run directory's size is listed by file, and on magpod-small each way to write the VTK
series and the trajectory is measured (:func:`variants`).

The dump's cost per frame is measured apart, in one process: each scene is run for
``dump_steps`` iterations (the robot standing on the sediment), then the trajectory's frame of
each is written ``reps`` times, in turn, as the run writes it (the moving particles) and as
``--dump-all`` does.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SCENES = ("magpod-small", "magpod", "sediment-large")


def _subreaper() -> None:
    """Make this process the reaper of the commands' orphans (Linux ``PR_SET_CHILD_SUBREAPER``):
    ``rackstress run``'s post-processing process says its status and ends without the run
    waiting for its exit (render/prepare.py), so it may outlive the command; it is then
    reaped here, and its CPU time counts in the command's."""
    import ctypes

    try:
        ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0)    # PR_SET_CHILD_SUBREAPER
    except (OSError, AttributeError):
        pass


def _reap_orphans() -> None:
    """Wait for every process left by the command (:func:`_subreaper`)."""
    while True:
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            return


def _size(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _cli_run(scene: str, out: Path, cold: bool, args, head_start: bool = True) -> dict:
    exe = str(Path(sys.executable).parent / "rackstress")
    env = dict(os.environ)
    if not head_start:
        env["RACKSTRESS_HEAD_START"] = "0"
    cache = None
    if cold:
        cache = tempfile.mkdtemp(prefix="rackstress-cold-")
        env["XDG_CACHE_HOME"] = cache               # compiled loops, Eq. 5's prediction
        env.pop("NUMBA_CACHE_DIR", None)
    load = os.getloadavg()[0]
    import resource

    _subreaper()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    r = subprocess.run([exe, "run", scene, "--out", str(out), "--overwrite", "--no-progress",
                        *args], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    _reap_orphans()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if cache:
        shutil.rmtree(cache, ignore_errors=True)
    rec = {"wall_s": wall, "exit": r.returncode, "cold": cold, "load_at_start": load,
           "head_start": head_start,
           # the command's CPU, its forked children's included (each is waited for)
           "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)}
    if r.returncode not in (0, 4):
        rec["stderr"] = r.stderr[-1500:]
        return rec
    summary = json.loads((out / "summary.json").read_text())
    try:
        stress = json.loads((out / "stress.json").read_text())["timings"]
    except (OSError, json.JSONDecodeError, KeyError):
        stress = {}
    render = (summary.get("render") or {}).get("wall_s", 0.0)
    phases = {"simulation": summary["wall_s"], "measures": stress.get("measures_s", 0.0),
              "pictures": render}
    phases["start-up and the rest"] = wall - sum(phases.values())
    phases["vtk (beside the pictures)"] = stress.get("vtk_s", 0.0)
    rec["frames_measured_while_running"] = stress.get("frames_measured_while_running", 0)
    rec["driver"] = summary.get("driver_s") or {}
    # after the simulation, CPU by process: the main one's render (its sheet), and the forked
    # VTK writer, plots and 3D view (each child's own clock, runs/forked.py)
    timings = (summary.get("render") or {}).get("timings") or {}
    rec["cpu_after"] = {"pictures": timings.get("cpu_s"), "vtk": stress.get("vtk_cpu_s"),
                        "plots": timings.get("plots_cpu_s"), "view3d": timings.get("beside_cpu_s")}
    rec["frames"] = summary.get("steps", 0) // max(summary.get("dump_every") or 1, 1) + 1
    rec["phases"] = phases
    rec["sizes"] = {p.name + ("/" if p.is_dir() else ""): _size(p)
                    for p in sorted(out.iterdir()) if not p.name.startswith(".")}
    rec["size_total"] = sum(rec["sizes"].values())
    rec["note"] = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else ""
    return rec


def dump_cost(scene: str, steps: int, reps: int = 5) -> dict:
    """Seconds and bytes per trajectory frame, moving particles against every particle."""
    return dump_costs([scene], steps, reps)[0]


def dump_costs(names, steps: int, reps: int = 5) -> list:
    """:func:`dump_cost` of several scenes, their frames written in turn (scene after scene,
    moving and every particle, ``reps`` rounds) so that the machine's load weighs on each
    alike; the best of the rounds."""
    from rackstress import scenes
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    with tempfile.TemporaryDirectory() as tmp:
        runs = []
        try:
            for name in names:
                sc = scenes.build(name).with_steps(steps)
                deck = compile_deck(sc, "exact")
                d = Path(tmp) / name
                d.mkdir()
                deck.write_data(d / "particles.data")
                eng = LammpsRun(deck, d, dump_every=10 ** 8)
                runs.append((name, sc, deck, d, eng))
                eng.run_schedule()
            times = {(name, m): [] for name in names for m in ("moving", "all")}
            for _ in range(reps):
                for name, sc, deck, d, eng in runs:
                    for mode in ("moving", "all"):
                        deck.dump_all = mode == "all"
                        t = time.perf_counter()
                        eng.command(deck.write_dump_command(str(d / f"{mode}.dump")))
                        times[(name, mode)].append(time.perf_counter() - t)
                    deck.dump_all = False
            out = []
            for name, sc, deck, d, eng in runs:
                rec = {"scene": name, "n_particles": sc.n_particles, "after_iterations": steps}
                for mode in ("moving", "all"):
                    text = (d / f"{mode}.dump").read_bytes()
                    rec[mode] = {"s_per_frame": min(times[(name, mode)]),
                                 "bytes_per_frame": len(text) // reps,
                                 "atoms_per_frame": int(text.split(b"ITEM: NUMBER OF ATOMS\n")[1]
                                                        .split(b"\n")[0])}
                out.append(rec)
            return out
        finally:
            for *_, eng in runs:
                eng.close()


def variants(rundir: Path) -> dict:
    """The size of each way to write a finished run's VTK series and trajectory (issue 24), on
    ``rundir`` (a warm ``rackstress run``), in one process and in turn: the VTK series with every
    measure (``rackstress stress``) and with the leading one (``rackstress run``), its zlib
    streams made by ISA-L (what a run writes) or by zlib, under each of VTK's XML compressors,
    and the OVITO variant; the trajectory as text and gzip-compressed, a member a frame, by
    ISA-L (level :data:`~rackstress.engines.dumpio.GZ_LEVEL`: what a run writes, and 1) and by
    zlib (levels 1 and 6). Seconds are this process's CPU time."""
    import gzip

    from rackstress.engines.dumpio import GZ_LEVEL, dump_path, gz_member
    from rackstress.stress import export
    from rackstress.stress.post import compute_fields
    from rackstress.stress.rundata import load_run

    run_ = load_run(rundir)
    fields = compute_fields(run_)
    vtk = []
    with tempfile.TemporaryDirectory(prefix="rackstress-variants-") as tmp:
        for measures, fmt, comp, level, deflate in (("default", "paraview", "zlib", 1, "isal"),
                                                    ("all", "paraview", "zlib", 1, "isal"),
                                                    ("default", "paraview", "zlib", 1, "zlib"),
                                                    ("default", "paraview", "zlib", 6, "zlib"),
                                                    ("default", "paraview", "lz4", 1, "zlib"),
                                                    ("default", "paraview", "lzma", 1, "zlib"),
                                                    ("all", "ovito", "zlib", 1, "zlib")):
            d = Path(tmp) / f"{measures}-{fmt}-{comp}{level}-{deflate}"
            t = time.process_time()
            export.write_vtk(run_, fields, d, fmt=fmt, measures=measures, compressor=comp,
                             level=level, deflate=deflate)
            what = (f"zlib streams by ISA-L {level}" if deflate == "isal" and comp == "zlib"
                    else f"{comp} {level}")
            vtk.append({"measures": measures, "format": fmt,
                        "compressor": what if fmt == "paraview" else "none",
                        "bytes": _size(d), "s": time.process_time() - t})
    path = dump_path(rundir)
    text = gzip.decompress(path.read_bytes()) if path.name.endswith(".gz") else path.read_bytes()
    frames = [b"ITEM: TIMESTEP\n" + f for f in text.split(b"ITEM: TIMESTEP\n")[1:]]
    dump = [{"kind": "text", "bytes": len(text), "s": 0.0}]
    for kind, level, member in (("ISA-L", GZ_LEVEL, gz_member), ("ISA-L", 1, gz_member),
                                ("zlib", 1, None), ("zlib", 6, None)):
        t = time.process_time()
        if member is not None:
            n = sum(len(member(f, level)) for f in frames)
        else:
            n = sum(len(gzip.compress(f, level, mtime=0)) for f in frames)
        dump.append({"kind": f"gzip by {kind} {level}, a member a frame", "bytes": n,
                     "s": time.process_time() - t})
    return {"scene": json.loads((rundir / "scene.json").read_text()).get("scene"),
            "frames": len(frames), "vtk": vtk, "dump": dump}


def bytecode() -> Path:
    """Write the package's bytecode (``__pycache__``) where it is missing or stale, as pip does
    when it installs rackstress and as a user's first run does in an editable install: the
    runs measured then read it, as a user's warm ones do, also where
    ``PYTHONDONTWRITEBYTECODE`` keeps them from writing it (each would compile the package's
    modules it imports again: 0.05-0.1 s of CPU). Returns the package's folder."""
    import compileall

    import rackstress

    where = Path(rackstress.__file__).parent
    compileall.compile_dir(where, quiet=1)
    return where


def run(out: Path, scene_names=SCENES, repeat: int = 1, steps: dict | None = None,
        dump_steps: int = 600, log=print) -> dict:
    """Measure every scene (module docstring); ``steps``: iterations per scene where not the
    scene's own (the long ones, to keep the benchmark short)."""
    steps = steps or {}
    bytecode()
    rows, sizes = [], []
    with tempfile.TemporaryDirectory(prefix="rackstress-e2e-") as tmp:
        for name in scene_names:
            args = ["--steps", str(steps[name])] if name in steps else []
            for k in range(repeat):
                for cold, head in ((True, True), (False, True), (False, False)):
                    rundir = Path(tmp) / f"{name}"
                    log(f"e2e: {name} {'cold' if cold else 'warm'}"
                        f"{'' if head else ', no head start'} ({k + 1}/{repeat}) ...")
                    rec = _cli_run(name, rundir, cold, args, head)
                    rec.update(scene=name, steps=steps.get(name), repeat=k)
                    rows.append(rec)
                    if (name == "magpod-small" and not cold and head and k == 0 and not sizes
                            and rec.get("exit") == 0):
                        log("e2e: magpod-small's formats, each size ...")
                        sizes.append(variants(rundir))
    names = [n for n in ("magpod", "sediment-large") if n in scene_names]
    log(f"e2e: the trajectory's cost per frame ({', '.join(names)}) ...")
    dumps = dump_costs(names, dump_steps) if names else []
    return {"runs": rows, "dumps": dumps, "variants": sizes}


def targets(data: dict) -> list:
    """Issue 24's targets for magpod-small (README's first command), against these runs: each
    warm run's total over its own simulation, cold over warm (paired by repeat), the run
    directory's size."""
    runs = [r for r in data["runs"] if r["scene"] == "magpod-small" and "phases" in r]
    alone = [r for r in runs if not r.get("head_start", True)]
    runs = [r for r in runs if r.get("head_start", True)]
    warm = [r for r in runs if not r["cold"]]
    cold = {r["repeat"]: r for r in runs if r["cold"]}
    if not warm:
        return []
    ratios = [r["wall_s"] / r["phases"]["simulation"] for r in warm]
    own = {a["repeat"]: a["phases"]["simulation"] for a in alone if not a["cold"]}
    honest = [r["wall_s"] / own[r["repeat"]] for r in warm if r["repeat"] in own]
    extra = [cold[r["repeat"]]["wall_s"] - r["wall_s"] for r in warm if r["repeat"] in cold]
    size = max(r["size_total"] for r in warm) / 1e6
    L = ["| magpod-small (README's first command) | target | measured here |", "|---|---|---|"]
    if honest:      # the simulation's own time: that of the run beside it without a head start
        L.append("| warm total / the simulation's own time (the *no head start* run of the "
                 f"same round) | ≤ 2× | {', '.join(f'{x:.2f}×' for x in honest)} |")
    L.append(f"| warm total / its simulation (beside the head start) | | "
             f"{', '.join(f'{x:.2f}×' for x in ratios)} |")
    if extra:
        L.append(f"| cold − warm | ≤ 3 s | {', '.join(f'{x:+.2f} s' for x in extra)} |")
    L.append(f"| run directory | ≤ 30 MB | {size:.1f} MB |")
    if alone:
        L.append("| the simulation, warm: beside the head start / without it (`RACKSTRESS_HEAD_"
                 "START=0`) | not slower | "
                 + ", ".join(f"{r['phases']['simulation']:.2f} / {a['phases']['simulation']:.2f} s"
                             for r in warm for a in alone if a["repeat"] == r["repeat"]) + " |")
    return L


def markdown(data: dict, machine: dict) -> str:
    """docs/benchmarks/e2e.md."""
    load = machine.get("load_avg_at_start")
    load = ", ".join(f"{x:.1f}" for x in load) if load else "?"
    L = ["# README's first command, end to end",
         "",
         "`rackstress bench e2e` (`workflow/rackstress/bench/e2e.py`): `rackstress run SCENE "
         "--out DIR --overwrite` as a user runs it (the package's bytecode written first, as "
         "an install does: `PYTHONDONTWRITEBYTECODE` would otherwise have each run compile "
         "its modules again), cold (an empty cache: kernels compiled, "
         "Eq. 5's limit predicted) and warm, with the engine path of this branch (numba "
         "callback kernels or the compiled plugin, whichever the run found), "
         "interleaved; the phases from the run's own records, the run directory by file. "
         "The run paints what its report shows (the sheet, the plots, the 3D view; the "
         "full-size pictures are `rackstress render RUNDIR` away) and drops its default "
         "checkpoints once finished. Its post-processing runs in a process forked before "
         "the first step (the *head start*, docs/output.md): it loads its modules, and from "
         "the run's first steps on (a run under 10 s) measures the frames LAMMPS has "
         "written (*measured while running*: frames of the run's; the measures column is "
         "what is left after it), prepares the pictures' render window and compresses the "
         "frames, then checks the guard rails and post-processes the finished run; the "
         "3D view is built by the plots' process after the plots. The rows *no "
         "head start* run with `RACKSTRESS_HEAD_START=0` (nothing beside the simulation), "
         "interleaved with the others: their simulation time is the simulation's own, what "
         "the verdict divides the total by. "
         "Its VTK frames carry the leading measure and displacement, the resting sediment "
         "once (`vtk/rest.vtp`), and its trajectory is `trajectory.dump.gz` once finished "
         "(docs/output.md). "
         f"Machine: {machine.get('cores', '?')} cores, load average at the start {load}; "
         "each row gives the 1-minute load when it started "
         "(shared with other jobs: compare within a row, not across runs).",
         "",
         "| scene | iterations | cache | load | simulation | measured while running | "
         "measures | pictures (VTK beside) | start-up and the rest | total | "
         "total / simulation | total / simulation alone | run directory |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    # the simulation's own time: the warm run of the same scene and round without a head start
    own = {(r["scene"], r["repeat"]): r["phases"]["simulation"] for r in data["runs"]
           if "phases" in r and not r["cold"] and not r.get("head_start", True)}
    for r in data["runs"]:
        if "phases" not in r:
            L.append(f"| {r['scene']} | | {'cold' if r['cold'] else 'warm'} | "
                     f"{r.get('load_at_start', float('nan')):.1f} | failed "
                     f"(exit {r['exit']}) | | | | | {r['wall_s']:.1f} s | | | |")
            continue
        p = r["phases"]
        its = r["steps"] or "the scene's"
        ahead = (f"{r['frames_measured_while_running']} of {r['frames']}"
                 if "frames" in r else "")
        L.append(f"| {r['scene']} | {its} | "
                 f"{'cold' if r['cold'] else 'warm'}"
                 f"{'' if r.get('head_start', True) else ', no head start'} | "
                 f"{r.get('load_at_start', float('nan')):.1f} | {p['simulation']:.2f} s | "
                 f"{ahead} | {p['measures']:.2f} s | {p['pictures']:.2f} s "
                 f"({p['vtk (beside the pictures)']:.2f} s) | {p['start-up and the rest']:.2f} s"
                 f" | {r['wall_s']:.2f} s | {r['wall_s'] / max(p['simulation'], 1e-9):.2f}× | "
                 + (f"{r['wall_s'] / own[(r['scene'], r.get('repeat'))]:.2f}×"
                    if (r["scene"], r.get("repeat")) in own else "")
                 + f" | {r['size_total'] / 1e6:.1f} MB |")
    cpu = [r for r in data["runs"] if r.get("cpu_after")]
    if cpu:
        def c(x):
            return "" if x is None else f"{x:.2f} s"
        L += ["", "The simulation's wall time by the driver's loop (`summary.json`'s `driver_s`: "
              "in LAMMPS' chunks of steps, in the watchdog after each, and between them: "
              "checkpoints, progress), then after the simulation, where four processes share "
              "the cores, CPU seconds by process (each one's own clock), and the whole "
              "command's (its children's included).", "",
              "| scene | cache | simulation: chunks / watchdog / between | "
              "pictures (this process) | VTK writer | plots | 3D view | "
              "post-processing, wall | the command's CPU |",
              "|---|---|---|---|---|---|---|---|---|"]
        for r in cpu:
            a, p, d = r["cpu_after"], r["phases"], r.get("driver") or {}
            split = (" / ".join(f"{d[k]:.2f}" for k in ("steps_s", "checks_s", "between_s"))
                     + " s") if d else ""
            L.append(f"| {r['scene']} | {'cold' if r['cold'] else 'warm'}"
                     f"{'' if r.get('head_start', True) else ', no head start'} | {split} | "
                     f"{c(a.get('pictures'))} | {c(a.get('vtk'))} | {c(a.get('plots'))} | "
                     f"{c(a.get('view3d'))} | {p['measures'] + p['pictures']:.2f} s | "
                     f"{c(r.get('cpu_s'))} |")
    L += [""] + targets(data)
    notes = {(r["scene"], r["exit"], r["note"]) for r in data["runs"]
             if r.get("exit") and r.get("note")}
    for scene, code, note in sorted(notes):
        L += ["", f"{scene}: exit {code} — {note}"]
    L += ["", "## The run directory, by file (warm runs)", ""]
    for r in data["runs"]:
        if r.get("cold") or "sizes" not in r or r.get("repeat") or not r.get("head_start", True):
            continue
        L.append(f"**{r['scene']}** ({r['size_total'] / 1e6:.1f} MB): "
                 + ", ".join(f"`{k}` {v / 1e6:.2f} MB" for k, v in
                             sorted(r["sizes"].items(), key=lambda kv: -kv[1]) if v > 1e4))
        L.append("")
    for v in data.get("variants") or []:
        L += [f"## What each format costs ({v['scene']}, {v['frames']} frames)", "",
              "The warm run's directory written again each way, in one process and in turn "
              "(`bench.e2e.variants`, CPU seconds); the first row of each table is what "
              "`rackstress run` writes.", "",
              "| VTK series | measures | arrays | size | time |", "|---|---|---|---|---|"]
        order = sorted(v["vtk"], key=lambda x: (x["measures"] != "default"
                                                 or "ISA-L" not in x["compressor"]))
        for x in order:
            what = ("the leading one and displacement" if x["measures"] == "default"
                    else "every one")
            L.append(f"| {x['format']} | {what} | {x['compressor']} | "
                     f"{x['bytes'] / 1e6:.2f} MB | {x['s']:.2f} s |")
        L += ["", "| trajectory | size | time |", "|---|---|---|"]
        for x in v["dump"][1:2] + v["dump"][:1] + v["dump"][2:]:    # the run's first
            L.append(f"| {x['kind']} | {x['bytes'] / 1e6:.2f} MB | {x['s']:.2f} s |")
        L.append("")
    if data["dumps"]:
        L += ["## The trajectory's cost per frame", "",
              "One frame written as the run writes it (the moving group: the robot and the "
              "sediment it reached) and as `--dump-all` writes it, after the scene's first "
              "iterations (the robot on the sediment); best of 5, the scenes' frames written "
              "in turn in one process.", "",
              "| scene | particles | after | moving: atoms, bytes, time | every particle: "
              "atoms, bytes, time |", "|---|---|---|---|---|"]
        for d in data["dumps"]:
            m, a = d["moving"], d["all"]
            L.append(f"| {d['scene']} | {d['n_particles']:,} | {d['after_iterations']} | "
                     f"{m['atoms_per_frame']:,}, {m['bytes_per_frame'] / 1e6:.2f} MB, "
                     f"{m['s_per_frame'] * 1e3:.1f} ms | {a['atoms_per_frame']:,}, "
                     f"{a['bytes_per_frame'] / 1e6:.2f} MB, {a['s_per_frame'] * 1e3:.1f} ms |")
        if len(data["dumps"]) == 2:
            mag, large = data["dumps"]
            r = large["moving"]["s_per_frame"] / mag["moving"]["s_per_frame"]
            r_all = large["all"]["s_per_frame"] / mag["all"]["s_per_frame"]
            L += ["", f"sediment-large's frame costs {r:.2f}× magpod's (every particle: "
                  f"{r_all:.1f}×)."]
    return "\n".join(L) + "\n"
