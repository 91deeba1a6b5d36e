"""A material solid on the compiled plugin: its bindings' per-pair c (the face
compensation of ``model/solid.py``) as a few bond types, one ``rs/bind`` fix each, against the
reference engine (the paper's equations in NumPy, an independent path) in real LAMMPS."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from rackstress.engines.lammps.deck import compile_deck
from rackstress.scenes import load

pytestmark = pytest.mark.lammps

SCENE = """
name = "bracket-solid"
units = "mm-N-s"
analysis = "dynamic"
steps = {steps}

[[group]]
name = "bracket"
mesh = "bracket.stl"
spacing = 2.0
material = "aluminium"

[[support]]
on = "bracket"
where = {{ cylinder = {{ start = [-1, 6, 8], end = [4, 6, 8], radius = 4 }} }}

[[load]]
on = "bracket"
where = {{ box = {{ min = [27, 26, -1], max = [31, 31, 17] }} }}
force = [0, -100, 0]
"""


def _scene(tmp_path, steps=300):
    from rackstress.bench import repository_file

    shutil.copy(repository_file("examples", "bracket", "bracket.stl"), tmp_path / "bracket.stl")
    f = tmp_path / "solid.toml"
    f.write_text(SCENE.format(steps=steps))
    return load(str(f))


def test_solid_bind_types_carry_every_pair_coefficient(tmp_path):
    """Each bond's type names its pair's own c (the face compensation times the boundary
    cells' fractions, clustered to at most 16 values: one bond type and fix each)."""
    sc = _scene(tmp_path)
    deck = compile_deck(sc, "exact", plugin=True)
    assert deck.plugin and not deck.python_ops            # nothing left in the Python callback
    (r,) = [r for r in deck.realized if r.plugin == "rs/bind"]
    assert len(r.btypes) >= 2                               # compensated and plain pairs
    op = r.op
    pl = op.pairs(sc.groups["bracket"], sc.groups["bracket"])
    keep = pl.i < pl.j
    c_of = dict(r.btypes)
    types, I, J = deck.bonds
    got = np.array([c_of[t] for t in types])
    want = {(int(a) + 1, int(b) + 1): float(c) for a, b, c in
            zip(pl.i[keep], pl.j[keep], pl.c[keep])}
    assert np.array_equal(got, [want[(int(a), int(b))] for a, b in zip(I, J)])
    ratios = np.unique(got / op.coeff.c)
    assert 2 <= len(ratios) <= 16 and ratios.min() > 0
    text = deck.input_text()
    assert text.count(" rs/bind ") == len(r.btypes) and "external" not in text


def test_solid_on_the_plugin_equals_the_reference_engine(tmp_path, reference_final):
    """300 steps of the loaded bracket (explicit dynamics): plugin = reference to 1e-10 mm."""
    from rackstress.engines.driver import drive
    from rackstress.engines.lammps.runner import LammpsRun

    sc = _scene(tmp_path)
    ref = reference_final(sc)
    assert np.abs(ref - sc.original_positions()).max() > 1e-6       # it really moved
    run = LammpsRun(compile_deck(sc, "exact", plugin=True), None)
    try:
        p = drive(run).positions
    finally:
        run.close()
    assert np.abs(p - ref).max() <= 1e-10


def test_weight_levels_compiled_and_plain_agree_to_the_bit():
    """model.solid.levels clusters the bindings' weights into at most 16 values (the plugin's
    bond types): the interior's most common weight kept exact, the rest replaced by their
    cluster means. Its 1D k-means table, compiled (numba) and in NumPy (the path without
    numba), gives the same weights to the bit."""
    from rackstress.model import solid

    rng = np.random.default_rng(0)
    w = np.r_[np.ones(5000), rng.random(3000) * 2, np.round(rng.random(500), 2)]
    compiled = solid.levels(w)
    saved = solid._KMEANS
    try:
        solid._KMEANS = solid._kmeans_table_numpy
        plain = solid.levels(w)
    finally:
        solid._KMEANS = saved
    assert solid._kmeans_table_compiled() is not None
    assert np.array_equal(compiled, plain)
    assert len(np.unique(compiled)) <= solid.WEIGHT_LEVELS
    assert np.all(compiled[:5000] == 1.0)
