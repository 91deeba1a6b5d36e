"""``rackstress bench inside``: how fast is ``bind … within … inside``, and is it the same test?

The bracket of ``examples/bracket`` (an STL with two bolt holes and a re-entrant corner) is
filled at the spacing that gives about 17,600, 100,000 and 1,000,000 particles and bound to
itself within 1.5 spacings inside its own mesh (:class:`rackstress.model.operators.WithinInside`,
decided by :mod:`rackstress.model.inside`). For each size, in one run:

* the time of the fill and of the whole binding (neighbour search + inside test + both
  directions sorted), the bindings kept and dropped;
* the old test (31 points × 8 diagonal neighbours sampled per binding:
  :func:`rackstress.model.inside.sampled`) on every binding at the smallest size, and on every
  dropped binding plus a seeded random sample of the kept ones at the larger sizes (its time per
  binding, extrapolated to all of them), and how many bindings the two tests decide differently.

Outputs ``inside.json`` and ``inside.md``. Timings are ratios inside one run (the machine is
shared); the target is ≤ 10 s wall for 1,000,000 particles.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from rackstress.bench import fmt, machine, md_table, out_dir, repository_file, write_json

SIZES = (17_600, 100_000, 1_000_000)
QUICK_SIZES = (3_000, 17_600)
#: Kept bindings re-tested by sampling at the larger sizes (seeded).
SAMPLE = 20_000
TARGET_S = 10.0
HEADER = ["particles", "spacing", "bindings", "dropped", "fill s", "bind s (new)",
          "bind CPU s", "old test s", "speed-up", "old test on", "differ"]


def _stl() -> Path:
    return repository_file("examples", "bracket", "bracket.stl")


def one(surface, n: int, full_old: bool, rng) -> dict:
    """Fill ``surface`` with about n particles, bind them inside it, time the old test."""
    from rackstress.model.inside import sampled
    from rackstress.model.operators import Bind, WithinInside
    from rackstress.model.particles import Group, fill

    spacing = (surface.volume / n) ** (1.0 / 3.0)
    o = fill(surface, spacing, max_particles=4 * n)        # a thin part holds fewer: once more
    spacing *= (len(o) / n) ** (1.0 / 3.0)
    t = time.perf_counter()
    o = fill(surface, spacing, max_particles=4 * n)
    t_fill = time.perf_counter() - t
    g = Group("bracket", o, spacing / 2)
    d = 1.5 * spacing
    t, c = time.perf_counter(), time.process_time()
    pl = Bind("bracket", WithinInside(d, 1.0, surface)).pairs(g, g)
    t_bind, c_bind = time.perf_counter() - t, time.process_time() - c
    kept = pl.i < pl.j
    ki, kj = pl.i[kept], pl.j[kept]
    # every within(d) pair once, for the old test
    from scipy.spatial import cKDTree

    ij = cKDTree(o).query_pairs(d, output_type="ndarray")
    diff = o[ij[:, 1]] - o[ij[:, 0]]
    ij = ij[np.einsum("ij,ij->i", diff, diff) < d * d]
    new_keep = np.isin(ij[:, 0] * len(o) + ij[:, 1], ki * len(o) + kj)
    if full_old:
        idx = np.arange(len(ij))
    else:
        kept_idx = np.flatnonzero(new_keep)
        idx = np.union1d(np.flatnonzero(~new_keep),
                         rng.choice(kept_idx, size=min(SAMPLE, len(kept_idx)), replace=False))
    t, c = time.perf_counter(), time.process_time()
    old = sampled(surface, o[ij[idx, 0]], o[ij[idx, 1]], d)
    t_old, c_old = time.perf_counter() - t, time.process_time() - c
    return {"particles": int(len(o)), "spacing": spacing, "bindings": int(len(ij)),
            "dropped": int((~new_keep).sum()), "fill_s": t_fill, "bind_s": t_bind,
            "bind_cpu_s": c_bind, "old_cpu_s_all": c_old * len(ij) / max(1, len(idx)),
            "old_tested": int(len(idx)), "old_s_measured": t_old,
            "old_s_all": t_old * len(ij) / max(1, len(idx)),
            "old_dropped": int((~old).sum()),
            "differ": int((old != new_keep[idx]).sum())}


def _warm(surface) -> None:
    """Load the compiled kernels (numba, cached on disk: compiled once per machine) before
    anything is timed, on a small fill of the same part."""
    from rackstress.model.operators import Bind, WithinInside
    from rackstress.model.particles import Group, fill

    s = (surface.volume / 20_000) ** (1.0 / 3.0)
    g = Group("bracket", fill(surface, s), s / 2)
    Bind("bracket", WithinInside(1.5 * s, 1.0, surface)).pairs(g, g)


def run_bench(out=None, quick: bool = False, sizes=None, echo=print) -> dict:
    """Run the benchmark (module docstring); returns the data written to ``inside.json``."""
    from rackstress.scenes.mesh import read_surface

    t0 = time.perf_counter()
    out = out_dir(out)
    surface = read_surface(_stl())
    sizes = tuple(sizes or (QUICK_SIZES if quick else SIZES))
    rng = np.random.default_rng(0)
    _warm(surface)
    rows = []
    for k, n in enumerate(sizes):
        r = one(surface, n, full_old=(k == 0), rng=rng)
        echo(f"{r['particles']:,} particles: bound in {r['bind_s']:.2f} s "
             f"({r['dropped']:,} of {r['bindings']:,} dropped), old test "
             f"{r['old_s_all']:.1f} s, {r['differ']} differ")
        rows.append(r)
    data = {"machine": machine(), "mesh": str(_stl().name), "within": "1.5 spacings",
            "target_s": TARGET_S, "sizes": rows,
            "met": all(r["bind_s"] <= TARGET_S for r in rows if r["particles"] >= 900_000)
            and all(r["differ"] == 0 for r in rows)}
    data["files"] = [str(out / "inside.json"), str(out / "inside.md")]
    data["wall_s"] = time.perf_counter() - t0
    write_json(out / "inside.json", data)
    (out / "inside.md").write_text(markdown(data))
    return data


def table_rows(data) -> list:
    rows = []
    for r in data["sizes"]:
        old_on = "all" if r["old_tested"] == r["bindings"] else f"{r['old_tested']:,}"
        est = "" if r["old_tested"] == r["bindings"] else " (est.)"
        rows.append([f"{r['particles']:,}", fmt(r["spacing"]), f"{r['bindings']:,}",
                     f"{r['dropped']:,}", fmt(r["fill_s"], 2), fmt(r["bind_s"], 3),
                     fmt(r["bind_cpu_s"], 3),
                     fmt(r["old_s_all"], 3) + est,
                     fmt(r["old_s_all"] / max(r["bind_s"], 1e-9), 3) + "×", old_on,
                     str(r["differ"])])
    return rows


def markdown(data) -> str:
    m = data["machine"]
    return (
        "# `bind … within … inside`: the fast inside test\n\n"
        "Written by `rackstress bench inside`. The bracket of `examples/bracket` "
        f"(`{data['mesh']}`) filled at three spacings, each particle bound to its neighbours "
        "within 1.5 spacings whose segment stays inside the mesh (`model/inside.py`: the "
        "lattice's own cells, a ray test near the boundary). *bind s* is the whole binding "
        "(wall): neighbour search (the lattice's site grid), inside test (compiled, on both "
        "cores), both directions sorted; *bind CPU s* its processor time over both cores "
        "(the machine is shared: wall time includes waiting for a core). The compiled "
        "kernels are loaded before anything is timed (numba's cache: compiled once per "
        "machine). *old test* is "
        "the sampling "
        "test it replaces (248 region tests per binding), run on every binding at the "
        "smallest size and, at the larger ones, on every dropped binding plus "
        f"{SAMPLE:,} random kept ones, its time extrapolated to all bindings. *differ*: "
        "bindings the two tests decide differently among those both ran on.\n\n"
        + md_table(HEADER, table_rows(data)) +
        f"\nTarget: 1,000,000 particles bound in ≤ {data['target_s']:g} s wall "
        f"({'met' if data['met'] else 'NOT met'}). Machine: {m['cores']} cores, load "
        f"{' / '.join(f'{x:.1f}' for x in m['load_avg_at_start'])} (1 / 5 / 15 min) at the "
        "start (shared: compare within the run).\n")
