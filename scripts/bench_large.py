"""Time per iteration and peak memory of a scene on LAMMPS (sediment-large).

    python scripts/bench_large.py [SCENE] [--steps 200] [--set key=value ...]
    mpiexec -n 2 python scripts/bench_large.py sediment-large --steps 200

Builds the scene and LAMMPS instance (no trajectory), enters the first phase, then times
``--steps`` iterations in the runner's chunks of 10 with the watchdog, as a run does. Prints
one JSON line: setup and per-iteration wall time, the Python callback's share, LAMMPS' atom
counts per rank, and the peak resident memory (ru_maxrss) of every rank.
"""
from __future__ import annotations

import argparse
import json
import resource
import time

from mpi4py import MPI


class Timed:
    """Wraps the fix external callback to time it."""

    def __init__(self, inner):
        self.inner, self.t, self.n = inner, 0.0, 0

    def __getattr__(self, k):
        return getattr(self.inner, k)

    def __call__(self, *a):
        t = time.perf_counter()
        self.inner(*a)
        self.t += time.perf_counter() - t
        self.n += 1


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene", nargs="?", default="sediment-large")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--set", dest="sets", action="append", default=[])
    a = ap.parse_args()
    comm = MPI.COMM_WORLD
    from rackstress import scenes
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    t0 = time.perf_counter()
    sc = scenes.load(a.scene, scenes.parse_overrides(a.sets))
    deck = compile_deck(sc, "exact")
    t1 = time.perf_counter()
    run = LammpsRun(deck, None, comm=comm)
    if run.py is not None:
        run.py = Timed(run.py)
    phase = sc.phases[0]
    run.enter_phase(phase.vars)
    comm.Barrier()
    t2 = time.perf_counter()
    left = a.steps
    while left > 0:
        k = min(10, left)
        run.advance(k)
        run.check()
        left -= k
    comm.Barrier()
    t3 = time.perf_counter()
    nlocal = run.lmp.extract_global("nlocal")
    nghost = run.lmp.extract_global("nghost")
    cb = run.py.t if run.py is not None else 0.0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    per = comm.gather({"rank": comm.Get_rank(), "nlocal": int(nlocal), "nghost": int(nghost),
                       "callback_ms_per_step": 1e3 * cb / max(1, a.steps),
                       "peak_rss_mb": round(rss, 1)}, root=0)
    run.close()
    if comm.Get_rank() == 0:
        print(json.dumps({
            "scene": a.scene, "sets": a.sets, "n_particles": sc.n_particles,
            "ranks": comm.Get_size(), "steps": a.steps,
            "build_s": round(t1 - t0, 2), "lammps_setup_s": round(t2 - t1, 2),
            "ms_per_iteration": round(1e3 * (t3 - t2) / a.steps, 2),
            "peak_rss_mb_total": round(sum(p["peak_rss_mb"] for p in per), 1),
            "per_rank": per}), flush=True)


if __name__ == "__main__":
    main()
