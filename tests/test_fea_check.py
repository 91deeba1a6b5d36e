"""The stress recovery and the FE check that compares where it matters: patch recovery on a
field with a known answer, the distance bands and the governing point on a synthetic set,
fea.png's one colour scale, and ``rackstress fea``'s refusals in real processes (a static run
that did not settle, an FE model that would not fit in memory, under ``ulimit -v`` too)."""
from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from rackstress.stress import tensor as T
from rackstress.validity import solid
from test_faults import QUIET, RS, rs
from test_faults_static import hinge


def _block(nx, ny, nz, a=1.0):
    return np.array([[x, y, z] for x in range(nx) for y in range(ny) for z in range(nz)],
                    float) * a


def test_patch_recovery_reads_a_linear_field_on_the_surface():
    """A stress varying linearly through a bar (σ_xx = 5 + 2x − 3y, σ_yz = 1 + z): the
    recovered value at each particle's recovery point is the field there — on the faces half a
    spacing out (x = −0.25 … 2.75 at spacing 0.5), at the centre inside — by the per-frame
    path (patch_matrix) and the direct fit alike."""
    a = 0.5
    o = _block(6, 4, 3, a)
    pts = T.part_recovery_points(o)
    faces = T.free_faces(o, a)
    assert np.array_equal(pts, o + 0.5 * a * faces)
    assert pts[:, 0].min() == pytest.approx(-0.25) and pts[:, 0].max() == pytest.approx(2.75)
    assert np.all(pts[T.interior(faces)] == o[T.interior(faces)])

    def field(x):
        s = np.zeros((len(x), 6))
        s[:, 0] = 5 + 2 * x[:, 0] - 3 * x[:, 1]
        s[:, 3] = 1 + x[:, 2]
        return s

    want = field(pts)
    W = T.patch_matrix(o, a, pts)
    assert np.asarray(W @ field(o)) == pytest.approx(want, abs=1e-9)
    assert T.patch_recover(o, field(o), a, pts) == pytest.approx(want, abs=1e-9)
    # a constant field stays itself: each row of W sums to 1
    assert np.asarray(W.sum(axis=1)).ravel() == pytest.approx(np.ones(len(o)))


def test_patch_recovery_keeps_parts_apart():
    """Two blocks side by side, each with its own constant stress: a particle's patch takes
    only its own part (labels), so each reads its own value right up to the gap."""
    o = np.vstack([_block(3, 3, 3), _block(3, 3, 3) + [3.0, 0, 0]])
    lab = np.repeat([0, 1], 27)
    s = np.where(lab[:, None] == 0, 1.0, 7.0) * np.ones((1, 6))
    pts = np.vstack([T.part_recovery_points(o[:27]), T.part_recovery_points(o[27:])])
    rec = np.asarray(T.patch_matrix(o, 1.0, pts, lab) @ s)
    assert rec[:27] == pytest.approx(np.ones((27, 6)))
    assert rec[27:] == pytest.approx(7 * np.ones((27, 6)))


def test_patch_recovery_fits_its_data_and_falls_back_where_they_are_flat():
    """``data``: only those particles' values enter a fit. A block whose top layer carries
    wrong values (+50, as a staircase's steps read) reads the linear field exactly where the
    other layers span three dimensions; a wall of one data layer (coplanar) cannot, and is
    fitted from its whole patch, the wrong values included, as before."""
    a = 1.0
    o = _block(5, 5, 4, a)
    pts = T.part_recovery_points(o)
    top = o[:, 2] == 3.0
    field = (2.0 + o[:, 0] - 0.5 * o[:, 2])[:, None] * np.ones((1, 6))
    s = field + np.where(top, 50.0, 0.0)[:, None]
    want = (2.0 + pts[:, 0] - 0.5 * pts[:, 2])[:, None] * np.ones((1, 6))
    rec = np.asarray(T.patch_matrix(o, a, pts, data=~top) @ s)
    assert rec == pytest.approx(want, abs=1e-9)
    # all particles as data: the top layer's +50 enters every fit near it
    assert np.abs(np.asarray(T.patch_matrix(o, a, pts) @ s) - want).max() > 10.0
    only = o[:, 2] == 1.0                    # one plane of data: no fit spans the normal
    rec = np.asarray(T.patch_matrix(o, a, pts, data=only) @ s)
    assert rec == pytest.approx(np.asarray(T.patch_matrix(o, a, pts) @ s), abs=1e-12)


def test_a_part_one_layer_thick_is_fitted_in_its_plane():
    """A membrane of one layer (z = 0.5 everywhere) with σ = 4 + 3x − 2y: its patches do not
    span z, so they are fitted in the plane, and every particle reads the field at its
    recovery point (the edges half a spacing out) — not its own value, which an edge row
    x = 7 would read 1.5 low (3 × ½ spacing). Its wrong steps (+50 on two particles of the edge,
    left out of ``data`` as ``regular_cells`` leaves a staircase's steps) are read from the
    other particles. A second part, a 3D block, is fitted in 3D beside it."""
    a = 1.0
    sheet = np.array([[x, y, 0.5] for x in range(8) for y in range(6)], float)
    block = _block(4, 4, 4, a) + [20.0, 0.0, 0.0]
    o = np.vstack([sheet, block])
    lab = np.r_[np.zeros(len(sheet), int), np.ones(len(block), int)]
    assert T.flat_axes(o, a, lab)[:len(sheet)].tolist() == [[False, False, True]] * len(sheet)
    assert not T.flat_axes(o, a, lab)[len(sheet):].any()
    pts = np.vstack([T.part_recovery_points(sheet), T.part_recovery_points(block)])
    assert pts[:len(sheet), 2] == pytest.approx(0.5)             # nothing out of the plane

    def field(x):
        return (4.0 + 3.0 * x[:, 0] - 2.0 * x[:, 1])[:, None] * np.ones((1, 6))

    steps = np.zeros(len(o), bool)
    steps[[5, 47]] = True                                        # (0, 5) and (7, 5)
    s = field(o) + np.where(steps, 50.0, 0.0)[:, None]
    rec = np.asarray(T.patch_matrix(o, a, pts, lab, data=~steps) @ s)
    assert rec == pytest.approx(field(pts), abs=1e-9)
    # the edge x = 7 (its corners aside) reads the field at x = 7.5: 1.5 above its own value
    edge = np.flatnonzero((o[:, 0] == 7.0) & (lab == 0) & (o[:, 1] > 0) & (o[:, 1] < 5))
    assert rec[edge, 0] - field(o)[edge, 0] == pytest.approx(1.5)


def test_regular_cells_are_the_lattice_boxes():
    """A 4 × 4 × 4 block's cells are all regular (faces at half a spacing: φ = 1); a face
    cell that overhangs by 0.7 spacing (φ = 1.2) is not, nor an edge cell whose face falls
    short by 0.2 spacing across one of its two free faces (φ = 0.8: a step's corner); a face
    cell whose one face falls short (φ = 0.6: a flat face at another offset) is; φ inside
    the part is not read; without φ (a dynamic run) all are regular."""
    o = _block(4, 4, 4)
    phi = np.ones((64, 3))
    assert T.regular_cells(o, 1.0, phi).all()
    face = int(np.flatnonzero((o[:, 0] == 3) & (o[:, 1] == 1) & (o[:, 2] == 1))[0])
    edge = int(np.flatnonzero((o[:, 0] == 3) & (o[:, 1] == 3) & (o[:, 2] == 1))[0])
    inner = int(np.flatnonzero((o[:, 0] == 1) & (o[:, 1] == 1) & (o[:, 2] == 1))[0])
    phi[face, 0] = 1.2
    phi[edge, 1] = 0.8
    phi[edge, 2] = 0.5                       # not a free axis of that edge cell: not read
    phi[inner] = 1.3
    flat = int(np.flatnonzero((o[:, 0] == 1) & (o[:, 1] == 1) & (o[:, 2] == 3))[0])
    phi[flat, 2] = 0.6
    got = T.regular_cells(o, 1.0, phi)
    assert not got[face] and not got[edge] and got[inner] and got[flat]
    assert got.sum() == 62
    assert T.regular_cells(o, 1.0).all()
    # bound by its bindings alone, an overhanging face cell is read where its face is flat
    # (its in-plane neighbours' extents within 0.05 of its own), not on a step (theirs 1)
    assert np.array_equal(T.regular_cells(o, 1.0, phi, volumetric=False), got)
    phi[o[:, 0] == 3, 0] = 1.2               # the whole face x = 3 overhangs: 16 cells
    assert T.regular_cells(o, 1.0, phi).sum() == 64 - 16
    lat = T.regular_cells(o, 1.0, phi, volumetric=False)   # its 2 × 2 middle are read
    assert lat.sum() == 64 - 16 + 4
    assert set(map(tuple, o[lat & (o[:, 0] == 3)])) == {(3, y, z) for y in (1, 2) for z in (1, 2)}


#: a round rod of radius 5 mm, 30 mm long, from an STL of 256 facets: one end clamped, the
#: other pulled by F = 100 MPa × its cross-section
ROD = """
name = "rod"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "rod"
fill = {{ mesh = "rod.stl" }}
spacing = 1
material = {{ E = 70e9, nu = 0.3, density = 2700 }}
poisson = "{poisson}"
[[support]]
on = "rod"
where = {{ box = {{ min = [-9, -9, -1], max = [9, 9, 1] }} }}
[[load]]
on = "rod"
where = {{ box = {{ min = [-9, -9, 29], max = [9, 9, 31] }} }}
force = [0, 0, {F}]
"""


@pytest.mark.parametrize("poisson", ["lattice", "material"])
def test_a_round_rod_in_tension_reads_its_stress_on_its_staircased_face(poisson, tmp_path):
    """Uniform tension, σ_zz = F/A = 100 MPa at every point away from the ends (statics, by
    hand; A the 256-gon's area). The lattice staircases the round face: its steps' cells
    overhang their particles by up to a spacing, or a slanted face cuts them. The patch fit
    samples the regular cells only, so every surface particle at mid-length reads 100 MPa
    within 3 %, and so does the largest von Mises stress there. With every particle as data
    (the fit before) the surface read σ_zz up to +15 % (+5.7 % median) on the lattice of
    ν = ¼ and von Mises up to +19 %; +8 % and +14 % on the material's ν."""
    import math

    import trimesh

    from rackstress.runs.run import run
    from rackstress.scenes import load_toml
    from rackstress.stress import load_run
    from rackstress.stress.measures import ParticleStress

    m = trimesh.creation.cylinder(radius=5.0, height=30.0, sections=256)
    m.apply_translation([0, 0, 15])
    m.export(tmp_path / "rod.stl")
    F = 100.0 * 0.5 * 256 * 25.0 * math.sin(2 * math.pi / 256)
    (tmp_path / "rod.toml").write_text(ROD.format(poisson=poisson, F=F))
    summary = run(load_toml(tmp_path / "rod.toml"), tmp_path / "r", progress=False)
    assert summary["settled"]
    got = load_run(tmp_path / "r")
    o = got.o
    mid = np.abs(o[:, 2] - 15.0) < 3.0
    surface = mid & np.any(T.free_faces(o, 1.0)[:, :2] != 0, axis=1)
    assert surface.sum() > 100
    res = ParticleStress(got).run().results
    s = res.stress[-1]
    assert s[surface, 2] == pytest.approx(100.0, rel=0.03)
    assert np.nanmax(res.von_mises[-1][mid]) == pytest.approx(100.0, rel=0.03)


#: a cantilever 60 mm long, 6 mm wide and h mm deep from an STL box: one end clamped, the
#: other carrying F = 20 N down
BEAM = """
name = "beam"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "beam"
fill = {{ mesh = "beam.stl" }}
spacing = 1
material = {{ E = 70e9, nu = 0.3, density = 2700 }}
poisson = "material"
[[support]]
on = "beam"
where = {{ box = {{ min = [-1, -9, -9], max = [1, 9, 9] }} }}
[[load]]
on = "beam"
where = {{ box = {{ min = [59, -9, -9], max = [61, 9, 9] }} }}
force = [0, 0, -20]
"""


def _bent_beam(tmp_path, depth: float, scene: str, lift: float = 0.0):
    """The cantilever of :data:`BEAM` (60 × 6 mm × ``depth``, from an STL box) solved by the
    scene text ``scene``: its run, settled. ``lift``: a block inside the clamp (x < 0) rising
    that far above the beam, which moves the fill's lattice (centred on the part) up by
    lift/2: the beam's faces fall off-centre between its layers."""
    import trimesh

    from rackstress.runs.run import run
    from rackstress.scenes import load_toml
    from rackstress.stress import load_run

    m = trimesh.creation.box(extents=[60.0, 6.0, depth])
    m.apply_translation([30.0, 0, 0])
    if lift:
        k = trimesh.creation.box(extents=[0.8, 6.0, depth + lift])
        k.apply_translation([-0.5, 0, lift / 2])
        m = trimesh.util.concatenate([m, k])
    m.export(tmp_path / "beam.stl")
    (tmp_path / "beam.toml").write_text(scene)
    assert run(load_toml(tmp_path / "beam.toml"), tmp_path / "r", progress=False)["settled"]
    return load_run(tmp_path / "r")


def _beam_theory(o: np.ndarray, x, depth: float, F: float = 20.0, b: float = 6.0):
    """M·(h/2)/I at ``x`` of :data:`BEAM`'s cantilever: M = F·(x_F − x), x_F where the load's
    particles are, I = b·h³/12 (by hand)."""
    x_F = o[o[:, 0] > 59, 0].mean()
    return F * (x_F - x) * (depth / 2) / (b * depth ** 3 / 12)


@pytest.mark.parametrize("depth", [5.6, 5.8])
def test_a_bent_beam_reads_its_face_stress_where_its_face_is(depth, tmp_path):
    """Beam theory, σ_xx = M·(h/2)/I with M = F·(x_F − x) and I = b·h³/12, on the top face
    across mid-span (x_F where the load's particles are). A depth of 5.6 (5.8) spacings puts
    the face 0.3 (0.4) spacings past the top layer, not half a spacing: the cells' extents
    φ = 0.8 (0.9). The face particles are read on the face, (φ − ½) spacings out, and the
    largest reads within 3 %. Read half a spacing out, past the face, the 5.6 beam's face
    read 4.4 % high."""
    from rackstress.stress.measures import ParticleStress

    got = _bent_beam(tmp_path, depth, BEAM.format())
    o = got.o
    assert np.ptp(o[:, 2]) == pytest.approx(round(depth) - 1)      # the layers the fill made
    top = o[:, 2] == o[:, 2].max()
    sx = ParticleStress(got).run().results.stress[-1][:, 0]
    for x in (25.0, 30.0, 35.0):
        at = top & (np.abs(o[:, 0] - x) < 0.6)
        want = _beam_theory(o, o[at, 0], depth)
        assert np.max(sx[at] / want) == pytest.approx(1.0, abs=0.03)


def test_bands_and_the_governing_point_of_a_synthetic_set():
    """Particles at known distances (in spacings 0.5, 1.5, 3, 4, 8, 12) from one singular
    point: each band holds those particles; its peak ratio is the particles' largest over
    FEA's largest in it, its median error the median |particle − FEA| over FEA's largest
    (hand calculation); the governing point is FEA's largest at ≥ 2 spacings."""
    a = 2.0
    d = np.array([0.5, 1.5, 3.0, 4.0, 8.0, 12.0]) * a
    x = np.column_stack([d, np.zeros(6), np.zeros(6)])
    sing = solid.Singular(np.zeros((1, 3)), 2 * a, "two spacings", a)
    assert sing.distance(x) == pytest.approx(d)
    part = np.array([90.0, 50, 40, 31, 20, 10])
    fea = np.array([100.0, 60, 42, 30, 20, 12])
    b = {r["band"]: r for r in solid.bands(part, fea, sing.distance(x), a)}
    assert [b[k]["n"] for k in ("0-1", "1-2", "2-5", ">5")] == [1, 1, 2, 2]
    assert b["2-5"]["peak_ratio"] == pytest.approx(40 / 42)
    assert b["2-5"]["median_error"] == pytest.approx(np.median([2.0, 1.0]) / 42)
    assert b[">5"]["peak_ratio"] == pytest.approx(20 / 20)
    assert b[">5"]["spearman"] is None                       # two points: no rank test
    gov = solid.governing(x, fea, sing)
    assert gov["value"] == 42 and gov["position"] == [6.0, 0.0, 0.0]


def test_the_fe_governing_stress_is_read_where_the_particles_are_read_too():
    """A stress rising toward a singular point, σ = 1/r (r its distance), is largest at the
    zone's edge. FE nodes 1 apart from r = 0.5 stand inside it (zone 1): their largest
    allowed is 1/1.5. The particles' read points at r = 1.05 (outside) and 0.9 (inside) add
    the FE's field there: its governing stress is 1/1.05, at that point (hand calculation)."""
    sing = solid.Singular(np.zeros((1, 3)), 1.0, "one", 1.0)
    nodes = np.column_stack([[0.5, 1.5, 2.5], np.zeros(3), np.zeros(3)])
    assert solid.governing(nodes, 1 / nodes[:, 0], sing)["value"] == pytest.approx(1 / 1.5)
    pts = np.column_stack([[1.05, 0.9], np.zeros(2), np.zeros(2)])
    gov = solid.governing(nodes, 1 / nodes[:, 0], sing, pts, 1 / pts[:, 0])
    assert gov["value"] == pytest.approx(1 / 1.05) and gov["position"] == [1.05, 0.0, 0.0]


def test_both_panels_of_fea_png_share_one_colour_scale(tmp_path):
    """fea.png: the particles' and FEA's von Mises on one scale (the larger 99.5th
    percentile), one colour bar labelled in the run's unit."""
    rng = np.random.default_rng(1)
    o = rng.uniform(0, 10, (400, 3)) * [1, 1, 0.2]
    part, fea = rng.uniform(0, 50, 400), rng.uniform(0, 80, 400)
    data = {"group": "part", "to_stress": 1.0, "stress_unit": "MPa",
            "agreement": {"spearman": 0.9, "top5_overlap": 0.5}, "governing": {}}
    lim = solid.picture(o, part, "von_mises", fea, tmp_path / "fea.png", data)
    assert lim[0] == lim[1] == (0.0, pytest.approx(np.percentile(fea, 99.5)))
    assert (tmp_path / "fea.png").stat().st_size > 10_000


# ------------------------------------------------------------------ real processes
@pytest.fixture(scope="module")
def settled(tmp_path_factory):
    """The clamped steel bar of the static faults, settled."""
    d = tmp_path_factory.mktemp("check")
    out = d / "run"
    r = rs("run", hinge(d), "--out", out, *QUIET, timeout=300)
    assert r.returncode == 0, r.stderr
    return out


@pytest.mark.lammps
def test_fea_refuses_a_run_that_did_not_settle(tmp_path, settled):
    """A run directory whose summary says "not settled" (as a static run that stopped short
    leaves it): exit 2 with the reason; --allow-unsettled compares it and says so."""
    d = tmp_path / "unsettled"
    shutil.copytree(settled, d)
    s = json.loads((d / "summary.json").read_text())
    s.update(status="not settled", settled=False, residual=3e-3)
    (d / "summary.json").write_text(json.dumps(s))
    r = rs("fea", d, timeout=300)
    assert r.returncode == 2, r.stderr
    assert "did not settle" in r.stderr and "--allow-unsettled" in r.stderr
    assert "Traceback" not in r.stderr and not (d / "fea.json").exists()
    r = rs("fea", d, "--allow-unsettled", "--no-converge", timeout=300)
    assert r.returncode == 0, r.stderr
    data = json.loads((d / "fea.json").read_text())
    assert "did not settle" in data["compared"]


@pytest.mark.lammps
@pytest.mark.slow
def test_fea_of_a_settled_run_reports_bands_and_its_own_convergence(settled):
    """The settled bar: the agreement by band, the zone and its rule, the FE's governing
    stress at two FE sizes (how much it moved), the particles' value at its point."""
    r = rs("fea", settled, timeout=600)
    assert r.returncode == 0, r.stderr
    data = json.loads((settled / "fea.json").read_text())
    assert data["compared"] == "the static equilibrium"
    assert [b["band"] for b in data["bands"]] == ["0-1", "1-2", "2-5", ">5"]
    assert sum(b["n"] for b in data["bands"]) == data["particles"]
    assert data["zone"]["spacings"] == 2.0 and "spacings" in data["zone"]["rule"]
    # the zone is the headline's: the run's singular points (singular.npz) and its zone, the
    # bar 4 thick at spacing 1 so two spacings govern (0.4 × 4 < 2)
    s = json.loads((settled / "summary.json").read_text())
    assert data["zone"]["source"] == "singular.npz"
    assert data["zone"]["length"] == pytest.approx(s["stress"]["governing"]["zone"]) == 2.0
    gov = data["governing"]
    assert len(data["fe_meshes"]) == 2 and gov["coarser"]["size"] > data["fe"]["size"]
    assert 0 <= gov["moved"] < 0.1 and 0.5 < gov["ratio"] < 1.5
    assert "spacings from a singular point" in r.stdout and "moved" in r.stdout


@pytest.mark.lammps
def test_fea_of_a_run_given_another_spacing_meshes_the_parts_own_file(tmp_path):
    """``rackstress run PART.toml --set spacing=1.5`` and ``rackstress fea``: the FE check
    rebuilds the scene the run solved (the spacing given on the command line with it) and
    meshes the part's own STL. The --set spacing was not recorded: the rebuilt part differed
    from the run's, and the FE fell back to the union of the particles' cells, a staircase
    of the part, said only in a note."""
    import trimesh

    m = trimesh.creation.box(extents=[24.0, 6.0, 6.0])
    m.apply_translation([12.0, 0, 0])
    m.export(tmp_path / "beam.stl")
    (tmp_path / "beam.toml").write_text(BEAM.format().replace("[59, -9, -9], max = [61",
                                                              "[23, -9, -9], max = [25"))
    out = tmp_path / "r"
    r = rs("run", tmp_path / "beam.toml", "--set", "spacing=1.5", "--out", out, *QUIET,
           timeout=300)
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "scene.json").read_text())["groups"][0]["spacing"] == 1.5
    r = rs("fea", out, "--no-converge", timeout=300)
    assert r.returncode == 0, r.stderr
    data = json.loads((out / "fea.json").read_text())
    assert data["mesh"].endswith("of beam.stl") and data["note"] is None, (data["mesh"],
                                                                          data["note"])
    assert data["spacing"] == 1.5


@pytest.mark.lammps
def test_fea_refuses_an_fe_model_that_would_not_fit(settled):
    """--size far below the spacing: the FE model's memory is estimated before meshing and
    refused with how much it needs and which --size fits (exit 2, nothing written); under
    ``ulimit -v`` the limit is the address space left, named in the message."""
    before = set(p.name for p in settled.iterdir())
    r = rs("fea", settled, "--size", "0.01", timeout=300)
    assert r.returncode == 2, r.stderr
    assert "needs about" in r.stderr and "--size" in r.stderr and "GB" in r.stderr
    assert "Traceback" not in r.stderr
    assert set(p.name for p in settled.iterdir()) == before
    # 3.5 GB of address space: the imports fit, 300,000 tetrahedra (5 GB) do not
    r = subprocess.run(["bash", "-c", f"ulimit -v 3500000; exec {RS} fea {settled} --size 0.15"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    assert "ulimit -v 3500000" in r.stderr and "needs about" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and "MemoryError" not in r.stderr


@pytest.mark.lammps
def test_a_finer_fe_mesh_skips_the_direct_analysis_its_coarser_one_failed(tmp_path, settled,
                                                                         monkeypatch):
    """When the coarser FE mesh's direct factor is refused (here: no memory granted to it),
    the finer mesh, whose factor can only be larger, goes to conjugate gradients without
    another PARDISO analysis: one analysis for the two sizes, both solved by CG."""
    from rackstress.engines import linear

    d = tmp_path / "run"
    shutil.copytree(settled, d)
    calls = []
    analyse = linear.Pardiso.analyse

    def counted(self):
        calls.append(self.n)
        return analyse(self)

    monkeypatch.setattr(linear.Pardiso, "analyse", counted)
    monkeypatch.setattr(solid, "DIRECT_DOFS", 0)
    monkeypatch.setattr(solid, "DIRECT_MEMORY", 1)
    got = solid.check_run(d, echo=lambda *_: None)
    assert len(calls) == 1 and got["fe"]["solver"] == "cg"
    assert got["fe"]["dofs"] > calls[0]             # the finer mesh, never analysed
    assert [m["solver"] for m in got["fe_meshes"]] == ["cg", "cg"]


def test_mesh_quality_names_slivers_and_a_poor_mesh():
    """q = 6·√2·V/ℓ³ (ℓ the rms edge): the corner tetrahedron of the unit cube, V = 1/6, three
    edges 1 and three √2 (ℓ² = 1.5): q = √2/1.5^1.5 = 0.7698; a flat one 0.01 above the
    middle of its base's hypotenuse, V = 0.5·0.01/3, ℓ² = (4 + 3·0.5001)/6: q = 0.0161, a
    sliver. One sliver in two is a poor mesh (above 5 %); the report says so."""
    from rackstress.render.report import fea_section

    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0.01]], float)
    q = solid.mesh_quality(p, np.array([[0, 1, 2, 3]]))
    assert q["min"] == pytest.approx(2 ** 0.5 / 1.5 ** 1.5) and not q["poor"]
    q = solid.mesh_quality(p, np.array([[0, 1, 2, 4]]))
    l2 = (4 + 3 * 0.5001) / 6
    assert q["min"] == pytest.approx(6 * 2 ** 0.5 * (0.5 * 0.01 / 3) / l2 ** 1.5)
    assert q["sliver_share"] == 1.0 and q["poor"]
    q = solid.mesh_quality(p, np.array([[0, 1, 2, 3], [0, 1, 2, 4]]))
    assert q["sliver_share"] == 0.5 and q["poor"]
    html = fea_section({"fe_quality": dict(q, why="50 % of the FE's tetrahedra are slivers")})
    assert 'id="fea-poor"' in html and "50 % of the FE" in html
    assert 'id="fea-poor"' not in fea_section({"fe_quality": {"poor": False}})


@pytest.mark.parametrize("depth", [6.29, 8.0])
def test_a_wall_bound_by_its_bindings_alone_reads_beam_theory_on_its_edges(depth, tmp_path):
    """The same cantilever bound by its bindings alone (``poisson = "lattice"``, the default:
    ν = ¼), 6 and 8 layers deep (φ = 1.145 and 1): beam theory's M·c/I (M = F·(x_F − x), I =
    b·h³/12) on every top particle at mid-span, the edges' included, within 3 %. Read with
    the volumetric lattice's sample offsets the edges read 1.084 and 1.054 of it."""
    from rackstress.stress.measures import ParticleStress

    scene = BEAM.format().replace('poisson = "material"\n', "")
    assert "poisson" not in scene
    got = _bent_beam(tmp_path, depth, scene)
    o = got.o
    assert len(np.unique(o[:, 2])) == int(depth)
    top = (o[:, 2] == o[:, 2].max()) & np.isclose(o[:, 0], 29.5)
    assert top.sum() == 6
    sx = ParticleStress(got).run().results.stress[-1][top, 0]
    want = _beam_theory(o, 29.5, depth)
    assert sx / want == pytest.approx(np.ones(6), abs=0.03)


def test_a_wall_the_lattice_meets_off_centre_reads_beam_theory_on_its_face(tmp_path):
    """The cantilever bound by its bindings alone, 4.29 deep, a block in the clamp rising 0.6
    above it, as a part's fill meets its walls off-centre. By hand: the fill centres its
    lattice on the part's box, z from −2.145 to 2.745 (centre 0.3), so its sites lie at
    −1.7, −0.7, 0.3, 1.3 inside the wall: four layers, the top face 0.845 spacings past the
    top layer (φ = ½ + 0.845 = 1.345), the bottom 0.445 (φ = 0.945). Every top particle at
    mid-span reads beam theory's M·c/I within 5 % (I = b·h³/12). Extrapolated from the layers
    inside, as when such a face cell was left out of the fit, they read 1.19 … 1.22 of it."""
    from rackstress.stress.measures import ParticleStress, read_fractions

    scene = BEAM.format().replace('poisson = "material"\n', "")
    got = _bent_beam(tmp_path, 4.29, scene, lift=0.6)
    o = got.o
    xs = np.unique(o[:, 0])
    x = xs[np.argmin(np.abs(xs - 29.5))]
    col = o[:, 0] == x
    zs = np.unique(o[col, 2])
    assert len(zs) == 4
    top = col & (o[:, 2] == zs[-1])
    assert top.sum() == 6
    assert read_fractions(got)[top, 2] == pytest.approx(np.full(6, 1.345), abs=1e-3)
    sx = ParticleStress(got).run().results.stress[-1][top, 0]
    assert sx / _beam_theory(o, x, 4.29) == pytest.approx(np.ones(6), abs=0.05)


@pytest.mark.parametrize("depth, nu, within", [(4.0, 0.1, 0.02), (4.29, 0.45, 0.02),
                                               (5.0, 0.3, 0.02), (2.4, 0.3, 0.03)])
def test_a_bent_walls_face_reads_its_own_curvature_across_its_width(depth, nu, within,
                                                                   tmp_path):
    """A cantilever 4 to 5 spacings deep (face cells whole or overhanging, φ = 1 and 1.145),
    6 wide: E·κ·c from the particles' own displacements (the slope across the layers of
    their axial strain between x = 24.5 and 34.5; c = depth/2) is what its face carries at
    mid-span. Every top particle there, the edges' included, reads it within 2 % — each
    sample of the fit where its value stands (tensor.sample_points). Read at their
    particles the samples gave 0.93 … 1.03 (ν = 0.1) and 0.97 … 1.05 (ν = 0.45) of it. A
    wall of two layers whose face cells overhang (2.4 deep, φ = 1.2: no cell a regular
    sample, the whole patch's fit) within 3 %: 1.08 … 1.21 at the particles' centres."""
    from rackstress.stress.measures import ParticleStress, positions

    E = 70e3
    got = _bent_beam(tmp_path, depth, BEAM.format().replace("nu = 0.3", f"nu = {nu}"))
    o = got.o
    u = positions(got.trajectory[-1]) - o
    zs = np.unique(o[:, 2])
    eps = [(u[(o[:, 2] == z) & np.isclose(o[:, 0], 34.5), 0].mean()
            - u[(o[:, 2] == z) & np.isclose(o[:, 0], 24.5), 0].mean()) / 10.0 for z in zs]
    kappa = np.polyfit(zs, eps, 1)[0]
    top = (o[:, 2] == zs[-1]) & np.isclose(o[:, 0], 29.5)
    assert top.sum() == 6
    sx = ParticleStress(got).run().results.stress[-1][top, 0]
    own = E * kappa * depth / 2
    assert sx / own == pytest.approx(np.ones(6), abs=within)
    if len(zs) >= 4:              # and beam theory's M·c/I within 6 % (two layers bend 1.19×)
        assert own == pytest.approx(_beam_theory(o, 29.5, depth), rel=0.06)
