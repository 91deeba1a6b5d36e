"""Scenes from TOML files (``rackstress.scenes.toml``): both forms, overrides, and bad input."""
from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

from rackstress import scenes
from rackstress.errors import SceneError
from rackstress.model.operators import (Attract, Bind, Collide, Const, Contact, Dampen, Force, Matched,
                                  PhaseIn, Within)
from rackstress.engines.reference import Reference
from rackstress.scenes.toml import load_toml

REPO = Path(__file__).resolve().parents[1]


def write(tmp_path: Path, text: str, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


GROUPS = """
    [[group]]
    name = "a"
    positions = [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 4.0, 0.0]]
    radius = 1.0

    [[group]]
    name = "b"
    positions = [[1.5, 0.0, 0.0]]
    radius = [1.0]
"""
TWO = """
    name = "two"
    dt = 0.05
    steps = 40
""" + GROUPS


# ----------------------------------------------------------------------------- form (a)
def test_builtin_with_params_and_overrides(tmp_path):
    path = write(tmp_path, """
        scene = "plane-rack"
        [params]
        n = 4
        plane_bind = 50.0
        steps = 30
    """)
    sc = load_toml(path, {"steps": 12})
    assert sc.name == "plane-rack"
    assert sc.groups["plane"].n == 16 and sc.groups["planerack"].n == 6
    assert sc.total_steps == 12                       # --set wins over [params]
    assert sc.params["plane_bind"] == 50.0 and sc.params["n"] == 4
    assert sc.operators["plane"][1] == Bind("planerack", Const(50.0))


def test_builtin_through_scenes_load(tmp_path):
    path = write(tmp_path, 'scene = "plane-bound"\n[params]\nd = 2.0\n')
    sc = scenes.load(str(path), {"magnitude": 7.0})
    assert sc.operators["plane"][1] == Bind("plane", Within(2.0, 7.0))


def test_example_plane_rack_file():
    sc = load_toml(REPO / "scenes" / "plane-rack.toml", {})
    assert sc.name == "plane-rack" and sc.n_particles == 406 and sc.total_steps == 180


@pytest.mark.parametrize("text, override, needles", [
    ('scene = "plane-rack"\n[params]\nfoo = 1\n', {}, ["[params]", "'foo'"]),
    ('scene = "plane-rack"\n', {"foo": 1}, ["--set", "'foo'"]),
    ('scene = "plane-rac"\n', {}, ["scene", "plane-rac", "plane-rack"]),
    ('scene = "plane-rack"\nextra = 1\n', {}, ["'extra'"]),
    ('scene = "plane-rack"\n[params]\nsteps = "many"\n', {}, ["steps"]),
])
def test_builtin_errors_name_the_file(tmp_path, text, override, needles):
    path = write(tmp_path, text)
    with pytest.raises(SceneError) as exc:
        load_toml(path, override)
    msg = str(exc.value)
    assert msg.startswith(str(path))
    for needle in needles:
        assert needle in msg


# ----------------------------------------------------------------------------- form (b)
def test_explicit_minimal_defaults(tmp_path):
    sc = load_toml(write(tmp_path, TWO), {})
    assert sc.name == "two" and sc.dt == 0.05 and sc.cycles == 1 and sc.bound == 1e4
    assert [(p.name, p.steps, dict(p.vars)) for p in sc.phases] == [("run", 40, {})]
    np.testing.assert_array_equal(sc.groups["a"].r, [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(sc.groups["b"].o, [[1.5, 0.0, 0.0]])
    assert sc.operators == {}
    sc = load_toml(write(tmp_path, TWO.replace("dt = 0.05\n    steps = 40\n", "")), {})
    assert sc.dt == 0.01 and sc.total_steps == 1200


def test_explicit_overrides(tmp_path):
    sc = load_toml(write(tmp_path, TWO), {"dt": 0.002, "steps": 7, "cycles": 3, "bound": 50.0})
    assert (sc.dt, sc.total_steps, sc.cycles, sc.bound) == (0.002, 21, 3, 50.0)


def test_explicit_operators_compile_to_the_model(tmp_path):
    path = write(tmp_path, 'name = "ops"\n' + textwrap.dedent(GROUPS) + textwrap.dedent("""
        [[operator]]
        on = "a"
        op = "force"
        accel = [0, 100, 0]
        where = { norm2_lt = 10 }

        [[operator]]
        on = "a"
        op = "force"
        accel = [1, 0, 0]
        where = { ids = [2] }
        when = { r = [1] }

        [[operator]]
        on = "a"
        op = "collide"
        from = "b"
        c = 100

        [[operator]]
        on = "b"
        op = "collide"
        from = "a"
        c = 20

        [[operator]]
        on = "a"
        op = "bind"
        from = "a"
        c = 2.5
        within = 4.5

        [[operator]]
        on = "a"
        op = "dampen"
        c = 10
        extra = 85
        when = { r = [2, 3] }
        contact = "b"

        [[operator]]
        on = "b"
        op = "attract"
        from = "a"
        c = 3
        when = { r = [2] }

        [[phase]]
        name = "first"
        steps = 5
        vars = { r = 1 }

        [[phase]]
        name = "second"
        steps = 6
        vars = { r = 2 }
    """))
    sc = load_toml(path, {})
    assert sc.name == "ops" and sc.dt == 0.01
    a_ops, b_ops = sc.operators["a"], sc.operators["b"]
    # ‖o‖² = 0, 9, 16 → mask (T, T, F)
    assert a_ops[0] == Force((0.0, 100.0, 0.0), where=(True, True, False))
    assert a_ops[1] == Force((1.0, 0.0, 0.0), where=(False, False, True),
                             when=(PhaseIn("r", (1,)),))
    assert a_ops[2] == Collide("b", Const(100.0))
    assert b_ops[0] == Collide("a", Const(20.0))
    assert a_ops[3] == Bind("a", Within(4.5, 2.5))
    assert a_ops[4] == Dampen(10.0, extra=85.0, when=(PhaseIn("r", (2, 3)), Contact("b")))
    assert b_ops[1] == Attract("a", Const(3.0), when=(PhaseIn("r", (2,)),))
    assert [(p.name, p.steps, dict(p.vars)) for p in sc.phases] == [
        ("first", 5, {"r": 1}), ("second", 6, {"r": 2})]
    assert sc.total_steps == 11
    assert sc.with_steps(3).total_steps == 3
    # --set steps with phases: the total number of iterations
    assert load_toml(path, {"steps": 20}).total_steps == 20

    # the compiled scene evaluates to hand values (phase r = 1, v = 0):
    # a0: pull (0,100,0) + collide from b (d 1.5, R 2: 100·(4/1.5 − 1.5) along −x);
    # a1: pull + collide (d 1.5 → same magnitude along +x); a2: ids force (1,0,0), and
    # a2 is 2.5 from b: no contact. Binds are at rest. b: collide from a0 and a1 cancel.
    k = 4.0 / 1.5 - 1.5
    a = Reference(sc).accelerations({"r": 1})
    np.testing.assert_allclose(a, [[-100 * k, 100, 0], [100 * k, 100, 0], [1, 0, 0], [0, 0, 0]],
                               rtol=1e-12, atol=1e-9)


def test_lattice_and_rack_groups(tmp_path):
    path = write(tmp_path, """
        name = "lr"
        [[group]]
        name = "hrack"
        rack = "h"
        [[group]]
        name = "h"
        kind = "body"
        positions = [[0, 0, 0], [2, 0, 0]]
        radius = 0.5
        [[group]]
        name = "blk"
        lattice = { shape = [2, 1, 2], spacing = 3.0, origin = [10, 0, 0] }
        radius = 0.5
        [[group]]
        name = "blkrack"
        rack = "blk"
        offset = 1.0
    """)
    sc = load_toml(path, {})
    assert list(sc.groups) == ["hrack", "h", "blk", "blkrack"]   # file order
    # host box: min (−0.5, −0.5, −0.5), max (2.5, 0.5, 0.5), ctr (1, 0, 0), offset 5
    np.testing.assert_allclose(sc.groups["hrack"].o, [
        [-5.5, 0, 0], [1, -5.5, 0], [1, 0, -5.5], [7.5, 0, 0], [1, 5.5, 0], [1, 0, 5.5]])
    np.testing.assert_array_equal(sc.groups["hrack"].r, np.ones(6))
    assert sc.groups["hrack"].kind == "rack" and sc.groups["hrack"].host == "h"
    assert sc.groups["h"].kind == "body"
    # lattice x fastest: (10,0,0), (13,0,0), (10,0,3), (13,0,3)
    np.testing.assert_allclose(sc.groups["blk"].o, [[10, 0, 0], [13, 0, 0], [10, 0, 3],
                                                    [13, 0, 3]])
    # blk box: min (9.5, −0.5, −0.5), max (13.5, 0.5, 3.5), ctr (11.5, 0, 1.5), offset 1
    np.testing.assert_allclose(sc.groups["blkrack"].o[[0, 4]], [[8.5, 0, 1.5], [11.5, 1.5, 1.5]])


def test_regions_and_matched_attract(tmp_path):
    path = write(tmp_path, """
        name = "walk"
        [[group]]
        name = "leg"
        positions = [[0, 0, 0], [1, 0, 0]]
        radius = 0.25
        regions = { mag = [1, 2] }
        [[group]]
        name = "body"
        positions = [[0, 3, 0], [1, 0, 4]]
        radius = 0.25
        regions = { breg1 = [1, 0], breg2 = [0, 2] }
        [[operator]]
        on = "leg"
        op = "attract"
        from = "body"
        c = 2
        match = ["mag", "breg{r}"]
        [[phase]]
        name = "1"
        steps = 3
        vars = { r = 1 }
        [[phase]]
        name = "2"
        steps = 3
        vars = { r = 2 }
    """)
    sc = load_toml(path, {})
    assert sc.operators["leg"][0] == Attract("body", Matched("mag", "breg{r}", 2.0))
    np.testing.assert_array_equal(sc.groups["body"].meta["regions"]["breg2"], [0, 2])
    ref = Reference(sc)
    # r = 1: leg0 (1) ↔ body0 (1) straight up: (0, 2, 0); r = 2: leg1 (2) ↔ body1 along +z
    np.testing.assert_allclose(ref.accelerations({"r": 1})[:2], [[0, 2, 0], [0, 0, 0]])
    np.testing.assert_allclose(ref.accelerations({"r": 2})[:2], [[0, 0, 0], [0, 0, 2]])


def test_example_two_blobs_file():
    sc = load_toml(REPO / "scenes" / "two-blobs.toml", {})
    assert {k: g.n for k, g in sc.groups.items()} == {"a": 27, "b": 27, "arack": 6, "brack": 6}
    assert sc.total_steps == 300
    col_a = [op for op in sc.operators["a"] if isinstance(op, Collide)]
    col_b = [op for op in sc.operators["b"] if isinstance(op, Collide)]
    assert col_a[0].source == "b" and col_b[0].source == "a"
    assert col_a[0].coeff.c != col_b[0].coeff.c
    assert Bind("a", Const(0.5)) in sc.operators["arack"]
    assert Bind("b", Const(0.5)) in sc.operators["brack"]


# ----------------------------------------------------------------------------- bad input
def expect_error(path, needles, overrides=None):
    with pytest.raises(SceneError) as exc:
        load_toml(path, overrides or {})
    msg = str(exc.value)
    assert str(path) in msg, msg
    for needle in needles:
        assert needle in msg, (needle, msg)
    return msg


def test_malformed_toml_names_line_and_column(tmp_path):
    path = write(tmp_path, 'name = "x"\ndt = 0.01\nsteps = = 3\n')
    msg = expect_error(path, ["line 3", "column"])
    assert "TOML" in msg


def test_unknown_operator(tmp_path):
    ops = "".join(f'\n[[operator]]\non = "a"\nop = "{k}"\n' + extra
                  for k, extra in (("force", "accel = [0,1,0]\n"), ("dampen", "c = 1\n"),
                                   ("pul", "")))
    path = write(tmp_path, TWO)
    path.write_text(path.read_text() + ops)
    expect_error(path, ["[[operator]] #3", "on 'a'", "unknown operator 'pul'",
                        "force, dampen, collide, bind, attract"])


def test_negative_radius(tmp_path):
    path = write(tmp_path, TWO.replace("radius = [1.0]", "radius = [-1.0]"))
    expect_error(path, ["[[group]] #2 'b'", "radius", "-1.0"])
    path = write(tmp_path, TWO.replace("radius = 1.0", "radius = 0"))
    expect_error(path, ["[[group]] #1 'a'", "radius"])


def test_coincident_particles(tmp_path):
    path = write(tmp_path, TWO.replace("[[1.5, 0.0, 0.0]]", "[[3.0, 0.0, 0.0]]"))
    expect_error(path, ["coincident", "'a' particle 1", "'b' particle 0"])


def test_unknown_set_key_for_explicit_scene(tmp_path):
    path = write(tmp_path, TWO)
    expect_error(path, ["--set", "'radius'", "dt, steps, duration, cycles, bound", "[params]"], {"radius": 2.0})
    expect_error(path, ["--set dt", "positive"], {"dt": -0.1})
    expect_error(path, ["--set steps", "integer"], {"steps": 2.5})


@pytest.mark.parametrize("snippet, needles", [
    ('\n[[operator]]\non = "c"\nop = "dampen"\nc = 1\n', ["[[operator]] #1", "'c'", "on"]),
    ('\n[[operator]]\non = "a"\nop = "bind"\nfrom = "zz"\nc = 1\n', ["from", "'zz'"]),
    ('\n[[operator]]\non = "a"\nop = "bind"\nc = 1\n', ["missing", "'from'"]),
    ('\n[[operator]]\non = "a"\nop = "collide"\nfrom = "b"\nc = "x"\n', ["c:", "number"]),
    ('\n[[operator]]\non = "a"\nop = "collide"\nfrom = "b"\nc = 1\nwithin = 2\n',
     ["'within'"]),
    ('\n[[operator]]\non = "a"\nop = "force"\naccel = [0, 1]\n', ["accel", "three"]),
    ('\n[[operator]]\non = "a"\nop = "force"\naccel = [0, 1, 0]\nwhere = { ids = [3] }\n',
     ["ids", "3"]),
    ('\n[[operator]]\non = "a"\nop = "dampen"\nc = 1\ncontact = "q"\nextra = 2\n',
     ["contact", "'q'"]),
    ('\n[[operator]]\non = "a"\nop = "dampen"\nc = 1\nwhen = { r = [1] }\nextra = 2\n',
     ["when.r", "'r'", "run"]),
    ('\n[[operator]]\non = "a"\nop = "attract"\nfrom = "b"\nc = 1\nmatch = ["m", "n"]\n',
     ["match", "'m'"]),
    ('\n[[operator]]\non = "a"\nop = "dampen"\nc = 1\ncolor = 2\n', ["'color'"]),
    ('\n[[group]]\nname = "r"\nrack = "nope"\n', ["[[group]] #3 'r'", "rack", "'nope'"]),
    ('\n[[group]]\nname = "a"\npositions = [[9, 9, 9]]\nradius = 1\n', ["used twice"]),
    ('\n[[group]]\nname = "z"\npositions = [[9, 9, 9]]\n', ["[[group]] #3 'z'", "'radius'"]),
    ('\n[[group]]\nname = "z"\npositions = [[9, 9, 9]]\nradius = 1\nshape = 2\n',
     ["'shape'"]),
    ('\n[[group]]\nname = "z"\nlattice = { shape = [2, 0, 1] }\nradius = 1\n',
     ["lattice", "shape"]),
    ('\n[[group]]\nname = "z"\npositions = [[9, 9, 9]]\nradius = [1, 2]\n', ["2 entries"]),
    ('\n[[group]]\nname = "z"\npositions = [[9, 9, 9]]\nradius = 1\nregions = { m = [1, 2] }\n',
     ["regions.m"]),
])
def test_field_errors(tmp_path, snippet, needles):
    path = write(tmp_path, TWO)
    path.write_text(path.read_text() + snippet)
    expect_error(path, needles)


def test_unknown_top_level_key_and_phase_errors(tmp_path):
    path = write(tmp_path, TWO.replace('name = "two"', 'name = "two"\ntimestep = 1'))
    expect_error(path, ["'timestep'"])
    path = write(tmp_path, TWO + '\n[[phase]]\nname = "p"\nsteps = 3\n')
    expect_error(path, ["steps", "[[phase]]"])
    path = write(tmp_path, TWO.replace("steps = 40\n", "") + '\n[[phase]]\nname = "p"\n')
    expect_error(path, ["[[phase]] #1 'p'", "'steps'"])


def test_missing_file():
    with pytest.raises(SceneError, match="nope.toml"):
        load_toml("/nonexistent/nope.toml", {})
