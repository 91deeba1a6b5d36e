"""Exploring a run: the peaks (summary.json, pictures, report, VTK, stress dump give one number),
the VTK time series read back by pyvista, the stress dump read by MDAnalysis and a plain parser,
plain LAMMPS runs that rackstress did not write, and report.html parsed by a real HTML parser.

Expected values come from the synthetic runs' construction (a rigid motion plus a known bump, a
uniform stretch with its analytic strain, a LAMMPS ``fix move`` with its known displacement),
not from the code under test.
"""
from __future__ import annotations

import json
import re
import math
from html.parser import HTMLParser

import numpy as np
import pytest
from click.testing import CliRunner

from rackstress.cli import main
from rackstress.lib import rigid
from rackstress.stress.post import postprocess
from test_stress import BLOCK, SHEET, lattice, rigid as rigid_motion, write_run

DT = 0.01
BUMP = np.array([0.0, 0.0, 0.7])          # the bump of BLOCK's particle 0 at iteration 20
STRETCH = 0.1                              # SHEET stretched by 1.1 along x at iteration 30


def _frames():
    """BLOCK moves rigidly and carries a bump of 0.3 then 0.7 on its particle 0 (id 1);
    SHEET stays, then is stretched uniformly along x (analytic strain)."""
    rot, t = [0.1, -0.2, 0.3], [1.0, 2.0, -0.5]
    frames = []
    for step, bump in ((0, 0.0), (10, 0.3), (20, 0.7), (30, 0.0)):
        pb = rigid_motion(BLOCK, rot if step else [0, 0, 0], t if step else [0, 0, 0])
        pb[0] += bump / 0.7 * BUMP
        ps = SHEET.copy()
        if step == 30:
            ps[:, 0] = SHEET[:, 0].min() + (SHEET[:, 0] - SHEET[:, 0].min()) * (1 + STRETCH)
        frames.append((step, np.concatenate([pb, ps])))
    return frames


@pytest.fixture
def synthetic(tmp_path):
    d = tmp_path / "run"
    frames = _frames()
    write_run(d, [("block", "part", BLOCK), ("sheet", "part", SHEET)], frames, dt=DT)
    (d / "summary.json").write_text(json.dumps({"scene": "synthetic", "status": "ok",
                                                "groups": {"block": {"n": len(BLOCK)},
                                                           "sheet": {"n": len(SHEET)}}}))
    return d, frames


# ----------------------------------------------------------------------------- one fit
def test_summary_max_deformation_is_the_robust_fit():
    o = lattice(5, 1, 5)
    p = rigid_motion(o, [0.2, 0.1, -0.3], [3.0, 1.0, 0.0])
    p[0] += [0.0, 1.0, 0.0]                              # a local bump of exactly 1
    assert rigid.max_deformation(o, p) == pytest.approx(1.0, abs=1e-12)
    # the plain fit is dragged by the bump: it reports less than the bump
    assert rigid.deformation(o, p).max() < 0.97
    assert rigid.max_deformation(o, rigid_motion(o, [1, 2, 3], [4, 5, 6])) < 1e-12


# ----------------------------------------------------------------------------- peaks
def test_peaks_where_and_when_and_into_summary(synthetic):
    d, frames = synthetic
    info = postprocess(d, vtk=False)
    peak = info["groups"]["block"]["paper"]
    assert peak["value"] == pytest.approx(0.7, abs=1e-12)
    assert peak["iteration"] == 20 and peak["particle"] == 1 and peak["index"] == 0
    np.testing.assert_allclose(peak["position"], frames[2][1][0], atol=1e-12)
    np.testing.assert_allclose(peak["original"], BLOCK[0], atol=0)
    # ∫ d dt by the trapezoid rule over t = 0, 0.1, 0.2, 0.3 with d = 0, 0.3, 0.7, 0
    acc = info["groups"]["block"]["accumulated"]
    assert acc["value"] == pytest.approx(0.5 * 0.1 * (0.3 + (0.3 + 0.7) + 0.7), abs=1e-12)
    assert acc["iteration"] == 30 and acc["particle"] == 1
    # the uniform stretch: η = E_xx/√3 with E_xx = ((1+e)² − 1)/2, everywhere on the sheet
    exx = 0.5 * ((1 + STRETCH) ** 2 - 1)
    strain = info["groups"]["sheet"]["strain"]
    assert strain["value"] == pytest.approx(exx / math.sqrt(3), rel=1e-9)
    assert strain["iteration"] == 30
    assert info["groups"]["sheet"]["d2min"]["value"] < 1e-20
    # summary.json: groups.<name>.peak.<measure>, and the overall peak
    summary = json.loads((d / "summary.json").read_text())
    assert summary["groups"]["block"]["peak"]["paper"] == peak
    assert summary["groups"]["block"]["n"] == len(BLOCK)            # kept
    top = max(info["groups"][g]["paper"]["value"] for g in ("block", "sheet"))
    assert summary["stress"]["peak"]["value"] == top
    # a dotted path reaches it (batch --report)
    from rackstress.runs.batch import lookup

    assert lookup(summary, "groups.block.peak.paper.value") == peak["value"]


# ----------------------------------------------------------------------------- VTK
def test_vtk_series_read_back_by_pyvista_equals_independent_values(synthetic):
    import pyvista as pv

    d, frames = synthetic
    postprocess(d, vtk=True, dump=False)
    reader = pv.get_reader(str(d / "vtk" / "run.pvd"))
    assert list(reader.time_values) == [0, 10, 20, 30]
    o = np.concatenate([BLOCK, SHEET])
    nb = len(BLOCK)
    exx = 0.5 * ((1 + STRETCH) ** 2 - 1)
    for step, p in frames:
        reader.set_active_time_value(step)
        mesh = reader.read()[0]
        assert mesh.n_points == len(p)
        np.testing.assert_array_equal(mesh.points, p.astype(np.float32))       # geometry: float32
        np.testing.assert_array_equal(mesh.point_data["displacement"], (p - o).astype(np.float32))
        np.testing.assert_array_equal(mesh.point_data["id"], np.arange(1, len(p) + 1))
        np.testing.assert_array_equal(mesh.point_data["group_id"], [0] * nb + [1] * len(SHEET))
        np.testing.assert_array_equal(mesh.point_data["group_block"], [1] * nb + [0] * len(SHEET))
        np.testing.assert_array_equal(mesh.point_data["group_sheet"], [0] * nb + [1] * len(SHEET))
        np.testing.assert_array_equal(mesh.point_data["type"], [1] * nb + [2] * len(SHEET))
        np.testing.assert_allclose(mesh.point_data["radius"], 0.5)   # touching, spacing 1
        paper = mesh.point_data["paper"]
        bump = {0: 0.0, 10: 0.3, 20: 0.7, 30: 0.0}[step]
        assert paper[0] == pytest.approx(bump, abs=1e-12)
        assert np.abs(paper[1:nb]).max() < 1e-12                  # the rest of the rigid block
        strain = mesh.point_data["strain"][nb:]
        expect = exx / math.sqrt(3) if step == 30 else 0.0
        np.testing.assert_allclose(strain, expect, atol=1e-12)
        for name in ("accumulated", "d2min", "displacement_magnitude", "original"):
            assert name in mesh.point_data
    assert "velocity" not in mesh.point_data                        # not dumped


def test_stress_dump_read_by_mdanalysis_and_a_plain_parser(synthetic):
    import MDAnalysis as mda

    d, frames = synthetic
    res = CliRunner().invoke(main, ["stress", str(d), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "peak paper" in res.output and (d / "stress.dump").is_file()
    assert (d / "vtk" / "run.pvd").is_file()
    # plain parser: named columns
    lines = (d / "stress.dump").read_text().splitlines()
    head = lines.index("ITEM: ATOMS id type mol x y z radius group dx dy dz paper accumulated "
                       "strain d2min")
    n = len(BLOCK) + len(SHEET)
    cols = lines[head].split()[2:]
    first = np.array([r.split() for r in lines[head + 1:head + 1 + n]], dtype=float)
    assert first.shape == (n, len(cols))
    np.testing.assert_array_equal(first[:, cols.index("paper")], 0.0)
    # MDAnalysis' own LAMMPS dump reader with the extra columns
    r = mda.coordinates.LAMMPS.DumpReader(str(d / "stress.dump"), additional_columns=True)
    assert r.n_frames == 4
    ts = r[2]
    assert ts.data["step"] == 20
    order = np.argsort(ts.data["id"]) if "id" in ts.data else np.arange(n)
    paper = np.asarray(ts.data["paper"])[order]
    assert paper[0] == pytest.approx(0.7, abs=1e-9) and np.abs(paper[1:len(BLOCK)]).max() < 1e-9
    np.testing.assert_allclose(np.asarray(ts.data["dz"])[order][0],
                               frames[2][1][0, 2] - BLOCK[0, 2], atol=1e-8)


# ----------------------------------------------------------------------------- plain LAMMPS
LAMMPS_SCRIPT = """
units lj
atom_style {style}
boundary f f f
lattice sc 1.0
region box block 0 4 0 3 0 2
create_box 2 box
create_atoms 1 box
region right block 2 4 0 3 0 2
set region right type 2
{mols}
mass * 1.0
pair_style zero 1.0
pair_coeff * *
write_data {data}
group one id 1
fix move one move linear 0.5 0.25 0.0
timestep {dt}
dump d all custom 10 {dump} id type xu yu zu vx vy vz
dump_modify d sort id
run {steps}
"""


def _plain_lammps(tmp_path, style="atomic", steps=40, dt=0.01):
    from rackstress.lib.mpi import lammps_module

    lammps = lammps_module().lammps
    data, dump = tmp_path / "plain.data", tmp_path / "plain.dump"
    mols = "set region box mol 1\nset region right mol 2" if style == "bond" else ""
    script = LAMMPS_SCRIPT.format(style=style, data=data, dump=dump, dt=dt, steps=steps,
                                  mols=mols)
    if style == "bond":
        script = script.replace("create_box 2 box", "create_box 2 box bond/types 1 "
                                                    "extra/bond/per/atom 1")
    lmp = lammps(cmdargs=["-log", "none", "-screen", "none"])
    try:
        lmp.commands_string(script)
    finally:
        lmp.close()
    return data, dump


@pytest.mark.lammps
def test_plain_lammps_data_and_dump_by_type(tmp_path):
    import pyvista as pv

    data, dump = _plain_lammps(tmp_path)
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["stress", str(data), str(dump), "--parts", "type", "--dt",
                                    "0.01", "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    info = json.loads((out / "stress.json").read_text())
    assert set(info["groups"]) == {"type1", "type2"}
    pk = info["groups"]["type1"]["paper"]
    # fix move linear (0.5, 0.25, 0) on atom 1 for 40 steps of 0.01: |displacement| = 0.4·|v|
    assert pk["value"] == pytest.approx(0.4 * math.hypot(0.5, 0.25), rel=1e-8)
    assert pk["iteration"] == 40 and pk["particle"] == 1
    assert info["groups"]["type2"]["paper"]["value"] < 1e-12
    reader = pv.get_reader(str(out / "vtk" / "run.pvd"))
    reader.set_active_time_value(reader.time_values[-1])
    mesh = reader.read()[0]
    np.testing.assert_allclose(mesh.point_data["velocity"][0], [0.5, 0.25, 0.0], atol=1e-12)
    assert np.abs(mesh.point_data["velocity"][1:]).max() == 0.0
    assert (out / "stress.dump").is_file()


@pytest.mark.lammps
def test_plain_lammps_parts_by_molecule(tmp_path):
    data, dump = _plain_lammps(tmp_path, style="bond")
    run_info = postprocess(None, run=__import__("rackstress.stress.foreign", fromlist=["x"])
                           .load_plain(data, dump, dt=0.01, outdir=tmp_path / "o"),
                           vtk=False, out=tmp_path / "o")
    assert set(run_info["groups"]) == {"mol1", "mol2"}
    assert run_info["groups"]["mol1"]["paper"]["particle"] == 1


def test_plain_input_errors_are_clear(tmp_path, synthetic):
    d, _ = synthetic
    res = CliRunner().invoke(main, ["stress", str(d / "particles.data"),
                                    str(d / "particles.data"), "--out", str(tmp_path / "x")])
    assert res.exit_code == 2 and "particles.data" in res.output
    bad = tmp_path / "bad.data"
    bad.write_text("LAMMPS data\n\n2 atoms\n\nAtoms # ellipsoid\n\n1 1 0 1 0 0 0\n2 1 0 1 1 0 0\n")
    res = CliRunner().invoke(main, ["stress", str(bad), str(d / "trajectory.dump"),
                                    "--out", str(tmp_path / "x")])
    assert res.exit_code == 2 and "atom style 'ellipsoid'" in res.output and "bad.data" in res.output


# ----------------------------------------------------------------------------- the report
class _Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.imgs, self.links, self.rows, self.ids = [], [], [], set()

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.add(a["id"])
        if tag == "img":
            self.imgs.append(a["src"])
        elif tag == "a":
            self.links.append(a["href"])
        elif tag == "tr" and "data-value" in a:
            self.rows.append(a)


@pytest.fixture(scope="module")
def plane_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("explore") / "pr"
    res = CliRunner().invoke(main, ["run", "plane-rack", "--steps", "150", "--dump-every", "3",
                                    "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    return out, res.output


@pytest.mark.lammps
def test_run_reports_one_peak_everywhere(plane_run):
    """summary.json, the pictures (render.json, colour scale), report.html, the VTK files and the
    stress dump give the same number for the peak."""
    import pyvista as pv
    from PIL import Image

    rundir, output = plane_run
    summary = json.loads((rundir / "summary.json").read_text())
    pk = summary["groups"]["plane"]["peak"]["paper"]
    assert f"peak paper = {pk['value']:.4g}" in output
    st = summary["groups"]["plane"]["peak"]["strain"]
    assert (f"plane        peak paper={pk['value']:.4g} (iteration {pk['iteration']}, particle "
            f"{pk['particle']}); strain={st['value']:.4g} (iteration {st['iteration']}, "
            f"particle {st['particle']})") in output
    # the pulled corner, early in the run (plane-rack peaks while the corner is pulled up)
    assert pk["iteration"] < 75 and np.linalg.norm(pk["original"]) < math.sqrt(10)
    # pictures: the peak frame is among the default frames and the scale covers it
    manifest = json.loads((rundir / "figures" / "render.json").read_text())
    assert manifest["peak"]["value"] == pk["value"] and manifest["vmax"] >= pk["value"]
    assert pk["iteration"] in [f["iteration"] for f in manifest["frames"] if f["peak"]]
    # the run paints what the report shows, the sheet (its peak column: the frames above);
    # the full-size picture of each view and frame is 'rackstress render RUNDIR' away
    assert "sheet.png" in manifest["files"]
    assert not list((rundir / "figures").glob("right_*.png"))
    # the sheet, stress_over_time.png and com_path.png (no sediment: no footprints)
    assert summary["render"]["wall_s"] > 0 and summary["render"]["pictures"] == 3
    # VTK: the largest 'paper' over every frame is the same value at the same iteration/particle
    reader = pv.get_reader(str(rundir / "vtk" / "run.pvd"))
    best = (-1.0, None, None)
    plane = None
    for t in reader.time_values:
        reader.set_active_time_value(t)
        m = reader.read()[0]
        sel = m.point_data["group_plane"] == 1
        plane = sel
        v = m.point_data["paper"][sel]
        if v.max() > best[0]:
            best = (float(v.max()), int(t), int(m.point_data["id"][sel][np.argmax(v)]))
    assert plane.sum() == 400
    assert best == (pk["value"], pk["iteration"], pk["particle"])
    # the report: a real HTML parser; every image exists and decodes; the table is summary.json's
    page = _Page()
    page.feed((rundir / "report.html").read_text())
    assert {"peak", "peaks", "pictures", "facts", "scene", "stability", "files"} <= page.ids
    assert "figures/sheet.png" in page.imgs and len(page.imgs) >= 3
    for src in page.imgs:
        with Image.open(rundir / src) as im:
            im.load()
            assert im.size[0] > 100
    assert "vtk/run.pvd" in page.links
    for href in page.links:
        assert (rundir / href).is_file(), href
    table = {(r["data-group"], r["data-measure"]): r for r in page.rows}
    # racks carry no stress (docs/scenes.md): the plane has peaks, the racks none
    assert {g for g, grec in summary["groups"].items() if "peak" in grec} == {"plane"}
    expected = {(g, m): rec for g, grec in summary["groups"].items()
                for m, rec in grec.get("peak", {}).items() if rec is not None}
    assert set(table) == set(expected)
    for key, rec in expected.items():
        row = table[key]
        assert float(row["data-value"]) == rec["value"]
        assert int(row["data-iteration"]) == rec["iteration"]
        assert int(row["data-particle"]) == rec["particle"]
    # the stability margin of Eq. 5 (plane-rack is predicted stable at t = 0.01)
    html = (rundir / "report.html").read_text()
    assert "× margin" in html and "within the limit" in html
    # the pictures' time of this very run, and the scene's phase cut by --steps 150
    assert re.search(r"<th>pictures \[s\]</th><td>[0-9.]+</td>", html)
    phase = json.loads((rundir / "scene.json").read_text())["phases"][0]
    assert phase["steps"] > 150
    assert f"(150 of its {phase['steps']} iterations run: the run stopped at iteration 150)" in html


@pytest.mark.lammps
def test_batch_jobs_get_peaks_and_report_shows_them(tmp_path):
    sw = tmp_path / "s.toml"
    sw.write_text('scene = "plane-rack"\nsteps = 60\ndump_every = 3\n'
                  '[grid]\nplane_bind = [50.0, 100.0]\n')
    res = CliRunner().invoke(main, ["batch", str(sw), "--out", str(tmp_path / "b")])
    assert res.exit_code == 0, res.output
    index = json.loads((tmp_path / "b" / "batch.json").read_text())
    res = CliRunner().invoke(main, ["batch", "--report", str(tmp_path / "b"), "--figure",
                                    "groups.plane.peak.paper", "--against", "plane_bind"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[0].split() == ["name", "plane_bind", "status", "groups.plane.peak.paper.value",
                                "iteration", "particle", "wall_s"]
    for j in index["jobs"]:
        s = json.loads((tmp_path / "b" / j["dir"] / "summary.json").read_text())
        pk = s["groups"]["plane"]["peak"]["paper"]
        assert j["figures"]["groups.plane.peak.paper.value"] == pk["value"]
        row = next(ln.split() for ln in lines[1:] if ln.startswith(j["name"]))
        assert row[3:6] == [f"{pk['value']:.6g}", str(pk["iteration"]), str(pk["particle"])]


def test_too_large_for_memory_is_a_clear_error(synthetic, monkeypatch):
    from rackstress.stress import post

    d, _ = synthetic
    monkeypatch.setattr(post, "MAX_VALUES", 100)      # the synthetic run: 162 atoms × 4 frames
    with pytest.raises(post.TooLargeError) as ei:
        post.postprocess(d)
    msg = str(ei.value)
    assert "trajectory.dump" in msg and "162 particles × 4 frames" in msg and "--dump-every" in msg
    assert not (d / "stress.json").exists()
