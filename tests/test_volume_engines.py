"""The volumetric term (the material's Poisson's ratio) realized in every engine: the compiled
plugin (``fix rs/volume``, serial, ``mpiexec -n 2``, plain ``lmp`` on a generated deck), the
Python callback (numba and NumPy kernels) and the static solver's forces, each against the
reference engine — the term's own formula in NumPy, an independent path — to round-off."""
from __future__ import annotations

import shutil

import numpy as np
import pytest
from conftest import lammps_under_mpi, trajectory
from test_plugin import _cli, _frames, _lmp, _same_to_dump_precision

from rackstress.engines.driver import drive
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import LammpsRun
from rackstress.engines.reference import Reference
from rackstress.engines.static import _bind_pairs, external_forces, forces
from rackstress.scenes.toml import load_toml

pytestmark = pytest.mark.lammps

#: a holed plate of a rubbery ν (κ/μ large: the term dominates), cells of every fraction
#: round the hole, loaded off its supports: it bends and twists
HOLED = """
name = "holed"
units = "mm-N-s"
analysis = "dynamic"
steps = {steps}

[[group]]
name = "plate"
fill = {{ difference = [ {{ box = {{ min = [0, 0, 0], max = [10, 6, 3] }} }},
                        {{ cylinder = {{ start = [5, 3, -1], end = [5, 3, 4], radius = 1.6 }} }} ] }}
spacing = 0.9
material = {{ E = 70e9, nu = 0.45, density = 2700 }}
poisson = "material"

[[support]]
on = "plate"
where = {{ box = {{ min = [-1, -1, -1], max = [0.6, 7, 4] }} }}

[[load]]
on = "plate"
where = {{ box = {{ min = [9.3, -1, -1], max = [11, 3, 4] }} }}
force = [0, 20, -50]
"""


def _scene(tmp_path, steps=300):
    f = tmp_path / "holed.toml"
    f.write_text(HOLED.format(steps=steps))
    return f, load_toml(f)


def _accelerations(deck, p):
    """LAMMPS' forces / its masses (the paper's accelerations) after ``run 0`` at ``p``."""
    run = LammpsRun(deck, None)
    try:
        run.enter_phase(deck.scene.phases[0].vars)
        run.scatter("x", p)
        run.command("run 0 post no")
        f = run.gather_forces()
    finally:
        run.close()
    sc = deck.scene
    m = np.concatenate([np.full(g.n, deck.masses.get(n, 1.0)) for n, g in sc.groups.items()])
    return f / m[:, None]


@pytest.mark.parametrize("how", ["plugin", "numba", "numpy", "static"])
def test_one_evaluation_on_a_distorted_part(how, tmp_path, monkeypatch):
    """The forces of one step on a randomly distorted holed plate: the plugin's rs/volume
    (carrying the part's bindings too), the callback's kernels and the static solver's
    forces with the loads (÷ m) equal the reference engine's to round-off (1e-12 of the
    largest), on every free particle — one scene, every engine."""
    _, sc = _scene(tmp_path)
    rng = np.random.default_rng(7)
    p = sc.original_positions() + 0.01 * rng.standard_normal((sc.n_particles, 3))
    ref = Reference(sc)
    ref.p = p.copy()
    a_ref = ref.accelerations({})
    if how == "static":
        m = sc.masses()
        F = external_forces(sc)
        got = forces(sc, p, _bind_pairs(sc), F, m) / m[:, None]
    else:
        if how != "plugin":
            monkeypatch.setenv("RACKSTRESS_KERNELS", how)
        deck = compile_deck(sc, "exact", plugin=how == "plugin")
        want = {"plugin": ["rs/bind", "rs/volume"], "numba": ["python", "python"],
                "numpy": ["python", "python"]}[how]
        assert [r.how for r in deck.realized if r.target == "plate"][:2] == want
        if how == "plugin":     # the part's bindings carried by rs/volume, no rs/bind left
            fixes = [ln for ln in deck.input_text().splitlines() if ln.startswith("fix ")]
            assert not [ln for ln in fixes if " rs/bind " in ln]
            assert [ln for ln in fixes if " rs/volume " in ln and " bind " in ln]
        got = _accelerations(deck, p)
    free = ~sc.fixed()
    assert np.abs(np.where(free, got - a_ref, 0.0)).max() <= 1e-12 * np.abs(a_ref).max()


@pytest.mark.parametrize("plugin", [True, False])
def test_short_dynamic_run_follows_the_reference(plugin, tmp_path, reference_final):
    """300 steps of the loaded plate (explicit dynamics, the time step from the predicted
    stability limit, which the term stiffens): LAMMPS with the plugin, and with the callback,
    end where the reference engine does, to 1e-10 mm."""
    _, sc = _scene(tmp_path)
    ref = reference_final(sc)
    assert np.abs(ref - sc.original_positions()).max() > 1e-5       # it really moved
    run = LammpsRun(compile_deck(sc, "exact", plugin=plugin), None)
    try:
        p = drive(run).positions
    finally:
        run.close()
    assert np.abs(p - ref).max() <= 1e-10


@pytest.mark.slow
@pytest.mark.mpi
def test_runs_under_mpi(tmp_path, reference_final):
    """The same under ``mpiexec -n 2`` (atoms split over both ranks; the plugin's forces on
    partners seen as ghosts reach their owners by one reverse communication): plugin and
    callback both end at the reference engine's positions to 1e-10 mm."""
    f, sc = _scene(tmp_path)
    ref = reference_final(sc)
    setup = f"""
from rackstress.scenes.toml import load_toml
scenes_ = {{"s": load_toml({str(f)!r})}}
"""
    for plugin in (True, False):
        out = tmp_path / ("plugin" if plugin else "callback")
        out.mkdir()
        p, counts = lammps_under_mpi(out, setup, plugin=plugin)["s"]
        assert len(counts) == 2 and counts.min() > 0
        assert np.abs(p - ref).max() <= 1e-10, plugin


@pytest.mark.slow
@pytest.mark.mpi
def test_standalone_deck_in_plain_lmp(tmp_path):
    """``rackstress deck`` (data file, volume.atoms with the boundary cells, in.lammps) run
    by the venv's plain ``lmp`` and ``mpiexec -n 2 lmp`` writes the reference engine's
    trajectory, frame by frame, to the dump's precision."""
    f, _ = _scene(tmp_path, steps=200)
    _cli("run", str(f), "--engine", "reference", "--out", str(tmp_path / "ref"),
         "--no-render", "--no-progress")
    ref = _frames(trajectory(tmp_path / "ref"))
    _cli("deck", str(f), "--out", str(tmp_path / "deck1"))
    text = (tmp_path / "deck1" / "in.lammps").read_text()
    assert " rs/volume " in text and "external" not in text
    assert (tmp_path / "deck1" / "volume.atoms").is_file()
    shutil.copytree(tmp_path / "deck1", tmp_path / "deck2")
    _same_to_dump_precision(_lmp(tmp_path / "deck1", 1), ref)
    _same_to_dump_precision(_lmp(tmp_path / "deck2", 2), ref)


#: a free 4 × 4 × 4 mm aluminium block of the material's ν, every cell whole (the spacing
#: divides it) and none held, thrown at 100 mm/s
FREE_BLOCK = """
name = "thrown"
units = "mm-N-s"
analysis = "dynamic"
dt = 1e-7
steps = 50

[[group]]
name = "b"
fill = { box = { min = [0, 0, 0], max = [4, 4, 4] } }
spacing = 1
material = { E = 70e9, nu = 0.3, density = 2700 }
poisson = "material"
velocity = [100.0, 0.0, 0.0]
"""


@pytest.mark.parametrize("engine", ["lammps", "reference"])
def test_a_free_block_whose_cells_are_all_whole_runs(engine, tmp_path):
    """Nothing for ``volume.atoms`` to list (no boundary cell that is not whole, no support):
    the plugin's deck sets every cell whole and reads no atomfile (LAMMPS refuses a set of
    none: the run stopped at step 0, "Atomfile variable rs_phi could not read values"). The
    block, at rest length and unloaded, translates: every particle moves by v·t = 100 mm/s ×
    50 × 1e-7 s = 5e-4 mm along x (hand calculation), on LAMMPS as on the reference engine."""
    from test_faults import QUIET, rs

    (tmp_path / "b.toml").write_text(FREE_BLOCK)
    out = tmp_path / engine
    r = rs("run", tmp_path / "b.toml", "--engine", engine, "--out", out, *QUIET)
    assert r.returncode == 0, r.stderr
    if engine == "lammps":
        assert " rs/volume " in (out / "in.lammps").read_text()
        assert "atomfile" not in (out / "in.lammps").read_text()
        assert not (out / "volume.atoms").exists()
    frames = _frames(trajectory(out))
    (_, i0, p0), (step, i1, p1) = frames[0], frames[-1]
    assert step == 50 and len(i0) == 64
    d = p1[np.argsort(i1)] - p0[np.argsort(i0)]
    # to the dump's precision (%.10g of coordinates below 4 mm: 1e-9 mm each)
    assert d[:, 0] == pytest.approx(np.full(64, 5e-4), abs=2e-9)
    assert np.abs(d[:, 1:]).max() <= 2e-9


#: a sheet one particle thick (no neighbour along z), held in z over part of it (a roller on
#: a floor): a support across an axis without neighbours holds no face, in every engine
SHEET = """
name = "sheet"
units = "mm-N-s"
analysis = "dynamic"
steps = 10

[[group]]
name = "sheet"
fill = { box = { min = [0, 0, 0], max = [8, 5, 1] } }
spacing = 1
material = { E = 70e9, nu = 0.45, density = 2700 }
poisson = "material"

[[support]]
on = "sheet"
where = { box = { min = [-1, -1, -1], max = [0.6, 6, 2] } }

[[support]]
on = "sheet"
where = { box = { min = [2.2, -1, -1], max = [5.8, 6, 2] } }
type = "fixed"
fix = ["z"]
"""


def test_a_sheet_held_across_its_thickness_has_the_same_forces_in_the_plugin(tmp_path):
    """A sheet one particle thick held in z (its normal, along which no particle has a
    neighbour) over part of it: the plugin's rs/volume treats that axis as not held, as the
    reference engine's term does (rackstress.model.volume.build: the sheet stays in plane
    stress there), and their forces on a distorted sheet agree to round-off on every free
    direction. The plugin had read the support as holding the overhang across z (a bulk
    modulus where the term has plane stress): the SO-100 moving jaw's equilibrium with
    ``poisson = "material"`` was 0.0014 of its load out of balance in LAMMPS."""
    f = tmp_path / "sheet.toml"
    f.write_text(SHEET)
    sc = load_toml(f)
    g = sc.groups["sheet"]
    assert np.ptp(g.o[:, 2]) == 0.0                       # one layer
    held_z = np.asarray(g.fixed, bool)[:, 2] & ~np.asarray(g.fixed, bool)[:, 0]
    assert held_z.sum() >= 10                             # the roller holds some in z only
    rng = np.random.default_rng(3)
    p = sc.original_positions() + 0.01 * rng.standard_normal((sc.n_particles, 3))
    ref = Reference(sc)
    ref.p = p.copy()
    a_ref = ref.accelerations({})
    deck = compile_deck(sc, "exact", plugin=True)
    assert [r.how for r in deck.realized if r.target == "sheet"][:2] == ["rs/bind", "rs/volume"]
    got = _accelerations(deck, p)
    free = ~sc.fixed()
    assert np.abs(np.where(free, got - a_ref, 0.0)).max() <= 1e-12 * np.abs(a_ref).max()
