"""Two material parts pressed together, solved statically (``[[contact]]`` in a static scene:
engines/static.py, its contact pairs a penalty that changes with the positions)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

#: an aluminium block 20 × 10 × 20 mm on a base of the same size, held at the base's bottom
#: layer; the block may only move along y (its x and z held), pushed down by LOAD newtons on
#: its top layer; the two touch through [[contact]]
PRESS = """name = "press"
units = "mm-N-s"

[params]
spacing = 2.0
load = 1000.0

[[group]]
name = "base"
fill = { box = { min = [0, 0, 0], max = [20, 10, 20] } }
spacing = "$spacing"
origin = ["$(spacing / 2)", "$(spacing / 2)", "$(spacing / 2)"]
material = "aluminium"

[[group]]
name = "block"
fill = { box = { min = [0, 10, 0], max = [20, 20, 20] } }
spacing = "$spacing"
origin = ["$(spacing / 2)", "$(10 + spacing / 2)", "$(spacing / 2)"]
material = "aluminium"

[[support]]
on = "base"
where = { box = { min = [-1, -1, -1], max = [21, "$(spacing)", 21] } }

[[support]]
on = "block"
fix = ["x", "z"]

[[load]]
on = "block"
where = { box = { min = [-1, "$(20 - spacing)", -1], max = [21, 21, 21] } }
force = [0, "$(-load)", 0]

[[contact]]
between = ["base", "block"]
"""


def _scene(tmp_path, text=PRESS):
    from rackstress.scenes import load

    f = tmp_path / "press.toml"
    f.write_text(text)
    return f, load(str(f))


def test_a_block_pressed_on_a_base_settles_and_carries_its_load_through_the_contact(tmp_path):
    """Statics alone: the base's support pushes back the whole 1,000 N, and every horizontal
    layer of the block carries it — the middle layer's mean σ_yy (the bindings' virial over
    each particle's 2 mm cube) is −F/A = −1000/400 = −2.5 MPa within 1 %. The contact pushes
    (the two parts overlap, by less than a spacing) and the scene is static by default."""
    from rackstress.engines import static
    from rackstress.engines.static import _bind_pairs, support_reactions
    from rackstress.model.operators import Bind

    _, sc = _scene(tmp_path)
    assert sc.analysis == "static"
    res = static.solve(sc)
    assert res.settled and res.residual <= 1e-6
    reac = support_reactions(sc, res)["reactions"]
    base = next(r for r in reac if r["group"] == "base")
    assert base["force"][1] == pytest.approx(1000.0, rel=1e-5)
    o, p = sc.original_positions(), res.p
    blk = sc.slice("block")
    gap = p[blk, 1].min() - p[sc.slice("base"), 1].max()
    assert 0 < gap < 2.0                       # pressed: closer than the sum of the radii
    I, J, C, Q = _bind_pairs(sc)
    mid = np.flatnonzero(np.isclose(o[:, 1], 15.0) & (np.arange(len(o)) >= blk.start))
    keep = np.isin(I, mid)
    f = Bind.accel(p[I[keep]], p[J[keep]], C[keep], Q[keep]) * sc.masses()[I[keep]][:, None]
    syy = ((p[J[keep], 1] - p[I[keep], 1]) * f[:, 1]).sum() / 2 / (len(mid) * 2.0 ** 3)
    assert syy == pytest.approx(-2.5, rel=0.01)


def test_the_contact_energy_is_the_potential_of_its_forces(tmp_path):
    """The solver weighs its steps by Π; with the parts pressed into each other (every
    facing pair in contact) the central difference of Π along a random direction equals −f·v
    (Eq. 10's kernel, an independent path) to 1e-6 of itself."""
    from rackstress.engines import static

    _, sc = _scene(tmp_path)
    prob = static._problem(sc)
    assert len(prob.contact) == 2              # each side of the contact
    p = prob.o.copy()
    p[sc.slice("block"), 1] -= 0.3             # 0.3 mm into the base
    rng = np.random.default_rng(3)
    p += 0.01 * rng.standard_normal(p.shape)
    pairs = static._pairs_at(prob, p)
    assert len(pairs[0]) > len(prob.pairs[0])  # contact pairs there
    v = rng.standard_normal(p.shape)
    f = static.forces(sc, p, pairs, prob.F_ext, prob.m)
    h = 1e-6
    slope = static.energy_change(prob, p - h * v, p + h * v) / (2 * h)
    assert slope == pytest.approx(-np.sum(f * v), rel=1e-6)


@pytest.mark.lammps
def test_pressed_parts_on_lammps_and_pulled_parts_refused(tmp_path):
    """``rackstress run``: LAMMPS evaluates the contact itself (the plugin's rs/collide) at the
    solver's equilibrium and agrees (residual ≤ 1e-6); the same scene with the load reversed
    pulls the block off the base, which contact cannot hold: exit 2 naming both parts, not
    a run that ends "not settled"."""
    f, _ = _scene(tmp_path)
    out = tmp_path / "r"
    r = subprocess.run([sys.executable, "-m", "rackstress.cli", "run", str(f), "--out", str(out),
                        "--no-render", "--no-progress"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "settled" and s["residual_engine"] <= 1e-6
    assert "rs/collide" in (out / "in.lammps").read_text()
    _contact_layers_carry_the_load(out)
    pull = tmp_path / "pull.toml"
    pull.write_text(PRESS.replace('force = [0, "$(-load)", 0]', 'force = [0, "$(load)", 0]'))
    r = subprocess.run([sys.executable, "-m", "rackstress.cli", "run", str(pull), "--out",
                        str(tmp_path / "p"), "--no-render", "--no-progress"],
                       capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    assert "'base' and 'block' separate" in r.stderr and "contact" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "p" / "summary.json").exists()


def _contact_layers_carry_the_load(out):
    """The stress of the run's own files (``rackstress run``'s post-processing): every layer of
    both parts carries σ_yy = −F/A = −2.5 MPa by the plain virial (exact in a section sum),
    the two layers that touch included — their contact's force enters their virial as a
    binding's (without it they read half); the contact pressure averages F/A over the 10 × 10
    particles of each face, its forces over the cells' faces sum to the 1,000 N load; the run's
    report names the contact and its pressure."""
    from rackstress.stress.measures import ParticleStress
    from rackstress.stress.rundata import load_run

    run = load_run(out)
    r = ParticleStress(run, method="virial").run().results
    o, s, pc = run.o, r.stress[-1], r.contact_pressure[-1]
    for name, layers in (("base", (3.0, 5.0, 7.0, 9.0)), ("block", (11.0, 13.0, 15.0, 17.0))):
        idx = run.parts[name].index
        for y in layers:
            at = idx[np.isclose(o[idx, 1], y)]
            assert len(at) == 100
            assert s[at, 1].mean() == pytest.approx(-2.5, rel=0.01), (name, y)
        face = idx[np.isclose(o[idx, 1], 9.0 if name == "base" else 11.0)]
        assert np.all(pc[face] > 0) and np.count_nonzero(pc[idx] > 0) == 100
        assert pc[face].mean() == pytest.approx(2.5, rel=0.01)
        assert pc[face].sum() * 2.0 ** 2 == pytest.approx(1000.0, rel=0.01)
    st = json.loads((out / "stress.json").read_text())
    (c,) = st["contact"]
    assert sorted(c["parts"]) == ["base", "block"] and c["touching"]
    assert c["peak"] == pytest.approx(2.5, rel=0.05) and c["units"] == "MPa"


@pytest.mark.lammps
def test_the_pin_joint_assembly_passes_its_load_through_both_contacts(tmp_path):
    """examples/assembly/pin-joint.toml as a user runs it: three parts that touch only through
    [[contact]] settle (active sets), and statics checks every transfer. The quarter model
    carries F/4 = 1,250 N: the pin puts exactly that on the lug (+x) and the clevis (−x); the
    lug's net section through the hole carries it, σ_xx = F/((w − d)·t) = 35.7 MPa on average
    (the virial, exact in a section sum); the pin's section in the gap between lug and cheek
    carries it as shear, τ = F/(2·π·d²/4) = 31.8 MPa on average (double shear); the pin's
    layer on its symmetry plane carries the moment the plane's support does."""
    from rackstress.stress.measures import ParticleStress, read_volumes
    from rackstress.stress.rundata import load_run

    repo = Path(__file__).resolve().parents[1]
    out = tmp_path / "pj"
    r = subprocess.run([sys.executable, "-m", "rackstress.cli", "run",
                        str(repo / "examples" / "assembly" / "pin-joint.toml"), "--out", str(out),
                        "--no-render", "--no-progress"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "settled" and s["residual_engine"] <= 1e-6
    st = json.loads((out / "stress.json").read_text())
    force = {tuple(c["parts"]): c["force"] for c in st["contact"]}
    assert force[("lug", "pin")]["lug"][0] == pytest.approx(1250.0, rel=1e-4)
    assert force[("clevis", "pin")]["clevis"][0] == pytest.approx(-1250.0, rel=1e-4)
    run = load_run(out)
    sig = ParticleStress(run, method="virial").run().results.stress[-1]   # xx yy zz xy yz xz
    V, o = read_volumes(run), run.o
    lug, pin = run.parts["lug"].index, run.parts["pin"].index
    net = lug[np.isclose(o[lug, 0], 0.5)]              # the lug's layer through the hole
    assert len(net) == 7 * 5                           # (w − d)/2 × t/2 cells of 1 mm
    assert (sig[net, 0] * V[net]).sum() == pytest.approx(1250.0, rel=0.01)
    assert sig[net, 0].mean() == pytest.approx(5000.0 / ((24 - 10) * 10), rel=0.01)
    gap = pin[np.isclose(o[pin, 2], 5.5)]              # the pin between lug and cheek
    assert (sig[gap, 5] * V[gap]).sum() == pytest.approx(1250.0, rel=0.01)
    # 40 cells of 1 mm² for the half disc's 39.3 mm²: the mean reads 1.8 % low
    assert sig[gap, 5].mean() == pytest.approx(5000.0 / (2 * np.pi * 10 ** 2 / 4), rel=0.02)
    # the pin's bending at mid-span, on its symmetry plane z = 0 (its layer z = 0.5 held in z):
    # the layer's Σ σ_zz·x·a² is the moment the plane's support carries about y, which
    # summary.json states (statics: its reactions' moment about the origin, M_y = −Σ x·R_z);
    # the run's default stress counts the plane's force on the layer's face (the plain virial:
    # half, its bindings beyond the plane gone), within the layer's half-spacing offset and
    # the staircase section
    m_y = next(x["moment"][1] for x in s["reactions"]
               if x["group"] == "pin" and np.allclose(x["force"][:2], 0.0, atol=1e-6 * 1250))
    mid = pin[np.isclose(o[pin, 2], 0.5)]
    sig_c = ParticleStress(run, method="continuum").run().results.stress[-1]
    assert (sig_c[mid, 2] * o[mid, 0]).sum() == pytest.approx(m_y, rel=0.1)
    assert (sig[mid, 2] * o[mid, 0]).sum() == pytest.approx(m_y / 2, rel=0.1)
    # the contact's edges (singular, left out of the governing stress): where the pin bears
    # on the rim of the lug's bore at its face toward the gap (z = 4.5, the bore's radius 5
    # give or take a spacing) — none on the symmetry plane z = 0, a mirror, not a free face;
    # the lug's points are the pin's too, and the cheek's rim (z = 6.5) is the clevis's
    from rackstress.stress.governing import contact_edges
    from rackstress.stress.post import compute_fields

    edges = contact_edges(run, compute_fields(run))
    for part, z in (("lug", 4.5), ("clevis", 6.5)):
        e = edges[part]
        assert len(e) and np.allclose(e[:, 2], z), part
        assert np.all(np.abs(np.hypot(e[:, 0], e[:, 1]) - 5.0) <= 1.0), part
    assert len(edges["pin"]) == len(edges["lug"]) + len(edges["clevis"])
    gov = st["governing_parts"]["lug"]
    assert gov["singular_points"].get("contact edge") == len(edges["lug"])
    # plain lmp: in.lammps is the equilibrium's deck (the positions from equilibrium.dump, one
    # run 0); its forces, each × the scene's particle mass / its type's mass, leave the same
    # largest unbalanced force as the run's own engine check, to round-off
    import shutil

    from rackstress.scenes import load

    plain = tmp_path / "plain"
    plain.mkdir()
    for name in ("in.lammps", "particles.data", "equilibrium.dump"):
        shutil.copy(out / name, plain / name)
    lmp = Path(sys.executable).parent / "lmp"
    r = subprocess.run([str(lmp), "-in", "in.lammps"], cwd=plain, capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr
    rows = (plain / "forces.dump").read_text().split("ITEM: ATOMS")[1].splitlines()[1:]
    fa = np.array([ln.split() for ln in rows if ln.strip()], float)
    fa = fa[np.argsort(fa[:, 0])][:, 1:4]
    sc = load(str(repo / "examples" / "assembly" / "pin-joint.toml"))
    md = np.concatenate([np.full(g.n, s["masses"][n]) for n, g in sc.groups.items()])
    worst = np.linalg.norm(fa * (sc.masses() / md)[:, None], axis=1).max()
    assert worst / s["applied_load_total"] == pytest.approx(s["residual_engine"], rel=1e-6)
    # its contact pressure pictured on the pin alone: the colour scale's top is the largest
    # pressure on the pin, the one stress.json names for the clevis-pin contact
    r = subprocess.run([sys.executable, "-m", "rackstress.cli", "render", str(out), "--measure",
                        "contact_pressure", "--groups", "pin", "--views", "iso,top"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    rec = json.loads((out / "figures" / "contact_pressure" / "render.json").read_text())
    assert rec["label"] == "contact pressure [MPa]" and rec["parts"]["coloured"] == ["pin"]
    on_pin = max(c["peak"] for c in st["contact"] if c["group"] == "pin")
    assert rec["vmax"] == pytest.approx(on_pin, rel=1e-6)
    assert (out / "figures" / "contact_pressure" / "sheet.png").stat().st_size > 10_000


def test_refine_scales_the_spacing_parameter_and_what_follows_it():
    """``--refine`` loads the scene at spacing/√2 as ``--set spacing=…`` would: the pin joint's
    lattice origin, "$(spacing / 2)", follows, so the first layer still lies half a (new)
    spacing off each symmetry plane, every part on one lattice (the pin's and the holes'
    particles complementary: touching at R, none closer) — scaling the parts' spacing alone
    left the origin at 0.5 mm and no particle within half a spacing of the planes (exit 2)."""
    from scipy.spatial import cKDTree

    from rackstress.scenes.toml import load_toml

    repo = Path(__file__).resolve().parents[1]
    sc = load_toml(repo / "examples" / "assembly" / "pin-joint.toml",
                   spacing_scale=1 / np.sqrt(2))
    a = 1 / np.sqrt(2)
    assert sc.params["spacing_scale"] == pytest.approx(a)
    for name in ("lug", "clevis", "pin"):
        o = sc.groups[name].o
        assert o[:, 1].min() == pytest.approx(a / 2) and o[:, 2].min() == pytest.approx(a / 2)
        assert sc.groups[name].fixed[np.isclose(o[:, 2], a / 2), 2].all()   # the plane holds
    pin, lug = sc.groups["pin"].o, sc.groups["lug"].o
    d, _ = cKDTree(lug).query(pin)
    assert d.min() == pytest.approx(a, rel=1e-9)


PLATE = """
name = "plate-on-base"
units = "mm-N-s"
analysis = "static"

[[group]]
name = "plate"
mesh = "{stl}"
scale = 1000
material = "PLA"
spacing = 1.0

[[group]]
name = "base"
fill = {{ box = {{ min = [-27, -22, -3], max = [27, 22, 0] }} }}
spacing = 1.0
material = "aluminium"

[[contact]]
between = ["plate", "base"]

[[support]]
on = "base"
where = {{ box = {{ min = [-28, -23, -4], max = [28, 23, -2.5] }} }}

[[support]]
on = "plate"
where = {{ union = [{{ hole = "H1" }}, {{ hole = "H2" }}, {{ hole = "H3" }}, {{ hole = "H4" }}] }}
fix = ["x", "y"]

[[load]]
on = "plate"
where = {{ face = "F3" }}
force = [0, 0, -20]
"""


def test_a_real_plate_on_a_base_starts_touching_and_passes_its_load(tmp_path):
    """A part nobody here drew (the SO-101 driver-board plate, examples/parts, in metres)
    resting on a base, located in its plane at its four screw holes and pushed down by 20 N
    on its boss: parts in contact are filled on one lattice, so no particle of the plate
    starts closer to the base than a spacing (the contact's R) and its flat bottom starts
    touching at zero force — each filled in its own box, the plate started 0.06 mm into the
    base and the contact pushed with 7.7e5 N before any load. It settles, and statics: the
    base's support takes the 20 N, the screws nothing (they only locate it)."""
    from scipy.spatial import cKDTree

    from rackstress.engines import static
    from rackstress.scenes import load

    repo = Path(__file__).resolve().parents[1]
    stl = repo / "examples" / "parts" / "so101-mounting-plate" / \
        "waveshare_mounting_plate_so101_v2.stl"
    f = tmp_path / "plate.toml"
    f.write_text(PLATE.format(stl=stl))
    sc = load(str(f))
    d, _ = cKDTree(sc.groups["base"].o).query(sc.groups["plate"].o)
    assert d.min() == pytest.approx(1.0, abs=1e-9)              # touching, not pressed
    assert np.count_nonzero(np.abs(d - 1.0) <= 1e-9) > 1000     # the bottom face, flat on it
    res = static.solve(sc)
    assert res.settled
    reac = {r["group"]: r["force"] for r in static.support_reactions(sc, res)["reactions"]}
    assert reac["base"][2] == pytest.approx(20.0, rel=1e-5)
    assert np.abs(reac["plate"]).max() <= 1e-4


def test_parts_in_contact_drawn_overlapping_give_their_shared_sites_to_the_first(tmp_path):
    """Two 10 mm cubes in contact drawn 2 mm into each other, spacing 1: the second is filled
    through the first's lattice (sites at 0.5 … 9.5 mm and 8.5 … 17.5 mm), and the 2 × 10 × 10
    sites inside both stay the first's — none coincide — with a warning naming the count."""
    from rackstress.scenes import load
    from rackstress.scenes.physical import held_load_warnings

    f = tmp_path / "over.toml"
    f.write_text('name = "over"\nunits = "mm-N-s"\nanalysis = "static"\n'
                 '[[group]]\nname = "a"\nfill = { box = { min = [0, 0, 0], max = [10, 10, 10] } }\n'
                 'spacing = 1.0\nmaterial = "aluminium"\n'
                 '[[group]]\nname = "b"\nfill = { box = { min = [8, 0, 0], max = [18, 10, 10] } }\n'
                 'spacing = 1.0\nmaterial = "aluminium"\n'
                 '[[contact]]\nbetween = ["a", "b"]\n')
    sc = load(str(f))
    a, b = sc.groups["a"].o, sc.groups["b"].o
    assert len(a) == 1000 and len(b) == 1000 - 200
    assert b[:, 0].min() == pytest.approx(10.5)
    (w,) = held_load_warnings(sc)
    assert w["kind"] == "contact_overlap" and w["sites"] == 200 and "'b'" in w["message"]
