"""A rigid sphere pressed on a part (``[[indenter]]``, model.operators.Indent): its scene
tables, the static analysis's active-set penalty against a hand calculation, the dynamic
engines against the reference engine, and Hertz's contact at the coarsest bench spacing
(docs/calibration.md "Contact", docs/benchmarks/hertz.md)."""
from __future__ import annotations

import json

import numpy as np
import pytest

#: a steel block of n³ particles at 1 mm, top row at z = -0.5 (its face at z = 0); the bottom
#: row held, symmetry planes x = 0 and y = 0 (rollers), or every particle held
BLOCK = '''
name = "{name}"
units = "mm-N-s"
{head}

[[group]]
name = "block"
fill = {{ box = {{ min = [0, 0, -{n}], max = [{m}, {m}, 0] }} }}
spacing = 1.0
origin = [0, 0, -0.5]
material = "steel"

{supports}

[[indenter]]
{indenter}
'''

ROLLERS = '''[[support]]
on = "block"
where = { box = { min = [-1, -1, -99], max = [99, 99, -%s] } }
[[support]]
on = "block"
where = { box = { min = [-1, -1, -99], max = [0.25, 99, 1] } }
fix = ["x"]
[[support]]
on = "block"
where = { box = { min = [-1, -1, -99], max = [99, 0.25, 1] } }
fix = ["y"]'''

HELD = '''[[support]]
on = "block"'''

INDENTER = '''on = "block"
sphere = { centre = [0, 0, 20], radius = 20 }
travel = [0, 0, -0.05]'''


def block(tmp_path, n=4, head='analysis = "static"', supports=None, indenter=INDENTER,
          name="indent"):
    """The scene file of BLOCK (``n`` layers), its path."""
    supports = ROLLERS % (n - 1) if supports is None else supports
    f = tmp_path / f"{name}.toml"
    f.write_text(BLOCK.format(name=name, head=head, n=n, m=n - 1, supports=supports,
                              indenter=indenter))
    return f


#: the dynamic scene of the parity tests: the centre lowered over a ramp of 1e-5 s, then held
DYNAMIC = 'analysis = "dynamic"\nduration = 1.99e-5\ndt = 9e-8'      # 220 steps
DYN_INDENTER = INDENTER + "\nramp = 1e-5"
DAMPED = ROLLERS % 3 + '\n[[operator]]\non = "block"\nop = "dampen"\nc = 4e5'


def dynamic_scene(tmp_path, name="dyn"):
    from rackstress.scenes import load

    return load(str(block(tmp_path, head=DYNAMIC, supports=DAMPED, indenter=DYN_INDENTER,
                          name=name)))


def test_indenter_tables_are_checked(tmp_path):
    """Each refusal names the table and the field (exit 2's SceneError)."""
    from rackstress.errors import SceneError
    from rackstress.scenes.toml import load_toml

    cases = {
        INDENTER + "\nradius = 3": ("[[indenter]] #1", "unknown key 'radius'"),
        INDENTER.replace('on = "block"', 'on = "floor"'): ("[[indenter]] #1", "on",
                                                           "unknown group 'floor'"),
        INDENTER.replace("sphere = { centre = [0, 0, 20], radius = 20 }\n", ""):
            ("[[indenter]] #1", "missing required field 'sphere'"),
        INDENTER.replace("radius = 20", "radius = -2"): ("sphere", "radius", "positive"),
        INDENTER.replace("radius = 20 }", "radius = 20, r = 1 }"): ("sphere", "unknown key 'r'"),
        INDENTER.replace("[0, 0, 20]", "[0, 20]"): ("sphere", "centre", "three finite numbers"),
        INDENTER.replace("[0, 0, -0.05]", "[0, 0, 0]"): ("[[indenter]] #1", "travel",
                                                        "nonzero"),
        INDENTER.replace("[0, 0, -0.05]", "[0, 0, 0.05]"): ("[[indenter]] #1", "travel",
                                                           "reaches no particle"),
        INDENTER.replace("[0, 0, 20]", "[0, 0, 1]").replace("radius = 20", "radius = 4"):
            ("[[indenter]] #1", "sphere", "inside"),
        INDENTER + "\nstiffness = 0": ("[[indenter]] #1", "stiffness", "positive"),
        INDENTER + '\nstiffness = "high"': ("[[indenter]] #1", "stiffness", "finite number"),
        INDENTER + "\nramp = -1": ("ramp", "positive time"),
    }
    for body, words in cases.items():
        f = block(tmp_path, indenter=body, head="")
        with pytest.raises(SceneError) as err:
            load_toml(str(f))
        for w in words:
            assert w in str(err.value), (body, str(err.value))
    # a dynamic analysis moves the sphere over the ramp: it needs one
    f = block(tmp_path, head='analysis = "dynamic"\nduration = 1e-5')
    with pytest.raises(SceneError, match=r"\[\[indenter\]\] #1.*ramp"):
        load_toml(str(f))
    # a material part only
    f = tmp_path / "paper.toml"
    f.write_text('name = "p"\nsteps = 1\n[[group]]\nname = "block"\npositions = [[0, 0, 0]]\nradius = 0.5\n'
                 '[[indenter]]\n' + INDENTER)
    with pytest.raises(SceneError, match=r"\[\[indenter\]\] #1.*(on|material)"):
        load_toml(str(f))


def test_the_held_block_takes_k_times_the_overlap(tmp_path):
    """Every particle held, the sphere reaching only the top row's middle particle: its force
    is k·g by hand, k = 10·E*·a with E* = E/(1 − ν²) (steel, the lattice's ν = 1/4; a whole
    cell: share 1) and g = R + a/2 − (distance of its centre) = 0.05 mm; its neighbours, 1 mm
    aside, stay out of reach (√(1 + 2.45²) = 2.646 > 2.5). The supports take it all."""
    from rackstress.engines import static
    from rackstress.scenes import load

    ind = INDENTER.replace("[0, 0, 20]", "[1, 1, 2]").replace("radius = 20", "radius = 2")
    sc = load(str(block(tmp_path, n=3, supports=HELD, indenter=ind)))
    res = static.solve(sc)
    assert res.settled
    out = static.support_reactions(sc, res)
    (row,) = out["indenters"]
    k = 10.0 * 200000.0 / (1.0 - 0.25 ** 2) * 1.0          # N/mm
    assert row["particles"] == 1
    assert row["force"][2] == pytest.approx(-k * 0.05, rel=1e-12)
    assert abs(row["force"][0]) + abs(row["force"][1]) < 1e-9 * k
    total = np.sum([r["force"] for r in out["reactions"]], axis=0)
    assert total == pytest.approx(-np.array(row["force"]), abs=1e-9 * k)


def test_a_static_run_reports_the_indenter_force(tmp_path):
    """``rackstress run`` of a static indentation on the reference engine: settled, its own
    check (engine_residual) counting the sphere's push, and summary.json's ``indenters`` force
    balanced by the supports' reactions."""
    from test_plugin import _cli

    f = block(tmp_path, n=6)
    _cli("run", str(f), "--engine", "reference", "--out", str(tmp_path / "run"), "--no-render",
         "--no-progress")
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert s["settled"] and s["residual_engine"] < 1e-6 and s["contact_sets"] >= 1
    (row,) = s["indenters"]
    F = np.array(row["force"])
    assert F[2] < 0 and row["particles"] >= 1
    total = np.sum([r["force"] for r in s["reactions"]], axis=0)
    assert np.abs(total + F).max() < 1e-6 * abs(F[2])


@pytest.mark.lammps
def test_indenter_runs_alike_on_the_reference_engine_and_the_plugin(tmp_path, monkeypatch):
    """The centre lowered over the ramp and held, 220 steps: the plugin's fix rs/indent and the
    Python callback (numba and NumPy kernels) reach the reference engine's positions to
    round-off (measured 8e-15 mm), the sphere moving the top by tens of micrometres."""
    from conftest import lammps_finals, reference_final

    sc = dynamic_scene(tmp_path)
    ref = reference_final(sc)
    assert np.abs(ref - sc.original_positions()).max() > 0.01
    for plugin, kernels, text, p in lammps_finals(sc, monkeypatch):
        assert (" rs/indent " in text) == plugin
        assert np.abs(p - ref).max() < 1e-12, (plugin, kernels)


@pytest.mark.lammps
@pytest.mark.mpi
def test_indenter_runs_alike_under_mpi(tmp_path):
    """The same on two ranks (the plugin: each rank pushes the atoms it owns)."""
    from conftest import lammps_under_mpi, reference_final

    sc = dynamic_scene(tmp_path)
    got = lammps_under_mpi(tmp_path, "from test_indenter import dynamic_scene\n"
                           "from pathlib import Path\nimport os\n"
                           f"d = Path({str(tmp_path)!r}) / f'rank-{{os.getpid()}}'\n"
                           "d.mkdir()\nscenes_ = {'dyn': dynamic_scene(d)}",
                           plugin=True)
    p, counts = got["dyn"]
    assert min(counts) > 0
    assert np.abs(p - reference_final(sc)).max() < 1e-12


@pytest.mark.lammps
@pytest.mark.mpi
def test_indenter_deck_in_plain_lmp(tmp_path):
    """``rackstress deck`` of the dynamic indentation, run by the venv's plain ``lmp`` and
    ``mpiexec -n 2 lmp`` (fix rs/indent, its stiffness per atom d_rsk1 set in the deck): the
    reference engine's trajectory, frame by frame, to the dump's precision."""
    import shutil

    from conftest import trajectory
    from test_plugin import _cli, _frames, _lmp, _same_to_dump_precision

    f = block(tmp_path, head=DYNAMIC, supports=DAMPED, indenter=DYN_INDENTER, name="dyn")
    _cli("run", str(f), "--engine", "reference", "--out", str(tmp_path / "ref"), "--no-render",
         "--no-progress")
    ref = _frames(trajectory(tmp_path / "ref"))
    _cli("deck", str(f), "--out", str(tmp_path / "deck1"))
    text = (tmp_path / "deck1" / "in.lammps").read_text()
    assert " rs/indent " in text and " d_rsk1 " in text
    shutil.copytree(tmp_path / "deck1", tmp_path / "deck2")
    _same_to_dump_precision(_lmp(tmp_path / "deck1", 1), ref)
    _same_to_dump_precision(_lmp(tmp_path / "deck2", 2), ref)


def test_hertz_at_the_coarsest_bench_spacing(tmp_path):
    """The bench's quarter block at h = 1 mm (a_H/h = 5.3), static: the fitted contact radius
    and peak pressure within 3 % of Hertz's for the force the sphere applies (the bench
    measured 1.4 % and 0.8 % there, 0.1 % and 0.05 % at 0.5 mm: docs/benchmarks/hertz.md),
    settled in a few active sets."""
    from rackstress.bench.hertz import static_case

    r = static_case(1.0, tmp_path)
    assert r["settled"] and r["sets"] <= 5
    assert abs(r["a_ratio"] - 1.0) < 0.03
    assert abs(r["p0_ratio"] - 1.0) < 0.03
