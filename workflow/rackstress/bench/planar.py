"""The three planar validity cases as a user builds them: aluminium in mm-N-s, loads in N, peak
von Mises in MPa against plane-stress FEA (``rackstress bench validity``, or
``--planar`` for these rows alone).

Each case is the paper-unit built-in of :mod:`rackstress.scenes.validation` at spacing 1 mm,
written as a scene file (:data:`SCENES`): a ``material = "aluminium"`` part (E = 70 GPa,
ν = 0.33) filled from a ``fill`` region (the solid lattice, bound within 1.5 spacings without
crossing free space), ``[[support]]`` / ``[[load]]`` with forces in N, ``analysis = "static"``,
run by ``rackstress run`` (:func:`rackstress.runs.run.run`) and measured by the run's own
default ``von_mises`` measure (:class:`rackstress.stress.measures.ParticleStress`).

**Why a plate of three layers.** The FEA is plane stress (a thin plate: σ_zz = 0, through-
thickness stress uniform). The lattice is simple cubic, so the plate is three layers thick
(t = 3 spacings, faces free at z = ±1.5 spacings); the middle layer (z = 0) is a symmetry
plane, held in z only (``fix = ["z"]``), which removes the out-of-plane rigid motions without
acting in the plane. One layer has no through-thickness bindings (a different material); three
is the fewest with an interior layer. The FEA carries the same total force per unit thickness
(P/t), so its stress is in MPa too.

Cases (lengths in mm at spacing a = 1 mm; particles at the cell centres, half a spacing inside
every face):

* ``cantilever`` — 40 × 6 × 3, held over x < 2 (two columns), 20 N in −y shared by the last
  column; FEA: the beam [2, 40] × [0, 6] clamped at x = 2.
* ``plate-hole`` — (2W)² × 3 with W = (n + ½)·a, a hole of radius 4 mm, 10 MPa along ±x (a
  total force σ·2W·t on each end column); symmetry planes x = 0 (``fix = ["x"]``) and y = 0
  (``fix = ["y"]``) as in the FEA's quarter model. Kirsch (infinite plate): σ_max = 3σ at the
  hole's edge (0, ±4); Heywood's finite-width strip: K_t = (2 + (1 − d/D)³)·D/(D − d).
  Run at spacings 1, ½, ¼, ⅛ mm (the hole 4, 8, 16, 32 spacings) for the ratio's convergence.
* ``l-bracket`` — leg 6 × 26, arm 24 × 6 (the arm's top at y = 26), held over y < 2, 20 N in −y
  on the arm's last column; FEA: the L shifted down by 2, fixed along its bottom edge. Particles
  within 1.5 spacings of the re-entrant corner (6, 20) are left out (singular, σ ~ r^−0.456).

FEA: :mod:`rackstress.validity.fea` (P2 triangles, E = 70,000 MPa, ν = 0.33, mesh densities 4
and 8 per mm), at the particles' centres and as the mean over each particle's a × a cell (4 × 4
samples, the part inside the body).
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

E, NU = 70000.0, 0.33                     # aluminium [MPa]
LAYERS = 3
P_CANTILEVER = 20.0                       # N
P_BRACKET = 20.0                          # N
SIGMA = 10.0                              # MPa, the plate's far-field tension
HOLE = 4.0                                # mm
HALF_WIDTH = 12.5                         # mm, at spacing 1 (n = 12)
PLATE_SPACINGS = (1.0, 0.5, 0.25, 0.125)
QUICK_PLATE_SPACINGS = (1.0,)
DENSITIES = (4, 8)                        # FEA mesh per mm
CORNER_EXCLUDE = 1.5                      # spacings
CELL_SAMPLES = 4

_HEAD = """name = "{name}"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "part"
fill = {fill}
spacing = {a}
origin = [{ox}, {oy}, 0]
material = "aluminium"
"""
_SUPPORT = """[[support]]
on = "part"
where = {{ box = {{ min = [{x0}, {y0}, {z0}], max = [{x1}, {y1}, {z1}] }} }}
fix = {fix}
"""
_LOAD = """[[load]]
on = "part"
where = {{ box = {{ min = [{x0}, {y0}, -9], max = [{x1}, {y1}, 9] }} }}
force = [{fx}, {fy}, 0]
"""


def _box(lo, hi) -> str:
    return f"{{ box = {{ min = {list(lo)}, max = {list(hi)} }} }}"


def scene_text(case: str, a: float = 1.0, half_width: float = HALF_WIDTH) -> tuple[str, dict]:
    """The scene file of ``case`` at spacing ``a`` [mm] and its FEA twin's geometry
    (``half_width``: the plate's, rounded to (n + ½)·a)."""
    h = LAYERS * a / 2                    # the plate's half thickness
    eps = 0.01 * a
    mid = dict(x0=-99, y0=-99, z0=-eps, x1=99, y1=99, z1=eps, fix='["z"]')
    if case == "cantilever":
        fill = _box([0, 0, -h], [40, 6, h])
        txt = _HEAD.format(name=case, fill=fill, a=a, ox=a / 2, oy=a / 2)
        txt += _SUPPORT.format(x0=-1, y0=-1, z0=-9, x1=2 - eps, y1=7, z1=9, fix='["x", "y", "z"]')
        txt += _LOAD.format(x0=40 - a + eps, y0=-1, x1=41, y1=7, fx=0, fy=-P_CANTILEVER)
        return txt, dict(L=38.0, h=6.0, P=P_CANTILEVER / (2 * h), x0=2.0, y0=0.0,
                         shift=(0.0, 0.0), t=2 * h)
    if case == "plate-hole":
        n = int(round(half_width / a - 0.5))
        W = (n + 0.5) * a
        fill = ("{ difference = [" + _box([-W, -W, -h], [W, W, h])
                + f", {{ cylinder = {{ start = [0, 0, {-2 * h}], end = [0, 0, {2 * h}], "
                f"radius = {HOLE} }} }} ] }}")
        txt = _HEAD.format(name=case, fill=fill, a=a, ox=0, oy=0)
        txt += _SUPPORT.format(x0=-eps, y0=-99, z0=-9, x1=eps, y1=99, z1=9, fix='["x"]')
        txt += _SUPPORT.format(x0=-99, y0=-eps, z0=-9, x1=99, y1=eps, z1=9, fix='["y"]')
        txt += _SUPPORT.format(**mid)
        F = SIGMA * 2 * W * 2 * h
        txt += _LOAD.format(x0=n * a - eps, y0=-99, x1=99, y1=99, fx=F, fy=0)
        txt += _LOAD.format(x0=-99, y0=-99, x1=-n * a + eps, y1=99, fx=-F, fy=0)
        return txt, dict(a=HOLE, W=W, sigma=SIGMA, shift=(0.0, 0.0), t=2 * h)
    if case == "l-bracket":
        fill = "{ union = [" + _box([0, 0, -h], [6, 26, h]) + ", " \
            + _box([0, 20, -h], [24, 26, h]) + "] }"
        txt = _HEAD.format(name=case, fill=fill, a=a, ox=a / 2, oy=a / 2)
        txt += _SUPPORT.format(x0=-1, y0=-1, z0=-9, x1=7, y1=2 - eps, z1=9, fix='["x", "y", "z"]')
        txt += _LOAD.format(x0=24 - a + eps, y0=19, x1=25, y1=27, fx=0, fy=-P_BRACKET)
        return txt, dict(w=6.0, H=24.0, Lx=24.0, P=P_BRACKET / (2 * h), shift=(0.0, 2.0),
                         t=2 * h, corner=(6.0, 20.0))
    raise ValueError(f"no planar case {case!r}")


def kirsch_von_mises(x: np.ndarray, y: np.ndarray, a: float, sigma: float) -> np.ndarray:
    """Kirsch's infinite plate with a hole of radius a under σ along x: plane-stress von Mises
    √(σ_rr² − σ_rrσ_θθ + σ_θθ² + 3σ_rθ²) at (x, y), r ≥ a (3σ at (0, ±a))."""
    r, th = np.hypot(x, y), np.arctan2(y, x)
    q2, q4, c, s = (a / r) ** 2, (a / r) ** 4, np.cos(2 * th), np.sin(2 * th)
    srr = sigma / 2 * (1 - q2) + sigma / 2 * (1 - 4 * q2 + 3 * q4) * c
    stt = sigma / 2 * (1 + q2) - sigma / 2 * (1 + 3 * q4) * c
    srt = -sigma / 2 * (1 + 2 * q2 - 3 * q4) * s
    return np.sqrt(srr ** 2 - srr * stt + stt ** 2 + 3 * srt ** 2)


def heywood(d: float, D: float) -> float:
    """Heywood's stress concentration of a strip of width D with a central hole of diameter d,
    on the gross section's stress: (2 + (1 − d/D)³)·D/(D − d)."""
    return (2 + (1 - d / D) ** 3) * D / (D - d)


def _fea(case: str, g: dict):
    from rackstress.validity import fea

    kw = dict(E=E, nu=NU)
    if case == "cantilever":
        return lambda density: fea.cantilever(g["L"], g["h"], g["P"], g["x0"], g["y0"],
                                              density=density, **kw)
    if case == "plate-hole":
        return lambda density: fea.plate_with_hole(g["a"], g["W"], g["sigma"], density=density,
                                                   **kw)
    return lambda density: fea.l_bracket(g["w"], g["H"], g["Lx"], g["P"], density=density, **kw)


def cell_mean(field, points: np.ndarray, a: float, hole: float | None) -> np.ndarray:
    """``field(points)`` (σ_vm) averaged over each point's a × a cell (CELL_SAMPLES² samples,
    those outside a hole of radius ``hole``): the particle's own resolution."""
    t = ((np.arange(CELL_SAMPLES) + 0.5) / CELL_SAMPLES - 0.5) * a
    offs = np.stack(np.meshgrid(t, t, indexing="ij"), axis=-1).reshape(-1, 2)
    pts = (points[:, None, :] + offs[None]).reshape(-1, 2)
    owner = np.repeat(np.arange(len(points)), len(offs))
    keep = np.ones(len(pts), dtype=bool) if hole is None else np.hypot(*pts.T) >= hole
    vm = field(pts[keep])
    return np.bincount(owner[keep], weights=vm, minlength=len(points)) \
        / np.maximum(np.bincount(owner[keep], minlength=len(points)), 1)


def staircase(o: np.ndarray, vm: np.ndarray, fvm: np.ndarray, a: float) -> dict:
    """The hole's staircase edge: particles within 1.5 spacings of the hole where FEA's σ_vm
    is at least half its peak, grouped by their in-plane neighbours within 1.5 spacings in
    their own layer (8: a full ring; 7: the inner corner of a step; ≤ 6: a step's outer
    corners): particles / FEA at centres, mean and largest, and where the peak particle is."""
    from scipy.spatial import cKDTree

    nb = np.zeros(len(o), dtype=int)
    for z in np.unique(np.round(o[:, 2] / a)):
        m = np.flatnonzero(np.round(o[:, 2] / a) == z)
        t = cKDTree(o[m, :2])
        nb[m] = [len(x) - 1 for x in t.query_ball_point(o[m, :2], 1.5 * a)]
    r = np.hypot(o[:, 0], o[:, 1])
    band = (r - HOLE < 1.5 * a) & (fvm >= 0.5 * fvm.max())
    out = {}
    for name, sel in (("8", nb == 8), ("7", nb == 7), ("<=6", nb <= 6)):
        q = (vm / fvm)[band & sel]
        out[name] = {"n": int(len(q)), "mean": float(q.mean()) if len(q) else None,
                     "max": float(q.max()) if len(q) else None}
    k = int(np.argmax(vm))
    out["peak_neighbours"] = int(nb[k])
    out["peak_r_minus_hole"] = float(r[k] - HOLE)
    return out


def run_case(case: str, a: float, work: Path, echo=print, half_width: float = HALF_WIDTH) -> dict:
    """Write, run (``rackstress run``) and measure one case; its FEA at centres and cells."""
    from rackstress.runs.run import run
    from rackstress.scenes import load
    from rackstress.stress.measures import ParticleStress
    from rackstress.stress.rundata import load_run

    txt, g = scene_text(case, a, half_width)
    f = work / f"{case}-{a:g}-{half_width:g}.toml"
    f.write_text(txt)
    t0 = time.perf_counter()
    sc = load(str(f))
    out = work / f"{case}-{a:g}-{half_width:g}"
    summary = run(sc, out, progress=False, overwrite=True)
    t_run = time.perf_counter() - t0
    vm_all = np.asarray(ParticleStress(load_run(out)).run().results.von_mises[-1])
    sl = sc.slice("part")
    grp = sc.groups["part"]
    o, vm = grp.o, vm_all[sl]
    free = ~np.asarray(grp.held, dtype=bool) if grp.held is not None else np.ones(len(o), bool)
    # held in every direction: outside the FEA body (the clamps); symmetry rollers stay
    keep = free.copy()
    if case == "l-bracket":
        keep &= np.hypot(o[:, 0] - g["corner"][0], o[:, 1] - g["corner"][1]) > CORNER_EXCLUDE * a
    xy = o[keep, :2] - np.asarray(g["shift"])
    t0 = time.perf_counter()
    solve = _fea(case, g)
    peaks = []
    for d in DENSITIES:
        res = solve(d)
        peaks.append(float(np.max(res.at(xy)["von_mises_stress"])))
    fvm = np.asarray(res.at(xy)["von_mises_stress"])
    fcell = cell_mean(lambda x: res.at(x)["von_mises_stress"], xy, a, g.get("a"))
    t_fea = time.perf_counter() - t0
    v = vm[keep]
    kp, kf, kc = int(np.argmax(v)), int(np.argmax(fvm)), int(np.argmax(fcell))
    row = {"case": case, "spacing": a, "thickness": g["t"], "particles": int(len(o)),
           "settled": summary.get("settled"), "iterations": summary.get("iterations"),
           "residual": summary.get("residual"), "run_s": t_run, "fea_s": t_fea,
           "particles_peak_MPa": float(v[kp]), "at": o[keep][kp].tolist(),
           "fea_peak_MPa": float(fvm[kf]), "fea_at": (xy[kf] + g["shift"]).tolist(),
           "fea_cell_peak_MPa": float(fcell[kc]), "ratio": float(v[kp] / fvm[kf]),
           "ratio_cell": float(v[kp] / fcell[kc]),
           "fea_peaks_by_density": dict(zip(map(str, DENSITIES), peaks)),
           "fea_change": abs(peaks[-1] - peaks[-2]) / peaks[-1],
           "excluded_near_corner": int((free & ~keep).sum())}
    if case == "plate-hole":
        kv = kirsch_von_mises(xy[:, 0], xy[:, 1], HOLE, SIGMA)
        kc = cell_mean(lambda x: kirsch_von_mises(x[:, 0], x[:, 1], HOLE, SIGMA), xy, a, HOLE)
        row.update({"W": g["W"], "hole_spacings": HOLE / a, "kirsch_edge_MPa": 3 * SIGMA,
                    "heywood_edge_MPa": heywood(2 * HOLE, 2 * g["W"]) * SIGMA,
                    "kirsch_centres_MPa": float(kv.max()), "kirsch_cells_MPa": float(kc.max()),
                    "fea_edge_MPa": float(res.at(np.array([[0.0, HOLE]]))["von_mises_stress"][0]),
                    "nearest_r": float(np.hypot(*xy.T).min())})
        row["staircase"] = staircase(o[keep], v, fvm, a)
        row["ratio_kirsch_centres"] = row["particles_peak_MPa"] / row["kirsch_centres_MPa"]
        row["ratio_kirsch_cells"] = row["particles_peak_MPa"] / row["kirsch_cells_MPa"]
    echo(f"  planar {case} a = {a:g} mm: {len(o):,} particles, peak σ_vm "
         f"{row['particles_peak_MPa']:.2f} MPa at {np.round(row['at'], 2).tolist()}, FEA "
         f"{row['fea_peak_MPa']:.2f} (cells {row['fea_cell_peak_MPa']:.2f}) → ratio "
         f"{row['ratio']:.3f} ({row['ratio_cell']:.3f}), run {t_run:.1f} s, FEA {t_fea:.1f} s")
    return row


CASES = ("cantilever", "plate-hole", "l-bracket")
#: the wide plate for Kirsch's infinite-plate check: W ≈ 40.5 mm (d/D ≈ 0.1), spacing 1, ½ mm
KIRSCH_HALF_WIDTH = 40.5
KIRSCH_SPACINGS = (1.0, 0.5)
TITLE = "## Peak von Mises in MPa: the planar cases as material scenes"


def run_planar(quick: bool = False, echo=print) -> dict:
    """Every case at spacing 1 mm, the plate also at ½, ¼ and ⅛ mm and, for Kirsch, 81 mm wide at 1 and ½ mm
    (``quick``: spacing 1 mm, no wide plate)."""
    from rackstress.bench import machine

    t0, c0 = time.perf_counter(), time.process_time()
    start = machine()
    rows = []
    with tempfile.TemporaryDirectory(prefix="rs-planar-") as tmp:
        for case in CASES:
            for a in ((1.0,) if case != "plate-hole" else
                      (QUICK_PLATE_SPACINGS if quick else PLATE_SPACINGS)):
                rows.append(run_case(case, a, Path(tmp), echo=echo))
        for a in (() if quick else KIRSCH_SPACINGS):
            r = run_case("plate-hole", a, Path(tmp), echo=echo, half_width=KIRSCH_HALF_WIDTH)
            r["case"] = "plate-hole (wide)"
            rows.append(r)
    return {"rows": rows, "material": {"E_MPa": E, "nu": NU}, "layers": LAYERS,
            "quick": bool(quick), "machine": start,
            "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}


def section(data: dict) -> str:
    """The Markdown section of ``validity.md`` (:data:`TITLE`)."""
    from rackstress.bench import fmt, md_table

    rows = data["rows"]
    lines = [TITLE, "",
             "Generated by `rackstress bench validity --planar` (also part of the full "
             "`rackstress bench validity`; module `rackstress.bench.planar`). The three cases "
             "as a user writes them: `units = \"mm-N-s\"`, `material = \"aluminium\"` (E = "
             "70 GPa, ν = 0.33) on a `fill`ed part (the solid lattice), `[[support]]`, "
             "`[[load]]` with forces in N, `analysis = \"static\"`, run by `rackstress run`, "
             "stress by the run's default `von_mises` measure (patch route) in MPa. Plates "
             f"of {data['layers']} layers (t = 3 spacings, free faces, the middle layer a "
             "symmetry plane held in z only): the fewest with an interior layer; plane-stress "
             "FEA (scikit-fem P2, E = 70,000 MPa, ν = 0.33, meshes 4 and 8 per mm) carries the "
             "same force per unit thickness. Cantilever 40 × 6 mm held over x < 2, 20 N; plate "
             "(2W)² with a 4 mm hole, 10 MPa along x, symmetry planes x = 0 and y = 0; "
             "L-bracket leg 6 × 26, arm 24 × 6, held over y < 2, 20 N on the arm's end "
             f"(particles within {CORNER_EXCLUDE:g} spacings of the re-entrant corner left "
             "out). Peaks over the part's free particles; FEA at the same particles' centres "
             "and as the mean over each particle's cell (4 × 4 samples, the part in the body).",
             ""]
    lines.append(md_table(
        ["case", "spacing [mm]", "hole / spacing", "particles", "particles' peak σ_vm [MPa]",
         "at", "FEA peak at centres [MPa]", "ratio", "FEA peak of cell means [MPa]",
         "ratio to it", "FEA mesh change", "settled (Newton steps)"],
        [[r["case"], fmt(r["spacing"], 3), fmt(r.get("hole_spacings"), 3)
          if "hole_spacings" in r else "", f"{r['particles']:,}",
          fmt(r["particles_peak_MPa"], 4), str([round(x, 2) for x in r["at"][:2]]),
          fmt(r["fea_peak_MPa"], 4), fmt(r["ratio"], 3), fmt(r["fea_cell_peak_MPa"], 4),
          fmt(r["ratio_cell"], 3), f"{100 * r['fea_change']:.2f} %",
          f"{'yes' if r['settled'] else 'no'} ({r['iterations']})"] for r in rows]))
    plates = [r for r in rows if "kirsch_edge_MPa" in r]
    if plates:
        lines += ["", "**The plate against Kirsch.** σ∞ = 10 MPa: Kirsch's infinite plate "
                  "has σ_max = 3σ∞ = 30 MPa at the hole's edge (0, ±4); Heywood's strip of "
                  "width D = 2W: K_t = (2 + (1 − d/D)³)·D/(D − d). FEA's own value at the edge "
                  "point (0, 4) is the square plate's (its ends are as near the hole as its "
                  "sides, so it exceeds the long strip's). Kirsch's field at the particles' "
                  "centres and as cell means (analytical, infinite plate) is the reference "
                  "for the wide plate, where the finite-width correction is small.", ""]
        lines.append(md_table(
            ["plate", "spacing [mm]", "W [mm]", "Kirsch edge 3σ∞", "Heywood edge",
             "FEA edge", "Kirsch peak at centres", "particles / it",
             "Kirsch peak of cell means", "particles / it", "nearest particle r [mm]"],
            [[r["case"], fmt(r["spacing"], 3), fmt(r["W"], 4), fmt(r["kirsch_edge_MPa"], 4),
              fmt(r["heywood_edge_MPa"], 4), fmt(r["fea_edge_MPa"], 4),
              fmt(r["kirsch_centres_MPa"], 4), fmt(r["ratio_kirsch_centres"], 3),
              fmt(r["kirsch_cells_MPa"], 4), fmt(r["ratio_kirsch_cells"], 3),
              fmt(r["nearest_r"], 4)] for r in plates]))
    if plates:
        lines += ["", "**The staircase edge.** The lattice's hole is a staircase. Particles "
                  "within 1.5 spacings of the hole where FEA's σ_vm is at least half its peak, "
                  "by their in-plane neighbours within 1.5 spacings (8: a full ring; 7: the "
                  "inner corner of a step; ≤ 6: a step's outer corners); particles / FEA at the "
                  "centres, mean (largest):", ""]
        lines.append(md_table(
            ["plate", "spacing [mm]", "8 neighbours", "7", "≤ 6",
             "peak particle: neighbours, r − 4 mm"],
            [[r["case"], fmt(r["spacing"], 3)]
             + [f"{fmt(r['staircase'][k]['mean'], 3)} ({fmt(r['staircase'][k]['max'], 3)}), "
                f"n = {r['staircase'][k]['n']}" if r["staircase"][k]["n"] else "none"
                for k in ("8", "7", "<=6")]
             + [f"{r['staircase']['peak_neighbours']}, "
                f"{r['staircase']['peak_r_minus_hole']:.3f} mm"] for r in plates]))
    if plates and not data.get("quick"):
        lines += ["", _what_it_shows(rows, plates), ""]
    m = data.get("machine", {})
    la = m.get("load_avg_at_start")
    la = " / ".join(f"{x:.2f}" for x in la) if isinstance(la, (list, tuple)) else "?"
    lines += ["", f"Wall {data['wall_s']:.0f} s, CPU {data['cpu_s']:.0f} s on one core (load "
              f"average {la} at the start).", ""]
    return "\n".join(lines)


def _what_it_shows(rows: list, plates: list) -> str:
    """The section's reading of its own tables (every figure from them)."""
    def at(case, a=1.0):
        return next((r for r in rows if r["case"] == case and r["spacing"] == a), None)

    flat = [(name, at(case)) for name, case in (("the cantilever", "cantilever"),
                                                ("the L-bracket", "l-bracket")) if at(case)]
    holes = sorted((r for r in plates if r["case"] == "plate-hole"), key=lambda r: -r["spacing"])
    out = ["**What it shows** (static solves: the figures reproduce exactly)."]
    if flat:
        out.append(" Where the part's edges are lattice faces (" + " and ".join(
            f"{n}, {r['ratio']:.3f}" for n, r in flat) + " of FEA's peak at the centres, "
            "at 1 mm) the run's default measure reads the peak on the face, where it is "
            "higher than at the centres FEA is read at.")
    if holes:
        out.append(" The plate's peak sits on the hole, which the lattice draws as a "
                   "staircase: " + ", ".join(f"{r['ratio']:.3f}" for r in holes)
                   + " of FEA's at " + ", ".join(f"{r['hole_spacings']:g}" for r in holes)
                   + " spacings per radius, the patch fit flattening the last spacing's "
                   "steep rise (docs/stress.md, \"Patch recovery\"); the particles with a full "
                   "ring of neighbours beside the hole read " + ", ".join(
                       _mean(r['staircase']['8']) for r in holes) + " and those "
                   "at a step's inner corner " + ", ".join(
                       _mean(r['staircase']['7']) for r in holes)
                   + " of FEA at their centres (means).")
    out.append(" Nothing was tuned: the scenes are the built-ins' geometry in mm.")
    return "".join(out)


def _mean(group: dict) -> str:
    """A staircase group's mean (:func:`staircase`), or 'none' where no particle is in it (a
    hole whose radius the spacing divides has no step's inner corner in the band)."""
    return "none" if group.get("mean") is None else f"{group['mean']:.3f}"


def write_section(md: Path, text: str, before: str = "## Against FEA seen through") -> None:
    """Put ``text`` (a section starting with :data:`TITLE`) into ``md``: replacing that
    section if present, else before the section titled ``before`` (else at the end)."""
    old = md.read_text() if md.is_file() else ""
    if TITLE in old:
        i = old.index(TITLE)
        j = old.find("\n## ", i + len(TITLE))
        new = old[:i] + text.rstrip("\n") + "\n" + (old[j:] if j >= 0 else "")
    elif before in old:
        i = old.index(before)
        new = old[:i] + text.rstrip("\n") + "\n\n" + old[i:]
    else:
        new = old.rstrip("\n") + "\n\n" + text
    md.write_text(new)


HEADER = ["case", "spacing [mm]", "particles' peak σ_vm [MPa]", "FEA at centres [MPa]",
          "ratio", "FEA cell means [MPa]", "ratio to it"]


def table_rows(data) -> list:
    from rackstress.bench import fmt

    return [[r["case"], fmt(r["spacing"], 3), fmt(r["particles_peak_MPa"], 4),
             fmt(r["fea_peak_MPa"], 4), fmt(r["ratio"], 3), fmt(r["fea_cell_peak_MPa"], 4),
             fmt(r["ratio_cell"], 3)] for r in data["rows"]]


def run_bench(out: Path | None = None, quick: bool = False, echo=print) -> dict:
    """``rackstress bench validity --planar``: these rows alone; ``validity_planar.json`` and
    the section of ``validity.md`` rewritten in place."""
    from rackstress.bench import out_dir, write_json

    out = out_dir(out)
    data = run_planar(quick, echo)
    write_json(out / "validity_planar.json", data)
    write_section(out / "validity.md", section(data))
    data["files"] = [str(out / "validity_planar.json"), str(out / "validity.md")]
    return data
