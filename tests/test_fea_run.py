"""``rackstress fea RUNDIR`` end to end: a real run (reference engine), the FEA of its part in a
real process, its files, its report section, and a directory that is not a run."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

SCENE = """
name = "beam3d"
dt = 0.05
steps = 60

[[group]]
name = "beam"
fill = { box = { min = [0, 0, 0], max = [12, 3, 3] } }
spacing = 1.0
held = { box = { min = [-1, -1, -1], max = [1, 4, 4] } }

[[operator]]
on = "beam"
op = "bind"
from = "beam"
c = 20.0
within = 1.5
inside = { box = { min = [0, 0, 0], max = [12, 3, 3] } }

[[operator]]
on = "beam"
op = "force"
accel = [0, 0, -0.01]
where = { box = { min = [11, -1, -1], max = [13, 4, 4] } }

[[operator]]
on = "beam"
op = "dampen"
c = 0.5
"""


def _cli(*args):
    exe = Path(sys.executable).with_name("rackstress")
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("fea")
    (d / "beam.toml").write_text(SCENE)
    r = _cli("run", str(d / "beam.toml"), "--engine", "reference", "--out", str(d / "run"),
             "--no-progress", "--no-render")
    assert r.returncode == 0, r.stderr
    return d / "run"


def test_fea_of_a_run_writes_its_check(run):
    import pyvista as pv

    r = _cli("fea", str(run), "--allow-dynamic")
    assert r.returncode == 0, r.stderr
    assert "Spearman" in r.stdout
    data = json.loads((run / "fea.json").read_text())
    # 12 × 3 × 3 particles at spacing 1 (x = 0.5 … 11.5); 9 held at x = 0.5, whose cells
    # x 0 … 1 hold 2 × 4 × 4 FE nodes; 9 loaded at x = 11.5 with 0.01 each (unit mass)
    assert data["particles"] == 108 and data["held_particles"] == 9
    assert data["fixed_fe_nodes"] == 32 and data["loaded_particles"] == 9
    assert data["total_force"] == pytest.approx([0, 0, -0.09])
    assert data["fe_total_force"] == pytest.approx([0, 0, -0.09])
    # every run writes boundary.npz (CONTRACT.md): its held ids and per-particle forces are
    # the ones counted above (9 held, 9 × 0.01 loaded)
    assert data["boundary"] == "boundary.npz"
    assert data["measure"] == "strain" and data["agreement"]["peak_ratio"] is None
    cloud = pv.read(run / "vtk" / "fea.vtp")
    assert cloud.n_points == 108
    assert cloud.point_data["fea_displacement"].shape == (108, 3)
    vm = np.asarray(cloud.point_data["fea_von_mises"])
    # bending: the largest stress at the held end's top or bottom fibre, not at the tip
    o = np.asarray(cloud.points)
    assert o[np.argmax(vm), 0] < 3 and o[np.argmax(vm), 2] in (0.5, 2.5)
    assert (run / "figures" / "fea.png").is_file() and (run / "vtk" / "fea_mesh.vtu").is_file()
    assert "Finite-element check" in (run / "report.html").read_text()


def test_fea_refuses_a_dynamic_run(run):
    """The beam is a dynamic run (its last frame a moving state): exit 2 naming it and the
    way out (analysis = "static", or --allow-dynamic, which labels the comparison)."""
    r = _cli("fea", str(run))
    assert r.returncode == 2, r.stderr
    assert "a dynamic run" in r.stderr and "--allow-dynamic" in r.stderr
    assert 'analysis = "static"' in r.stderr and "Traceback" not in r.stderr
    if (run / "fea.json").is_file():
        data = json.loads((run / "fea.json").read_text())
        assert data["compared"].startswith("the last frame of a dynamic run")


def test_fea_of_a_directory_that_is_not_a_run(tmp_path):
    r = _cli("fea", str(tmp_path))
    assert r.returncode == 2
    assert "no summary.json" in r.stderr and not (tmp_path / "fea.json").exists()


def test_boundary_npz_is_used_when_present(run, tmp_path):
    """boundary.npz (CONTRACT.md, written by runs of material scenes) takes precedence over
    the scene: the same supports and twice the load give twice FEA's stress (linearity)."""
    import shutil

    first = json.loads((run / "fea.json").read_text()) if (run / "fea.json").is_file() else None
    if first is None:
        assert _cli("fea", str(run), "--allow-dynamic").returncode == 0
    base = np.load(run / "fea.npz")["fea_von_mises"]
    twin = tmp_path / "twin"
    shutil.copytree(run, twin)
    o_ids = np.arange(1, 109)
    x = (o_ids - 1) % 12                       # a filled part's id order: x fastest
    np.savez(twin / "boundary.npz", held_ids=o_ids[x == 0].astype(np.int64),
             held_mask=np.ones((9, 3), bool), load_ids=o_ids[x == 11].astype(np.int64),
             load_force=np.tile([0.0, 0.0, -0.02], (9, 1)), units=np.str_("paper"))
    r = _cli("fea", str(twin), "--allow-dynamic")
    assert r.returncode == 0, r.stderr
    data = json.loads((twin / "fea.json").read_text())
    assert data["boundary"] == "boundary.npz"
    assert data["total_force"] == pytest.approx([0, 0, -0.18])
    assert np.load(twin / "fea.npz")["fea_von_mises"] == pytest.approx(2 * base, rel=1e-6)
