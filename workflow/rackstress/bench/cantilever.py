"""``rackstress bench cantilever`` (also run by ``bench validity``): the material solid in
physical units against beam theory and scikit-fem, and its calibration.

* **convergence**: ``examples/cantilever`` (aluminium 100 × 10 × 10 mm, 100 N, static) at
  spacings 2, 1, 0.7 and 0.5 mm (0.7: 14.3 layers across the 10 mm, the load on the last
  layer at x = 99.4): tip deflection against P·x³/(3EI)·1.008 at the load's x (0.576 mm at
  100), mid-span top-fibre σ_xx and von Mises (virial of the bindings' forces over each
  particle's share of the bar, computed here) against M·z/I at the top particles' centres
  (27.0 MPa at z = 4.5), Newton iterations, residual, solve time;
* **calibration**: a 20 × 10 × 10 mm bar on rollers pulled by 10 MPa, uniaxial stress:
  E_eff = σ/ε_xx and ν_eff = −ε_yy/ε_xx at each spacing, against E of the material and the
  lattice's ν = 1/4 (``poisson = "material"`` gives the material's, ``rackstress bench
  lattice``);
* **ν's cost**: scikit-fem hexahedra on the same cantilever with ν = 0.33 and ν = 1/4: how much
  the peak von Mises at the clamp and the tip deflection move when only ν changes;
* **speed**: a 125 × 10 × 10 mm bar at 0.5 mm (100,400 particles) to equilibrium, beside
  scikit-fem's assembly and solve of the same part (trilinear hexahedra on the particles as
  nodes, the same AMG-preconditioned CG) — interleaved in one process.

Writes ``docs/benchmarks/cantilever.{md,json,png}``.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from rackstress.bench import repository_file

ROOT = Path(__file__).resolve().parents[3]
SCENE = repository_file("examples", "cantilever", "scene.toml")
E, NU, P, L, H = 70000.0, 0.33, 100.0, 100.0, 10.0
I = H ** 4 / 12
TIP = P * L ** 3 / (3 * E * I) * 1.008
SIGMA = P * (L / 2) * 4.5 / I


def cells(o: np.ndarray, a: float) -> np.ndarray:
    """Each particle's share of the bar [0, L] × [−H/2, H/2]², by geometry: along each axis
    ±a/2 where the next lattice site is in the bar, else up to the bar's face."""
    lo, hi = np.array([0.0, -H / 2, -H / 2]), np.array([L, H / 2, H / 2])
    up = np.where(o + a <= hi + 1e-9, a / 2, hi - o)
    down = np.where(o - a >= lo - 1e-9, a / 2, o - lo)
    return np.prod(up + down, axis=1)


def virial(scene, p: np.ndarray, V=None) -> np.ndarray:
    """n×3×3 stress per particle: Σ_j r_ij ⊗ f_ij / (2V) over its bindings and its own
    volumetric terms' virial / V (the material's Poisson's ratio, docs/calibration.md) in scene
    units; ``V`` per particle (default: the group's volume per particle)."""
    from rackstress.engines.static import _bind_pairs
    from rackstress.model.operators import Bind
    from rackstress.model.volume import Volume, volume_terms

    I_, J, C, Q = _bind_pairs(scene)
    m = scene.masses()
    f = Bind.accel(p[I_], p[J], C, Q) * m[I_][:, None]
    r = p[J] - p[I_]
    if V is None:
        V = np.concatenate([np.full(g.n, g.volume or 1.0) for g in scene.groups.values()])
    s = np.zeros((len(p), 3, 3))
    for a in range(3):
        for b in range(3):
            s[:, a, b] = np.bincount(I_, weights=r[:, a] * f[:, b], minlength=len(p)) / 2
    vol = volume_terms(scene)
    if vol is not None:
        W = Volume.virial(p, vol, m)
        for c, (a, b) in enumerate(((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))):
            s[:, a, b] += W[:, c]
            if a != b:
                s[:, b, a] += W[:, c]
    return s / V[:, None, None]


def von_mises(s: np.ndarray) -> np.ndarray:
    d = s - np.trace(s, axis1=1, axis2=2)[:, None, None] * np.eye(3) / 3
    return np.sqrt(1.5 * np.einsum("nij,nij->n", d, d))


def convergence(spacings, echo=print) -> list:
    from rackstress.engines.static import solve
    from rackstress.scenes.toml import load_toml

    rows = []
    for a in spacings:
        sc = load_toml(SCENE, {"spacing": a})
        res = solve(sc)
        o = sc.original_positions()
        # the load acts on the last layer, x_e (= L when a divides L): beam theory there
        xe = float(o[:, 0].max())
        tip = -float((res.p - o)[o[:, 0] > xe - 1e-9, 2].mean())
        tip_beam = TIP * (xe / L) ** 3
        s = virial(sc, res.p, cells(o, a))
        xm = float(o[np.argmin(np.abs(o[:, 0] - L / 2)), 0])
        z = float(o[:, 2].max())
        top = (np.abs(o[:, 0] - xm) < 1e-9) & (np.abs(o[:, 2] - z) < 1e-9)
        expect = P * (xe - xm) * z / I
        row = {"spacing": a, "particles": sc.n_particles, "iterations": res.iterations,
               "residual": res.residual, "settled": res.settled, "solve_s": res.wall_s,
               "tip_mm": tip, "tip_ratio": tip / tip_beam, "tip_beam_mm": tip_beam,
               "x_load": xe, "top_z": z,
               "top_sxx_MPa": float(s[top, 0, 0].mean()),
               "top_von_mises_MPa": float(von_mises(s[top]).mean()),
               "beam_sigma_MPa": expect}
        row["von_mises_ratio"] = row["top_von_mises_MPa"] / expect
        rows.append(row)
        echo(f"  cantilever a = {a:g} mm: {sc.n_particles:,} particles, tip {tip:.4f} mm "
             f"({tip / tip_beam:.3f} of {tip_beam:.3f}), top fibre von Mises "
             f"{row['top_von_mises_MPa']:.2f} MPa ({row['von_mises_ratio']:.3f} of "
             f"{expect:.2f}), {res.iterations} iterations, {res.wall_s:.1f} s")
    return rows


BAR = """
name = "tension"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "bar"
fill = {{ box = {{ min = [0, -5, -5], max = [20, 5, 5] }} }}
spacing = {a}
origin = [0, {o}, {o}]
material = "aluminium"
[[support]]            # rollers on the end face x = 0: only x fixed
on = "bar"
where = {{ box = {{ min = [-1, -6, -6], max = [0.01, 6, 6] }} }}
fix = ["x"]
[[support]]            # the middle lines of that face pinned across (no rigid motion, no
on = "bar"             # rotation about x about a single pinned point)
where = {{ box = {{ min = [-1, {p}, -6], max = [0.01, {q}, 6] }} }}
fix = ["y"]
[[support]]
on = "bar"
where = {{ box = {{ min = [-1, -6, {p}], max = [0.01, 6, {q}] }} }}
fix = ["z"]
[[load]]
on = "bar"
where = {{ box = {{ min = [19.99, -6, -6], max = [21, 6, 6] }} }}
force = [{F}, 0, 0]
"""


def calibration(spacings, tmp: Path, echo=print) -> list:
    """Uniaxial tension of a 20 × 10 × 10 mm bar: rollers on x = 0, a total force on x = 20."""
    from rackstress.engines.static import solve
    from rackstress.scenes.toml import load_toml

    rows = []
    sigma = 10.0                                    # MPa
    for a in spacings:
        f = tmp / f"bar-{a:g}.toml"
        f.write_text(BAR.format(a=a, o=-5 + a / 2, p=-0.6 * a, q=0.6 * a, F=sigma * 100.0))
        sc = load_toml(f)
        res = solve(sc)
        o = sc.original_positions()
        u = res.p - o
        exx = float(u[np.abs(o[:, 0] - 20) < 1e-9, 0].mean()) / 20.0
        mid = np.abs(o[:, 0] - 10) < 0.6 * a
        hi, lo = mid & (o[:, 1] > 5 - a), mid & (o[:, 1] < -5 + a)
        eyy = float(u[hi, 1].mean() - u[lo, 1].mean()) / (10.0 - a)
        rows.append({"spacing": a, "particles": sc.n_particles, "E_eff_MPa": sigma / exx,
                     "E_ratio": sigma / exx / E, "nu_eff": -eyy / exx})
        echo(f"  calibration a = {a:g} mm: E_eff {sigma / exx:.0f} MPa ({sigma / exx / E:.4f} "
             f"of E), nu_eff {-eyy / exx:.4f}")
    return rows


def fem_cantilever(a: float, nu: float, length: float = L, solver: str = "direct"):
    """scikit-fem trilinear hexahedra of size ``a`` over the whole bar, clamped at x = 0, P
    shared by the end face's nodes: tip deflection, peak von Mises of the clamp's elements,
    mid-span top-element σ_xx (element means, centres at z = H/2 − a/2), seconds, dofs."""
    import skfem
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    t0 = time.perf_counter()
    nx, ny = int(round(length / a)), int(round(H / a))
    mesh = skfem.MeshHex.init_tensor(np.linspace(0, length, nx + 1),
                                     np.linspace(-H / 2, H / 2, ny + 1),
                                     np.linspace(-H / 2, H / 2, ny + 1))
    e = skfem.ElementVector(skfem.ElementHex1())
    basis = skfem.Basis(mesh, e, intorder=2)
    K = linear_elasticity(*lame_parameters(E, nu)).assemble(basis)
    f = np.zeros(K.shape[0])
    end = basis.get_dofs(lambda x: x[0] > length - 1e-9).nodal["u^3"]
    f[end] = -P / len(end)
    D = basis.get_dofs(lambda x: x[0] < 1e-9).all()
    if solver == "direct":
        u = skfem.solve(*skfem.condense(K, f, D=D))
    else:
        import pyamg
        import scipy.sparse.linalg as spla

        from rackstress.engines.static import rigid_modes

        A, b, x0, I_ = skfem.condense(K, f, D=D)
        ml = pyamg.smoothed_aggregation_solver(A.tocsr(), symmetry="symmetric",
                                               B=rigid_modes(mesh.p.T, I_), max_coarse=500)
        x, _ = spla.cg(A, b, rtol=1e-8, M=ml.aspreconditioner())
        u = np.zeros(K.shape[0])
        u[I_] = x
    secs = time.perf_counter() - t0
    tip = -float(u[end].mean())
    # stresses at element centres
    from skfem.helpers import sym_grad

    ub = basis.interpolate(u)
    lam, mu = lame_parameters(E, nu)
    eps = sym_grad(ub)                          # 3×3×elements×points
    tr = eps[0, 0] + eps[1, 1] + eps[2, 2]
    s = 2 * mu * eps + lam * tr * np.eye(3)[:, :, None, None]
    s = s.mean(axis=3)                          # element means
    d = s - (s[0, 0] + s[1, 1] + s[2, 2]) / 3 * np.eye(3)[:, :, None]
    vm = np.sqrt(1.5 * np.einsum("ije,ije->e", d, d))
    c = mesh.p[:, mesh.t].mean(axis=1)
    near = (np.abs(c[0] - L / 2) < a) & (c[2] > H / 2 - a)
    return {"tip_mm": tip, "clamp_peak_vm_MPa": float(vm[c[0] < a].max()),
            "mid_top_sxx_MPa": float(s[0, 0][near].mean()), "seconds": secs,
            "dofs": int(K.shape[0])}


def speed(tmp: Path, echo=print, a: float = 0.5, length: float = 125.0) -> dict:
    """The same bar to equilibrium by rackstress and by scikit-fem, interleaved."""
    from rackstress.engines.static import solve
    from rackstress.scenes.toml import load_toml

    text = SCENE.read_text().replace("max = [100, 5, 5]", f"max = [{length:g}, 5, 5]").replace(
        'min = ["$(100 - 0.99 * spacing)", -6, -6], max = [100.01, 6, 6]',
        f'min = ["$({length:g} - 0.99 * spacing)", -6, -6], max = [{length + 0.01:g}, 6, 6]')
    if f"{length:g} - 0.99" not in text:
        raise RuntimeError(f"{SCENE}: its load region changed; the speed bar's load would "
                           "stay at x = 100")
    f = tmp / "bar100k.toml"
    f.write_text(text)
    t0, c0 = time.perf_counter(), time.process_time()
    sc = load_toml(f, {"spacing": a})
    build, build_cpu = time.perf_counter() - t0, time.process_time() - c0
    c0 = time.process_time()
    res = solve(sc, progress=True)
    solve_cpu = time.process_time() - c0
    c0 = time.process_time()
    fem = fem_cantilever(a, NU, length, solver="amg")
    fem_cpu = time.process_time() - c0
    out = {"particles": sc.n_particles, "build_s": build, "solve_s": res.wall_s,
           "total_s": build + res.wall_s, "iterations": res.iterations,
           "residual": res.residual, "settled": res.settled,
           "skfem_s": fem["seconds"], "skfem_dofs": fem["dofs"],
           "cpu_s": build_cpu + solve_cpu, "skfem_cpu_s": fem_cpu,
           "tip_mm": -float((res.p - sc.original_positions())[
               sc.original_positions()[:, 0] > length - 1e-9, 2].mean()),
           "skfem_tip_mm": fem["tip_mm"]}
    echo(f"  speed: {sc.n_particles:,} particles: scene {build:.1f} s + equilibrium "
         f"{res.wall_s:.1f} s ({res.iterations} Newton steps), {out['cpu_s']:.1f} s of CPU; "
         f"scikit-fem hex8 assembly + AMG-CG solve {fem['seconds']:.1f} s, {fem_cpu:.1f} s of "
         f"CPU ({fem['dofs']:,} dofs)")
    return out


def run_bench(out: Path | None = None, quick: bool = False, echo=print) -> dict:
    """All four parts (``quick``: spacings 2 and 1, no speed run); writes the figures."""
    import tempfile

    out = Path(out) if out is not None else ROOT / "docs" / "benchmarks"
    out.mkdir(parents=True, exist_ok=True)
    spacings = (2.0, 1.0) if quick else (2.0, 1.0, 0.5)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        data = {"tip_beam_mm": TIP, "sigma_beam_MPa": SIGMA, "quick": quick,
                "convergence": convergence(spacings if quick else (2.0, 1.0, 0.7, 0.5), echo),
                "calibration": calibration(spacings, tmp, echo)}
        nu_rows = []
        h = 2.0 if quick else 1.0           # the hexahedra's size (quick: 8× fewer, 20× faster)
        for nu in (NU, 0.25):
            r = fem_cantilever(h, nu)
            r["nu"], r["size"] = nu, h
            nu_rows.append(r)
            echo(f"  scikit-fem hex8 a = {h:g}, nu = {nu}: tip {r['tip_mm']:.4f} mm, clamp peak "
                 f"von Mises {r['clamp_peak_vm_MPa']:.1f} MPa, mid-span top sxx "
                 f"{r['mid_top_sxx_MPa']:.2f} MPa")
        data["nu_cost"] = nu_rows
        if not quick:
            import os

            data["speed"] = speed(tmp, echo)
            data["speed"]["load"] = round(os.getloadavg()[0], 1)
    name = "cantilever-quick" if quick else "cantilever"
    (out / f"{name}.json").write_text(json.dumps(data, indent=1))
    (out / f"{name}.md").write_text(report(data))
    plot(data, out / f"{name}.png")
    return data


def report(d: dict) -> str:
    L_ = ["# The cantilever in physical units: beam theory, calibration, speed", "",
          "Written by `rackstress bench cantilever` (also run by `rackstress bench validity`). "
          "Aluminium bar 100 × 10 × 10 mm (E = 70 GPa, ν = 0.33), clamped over x = 0, 100 N "
          "in −z on the free end, static (`examples/cantilever`).", "",
          f"Beam theory: tip deflection {d['tip_beam_mm']:.3f} mm (P·L³/3EI + 0.8 % shear) "
          "with the load at x = 100; at a spacing that does not divide 100 mm (0.7: 14.3 "
          "layers across the 10 mm too) the load acts on the last layer, x_e, and beam theory "
          "is taken there. Bending stress M·z/I at the mid-span particles nearest x = 50, at "
          "the top particles' centres.", "",
          "| spacing [mm] | particles | Newton steps | residual | solve [s] | load at x_e [mm] "
          "| tip [mm] | tip / beam | top σ_xx [MPa] | top von Mises [MPa] | beam M·z/I [MPa] | "
          "von Mises / beam |", "|" + "---|" * 12]
    for r in d["convergence"]:
        L_.append(f"| {r['spacing']:g} | {r['particles']:,} | {r['iterations']} | "
                  f"{r['residual']:.1e} | {r['solve_s']:.1f} | {r.get('x_load', 100):g} | "
                  f"{r['tip_mm']:.4f} | "
                  f"{r['tip_ratio']:.3f} | {r['top_sxx_MPa']:.2f} | "
                  f"{r['top_von_mises_MPa']:.2f} | {r['beam_sigma_MPa']:.2f} | "
                  f"{r['von_mises_ratio']:.3f} |")
    tips = [r["tip_ratio"] for r in d["convergence"]]
    L_ += ["", f"Spread of tip / beam over the spacings: "
           f"{(max(tips) - min(tips)) / min(tips) * 100:.1f} % (target ≤ 5 %). The stress is "
           "the virial of the bindings' forces, Σ r⊗f / 2V per particle, computed by this "
           "benchmark, V each particle's share of the bar from its geometry "
           "(docs/calibration.md \"Walls of any thickness\").", "",
           "## Calibration: E_eff and ν of the lattice", "",
           "A 20 × 10 × 10 mm aluminium bar on rollers at x = 0 (`[[support]]` fixing x only, "
           "its middle lines pinned across) pulled by 1000 N (10 MPa) at x = 20: uniaxial "
           "stress, E_eff = σ/ε_xx (the end face's mean displacement), ν_eff = −ε_yy/ε_xx "
           "(the side faces' particles at mid-length, 10 − a apart), with c = E/(5ρa²) "
           "(docs/calibration.md).", "",
           "| spacing [mm] | particles | E_eff [MPa] | E_eff / E | ν_eff |", "|---|---|---|---|---|"]
    for r in d["calibration"]:
        L_.append(f"| {r['spacing']:g} | {r['particles']:,} | {r['E_eff_MPa']:.0f} | "
                  f"{r['E_ratio']:.4f} | {r['nu_eff']:.4f} |")
    L_ += ["", "## What the lattice's ν = 1/4 costs", "",
           f"scikit-fem trilinear hexahedra (nodes on the {d['nu_cost'][0].get('size', 1.0):g} mm "
           "lattice) on the same cantilever, "
           "only ν changed (`poisson = \"material\"` gives a part the material's ν, "
           "docs/calibration.md):", "",
           "| ν | tip [mm] | peak von Mises at the clamp [MPa] | mid-span top σ_xx [MPa] |",
           "|---|---|---|---|"]
    for r in d["nu_cost"]:
        L_.append(f"| {r['nu']:g} | {r['tip_mm']:.4f} | {r['clamp_peak_vm_MPa']:.1f} | "
                  f"{r['mid_top_sxx_MPa']:.2f} |")
    a, b = d["nu_cost"]
    L_ += ["", f"ν = 1/4 instead of 0.33 moves the tip by "
           f"{(b['tip_mm'] / a['tip_mm'] - 1) * 100:+.1f} %, the clamp's peak von Mises by "
           f"{(b['clamp_peak_vm_MPa'] / a['clamp_peak_vm_MPa'] - 1) * 100:+.1f} % and the "
           f"bending stress by {(b['mid_top_sxx_MPa'] / a['mid_top_sxx_MPa'] - 1) * 100:+.1f} %:"
           " where the load path fixes the stress (bending, tension) ν does not matter; where "
           "a support stops the lateral contraction it does."]
    if "speed" in d:
        s = d["speed"]
        L_ += ["", "## Speed: a 100,000-particle part to equilibrium", "",
               f"A 125 × 10 × 10 mm bar at 0.5 mm: {s['particles']:,} particles. Scene "
               f"(fill, bindings) {s['build_s']:.1f} s, equilibrium {s['solve_s']:.1f} s "
               f"({s['iterations']} Newton steps, residual {s['residual']:.1e}): "
               f"{s['total_s']:.1f} s in all (target ≤ 60 s). scikit-fem, the same part as "
               f"trilinear hexahedra ({s['skfem_dofs']:,} dofs), assembly and the same "
               f"AMG-preconditioned CG: {s['skfem_s']:.1f} s. Measured in one process, one "
               "after the other, on the shared 2-core machine."]
        if "cpu_s" in s:
            L_ += ["", f"CPU time (what the process itself used; the machine was shared, load "
                   f"average {s.get('load', '?')} on 2 cores): rackstress {s['cpu_s']:.1f} s, "
                   f"scikit-fem {s['skfem_cpu_s']:.1f} s — a ratio of "
                   f"{s['cpu_s'] / s['skfem_cpu_s']:.2f}. Tip deflection: rackstress "
                   f"{s['tip_mm']:.4f} mm, scikit-fem hexahedra {s['skfem_tip_mm']:.4f} mm "
                   f"(beam theory {TIP * (125 / 100) ** 3:.4f} mm)."]
    return "\n".join(L_) + "\n"


def plot(d: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
    a = [r["spacing"] for r in d["convergence"]]
    ax[0].plot(a, [r["tip_ratio"] for r in d["convergence"]], "o-", label="lattice")
    ax[0].axhline(1.0, color="k", ls="--", label="beam theory")
    ax[0].set_xscale("log", base=2)
    ax[0].set_xlabel("spacing [mm]")
    ax[0].set_ylabel("tip deflection / beam theory")
    ax[0].set_ylim(0.8, 1.2)
    ax[0].legend()
    ax[1].plot(a, [r["von_mises_ratio"] for r in d["convergence"]], "o-", label="top-fibre von Mises")
    ax[1].plot([r["spacing"] for r in d["calibration"]],
               [r["E_ratio"] for r in d["calibration"]], "s-", label="E_eff / E (tension)")
    ax[1].axhline(1.0, color="k", ls="--")
    ax[1].set_xscale("log", base=2)
    ax[1].set_xlabel("spacing [mm]")
    ax[1].set_ylabel("ratio to theory")
    ax[1].set_ylim(0.8, 1.2)
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
