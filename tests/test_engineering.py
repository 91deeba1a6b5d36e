"""The engineer's language: units, materials, loads in newtons, supports by
direction, static analysis. Expected values come from beam theory and hand calculation."""
from __future__ import annotations

import functools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import dump_text, trajectory

from rackstress.engines.static import external_forces, solve
from rackstress.scenes.toml import load_toml

ROOT = Path(__file__).resolve().parents[1]
CANTILEVER = ROOT / "examples" / "cantilever" / "scene.toml"
#: beam theory, DESIGN §6: P·L³/(3·E·I) = 0.5714 mm plus 0.8 % shear (Timoshenko, κ = 5/6)
TIP = 100.0 * 100.0 ** 3 / (3 * 70000.0 * 10.0 ** 4 / 12) * 1.008


@functools.lru_cache(maxsize=None)
def _solved(spacing: float):
    """The cantilever at ``spacing``, loaded and solved once a worker process: the spacing
    tests compare each spacing with spacings 2 and 1, which were solved again for every
    comparison (spacing 1 three times, 2 four times). Callers only read the result."""
    sc = load_toml(CANTILEVER, {"spacing": spacing})
    res = solve(sc)
    assert res.settled and res.residual <= 1e-6
    return sc, res


def _tip(spacing: float) -> float:
    sc, res = _solved(spacing)
    o = sc.original_positions()
    end = o[:, 0] > 100 - 1e-9
    return -float((res.p - o)[end, 2].mean()), sc, res


def _virial_sxx(sc, p, rows):
    """σ_xx of particles ``rows`` from their bindings' forces (virial, Σ r⊗f / 2V) and from
    the material's volumetric term (each particle's own terms' Σ r⊗f / V, the term that gives
    the lattice the material's Poisson's ratio: docs/calibration.md), MPa."""
    from rackstress.engines.static import _bind_pairs
    from rackstress.model.operators import Bind
    from rackstress.model.volume import Volume, volume_terms

    I, J, C, Q = _bind_pairs(sc)
    m = sc.masses()
    keep = np.isin(I, rows)
    I, J, C, Q = I[keep], J[keep], C[keep], Q[keep]
    f = Bind.accel(p[I], p[J], C, Q) * m[I][:, None]
    r = p[J] - p[I]
    V = sc.groups["bar"].volume
    s = np.bincount(I, weights=r[:, 0] * f[:, 0], minlength=len(p)) / (2 * V)
    vol = volume_terms(sc)
    if vol is not None:
        s = s + Volume.virial(p, vol, m)[:, 0] / V
    return s[rows]


def test_cantilever_tip_deflection_and_convergence():
    """Tip deflection within 5 % of beam theory at spacing 1; spacings 2 and 1 within 5 %."""
    d1, sc, res = _tip(1.0)
    d2, _, _ = _tip(2.0)
    assert abs(d1 / TIP - 1) < 0.05, (d1, TIP)
    assert abs(d2 / d1 - 1) < 0.05, (d2, d1)
    # the top fibre at mid-span: M·z/I = 100·50·4.5/833.3 = 27.0 MPa (tension on top, z = +4.5)
    o = sc.original_positions()
    top = np.flatnonzero((np.abs(o[:, 0] - 50) < 1e-9) & (np.abs(o[:, 2] - 4.5) < 1e-9))
    bottom = np.flatnonzero((np.abs(o[:, 0] - 50) < 1e-9) & (np.abs(o[:, 2] + 4.5) < 1e-9))
    expected = 100.0 * 50.0 * 4.5 / (10.0 ** 4 / 12)
    assert abs(_virial_sxx(sc, res.p, top).mean() / expected - 1) < 0.10
    assert abs(-_virial_sxx(sc, res.p, bottom).mean() / expected - 1) < 0.10


def _box_cells(o: np.ndarray, a: float, lo=(0.0, -5.0, -5.0), hi=(100.0, 5.0, 5.0)):
    """Each particle's share of the bar, by geometry: along each axis ±a/2 where the next
    lattice site is in the bar, else up to the bar's face."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    up = np.where(o + a <= hi + 1e-9, a / 2, hi - o)
    down = np.where(o - a >= lo - 1e-9, a / 2, o - lo)
    return np.prod(up + down, axis=1)


def _bent(spacing: float):
    """The cantilever at ``spacing``, solved: (tip / beam theory, top and bottom fibre σ_xx /
    M·z/I at mid-span), beam theory taken at the last layer x_e, where the load acts."""
    sc, res = _solved(spacing)
    o = sc.original_positions()
    xe = o[:, 0].max()
    end = o[:, 0] > xe - 1e-9
    tip = -float((res.p - o)[end, 2].mean())
    I = 10.0 ** 4 / 12                          # the bar's own 10 × 10 mm section
    theory = 100.0 * xe ** 3 / (3 * 70000.0 * I) * 1.008
    xm = o[np.argmin(np.abs(o[:, 0] - 50)), 0]
    V = _box_cells(o, spacing)
    fibres = []
    for z in (o[:, 2].max(), o[:, 2].min()):
        rows = np.flatnonzero((np.abs(o[:, 0] - xm) < 1e-9) & (np.abs(o[:, 2] - z) < 1e-9))
        sxx = _virial_sxx(sc, res.p, rows) * sc.groups["bar"].volume / V[rows]
        fibres.append(sxx.mean() / (100.0 * (xe - xm) * z / I))
    return tip / theory, fibres


@pytest.mark.parametrize("spacing", [1.5, 0.7])
def test_cantilever_does_not_depend_on_spacing(spacing):
    """10 mm is 6.7 layers of 1.5 mm and 14.3 of 0.7 mm: the bar is still 10 mm thick, not n·h
    (docs/calibration.md "Walls of any thickness"). Tip within 5 % of beam theory, top and bottom
    fibre within 10 % of M·z/I at the particle centres, and within 5 % of spacings 2 and 1."""
    tip, fibres = _bent(spacing)
    assert abs(tip - 1) < 0.05, tip
    for f in fibres:
        assert abs(f - 1) < 0.10, fibres
    for other in (2.0, 1.0):
        assert abs(tip / _bent(other)[0] - 1) < 0.05, (spacing, other)


PLATE = """
name = "plate"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "p"
fill = {{ box = {{ min = [0, 0, 0], max = [14, 20, 3] }} }}
spacing = 0.7
origin = [0, 0.35, {oz}]
material = "aluminium"
[[support]]
on = "p"
where = {{ box = {{ min = [-0.01, -1, -1], max = [0.01, 21, 4] }} }}
"""


@pytest.mark.parametrize("oz", [0.35, 0.2])
def test_a_plate_is_as_stiff_as_its_own_thickness(oz, tmp_path):
    """A 3 mm plate at spacing 0.7 is 4 layers (2.8 mm) or 5 (3.5 mm), as the lattice falls.
    Its bindings' stiffness in tension along x, Σ k·ℓ²·n_x⁴ over the bindings, is C11·V = 3k/a
    × 14 × 20 × 3 mm³ (DESIGN §6: C11 = 3k/a) — the plate's own volume, not n·a's."""
    from rackstress.model.operators import Bind

    f = tmp_path / "plate.toml"
    f.write_text(PLATE.format(oz=oz))
    sc = load_toml(f)
    g = sc.groups["p"]
    (op,) = [x for x in sc.operators["p"] if isinstance(x, Bind)]
    pl = op.pairs(g, g)
    keep = pl.i < pl.j
    d = g.o[pl.j[keep]] - g.o[pl.i[keep]]
    w = pl.c[keep] / op.coeff.c                     # k in units of the bulk binding's
    layers = len(np.unique(g.o[:, 2]))
    assert layers == {0.35: 4, 0.2: 5}[oz]
    S = float(np.sum(w * d[:, 0] ** 4 / np.einsum("ij,ij->i", d, d)))
    assert abs(S / (3 / 0.7 * 14 * 20 * 3.0) - 1) < 0.002, S


@pytest.mark.parametrize("spacing", [2.0, 1.0])
def test_loads_do_not_change_with_spacing(spacing, tmp_path):
    """A total force is shared by the selected particles; a pressure is p × the face's area."""
    sc = load_toml(CANTILEVER, {"spacing": spacing})
    F = external_forces(sc)
    assert np.allclose(F.sum(axis=0), [0.0, 0.0, -100.0], rtol=1e-12, atol=1e-9)
    text = CANTILEVER.read_text().replace(
        'force = [0, 0, "$(-load)"]', "pressure = 2.0\nnormal = [1, 0, 0]")
    f = tmp_path / "pressure.toml"
    f.write_text(text)
    F = external_forces(load_toml(f, {"spacing": spacing}))
    # 2 MPa on the 10 × 10 mm end face pushes with 200 N in −x
    assert np.allclose(F.sum(axis=0), [-200.0, 0.0, 0.0], rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("spacing", [0.7, 1.5])
def test_weight_and_pressure_are_the_parts_own_where_spacing_does_not_divide_it(spacing,
                                                                                 tmp_path):
    """At 0.7 and 1.5 mm the 100 × 10 × 10 mm bar is 143 × 15 × 15 / 67 × 7 × 7 sites, whose
    cubes hold 1,051 / 1,034 mm³ of the bar's 1,000: its weight is still ρ·g·V of the bar's
    own volume (2.7e-9 t/mm³ × 9,810 mm/s² × 10,000 mm³), and 2 MPa on its 10 × 10 mm end face
    still pushes with 200 N (geometry, not the lattice's n·a)."""
    text = CANTILEVER.read_text()
    grav = text[:text.rindex("[[load]]")] + "[[load]]\non = \"bar\"\ngravity = [0, 0, -9810.0]\n"
    f = tmp_path / "gravity.toml"
    f.write_text(grav)
    F = external_forces(load_toml(f, {"spacing": spacing}))
    weight = 2.7e-9 * 9810.0 * 100 * 10 * 10
    assert abs(F.sum(axis=0)[2] / -weight - 1) < 1e-3, F.sum(axis=0)
    f = tmp_path / "pressure.toml"
    f.write_text(text.replace('force = [0, 0, "$(-load)"]', "pressure = 2.0\nnormal = [1, 0, 0]"))
    F = external_forces(load_toml(f, {"spacing": spacing}))
    assert abs(F.sum(axis=0)[0] / -200.0 - 1) < 1e-3, F.sum(axis=0)


def test_material_and_units_in_summary_and_boundary(tmp_path):
    """A static run on LAMMPS settles, says so, and writes boundary.npz (CONTRACT.md)."""
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "rackstress.cli", "run", str(CANTILEVER),
                        "--set", "spacing=2", "--out", str(out), "--no-render"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["analysis"] == "static" and s["settled"] is True and s["status"] == "settled"
    assert s["residual"] <= s["tolerance"] == 1e-6 and s["iterations"] >= 1
    assert s["units"] == "mm-N-s"
    assert s["groups"]["bar"]["material"]["E"] == 70000.0       # MPa
    b = np.load(out / "boundary.npz")
    assert str(b["units"]) == "mm-N-s"
    assert len(b["held_ids"]) == 25 and b["held_mask"].all()    # the 5 × 5 end face
    assert b["held_ids"].dtype == np.int64 and b["load_ids"].dtype == np.int64
    assert np.allclose(b["load_force"].sum(axis=0), [0, 0, -100.0])


ROLLER = """
name = "roller"
steps = 40
dt = 0.01

[[group]]
name = "block"
lattice = { shape = [3, 3, 3], spacing = 1.0 }
radius = 0.5

[[support]]           # a roller on the floor: z fixed, x and y free
on = "block"
where = { box = { min = [-1, -1, -0.1], max = [3, 3, 0.1] } }
fix = ["z"]

[[support]]           # one corner pinned in x and y as well
on = "block"
where = { ids = [0] }
fix = ["x", "y"]

[[operator]]
on = "block"
op = "bind"
from = "block"
c = 50.0
within = 1.5

[[operator]]
on = "block"
op = "force"
accel = [3.0, 0.0, -2.0]
"""


def _run(scene: Path, engine: str, out: Path) -> Path:
    """``rackstress run SCENE --engine ENGINE --out OUT --no-render``, which must succeed."""
    r = subprocess.run([sys.executable, "-m", "rackstress.cli", "run", str(scene), "--engine",
                        engine, "--out", str(out), "--no-render"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return out


def test_roller_support_on_both_engines(tmp_path):
    """Fixed directions stay at the original coordinate on the reference engine and on LAMMPS
    (fix setforce with NULL), the free ones move, and the two engines agree."""
    f = tmp_path / "roller.toml"
    f.write_text(ROLLER)
    ends = {}
    for engine in ("reference", "lammps"):
        out = _run(f, engine, tmp_path / engine)
        frames = dump_text(trajectory(out)).split("ITEM: TIMESTEP")[-1]
        rows = frames.split("ITEM: ATOMS")[1].strip().splitlines()[1:]
        ends[engine] = np.array([[float(x) for x in row.split()[3:6]] for row in rows])
        b = np.load(out / "boundary.npz")
        assert len(b["held_ids"]) == 9 and b["held_mask"][:, 2].all()
        assert b["held_mask"][0].all() and not b["held_mask"][1:, :2].any()
    sc = load_toml(f)
    o = sc.original_positions()
    floor = o[:, 2] == 0
    for p in ends.values():
        assert np.array_equal(p[floor, 2], o[floor, 2])        # z fixed exactly
        assert np.array_equal(p[0], o[0])                       # the pinned corner
        assert (p[floor][1:, 0] - o[floor][1:, 0]).max() > 1e-3  # x free: pushed by the force
    assert np.allclose(ends["reference"], ends["lammps"], atol=1e-9)


UNSUPPORTED = """
name = "drift"
units = "mm-N-s"

[[group]]
name = "part"
fill = { union = [ { box = { min = [0, 0, 0], max = [4, 4, 4] } },
                   { box = { min = [10, 0, 0], max = [14, 4, 4] } } ] }
spacing = 1.0
material = "steel"

[[support]]
on = "part"
where = { box = { min = [-1, -1, -1], max = [0.6, 5, 5] } }

[[load]]
on = "part"
where = { box = { min = [13.4, -1, -1], max = [15, 5, 5] } }
force = [10, 0, 0]
"""


def test_a_load_on_an_unsupported_piece_is_refused_before_the_solve(tmp_path):
    """A load on a piece bound to no support: no equilibrium. The part check says so before
    any Newton step (exit 2, was exit 6 after every iteration), naming the piece and what to
    do; nothing is written."""
    f = tmp_path / "drift.toml"
    f.write_text(UNSUPPORTED)
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "rackstress.cli", "run", str(f), "--engine",
                        "reference", "--out", str(out), "--no-render"], capture_output=True,
                       text=True)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "held by no support" in r.stderr and "floats away" in r.stderr
    assert "Traceback" not in r.stderr and "iteration" not in r.stderr
    assert not (out / "summary.json").exists()


def test_material_needs_units(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text(CANTILEVER.read_text().replace('units = "mm-N-s"', ""))
    with pytest.raises(Exception, match="units"):
        load_toml(f)


RAMP = """
name = "ramp"
dt = 0.01
duration = 0.5

[[group]]
name = "dot"
positions = [[0, 0, 0], [5, 0, 0]]
radius = 0.5

[[load]]
on = "dot"
gravity = [0, 0, -10]
ramp = 0.2
"""


def test_load_ramp_rises_in_ten_stairs(tmp_path):
    """A ramp over 0.2 time units: ten phases of 0.02 (2 steps each at dt 0.01), the k-th
    carrying k/10 of the load, then the full load to the end (0.3 more: 30 steps)."""
    from rackstress.engines.reference import Reference

    f = tmp_path / "ramp.toml"
    f.write_text(RAMP)
    sc = load_toml(f)
    assert sc.analysis == "dynamic"
    assert [p.name for p in sc.phases] == [f"ramp{k}" for k in range(1, 11)] + ["full"]
    assert [p.steps for p in sc.phases] == [2] * 10 + [30]
    eng = Reference(sc)
    for k in (1, 3, 10):
        a = eng.accelerations({"ramp": k})
        assert np.allclose(a, [[0, 0, -k]] * 2, rtol=1e-12)
    assert np.allclose(external_forces(sc), [[0, 0, -10]] * 2)      # full load, unit masses


def test_static_run_under_mpi(tmp_path):
    """mpiexec -n 2: the equilibrium is solved once, checked by LAMMPS on both ranks."""
    out = tmp_path / "mpi"
    mpiexec = Path(sys.executable).parent / "mpiexec"
    r = subprocess.run([str(mpiexec), "-n", "2", sys.executable, "-m", "rackstress.cli", "run",
                        str(CANTILEVER), "--set", "spacing=2", "--out", str(out), "--no-render"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["ranks"] == 2 and s["settled"] is True and s["residual_engine"] <= 1e-6


def test_support_reactions_balance_the_load():
    """Statics: the clamp's reactions (minus the bindings' pull on the held particles) carry
    the 100 N and its moment about the clamp, P·L = 100 N × 100 mm = 10,000 N·mm."""
    from rackstress.engines.static import _bind_pairs, forces

    sc, res = _solved(2.0)
    f = forces(sc, res.p, _bind_pairs(sc), np.zeros((sc.n_particles, 3)), sc.masses())
    held = sc.held()
    reaction = -f[held]                       # what the support must push to hold them
    assert np.allclose(reaction.sum(axis=0), [0, 0, 100.0], rtol=1e-5, atol=1e-3)
    r = res.p[held]                           # moment about the y axis through the origin
    My = float((r[:, 2] * reaction[:, 0] - r[:, 0] * reaction[:, 2]).sum())
    # the load (0, 0, −100) acts at x ≈ 100 (+ its small deflection): its moment about y is
    # z·Fx − x·Fz = 100·100; the reactions' is the opposite
    assert abs(My + 100.0 * 100.0) < 0.01 * 100.0 * 100.0


@pytest.mark.lammps
def test_a_prescribed_displacement_settles_with_beam_theorys_reaction(tmp_path):
    """The cantilever bar with its free end face held at o + (0, 0, −δ) instead of loaded
    (`displacement`, every direction held: a clamped–guided beam), on both engines.

    It settles (exit 0; was exit 6 on both: the solver measured the load as the reactions of
    the first state — the displaced face pulled against an undeformed bar, 1.7e6 N against
    1.2e4 N at equilibrium — and the engines, which zero a held particle's force, measured none
    and compared an absolute residual in newtons with 1e-6). Beam theory for a guided end
    (Timoshenko): δ = P·L³/(12·E·I) + P·L/(κ·G·A), κ = 5/6, G = E/(2(1 + ν)): P = 386 N for
    δ = 0.5692 mm; the lattice (E_eff 1.5 % stiff, ν = 1/4) within 5 %. By antisymmetry the
    mid-span deflects by δ/2 exactly in the continuum; within 1 %."""
    from rackstress.engines.static import _bind_pairs, forces

    delta = 0.5692
    text = CANTILEVER.read_text()
    text = text.replace('where = { box = { min = ["$(100 - 0.99 * spacing)", -6, -6], '
                        'max = [100.01, 6, 6] } }\nforce = [0, 0, "$(-load)"]',
                        'where = { box = { min = [99.99, -6, -6], max = [100.01, 6, 6] } }\n'
                        f'displacement = [0, 0, {-delta}]')
    assert "displacement" in text
    # at 2 mm (1,275 particles): P within 5 % there too (−1.5 %), in a seventh of the time
    text = text.replace("\nspacing = 1.0 ", "\nspacing = 2.0 ", 1)
    assert "\nspacing = 2.0 " in text
    f = tmp_path / "guided.toml"
    f.write_text(text)
    for engine in ("reference", "lammps"):
        out = _run(f, engine, tmp_path / engine)
        s = json.loads((out / "summary.json").read_text())
        assert s["settled"] and s["residual_engine"] <= 1e-6 and s["residual_solver"] <= 1e-6
    sc = load_toml(f)
    res = solve(sc)
    o = sc.original_positions()
    f_ = forces(sc, res.p, _bind_pairs(sc), np.zeros((sc.n_particles, 3)), sc.masses())
    tip = np.abs(o[:, 0] - 100) < 1e-9
    P = float(f_[tip, 2].sum())                 # the bar pulls the lowered face back up
    E, nu, L, I, A = 70000.0, 0.33, 100.0, 10.0 ** 4 / 12, 100.0
    beam = delta / (L ** 3 / (12 * E * I) + L / (5 / 6 * E / (2 * (1 + nu)) * A))
    assert abs(P / beam - 1) < 0.05, (P, beam)
    mid = np.abs(o[:, 0] - 50) < 1e-9
    assert abs(-(res.p - o)[mid, 2].mean() / (delta / 2) - 1) < 0.01
