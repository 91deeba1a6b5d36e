"""``rackstress bench nafems``: NAFEMS linear-elastic benchmarks and two classical cases on the
elastic lattice with the material's Poisson's ratio (docs/calibration.md).

Targets: NAFEMS, *The Standard NAFEMS Benchmarks*, TNSB Rev. 3 (1990), problems LE1 and LE10
(the geometry and loads as reproduced in public verification suites, e.g. seamplex Fino's cases
010-nafems-le1 and 012-nafems-le10, and Code_Aster's SSLP/SSLV test manuals):

* **LE1, elliptic membrane** (also with the lattice a mesh part gets by default, cells
  tiling the quarter: ``LE1_filled``) — the quarter of a plate between the ellipses (x/2)² + y² = 1 and
  (x/3.25)² + (y/2.75)² = 1 (metres), 0.1 m thick, E = 210 GPa, ν = 0.3, plane stress; 10 MPa
  of outward normal pressure on the outer edge; u_y = 0 on y = 0, u_x = 0 on x = 0 (symmetry
  planes as rollers). σ_yy at D = (2, 0): **92.7 MPa**.
* **LE10, thick plate under pressure** (with the lattice a mesh part gets by default,
  ``LE10_filled``, at four spacings, and with particles on the faces) — the same two
  ellipses, 0.6 m thick (z from 0 to 0.6),
  1 MPa of pressure on the upper face; u_y = 0 on y = 0, u_x = 0 on x = 0, u_x = u_y = 0 on
  the outer curved face, u_z = 0 along that face's mid-plane line (z = 0.3). σ_yy at
  D = (2, 0, 0.6): **−5.38 MPa**.
* **Kirsch** — a plate 0.5 × 0.5 m with a central hole of 0.1 m diameter (d/W = 0.2) in plane
  stress (a membrane one layer thick, as LE1), 10 MPa of tension on its x faces, at ν = 0.3 and
  0.45: K_t = σ_max/σ_gross against converged plane-stress FEA of the same square plate
  (:func:`kirsch_fe`: scikit-fem P2 on a graded quarter, 3.360 at two meshes, to 1e-4; plane
  stress under tractions makes it independent of ν). Peterson's finite-width chart
  (Pilkey & Pilkey, *Peterson's Stress Concentration Factors*, 3rd ed., Chart 4.1: K_tn = 3 −
  3.14(d/W) + 3.667(d/W)² − 1.527(d/W)³ on the net section, 3.13 on the gross) is for a
  long strip; this plate is as long as it is wide, its ends 2 diameters from the hole, and
  its K_t 7 % higher (the chart was the target until 2026-12-01, and read the lattice's
  under-read as agreement). Four spacings: the finest is where the headline, before a
  one-layer part was fitted in its plane, sat on a step of the hole's staircase and read
  +10.8 %, growing with refinement.
* **Constrained block** — a 20 mm cube on rollers on its four side faces and its floor,
  pressed by 10 MPa on its top: axial stiffness σ/ε against the constrained modulus
  E(1 − ν)/((1 + ν)(1 − 2ν)) (1.35 E at ν = 0.3, 3.79 E at ν = 0.45; a ν = 1/4 lattice has 1.2 E
  whatever the material).

The stress at a point is read as the project's stress measure gives it (``ParticleStress``,
the default ``patch`` route: the bindings' and the volumetric term's virial over each
particle's cell, the free faces' cell moment restored, fitted linearly over each particle's
patch (in its plane, for a part one layer thick) and read at its recovery point — on the
face for a surface particle, docs/stress.md) at
the particle nearest the point, whose position is reported; beside it the value at the point extrapolated from the field
near it (:func:`extrapolated`: the parabola through the three nearest particles half a spacing
or more inside, on the lattice line through the point) — the project's recovery lags a steep
concentration at the surface particle itself (docs/stress.md). Three spacings each; the order
of convergence from the last two errors.

Writes ``docs/benchmarks/nafems.{md,json}``.
"""
from __future__ import annotations

import functools
import json
import time
from pathlib import Path

import numpy as np

from rackstress.bench import machine

LE1_TARGET, LE10_TARGET = 92.7, -5.38         # MPa, NAFEMS TNSB Rev. 3 (1990)
TARGET = 0.05

#: the ellipses of LE1 and LE10 (semi-axes, metres)
INNER, OUTER = (2.0, 1.0), (3.25, 2.75)
SEGMENTS = 720


def ring_stl(path: Path, z0: float, z1: float) -> Path:
    """A closed triangle mesh of the quarter ring between the two ellipses (x, y ≥ 0), from
    z0 to z1: each ellipse as SEGMENTS chords (angle parameter t: (A cos t, B sin t)), the
    two at the same t joined in quadrilaterals."""
    import trimesh

    t = np.linspace(0.0, np.pi / 2, SEGMENTS + 1)
    inner = np.column_stack([INNER[0] * np.cos(t), INNER[1] * np.sin(t)])
    outer = np.column_stack([OUTER[0] * np.cos(t), OUTER[1] * np.sin(t)])
    inner[-1, 0] = outer[-1, 0] = 0.0           # exactly on the axes
    inner[0, 1] = outer[0, 1] = 0.0
    n = len(t)
    V = np.concatenate([np.column_stack([inner, np.full(n, z0)]),
                        np.column_stack([outer, np.full(n, z0)]),
                        np.column_stack([inner, np.full(n, z1)]),
                        np.column_stack([outer, np.full(n, z1)])])
    i0, o0, i1, o1 = 0, n, 2 * n, 3 * n
    F = []
    for k in range(n - 1):
        F += [[i0 + k, o0 + k + 1, o0 + k], [i0 + k, i0 + k + 1, o0 + k + 1]]          # bottom
        F += [[i1 + k, o1 + k, o1 + k + 1], [i1 + k, o1 + k + 1, i1 + k + 1]]          # top
        F += [[o0 + k, o0 + k + 1, o1 + k + 1], [o0 + k, o1 + k + 1, o1 + k]]          # outer
        F += [[i0 + k, i1 + k + 1, i0 + k + 1], [i0 + k, i1 + k, i1 + k + 1]]          # inner
    F += [[i0, o0, o1], [i0, o1, i1]]                                                   # y = 0
    e = n - 1
    F += [[i0 + e, i1 + e, o1 + e], [i0 + e, o1 + e, o0 + e]]                           # x = 0
    mesh = trimesh.Trimesh(V, np.array(F), process=True)
    trimesh.repair.fix_normals(mesh)
    if not mesh.is_watertight:                       # pragma: no cover - a geometry slip
        raise RuntimeError("the LE ring mesh is not watertight")
    mesh.export(path)
    return path


SCENE = """
name = "{name}"
units = "SI"
analysis = "static"
[[group]]
name = "p"
mesh = "{stl}"
spacing = {a}
origin = [0, 0, {oz}]
material = {{ E = 210e9, nu = {nu}, density = 7850 }}
poisson = "material"
[[support]]
on = "p"
where = {{ box = {{ min = [-1, -1, -1], max = [{h}, 4, 2] }} }}
fix = ["x"]
[[support]]
on = "p"
where = {{ box = {{ min = [-1, -1, -1], max = [4, {h}, 2] }} }}
fix = ["y"]
"""


def _outer_layer(o: np.ndarray, a: float) -> np.ndarray:
    """The particles of the outer curved face: within a spacing of the outer ellipse."""
    r = np.sqrt((o[:, 0] / OUTER[0]) ** 2 + (o[:, 1] / OUTER[1]) ** 2)
    return (1.0 - r) * min(OUTER) < a


def _run_and_measure(sc, tmp: Path, name: str, headline: bool = False):
    """Run ``sc`` statically on the reference engine into a run directory and read its stress
    with the project's measure (ParticleStress, its default patch route): (stress n × 3 × 3 in
    the scene's stress unit, whether it settled, and with ``headline`` the run's own governing
    stress as ``postprocess`` records it, else None). With ``headline`` the stress is the one
    ``postprocess`` measured (compute_fields keeps it in this process; stored in float32, the
    pictures' precision: 1e-7 of it), not measured a second time: Kirsch's plate at 1.25 mm
    (155,788 particles) in 35.7 against 38.0 s of CPU, its K_t the same to 7 digits (measured
    2026-12-02)."""
    from rackstress.runs.run import run
    from rackstress.stress import load_run
    from rackstress.stress.measures import ParticleStress

    out = tmp / name
    run(sc, out, engine="reference", progress=False, dump_every=1)
    head, data = None, load_run(out)
    if headline:
        from rackstress.stress.post import compute_fields, postprocess

        head = postprocess(out, vtk=False, dump=False, run=data)["governing"]
        s6 = np.asarray(compute_fields(data).extras["stress"][-1], dtype=float)
    else:
        s6 = ParticleStress(data).run().results.stress[-1]          # xx yy zz xy yz xz
    S = np.empty((len(s6), 3, 3))
    for c, (x, y) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (0, 2))):
        S[:, x, y] = S[:, y, x] = s6[:, c]
    summary = json.loads((out / "summary.json").read_text())
    return S, summary.get("settled", summary.get("status") == "settled"), head


def le1(a: float, tmp: Path, filled: bool = False) -> dict:
    """LE1 at spacing ``a`` (metres). A membrane in plane stress: its stress does not depend
    on its thickness (the load scales with it), so the lattice is one layer, a thick (exactly
    plane stress: every cell overhangs both free faces, docs/calibration.md), the pressure
    10 MPa × a on the outer edge per unit length; a divides 2 m, so a particle sits at D.
    ``filled``: the lattice a mesh part gets by default instead — its cells tiling the
    quarter, the particles half a spacing off both symmetry planes, the rows next to them held
    across (a symmetry plane's support), the particle nearest D half a spacing from it along
    each axis."""
    from rackstress.scenes.toml import load_toml

    tag = "le1f" if filled else "le1"
    stl = ring_stl(tmp / f"{tag}-{a:g}.stl", 0.0, a)
    f = tmp / f"{tag}-{a:g}.toml"
    text = SCENE.format(name=tag, stl=stl.name, a=a, oz=a / 2, nu=0.3, h=a if filled else a / 2)
    if filled:
        text = text.replace("origin = [0, 0, ", f"origin = [{a / 2}, {a / 2}, ")
    f.write_text(text + """[[support]]           # out of its plane: nothing (one layer)
on = "p"
fix = ["z"]
""")
    sc = load_toml(f)
    o = sc.groups["p"].o
    # 10 MPa outward on the outer edge: each outer particle's share of the arc, by angle
    # (the arc between the midpoints to its neighbours), times the thickness a
    k = np.flatnonzero(_outer_layer(o, a) & _exposed_outward(o, a))
    t = np.arctan2(o[k, 1] / OUTER[1], o[k, 0] / OUTER[0])
    ordr = np.argsort(t)
    k, t = k[ordr], t[ordr]
    mids = np.concatenate([[0.0], 0.5 * (t[1:] + t[:-1]), [np.pi / 2]])
    ds = np.array([_arc(t0, t1) for t0, t1 in zip(mids[:-1], mids[1:])])
    tc = 0.5 * (mids[:-1] + mids[1:])
    nrm = np.column_stack([np.cos(tc) / OUTER[0], np.sin(tc) / OUTER[1], np.zeros(len(tc))])
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    F = np.zeros((len(o), 3))
    F[k] = 10e6 * a * ds[:, None] * nrm
    sc = _with_forces(sc, "p", F)
    S, settled, _ = _run_and_measure(sc, tmp, f"{tag}-{a:g}")
    k = int(np.argmin(np.linalg.norm(o[:, :2] - [2.0, 0.0], axis=1)))
    ext = extrapolated(o, S[:, 1, 1], [2.0, a / 2 if filled else 0.0, a / 2], [1.0, 0, 0],
                       a) / 1e6
    return {"spacing": a, "layers": 1, "particles": sc.n_particles, "settled": settled,
            "at": o[k].tolist(), "sigma_yy_MPa": float(S[k, 1, 1]) / 1e6,
            "ratio": float(S[k, 1, 1]) / 1e6 / LE1_TARGET, "extrapolated_MPa": ext,
            "extrapolated_ratio": ext / LE1_TARGET}


def extrapolated(o: np.ndarray, values: np.ndarray, point, along, a: float) -> float:
    """The value at ``point`` of the parabola through the three particles nearest it on the
    lattice line through it along ``along`` (unit axis) that lie half a spacing or more inside:
    a reading of a surface value from the field near it, stated beside the project's own
    (the particle's), not a replacement for it."""
    point, along = np.asarray(point, float), np.asarray(along, float)
    rel = o - point
    t = rel @ along
    off = rel - t[:, None] * along[None, :]
    line = (np.linalg.norm(off, axis=1) < 1e-6 * a) & (t >= 0.5 * a) & np.isfinite(values)
    k = np.flatnonzero(line)[np.argsort(t[line])][:3]
    if len(k) < 3:
        return float("nan")
    c = np.polyfit(t[k], values[k], 2)
    return float(np.polyval(c, 0.0))


def _arc(t0: float, t1: float) -> float:
    """Arc length of the outer ellipse between angle parameters t0 and t1."""
    t = np.linspace(t0, t1, 65)
    dx, dy = -OUTER[0] * np.sin(t), OUTER[1] * np.cos(t)
    w = np.sqrt(dx * dx + dy * dy)
    return float(np.sum(0.5 * (w[1:] + w[:-1]) * np.diff(t)))


def _exposed_outward(o: np.ndarray, a: float) -> np.ndarray:
    """Particles whose outward lattice neighbour (along x or y, away from the origin) is
    missing: the outer edge's own particles."""
    from scipy.spatial import cKDTree

    tree = cKDTree(o)
    out = np.zeros(len(o), bool)
    for e in ((a, 0, 0), (0, a, 0)):
        d, _ = tree.query(o + np.array(e), distance_upper_bound=0.01 * a)
        out |= ~np.isfinite(d)
    return out


def _with_forces(sc, name: str, F: np.ndarray):
    """``sc`` with the forces ``F`` (N, per particle) as force operators (one per distinct
    vector, Eq. 8: accelerations F/m on the particles that carry it)."""
    import dataclasses

    from rackstress.model.operators import Force

    m = sc.groups[name].mass(sc.units)
    keys, inv = np.unique(np.round(F, 9), axis=0, return_inverse=True)
    ops = list(sc.operators[name])
    for k, vec in enumerate(keys):
        if not np.any(vec):
            continue
        ops.append(Force(tuple(float(x) / m for x in vec), where=tuple(bool(b) for b in
                                                                      inv.reshape(-1) == k)))
    return dataclasses.replace(sc, operators={**sc.operators, name: ops})


def le10(a: float, tmp: Path, filled: bool = False) -> dict:
    """LE10 at spacing ``a``, which divides 0.3 m and 2 m: the lattice's layers on the upper
    and lower faces (z = 0 … 0.6), one on the mid-plane, a particle at D. ``filled``: the
    lattice a mesh part gets by default instead — its cells tiling the quarter (0.6/a layers
    of cells, an odd number, so one on the mid-plane; 2/a whole cells to D's x), the rows next
    to the symmetry planes held across them, the particle whose recovery point is D (half a
    spacing from it along each axis) read there."""
    from rackstress.scenes.toml import load_toml

    tag = "le10f" if filled else "le10"
    layers = int(round(0.6 / a)) + (0 if filled else 1)
    stl = ring_stl(tmp / f"{tag}.stl", 0.0, 0.6)
    f = tmp / f"{tag}-{a:g}.toml"
    text = SCENE.format(name=tag, stl=stl.name, a=a, oz=a / 2 if filled else 0.0, nu=0.3,
                        h=a if filled else a / 2)
    if filled:
        text = text.replace("origin = [0, 0, ", f"origin = [{a / 2}, {a / 2}, ")
    f.write_text(text + f"""[[load]]
on = "p"
where = {{ box = {{ min = [-1, -1, {0.6 - (a if filled else a / 2)}], max = [4, 4, 1] }} }}
pressure = 1e6
normal = [0, 0, 1]
""")
    sc = load_toml(f)
    g = sc.groups["p"]
    o = g.o
    outer = _outer_layer(o, a) & _exposed_outward(o, a)
    g.fixed[outer, 0] = g.fixed[outer, 1] = True
    mid = outer & (np.abs(o[:, 2] - 0.3) < 1e-9)
    if not mid.any():
        raise RuntimeError(f"LE10 at spacing {a}: no layer on the mid-plane")
    g.fixed[mid, 2] = True
    g.held = np.ascontiguousarray(g.fixed.all(axis=1))
    g.v0 = np.zeros_like(o)
    S, settled, _ = _run_and_measure(sc, tmp, f"{tag}-{a:g}")
    c = [2.0 + a / 2, a / 2, 0.6 - a / 2] if filled else [2.0, 0.0, 0.6]
    k = int(np.argmin(np.linalg.norm(o - c, axis=1)))
    ext = extrapolated(o, S[:, 1, 1], [2.0] + c[1:], [1.0, 0, 0], a) / 1e6
    return {"spacing": a, "layers": layers, "particles": sc.n_particles, "settled": settled,
            "at": o[k].tolist(), "sigma_yy_MPa": float(S[k, 1, 1]) / 1e6,
            "ratio": float(S[k, 1, 1]) / 1e6 / LE10_TARGET, "extrapolated_MPa": ext,
            "extrapolated_ratio": ext / LE10_TARGET}


KIRSCH = """
name = "kirsch"
units = "SI"
analysis = "static"
[[group]]
name = "p"
fill = {{ difference = [ {{ box = {{ min = [-0.25, -0.25, 0], max = [0.25, 0.25, {a}] }} }},
                        {{ cylinder = {{ start = [0, 0, -1], end = [0, 0, 1], radius = 0.05 }} }} ] }}
spacing = {a}
origin = [0, 0, {oz}]
material = {{ E = 210e9, nu = {nu}, density = 7850 }}
poisson = "material"
[[support]]          # symmetry: the middle lines held across, the middle layer in z
on = "p"
where = {{ box = {{ min = [-{q}, -1, -1], max = [{q}, 1, 1] }} }}
fix = ["x"]
[[support]]
on = "p"
where = {{ box = {{ min = [-1, -{q}, -1], max = [1, {q}, 1] }} }}
fix = ["y"]
[[support]]          # out of its plane: nothing (one layer)
on = "p"
fix = ["z"]
[[load]]
on = "p"
where = {{ box = {{ min = [{e}, -1, -1], max = [1, 1, 1] }} }}
pressure = -10e6
normal = [1, 0, 0]
[[load]]
on = "p"
where = {{ box = {{ min = [-1, -1, -1], max = [-{e}, 1, 1] }} }}
pressure = -10e6
normal = [-1, 0, 0]
"""
#: Peterson's chart 4.1 at d/W = 0.2, on the gross section: a long strip's, stated beside
KIRSCH_KT_STRIP = (3.0 - 3.14 * 0.2 + 3.667 * 0.04 - 1.527 * 0.008) / 0.8
#: The FE meshes of :func:`kirsch_fe`: elements per mm along the hole (the plate in mm)
KIRSCH_FE_DENSITY = (1, 2)


def kirsch_fe() -> dict:
    """K_t of the bench's square plate by converged plane-stress FEA: σ_xx at the hole's side
    over the remote 1 (validity.fea.plate_with_hole: its quarter, symmetry on x = 0 and y = 0,
    the traction on x = W; a = 50, W = 250 mm) at two meshes; ``Kt`` the finer's, ``change``
    between them."""
    from rackstress.validity import fea

    vals = [float(fea.plate_with_hole(50.0, 250.0, 1.0, density=d, nu=0.3)
                  .at(np.array([[0.0, 50.0]]))["sxx"][0]) for d in KIRSCH_FE_DENSITY]
    return {"Kt": vals[-1], "values": vals, "density_per_mm": list(KIRSCH_FE_DENSITY),
            "change": abs(vals[-1] - vals[0]) / vals[-1]}



def kirsch(nu: float, a: float, tmp: Path, target: float | None = None) -> dict:
    """Kirsch's plate at ν and spacing ``a`` (m), its K_t three ways against ``target``
    (default :func:`kirsch_fe`'s)."""
    from rackstress.scenes.toml import load_toml

    target = float(target if target is not None else kirsch_fe()["Kt"])
    f = tmp / f"kirsch-{nu:g}-{a:g}.toml"
    f.write_text(KIRSCH.format(a=a, nu=nu, oz=a / 2, q=0.1 * a, zq=0.6 * a, e=0.25 - a / 2))
    sc = load_toml(f)
    S, settled, head = _run_and_measure(sc, tmp, f"kirsch-{nu:g}-{a:g}", headline=True)
    o = sc.original_positions()
    z = a / 2                                                # the one layer
    side = (np.abs(o[:, 0]) < 0.5 * a) & (o[:, 1] > 0)
    k = np.flatnonzero(side)[np.argmin(o[side, 1])]          # the hole's side, on y > 0
    kt = float(S[k, 0, 0]) / 10e6
    ext = extrapolated(o, S[:, 0, 0], [0.0, 0.05, z], [0, 1.0, 0], a) / 10e6
    # head: the run's own headline (summary's governing stress, von Mises: uniaxial at the
    # hole's side, so |σ_θθ| there), as a user reads it
    return {"nu": nu, "spacing": a, "particles": sc.n_particles, "settled": settled,
            "at": o[k].tolist(), "Kt": kt, "ratio": kt / target, "Kt_extrapolated": ext,
            "extrapolated_ratio": ext / target, "Kt_headline": head["value"] / 10e6,
            "headline_ratio": head["value"] / 10e6 / target,
            "headline_at": head["read_at"], "headline_read": head.get("read")}


BLOCK = """
name = "block"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "p"
fill = {{ box = {{ min = [0, 0, 0], max = [20, 20, 20] }} }}
spacing = {a}
material = {{ E = 70e9, nu = {nu}, density = 2700 }}
poisson = "material"
[[support]]
on = "p"
where = {{ box = {{ min = [-1, -1, -1], max = [21, 21, {h}] }} }}
fix = ["z"]
[[support]]
on = "p"
where = {{ box = {{ min = [-1, -1, -1], max = [{h}, 21, 21] }} }}
fix = ["x"]
[[support]]
on = "p"
where = {{ box = {{ min = [{e}, -1, -1], max = [21, 21, 21] }} }}
fix = ["x"]
[[support]]
on = "p"
where = {{ box = {{ min = [-1, -1, -1], max = [21, {h}, 21] }} }}
fix = ["y"]
[[support]]
on = "p"
where = {{ box = {{ min = [-1, {e}, -1], max = [21, 21, 21] }} }}
fix = ["y"]
[[load]]
on = "p"
where = {{ box = {{ min = [-1, -1, {e}], max = [21, 21, 21] }} }}
pressure = 10
normal = [0, 0, 1]
"""


def block(nu: float, a: float, tmp: Path) -> dict:
    from rackstress.engines.static import solve
    from rackstress.scenes.toml import load_toml

    f = tmp / f"block-{nu:g}-{a:g}.toml"
    f.write_text(BLOCK.format(a=a, nu=nu, h=a / 2, e=20 - a / 2))
    sc = load_toml(f)
    res = solve(sc)
    o = sc.original_positions()
    u = res.p - o
    inner = (o[:, 2] > 5) & (o[:, 2] < 15)
    ezz = np.polyfit(o[inner, 2], u[inner, 2], 1)[0]
    E = 70000.0
    M = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    return {"nu": nu, "spacing": a, "particles": sc.n_particles, "settled": bool(res.settled),
            "stiffness_MPa": -10.0 / ezz, "constrained_modulus_MPa": M,
            "ratio": -10.0 / ezz / M}


def order(spacings, errors) -> float | None:
    """The observed order of convergence from the last two (spacing, |error|) pairs."""
    e = [abs(x) for x in errors]
    if len(e) < 2 or min(e[-2:]) <= 0:
        return None
    return float(np.log(e[-2] / e[-1]) / np.log(spacings[-2] / spacings[-1]))


def band(spacings, values) -> dict | None:
    """The error bar ``rackstress run --refine`` would give the reading from its last three
    spacings, without the target (:func:`rackstress.stress.governing.error_bar`: Richardson's
    extrapolation at the order those three give, Roache's grid convergence index about the
    finest value), as {"order", "order_from", "extrapolated", "low", "high"}; None with fewer
    than three spacings."""
    from rackstress.stress.governing import error_bar

    if len(values) < 3:
        return None
    e = error_bar(values[-3:], spacings[-3:])
    return {"order": e["order"], "order_from": e["order_from"],
            "extrapolated": e["extrapolated"], "low": e["value"] - e["estimate"],
            "high": e["value"] + e["estimate"]}


def run_bench(out: Path | None = None, quick: bool = False, echo=print) -> dict:
    import tempfile

    from rackstress.bench import out_dir

    out = out_dir(out)
    sp = {"le1": (0.05, 0.025, 0.0125), "le1_filled": (0.05, 0.025, 0.0125),
          "le10": (0.1, 0.05, 1 / 30), "le10_filled": (0.2 / 3, 0.04, 0.2 / 7, 0.2 / 9),
          "kirsch": (0.01, 0.005, 0.0025, 0.00125), "block": (4.0, 2.0, 1.0)}
    if quick:
        sp = {k: v[:2] for k, v in sp.items()}
    fe = kirsch_fe()
    data = {"machine": machine(), "quick": quick, "targets": {"LE1": LE1_TARGET,
                                                              "LE10": LE10_TARGET,
                                                              "Kirsch_Kt": fe["Kt"],
                                                              "Kirsch_Kt_strip": KIRSCH_KT_STRIP},
            "Kirsch_fe": fe}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, fn, args in (("LE1", le1, [()]),
                               ("LE1_filled", functools.partial(le1, filled=True), [()]),
                               ("LE10", le10, [()]),
                               ("LE10_filled", functools.partial(le10, filled=True), [()]),
                               ("Kirsch", functools.partial(kirsch, target=fe["Kt"]),
                                [(0.3,), (0.45,)]),
                               ("block", block, [(0.3,), (0.45,)])):
            rows = []
            for extra in args:
                for a in sp[name.lower()]:
                    t0 = time.process_time()
                    r = fn(*extra, a, tmp)
                    r["cpu_s"] = time.process_time() - t0
                    r = {k: float(v) if isinstance(v, np.floating) else
                         bool(v) if isinstance(v, np.bool_) else v for k, v in r.items()}
                    rows.append(r)
                    echo(f"  {name} {' '.join(f'nu {x:g}' for x in extra)} spacing {a:g}: "
                         + ", ".join(f"{k} {v:.4g}" for k, v in r.items()
                                     if isinstance(v, float) and k not in ("spacing",)))
            data[name] = rows
    for name in ("LE1", "LE1_filled", "LE10", "LE10_filled"):
        rows = data[name]
        for tag, key in (("", "ratio"), ("_extrapolated", "extrapolated_ratio")):
            data[f"{name}_order{tag}"] = order([r["spacing"] for r in rows],
                                               [r[key] - 1 for r in rows])
            data[f"{name}_within{tag}"] = bool(abs(rows[-1][key] - 1) <= TARGET)
        data[f"{name}_band"] = band([r["spacing"] for r in rows],
                                    [r["sigma_yy_MPa"] for r in rows])
    (out / "nafems.json").write_text(json.dumps(data, indent=1))
    (out / "nafems.md").write_text(report(json.loads(json.dumps(data))))   # as the JSON reads
    return data


def report(d: dict) -> str:
    from rackstress.bench import md_table

    L = ["# NAFEMS linear-elastic benchmarks and classical cases", "",
         "Written by `rackstress bench nafems` (its module doc holds every geometry, load, "
         "support and source). Each case solved statically on the reference engine and read "
         "through the project's stress measure (`rackstress.stress.measures.ParticleStress`, "
         "the default `patch` route, docs/stress.md) at the particle nearest the point, "
         "whose position "
         "is given.", ""]
    if d.get("quick"):
        L += ["**`--quick`**: the two coarser spacings of each case only (the \"finest "
              "spacing\" and the order below are theirs); the third, finest spacing comes from "
              "the full command.", ""]
    for name, target in (("LE1", LE1_TARGET), ("LE1_filled", LE1_TARGET),
                         ("LE10_filled", LE10_TARGET), ("LE10", LE10_TARGET)):
        if name not in d:
            continue
        title = {"LE1_filled": "LE1, the lattice a mesh part gets by default",
                 "LE10_filled": "LE10, the lattice a mesh part gets by default",
                 "LE10": "LE10, particles on the faces"}.get(name, name)
        L += [f"## {title}: σ_yy at D, target {target} MPa (NAFEMS TNSB Rev. 3, 1990)", ""]
        if name == "LE1_filled":
            L += ["The same membrane with its cells tiling the quarter (the default fill: "
                  "particles half a spacing off every face and both symmetry planes), the rows "
                  "next to the planes held across them (the planes' support, whose force the "
                  "stress counts on the cells' faces, docs/stress.md); the particle nearest D "
                  "sits half a spacing from it along x and y, where its cell ends, and is "
                  "read at its recovery point, D itself (the membrane is fitted in its "
                  "plane).", ""]
        if name == "LE10_filled":
            L += ["The thick plate with its cells tiling the quarter (the default fill: "
                  "0.6/a layers of cells, an odd number, so that one lies on the mid-plane, "
                  "where the outer face is held along z), the rows next to both symmetry "
                  "planes held "
                  "across them; the particle nearest D is half a spacing from it along each "
                  "axis, on the pressed face, the hole's face and the symmetry plane, and is "
                  "read at its recovery point, D itself. The column \"extrapolated\" is the "
                  "field extrapolated along x to the hole on the particles' row next to the "
                  "symmetry plane, half a spacing below the face: beside D, not at it.", ""]
        if name == "LE10":
            L += ["The lattice through D itself: its layers on the upper and lower faces "
                  "(half cells there), a particle on each symmetry plane, D a particle. Its "
                  "reading does not move steadily with the spacing (the table), and why was "
                  "not found; the default fill above is the lattice a user's mesh part gets.",
                  ""]
        rows = [[f"{r['spacing']:g}", r["layers"], f"{r['particles']:,}",
                 "(" + ", ".join(f"{x:.4g}" for x in r["at"]) + ")",
                 f"{r['sigma_yy_MPa']:.2f}", f"{(r['ratio'] - 1) * 100:+.1f} %",
                 f"{r['extrapolated_MPa']:.2f}", f"{(r['extrapolated_ratio'] - 1) * 100:+.1f} %",
                 "yes" if r["settled"] else "**no**"] for r in d[name]]
        L += [md_table(["spacing [m]", "layers", "particles", "particle at D [m]",
                        "σ_yy there [MPa]", "error", "σ_yy extrapolated to D [MPa]", "error",
                        "settled"], rows)]
        o, oe = d.get(f"{name}_order"), d.get(f"{name}_order_extrapolated")
        L += [f"At the finest spacing, the project's reading (the particle at D): "
              f"{'within' if d[f'{name}_within'] else '**not within**'} {TARGET * 100:.0f} % "
              f"of the target; extrapolated to D: "
              f"{'within' if d[f'{name}_within_extrapolated'] else '**not within**'}. Observed "
              f"order of convergence from the last two errors against the target: "
              f"{'—' if o is None else f'{o:.2f}'} (particle), "
              f"{'—' if oe is None else f'{oe:.2f}'} (extrapolated).", ""]
        b = d.get(f"{name}_band")
        if b:
            lo, hi = sorted((b["low"], b["high"]))
            L += [f"The error bar `rackstress run --refine` gives from the last three "
                  f"readings, without the target (Richardson at order {b['order']:.2f}, "
                  f"{b['order_from']}; Roache's grid convergence index about the finest): "
                  f"{lo:.2f} … {hi:.2f} MPa, extrapolated {b['extrapolated']:.2f} MPa; it "
                  f"{'covers' if lo <= target <= hi else '**does not cover**'} the target.",
                  ""]
    fe = d["Kirsch_fe"]
    L += [f"## Kirsch: a hole's K_t (target {fe['Kt']:.3f}, converged plane-stress FEA of the "
          "same plate, d/W = 0.2)", ""]
    L += [f"The target: scikit-fem P2 on the plate's graded quarter "
          f"(`validity.fea.plate_with_hole`), {fe['values'][0]:.4f} and {fe['values'][1]:.4f} "
          f"at {fe['density_per_mm'][0]} and {fe['density_per_mm'][1]} elements per mm along "
          f"the hole ({100 * fe['change']:.3f} % apart). Peterson's chart 4.1 gives "
          f"{d['targets']['Kirsch_Kt_strip']:.3f} for a long strip of that width; this plate "
          "is as long as it is wide.", ""]
    L += ["K_t = σ/10 MPa three ways: the run's own headline (`summary.json`'s governing "
          "stress, the von Mises stress of the patch route at the face, where it is largest; "
          "uniaxial at the hole's side, so |σ_θθ| there) — the number a user reads; σ_xx at "
          "the lattice particle on the y axis nearest the hole (on the hole's edge: the "
          "spacing divides its radius); and that field extrapolated to the edge from the "
          "three particles beyond it.", ""]
    rows = [[f"{r['nu']:g}", f"{r['spacing']:g}", f"{r['particles']:,}",
             f"{r['Kt_headline']:.3f}", f"{(r['headline_ratio'] - 1) * 100:+.1f} %",
             "(" + ", ".join(f"{x:.4g}" for x in r["headline_at"]) + ")",
             "(" + ", ".join(f"{x:.4g}" for x in r["at"]) + ")", f"{r['Kt']:.3f}",
             f"{(r['ratio'] - 1) * 100:+.1f} %", f"{r['Kt_extrapolated']:.3f}",
             f"{(r['extrapolated_ratio'] - 1) * 100:+.1f} %"] for r in d["Kirsch"]]
    L += [md_table(["ν", "spacing [m]", "particles", "K_t, the headline", "error",
                    "read at [m]", "particle on the y axis [m]", "K_t there", "error",
                    "K_t extrapolated", "error"], rows), ""]
    for nu in sorted({r["nu"] for r in d["Kirsch"]}):
        rs = [r for r in d["Kirsch"] if r["nu"] == nu]
        pct = lambda key: " / ".join(f"{(r[key] - 1) * 100:+.1f}" for r in rs)  # noqa: E731
        over = [r for r in rs if r["headline_ratio"] > 1 + TARGET]
        L += [f"At ν = {nu:g} the headline reads {pct('headline_ratio')} % and the particle on "
              f"the axis {pct('ratio')} % at " + " / ".join(f"{r['spacing']:g}" for r in rs)
              + " m."
              + (" Where the headline reads above the target by more than "
                 f"{100 * TARGET:g} % (" + ", ".join(f"{r['spacing']:g} m" for r in over)
                 + ") it is read off the axis (its position above): look there for a step "
                 "of the staircase the lattice makes of the hole (docs/stress.md)."
                 if over else ""), ""]
    L += ["## A laterally constrained block: σ/ε against E(1 − ν)/((1 + ν)(1 − 2ν))", ""]
    rows = [[f"{r['nu']:g}", f"{r['spacing']:g}", f"{r['particles']:,}",
             f"{r['stiffness_MPa']:.0f}", f"{r['constrained_modulus_MPa']:.0f}",
             f"{(r['ratio'] - 1) * 100:+.1f} %"] for r in d["block"]]
    L += [md_table(["ν", "spacing [mm]", "particles", "σ/ε [MPa]", "constrained modulus [MPa]",
                    "error"], rows), "",
          f"Machine: {d['machine']['cores']} cores, load average "
          f"{d['machine']['load_avg_at_start']} at the start."]
    return "\n".join(L) + "\n"
