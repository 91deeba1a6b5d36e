"""Faults of physical scenes, static analysis and batches over them, played with real processes:
a static run that cannot settle (a part that floats away, a
mechanism) ends with ``not settled`` and exit 6 in bounded time; a load on a region that
selects nothing, a mesh in other units than the scene's, a material without E are exit 2 with
a message naming the place; a batch over mesh scenes refuses a missing STL before any job runs
and records a job that does not settle as such. README's fault table lists each case."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from test_faults import QUIET, rs
from conftest import HANG_S, child_cpu

ROOT = Path(__file__).resolve().parents[1]
BRACKET = ROOT / "examples" / "bracket"

#: a steel bar 20 × 4 × 4 mm (particles at 0.5, 1.5, … mm), held on a cylinder around the
#: line x = y = 0.5 of radius `pin`, 10 N down on its far end. pin = 2.5 clamps a block of its
#: end (it settles); pin = 0.1 holds one line of particles along z, about which the bar turns
#: freely: a mechanism, no equilibrium.
HINGE = """name = "hinge"
units = "mm-N-s"
analysis = "static"

[params]
pin = 2.5

[[group]]
name = "bar"
fill = {{ box = {{ min = [0, 0, 0], max = [20, 4, 4] }} }}
spacing = 1.0
material = {material}

[[support]]
on = "bar"
where = {{ cylinder = {{ start = [0.5, 0.5, -1], end = [0.5, 0.5, 5], radius = "$pin" }} }}

[[load]]
on = "{load_on}"
where = {{ box = {{ min = {load_min}, max = {load_max} }} }}
force = [0, -10, 0]
{extra}"""

LOOSE = """
[[group]]
name = "loose"
fill = { box = { min = [30, 0, 0], max = [40, 4, 4] } }
spacing = 1.0
material = "steel"
"""


def hinge(tmp_path: Path, name="hinge.toml", material='"steel"', load_on="bar",
          load_min="[19.5, -1, -1]", load_max="[21, 5, 5]", extra="") -> Path:
    p = tmp_path / name
    p.write_text(HINGE.format(material=material, load_on=load_on, load_min=load_min,
                              load_max=load_max, extra=extra))
    return p


def summary(rundir: Path) -> dict:
    return json.loads((rundir / "summary.json").read_text())


# ---------------------------------------------------------------------------- not settled
@pytest.mark.lammps
@pytest.mark.parametrize("case", ["mechanism", "floats away"])
def test_a_static_run_that_cannot_settle_is_refused_before_the_solve(tmp_path, case):
    """A mechanism (a bar held on one line of particles turns about it) and a part with no
    support at all beside a held one (its load reaches no support): no equilibrium exists.
    The part check refuses both before any Newton step (exit 2, one paragraph naming the part
    and what to do; was exit 6 after 25 iterations), and nothing is written; the same bar
    clamped settles (exit 0)."""
    if case == "mechanism":
        scene, sets = hinge(tmp_path), ["--set", "pin=0.1"]
    else:
        scene = hinge(tmp_path, load_on="loose", load_min="[38.5, -1, -1]",
                      load_max="[41, 5, 5]", extra=LOOSE)
        sets = []
    out = tmp_path / "run"
    with child_cpu() as cpu:
        r = rs("run", scene, *sets, "--out", out, *QUIET)
    assert r.returncode == 2, r.stderr
    assert cpu.s < 60, cpu.s           # bounded work: refused before any Newton step
    errors = [line for line in r.stderr.splitlines() if line.startswith("rackstress: error")]
    assert len(errors) == 1 and "cannot hold this part" in errors[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not (out / "summary.json").exists()
    if case == "floats away":            # the unsupported part is named
        assert "'loose'" in errors[0] and "no support" in errors[0]
    else:                                # the clamped bar: the same scene settles
        assert "turn about the axis" in errors[0]
        ok = rs("run", scene, "--set", "pin=2.5", "--out", tmp_path / "ok", *QUIET)
        assert ok.returncode == 0, ok.stderr
        assert summary(tmp_path / "ok")["status"] == "settled"


@pytest.mark.lammps
def test_a_load_too_small_to_resolve_says_why_it_cannot_settle(tmp_path):
    """The clamped steel bar under 1e-9 N instead of 10 N: its deformation is below what
    rounding the positions resolves (ε·|p| ≈ 4e-15 mm, times the bar's stiffness, is more than
    1e-6 of so small a load), so Newton's method stalls and the run is ``not settled`` (exit 6)
    — with the reason and the remedy in the message and the estimate in summary.json (was: the
    bare "did not settle", as for a mechanism)."""
    scene = hinge(tmp_path)
    scene.write_text(scene.read_text().replace("force = [0, -10, 0]", "force = [0, -1e-9, 0]"))
    out = tmp_path / "run"
    r = rs("run", scene, "--out", out, *QUIET, timeout=HANG_S)
    assert r.returncode == 6, r.stderr
    assert "Traceback" not in r.stderr
    assert "did not settle" in r.stderr and "rounding of its positions" in r.stderr
    assert "A larger load settles it" in r.stderr
    s = summary(out)
    assert s["status"] == "not settled" and s["rounding_floor"] > s["tolerance"]
    # the same bar under its 10 N settles (the first test's clamped case)


# ---------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("case", ["empty load", "no E", "mesh in metres", "mesh in mm in SI",
                                  "E 1e-300", "E 1e300", "density 1e9", "force 1e300",
                                  "gravity 1e308", "displacement 1e300", "displacement 1e6",
                                  "displacement on a support", "fix x twice",
                                  "spacing 1e-300"])
def test_physical_input_errors_name_the_place(tmp_path, case):
    """Exit 2 and one paragraph naming the file and the field; nothing written.

    A fault sweep of numbers no solid or load has found: E = 1e-300 Pa ran into
    LAMMPS' "Non-numeric atom coords" (exit 3); E = 1e300 Pa, a force of 1e300 N or gravity of
    1e308 ended "not settled" (exit 6, a residual of nan); a prescribed displacement of 1e300
    mm lost atoms in LAMMPS (exit 3) and 1e6 mm, beyond the watchdog bound, did not settle."""
    bad = {"E 1e-300": ("material", "{ E = 1e-300, nu = 0.3, density = 7850 }",
                        ["'bar'", "material", "E = 1e-300 Pa", "outside what any solid has"]),
           "E 1e300": ("material", "{ E = 1e300, nu = 0.3, density = 7850 }",
                       ["'bar'", "material", "E = 1e+300 Pa", "outside what any solid has"]),
           "density 1e9": ("material", "{ E = 2e11, nu = 0.3, density = 1e9 }",
                           ["'bar'", "density = 1e+09 kg/m³", "outside what any solid has"]),
           "force 1e300": ("load", "force = [0, -1e300, 0]",
                           ["[[load]] #1", "force", "beyond 1e+150", "overflows"]),
           "gravity 1e308": ("load", "gravity = [0, -1e308, 0]",
                             ["[[load]] #1", "gravity", "beyond 1e+150"]),
           "displacement 1e300": ("load", "displacement = [0, -1e300, 0]",
                                  ["'bar' particle", "prescribed displacement",
                                   "watchdog bound 10000"]),
           "displacement 1e6": ("load", "displacement = [0, -1e6, 0]",
                                ["'bar' particle", "prescribed displacement",
                                 "watchdog bound 10000"]),
           # the support's own cylinder displaced: held at o and at o + u (was: "not settled",
           # exit 6, a residual of 0.09 of the reactions)
           "displacement on a support": ("support", "displacement = [0, 0, 1]",
                                         ["[[load]] #1", "displacement", "already held in z",
                                          "[[support]]"])}
    if case == "fix x twice":
        # ["x", "x"] for ["x", "y"]: was accepted, the bar a mechanism, "not settled" (exit 6)
        scene = hinge(tmp_path)
        text = scene.read_text()
        scene.write_text(text.replace('radius = "$pin" } }\n',
                                      'radius = "$pin" } }\nfix = ["x", "x"]\n', 1))
        assert scene.read_text() != text
        says = ["hinge.toml", "[[support]] #1", "'bar'", "fix", "'x' more than once"]
    elif case == "spacing 1e-300":
        # 20 × 4 × 4 mm at 1e-300 mm: 320 mm³ / 1e-900 mm³ = 3.2e902 particles (hand count;
        # was "about inf particles" after a NumPy overflow warning)
        scene = hinge(tmp_path)
        scene.write_text(scene.read_text().replace("spacing = 1.0", "spacing = 1e-300"))
        says = ["hinge.toml", "'bar'", "spacing 1e-300", "about 3.2e+902 particles",
                "10,000,000"]
    elif case in bad:
        where, value, says = bad[case]
        if where == "material":
            scene = hinge(tmp_path, material=value)
        elif where == "support":
            scene = hinge(tmp_path, load_min="[-1, -1, -1]", load_max="[1.5, 1.5, 5]")
            scene.write_text(scene.read_text().replace("force = [0, -10, 0]", value))
        else:
            scene = hinge(tmp_path)
            scene.write_text(scene.read_text().replace("force = [0, -10, 0]", value))
        says = ["hinge.toml", *says]
    elif case == "empty load":
        scene = hinge(tmp_path, load_min="[100, 100, 100]", load_max="[101, 101, 101]")
        says = ["hinge.toml", "[[load]] #1", "'bar'", "where", "selects no particle"]
    elif case == "no E":
        scene = hinge(tmp_path, material="{ nu = 0.3, density = 7850 }")
        says = ["hinge.toml", "'bar'", "material", "lacks E"]
    else:
        shutil.copy(BRACKET / "bracket.stl", tmp_path / "bracket.stl")
        text = (BRACKET / "static.toml").read_text()
        if case == "mesh in metres":     # a mm part read as metres' thousandths: too small
            text = text.replace('mesh = "bracket.stl"', 'mesh = "bracket.stl"\nscale = 0.001')
            says = ["static.toml", "bracket.stl", "larger than the part", "scale"]
        else:                            # a mm mesh in an SI scene: 30 m wide, too large
            text = text.replace('units = "mm-N-s"', 'units = "SI"').replace(
                "spacing = 1.0 ", "spacing = 0.001 ")
            says = ["static.toml", "bracket.stl", "10,000,000", "scale"]
        scene = tmp_path / "static.toml"
        scene.write_text(text)
    out = tmp_path / "run"
    r = rs("run", scene, "--out", out, *QUIET, timeout=HANG_S)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "inf " not in r.stderr and "Warning" not in r.stderr
    for word in says:
        assert word in r.stderr, (word, r.stderr)
    assert not out.exists()


# ---------------------------------------------------------------------------- batches
def test_a_batch_with_a_missing_stl_is_refused_before_any_job_runs(tmp_path):
    shutil.copy(BRACKET / "bracket.stl", tmp_path / "bracket.stl")
    text = (BRACKET / "static.toml").read_text()
    text = text.replace('mesh = "bracket.stl"', 'mesh = "$part"').replace(
        "[params]\n", '[params]\npart = "bracket.stl"\n', 1)
    (tmp_path / "parts.toml").write_text(text)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('scene = "parts.toml"\nengine = "lammps"\n\n[grid]\n'
                     'part = ["bracket.stl", "missing.stl"]\n')
    out = tmp_path / "b"
    r = rs("batch", sweep, "--out", out, timeout=HANG_S)
    assert r.returncode == 2, r.stderr
    assert "missing.stl" in r.stderr and "does not exist" in r.stderr
    assert "g001" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists() or not list(out.glob("g0*"))        # no job ran


@pytest.mark.lammps
def test_a_batch_records_a_job_that_did_not_settle(tmp_path):
    """Two jobs of the clamped hinge bar: under 10 N (settles) and under 1e-9 N (too small
    for rounding to resolve: it cannot settle; a mechanism is now refused before its solve).
    The batch goes on (exit 0, as with a diverged job) and batch.json, the job's summary and
    the batch report say ``not settled`` (was: ``ok``)."""
    scene = hinge(tmp_path)
    scene.write_text(scene.read_text().replace("pin = 2.5", "pin = 2.5\nload = 10.0")
                     .replace("force = [0, -10, 0]", 'force = [0, "$(-load)", 0]'))
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('scene = "hinge.toml"\nengine = "lammps"\n\n[grid]\nload = [10.0, 1e-9]\n')
    out = tmp_path / "b"
    r = rs("batch", sweep, "--out", out, timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    jobs = {j["params"]["load"]: j for j in json.loads((out / "batch.json").read_text())["jobs"]}
    assert jobs[10.0]["status"] == "ok", jobs[10.0]
    assert jobs[1e-9]["status"] == "not settled", jobs[1e-9]
    assert "did not settle" in jobs[1e-9]["error"]
    assert summary(out / jobs[1e-9]["dir"])["status"] == "not settled"
    counts = json.loads((out / "batch.json").read_text())["counts"]
    assert counts == {"ok": 1, "not settled": 1}
    page = (out / "report.html").read_text()
    assert 'data-status="not settled"' in page


# ---------------------------------------------------------------------------- rackstress fea
@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    """The clamped hinge bar, settled: a run directory ``rackstress fea`` can check."""
    d = tmp_path_factory.mktemp("fea")
    out = d / "run"
    r = rs("run", hinge(d), "--out", out, *QUIET, timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    return out


@pytest.mark.lammps
@pytest.mark.parametrize("damage,says", [
    ("boundary.npz cut", "boundary.npz cannot be read (File is not a zip file): remove it"),
    ("scene.json gone", "scene.json is missing: the run directory is incomplete"),
    ("scene.json cut", "scene.json cannot be read (")])
def test_fea_on_a_damaged_run_directory_names_the_file(tmp_path, static_run, damage, says):
    """``rackstress fea`` on a run directory copied in part or cut short: exit 2 and one
    paragraph naming the file (was: a BadZipFile or FileNotFoundError traceback, exit 1, or a
    bare "Expecting value: line 2 column 1")."""
    d = tmp_path / "copy"
    shutil.copytree(static_run, d)
    name = damage.split()[0]
    if damage.endswith("gone"):
        (d / name).unlink()
    else:
        data = (d / name).read_bytes()
        (d / name).write_bytes(data[:len(data) // 3])
    r = rs("fea", d, timeout=HANG_S)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert r.stderr.count("rackstress: error") == 1 and says in r.stderr, r.stderr
    assert str(d / name) in r.stderr
    assert not (d / "fea.json").exists()


@pytest.mark.lammps
def test_fea_without_boundary_npz_rebuilds_a_scene_file_named_like_a_built_in(tmp_path):
    """A run of a scene file whose name is a built-in scene's (examples/cantilever/scene.toml
    is "cantilever", like the planar built-in) with its boundary.npz gone: ``rackstress fea``
    rebuilds the scene from its file (was: the built-in's phases differed, "could not be
    rebuilt", exit 2) and takes the supports and loads from it: the same FE field as from the
    run's own boundary.npz, 32 held particles (the cylinder r = 2.5 about x = y = 0.5 holds the
    8 columns with dx² + dy² ≤ 6.25, 4 high) and the 10 N on the 16 particles at x = 19.5."""
    scene = hinge(tmp_path)
    scene.write_text(scene.read_text().replace('name = "hinge"', 'name = "cantilever"'))
    out = tmp_path / "run"
    r = rs("run", scene, "--out", out, *QUIET, timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    bare = tmp_path / "bare"
    shutil.copytree(out, bare)
    (bare / "boundary.npz").unlink()
    for d in (out, bare):        # the boundary's source is the point, not the FE's size
        r = rs("fea", d, "--no-converge", timeout=HANG_S)
        assert r.returncode == 0, r.stderr
    import numpy as np

    data = json.loads((bare / "fea.json").read_text())
    assert data["boundary"] == "the scene (no boundary.npz)"
    assert not data["note"] or "could not be rebuilt" not in data["note"]
    assert data["held_particles"] == 32 and data["loaded_particles"] == 16
    assert data["total_force"] == pytest.approx([0, -10, 0])
    assert np.load(bare / "fea.npz")["fea_von_mises"] == pytest.approx(
        np.load(out / "fea.npz")["fea_von_mises"], rel=1e-9)
