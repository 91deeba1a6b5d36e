"""``rackstress bench walls``: a wall whose faces fall between the lattice's layers, in bending.

A cantilever from an STL box, 60 mm long and 6 mm wide, spacing 1 mm (E = 70 GPa, ν = 0.3 and
three depths at 0.1 and 0.45, ``poisson = "material"``; and bound by its bindings alone, as a
part is by default, ``poisson = "lattice"`` with ν = ¼), clamped at x < 1 and carrying
F = 20 N·(t/5 mm)³ at x > 59 (the same strains at every depth), as a user
runs it (``rackstress.runs.run``, static). Its depth t is swept so that the face lies anywhere
from the outer layer to a spacing past it: the face cells' extent φ (``bindings.npz``) runs
from 0.8 to 1.225 (docs/calibration.md "Walls of any thickness"); and walls the lattice meets
off-centre (:data:`OFF_CENTRE`: a block at the clamp rises above the wall, the top face's
cells overhang up to φ = 1.345 and the bottom's fall short). Measured against beam
theory (E·I = E·b·t³/12, Timoshenko's shear term F·L/(κ·G·A) with κ = 5/6):

* **tip**: the loaded particles' mean deflection over F·L³/(3EI) + F·L/(κGA), L from the
  clamp's last layer to the load's particles: the lattice's bending stiffness;
* **curvature**: the lattice's own strain at the face, E·κ·t/2 over M·(t/2)/I at x = 29.5,
  κ the slope across the layers of the axial strain between x = 24.5 and 34.5 (their
  displacements), M = F·(x_F − 29.5): what the particles' displacements say;
* **face**: the default route's (patch recovery, read on the face) largest σ_xx on the top
  face at x = 29.5 over M·(t/2)/I: what ``rackstress run`` reads; and each top particle's
  across the width (edges included) over the curvature's and over M·(t/2)/I, smallest and
  largest; the bottom face's particles (in compression) over M·(t/2)/I.

The face reading follows the lattice's curvature where the recovery is exact for a linear
field; the difference between the two columns is the recovery's own error, the curvature's
over 1 the lattice's. Writes ``docs/benchmarks/walls.{json,md}``.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from rackstress.bench import fmt, machine, md_table, out_dir, write_json

E, B, L, FORCE = 70000.0, 6.0, 60.0, 20.0
#: (depth [mm] at spacing 1, ν, poisson): 2 to 8 layers, faces from 0.3 spacings short of half
#: a spacing past the outer layer to 0.725 past it, at ν = 0.3; three of them at 0.1, 0.45; and
#: 2 to 10 layers bound by their bindings alone (ν = ¼), where the sample offsets of
#: ``tensor.SAMPLE_BINDINGS_EDGE`` were fitted
CASES = tuple((t, 0.3, "material") for t in (2.05, 2.2, 2.4, 2.6, 2.8, 3.0, 4.0, 4.15, 4.29,
                                             4.45, 4.6, 4.8, 5.0, 5.29, 6.29, 8.29)) \
    + tuple((t, nu, "material") for nu in (0.1, 0.45) for t in (4.0, 4.29, 5.0)) \
    + tuple((t, 0.25, "lattice") for t in (2.05, 2.4, 2.8, 3.0, 3.2, 4.0, 4.29, 5.0, 5.29, 6.0,
                                           6.29, 8.0, 10.0))
#: (depth, ν, poisson, lift [mm]): walls the lattice meets off-centre, as a part's walls are
#: where the fill's lattice is centred on the whole part, not on the wall. A block at the
#: clamp (x < 0, held) rises ``lift`` above the wall and moves the lattice's centre (the part's
#: box's) up by lift/2: the top face's cells overhang (φ 1.2 … 1.345), the bottom's fall short;
#: or the top's fall short (4 at lift 0.4: φ 0.8 / 1.2) and both (2.4 at 0.3: φ 0.55 / 0.85,
#: three layers in 2.4 spacings)
OFF_CENTRE = ((3.0, 0.25, "lattice", 1.6), (4.29, 0.25, "lattice", 0.6),
              (5.29, 0.25, "lattice", 0.6), (6.29, 0.25, "lattice", 0.6),
              (4.0, 0.25, "lattice", 0.4), (2.4, 0.25, "lattice", 0.3),
              (4.29, 0.3, "material", 0.6))
QUICK = ((4.0, 0.3, "material"), (4.29, 0.3, "material"), (4.0, 0.25, "lattice"))
SCENE = """
name = "wall"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "wall"
fill = {{ mesh = "wall.stl" }}
spacing = 1
material = {{ E = {E_pa:.6g}, nu = {nu}, density = 2700 }}
poisson = "{poisson}"
[[support]]
on = "wall"
where = {{ box = {{ min = [-1, -9, -9], max = [1, 9, 9] }} }}
[[load]]
on = "wall"
where = {{ box = {{ min = [59, -9, -9], max = [61, 9, 9] }} }}
force = [0, 0, -{F:.6g}]
"""
HEADER = ["poisson", "depth [mm]", "ν", "layers", "face φ", "bottom φ", "tip / beam",
          "curvature / beam",
          "face σ_xx / beam", "face / curvature", "across the width / curvature",
          "across the width / beam", "bottom face / beam"]


def case(depth: float, nu: float, tmp: Path, poisson: str = "material",
         lift: float = 0.0) -> dict:
    """One depth: the run and its three ratios (module docstring); ``lift``: the clamp's block
    rising that far above the wall (:data:`OFF_CENTRE`)."""
    import trimesh

    from rackstress.runs.run import run
    from rackstress.scenes import load_toml
    from rackstress.stress import load_run
    from rackstress.stress.measures import ParticleStress, positions, read_fractions

    d = tmp / f"t{depth:g}-{nu:g}-{poisson}-{lift:g}"
    d.mkdir()
    m = trimesh.creation.box(extents=[L, B, depth])
    m.apply_translation([L / 2, 0, depth / 2])
    if lift:
        k = trimesh.creation.box(extents=[0.8, B, depth + lift])
        k.apply_translation([-0.5, 0, (depth + lift) / 2])
        m = trimesh.util.concatenate([m, k])
    m.export(d / "wall.stl")
    F = FORCE * (depth / 5.0) ** 3
    (d / "wall.toml").write_text(SCENE.format(E_pa=E * 1e6, nu=nu, F=F, poisson=poisson))
    summary = run(load_toml(d / "wall.toml"), d / "r", progress=False)
    got = load_run(d / "r")
    o = got.o
    u = positions(got.trajectory[-1]) - o             # float64, as the dump wrote them
    xs = np.unique(o[:, 0])
    xa, xb, x0 = (float(xs[np.argmin(np.abs(xs - x))]) for x in (24.5, 34.5, 29.5))
    zs = np.unique(o[o[:, 0] == x0, 2])              # the wall's layers (not the block's)
    zc = 0.5 * (zs[0] + zs[-1])
    I = B * depth ** 3 / 12
    G = E / (2 * (1 + nu))
    x_F = o[o[:, 0] > 59, 0].mean()
    span = x_F - o[o[:, 0] < 1.01, 0].max()
    beam = F * span ** 3 / (3 * E * I) + F * span / (5 / 6 * G * B * depth)
    tip = -u[o[:, 0] > 59, 2].mean() / beam
    eps = []
    for z in zs:
        a = (o[:, 2] == z) & np.isclose(o[:, 0], xa)
        b = (o[:, 2] == z) & np.isclose(o[:, 0], xb)
        eps.append((u[b, 0].mean() - u[a, 0].mean()) / (xb - xa))
    kappa = np.polyfit(zs - zc, eps, 1)[0]
    sigma = F * (x_F - x0) * (depth / 2) / I
    curvature = kappa * E * (depth / 2) / sigma
    sx = ParticleStress(got).run().results.stress[-1][:, 0]
    top = (o[:, 2] == zs[-1]) & np.isclose(o[:, 0], x0)
    bottom = (o[:, 2] == zs[0]) & np.isclose(o[:, 0], x0)
    face = float(np.max(sx[top])) / sigma
    width = sx[top] / sigma / float(curvature)
    phi = read_fractions(got)
    return {"poisson": poisson, "depth": depth, "nu": nu, "layers": len(zs), "lift": lift,
            "phi": float(np.median(phi[top, 2])), "phi_bottom": float(np.median(phi[bottom, 2])),
            "width_low": float(width.min()), "width_high": float(width.max()),
            "beam_low": float(np.min(sx[top]) / sigma), "beam_high": float(np.max(sx[top]) / sigma),
            "bottom_low": float(np.min(-sx[bottom]) / sigma),
            "bottom_high": float(np.max(-sx[bottom]) / sigma),
            "settled": bool(summary["settled"]), "particles": len(o), "tip_ratio": float(tip),
            "curvature_ratio": float(curvature), "face_ratio": face,
            "face_over_curvature": face / float(curvature)}


def run_bench(out: Path | None = None, quick: bool = False, echo=print) -> dict:
    """Every case of :data:`CASES` (``quick``: two); writes walls.{json,md}."""
    out = out_dir(out)
    t0 = time.time()
    rows = []
    with tempfile.TemporaryDirectory(prefix="rs-walls-") as tmp:
        for depth, nu, poisson, *lift in QUICK if quick else CASES + OFF_CENTRE:
            r = case(depth, nu, Path(tmp), poisson, *lift)
            rows.append(r)
            echo(f"{poisson}: depth {depth:g} mm, nu {nu:g}: {r['layers']} layers, face φ {r['phi']:.3f}: tip "
                 f"{r['tip_ratio']:.3f}, curvature {r['curvature_ratio']:.3f}, face "
                 f"{r['face_ratio']:.3f} of beam theory")
    name = "walls-quick" if quick else "walls"
    data = {"rows": rows, "machine": machine(), "wall_s": time.time() - t0,
            "files": [str(out / f"{name}.json"), str(out / f"{name}.md")]}
    write_json(out / f"{name}.json", data)
    (out / f"{name}.md").write_text(report(data))
    return data


def table_rows(data) -> list:
    return [[r["poisson"], fmt(r["depth"]), fmt(r["nu"]), r["layers"], fmt(r["phi"], 4),
             fmt(r["phi_bottom"], 4), fmt(r["tip_ratio"], 4), fmt(r["curvature_ratio"], 4),
             fmt(r["face_ratio"], 4),
             fmt(r["face_over_curvature"], 4),
             f"{fmt(r['width_low'], 3)} … {fmt(r['width_high'], 3)}",
             f"{fmt(r['beam_low'], 3)} … {fmt(r['beam_high'], 3)}",
             f"{fmt(r['bottom_low'], 3)} … {fmt(r['bottom_high'], 3)}"] for r in data["rows"]]


def report(data) -> str:
    rows = data["rows"]
    mat = [r for r in rows if r.get("poisson", "material") == "material"]
    lat = [r for r in rows if r.get("poisson") == "lattice"]
    text = ""
    if mat:
        dev = max(abs(r["curvature_ratio"] - 1) for r in mat)
        rec = max(max(abs(r["width_low"] - 1), abs(r["width_high"] - 1)) for r in mat)
        text += (f"\nWith the material's ν (`poisson = \"material\"`) the lattice's curvature is "
                 f"within {100 * dev:.1f} % of beam theory's at every depth; the recovered face "
                 f"stress, edges included, within {100 * rec:.1f} % of the lattice's own "
                 "curvature (docs/stress.md).\n")
    if lat:
        dev = max(abs(r["curvature_ratio"] - 1) for r in lat)
        thick = [r for r in lat if r["layers"] >= 3]
        beam = max(max(abs(r["beam_low"] - 1), abs(r["beam_high"] - 1)) for r in thick) \
            if thick else float("nan")
        bottom = max(max(abs(r["bottom_low"] - 1), abs(r["bottom_high"] - 1)) for r in thick) \
            if thick else float("nan")
        text += (f"\nBound by its bindings alone (`poisson = \"lattice\"`, the default) the "
                 f"lattice's curvature is within {100 * dev:.1f} % of beam theory's; on walls "
                 f"of three layers and more every top particle, edges included, reads beam "
                 f"theory's face stress within {100 * beam:.1f} %, every bottom particle within "
                 f"{100 * bottom:.1f} % (docs/stress.md).\n")
    return (
        "# A wall whose faces fall between the layers, in bending\n\n"
        "Written by `rackstress bench walls` (module docstring of `bench/walls.py`): a "
        f"cantilever from an STL box, {L:g} × {B:g} mm × the depth, spacing 1 mm "
        f"(E = {E / 1000:g} GPa, ν as given, with the material's ν (`poisson = \"material\"`) "
        "or bound by its bindings alone (`poisson = \"lattice\"`, ν = ¼, the default)), "
        "clamped at one end and "
        f"carrying {FORCE:g} N·(t/5 mm)³ at the other, static. *tip*: the load's mean "
        "deflection over beam theory with Timoshenko's shear term; *curvature*: the lattice's own axial strain at "
        "the face (the slope across the layers of their displacements' strain at mid-span) "
        "times E over M·(t/2)/I; *face*: the default route's largest σ_xx on the top face at "
        "mid-span over M·(t/2)/I, what `rackstress run` reads, and over the curvature's; "
        "*across the width*: every top particle's there (edges included) over the "
        "curvature's and over M·(t/2)/I; *bottom face*: the same of the bottom layer's "
        "particles (in compression) over M·(t/2)/I. *face φ*, *bottom φ*: the top and bottom layers' cell "
        "extent across the face (1: the face half a spacing past it); where the two differ the "
        "lattice meets the wall off-centre, as it meets a part's walls (a block at the clamp "
        "rises above the wall and moves the lattice up).\n\n"
        + md_table(HEADER, table_rows(data))
        + text + "\n"
        f"Machine: {data['machine']['cores']} cores, load average "
        + " / ".join(f"{x:.1f}" for x in data["machine"]["load_avg_at_start"] or ())
        + f" at the start; {data['wall_s']:.0f} s wall.\n")
