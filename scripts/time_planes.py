#!/usr/bin/env python
"""Wall time of 1200 steps of the plane scenes: reference engine vs LAMMPS (1 and 2 ranks).

    python scripts/time_planes.py [--steps 1200] [--repeat 3] [--out docs/benchmarks/plane-timings.json]

All timings are taken in one invocation, interleaved, best of ``--repeat``; compare the ratios,
not the seconds (shared machines are noisy). The 2-rank figure runs the same code under
``mpiexec -n 2`` from this interpreter's environment.
"""
from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CASES = {"plane-bound-d2": ("plane-bound", {"d": 2.0}), "plane-bound-d10": ("plane-bound", {"d": 10.0}),
         "plane-bound-d100": ("plane-bound", {"d": 100.0}), "plane-rack": ("plane-rack", {})}


def time_reference(name, params, steps):
    from rackstress import scenes
    from rackstress.engines.driver import drive
    from rackstress.engines.reference import Reference

    sc = scenes.build(name, steps=steps, **params)
    ref = Reference(sc)
    t = time.perf_counter()
    drive(ref)
    return time.perf_counter() - t


def time_lammps(name, params, steps, mode="exact"):
    from rackstress import scenes
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.driver import drive
    from rackstress.engines.lammps.runner import LammpsRun
    from rackstress.lib.mpi import world

    sc = scenes.build(name, steps=steps, **params)
    run = LammpsRun(compile_deck(sc, mode), None)
    world().Barrier()
    t = time.perf_counter()
    drive(run)
    world().Barrier()
    wall = time.perf_counter() - t
    run.close()
    return wall


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=1200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path("docs/benchmarks/plane-timings.json"))
    ap.add_argument("--mpi-child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.mpi_child:
        from rackstress.lib.mpi import world
        name, params = CASES[args.mpi_child]
        best = min(time_lammps(name, params, args.steps) for _ in range(args.repeat))
        if world().Get_rank() == 0:
            print(json.dumps({"wall": best}))
        return
    import os

    mpiexec = Path(sys.executable).parent / "mpiexec"
    load_start = list(os.getloadavg())
    rows = {}
    for case, (name, params) in CASES.items():
        ref = min(time_reference(name, params, args.steps) for _ in range(args.repeat))
        lmp1 = min(time_lammps(name, params, args.steps) for _ in range(args.repeat))
        fast = min(time_lammps(name, params, args.steps, "fast") for _ in range(args.repeat))
        out = subprocess.run([str(mpiexec), "-n", "2", sys.executable, __file__, "--steps",
                              str(args.steps), "--repeat", str(args.repeat), "--mpi-child", case],
                             capture_output=True, text=True, check=True).stdout
        lmp2 = json.loads(out.strip().splitlines()[-1])["wall"]
        rows[case] = {"reference_s": ref, "lammps_exact_1rank_s": lmp1,
                      "lammps_exact_2ranks_s": lmp2, "lammps_fast_1rank_s": fast,
                      "ratio_lammps1_over_reference": lmp1 / ref,
                      "ratio_lammps2_over_reference": lmp2 / ref,
                      "ratio_fast_over_reference": fast / ref}
        print(f"{case:18s} reference {ref:7.3f} s | lammps exact 1 rank {lmp1:7.3f} s "
              f"({lmp1 / ref:5.2f}x) | 2 ranks {lmp2:7.3f} s ({lmp2 / ref:5.2f}x) | "
              f"fast 1 rank {fast:7.3f} s ({fast / ref:5.2f}x)", flush=True)
    result = {"steps": args.steps, "repeat": args.repeat, "machine": platform.platform(),
              "cpus": __import__("os").cpu_count(), "python": platform.python_version(),
              "numpy": np.__version__, "load_avg_at_start": load_start,
              "load_avg_at_end": list(os.getloadavg()), "cases": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
