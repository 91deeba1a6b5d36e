"""``rackstress bench static``: the static solve's speed and memory, on the cantilever up to
~100,000 particles and on real parts, with the direct factorization and with AMG-CG alone.

Each case runs in a process of its own (its peak memory is its own): the scene is built, then
:func:`rackstress.engines.static.solve` is timed (CPU and wall), with the part check; Newton
steps, factorizations, residual and peak resident memory are recorded. The real parts are the
SO-ARM100's (``example-robot-data``'s meshes, in metres: scale 1000; ``Base.stl``'s four
bodies split by trimesh and given as one part's ``parts``), and any scene given with
``--scene``. Writes ``docs/benchmarks/static.{md,json}``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rackstress.bench import fmt, machine, md_table, out_dir, repository_file, write_json

CANTILEVER = repository_file("examples", "cantilever", "scene.toml")
#: where the example-robot-data wheel's SO-ARM meshes are looked for (else its package)
SO_ARM = Path(os.environ.get("RACKSTRESS_SO_ARM",
                             "/work/parts/example-robot-data/so_arm_description/meshes/so100"))

PART = """name = "{name}"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "part"
{source}
spacing = {spacing}
material = "{material}"
[[support]]       # bolted down: the lowest {hold} mm of the part
on = "part"
where = {{ box = {{ min = [-1e3, -1e3, -1e3], max = [1e3, 1e3, {zhold}] }} }}
[[load]]          # {load} N in −z on the particles above {zload} mm
on = "part"
where = {{ box = {{ min = [-1e3, -1e3, {zload}], max = [1e3, 1e3, 1e3] }} }}
force = [0, 0, -{load}]
"""


def _measure(path: str, sets: dict, direct: bool) -> dict:
    """One case in this process: build, check and solve; the figures as a dict."""
    import resource

    from rackstress.engines import static
    from rackstress.engines.linear import backend
    from rackstress.scenes.toml import load_toml

    t0 = time.process_time()
    sc = load_toml(path, sets)
    static._bind_pairs(sc)                  # the scene's bindings (inside tests): not the solve
    build = time.process_time() - t0
    static._Linear.direct_allowed = direct
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        static.check_part(sc)
        check_cpu = time.process_time() - c0
        res = static.solve(sc)
        out = {"settled": res.settled, "iterations": res.iterations, "residual": res.residual,
               "factorizations": res.factorizations, "solver": res.solver}
    except Exception as exc:  # noqa: BLE001 - a refused part is a figure too
        check_cpu = time.process_time() - c0
        out = {"settled": False, "error": str(exc)[:300]}
    out.update({"particles": sc.n_particles, "unknowns": int((~sc.fixed()).sum()),
                "build_cpu_s": build, "check_cpu_s": check_cpu,
                "solve_cpu_s": time.process_time() - c0, "solve_wall_s": time.perf_counter() - w0,
                "peak_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                "direct": direct, "backend": backend() if direct else "amg-cg"})
    return out


def _run_case(path: Path, sets: dict, direct: bool, echo) -> dict:
    code = ("import json, sys; from rackstress.bench.static import _measure; "
            f"print('@@' + json.dumps(_measure({str(path)!r}, {sets!r}, {direct!r})))")
    env = {**os.environ, "MKL_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "NUMBA_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       timeout=3600)
    line = [x for x in r.stdout.splitlines() if x.startswith("@@")]
    if not line:
        return {"error": (r.stderr or r.stdout)[-300:], "settled": False}
    return json.loads(line[0][2:])


def _so_arm_scenes(tmp: Path) -> list:
    """(label, scene path, sets) of the SO-ARM parts found (none when the meshes are absent)."""
    out = []
    if not SO_ARM.is_dir():
        return out
    import trimesh

    base = trimesh.load(SO_ARM / "Base.stl")
    bodies = base.split(only_watertight=False)
    names = []
    for k, b in enumerate(bodies):
        f = tmp / f"base-body{k}.stl"
        b.export(f)
        names.append(f'{{ mesh = "{f}", scale = 1000 }}')
    src = "parts = [" + ", ".join(names) + "]"
    for a in (4.0, 2.0):
        f = tmp / f"base-{a:g}.toml"
        f.write_text(PART.format(name="so100-base", source=src, spacing=a, material="aluminium",
                                 hold=3, zhold=a, load=200, zload=60))
        out.append((f"SO-ARM100 Base (4 bodies), aluminium, {a:g} mm", f, {}))
    f = tmp / "upper.toml"
    f.write_text(PART.format(name="so100-upper-arm",
                             source=f'mesh = "{SO_ARM / "Upper_Arm.stl"}"\nscale = 1000',
                             spacing=1.5, material="PLA", hold=3, zhold=-9, load=20, zload=12))
    out.append(("SO-ARM100 Upper_Arm, PLA, 1.5 mm", f, {}))
    return out


def run_bench(out=None, quick: bool = False, scenes=(), echo=print) -> dict:
    out = out_dir(out)
    spacings = [2.0, 1.0] if quick else [2.0, 1.0, 0.7, 0.5, 0.46]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(f"cantilever {a:g} mm", CANTILEVER, {"spacing": a}) for a in spacings]
        if not quick:
            cases += _so_arm_scenes(Path(tmp))
        cases += [(f"{Path(s).stem}", Path(s), {}) for s in scenes]
        for label, path, sets in cases:
            for direct in (True, False):
                r = _run_case(path, sets, direct, echo)
                r["case"] = label
                rows.append(r)
                echo(f"  {label}, {'direct' if direct else 'AMG-CG'}: "
                     f"{r.get('particles', '?')} particles, settled {r.get('settled')}, "
                     f"{r.get('iterations', '—')} steps, {fmt(r.get('solve_cpu_s'))} s CPU, "
                     f"{fmt(r.get('peak_MB'))} MB" + (f" ({r['error'][:120]})" if 'error' in r
                                                     else ""))
    data = {"machine": machine(), "rows": rows}
    write_json(out / "static.json", data)
    (out / "static.md").write_text(report(data))
    return data


def report(data: dict) -> str:
    head = ["case", "particles", "linear solve", "settled", "Newton steps", "factorizations",
            "residual", "check CPU s", "solve CPU s", "solve wall s", "peak MB"]
    rows = [[r["case"], f"{r.get('particles', 0):,}",
             (r.get("solver") or r.get("backend", "")) if r.get("direct") else "AMG-CG only",
             "yes" if r.get("settled") else ("refused" if "error" in r else "no"),
             r.get("iterations", "—"), r.get("factorizations", "—"), fmt(r.get("residual")),
             fmt(r.get("check_cpu_s")), fmt(r.get("solve_cpu_s")), fmt(r.get("solve_wall_s")),
             fmt(r.get("peak_MB"))] for r in data["rows"]]
    m = data["machine"]
    lines = ["# Static solve: speed and memory", "",
             "`rackstress bench static`: each case in a process of its own on one core "
             "(MKL_NUM_THREADS = 1); the scene is built first (not counted), then the part "
             "check and Newton's method (solve CPU includes the check). Each case twice: the "
             "direct factorization where it fits (engines/linear.py) and AMG-CG alone (the "
             "iterative path, which was the only one above 6,000 unknowns).", "",
             f"Machine: {m['cores']} cores ({m['cpu']}), load average at start "
             f"{m['load_avg_at_start']}; {m['note']}.", "",
             md_table(head, rows)]
    errs = [r for r in data["rows"] if "error" in r]
    for r in errs:
        lines.append(f"- {r['case']} ({'direct' if r.get('direct') else 'AMG-CG'}): "
                     f"{r['error']}")
    return "\n".join(lines) + "\n"
