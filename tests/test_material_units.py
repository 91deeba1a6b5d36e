"""Material tables: quantities with units (pint), and numbers no solid has named with the
likely slip of units (model/materials.py, docs/units.md)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from rackstress import scenes
from rackstress.errors import SceneError
from rackstress.model.materials import material
from rackstress.model.operators import Bind

RS = str(Path(sys.executable).parent / "rackstress")

BAR = """name = "bar"
units = "mm-N-s"
analysis = "static"

[[group]]
name = "bar"
fill = {{ box = {{ min = [0, 0, 0], max = [10, 3, 3] }} }}
spacing = 1.0
material = {material}

[[support]]
on = "bar"
where = {{ box = {{ min = [-1, -1, -1], max = [0.5, 4, 4] }} }}

[[load]]
on = "bar"
where = {{ box = {{ min = [9.5, -1, -1], max = [11, 4, 4] }} }}
force = [0, -10, 0]
"""


def bar(tmp_path: Path, mat: str) -> Path:
    p = tmp_path / "bar.toml"
    p.write_text(BAR.format(material=mat))
    return p


def bind_c(path: Path) -> float:
    sc = scenes.load(str(path), {})
    (op,) = [op for op in sc.operators["bar"] if isinstance(op, Bind)]
    return op.coeff.c


def test_e_in_mpa_in_a_mm_scene_is_refused_naming_the_slip(tmp_path):
    """A table of an mm-N-s user's numbers (E and yield in MPa) was read as pascals: the run
    strained 3,300 % and yielded at 0.000276 MPa. Refused (exit 2) with the slip named."""
    scene = bar(tmp_path, "{ E = 70000, nu = 0.33, density = 2700, yield = 276 }")
    r = subprocess.run([RS, "run", scene, "--out", tmp_path / "r", "--no-render",
                        "--no-progress"], capture_output=True, text=True, timeout=900)
    assert r.returncode == 2, r.stderr
    msg = r.stderr
    assert "bar.toml" in msg and "material" in msg and "no solid's" in msg
    assert "softer than any rubber" in msg
    assert "E = 70000 looks like MPa" in msg and "yield = 276 looks like MPa" in msg
    assert 'E = "70000 MPa"' in msg and "Traceback" not in msg
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("table, slip", [
    # density in g/cm³: √(E/ρ) = √(70e9 / 2.7) = 161,000 m/s, faster than diamond
    ({"E": 70e9, "nu": 0.33, "density": 2.7}, "density = 2.7 looks like g/cm³"),
    # density in t/mm³ (the scene's own unit)
    ({"E": 70e9, "nu": 0.33, "density": 2.7e-9}, "density = 2.7e-09 looks like t/mm³"),
    # E in GPa: 70 Pa at 2700 kg/m³, √(E/ρ) = 0.16 m/s
    ({"E": 70, "nu": 0.33, "density": 2700}, "E = 70 looks like GPa"),
    # yield in MPa beside an SI E: a strain at yield of 3.9e-9
    ({"E": 70e9, "nu": 0.33, "density": 2700, "yield": 276}, "yield = 276 looks like MPa"),
    # ABS from a data sheet in MPa: both stresses in one unit (not E alone in kPa)
    ({"E": 2300, "nu": 0.35, "density": 1040, "yield": 40}, "E = 2300 looks like MPa"),
])
def test_numbers_no_solid_has_name_the_likely_slip(table, slip):
    with pytest.raises(SceneError) as err:
        material(table)
    assert "no solid's" in str(err.value) and slip in str(err.value)


def test_quantities_with_units_give_the_presets_lattice_exactly(tmp_path):
    """c = E/(5·ρ·a²) (docs/calibration.md, the lattice's own ν) by hand, in mm-N-s: E = 70
    GPa = 70,000 MPa, ρ = 2.7 g/cm³ = 2.7e-9 t/mm³, a = 1 mm: c = 70,000 / (5 · 2.7e-9)
    = 5.185185…e12 /s²."""
    hand = 70000.0 / (5.0 * 2.7e-9 * 1.0 ** 2)
    preset = bind_c(bar(tmp_path, '"aluminium"'))
    for table in ('{ E = "70 GPa", nu = 0.33, density = "2.7 g/cm3", yield = "276 MPa" }',
                  '{ E = "70000 N/mm^2", nu = 0.33, density = "2.7e-9 t/mm^3" }',
                  '{ E = "70e9 Pa", nu = 0.33, density = "2700 kg/m³" }'):
        got = bind_c(bar(tmp_path, table))
        assert got == preset, table
        assert got == pytest.approx(hand, rel=1e-15)
    m = material({"E": "10152.6 ksi", "nu": 0.33, "density": "0.0975 lb/in^3",
                  "yield": "40 ksi"})
    # 1 ksi = 6.894757293168361 MPa, 1 lb/in³ = 27,679.9047 kg/m³ (exact definitions)
    assert m.E == pytest.approx(10152.6 * 6.894757293168361e6, rel=1e-14)
    assert m.density == pytest.approx(0.0975 * 27679.904710203125, rel=1e-12)
    # a gel, softer than any rubber, is taken as meant when its unit is written
    assert material({"E": "5 kPa", "nu": 0.45, "density": "1 g/cm3"}).E == 5000.0


def test_a_quantity_of_the_wrong_kind_is_named():
    with pytest.raises(SceneError, match=r"density = '2.7 g' is not a density"):
        material({"E": "70 GPa", "nu": 0.33, "density": "2.7 g"})
    with pytest.raises(SceneError, match=r"E = '70 parsecs' is not a pressure"):
        material({"E": "70 parsecs", "nu": 0.33, "density": 2700})
    with pytest.raises(SceneError, match=r"is not a quantity pint reads"):
        material({"E": "seventy GPa", "nu": 0.33, "density": 2700})
