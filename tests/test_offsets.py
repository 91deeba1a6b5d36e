"""``rackstress run --offsets N``: the same part on lattices moved within a spacing. Expected
values from geometry (which lattice sites a box holds, by how much a lattice moved) and from
R₃'s definition (its generator the root of x⁴ = x + 1, found here by numpy's polynomial roots,
not by the code under test)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rackstress.model.particles import fill
from rackstress.model.regions import Box


def _r3(n: int) -> np.ndarray:
    """k·(1/g, 1/g², 1/g³) mod 1, g the real root of x⁴ − x − 1 above 1 (Roberts' R₃)."""
    roots = np.roots([1, 0, 0, -1, -1])
    g = max(r.real for r in roots if abs(r.imag) < 1e-12)
    return np.mod(np.arange(n)[:, None] * g ** -np.arange(1.0, 4.0)[None, :], 1.0)


def test_a_moved_lattice_holds_the_sites_geometry_gives():
    """A 4 × 2 × 2 box at spacing 1: centred, its sites are at ½, 1½ … (16 of them); moved by
    ¼ spacing on every axis they are at ¾, 1¾ …: still 4 × 2 × 2 (−¼ lies outside), the first
    at (¾, ¾, ¾); moved by (0.9, 0, 0) the x sites are 0.5 + 0.9 − 1 = 0.4 … 3.4: 4 again."""
    box = Box([0, 0, 0], [4, 2, 2])
    o = fill(box, 1.0, shift=[0.25, 0.25, 0.25])
    assert len(o) == 16
    np.testing.assert_allclose(o.min(axis=0), [0.75, 0.75, 0.75])
    np.testing.assert_allclose(o.max(axis=0), [3.75, 1.75, 1.75])
    o = fill(box, 1.0, shift=[0.9, 0.0, 0.0])
    np.testing.assert_allclose(sorted(set(np.round(o[:, 0], 9))), [0.4, 1.4, 2.4, 3.4])
    # an origin given is moved too
    o = fill(box, 1.0, origin=[0.5, 0.5, 0.5], shift=[0.0, 0.0, 0.3])
    np.testing.assert_allclose(sorted(set(np.round(o[:, 2], 9))), [0.8, 1.8])


BAR = """
name = "bar"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "bar"
mesh = "bar.stl"
spacing = 1.0
material = "aluminium"
[[support]]
on = "bar"
where = {{ face = {{ near = [0, 3, 3] }} }}
fix = ["x"]
[[support]]
on = "bar"
where = {{ face = {{ near = [15, 0, 3] }} }}
fix = ["y"]
[[support]]
on = "bar"
where = {{ face = {{ near = [15, 3, 0] }} }}
fix = ["z"]
[[load]]
on = "bar"
where = {{ face = {{ near = [30, 3, 3] }} }}
pressure = {p}
normal = [1, 0, 0]
"""


@pytest.fixture
def bar(tmp_path):
    """A 30 × 6 × 6 mm bar (an STL, so that its faces select the same layers wherever the
    lattice falls) on rollers on three faces, pulled by 10 MPa on its far end."""
    import trimesh

    b = trimesh.creation.box([30, 6, 6])
    b.apply_translation([15, 3, 3])
    b.export(tmp_path / "bar.stl")
    (tmp_path / "bar.toml").write_text(BAR.format(p=-10.0))
    return tmp_path / "bar.toml"


def test_offsets_run_the_part_on_moved_lattices_and_give_the_spread(bar, tmp_path):
    from test_faults import QUIET, rs

    out = tmp_path / "run"
    p = rs("run", bar, "--offsets", 3, "--out", out, *QUIET)
    assert p.returncode == 0, p.stderr
    summary = json.loads((out / "summary.json").read_text())
    off = summary["stress"]["offsets"]
    want = _r3(3)
    o0 = _positions(out)
    assert len(off["rows"]) == 3 and off["unsettled"] == 0
    for k in (1, 2):
        d = out / "offsets" / str(k)
        s = json.loads((d / "summary.json").read_text())
        assert s["settled"] is True
        o = _positions(d)
        # every axis of a 30 × 6 × 6 box holds 30, 6, 6 sites at any offset that is not
        # a whole spacing (geometry): 1,080 particles
        assert len(o) == 1080 == s["n_particles"]
        # moved by the offset: the sites' fractional positions differ by it (mod 1)
        moved = np.mod(o.min(axis=0) - o0.min(axis=0), 1.0)
        np.testing.assert_allclose(moved, want[k], atol=1e-9)
        assert off["rows"][k]["offset"] == pytest.approx(want[k].tolist(), abs=1e-12)
        assert off["rows"][k]["dir"] == f"offsets/{k}"
    # the first reading is the run's own governing stress; the spread is the readings'
    values = [r["value"] for r in off["rows"]]
    assert values[0] == summary["stress"]["governing"]["value"]
    assert off["median"] == pytest.approx(float(np.median(values)))
    assert (off["low"], off["high"]) == (min(values), max(values))
    assert off["spread"] == pytest.approx(max(abs(v / np.median(values) - 1) for v in values))
    # the bar carries 10 MPa (the load over its section, 360 N / 36 mm²) at every offset: no
    # reading is below it by more than the lattice's in-section scatter, none reads twice it
    assert all(8.0 < v < 20.0 for v in values), values
    assert "lattice offsets within a spacing" in p.stdout
    # whether the band the run prints holds them all
    band = summary["stress"]["error"]
    holds = band["low"] <= min(values) and max(values) <= band["high"]
    assert off["band_holds"] is holds and off["band"] == [band["low"], band["high"]]
    assert ("the error band holds every one" in p.stdout) is holds
    # again, on the finished run: nothing is solved again, the same readings
    stamp = (out / "offsets" / "1" / "summary.json").stat().st_mtime_ns
    p = rs("run", "--resume", out, "--offsets", 3, *QUIET)
    assert p.returncode == 0, p.stderr
    assert (out / "offsets" / "1" / "summary.json").stat().st_mtime_ns == stamp
    again = json.loads((out / "summary.json").read_text())["stress"]["offsets"]
    assert [r["value"] for r in again["rows"]] == values
    # the report lists every lattice's reading
    p = rs("render", out)
    assert p.returncode == 0, p.stderr
    page = (out / "report.html").read_text()
    table = page.split('<table id="offsets">')[1].split("</table>")[0]
    assert table.count("<tr>") == 4 and "offsets/2" in table
    assert f"{values[2]:.4g}" in table and 'id="offsets-spread"' in page


def _positions(rundir) -> np.ndarray:
    """The particles' positions from a run's LAMMPS data file (its Atoms section, atom style
    bond: id, molecule, type, x, y, z)."""
    lines = (rundir / "particles.data").read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("Atoms")) + 2
    rows = []
    for line in lines[start:]:
        if not line.strip():
            break
        rows.append([float(x) for x in line.split()])
    a = np.array(rows)
    return a[:, 3:6]


def test_a_moved_lattice_that_cannot_be_loaded_is_named_and_left_out(bar, tmp_path):
    """The load on a slab 29.4 < x < 31 holds the centred lattice's last layer (x = 29.5); moved
    by 0.819 and 0.638 spacings along x the last layers are at 29.319 and 29.138 (geometry):
    the slab holds no particle, the scene is refused for those lattices, and the run says so
    and keeps the first."""
    from test_faults import QUIET, rs

    text = bar.read_text().replace("where = { face = { near = [30, 3, 3] } }\npressure = -10.0"
                                   "\nnormal = [1, 0, 0]",
                                   "where = { box = { min = [29.4, -1, -1], max = [31, 7, 7] } }"
                                   "\nforce = [360, 0, 0]")
    assert "force = [360" in text
    slab = bar.with_name("slab.toml")
    slab.write_text(text)
    out = tmp_path / "slab"
    p = rs("run", slab, "--offsets", 3, "--out", out, *QUIET)
    assert p.returncode == 0, p.stderr
    off = json.loads((out / "summary.json").read_text())["stress"]["offsets"]
    assert off["refused"] == 2 and off["unsettled"] == 0
    assert [("selects no particle" in r.get("refused", "")) for r in off["rows"]] == \
        [False, True, True]
    assert off["values"] == [off["rows"][0]["value"]] and off["spread"] == 0.0
    assert "2 moved lattice(s) could not hold the part" in p.stdout


def test_offsets_are_refused_where_nothing_can_be_moved(bar, tmp_path):
    from test_faults import QUIET, rs

    p = rs("run", "plane-rack", "--offsets", 2, "--out", tmp_path / "r", *QUIET)
    assert p.returncode == 2 and "built-in scene: --offsets" in p.stderr
    assert not (tmp_path / "r").exists()
    p = rs("run", bar, "--offsets", 1, "--out", tmp_path / "r", *QUIET)
    assert p.returncode == 2 and "--offsets" in p.stderr
    assert not (tmp_path / "r").exists()


def test_bench_offsets_reads_a_part_against_bench_parts_fe(tmp_path):
    """``rackstress bench offsets --only hip --offsets 2``: the SOLO-12 hip on its own lattice
    and one moved one; each reading over the FE reference ``bench parts`` converged for it
    (docs/benchmarks/parts.json), and the page says the counts of its one row."""
    from pathlib import Path

    from test_faults import rs

    p = rs("bench", "offsets", "--only", "hip", "--offsets", 2, "--out", tmp_path)
    assert p.returncode == 0, p.stderr
    data = json.loads((tmp_path / "offsets.json").read_text())
    parts = json.loads((Path(__file__).parents[1] / "docs" / "benchmarks" / "parts.json")
                       .read_text())
    fe = next(r for r in parts["rows"] if r["part"] == "solo12-hip")["fe_reference_mpa"]
    (row,) = data["rows"]
    assert row["part"] == "solo12-hip" and row["fe_mpa"] == fe and len(row["values"]) == 2
    assert row["ratios"] == pytest.approx([v / fe for v in row["values"]], rel=1e-12)
    assert row["range_holds_fe"] is (min(row["values"]) <= fe <= max(row["values"]))
    # on its own lattice a run reads its own governing stress: the first is the first reading
    assert row["own"][0]["value"] == row["values"][0]
    assert row["own_bands_hold_fe"] == sum(o["low"] <= fe <= o["high"] for o in row["own"] if o)
    within = sum(abs(v / fe - 1) < 0.1 for v in row["values"])
    assert data["readings_within"] == within and data["readings"] == 2
    md = (tmp_path / "offsets.md").read_text()
    assert f"{within} of 2 are within 10 %" in md and "| solo12-hip | 3.2 |" in md
