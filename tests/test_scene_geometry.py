"""TOML scenes with parts from meshes and shapes, regions, supports, [params] and duration.

Expected values by hand or from geometry: lattice counts, volumes, the selections of simple
shapes, steps = duration / dt.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from rackstress.errors import SceneError
from rackstress.runs.sweep import load_sweep
from rackstress.scenes.toml import load_toml
from conftest import HANG_S

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "bracket"
RACKSTRESS = Path(sys.executable).with_name("rackstress")


def write(tmp_path: Path, text: str, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def expect_error(path, needles, overrides=None):
    with pytest.raises(SceneError) as exc:
        load_toml(path, overrides or {})
    msg = str(exc.value)
    assert str(path) in msg, msg
    for needle in needles:
        assert needle in msg, (needle, msg)
    return msg


def box_stl(path: Path, extents=(4.0, 2.0, 3.0), at=(0.0, 0.0, 0.0)) -> Path:
    import trimesh
    m = trimesh.creation.box(extents=extents)
    m.apply_translation(np.asarray(at) + np.asarray(extents) / 2)
    m.export(path)
    return path


PARAMS = """
    name = "p"
    dt = 0.01
    steps = 10

    [params]
    n = 3
    gap = 1.5
    pull = 2.0

    [[group]]
    name = "a"
    lattice = { shape = ["$n", 1, 1], spacing = 1.0, origin = [0, 0, 0] }

    [[group]]
    name = "b"
    lattice = { shape = [2, 1, 1], spacing = 1.0, origin = ["$(n - 1 + gap)", 0, 0] }

    [[operator]]
    on = "a"
    op = "force"
    accel = ["$pull", 0, "$(-2 * pull)"]
"""


# ----------------------------------------------------------------------------- [params]
def test_params_referred_to_and_set(tmp_path):
    path = write(tmp_path, PARAMS)
    sc = load_toml(path)
    assert sc.groups["a"].n == 3
    assert sc.groups["b"].o[0].tolist() == [3.5, 0, 0]           # 3 − 1 + 1.5
    assert sc.operators["a"][0].accel == (2.0, 0.0, -4.0)
    assert sc.groups["a"].r.tolist() == [0.5] * 3                 # radius: spacing / 2
    assert sc.params["n"] == 3 and sc.params["gap"] == 1.5
    sc = load_toml(path, {"n": 5, "pull": 1.0, "dt": 0.02})
    assert sc.groups["a"].n == 5 and sc.groups["b"].o[0, 0] == 5.5
    assert sc.operators["a"][0].accel == (1.0, 0.0, -2.0)
    assert sc.params["n"] == 5 and sc.dt == 0.02


@pytest.mark.parametrize("overrides, needles", [
    ({"c": 1}, ["--set", "no parameter 'c'", "n=3, gap=1.5, pull=2.0"]),
    ({"n": "x"}, ["--set n", "must be a number"]),
    ({"n": 2.5}, ["shape", "integer"]),
])
def test_params_set_errors(tmp_path, overrides, needles):
    expect_error(write(tmp_path, PARAMS), needles, overrides)


@pytest.mark.parametrize("old, new, needles", [
    ('"$pull", 0', '"$pul", 0', ["operator", "accel[0]", "'pul'", "not in [params]"]),
    ('"$pull", 0', '"$(pull +)", 0', ["accel[0]", "not valid"]),
    ('"$pull", 0', '"$(__import__(1))", 0', ["accel[0]", "not allowed"]),
    ('"$pull", 0', '"$pull x", 0', ["accel[0]", "not a parameter reference"]),
    ("gap = 1.5", "dt = 1.5", ["[params] dt", "top-level setting"]),
    ("gap = 1.5", "gap = [1, 2]", ["[params] gap", "finite number, a string or a boolean"]),
    ('"$pull", 0', '"$(1 / (n - 3))", 0', ["accel[0]", "cannot be evaluated"]),
])
def test_param_reference_errors_name_the_field(tmp_path, old, new, needles):
    path = write(tmp_path, PARAMS.replace(old, new, 1))
    msg = expect_error(path, needles)
    assert msg.count(str(path)) == 1, msg           # one paragraph, the file named once


def test_an_unknown_name_inside_an_expression_is_named_once(tmp_path):
    path = write(tmp_path, PARAMS.replace('"$pull", 0', '"$(pull + nope)", 0', 1))
    msg = expect_error(path, ["accel[0]", "'nope'", "not in [params]"])
    assert msg.count(str(path)) == 1 and "cannot be evaluated" not in msg, msg


def test_builtin_sweep_style_set_on_own_params_via_batch_job(tmp_path):
    path = write(tmp_path, PARAMS)
    sweep = write(tmp_path, f"""
        scene = "{path.name}"
        engine = "reference"
        [grid]
        n = [2, 4]
        dt = [0.01, 0.02]
    """, "sweep.toml")
    sw = load_sweep(sweep)
    sw.validate()
    built = {j.name: j.build(sw.spec) for j in sw.jobs}
    assert sorted((s.groups["a"].n, s.dt) for s in built.values()) == [
        (2, 0.01), (2, 0.02), (4, 0.01), (4, 0.02)]


# ----------------------------------------------------------------------------- duration
DURATION = """
    name = "d"
    dt = 0.01
    duration = 2.5

    [[group]]
    name = "a"
    positions = [[0, 0, 0]]
    radius = 0.5
"""


def test_duration_sets_steps_and_survives_a_dt_change(tmp_path):
    path = write(tmp_path, DURATION)
    sc = load_toml(path)
    assert sc.total_steps == 250                       # 2.5 / 0.01
    assert sc.params["duration"] == 2.5
    assert load_toml(path, {"dt": 0.005}).total_steps == 500
    assert sc.with_dt(0.02).total_steps == 125          # --dt and sweep dt go through with_dt
    assert sc.with_dt(0.003).total_steps == 833         # round(2.5 / 0.003): within dt/2
    assert load_toml(path, {"steps": 7}).total_steps == 7  # --set steps wins
    assert load_toml(path, {"duration": 1.0}).total_steps == 100
    expect_error(write(tmp_path, DURATION.replace("duration = 2.5", "duration = 2.5\nsteps = 3")),
                 ["steps", "duration", "not both"])


def test_phase_durations(tmp_path):
    text = DURATION.replace("duration = 2.5\n", "") + """
    [[phase]]
    name = "push"
    duration = 0.5
    vars = { k = 1 }

    [[phase]]
    name = "rest"
    steps = 20
    vars = { k = 2 }
    """
    sc = load_toml(write(tmp_path, text))
    assert [p.steps for p in sc.phases] == [50, 20]
    sc2 = sc.with_dt(0.001)
    assert [p.steps for p in sc2.phases] == [500, 20]  # a phase given in time keeps its time
    both = text.replace("duration = 0.5", "duration = 0.5\nsteps = 3")
    expect_error(write(tmp_path, both), ["[[phase]] #1 'push'", "'steps'", "'duration'"])
    total = load_toml(write(tmp_path, text.replace('name = "d"', 'name = "d"\nduration = 1.4')))
    assert total.total_steps == 140                    # the schedule repeated for 1.4 time
    assert total.with_dt(0.02).total_steps == 70


# ----------------------------------------------------------------------------- parts
def test_mesh_part_with_placement_and_default_radius(tmp_path):
    box_stl(tmp_path / "part.stl")                     # 4 × 2 × 3 box: 24 cells of 1
    path = write(tmp_path, """
        name = "m"
        [[group]]
        name = "part"
        mesh = "part.stl"
        spacing = 1.0
        translate = [10, 0, 0]
        rotate = [0, 0, 90]
    """)
    sc = load_toml(path)
    g = sc.groups["part"]
    assert g.n == 24 and (g.r == 0.5).all()
    # rotated 90° about z: x ∈ [−2, 0] + 10, y ∈ [0, 4]
    assert g.o[:, 0].min() == pytest.approx(8.5) and g.o[:, 0].max() == pytest.approx(9.5)
    assert g.o[:, 1].min() == pytest.approx(0.5) and g.o[:, 1].max() == pytest.approx(3.5)
    hcp = load_toml(write(tmp_path, path.read_text() + 'packing = "hcp"\n', "h.toml"))
    o = hcp.groups["part"].o                          # every centre in the placed box
    assert ((o[:, 0] >= 8 - 1e-9) & (o[:, 0] <= 10 + 1e-9) & (o[:, 1] >= -1e-9)
            & (o[:, 1] <= 4 + 1e-9) & (o[:, 2] >= -1e-9) & (o[:, 2] <= 3 + 1e-9)).all()
    from scipy.spatial import cKDTree
    assert cKDTree(o).query(o, k=2)[0][:, 1].min() == pytest.approx(1.0)   # close packed


def test_parts_union_of_meshes_shapes_and_lattices(tmp_path):
    box_stl(tmp_path / "a.stl", (4.0, 2.0, 2.0))
    path = write(tmp_path, """
        name = "u"
        [[group]]
        name = "part"
        spacing = 1.0
        parts = [
            { mesh = "a.stl" },                                        # 16 cells
            { mesh = "a.stl", translate = [2, 0, 0] },                 # overlaps 8 of them
            { box = { min = [0, 2, 0], max = [2, 4, 2] } },            # 8 more above
            { lattice = { shape = [2, 1, 1], spacing = 1.0, origin = [0.5, 0.5, 0.5] } },
            { lattice = { shape = [1, 1, 1], origin = [20, 0, 0] } },  # a separate particle
        ]
    """)
    g = load_toml(path).groups["part"]
    # union of the solids: 6 × 2 × 2 + 2 × 2 × 2 = 32 cells; the first lattice coincides with
    # two filled particles (dropped), the second adds one
    assert g.n == 33
    assert len(np.unique(np.round(g.o, 9), axis=0)) == 33


def test_fill_shape_and_hcp(tmp_path):
    path = write(tmp_path, """
        name = "f"
        [[group]]
        name = "plate"
        spacing = 1.0
        packing = "$pack"
        fill = { difference = [ { box = { min = [0, 0, 0], max = [10, 10, 2] } },
                                { cylinder = { start = [5, 5, -1], end = [5, 5, 3], radius = 1.5 } } ] }
        [params]
        pack = "cubic"
    """)
    g = load_toml(path).groups["plate"]
    # 100 columns of 2; the hole takes the centres within 1.5 of (5, 5): (x−5)²+(y−5)² ≤ 2.25
    # with x, y ∈ {0.5 … 9.5}: the four centres (4.5|5.5, 4.5|5.5) at √0.5 and the eight at
    # √2.5 > 1.5 stay: 4 columns → 200 − 8
    assert g.n == 192
    gh = load_toml(path, {"pack": "hcp"}).groups["plate"]
    assert abs(gh.n / (math.sqrt(2) * (200 - 2 * math.pi * 1.5 ** 2)) - 1) < 0.15
    expect_error(path, ["packing", "cubic, hcp"], {"pack": "fcc"})


@pytest.mark.parametrize("snippet, needles", [
    ('mesh = "nope.stl"\nspacing = 1.0', ["[[group]] #1 'g'", "mesh", "nope.stl", "does not exist"]),
    # a mesh part without spacing gets one from its walls; a fill has no walls to ask
    ('fill = { box = { min = [0, 0, 0], max = [4, 2, 3] } }', ["missing required field 'spacing'"]),
    ('mesh = "part.stl"\nspacing = 5.0', ["part.stl", "larger than the part"]),
    ('mesh = "part.stl"\nspacing = 0.0001', ["part.stl", "more than", "scale"]),
    ('lattice = { shape = [2, 1, 1] }\ntranslate = [1, 0, 0]', ["translate", "places a group's mesh"]),
    ('positions = [[0, 0, 0]]', ["missing required field 'radius'"]),
    ('mesh = "part.stl"\nspacing = 1.0\nheld = { box = { min = [50, 0, 0], max = [60, 1, 1] } }',
     ["held", "selects no particle"]),
    ('mesh = "part.stl"\nspacing = 1.0\nheld = { cube = 1 }', ["held", "needs exactly one of box"]),
    ('fill = { plane = { point = [0, 0, 0], normal = [0, 1, 0] } }\nspacing = 1.0',
     ["half-space", "no inside to fill"]),
])
def test_part_errors(tmp_path, snippet, needles):
    box_stl(tmp_path / "part.stl")
    path = write(tmp_path, 'name = "e"\n[[group]]\nname = "g"\n' + snippet + "\n")
    expect_error(path, needles)


# ----------------------------------------------------------------------------- regions, supports
def test_regions_in_where_held_velocity_and_attraction(tmp_path):
    path = write(tmp_path, """
        name = "r"
        [[group]]
        name = "beam"
        lattice = { shape = [10, 2, 2], spacing = 1.0 }
        held = { plane = { point = [1, 0, 0], normal = [-1, 0, 0] } }     # x ≤ 1: 8 particles
        velocity = [0, 0, 2]
        regions.ends = [ { box = { min = [0, 0, 0], max = [0, 1, 1] } },
                         { box = { min = [9, 0, 0], max = [9, 1, 1] } } ]
        regions.mid = { sphere = { centre = [4.5, 0.5, 0.5], radius = 0.9 } }

        [[group]]
        name = "beamrack"
        rack = "beam"

        [[operator]]
        on = "beam"
        op = "force"
        accel = [0, -1, 0]
        where = { intersection = [ { cylinder = { start = [0, 0.5, 0.5], end = [20, 0.5, 0.5], radius = 0.8 } },
                                   { plane = { point = [7, 0, 0], normal = [1, 0, 0] } } ] }
    """)
    sc = load_toml(path)
    beam = sc.groups["beam"]
    assert beam.held.sum() == 8 and (beam.o[beam.held, 0] <= 1).all()
    assert (beam.v0[~beam.held] == [0, 0, 2]).all() and (beam.v0[beam.held] == 0).all()
    # the rack moves with its part: it starts with the part's velocity
    assert (sc.groups["beamrack"].v0 == [0, 0, 2]).all()
    # x ∈ {7, 8, 9}, all four (y, z) within 0.8 of the axis (distance √0.5): 12 particles
    where = np.array(sc.operators["beam"][0].where)
    assert where.sum() == 12 and (beam.o[where, 0] >= 7).all()
    ends = beam.meta["regions"]["ends"]
    assert (ends == 1).sum() == 4 and (ends == 2).sum() == 4
    assert set(beam.o[ends == 2, 0]) == {9.0}
    mid = beam.meta["regions"]["mid"]                 # (4|5, 0|1, 0|1) at distance √0.75
    assert mid.sum() == 8 and set(beam.o[mid == 1, 0]) == {4.0, 5.0}


def test_mesh_region_selects_inside_particles(tmp_path):
    box_stl(tmp_path / "sel.stl", (2.0, 10.0, 10.0), (2.6, -1.0, -1.0))   # x ∈ [2.6, 4.6]
    path = write(tmp_path, """
        name = "mr"
        [[group]]
        name = "beam"
        lattice = { shape = [10, 2, 2], spacing = 1.0 }
        [[operator]]
        on = "beam"
        op = "force"
        accel = [0, -1, 0]
        where = { mesh = "sel.stl" }
    """)
    where = np.array(load_toml(path).operators["beam"][0].where)
    o = load_toml(path).groups["beam"].o
    assert where.sum() == 8 and set(o[where, 0]) == {3.0, 4.0}


# ----------------------------------------------------------------------------- the example
def test_example_bracket_volume_count_and_supports():
    sys.path.insert(0, str(EXAMPLE))
    try:
        import make_bracket
    finally:
        sys.path.remove(str(EXAMPLE))
    sc = load_toml(EXAMPLE / "scene.toml")
    br = sc.groups["bracket"]
    assert abs(br.n / make_bracket.expected_volume() - 1) <= 0.05
    # held: within the washer radius 4 of either hole axis (along x at (y, z) = (6|16, 8))
    d = np.minimum(np.hypot(br.o[:, 1] - 6, br.o[:, 2] - 8), np.hypot(br.o[:, 1] - 16, br.o[:, 2] - 8))
    np.testing.assert_array_equal(br.held, (d <= 4 + 1e-9) & (br.o[:, 0] <= 4))
    # no particle in a hole (radius 2 polygon: inradius 2·cos(π/32))
    assert d.min() > 2 * math.cos(math.pi / 32) - 1e-9
    assert sc.total_steps == round(3.0 / 0.01)
    blk = sc.groups["block"]
    assert blk.o[:, 1].min() == pytest.approx(30 + 0.5 + 1.0)   # spacing/2 + gap above the arm
    assert (blk.v0 == [0, -4.0, 0]).all()


def test_example_stl_is_what_the_script_writes(tmp_path):
    import trimesh
    subprocess.run([sys.executable, str(EXAMPLE / "make_bracket.py"), str(tmp_path / "b.stl")],
                   check=True, capture_output=True, timeout=HANG_S)
    a, b = trimesh.load(tmp_path / "b.stl"), trimesh.load(EXAMPLE / "bracket.stl")
    assert a.volume == pytest.approx(b.volume, rel=1e-12)
    np.testing.assert_allclose(np.sort(a.vertices, axis=0), np.sort(b.vertices, axis=0), atol=1e-5)


@pytest.mark.lammps
@pytest.mark.slow
def test_example_runs_and_sweeps_from_the_command_line(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.run([str(RACKSTRESS), "run", str(EXAMPLE / "scene.toml"), "--out", str(out),
                           "--no-render", "--set", "speed=3", "--dt", "0.005"],
                          capture_output=True, text=True, timeout=HANG_S)
    assert proc.returncode == 0, proc.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["steps"] == 600          # duration 3 at dt 0.005
    assert s["params"]["speed"] == 3
    assert s["groups"]["bracket"]["max_deformation"] > 0.1    # the block struck it
    proc = subprocess.run([str(RACKSTRESS), "batch", str(EXAMPLE / "sweep.toml"), "--out",
                           str(tmp_path / "batch")], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    batch = json.loads((tmp_path / "batch" / "batch.json").read_text())
    jobs = batch["jobs"]
    assert [j["status"] for j in jobs] == ["ok"] * 3
    assert sorted(j["params"]["speed"] for j in jobs) == [2.0, 4.0, 8.0]


def test_rackstress_scenes_lists_a_files_own_parameters():
    proc = subprocess.run([str(RACKSTRESS), "scenes", "--json", str(EXAMPLE / "scene.toml")],
                          capture_output=True, text=True, timeout=HANG_S)
    assert proc.returncode == 0, proc.stderr
    listed = json.loads(proc.stdout)[str(EXAMPLE / "scene.toml")]["parameters"]
    assert listed["speed"] == 4.0 and listed["duration"] == 3.0 and "steps" not in listed
