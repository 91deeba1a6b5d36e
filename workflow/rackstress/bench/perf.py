"""``rackstress bench perf``: wall time per 1200 MagPod iterations, and where it goes.

Every configuration runs the full ``magpod`` scene (33,689 particles) for ``steps`` iterations
(default 1200: the first gait phase) in its own process, so that its peak memory
(``resource.getrusage(...).ru_maxrss``; under MPI the largest over the ranks, and their sum) is
its own: the reference engine, LAMMPS exact and fast mode, each LAMMPS mode serial and under
``mpiexec -n 2`` (the venv's ``mpiexec``). All configurations run in one invocation, one after
another, and are reported as ratios to LAMMPS exact serial and to the reference engine (the
machine is shared: absolute seconds drift, ratios within one run hold better). The paper's own
figure (142 s per 1200 iterations, one thread, 1.83 GHz) is a row.

Rows are (engine, mode, ranks[, kernels[, scene[, steps[, particles]]]]): ``kernels`` is the
callback's compiled (numba) path or its NumPy path (the reference implementation); ``scene`` lets
one invocation cover ``magpod-small`` (a whole gait cycle, 4800 iterations: its target is the
cycle's time), ``magpod`` and ``sediment-large`` (one million particles, 200 iterations); a row's
own steps hold unless ``--quick``.
Each row reports wall time and CPU time per iteration (the machine is shared: CPU time drifts
less). Compiling the kernels is never counted in a figure: it happens in setup, and the
"kernels" section measures it apart — the first compile (a fresh cache directory) and the warm
start that loads the disk cache.

Profile, per LAMMPS configuration: the Python callback's share (``PyForces.__call__`` timed by
a wrapper, summed over the run and over the ranks' own calls) and LAMMPS' own "MPI task timing
breakdown" of one extra chunk (``run N pre no post yes`` with the log switched to a temporary
file, N = ``profile_steps``), parsed from that log.
"""
from __future__ import annotations

import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rackstress.bench import fmt, machine, md_table, out_dir, write_json
from rackstress.engines.driver import drive

PAPER = {"config": "paper (Rönkkö et al.): one thread, 1.83 GHz", "s_per_1200": 142.0,
         "n_particles": 33689}
#: sediment-large with a bed four times as long: 4400 x 910 = 4,004,000 sediment particles
#: (a scene name with ``--set`` overrides after a colon, as the worker reads it)
HUGE = "sediment-large:sediment_nx=4400"
#: the same bed with sediment-large's former fixed weight of a moving particle (150): balance rcb
#: then cuts across the track's length, 5,600 units from the robot, which stays whole on one rank
#: with fewer ghosts between the ranks (~6,000 across the bed's width, against ~32,000 along its
#: length where the default weight, the bed's own, cuts through the robot: scenes/large.py)
HUGE_WHOLE = HUGE + ",robot_weight=150"
CONFIGS = (("reference", "exact", 1), ("lammps", "exact", 1, "numpy"),
           ("lammps", "exact", 1, "numba"), ("lammps", "fast", 1, "numba"),
           ("lammps", "exact", 2, "numba"), ("lammps", "fast", 2, "numba"),
           ("lammps", "exact", 1, "numba", "magpod-small", 4800),
           ("lammps", "exact", 1, "numpy", "magpod-small", 4800),
           ("lammps", "exact", 1, "numba", "magpod", None, "all"),
           # the same iterations as magpod's (its first 1200): the ratio of the two is a target
           ("lammps", "exact", 1, "numba", "sediment-large", None),
           ("lammps", "exact", 1, "numba", "sediment-large", 200, "all"),
           ("lammps", "exact", 2, "numba", "sediment-large", 200),
           # the compiled plugin (docs/plugin.md), one and two ranks
           ("lammps", "exact", 1, "plugin"), ("lammps", "exact", 2, "plugin"),
           ("lammps", "exact", 1, "plugin", "magpod", None, "all"),
           ("lammps", "exact", 1, "plugin", "magpod-small", 4800),
           # the numba row's iterations (the first 1200, as magpod's): plugin against numba
           ("lammps", "exact", 1, "plugin", "sediment-large", None),
           ("lammps", "exact", 1, "plugin", "sediment-large", 200),
           ("lammps", "exact", 2, "plugin", "sediment-large", 200),
           # the larger sediment (>= 4 M particles, what a cluster user brings; a bed four times as long)
           ("lammps", "exact", 1, "plugin", HUGE, 200),
           ("lammps", "exact", 2, "plugin", HUGE, 200),
           ("lammps", "exact", 2, "plugin", HUGE_WHOLE, 200),
           # ... over a whole gait cycle (4 phases of 1200): what a user running the scene sees.
           # 200 iterations are mostly the first setup (the plugin's first pass over every
           # atom, LAMMPS' own over 4 M) and its first reneighbourings; a cycle has a phase
           # switch's setups and LAMMPS' reneighbourings (~30 ms each over 4 M atoms) too
           ("lammps", "exact", 1, "plugin", HUGE, 4800),
           ("lammps", "exact", 2, "plugin", HUGE, 4800),
           # the block (bench.scaling.block_scene: 250,000 particles bound within(1.5)):
           # the plugin against the numba callback on one rank, and on two ranks
           ("lammps", "exact", 1, "numba", "block", 200),
           ("lammps", "exact", 1, "plugin", "block", 200),
           ("lammps", "exact", 2, "plugin", "block", 200))


def normalize(config, scene_name: str, steps: int) -> dict:
    """A row's configuration as a dict (defaults: numba kernels, the bench's scene and steps)."""
    engine, mode, ranks, *rest = config
    return {"engine": engine, "mode": mode, "ranks": int(ranks),
            "kernels": rest[0] if rest else "numba",
            "scene": rest[1] if len(rest) > 1 else scene_name,
            "steps": int(rest[2]) if len(rest) > 2 and rest[2] else steps,
            "particles": rest[3] if len(rest) > 3 else "active"}


class TimedCallback:
    """A stand-in for the runner's :class:`PyForces` that times every call."""

    def __init__(self, inner):
        self.inner, self.seconds, self.calls = inner, 0.0, 0

    def __call__(self, *args):
        t0 = time.perf_counter()
        try:
            return self.inner(*args)
        finally:
            self.seconds += time.perf_counter() - t0
            self.calls += 1

    def __getattr__(self, name):
        return getattr(self.inner, name)


def parse_breakdown(log: str) -> dict:
    """The 'MPI task timing breakdown' table of a LAMMPS log: section → (avg s, % total)."""
    out = {}
    m = re.search(r"MPI task timing breakdown:\n(.*?)\n\n", log, re.S)
    if not m:
        return out
    for line in m.group(1).splitlines():
        parts = [x.strip() for x in line.split("|")]
        if len(parts) >= 6 and parts[0] and parts[0] not in ("Section",) \
                and not parts[0].startswith("-"):
            try:
                out[parts[0]] = {"avg_s": float(parts[2]), "pct": float(parts[5])}
            except ValueError:
                continue
    loop = re.search(r"Loop time of ([\d.eE+-]+) on (\d+) procs for (\d+) steps", log)
    if loop:
        out["_loop"] = {"seconds": float(loop.group(1)), "procs": int(loop.group(2)),
                        "steps": int(loop.group(3))}
    return out


# ---------------------------------------------------------------------------- the worker
def build_scene(name: str):
    """A built-in scene, ``NAME`` or ``NAME:key=value,key=value`` (``--set`` overrides), or
    ``block``: bench.scaling's block (a bound lattice of 250,000 particles)."""
    from rackstress import scenes
    from rackstress.scenes.builtins import parse_overrides

    if name == "block":
        from rackstress.bench.scaling import block_scene

        return block_scene()
    base, _, sets = name.partition(":")
    return scenes.build(base, **parse_overrides(sets.split(",") if sets else ()))


def _no_shim() -> float:
    return 0.0


def _mpi_inside():
    """The thread CPU seconds spent inside MPI calls so far, read from bench.scaling's PMPI shim
    (``rs_mpi_cpu_inside``) when it is preloaded (LD_PRELOAD); else a function returning 0."""
    import ctypes

    try:
        fn = ctypes.CDLL(None).rs_mpi_cpu_inside
    except (AttributeError, OSError):
        return _no_shim
    fn.restype = ctypes.c_double
    fn.argtypes = []
    return fn


def worker(engine: str, mode: str, steps: int, profile_steps: int, scene_name: str) -> dict:
    """One configuration, in this process (all ranks of COMM_WORLD); rank 0 returns the result."""
    sc = build_scene(scene_name).with_steps(steps)
    t0 = time.perf_counter()
    res = {"engine": engine, "mode": mode, "steps": steps, "n_particles": sc.n_particles}
    if engine == "reference":
        from rackstress.engines.reference import Reference

        ref = Reference(sc)
        res["setup_s"] = time.perf_counter() - t0
        t0, c0 = time.perf_counter(), time.process_time()
        drive(ref)
        res["wall_s"] = time.perf_counter() - t0
        res["cpu_s"] = time.process_time() - c0
        res["ranks"] = 1
        res["maxrss_mb"] = res["maxrss_sum_mb"] = \
            resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        return res
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    # kernels "plugin": the compiled styles (docs/plugin.md) instead of the Python callback
    deck = compile_deck(sc, mode, measure_fast=True,
                        active_only=os.environ.get("RACKSTRESS_PARTICLES", "active") == "active",
                        plugin=os.environ.get("RACKSTRESS_KERNELS") == "plugin")
    res["plugin"] = deck.plugin
    res["passive"] = list(deck.passive)
    runner = LammpsRun(deck, None, log=False)
    comm = runner.comm
    if runner.py is not None:
        res["kernels"], res["kernel_warm"] = runner.py.kernels, runner.py.warm
        runner.py = TimedCallback(runner.py)
    res["setup_s"] = time.perf_counter() - t0
    inside = _mpi_inside()
    comm.Barrier()
    t0, c0 = time.perf_counter(), time.process_time()
    w0, in0 = time.thread_time(), inside()
    outcome = drive(runner)
    # the driver's split (rank 0): LAMMPS' chunks, the watchdog after them, and the rest, which
    # is the phase switches (their setups: run 0 twice, the velocity shifts) and the final gather
    res["driver_s"] = outcome.timings
    cpu = time.process_time() - c0
    work = time.thread_time() - w0 - (inside() - in0)
    comm.Barrier()
    res["wall_s"] = time.perf_counter() - t0
    all_cpu = comm.gather(cpu, root=0)
    all_work = comm.gather(work, root=0)
    cb = runner.py.seconds if runner.py is not None else 0.0
    calls = runner.py.calls if runner.py is not None else 0
    # LAMMPS' own breakdown of one more chunk, logged to a temporary file
    breakdown = {}
    if profile_steps:
        tmp = tempfile.mkdtemp(prefix="rs-perf-") if comm.Get_rank() == 0 else None
        tmp = comm.bcast(tmp, root=0)
        cb0 = runner.py.seconds if runner.py is not None else 0.0
        runner.command(f"log {tmp}/log.lammps")
        tp = time.perf_counter()
        runner.command(f"run {profile_steps} pre no post yes")
        prof_wall = time.perf_counter() - tp
        runner.command("log none")
        cb_prof = (runner.py.seconds if runner.py is not None else 0.0) - cb0
        if comm.Get_rank() == 0:
            breakdown = parse_breakdown(Path(tmp, "log.lammps").read_text())
            shutil.rmtree(tmp, ignore_errors=True)     # the log is read: leave nothing behind
            breakdown["_profile_wall_s"] = prof_wall
        cb_prof_all = comm.gather(cb_prof, root=0)
        if comm.Get_rank() == 0:
            breakdown["_callback_s_per_rank"] = cb_prof_all
    runner.close()
    res["load"] = os.getloadavg()[0]
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    all_rss = comm.gather(rss, root=0)
    all_cb = comm.gather(cb, root=0)
    all_calls = comm.gather(calls, root=0)
    if comm.Get_rank() != 0:
        return {}
    res.update(ranks=comm.Get_size(), maxrss_mb=max(all_rss), maxrss_sum_mb=sum(all_rss),
               cpu_s=max(all_cpu), cpu_s_per_rank=all_cpu,
               # with bench.scaling's PMPI shim preloaded: each rank's thread CPU time outside
               # MPI calls (its own work, whatever the load); else its thread CPU time
               work_s_per_rank=all_work, work_outside_mpi=inside is not _no_shim,
               callback_s_per_rank=all_cb, callback_calls=all_calls[0],
               callback_share=max(all_cb) / res["wall_s"] if res["wall_s"] else None,
               breakdown=breakdown, python_operators=[f"{r.target} <- {r.op.kind}"
                                                      for r in deck.python_ops],
               # fast mode where the callback stays is refused by `rackstress run`
               offered=not (mode == "fast" and deck.python_ops))
    return res


def spawn(engine: str, mode: str, ranks: int, steps: int, profile_steps: int,
          scene_name: str, kernels: str = "numba", env: dict | None = None,
          particles: str = "active", shim: Path | None = None) -> dict:
    """One configuration in its own process (``mpiexec -n ranks`` when ranks > 1); ``shim``:
    bench.scaling's PMPI shim preloaded into every rank (each rank's CPU time outside MPI)."""
    cmd = [sys.executable, "-m", "rackstress.bench.perf", "--worker", engine, mode, str(steps),
           str(profile_steps), scene_name]
    if shim is not None:
        env = {**(env or {}), "LD_PRELOAD": str(shim)}
    if ranks > 1:
        mpiexec = Path(sys.executable).parent / "mpiexec"
        pre = ["-genv", "LD_PRELOAD", str(shim)] if shim is not None else []
        cmd = [str(mpiexec), *pre, "-n", str(ranks)] + cmd
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1", "RACKSTRESS_KERNELS": kernels,
                               "RACKSTRESS_PARTICLES": particles, **(env or {})})
    if proc.returncode != 0:
        return {"engine": engine, "mode": mode, "ranks": ranks, "status": "failed",
                "error": (proc.stderr or proc.stdout)[-2000:]}
    line = [x for x in proc.stdout.splitlines() if x.startswith("RSPERF ")][-1]
    res = json.loads(line[len("RSPERF "):])
    res["status"] = "ok"
    res["process_s"] = time.perf_counter() - t0
    return res


def measure_kernels(echo=print) -> dict:
    """Compile time of the callback's kernels, apart from every figure: the first compile
    (into a fresh cache directory) and the warm start (a second process loading that cache),
    each in its own process."""
    code = ("import json, time; t = time.perf_counter(); "
            "from rackstress.model import kernels as K; w = K.warm(); "
            "print('RSKERN ' + json.dumps({'import_s': time.perf_counter() - t - w['seconds'], "
            "'warm_s': w['seconds']}))")
    out = {}
    with tempfile.TemporaryDirectory(prefix="rs-numba-") as cache:
        for key in ("first_compile", "warm_start"):
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                  env={**os.environ, "NUMBA_CACHE_DIR": cache})
            if proc.returncode != 0:
                out[key] = {"status": "failed", "error": proc.stderr[-1000:]}
                continue
            line = [x for x in proc.stdout.splitlines() if x.startswith("RSKERN ")][-1]
            out[key] = {**json.loads(line[len("RSKERN "):]), "process_s": time.perf_counter() - t0}
            echo(f"  kernels, {key.replace('_', ' ')}: {out[key]['warm_s']:.2f} s")
    return out


#: The plugin's 1- and 2-rank rows of a scene (same steps) run as pairs, interleaved this many
#: times (1, 2, 1, 2: the machine is shared), with bench.scaling's PMPI shim in every rank; a
#: row keeps its best wall time and reports every run's (``repeats``) and each rank's CPU time
#: outside MPI calls (``work_ms_per_it``: the work, whatever the load)
INTERLEAVE = 2


def _pairs(cs: list[dict]) -> dict:
    """{index of a plugin row: indices of its interleaved group} for the plugin's 1- and 2-rank
    rows of one scene over the same steps (exact mode, active particles), with the numba
    callback's one-rank row of that scene and steps if there is one."""
    groups: dict = {}
    for i, c in enumerate(cs):
        if c["engine"] == "lammps" and c["mode"] == "exact" and c["particles"] == "active" \
                and (c["kernels"] == "plugin" or (c["kernels"] == "numba" and c["ranks"] == 1)):
            # a scene with another balance weight joins its scene's group
            scene = re.sub(r"[:,]robot_weight=[^,]*", "", c["scene"])
            groups.setdefault((scene, c["steps"]), []).append(i)
    return {i: g for g in groups.values() if len({(cs[k]["ranks"], cs[k]["kernels"]) for k in g}) > 1
            and any(cs[k]["kernels"] == "plugin" for k in g) for i in g}


def _key(r: dict) -> tuple:
    return (r.get("engine"), r.get("mode"), r.get("ranks"), r.get("kernels"), r.get("scene"),
            r.get("steps"), r.get("particles"))


def run_bench(out: Path | None = None, steps: int = 1200, quick: bool = False,
              profile_steps: int = 100, scene_name: str = "magpod", configs=CONFIGS,
              echo=print, kernel_times: bool = True, interleave: int = INTERLEAVE,
              only=()) -> dict:
    """``only``: measure only the rows whose scene is one of these (``sediment-large:
    sediment_nx=4400`` also takes its ``robot_weight`` variant) and keep every other row of the
    ``perf.json`` already in ``out``; the page says which rows were measured when."""
    from rackstress.bench.scaling import _shim

    out = out_dir(out)
    if quick:
        steps = min(steps, 300)
        profile_steps = min(profile_steps, 50)
    t0 = time.perf_counter()
    load0 = machine()["load_avg_at_start"]
    kernels = measure_kernels(echo) if kernel_times and not only else None
    cs = []
    for config in configs:
        c = normalize(config, scene_name, steps)
        if quick:
            c["steps"] = min(c["steps"], steps)
        if only and re.sub(r"[:,]robot_weight=[^,]*", "", c["scene"]) not in only:
            continue
        cs.append(c)
    pairs = _pairs(cs)
    work = Path(tempfile.mkdtemp(prefix="rs-perf-shim-"))
    shim = _shim(work) if pairs else None
    done: dict = {}
    rows = []
    for i, c in enumerate(cs):
        engine, mode, ranks, n = c["engine"], c["mode"], c["ranks"], c["steps"]
        kern = c["kernels"] if engine == "lammps" else "—"
        prof = profile_steps if engine == "lammps" else 0
        if i in pairs and i not in done:
            # the group's rows interleaved (1, 2, 1, 2, ...), each keeping its best wall time
            runs = {k: [] for k in pairs[i]}
            for _ in range(max(1, interleave)):
                for k in pairs[i]:
                    ck = cs[k]
                    runs[k].append(spawn(engine, mode, ck["ranks"], n, prof, ck["scene"],
                                         ck["kernels"], particles=ck["particles"], shim=shim))
            for k, got in runs.items():
                ok = [g for g in got if g["status"] == "ok"]
                best = min(ok, key=lambda g: g["wall_s"]) if ok else got[-1]
                if ok:
                    best["repeats"] = [{"wall_s": g["wall_s"], "work_s_per_rank":
                                        g.get("work_s_per_rank"), "load": g.get("load")}
                                       for g in got if g["status"] == "ok"]
                done[k] = best
        r = done.get(i) or spawn(engine, mode, ranks, n, prof, c["scene"], c["kernels"],
                                 particles=c["particles"])
        r.update(ranks=ranks, scene=c["scene"], kernels=kern, steps=n,
                 particles=c["particles"] if engine == "lammps" else "all")
        label = (f"  {c['scene']:14s} {engine:9s} {mode:5s} {kern:5s} {r['particles']:6s} "
                 f"ranks={ranks}")
        if r["status"] == "ok":
            if r.get("work_outside_mpi"):
                r["work_ms_per_it"] = [1e3 * w / n for w in r["work_s_per_rank"]]
            r["s_per_1200"] = r["wall_s"] * 1200.0 / n
            r["ms_per_it"] = 1e3 * r["wall_s"] / n
            r["cpu_ms_per_it"] = 1e3 * r["cpu_s"] / n if "cpu_s" in r else None
            r["particle_steps_per_s"] = r["n_particles"] * n / r["wall_s"]
            echo(f"{label}: {r['ms_per_it']:.3f} ms/it wall"
                 + (f", {r['cpu_ms_per_it']:.3f} ms/it CPU" if r.get("cpu_ms_per_it") else "")
                 + f", {r['maxrss_mb']:.0f} MB peak")
        else:
            echo(f"{label}: FAILED {r['error'][-300:]}")
        rows.append(r)
    shutil.rmtree(work, ignore_errors=True)
    earlier = {}
    if only and (out / "perf.json").is_file():
        earlier = json.loads((out / "perf.json").read_text())
        mine = {_key(r) for r in rows}
        rows = [r for r in earlier.get("rows", []) if _key(r) not in mine] + rows
        kernels = earlier.get("kernel_compile")

    def ratio(engine, mode, ranks, kern):
        key = f"x_{engine}_{mode}_{ranks}"
        b = next((r for r in rows if r["status"] == "ok" and r["scene"] == scene_name
                  and (r["engine"], r["mode"], r["ranks"]) == (engine, mode, ranks)
                  and (engine == "reference" or r["particles"] == "active")
                  and r["kernels"] in (kern, "—")), None)
        for r in rows:
            if r["status"] == "ok" and b is not None and r["scene"] == scene_name:
                r[key] = r["wall_s"] / r["steps"] / (b["wall_s"] / b["steps"])
        return b
    ratio("lammps", "exact", 1, "numba") or ratio("lammps", "exact", 1, "numpy")
    ratio("reference", "exact", 1, "—")
    paper = dict(PAPER)
    paper["particle_steps_per_s"] = paper["n_particles"] * 1200 / paper["s_per_1200"]
    data = {"benchmark": "perf", "scene": scene_name, "steps": steps, "quick": quick,
            "profile_steps": profile_steps, "machine": machine(), "rows": rows,
            "kernel_compile": kernels,
            "paper": paper, "targets": {"exact_1core_required_s_per_1200": 0.4,
                                        "exact_1core_aimed_s_per_1200": 0.25,
                                        "large_over_magpod_max": 2.0,
                                        "magpod_small_cycle_s_max": 2.0},
            "wall_s": time.perf_counter() - t0, "load_avg_at_end": machine()["load_avg_at_start"]}
    if earlier:
        # the page's header is the full run's; the rows measured now are named beside it
        data.update(machine=earlier.get("machine", data["machine"]),
                    load_avg_at_end=earlier.get("load_avg_at_end"),
                    quick=earlier.get("quick", quick),
                    # an earlier note on the same scenes: those rows are measured again now
                    remeasured=[m for m in earlier.get("remeasured", [])
                                if not set(m["scenes"]) <= set(only)] + [{
                        "scenes": sorted(only), "date": time.strftime("%Y-%m-%d %H:%M UTC",
                                                                      time.gmtime()),
                        "load_avg_at_start": load0,
                        "load_avg_at_end": machine()["load_avg_at_start"]}])
    write_json(out / "perf.json", data)
    (out / "perf.md").write_text(markdown(data))
    data["files"] = [str(out / f) for f in ("perf.json", "perf.md")]
    return data


HEADER = ["scene", "configuration", "kernels", "integrated", "ms / it (wall)", "ms / it (CPU)",
          "s / 1200 it", "× LAMMPS exact 1 rank", "× reference", "particle-steps/s",
          "peak RSS MB (max rank / sum)", "callback share", "setup s"]


def table_rows(data: dict) -> list:
    out = []
    for r in data["rows"]:
        name = r["engine"] if r["engine"] == "reference" else f"LAMMPS {r['mode']}"
        name += f", {r['ranks']} rank{'s' if r['ranks'] > 1 else ''}"
        if r.get("offered") is False:
            name += " (not offered for this scene)"
        scene, kern = r.get("scene", data["scene"]), r.get("kernels", "—")
        if r["status"] != "ok":
            out.append([scene, name, kern, r.get("particles", ""), "failed"] + [""] * 8)
            continue
        mem = f"{r['maxrss_mb']:.0f}" + (f" / {r['maxrss_sum_mb']:.0f}" if r["ranks"] > 1 else "")
        share = r.get("callback_share")
        cpu = r.get("cpu_ms_per_it")
        integ = "active only" if r.get("passive") else "all"
        out.append([scene, name, kern, integ, f"{r['ms_per_it']:.3f}",
                    f"{cpu:.3f}" if cpu is not None else "—", f"{r['s_per_1200']:.2f}",
                    fmt(r.get("x_lammps_exact_1")), fmt(r.get("x_reference_exact_1")),
                    f"{r['particle_steps_per_s']:.3g}", mem,
                    f"{share:.0%}" if share is not None else "—", f"{r['setup_s']:.1f}"])
    p = data["paper"]
    out.append([data["scene"], p["config"], "", "", "", "", f"{p['s_per_1200']:.0f}", "", "",
                f"{p['particle_steps_per_s']:.3g}", "", "", ""])
    return out


def breakdown_rows(data: dict) -> tuple[list, list]:
    sections = ["Pair", "Bond", "Neigh", "Comm", "Output", "Modify", "Other"]
    rows = []
    for r in data["rows"]:
        b = r.get("breakdown") or {}
        if not b or "_loop" not in b:
            continue
        name = (f"{r.get('scene', data['scene'])}: LAMMPS {r['mode']}, {r['ranks']} "
                f"rank{'s' if r['ranks'] > 1 else ''}, {r.get('kernels', 'numba')}, "
                f"{'active only' if r.get('passive') else 'all'}")
        loop = b["_loop"]
        cbs = b.get("_callback_s_per_rank") or [0.0]
        rows.append([name, f"{loop['seconds']:.3f} ({loop['steps']} steps)"]
                    + [f"{b[s]['pct']:.1f}" if s in b else "—" for s in sections]
                    + [f"{100 * max(cbs) / loop['seconds']:.1f}" if loop["seconds"] else "—"])
    return ["configuration", "loop time"] + [f"{s} %" for s in sections] + \
        ["Python callback % (in Modify)"], rows


def _row(data, scene, kernels="numba", ranks=1, mode="exact", particles="active", steps=None):
    return next((r for r in data["rows"] if r["status"] == "ok" and r["engine"] == "lammps"
                 and r.get("scene", data["scene"]) == scene and r["mode"] == mode
                 and r["ranks"] == ranks and r.get("kernels") == kernels
                 and r.get("particles", "active") == particles
                 and (steps is None or r["steps"] == steps)), None)


def verdict(data: dict) -> list[str]:
    """The speed targets, met or not (LAMMPS exact, one rank, compiled kernels)."""
    out = []
    ex = _row(data, data["scene"]) or _row(data, data["scene"], "numpy")
    if ex is None:
        out.append("- LAMMPS exact on one rank with the callback did not run.")
    else:
        out += _verdict_callback(data, ex)
    return out + _verdict_plugin(data)


def _verdict_callback(data: dict, ex: dict) -> list[str]:
    t, out = data["targets"], []
    s = ex["s_per_1200"]
    cpu = ex["cpu_ms_per_it"] * 1.2 if ex.get("cpu_ms_per_it") else None
    best = min(s, cpu) if cpu is not None else s
    req, aim = t["exact_1core_required_s_per_1200"], t["exact_1core_aimed_s_per_1200"]
    out += [f"- `{data['scene']}`, exact, one core, {ex.get('kernels')} kernels: {s:.2f} s per "
            f"1200 iterations in wall time" + (f", {cpu:.2f} s in CPU time" if cpu else "")
            + f" ({data['paper']['s_per_1200'] / best:.0f}× the paper's figure); "
            f"required ≤ {req:g} s: {'**met**' if best <= req else '**not met**'}; aimed ≤ "
            f"{aim:g} s: {'**met**' if best <= aim else '**not met**'}."]
    npy = _row(data, data["scene"], "numpy")
    if npy is not None and ex is not npy:
        out.append(f"- Compiled kernels against the NumPy path, same scene: "
                   f"{npy['ms_per_it'] / ex['ms_per_it']:.2f}× faster in wall time"
                   + (f", {npy['cpu_ms_per_it'] / ex['cpu_ms_per_it']:.2f}× in CPU time"
                      if ex.get("cpu_ms_per_it") and npy.get("cpu_ms_per_it") else "") + ".")
    large, mag = _row(data, "sediment-large"), _row(data, "magpod")
    if large is not None and mag is not None:
        q = large["ms_per_it"] / mag["ms_per_it"]
        if large.get("cpu_ms_per_it") and mag.get("cpu_ms_per_it"):
            q = min(q, large["cpu_ms_per_it"] / mag["cpu_ms_per_it"])
        same = " over the same iterations" if large["steps"] == mag["steps"] else ""
        out.append(f"- sediment-large per iteration / magpod's{same} (the better of wall and "
                   f"CPU time): {q:.1f}× "
                   f"(target ≤ {t['large_over_magpod_max']:g}×: "
                   f"{'**met**' if q <= t['large_over_magpod_max'] else '**not met**'}).")
    small = _row(data, "magpod-small")
    if small is not None:
        cyc = min(small["ms_per_it"], small.get("cpu_ms_per_it") or small["ms_per_it"]) * 4.8
        how = ("measured over the whole cycle" if small["steps"] >= 4800
               else f"from {small['steps']} iterations")
        out.append(f"- A gait cycle of magpod-small (4800 iterations, {how}; the better of "
                   f"wall and CPU time): {cyc:.2f} s "
                   f"(target ≤ {t['magpod_small_cycle_s_max']:g} s: "
                   f"{'**met**' if cyc <= t['magpod_small_cycle_s_max'] else '**not met**'}).")
    return out


def _verdict_plugin(data: dict) -> list[str]:
    out = []
    plug, numba = _row(data, data["scene"], "plugin"), _row(data, data["scene"])
    if plug is not None:
        cpu = plug["cpu_ms_per_it"] * 1.2 if plug.get("cpu_ms_per_it") else None
        out.append(f"- `{data['scene']}`, the compiled plugin, one core: {plug['s_per_1200']:.2f} s "
                   "per 1200 iterations in wall time" + (f", {cpu:.2f} s in CPU time" if cpu else "")
                   + " (target ≤ 0.20 s: " + ("**met**" if min(plug["s_per_1200"], cpu or 1e9)
                                               <= 0.20 else "**not met**") + ")" + (
                       f"; against the numba callback {numba['ms_per_it'] / plug['ms_per_it']:.2f}× "
                       "(wall)" + (f", {numba['cpu_ms_per_it'] / plug['cpu_ms_per_it']:.2f}× (CPU)"
                                   if cpu and numba.get("cpu_ms_per_it") else "")
                       if numba is not None else "") + " (> 1: the plugin is faster).")
    for scene in ("magpod-small", "sediment-large", "block"):
        plug, numba = _row(data, scene, "plugin"), _row(data, scene)
        if plug is not None and numba is not None and scene != data["scene"]:
            same = "" if plug["steps"] == numba["steps"] else (
                f" ({plug['steps']} against {numba['steps']} iterations)")
            out.append(f"- `{scene}`, the plugin against the numba callback, one core{same}: "
                       f"{numba['ms_per_it'] / plug['ms_per_it']:.2f}× (wall)"
                       + (f", {numba['cpu_ms_per_it'] / plug['cpu_ms_per_it']:.2f}× (CPU)"
                          if plug.get("cpu_ms_per_it") and numba.get("cpu_ms_per_it") else "")
                       + " (> 1: the plugin is faster).")
    for scene, two in ((scene, r) for scene in (data["scene"], "sediment-large", HUGE,
                                                HUGE_WHOLE, "block")
                       for r in data["rows"] if r is _row(data, scene, "plugin", 2, steps=r["steps"])):
        # the one-rank row over the same iterations, if there is one
        base = HUGE if scene == HUGE_WHOLE else scene
        one = two and (_row(data, base, "plugin", steps=two["steps"]) or _row(data, base, "plugin"))
        if one is not None and two is not None:
            line = (f"- `{scene}` ({one['n_particles']:,} particles, {two['steps']} iterations), "
                    f"the plugin on 2 ranks against 1: {one['ms_per_it'] / two['ms_per_it']:.2f}× "
                    "(best wall times; > 1: faster)")
            if one.get("repeats") and two.get("repeats"):
                line += (", every run interleaved: 1 rank " + " / ".join(
                    f"{g['wall_s']:.3f}" for g in one["repeats"]) + " s, 2 ranks " + " / ".join(
                    f"{g['wall_s']:.3f}" for g in two["repeats"]) + " s")
            if one.get("work_ms_per_it") and two.get("work_ms_per_it"):
                w1, w2 = one["work_ms_per_it"], two["work_ms_per_it"]
                line += (f"; CPU time outside MPI calls (the work, whatever the load) "
                         f"{w1[0]:.3f} ms/it on 1 rank, " + " / ".join(f"{w:.3f}" for w in w2)
                         + f" on 2 (bound on the speed-up {w1[0] / max(w2):.2f}×)")
            else:
                line += (f"; CPU time of the busiest rank {two['cpu_ms_per_it']:.3f} against "
                         f"{one['cpu_ms_per_it']:.3f} ms/it (MPICH's ranks poll while they "
                         "wait, so that counts waiting too)")
            if one.get("driver_s") and two.get("driver_s"):
                line += ("; of the best runs, in LAMMPS' chunks (steps, reneighbourings) "
                         f"{one['driver_s']['steps_s']:.3f} s on 1 rank, "
                         f"{two['driver_s']['steps_s']:.3f} s on 2, outside them (the phase "
                         "switches' setups, the first one's pass over every atom among them) "
                         f"{one['driver_s']['between_s']:.3f} s and "
                         f"{two['driver_s']['between_s']:.3f} s")
            out.append(line + ".")
    for scene in (data["scene"], "sediment-large"):
        act, every = _row(data, scene), _row(data, scene, particles="all")
        if act is not None and every is not None:
            out.append(f"- `{scene}`: integrating only the particles that can move against all "
                       f"of them: {every['ms_per_it'] / act['ms_per_it']:.2f}× faster (wall)"
                       + (f", {every['cpu_ms_per_it'] / act['cpu_ms_per_it']:.2f}× (CPU)"
                          if act.get("cpu_ms_per_it") and every.get("cpu_ms_per_it") else "")
                       + ".")
    return out


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# Speed: full MagPod, wall time per 1200 iterations", "",
             f"Regenerate: `rackstress bench perf{' --quick' if data['quick'] else ''}` "
             f"(measured over {data['steps']} iterations of `{data['scene']}`, scaled to 1200). "
             f"Machine: {m['cores']} cores ({m['cpu']}), shared with other work: compare rows "
             "as ratios (all measured in one invocation, one after another; CPU time drifts "
             "less than wall time)" + (
                 "; load average at the start {:.1f} / {:.1f} / {:.1f} (1 / 5 / 15 min)".format(
                     *m["load_avg_at_start"]) + (
                     ", at the end {:.1f} / {:.1f} / {:.1f}".format(*data["load_avg_at_end"])
                     if data.get("load_avg_at_end") else "")
                 if m.get("load_avg_at_start") else "") + ". Targets: LAMMPS exact, one core, ≤ 0.4 s per 1200 "
             "iterations of magpod required, ≤ 0.25 s aimed; sediment-large per iteration ≤ 2× "
             "magpod's; a magpod-small gait cycle ≤ 2 s.", "",
             ] + [line for r in data.get("remeasured", []) for line in (
                 f"Rows of {', '.join(f'`{x}`' for x in r['scenes'])} measured again on "
                 f"{r['date']} (`rackstress bench perf --only SCENE`; load average at the start "
                 + "{:.1f} / {:.1f} / {:.1f}".format(*r["load_avg_at_start"])
                 + (", at the end {:.1f} / {:.1f} / {:.1f}".format(*r["load_avg_at_end"])
                    if r.get("load_avg_at_end") else "")
                 + "); the rest are the full run's.", "")] + [
             md_table(HEADER, table_rows(data)), "",
             f"LAMMPS' own timing breakdown of one extra chunk (`run {data['profile_steps']} pre "
             "no post yes`; % of the loop time, averaged over ranks) and the Python callback's "
             "share of it (largest rank):", ""]
    h, rows = breakdown_rows(data)
    lines.append(md_table(h, rows))
    kc = data.get("kernel_compile") or {}
    if kc:
        lines += ["", "Compiled kernels (numba, cached on disk), measured apart from every "
                  "figure above: " + "; ".join(
                      f"{k.replace('_', ' ')} {v['warm_s']:.2f} s" if "warm_s" in v
                      else f"{k.replace('_', ' ')} failed" for k, v in kc.items()) + "."]
    lines += [""] + verdict(data) + [""]
    if _row(data, HUGE, "plugin", 2, steps=4800) is not None:
        lines += ["The 4 M bed's 200 iterations are mostly its first setup (the plugin's first "
                  "pass over every atom for each pair of contact sides, LAMMPS' own setup over "
                  "4 M atoms) and two or three of LAMMPS' reneighbourings; its gait cycle "
                  "(4800 iterations: four phases, three phase switches, the reneighbourings of "
                  "each) is what a user running the scene sees, and its 2-rank line says how much of "
                  "each run was in LAMMPS' chunks and how much in the phase switches.", ""]
    for r in data["rows"]:
        if r.get("python_operators"):
            lines.append(f"- {r['mode']} mode, Python operators: "
                         + ", ".join(r["python_operators"]))
            break
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if len(sys.argv) >= 7 and sys.argv[1] == "--worker":
        _, _, eng, md, st, ps, name = sys.argv[:7]
        result = worker(eng, md, int(st), int(ps), name)
        if result:
            print("RSPERF " + json.dumps(result, default=float), flush=True)
    else:
        sys.exit("usage: python -m rackstress.bench.perf --worker ENGINE MODE STEPS PROFILE SCENE")
