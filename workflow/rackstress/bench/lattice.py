"""``rackstress bench lattice``: the elastic lattice's calibration, proven — E, ν, the bulk and
shear moduli it has for a material of E and ν (docs/calibration.md "The volumetric term").

For each ν of :data:`NUS` (E = 70 GPa) and each spacing of :data:`SPACINGS` (5, 10 and 20
layers across the 10 mm sections), statically:

* **uniaxial tension** — a 30 × 10 × 10 mm bar on rollers at x = 0 (its middle lines pinned
  across), 10 MPa on x = 30: E_eff = σ/ε_xx and ν_eff = −ε_yy/ε_xx, −ε_zz/ε_xx, the strains
  least-squares fits of the displacements over the middle third;
* **hydrostatic box** — a 10 mm cube on three symmetry planes (x = 0, y = 0, z = 0 rollers),
  10 MPa of pressure on its other three faces: K_eff = p/(−tr ε), tr ε fitted over the cube;
* **shear on the lattice's axes** — the same cube held at three particles (3-2-1: no rigid
  motion, no constraint), 10 MPa of shear traction on its four faces normal to x and y:
  G_axes = τ/γ_xy (C44);
* **shear at 45° to them** — σ_xx = +10, σ_yy = −10 MPa on those faces (pure shear on the
  planes at 45°): G_45 = τ/(ε_xx − ε_yy) ((C11 − C12)/2): the lattice is isotropic when
  G_axes = G_45 = G.

Targets (docs/calibration.md): ν_eff within 0.01 of ν and E_eff within 2 % of E at every ν and
spacing. Writes ``docs/benchmarks/lattice.{md,json}``.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from rackstress.bench import machine

E = 70000.0                                   # MPa
NUS = (0.0, 0.2, 0.3, 0.33, 0.45)
SPACINGS = (2.0, 1.0, 0.5)
S = 10.0                                      # MPa, every load
TARGET_NU, TARGET_E = 0.01, 0.02

_MAT = "material = {{ E = 70e9, nu = {nu}, density = 2700 }}\npoisson = \"material\""

BAR = """
name = "tension"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "p"
fill = {{ box = {{ min = [0, 0, 0], max = [30, 10, 10] }} }}
spacing = {a}
""" + _MAT + """
[[support]]
on = "p"
where = {{ box = {{ min = [-1, -1, -1], max = [{h}, 11, 11] }} }}
fix = ["x"]
[[support]]
on = "p"
where = {{ box = {{ min = [-1, {c0}, -1], max = [{h}, {c1}, 11] }} }}
fix = ["y"]
[[support]]
on = "p"
where = {{ box = {{ min = [-1, -1, {c0}], max = [{h}, 11, {c1}] }} }}
fix = ["z"]
[[load]]
on = "p"
where = {{ box = {{ min = [{e}, -1, -1], max = [31, 11, 11] }} }}
pressure = {mS}
normal = [1, 0, 0]
"""

CUBE = """
name = "cube"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "p"
fill = {{ box = {{ min = [0, 0, 0], max = [10, 10, 10] }} }}
spacing = {a}
""" + _MAT + """
{supports}
{loads}
"""

#: symmetry planes x = 0, y = 0, z = 0 (rollers)
PLANES = "\n".join(f"""[[support]]
on = "p"
where = {{{{ box = {{{{ min = [{lo}], max = [{hi}] }}}} }}}}
fix = ["{ax}"]""" for ax, lo, hi in (("x", "-1, -1, -1", "{h}, 11, 11"),
                                     ("y", "-1, -1, -1", "11, {h}, 11"),
                                     ("z", "-1, -1, -1", "11, 11, {h}")))


def _pin(x, y, z, fix):
    """A support on the one particle at (x, y, z), each one of the placeholders l (the first
    layer) or u (the last): {l0}…{l1} and {u0}…{u1} bracket them."""
    return f"""[[support]]
on = "p"
where = {{{{ box = {{{{ min = [{{{x}0}}, {{{y}0}}, {{{z}0}}], max = [{{{x}1}}, {{{y}1}}, {{{z}1}}] }}}} }}}}
fix = {fix}"""


#: three particles held, 3-2-1 (rigid motion removed, nothing constrained)
THREE = "\n".join([_pin("l", "l", "l", '["x", "y", "z"]'), _pin("u", "l", "l", '["y", "z"]'),
                   _pin("l", "u", "l", '["z"]')])


def _face(axis: int, side: int, key: str, value) -> str:
    lo = ["-1", "-1", "-1"]
    hi = ["11", "11", "11"]
    if side > 0:
        lo[axis] = "{e}"
    else:
        hi[axis] = "{h}"
    normal = [0, 0, 0]
    normal[axis] = side
    extra = f"\nnormal = {normal}" if key == "pressure" else ""
    return f"""[[load]]
on = "p"
where = {{{{ box = {{{{ min = [{', '.join(lo)}], max = [{', '.join(hi)}] }}}} }}}}
{key} = {value}{extra}"""


def _scene(tmp: Path, name: str, text: str, a: float, nu: float):
    from rackstress.scenes.toml import load_toml

    f = tmp / f"{name}-{nu:g}-{a:g}.toml"
    f.write_text(text.format(a=a, nu=nu, h=a / 2, e=10 - a / 2, l0=0.4 * a, l1=0.6 * a,
                             u0=10 - 0.6 * a, u1=10 - 0.4 * a, c0=5 - a / 2 - 1e-6,
                             c1=5 + a / 2 + 1e-6, mS=-S))
    return load_toml(f)


def _grad(sc, p, box=None):
    """The displacement gradient ∂u_i/∂x_j (3 × 3), least squares over the particles (in
    ``box`` = (lo, hi) if given)."""
    o = sc.original_positions()
    u = p - o
    sel = np.ones(len(o), bool) if box is None else np.all((o > box[0]) & (o < box[1]), axis=1)
    X = np.column_stack([o[sel], np.ones(sel.sum())])
    coef, *_ = np.linalg.lstsq(X, u[sel], rcond=None)
    return coef[:3].T


def _held(sc, grad: np.ndarray):
    """Hold every particle of the cube's two outer layers at the uniform displacement
    u = grad·x (about the cube's centre): the part inside them, whose every particle sees only
    whole cells around it, must take that uniform strain — the lattice's own bulk and shear
    moduli, measured through the stress measure (a face's cells, free or held, are the other
    rows' matter)."""
    (g,) = sc.groups.values()
    o = g.o
    lo, hi = o.min(axis=0), o.max(axis=0)
    a = float(g.meta["spacing"])
    outer = np.any((o <= lo + 1.01 * a) | (o >= hi - 1.01 * a), axis=1)
    g.fixed = np.ascontiguousarray(np.repeat(outer[:, None], 3, axis=1))
    g.held = outer
    g.u0 = np.ascontiguousarray(np.where(g.fixed, (o - 5.0) @ grad.T, 0.0))
    g.v0 = np.zeros_like(o)
    return outer


def _inner_stress(sc, p, outer):
    """The mean stress (3 × 3) of the particles two layers or more inside, by the project's
    own measure: the bindings' virial and the volumetric term's (stress/tensor.py), each over
    the particle's volume."""
    from rackstress.engines.static import _bind_pairs
    from rackstress.model.operators import Bind
    from rackstress.model.volume import Volume, volume_terms

    I, J, C, Q = _bind_pairs(sc)
    m = sc.masses()
    f = Bind.accel(p[I], p[J], C, Q) * m[I][:, None]
    r = p[J] - p[I]
    o = sc.original_positions()
    lo, hi = o.min(axis=0), o.max(axis=0)
    a = float(next(iter(sc.groups.values())).meta["spacing"])
    inner = np.all((o > lo + 1.5 * a) & (o < hi - 1.5 * a), axis=1)     # the free ones
    s = np.zeros((3, 3))
    for x in range(3):
        for y in range(3):
            s[x, y] = 0.5 * np.bincount(I, weights=r[:, x] * f[:, y], minlength=len(p))[inner].mean()
    Wv = Volume.virial(p, volume_terms(sc), m)[inner].mean(axis=0)
    for c, (x, y) in enumerate(((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))):
        s[x, y] += Wv[c]
        if x != y:
            s[y, x] += Wv[c]
    return s / a ** 3


def measure(nu: float, a: float, tmp: Path) -> dict:
    """The tests at one ν and spacing (module doc)."""
    from rackstress.engines.static import solve

    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    K = lam + 2 * mu / 3
    row = {"nu": nu, "spacing": a}
    t0 = time.process_time()
    # uniaxial tension: free side faces
    sc = _scene(tmp, "bar", BAR.replace("{e}", f"{30 - a / 2}"), a, nu)
    res = solve(sc)
    g = _grad(sc, res.p, (np.array([10.0, -1, -1]), np.array([20.0, 11, 11])))
    row.update(particles_bar=sc.n_particles, settled=bool(res.settled),
               E_ratio=S / g[0, 0] / E, nu_y=-g[1, 1] / g[0, 0], nu_z=-g[2, 2] / g[0, 0])
    eps = S / E                       # the strains prescribed below: about the load's
    # hydrostatic box and shear: the two outer layers held at u = ε·x, the stress read inside
    for key, grad in (("K_ratio", -eps * np.eye(3)),
                      ("G_axes_ratio", np.array([[0, eps, 0], [0, 0, 0], [0, 0, 0.0]])),
                      ("G_45_ratio", np.diag([eps, -eps, 0.0]))):
        sc = _scene(tmp, "cube", CUBE.replace("{supports}", PLANES).replace("{loads}", ""), a,
                    nu)
        outer = _held(sc, grad)
        res = solve(sc)
        row["settled"] &= bool(res.settled)
        sig = _inner_stress(sc, res.p, outer)
        if key == "K_ratio":
            row[key] = np.trace(sig) / 3 / (K * np.trace(grad))
        elif key == "G_axes_ratio":
            row[key] = sig[0, 1] / (mu * eps)              # γ = ε (simple shear)
        else:
            row[key] = (sig[0, 0] - sig[1, 1]) / 2 / (2 * mu * eps)
    row["particles_cube"] = sc.n_particles
    # the same box under pressure on three faces (three symmetry planes): a face loaded
    # across is not free (docs/calibration.md "Loaded faces")
    loads = "\n".join(_face(k, 1, "pressure", S) for k in range(3))
    sc = _scene(tmp, "hydro", CUBE.replace("{supports}", PLANES).replace("{loads}", loads), a, nu)
    res = solve(sc)
    row["settled"] &= bool(res.settled)
    row["K_pressure_ratio"] = S / -np.trace(_grad(sc, res.p)) / K
    row["cpu_s"] = time.process_time() - t0
    row["nu_ok"] = bool(abs(row["nu_y"] - nu) <= TARGET_NU and abs(row["nu_z"] - nu) <= TARGET_NU)
    row["E_ok"] = bool(abs(row["E_ratio"] - 1) <= TARGET_E)
    return {k: float(v) if isinstance(v, np.floating) else v for k, v in row.items()}


def run_bench(out: Path | None = None, quick: bool = False, echo=print) -> dict:
    """Every ν of :data:`NUS` at every spacing (``quick``: 2 and 1 mm); writes the figures."""
    import tempfile

    from rackstress.bench import out_dir

    out = out_dir(out)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for nu in NUS:
            for a in (SPACINGS[:2] if quick else SPACINGS):
                r = measure(nu, a, Path(tmp))
                rows.append(r)
                echo(f"  nu {nu:g}, spacing {a:g} mm: E_eff/E {r['E_ratio']:.4f}, nu_eff "
                     f"{r['nu_y']:.4f} / {r['nu_z']:.4f}, K/K {r['K_ratio']:.4f}, G_axes/G "
                     f"{r['G_axes_ratio']:.4f}, G_45/G {r['G_45_ratio']:.4f} "
                     f"({r['cpu_s']:.1f} s of CPU)")
        c = cost(Path(tmp), echo, a=1.0 if quick else 0.5)
        ex = examples(Path(tmp), echo)
    data = {"machine": machine(), "quick": quick, "E_MPa": E, "rows": rows,
            "targets": {"nu_abs": TARGET_NU, "E_rel": TARGET_E},
            "all_within": bool(all(r["nu_ok"] and r["E_ok"] and r["settled"] for r in rows)),
            "cost": c, "examples": ex}
    (out / "lattice.json").write_text(json.dumps(data, indent=1))
    (out / "lattice.md").write_text(report(data))
    return data


def report(d: dict) -> str:
    from rackstress.bench import md_table

    L = ["# The lattice's calibration: E, ν, bulk and shear moduli", "",
         "Written by `rackstress bench lattice` (docs/calibration.md \"The volumetric term\"). "
         "E = 70 GPa; each ν at three spacings, 5, 10 and 20 layers across the 10 mm "
         "sections; static solves. **E_eff, ν_eff**: a 30 × 10 × 10 mm bar in uniaxial "
         "tension (10 MPa on x = 30, rollers on x = 0; its free side faces are where the "
         "calibration of the cells shows), the strains fitted over its middle third. **K, "
         "G_axes, G_45**: a 10 mm cube whose two outer layers are held at a uniform "
         "displacement (hydrostatic ε·I; simple shear γ = ε on the lattice's axes; pure shear "
         "ε·(1, −1, 0), i.e. shear at 45° to them), the stress inside read by the project's "
         "measure (bindings' and volumetric term's virial): the lattice's own moduli C11 + 2C12, "
         "C44 and (C11 − C12)/2. **K under pressure**: the same cube on three symmetry planes "
         "(rollers) with 10 MPa of pressure on its other three faces, K = p/(−tr ε) from the "
         "displacements: every face loaded or held, none free (docs/calibration.md \"Loaded "
         "and held faces\"). Each modulus over the material's: E, K = E/(3(1 − 2ν)), "
         "G = E/(2(1 + ν)).", ""]
    if d.get("quick"):
        L += ["**`--quick`**: spacings 2 and 1 mm only (5 and 10 layers), the cost at 1 mm; "
              "the third spacing (0.5 mm, 20 layers) comes from the full command.", ""]
    rows = [[f"{r['nu']:g}", f"{r['spacing']:g}", f"{r['particles_bar']:,}",
             f"{r['E_ratio']:.4f}", f"{r['nu_y']:.4f}", f"{r['nu_z']:.4f}",
             f"{r['K_ratio']:.4f}", f"{r['G_axes_ratio']:.4f}", f"{r['G_45_ratio']:.4f}",
             f"{r['K_pressure_ratio']:.4f}",
             "yes" if r["nu_ok"] and r["E_ok"] and r["settled"] else "**no**"]
            for r in d["rows"]]
    L += [md_table(["ν", "spacing [mm]", "bar particles", "E_eff / E", "ν_eff (y)",
                    "ν_eff (z)", "K / K", "G_axes / G", "G_45 / G", "K under pressure / K",
                    "E, ν within targets"], rows)]
    worst_nu = max(max(abs(r["nu_y"] - r["nu"]), abs(r["nu_z"] - r["nu"])) for r in d["rows"])
    worst_E = max(abs(r["E_ratio"] - 1) for r in d["rows"])
    worst_G = max(abs(r[k] - 1) for r in d["rows"] for k in ("G_axes_ratio", "G_45_ratio"))
    worst_K = max(abs(r["K_ratio"] - 1) for r in d["rows"])
    finest = [r for r in d["rows"] if r["spacing"] == min(x["spacing"] for x in d["rows"])]
    worst_Kp = max(abs(r["K_pressure_ratio"] - 1) for r in finest)
    L += ["", f"Largest deviations: ν_eff {worst_nu:.4f} (target ≤ {TARGET_NU}), E_eff "
          f"{worst_E * 100:.2f} % (target ≤ {TARGET_E * 100:.0f} %), K {worst_K * 100:.2f} %, "
          f"G {worst_G * 100:.2f} % (on the axes and at 45° alike: isotropic); K under "
          f"pressure {worst_Kp * 100:.1f} % at the finest spacing. E and ν within the targets "
          f"in every row: {'yes' if d['all_within'] else '**no**'}.", ""]
    c = d.get("cost")
    if c:
        so, sn = c["static_old"], c["static_new"]
        L += ["## Cost beside today's lattice", "",
              "Measured in one run (`rackstress bench lattice`): the lattice as it was before the "
              "volumetric term (the bindings alone, c = E/(5ρa²)) against the same lattice "
              f"with it, on the 125 × 10 × 10 mm aluminium bar, {c['particles']:,} particles at "
              f"{c['spacing']:g} mm.", "",
              md_table(["", "bindings alone", "with the volumetric term", "ratio (target ≤ 1.5)"],
                       [["static solve, CPU [s] (each in its own process on one thread, "
                         "best of two)",
                         f"{so['cpu_s']:.1f}", f"{sn['cpu_s']:.1f}",
                         f"{c['static_ratio']:.2f}"],
                        ["Newton steps", so["iterations"], sn["iterations"], ""],
                        ["peak memory of that process [MB]", f"{so['maxrss_MB']:.0f}",
                         f"{sn['maxrss_MB']:.0f}",
                         f"{sn['maxrss_MB'] / so['maxrss_MB']:.2f}"],
                        [f"plugin step, CPU [ms] (1 mm, {c['steps']} steps, best of three)",
                         f"{c['step_old_ms']:.3f}", f"{c['step_new_ms']:.3f}",
                         f"{c['step_ratio']:.2f}"]]),
              f"The terms themselves hold {c['term_MB']:.1f} MB "
              f"({c['term_bytes_per_particle']:.0f} bytes a particle: their pairs, terms and "
              f"coefficients); load average {c['load']} at the end on the 2 cores.", ""]
    if d.get("examples"):
        L += ["## What the material's ν changes in the examples", "",
              "Each committed material example and README's part solved twice at its own "
              "spacing: with the former lattice (the bindings alone, c = E/(5ρa²): ν = 1/4) "
              "and with the volumetric term (aluminium's ν = 0.33). The loaded particles' mean "
              "displacement; the peak von Mises of the plain virial over each cell "
              "(bindings' and term's), where it is — on a wall N layers thick in bending the "
              "bindings' plain virial reads N²/(N² − 1) × M·z/I and the term's M·z/I itself "
              "(docs/stress.md \"The cells' own moment\"); and the governing stress "
              "`rackstress run` reports (the default route, singular points left out).", "",
              md_table(["case", "displacement, ν = 1/4 → 0.33 [mm]", "change",
                        "peak von Mises of the plain virial, ν = 1/4 → 0.33 [MPa]", "change",
                        "where (ν = 0.33)", "governing stress, ν = 1/4 → 0.33 [MPa]",
                        "change"],
                       [[r["case"], f"{r['old']['displacement_mm']:.4f} → "
                         f"{r['new']['displacement_mm']:.4f}",
                         f"{r['displacement_change'] * 100:+.1f} %",
                         f"{r['old']['peak_MPa']:.1f} → {r['new']['peak_MPa']:.1f}",
                         f"{r['peak_change'] * 100:+.1f} %",
                         "(" + ", ".join(f"{x:.3g}" for x in r["new"]["at"]) + ")",
                         (f"{r['old']['governing_MPa']:.1f} → {r['new']['governing_MPa']:.1f}"
                          if "governing_MPa" in r["new"] else "—"),
                         (f"{r['governing_change'] * 100:+.1f} %"
                          if "governing_change" in r else "—")]
                        for r in d["examples"]]), ""]
    load = ", ".join(f"{x:.2f}" for x in d["machine"]["load_avg_at_start"])
    L += [f"Machine: {d['machine']['cores']} cores, load average (1, 5, 15 min) {load} at the "
          "start."]
    return "\n".join(L) + "\n"


# ---------------------------------------------------------------------------- cost
COST_SCRIPT = r"""
import json, resource, sys, time
from rackstress.bench.lattice import _cost_scene
from rackstress.engines.static import solve
sc = _cost_scene(sys.argv[1], float(sys.argv[2]), sys.argv[3] == "old")
c0 = time.process_time()
res = solve(sc)
cpu = time.process_time() - c0
print(json.dumps({"cpu_s": cpu, "iterations": res.iterations, "settled": bool(res.settled),
                  "particles": sc.n_particles,
                  "maxrss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def _cost_scene(path: str, a: float, old: bool):
    """The cost bar at spacing ``a``; ``old``: the lattice without the volumetric term — the
    bindings alone, c = E/(5ρa²) (ν = 1/4 whatever the material, ``poisson = "lattice"``)."""
    from rackstress.scenes.toml import load_toml

    return load_toml(Path(path), {"spacing": a}, poisson="lattice" if old else "material")

COST_BAR = """
name = "cost"
units = "mm-N-s"
analysis = "{analysis}"
steps = {steps}
[params]
spacing = 1.0
[[group]]
name = "bar"
fill = {{ box = {{ min = [0, -5, -5], max = [{L}, 5, 5] }} }}
spacing = "$spacing"
origin = [0, "$(-5 + spacing / 2)", "$(-5 + spacing / 2)"]
material = "aluminium"
[[support]]
on = "bar"
where = {{ box = {{ min = [-0.01, -6, -6], max = [0.01, 6, 6] }} }}
[[load]]
on = "bar"
where = {{ box = {{ min = ["$({L} - 0.99 * spacing)", -6, -6], max = [{L1}, 6, 6] }} }}
force = [0, 0, -100]
"""


def cost(tmp: Path, echo=print, a: float = 0.5, length: float = 125.0,
         steps: int = 1200, repeat: int = 3) -> dict:
    """Today's lattice (bindings alone) against it with the volumetric term, in one run: a
    static solve of the 125 × 10 × 10 mm aluminium bar at ``a`` (100,400 particles at 0.5 mm),
    each in its own process (CPU time and peak memory); and the compiled plugin's step on the
    same bar at 1 mm, dynamic, ``steps`` steps, interleaved ``repeat`` times (CPU time of the
    LAMMPS run in this process, the best of each). Every BLAS on one thread: an idle BLAS
    thread spinning after NumPy's work is counted as CPU time, the same seconds for both
    lattices, which flattered their ratio."""
    import os
    import subprocess
    import sys

    from threadpoolctl import threadpool_limits

    from rackstress.engines.driver import drive
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    f = tmp / "cost-static.toml"
    f.write_text(COST_BAR.format(analysis="static", steps=1, L=length, L1=length + 0.01))
    script = tmp / "cost.py"
    script.write_text(COST_SCRIPT)
    static = {}
    for which in ("old", "new", "old", "new"):
        r = subprocess.run([sys.executable, str(script), str(f), str(a), which],
                           capture_output=True, text=True, timeout=3600,
                           env={**os.environ, "OPENBLAS_NUM_THREADS": "1",
                                "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
        if r.returncode != 0:
            raise RuntimeError(f"cost run ({which}) failed: {r.stderr[-2000:]}")
        got = json.loads(r.stdout.strip().splitlines()[-1])
        if which not in static or got["cpu_s"] < static[which]["cpu_s"]:
            static[which] = got
        echo(f"  static solve, {which} lattice: {got['cpu_s']:.1f} s of CPU, "
             f"{got['iterations']} Newton steps, peak {got['maxrss_MB']:.0f} MB")
    f = tmp / "cost-dynamic.toml"
    f.write_text(COST_BAR.format(analysis="dynamic", steps=steps, L=length, L1=length + 0.01))
    step = {}
    for k in range(repeat):
        for which in ("old", "new"):
            sc = _cost_scene(str(f), 1.0, which == "old")
            run = LammpsRun(compile_deck(sc, "exact", plugin=True), None)
            try:
                with threadpool_limits(1):
                    c0 = time.process_time()
                    drive(run)
                    cpu = time.process_time() - c0
            finally:
                run.close()
            step[which] = min(step.get(which, np.inf), cpu / steps)
            echo(f"  plugin, {which} lattice: {cpu / steps * 1e3:.3f} ms of CPU a step "
                 f"({sc.n_particles:,} particles)")
    from rackstress.model.volume import volume_terms

    sc = _cost_scene(str(tmp / "cost-static.toml"), a, False)
    t = volume_terms(sc)
    term_bytes = (t.i.nbytes + t.j.nbytes + t.L.nbytes + t.owner.nbytes + t.kappa.nbytes
                  + t.C.data.nbytes + t.C.indices.nbytes + t.C.indptr.nbytes)
    return {"spacing": a, "particles": static["new"]["particles"],
            "static_old": static["old"], "static_new": static["new"],
            "static_ratio": static["new"]["cpu_s"] / static["old"]["cpu_s"],
            "step_old_ms": step["old"] * 1e3, "step_new_ms": step["new"] * 1e3,
            "step_ratio": step["new"] / step["old"], "steps": steps,
            "term_MB": term_bytes / 1e6,
            "term_bytes_per_particle": term_bytes / sc.n_particles,
            "load": round(os.getloadavg()[0], 1)}


# ---------------------------------------------------------------------------- the examples
README_PART = """
name = "my-part"
units = "mm-N-s"
analysis = "static"
[params]
spacing = 1.0
[[group]]
name = "part"
mesh = "{stl}"
spacing = "$spacing"
material = "aluminium"
[[support]]
on = "part"
where = {{ cylinder = {{ start = [-1, 6, 8], end = [4, 6, 8], radius = 4 }} }}
[[load]]
on = "part"
where = {{ box = {{ min = [28, 26, -1], max = [31, 31, 17] }} }}
force = [0, -100, 0]
"""


def _peak(sc, p):
    """(largest von Mises [MPa] over the part's particles, where) by the stress measure's
    plain virial over each cell (the bindings' and the volumetric term's), and the loaded
    particles' mean displacement [mm]."""
    from rackstress.bench.cantilever import virial, von_mises
    from rackstress.engines.static import external_forces
    from rackstress.runs.run import volumes_of

    s = virial(sc, p, volumes_of(sc))
    vm = von_mises(s)
    k = int(np.nanargmax(vm))
    loaded = np.any(external_forces(sc) != 0.0, axis=1)
    u = np.linalg.norm((p - sc.original_positions())[loaded], axis=1).mean()
    return float(vm[k]), sc.original_positions()[k].tolist(), float(u)


def examples(tmp: Path, echo=print) -> list:
    """The committed material examples and README's part, solved with the former lattice
    (the bindings alone, ν = 1/4) and with the volumetric term (the material's ν = 0.33): the
    loaded particles' displacement and the peak von Mises, each's change."""
    import shutil

    from rackstress.bench import repository_file
    from rackstress.engines.static import solve

    stl = repository_file("examples", "bracket", "bracket.stl")
    shutil.copy(stl, tmp / "bracket.stl")
    (tmp / "my-part.toml").write_text(README_PART.format(stl="bracket.stl"))
    cases = [("cantilever (examples/cantilever, spacing 1)",
              repository_file("examples", "cantilever", "scene.toml")),
             ("bracket (examples/bracket/static.toml)",
              repository_file("examples", "bracket", "static.toml")),
             ("link (examples/link)", repository_file("examples", "link", "scene.toml")),
             ("README's part (bracket.stl, one bolt)", tmp / "my-part.toml")]
    from rackstress.runs.run import run
    from rackstress.stress.post import postprocess

    rows = []
    for k, (label, path) in enumerate(cases):
        row = {"case": label}
        for which in ("old", "new"):
            sc = _cost_scene(str(path), 1.0, which == "old")
            res = solve(sc)
            vm, at, u = _peak(sc, res.p)
            # the governing stress as `rackstress run` reports it (the default route)
            out = tmp / f"example-{k}-{which}"
            run(sc, out, progress=False)
            gov = postprocess(out, vtk=False, dump=False)["governing"]
            row[which] = {"settled": bool(res.settled), "iterations": res.iterations,
                          "peak_MPa": vm, "at": at, "displacement_mm": u,
                          "governing_MPa": float(gov["value"]), "governing_read": gov.get("read")}
        row["peak_change"] = row["new"]["peak_MPa"] / row["old"]["peak_MPa"] - 1
        row["governing_change"] = (row["new"]["governing_MPa"] / row["old"]["governing_MPa"]
                                   - 1)
        row["displacement_change"] = (row["new"]["displacement_mm"]
                                      / row["old"]["displacement_mm"] - 1)
        rows.append(row)
        echo(f"  {label}: displacement {row['old']['displacement_mm']:.4f} -> "
             f"{row['new']['displacement_mm']:.4f} mm ({row['displacement_change'] * 100:+.1f} %),"
             f" peak von Mises {row['old']['peak_MPa']:.1f} -> {row['new']['peak_MPa']:.1f} MPa "
             f"({row['peak_change'] * 100:+.1f} %), governing {row['old']['governing_MPa']:.1f} "
             f"-> {row['new']['governing_MPa']:.1f} MPa ({row['governing_change'] * 100:+.1f} %)")
    return rows
