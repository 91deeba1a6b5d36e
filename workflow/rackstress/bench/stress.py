"""``rackstress bench stress [--quick]``: which route from particles to stress, measured.

Aluminium bars on the simple cubic lattice (spacing 1 mm, within 1.5 spacings, k = 2·m·c per
binding with c from E = 2.5·k/a; docs/stress.md), run to damped equilibrium on the reference
engine, against two analytical fields:

* **uniform tension** — ±F on the two end faces (self-equilibrated): σ_xx = F/A on every
  section, A = the cells' union;
* **pure bending** — couples ±M on the end faces (forces ∝ z): σ_xx = M·z/I at mid-span,
  I = b·h³/12, read at the particle centres (the top layer at z = h/2 − a/2).

Routes compared at the same positions:

``virial``
    the bindings' virial per particle volume W_i/V_i (the default of the ``von_mises`` measure);
``completed``
    the same, surface-completed: C · A_i⁺ · W_i (:mod:`rackstress.stress.tensor`);
``hooke(ν=0.33)``
    σ = C(E, ν) : E_GL from the material's E and ν on the Green–Lagrange strain of the
    ``strain`` measure's affine fit (1.5 spacings);
``hooke(ν=1/4)``
    the same with the lattice's own Poisson's ratio.

Each on the plain within(1.5) lattice and, where this rackstress has material solids
(``rackstress.model.solid.Solid``), on their face-compensated lattice (the missing outer
second-neighbour bindings' share given to the face-parallel ones). It also measures the
lattice's Poisson's ratio (lateral over axial strain at mid-length of the
tension bar) and its effective Young's modulus (F/A over the axial strain between two sections),
which set what a ν = 0.33 material costs (docs/stress.md). Writes ``stress.json`` and
``stress.md`` into docs/benchmarks/.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from rackstress.bench import fmt, machine, md_table, out_dir, write_json

E = 70000.0          # MPa, aluminium
NU = 0.33
RHO = 2.7e-9         # t/mm³
FULL = {"tension": [(12, 4), (20, 10)], "bending": [(16, 6), (30, 10)]}
QUICK = {"tension": [(10, 4)], "bending": [(16, 6)]}
ROUTES = ("virial", "completed", "hooke(ν=0.33)", "hooke(ν=1/4)")


def lattices() -> dict:
    """The bind coefficients measured: the plain within(1.5) lattice, and the material solid's
    face-compensated lattice (``rackstress.model.solid.Solid``) where this rackstress has it."""
    from rackstress.model.operators import Within

    out = {"plain": lambda c: Within(1.5, c)}
    try:
        from rackstress.model.solid import Solid
    except ImportError:                  # a rackstress without material solids
        return out
    out["face-compensated"] = lambda c: Solid(d=1.5, c=c, region=None, spacing=1.0,
                                              material="aluminium")
    return out


def _bar(nx, n, loads_of, steps=200000, lattice="plain"):
    from rackstress.model.materials import material
    from rackstress.model.operators import Bind, Dampen, Force
    from rackstress.model.particles import Group
    from rackstress.model.scene import Phase, Scene
    from rackstress.model.stability import predict
    from rackstress.model.units import SYSTEMS

    o = np.mgrid[0:nx, 0:n, 0:n].reshape(3, -1).T.astype(float)
    o[:, 1:] -= (n - 1) / 2
    m = RHO
    c = E / (5.0 * m)                 # E = 2.5·k/a, k = 2·m·c, a = 1
    g = Group("bar", o, 0.5, material=material("aluminium"), volume=1.0)
    ops = [Force(tuple(float(x) / m for x in f), where=tuple(bool(b) for b in mask))
           for mask, f in loads_of(o)]
    omega = np.pi / (2 * nx) * np.sqrt(E / RHO)
    ops += [Bind("bar", lattices()[lattice](c)), Dampen(2 * omega)]
    units = SYSTEMS["mm-N-s"]
    sc = Scene("bar", {"bar": g}, {"bar": ops}, [Phase("load", steps)], dt=1.0, units=units)
    dt = 0.5 * predict(sc)["t_max"]
    return Scene("bar", {"bar": g}, {"bar": ops}, [Phase("load", steps)], dt=dt, units=units), o


def routes(scene, o, p) -> dict:
    """Stress (n, 6, internal Voigt) of every route at positions ``p``."""
    from rackstress.runs.run import bindings_of
    from rackstress.stress import tensor as T
    from rackstress.validity.compare import affine_fit_gradient

    b = bindings_of(scene)
    V = np.ones(len(o))
    A = T.binding_moment(o, b[0], b[1], b[2])
    F = affine_fit_gradient(o, p)
    Egl = 0.5 * (np.transpose(F, (0, 2, 1)) @ F - np.eye(3))
    return {"virial": T.stress(p, b, volume=V),
            "completed": T.stress(p, b, T.completion(A, V, [np.arange(len(o))])),
            "hooke(ν=0.33)": T.hooke(Egl, E, NU), "hooke(ν=1/4)": T.hooke(Egl, E, 0.25)}


def tension(nx, n, F=100.0, echo=print, lattice="plain") -> dict:
    from rackstress.stress import tensor as T
    from rackstress.validity.compare import equilibrate

    face = n * n
    sc, o = _bar(nx, n, lambda o: [(o[:, 0] == nx - 1, (F / face, 0, 0)),
                                   (o[:, 0] == 0, (-F / face, 0, 0))], lattice=lattice)
    t0 = time.perf_counter()
    p, info = equilibrate(sc, tol=1e-8, check_every=1000)
    R = routes(sc, o, p)
    ref = F / face
    mid = o[:, 0] == nx // 2
    x1, x2 = nx // 4, nx - 1 - nx // 4
    L = p[o[:, 0] == x2, 0].mean() - p[o[:, 0] == x1, 0].mean()
    ex = (L - (x2 - x1)) / (x2 - x1)
    top, bot = mid & (o[:, 1] == o[:, 1].max()), mid & (o[:, 1] == o[:, 1].min())
    ey = (p[top, 1].mean() - p[bot, 1].mean() - (n - 1)) / (n - 1)
    out = {"lattice": lattice, "nx": nx, "n": n, "F": F, "sigma": ref, "steps": info["steps"],
           "at_rest": info["at_rest"], "wall_s": time.perf_counter() - t0,
           "E_eff": ref / ex, "nu_lattice": -ey / ex, "routes": {}}
    for name, s in R.items():
        vm = T.von_mises(s[mid])
        out["routes"][name] = {"mean_sxx": float(s[mid, 0].mean() / ref),
                               "min_sxx": float(s[mid, 0].min() / ref),
                               "max_sxx": float(s[mid, 0].max() / ref),
                               "peak_vm": float(vm.max() / ref)}
    echo(f"  {lattice} tension {nx}x{n}x{n}: E_eff {out['E_eff']:.0f} MPa, ν {out['nu_lattice']:.3f}, "
         + ", ".join(f"{k} mean {v['mean_sxx']:.3f} peak {v['peak_vm']:.3f}"
                     for k, v in out["routes"].items()))
    return out


def bending(nx, n, s0=1.0, echo=print, lattice="plain") -> dict:
    from rackstress.stress import tensor as T
    from rackstress.validity.compare import equilibrate

    def loads(o):
        out = []
        for zk in np.unique(o[:, 2]):
            out.append(((o[:, 0] == nx - 1) & (o[:, 2] == zk), (s0 * zk, 0, 0)))
            out.append(((o[:, 0] == 0) & (o[:, 2] == zk), (-s0 * zk, 0, 0)))
        return out

    sc, o = _bar(nx, n, loads, lattice=lattice)
    zs = np.unique(o[:, 2])
    M = s0 * n * float((zs ** 2).sum())
    I = n * n ** 3 / 12.0
    t0 = time.perf_counter()
    p, info = equilibrate(sc, tol=1e-8, check_every=1000)
    R = routes(sc, o, p)
    mid = o[:, 0] == nx // 2
    top = mid & (o[:, 2] == zs.max())
    ref = M * zs.max() / I
    out = {"lattice": lattice, "nx": nx, "n": n, "M": M, "I": I, "sigma_top": ref, "steps": info["steps"],
           "at_rest": info["at_rest"], "wall_s": time.perf_counter() - t0, "routes": {}}
    for name, s in R.items():
        out["routes"][name] = {
            "top_sxx": float(s[top, 0].mean() / ref),
            "peak_vm": float(T.von_mises(s[mid]).max() / ref),
            "moment": float((s[mid, 0] * o[mid, 2]).sum() / M),
            "layers": {f"{z:g}": float(s[mid & (o[:, 2] == z), 0].mean() / (M * z / I))
                       for z in zs if z > 0}}
    echo(f"  {lattice} bending {nx}x{n}x{n}: " + ", ".join(
        f"{k} top {v['top_sxx']:.3f} peak {v['peak_vm']:.3f} moment {v['moment']:.3f}"
        for k, v in out["routes"].items()))
    return out


def run_bench(out: Path | None = None, quick: bool = False, echo=print) -> dict:
    out = out_dir(out)
    t0 = time.perf_counter()
    sizes = QUICK if quick else FULL
    data = {"quick": quick, "machine": machine(),
            "lattices": list(lattices()),
            "tension": [tension(nx, n, echo=echo, lattice=lat) for lat in lattices()
                        for nx, n in sizes["tension"]],
            "bending": [bending(nx, n, echo=echo, lattice=lat) for lat in lattices()
                        for nx, n in sizes["bending"]]}
    data["wall_s"] = time.perf_counter() - t0
    write_json(out / "stress.json", data)
    (out / "stress.md").write_text(report(data))
    data["files"] = [str(out / f"stress.{x}") for x in ("json", "md")]
    return data


def table_rows(data) -> list:
    rows = []
    for t in data["tension"]:
        for name, r in t["routes"].items():
            rows.append([t.get("lattice", "plain"), f"tension {t['nx']}×{t['n']}×{t['n']}", name, fmt(r["mean_sxx"], 3),
                         f"{fmt(r['min_sxx'], 3)} … {fmt(r['max_sxx'], 3)}",
                         fmt(r["peak_vm"], 3)])
    for b in data["bending"]:
        for name, r in b["routes"].items():
            rows.append([b.get("lattice", "plain"), f"bending {b['nx']}×{b['n']}×{b['n']}", name, fmt(r["moment"], 3),
                         f"top {fmt(r['top_sxx'], 3)}", fmt(r["peak_vm"], 3)])
    return rows


HEADER = ["lattice", "case", "route", "section mean σ_xx / (F/A) or moment / M", "σ_xx / analytical",
          "peak von Mises / analytical"]


def report(data) -> str:
    lines = ["# Stress from particles: routes against analytical fields", "",
             "Generated by `rackstress bench stress" + (" --quick" if data["quick"] else "")
             + "` (module docstring of `rackstress.bench.stress`). Aluminium (E = 70 GPa, "
             "ν = 0.33), spacing 1 mm, c from E = 2.5·k/a; reference engine to damped "
             "equilibrium. Ratios to the analytical value: uniform tension F/A (every particle "
             "of the mid-length section), pure bending M·z/I at the mid-span particle centres "
             "(top layer z = h/2 − ½).", ""]
    lines.append(md_table(HEADER, table_rows(data)))
    lines.append("")
    for t in data["tension"]:
        lines.append(f"Tension bar {t['nx']}×{t['n']}×{t['n']} ({t.get('lattice', 'plain')} "
                     "lattice): the lattice's Poisson's ratio "
                     f"{fmt(t['nu_lattice'], 3)} (continuum limit 1/4), effective Young's "
                     f"modulus {fmt(t['E_eff'], 4)} MPa (interior 2.5·k/a = {E:g} MPa; the "
                     "surface particles, missing their outer bindings, are softer).")
    for b in data["bending"]:
        lines.append(f"Bending {b['nx']}×{b['n']}×{b['n']} ({b.get('lattice', 'plain')} "
                     "lattice), virial σ_xx by layer over M·z/I: "
                     + ", ".join(f"z = {z}: {fmt(v, 3)}"
                                 for z, v in b["routes"]["virial"]["layers"].items()) + ".")
    lines.append("")
    return "\n".join(lines)
