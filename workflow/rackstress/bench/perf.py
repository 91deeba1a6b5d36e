"""``rackstress bench perf``: wall time per 1200 MagPod iterations, and where it goes.

Every configuration runs the full ``magpod`` scene (33,689 particles) for ``steps`` iterations
(default 1200: the first gait phase) in its own process, so that its peak memory
(``resource.getrusage(...).ru_maxrss``; under MPI the largest over the ranks, and their sum) is
its own: the reference engine, LAMMPS exact and fast mode, each LAMMPS mode serial and under
``mpiexec -n 2`` (the venv's ``mpiexec``). All configurations run in one invocation, one after
another, and are reported as ratios to LAMMPS exact serial and to the reference engine (the
machine is shared: absolute seconds drift, ratios within one run hold better). The paper's own
figure (142 s per 1200 iterations, one thread, 1.83 GHz) is a row.

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
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rackstress.bench import fmt, machine, md_table, out_dir, write_json
from rackstress.engines.driver import drive

PAPER = {"config": "paper (Rönkkö et al.): one thread, 1.83 GHz", "s_per_1200": 142.0,
         "n_particles": 33689}
CONFIGS = (("reference", "exact", 1), ("lammps", "exact", 1), ("lammps", "fast", 1),
           ("lammps", "exact", 2), ("lammps", "fast", 2))


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
def worker(engine: str, mode: str, steps: int, profile_steps: int, scene_name: str) -> dict:
    """One configuration, in this process (all ranks of COMM_WORLD); rank 0 returns the result."""
    from rackstress import scenes

    sc = scenes.build(scene_name).with_steps(steps)
    t0 = time.perf_counter()
    res = {"engine": engine, "mode": mode, "steps": steps, "n_particles": sc.n_particles}
    if engine == "reference":
        from rackstress.engines.reference import Reference

        ref = Reference(sc)
        res["setup_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        drive(ref)
        res["wall_s"] = time.perf_counter() - t0
        res["ranks"] = 1
        res["maxrss_mb"] = res["maxrss_sum_mb"] = \
            resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        return res
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    deck = compile_deck(sc, mode, measure_fast=True)
    runner = LammpsRun(deck, None, log=False)
    comm = runner.comm
    if runner.py is not None:
        runner.py = TimedCallback(runner.py)
    res["setup_s"] = time.perf_counter() - t0
    comm.Barrier()
    t0 = time.perf_counter()
    drive(runner)
    comm.Barrier()
    res["wall_s"] = time.perf_counter() - t0
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
            breakdown["_profile_wall_s"] = prof_wall
        cb_prof_all = comm.gather(cb_prof, root=0)
        if comm.Get_rank() == 0:
            breakdown["_callback_s_per_rank"] = cb_prof_all
    runner.close()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    all_rss = comm.gather(rss, root=0)
    all_cb = comm.gather(cb, root=0)
    all_calls = comm.gather(calls, root=0)
    if comm.Get_rank() != 0:
        return {}
    res.update(ranks=comm.Get_size(), maxrss_mb=max(all_rss), maxrss_sum_mb=sum(all_rss),
               callback_s_per_rank=all_cb, callback_calls=all_calls[0],
               callback_share=max(all_cb) / res["wall_s"] if res["wall_s"] else None,
               breakdown=breakdown, python_operators=[f"{r.target} <- {r.op.kind}"
                                                      for r in deck.python_ops],
               # fast mode where the callback stays is refused by `rackstress run`
               offered=not (mode == "fast" and deck.python_ops))
    return res


def spawn(engine: str, mode: str, ranks: int, steps: int, profile_steps: int,
          scene_name: str) -> dict:
    cmd = [sys.executable, "-m", "rackstress.bench.perf", "--worker", engine, mode, str(steps),
           str(profile_steps), scene_name]
    if ranks > 1:
        mpiexec = Path(sys.executable).parent / "mpiexec"
        cmd = [str(mpiexec), "-n", str(ranks)] + cmd
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ,
                                                                    "OMP_NUM_THREADS": "1"})
    if proc.returncode != 0:
        return {"engine": engine, "mode": mode, "ranks": ranks, "status": "failed",
                "error": (proc.stderr or proc.stdout)[-2000:]}
    line = [x for x in proc.stdout.splitlines() if x.startswith("RSPERF ")][-1]
    res = json.loads(line[len("RSPERF "):])
    res["status"] = "ok"
    res["process_s"] = time.perf_counter() - t0
    return res


def run_bench(out: Path | None = None, steps: int = 1200, quick: bool = False,
              profile_steps: int = 100, scene_name: str = "magpod", configs=CONFIGS,
              echo=print) -> dict:
    out = out_dir(out)
    if quick:
        steps = min(steps, 300)
        profile_steps = min(profile_steps, 50)
    t0 = time.perf_counter()
    rows = []
    for engine, mode, ranks in configs:
        r = spawn(engine, mode, ranks, steps, profile_steps if engine == "lammps" else 0,
                  scene_name)
        r.setdefault("ranks", ranks)
        if r["status"] == "ok":
            r["s_per_1200"] = r["wall_s"] * 1200.0 / steps
            r["particle_steps_per_s"] = r["n_particles"] * steps / r["wall_s"]
            echo(f"  {engine:9s} {mode:5s} ranks={ranks}: {r['s_per_1200']:.2f} s / 1200 it, "
                 f"{r['maxrss_mb']:.0f} MB peak")
        else:
            echo(f"  {engine:9s} {mode:5s} ranks={ranks}: FAILED {r['error'][-300:]}")
        rows.append(r)

    def ratio(base):
        b = next((r for r in rows if r["status"] == "ok" and (r["engine"], r["mode"],
                                                              r["ranks"]) == base), None)
        for r in rows:
            if r["status"] == "ok" and b is not None:
                r[f"x_{base[0]}_{base[1]}_{base[2]}"] = r["wall_s"] / b["wall_s"]
        return b
    ratio(("lammps", "exact", 1))
    ratio(("reference", "exact", 1))
    paper = dict(PAPER)
    paper["particle_steps_per_s"] = paper["n_particles"] * 1200 / paper["s_per_1200"]
    data = {"benchmark": "perf", "scene": scene_name, "steps": steps, "quick": quick,
            "profile_steps": profile_steps, "machine": machine(), "rows": rows,
            "paper": paper, "targets": {"exact_1core_required_s_per_1200": 5.0,
                                        "exact_1core_aimed_s_per_1200": 1.0},
            "wall_s": time.perf_counter() - t0}
    write_json(out / "perf.json", data)
    (out / "perf.md").write_text(markdown(data))
    data["files"] = [str(out / f) for f in ("perf.json", "perf.md")]
    return data


HEADER = ["configuration", "s / 1200 it", "× LAMMPS exact 1 rank", "× reference",
          "particle-steps/s", "peak RSS MB (max rank / sum)", "callback share", "setup s"]


def table_rows(data: dict) -> list:
    out = []
    for r in data["rows"]:
        name = r["engine"] if r["engine"] == "reference" else f"LAMMPS {r['mode']}"
        name += f", {r['ranks']} rank{'s' if r['ranks'] > 1 else ''}"
        if r.get("offered") is False:
            name += " (not offered for this scene)"
        if r["status"] != "ok":
            out.append([name, "failed", "", "", "", "", "", ""])
            continue
        mem = f"{r['maxrss_mb']:.0f}" + (f" / {r['maxrss_sum_mb']:.0f}" if r["ranks"] > 1 else "")
        share = r.get("callback_share")
        out.append([name, f"{r['s_per_1200']:.2f}", fmt(r.get("x_lammps_exact_1")),
                    fmt(r.get("x_reference_exact_1")), f"{r['particle_steps_per_s']:.3g}", mem,
                    f"{share:.0%}" if share is not None else "—", f"{r['setup_s']:.1f}"])
    p = data["paper"]
    out.append([p["config"], f"{p['s_per_1200']:.0f}", "", "", f"{p['particle_steps_per_s']:.3g}",
                "", "", ""])
    return out


def breakdown_rows(data: dict) -> tuple[list, list]:
    sections = ["Pair", "Bond", "Neigh", "Comm", "Output", "Modify", "Other"]
    rows = []
    for r in data["rows"]:
        b = r.get("breakdown") or {}
        if not b or "_loop" not in b:
            continue
        name = f"LAMMPS {r['mode']}, {r['ranks']} rank{'s' if r['ranks'] > 1 else ''}"
        loop = b["_loop"]
        cbs = b.get("_callback_s_per_rank") or [0.0]
        rows.append([name, f"{loop['seconds']:.3f} ({loop['steps']} steps)"]
                    + [f"{b[s]['pct']:.1f}" if s in b else "—" for s in sections]
                    + [f"{100 * max(cbs) / loop['seconds']:.1f}" if loop["seconds"] else "—"])
    return ["configuration", "loop time"] + [f"{s} %" for s in sections] + \
        ["Python callback % (in Modify)"], rows


def verdict(data: dict) -> list[str]:
    """The targets, met or not, for LAMMPS exact on one rank."""
    ex = next((r for r in data["rows"] if r["status"] == "ok" and r["engine"] == "lammps"
               and r["mode"] == "exact" and r["ranks"] == 1), None)
    if ex is None:
        return ["Targets: LAMMPS exact on one rank did not run."]
    s, t = ex["s_per_1200"], data["targets"]
    req, aim = t["exact_1core_required_s_per_1200"], t["exact_1core_aimed_s_per_1200"]
    return [f"- Required ≤ {req:g} s per 1200 iterations (exact, one core): "
            f"{'**met**' if s <= req else '**not met**'} at {s:.2f} s "
            f"({data['paper']['s_per_1200'] / s:.0f}× the paper's figure).",
            f"- Aimed ≤ {aim:g} s: {'**met**' if s <= aim else '**not met**'} "
            f"({s / aim:.1f}× the aim)."]


def markdown(data: dict) -> str:
    m = data["machine"]
    lines = ["# Speed: full MagPod, wall time per 1200 iterations", "",
             f"Regenerate: `rackstress bench perf{' --quick' if data['quick'] else ''}` "
             f"(measured over {data['steps']} iterations of `{data['scene']}`, scaled to 1200). "
             f"Machine: {m['cores']} cores ({m['cpu']}), shared with other work: compare rows "
             "as ratios (all measured in one invocation, one after another). Targets: LAMMPS "
             "exact, one core, ≤ 5 s per 1200 iterations required, ≤ 1 s aimed.", "",
             md_table(HEADER, table_rows(data)), "",
             f"LAMMPS' own timing breakdown of one extra chunk (`run {data['profile_steps']} pre "
             "no post yes`; % of the loop time, averaged over ranks) and the Python callback's "
             "share of it (largest rank):", ""]
    h, rows = breakdown_rows(data)
    lines.append(md_table(h, rows))
    lines += [""] + verdict(data) + [""]
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
