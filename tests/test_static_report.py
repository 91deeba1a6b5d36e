"""A static run's report reads as one: settled or NOT SETTLED first, the headline in the part's
own undeformed coordinates, the support reactions against the applied load, the stress painted
on the part's surface, nothing over time.

Real processes (``rackstress run`` through its console script, ``mpiexec -n 2``), real LAMMPS,
real VTK files read back with pyvista. Expected values come from hand calculation and beam
theory (the aluminium cantilever of ``examples/cantilever``: 100 × 10 × 10 mm, 100 N on its free
end, I = 10⁴/12 mm⁴), from geometry (the bar's faces), from the run's own particles.data read
by hand, and from fields whose interpolation is known exactly (linear in position).
"""
from __future__ import annotations

import json
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from conftest import dump_text, trajectory
from test_faults import mpi_rs, rs

ROOT = Path(__file__).resolve().parents[1]
CANTILEVER = ROOT / "examples" / "cantilever" / "scene.toml"
#: aluminium's yield strength in MPa (docs/units.md): the factor of safety is yield / stress
YIELD_AL = 276.0
#: 1e-9 N on a clamped steel bar 20 × 4 × 4 mm: below what rounding resolves, so Newton's
#: method stalls and the run does not settle (exit 6) — a load a user can give
TINY = """name = "tiny"
units = "mm-N-s"
analysis = "static"

[[group]]
name = "bar"
fill = { box = { min = [0, 0, 0], max = [20, 4, 4] } }
spacing = 1.0
material = "steel"

[[support]]
on = "bar"
where = { cylinder = { start = [0.5, 0.5, -1], end = [0.5, 0.5, 5], radius = 2.5 } }

[[load]]
on = "bar"
where = { box = { min = [19.5, -1, -1], max = [21, 5, 5] } }
force = [0, -1e-9, 0]
"""


class Page(HTMLParser):
    """Every tag with its attributes, the text inside each tag with an id, the whole text."""

    def __init__(self, path: Path):
        super().__init__()
        self.tags, self.by_id, self.text, self._open = [], {}, "", []
        self.feed(path.read_text(encoding="utf-8"))

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags.append((tag, a))
        if a.get("id"):
            self.by_id[a["id"]] = {"attrs": a, "text": ""}
        self._open.append(a.get("id"))

    def handle_endtag(self, tag):
        if self._open:
            self._open.pop()

    def handle_data(self, data):
        self.text += data
        for i in self._open:
            if i:
                self.by_id[i]["text"] += data


def summary(d: Path) -> dict:
    return json.loads((d / "summary.json").read_text())


def originals(d: Path) -> dict:
    """Every atom's position in particles.data, read by hand (the part's own coordinates)."""
    lines = (d / "particles.data").read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.strip().startswith("Atoms"))
    out = {}
    for line in lines[k + 2:]:
        f = line.split()
        if not f:
            break
        out[int(f[0])] = [float(x) for x in f[3:6]]     # atom style bond: id mol type x y z
    return out


def original(d: Path, atom_id: int) -> list:
    return originals(d)[int(atom_id)]


def last_frame(d: Path) -> tuple[np.ndarray, np.ndarray]:
    """(ids, positions) of the dump's last frame, read by hand."""
    text = dump_text(trajectory(d))
    block = text.split("ITEM: TIMESTEP")[-1].splitlines()
    n = int(block[3])
    cols = block[8].split()[2:]
    rows = np.array([[float(x) for x in line.split()] for line in block[9:9 + n]])
    ids = rows[:, cols.index("id")].astype(int)
    return ids, rows[:, [cols.index("x"), cols.index("y"), cols.index("z")]]


# ----------------------------------------------------------------------------- settled
@pytest.fixture(scope="module")
def cantilever(tmp_path_factory):
    """The example cantilever at spacing 2 mm (1,275 particles), run and rendered."""
    d = tmp_path_factory.mktemp("static") / "cantilever"
    r = rs("run", CANTILEVER, "--set", "spacing=2", "--out", d, "--no-progress", timeout=300)
    assert r.returncode == 0, r.stderr
    return d, r.stdout


@pytest.mark.lammps
def test_a_settled_run_leads_with_settled_and_its_headline_in_part_coordinates(cantilever):
    d, out = cantilever
    s = summary(d)
    page = Page(d / "report.html")
    banner = page.by_id["status"]
    assert banner["attrs"]["data-status"] == "settled" and "Settled" in banner["text"]
    # the banner comes first: before the headline, the reactions and the pictures
    assert page.text.index(banner["text"]) < page.text.index(page.by_id["headline"]["text"])
    head = page.by_id["headline"]["attrs"]
    pk = s["stress"].get("governing") or s["stress"]["peak"]
    assert float(head["data-value"]) == pk["value"]
    # the position is the particle's in particles.data (undeformed), not where it moved to
    pid = int(head["data-particle"])
    o = original(d, pid)
    shown = [float(x) for x in head["data-position"].split(",")]
    assert np.allclose(shown, o, atol=1e-3)
    # the headline's particle sits at the clamp and hardly moves; every position the page
    # gives is its particle's in particles.data, the free end's too, which moved 0.6 mm
    ids, p = last_frame(d)
    rows = [a for tag, a in page.tags if tag in ("tr", "p") and "data-position" in a]
    moved = 0
    for a in rows:
        q = original(d, int(a["data-particle"]))
        assert np.allclose([float(x) for x in a["data-position"].split(",")], q, atol=1e-3)
        moved += np.linalg.norm(p[ids == int(a["data-particle"])][0] - q) > 0.5
    assert len(rows) >= 4 and moved == 1
    # the factor of safety beside it is of the same stress: aluminium's yield over it
    assert float(head["data-safety"]) == pytest.approx(YIELD_AL / pk["value"], rel=1e-6)
    # the printed lines say the same, in the part's coordinates
    line = next(x for x in out.splitlines() if "von Mises stress" in x)
    assert "(undeformed coordinates)" in line and f"particle {pid}" in line
    assert f"({', '.join(f'{x:.4g}' for x in o)})" in line
    assert "NOT SETTLED" not in out and "NOT SETTLED" not in page.text


@pytest.mark.lammps
def test_a_static_report_has_no_time_in_it(cantilever):
    """No plots over time, no centre-of-mass paths, no frame talk, no paper measures of motion,
    no time step; the figures are the surface and the particles."""
    d, out = cantilever
    figures = sorted(p.name for p in (d / "figures").iterdir())
    assert figures == ["particles.png", "render.json", "sheet.png"]
    page = Page(d / "report.html")
    imgs = [a["src"] for tag, a in page.tags if tag == "img"]
    assert imgs == ["figures/sheet.png", "figures/particles.png"]
    for said in ("is not in the dump", "nearest frame", "over time", "centre of mass",
                 "Centre-of-mass", "time step", "Stability margin", "desired position"):
        assert said not in page.text and said not in out, said
    measures = [a["data-measure"] for tag, a in page.tags if tag == "tr" and "data-measure" in a]
    assert "von_mises" in measures and not {"paper", "accumulated"} & set(measures)
    manifest = json.loads((d / "figures" / "render.json").read_text())
    assert manifest["static"] is True and manifest["frames"] == []
    assert not [n for n in manifest["notes"] if "dump" in n]


@pytest.mark.lammps
def test_max_deformation_is_the_largest_displacement(cantilever):
    """Of a held part, the largest |p − o| (read by hand from the dump and particles.data), at
    the free end: beam theory's tip deflection P·L³/(3EI) + shear = 0.576 mm, within 5 %."""
    d, out = cantilever
    g = summary(d)["groups"]["bar"]
    ids, p = last_frame(d)
    known = originals(d)
    o = np.array([known[i] for i in ids])
    u = np.linalg.norm(p - o, axis=1)
    assert g["max_deformation"] == pytest.approx(u.max(), rel=1e-6)
    assert g["max_deformation_particle"] == int(ids[np.argmax(u)])
    assert g["max_deformation_at"][0] == pytest.approx(100.0)
    assert g["max_deformation"] == pytest.approx(0.576, rel=0.05)
    assert f"largest displacement={u.max():.4g}" in out


@pytest.mark.lammps
def test_the_surface_file_carries_the_particles_values_onto_the_parts_faces(cantilever):
    """``vtk/surface.vtp``: the bar's own faces (x = 0, 100; y, z = ±5 mm) with ``von_mises``,
    ``displacement`` and ``group_id``. On the top face at mid-span the surface's stress is
    beam theory's at the surface, M·c/I = 100·50·5/(10⁴/12) = 30 MPa (within 5 %), above the
    particles' layer at z = 4 (24 MPa): extrapolated to the face, not averaged inwards; the
    free end's deflection is beam theory's 0.576 mm (within 5 %)."""
    import pyvista as pv

    d, _ = cantilever
    m = pv.read(d / "vtk" / "surface.vtp")
    assert {"von_mises", "displacement", "group_id"} <= set(m.point_data.keys())
    assert m["displacement"].shape == (m.n_points, 3) and m.n_cells > 1000
    P = np.asarray(m.points)
    assert P[:, 2].max() == pytest.approx(5.0, abs=0.05) and P[:, 1].min() == pytest.approx(
        -5.0, abs=0.05)
    # the end faces too, though the lattice's particles sit on them (x = 0 and 100: their
    # cells half outside the bar, which their volumes say)
    assert P[:, 0].min() == pytest.approx(0.0, abs=0.1) and P[:, 0].max() == pytest.approx(
        100.0, abs=0.1)
    top = (np.abs(P[:, 0] - 50) < 1) & (P[:, 2] > 4.9) & (np.abs(P[:, 1]) < 3)
    assert top.sum() > 10
    assert m["von_mises"][top].mean() == pytest.approx(30.0, rel=0.05)
    # not averaged inwards: the outer layer's centres (z = 4) carry M·z/I = 24 MPa; the
    # particles' own (patch-recovered) values are read on the face, as the surface's are
    parts = pv.read(sorted((d / "vtk").glob("frame_*.vtp"))[-1])
    layer = (np.abs(parts["original"][:, 0] - 50) < 1) & (parts["original"][:, 2] > 3.9)
    assert m["von_mises"][top].mean() > 24.0 + 3.0
    assert m["von_mises"][top].mean() == pytest.approx(parts["von_mises"][layer].mean(),
                                                       rel=0.05)
    tip = P[:, 0] > P[:, 0].max() - 0.5
    assert -m["displacement"][tip, 2].mean() == pytest.approx(0.576, rel=0.05)


@pytest.mark.lammps
def test_the_surface_fit_is_exact_on_a_linear_field(cantilever):
    """The fit that carries values onto the surface reproduces any field linear in position
    (here v = 3 + 2x − y + 0.5z, and a rotation's displacement) at the run's own surface
    points from its own particles, to rounding."""
    import pyvista as pv

    from rackstress.stress.surface import interpolate

    d, _ = cantilever
    P = np.asarray(pv.read(d / "vtk" / "surface.vtp").points, dtype=float)
    o = np.array(list(originals(d).values()))

    def lin(x):
        return 3 + 2 * x[:, 0] - x[:, 1] + 0.5 * x[:, 2]

    assert np.abs(interpolate(o, lin(o), P, 2.0) - lin(P)).max() < 1e-6 * np.abs(lin(P)).max()
    w = np.array([0.01, -0.02, 0.03])                  # a small rotation: u = w × x
    got = interpolate(o, np.cross(w, o), P, 2.0)
    assert np.abs(got - np.cross(w, P)).max() < 1e-8


@pytest.mark.lammps
def test_the_3d_view_shows_the_surface_and_the_particles_one_click_away(cantilever):
    from test_view3d import parse

    d, _ = cantilever
    page = parse(d / "view3d.html")
    info = json.loads(next(t for a, t in page.scripts if a.get("id") == "rs-frames"))
    assert info["roles"]["surface"] and info["roles"]["particles"]
    assert [a.get("type") for tag, a in page.tags if tag == "input"] == ["checkbox"] * 3
    what = Page(d / "report.html").by_id["view3d-what"]["attrs"]
    assert int(what["data-shown"]) == 1275 and int(what["data-triangles"]) > 1000
    manifest = json.loads((d / "figures" / "render.json").read_text())
    assert float(what["data-magnification"]) == manifest["magnification"]


def test_a_surface_beyond_the_pages_budget_is_decimated_to_it(cantilever, tmp_path,
                                                              monkeypatch):
    """A static view's surface of more than ``view3d.MAX_TRIANGLES`` is decimated for the
    page (vtkDecimatePro, topology kept) to that many: here the cantilever's surface with the
    budget set to a fifth of its triangles, its 1,275 particles still shown. (A public 1.2 mm slot cover's 481,779 triangles
    took vtkQuadricDecimation past 10 minutes.)"""
    import shutil

    from rackstress.render import view3d

    d, _ = cantilever
    run = tmp_path / "run"
    shutil.copytree(d, run)
    full = view3d.build_static_view(run)["triangles"]
    monkeypatch.setattr(view3d, "MAX_TRIANGLES", full // 5)
    got = view3d.build_static_view(run)
    assert 0.9 * (full // 5) <= got["triangles"] <= full // 5, (full, got["triangles"])
    assert got["shown"] == 1275 and (run / "view3d.html").stat().st_size > 10_000


# ----------------------------------------------------------------------------- reactions
@pytest.mark.lammps
@pytest.mark.mpi
def test_reactions_per_support_balance_the_load_by_hand(tmp_path):
    """The cantilever's clamp split into three supports (y < 0, y > 0, the middle row), under
    ``mpiexec -n 2``. By hand: the load is (0, 0, −100) N at x = 100 mm, its moment about the
    origin r × F = (0, 100·100, 0) N·mm; the reactions sum to minus both; by the bar's symmetry
    in y the two outer supports carry equal vertical forces and opposite moments about x.
    Within the settle tolerance: each free particle is left at most residual × load
    unbalanced."""
    text = CANTILEVER.read_text()
    clamp = 'where = { box = { min = [-0.01, -6, -6], max = [0.01, 6, 6] } }'
    assert clamp in text
    split = "\n".join(f'[[support]]\non = "bar"\nwhere = {{ box = {{ min = [-0.01, {lo}, -6], '
                      f'max = [0.01, {hi}, 6] }} }}\n' for lo, hi in
                      ((-6, -0.5), (0.5, 6), (-0.5, 0.5)))
    text = text.replace(f'[[support]]                # clamped: the end face at x = 0 held in '
                        f'every direction\non = "bar"\n{clamp}\n', split)
    assert text.count("[[support]]") == 3
    scene = tmp_path / "split.toml"
    scene.write_text(text)
    d = tmp_path / "run"
    r = mpi_rs("run", scene, "--set", "spacing=2", "--out", d, "--no-progress", "--no-render",
               timeout=300)
    assert r.returncode == 0, r.stderr
    s = summary(d)
    assert s["ranks"] == 2 and s["settled"]
    R = {x["support"]: x for x in s["reactions"]}
    assert list(R) == ["[[support]] #1", "[[support]] #2", "[[support]] #3"]
    # 5 × 5 particles on the clamped face at spacing 2 (y, z = −4 … 4): 2 rows of 5 either side
    assert [R[k]["particles"] for k in R] == [10, 10, 5]
    F = np.sum([x["force"] for x in s["reactions"]], axis=0)
    M = np.sum([x["moment"] for x in s["reactions"]], axis=0)
    bound = s["residual"] * 100.0 * s["n_particles"]      # what settling leaves, at most
    assert np.allclose(s["applied_load"]["force"], [0, 0, -100], atol=1e-9)
    assert np.allclose(F, [0, 0, 100], atol=bound)
    assert np.allclose(s["applied_load"]["moment"], [0, 100 * 100, 0], rtol=1e-4, atol=1e-6)
    assert np.allclose(M, [0, -100 * 100, 0], atol=1e-4 * 100 * 100)
    assert np.allclose(F + s["applied_load"]["force"], 0, atol=bound)
    assert np.allclose(M + s["applied_load"]["moment"], 0, atol=bound * 101)
    a, b = R["[[support]] #1"], R["[[support]] #2"]
    assert a["force"][2] == pytest.approx(b["force"][2], rel=1e-6)
    assert a["moment"][0] == pytest.approx(-b["moment"][0], rel=1e-6)
    assert "reactions' sum" in r.stdout


# ----------------------------------------------------------------------------- not settled
@pytest.fixture(scope="module")
def unsettled(tmp_path_factory):
    """The tiny load that cannot settle, under ``mpiexec -n 2``, rendered."""
    base = tmp_path_factory.mktemp("unsettled")
    (base / "tiny.toml").write_text(TINY)
    d = base / "run"
    r = mpi_rs("run", base / "tiny.toml", "--out", d, "--no-progress", timeout=300)
    return d, r


@pytest.mark.lammps
@pytest.mark.mpi
def test_a_run_that_did_not_settle_says_so_first_and_withholds_its_numbers(unsettled):
    d, r = unsettled
    assert r.returncode == 6, r.stderr
    s = summary(d)
    assert s["status"] == "not settled" and s["ranks"] == 2
    value = s["stress"]["peak"]["value"]           # summary.json keeps its numbers
    page = Page(d / "report.html")
    banner = page.by_id["status"]
    assert banner["attrs"]["data-status"] == "not settled"
    assert "NOT SETTLED" in banner["text"] and "do not use these numbers" in banner["text"]
    assert f"{s['residual']:.3g}" in banner["text"] and "What to do" in banner["text"]
    head = page.by_id["headline"]
    assert head["attrs"].get("data-withheld") == "true" and "data-value" not in head["attrs"]
    assert "--allow-unsettled" in head["text"]
    assert not [a for tag, a in page.tags if tag == "tr" and "data-measure" in a]
    # the printed lines: no stress as a result
    assert "NOT SETTLED" in r.stdout
    assert "von Mises stress" not in r.stdout and "factor of safety" not in r.stdout.replace(
        "no stress or factor of safety is reported", "")
    # the pictures say it too; still the surface and the particles, nothing over time
    manifest = json.loads((d / "figures" / "render.json").read_text())
    assert manifest["settled"] is False
    assert sorted(p.name for p in (d / "figures").iterdir()) == ["particles.png", "render.json",
                                                                   "sheet.png"]
    assert (d / "vtk" / "surface.vtp").is_file()
    del value


@pytest.mark.lammps
@pytest.mark.mpi
def test_allow_unsettled_shows_the_numbers_marked(unsettled):
    d, r = unsettled
    assert r.returncode == 6, r.stderr
    s = summary(d)
    got = rs("render", d, "--allow-unsettled", "--no-progress", timeout=300)
    assert got.returncode == 0, got.stderr
    page = Page(d / "report.html")
    assert page.by_id["status"]["attrs"]["data-status"] == "not settled"
    head = page.by_id["headline"]
    assert float(head["attrs"]["data-value"]) == s["stress"]["peak"]["value"]
    assert "Not an equilibrium" in head["text"]
    again = rs("render", d, "--no-progress", timeout=300)          # withheld again without it
    assert again.returncode == 0, again.stderr
    assert Page(d / "report.html").by_id["headline"]["attrs"].get("data-withheld") == "true"


# ----------------------------------------------------------------------------- the rest
def test_rackstress_scenes_lists_no_time_for_a_static_scene():
    r = rs("scenes", CANTILEVER, ROOT / "examples" / "bracket" / "scene.toml")
    assert r.returncode == 0, r.stderr
    static, dynamic = r.stdout.split("examples/bracket/scene.toml")
    assert "spacing=1.0" in static and not re.search(r"\b(dt|steps|duration|cycles)=", static)
    assert "dt=0.01" in dynamic and "duration=3.0" in dynamic


def test_the_magnification_is_round_and_near_a_tenth_of_the_part():
    from rackstress.render.static import magnification

    # 0.1 × 101 mm / 0.576 mm = 17.5 → 20 (the nearest of 10, 20, 50 on a log scale)
    assert magnification(0.576, 101.0) == 20.0
    assert magnification(0.684, 30.0) == 5.0        # 4.39 → 5
    assert magnification(0.143, 142.2) == 100.0      # 99.4
    assert magnification(50.0, 100.0) == 1.0         # already a tenth of it and more: to scale
    assert magnification(0.0, 100.0) == 1.0


@pytest.mark.slow
@pytest.mark.lammps
def test_a_mesh_gone_since_the_run_falls_back_to_the_lattice_surface(tmp_path):
    """A static part from an STL (a 12 × 4 × 4 mm box written here) is painted on that STL; once
    the STL is gone, ``rackstress render`` paints the lattice's outer surface and says why
    (exit 0)."""
    import pyvista as pv

    pv.Box(bounds=(0, 12, 0, 4, 0, 4)).triangulate().save(tmp_path / "box.stl")
    (tmp_path / "box.toml").write_text(TINY.replace(
        'fill = { box = { min = [0, 0, 0], max = [20, 4, 4] } }', 'mesh = "box.stl"').replace(
        "[19.5, -1, -1], max = [21, 5, 5]", "[11, -1, -1], max = [13, 5, 5]").replace(
        "-1e-9", "-10"))
    d = tmp_path / "run"
    r = rs("run", tmp_path / "box.toml", "--out", d, "--no-progress", timeout=300)
    assert r.returncode == 0, r.stderr
    m = json.loads((d / "figures" / "render.json").read_text())
    assert m["surfaces"][0]["source"] == "its mesh box.stl"
    scene = json.loads((d / "scene.json").read_text())
    assert scene["groups"][0]["mesh"]["file"] == str((tmp_path / "box.stl").resolve())
    (tmp_path / "box.stl").unlink()
    r = rs("render", d, "--no-progress", timeout=300)
    assert r.returncode == 0, r.stderr
    assert "could not be read" in r.stdout and "lattice's outer surface" in r.stdout
    m = json.loads((d / "figures" / "render.json").read_text())
    assert m["surfaces"][0]["source"] == "the lattice's outer surface"


@pytest.mark.lammps
def test_frames_or_a_movie_of_a_static_run_is_refused(cantilever):
    d, _ = cantilever
    before = sorted(p.name for p in (d / "figures").iterdir())
    for opt in (["--movie"], ["--frames", "0,1"]):
        r = rs("render", d, *opt, "--no-progress", timeout=120)
        assert r.returncode == 2, r.stderr
        assert "is a static analysis: it has one state" in r.stderr and "Traceback" not in r.stderr
    assert sorted(p.name for p in (d / "figures").iterdir()) == before
