"""The command line on the reference engine: run directory, summary.json, divergence, bad input."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import dump_text, trajectory
from click.testing import CliRunner

from rackstress import scenes
from rackstress.cli import main
from rackstress.engines.reference import Reference

REPO = Path(__file__).resolve().parents[1]


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def read_frames(path: Path):
    """Parse a LAMMPS dump into [(timestep, array n×6)], insisting every frame is complete."""
    lines = dump_text(path).splitlines()
    frames, k = [], 0
    while k < len(lines):
        assert lines[k] == "ITEM: TIMESTEP", (k, lines[k])
        step = int(lines[k + 1])
        assert lines[k + 2] == "ITEM: NUMBER OF ATOMS"
        n = int(lines[k + 3])
        assert lines[k + 4].startswith("ITEM: BOX BOUNDS")
        assert lines[k + 8].split()[:3] == ["ITEM:", "ATOMS", "id"]
        rows = lines[k + 9:k + 9 + n]
        assert len(rows) == n, f"frame at step {step} is truncated"
        table = np.array([[float(x) for x in r.split()] for r in rows])
        assert table.shape == (n, 6)
        frames.append((step, table))
        k += 9 + n
    return frames


@pytest.mark.slow
def test_run_plane_rack_writes_summary(tmp_path):
    out = tmp_path / "run"
    res = invoke("run", "plane-rack", "--engine", "reference", "--steps", 50, "--out", out,
                 "--no-progress")
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["scene"] == "plane-rack"
    assert s["engine"] == "reference"
    assert s["status"] == "ok"
    assert s["n_particles"] == 406          # 20 × 20 plane + 6 rack particles
    assert s["steps"] == 50
    assert s["dt"] == 0.01
    assert s["wall_s"] > 0
    g = s["groups"]
    assert set(g) == {"plane", "planerack"}
    assert g["plane"]["n"] == 400 and g["planerack"]["n"] == 6
    # lattice 0..19 in x and z, y = 0: centre (9.5, 0, 9.5); the racks sit symmetrically
    # around the same box centre (Eq. 21), so their mean is the same point.
    np.testing.assert_allclose(g["plane"]["com_start"], [9.5, 0.0, 9.5], atol=1e-12)
    np.testing.assert_allclose(g["planerack"]["com_start"], [9.5, 0.0, 9.5], atol=1e-12)
    assert g["plane"]["com_end"][1] > 0.0           # pulled up (+y)
    for name in g:
        assert 0.0 <= g[name]["max_deformation"] < 5.0

    # the run directory agrees with itself and with a direct 50-step reference run
    frames = read_frames(trajectory(out))
    assert frames[0][0] == 0 and frames[-1][0] == 50
    last = frames[-1][1]
    np.testing.assert_allclose(last[:400, 3:].mean(axis=0), g["plane"]["com_end"], atol=1e-8)
    ref = Reference(scenes.build("plane-rack"))
    for _ in range(50):
        ref.step({})
    np.testing.assert_allclose(ref.p[:400].mean(axis=0), g["plane"]["com_end"], atol=1e-12)


def test_run_toml_scene(tmp_path):
    out = tmp_path / "tb"
    res = invoke("run", REPO / "scenes" / "two-blobs.toml", "--engine", "reference", "--steps",
                 20, "--out", out, "--no-progress")
    assert res.exit_code == 0, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["scene"] == "two-blobs" and s["steps"] == 20 and s["n_particles"] == 66
    # blob a is pushed in +x, b in −x (no contact yet after 20 steps)
    assert s["groups"]["a"]["com_end"][0] > s["groups"]["a"]["com_start"][0]
    assert s["groups"]["b"]["com_end"][0] < s["groups"]["b"]["com_start"][0]


def test_divergence_exit_code_and_summary(tmp_path):
    out = tmp_path / "div"
    res = invoke("run", "plane-bound", "--engine", "reference", "--set", "d=100",
                 "--set", "magnitude=100", "--steps", 150, "--dump-every", 5, "--out", out,
                 "--no-progress", "--allow-unstable")
    assert res.exit_code == 3, res.output
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "diverged"
    err = s["error"]
    assert 1 <= err["step"] <= 150
    assert err["group"] == "plane"
    assert 0 <= err["particle"] < 400
    assert s["steps"] == err["step"]
    frames = read_frames(trajectory(out))        # every frame complete
    steps = [f[0] for f in frames]
    # frames every 5 steps from 0 up to the last multiple of 5 before the failing step
    assert steps == list(range(0, (err["step"] - 1) // 5 * 5 + 1, 5))
    assert all(np.isfinite(f[1]).all() for f in frames)


def test_bad_input_exit_code(tmp_path):
    res = invoke("run", REPO / "scenes" / "two-blobs.toml", "--engine", "reference",
                 "--set", "radius=2", "--out", tmp_path / "x", "--no-progress")
    assert res.exit_code == 2
    assert "two-blobs.toml" in res.output and "radius" in res.output
    res = invoke("run", "plane-rack", "--engine", "reference", "--set", "nosuch=1",
                 "--out", tmp_path / "y", "--no-progress")
    assert res.exit_code == 2
    assert "nosuch" in res.output


@pytest.mark.parametrize("bad", ["steps = = 1\n", 'name = "x"\n[[group]]\nname = "g"\n'
                                 'positions = [[0, 0, 0]]\nradius = -1\n'])
def test_bad_toml_via_cli(tmp_path, bad):
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    res = invoke("run", path, "--engine", "reference", "--out", tmp_path / "z", "--no-progress")
    assert res.exit_code == 2
    assert "bad.toml" in res.output
    assert not (tmp_path / "z" / "summary.json").exists()
