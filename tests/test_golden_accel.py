"""Per-operator accelerations of small hand-made configurations against a golden file.

``tests/data/golden_accel.json`` was written by ``tests/data/make_golden.py``, a separate plain
Python script (no NumPy, no rackstress) that evaluates the paper's Eqs. 8–16 once more from the
text; it is its derivation. Every path that evaluates operators is checked against it:

* the reference engine (``Reference.accelerations``);
* LAMMPS in exact mode as compiled (fix addforce, fix viscous, ``pair_style lepton`` for the
  reciprocal collisions, the Python callback for bind, attract, one-way collisions and contact
  conditions);
* LAMMPS with every pair operator in the Python callback (``native=False``), with the callback's
  NumPy path and with its compiled (numba) kernels;
* LAMMPS fast mode (harmonic bonds): equal to Eq. 12 only to first order in the strain, so it
  must lie within the golden file's ``harmonic_bound`` (Σ c·(d − L0)²/d per particle, the exact
  difference of the two forces per pair).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rackstress import (Attract, Bind, Collide, Const, Contact, Dampen, Force, Group, Matched,
                        Phase, PhaseIn, Scene, Within)
from rackstress.engines.lammps.deck import compile_deck
from rackstress.engines.lammps.runner import LammpsRun
from rackstress.engines.reference import Reference
from rackstress.model.operators import norm2_below

GOLDEN = json.loads((Path(__file__).parent / "data" / "golden_accel.json").read_text())["cases"]
CASES = {case["name"]: case for case in GOLDEN}


def _when(spec) -> tuple:
    out = []
    for cond in spec.get("when", []):
        if "phase" in cond:
            out.append(PhaseIn(cond["phase"][0], tuple(cond["phase"][1])))
        else:
            out.append(Contact(cond["contact"]))
    return tuple(out)


def _coeff(spec):
    if "const" in spec:
        return Const(spec["const"])
    if "within" in spec:
        return Within(*spec["within"])
    return Matched(*spec["matched"])


def _operator(spec, o):
    kind, when = spec["op"], _when(spec)
    if kind == "force":
        where = norm2_below(o, spec["norm2_lt"]) if "norm2_lt" in spec else None
        return Force(tuple(spec["accel"]), where=where, when=when)
    if kind == "dampen":
        return Dampen(spec["c"], spec.get("extra", 0.0), when=when)
    cls = {"collide": Collide, "bind": Bind, "attract": Attract}[kind]
    return cls(spec["source"], _coeff(spec["coeff"]), when=when)


def build(case) -> tuple[Scene, np.ndarray, np.ndarray, np.ndarray]:
    """The case as a scene, and the global p, v and golden accelerations (group order)."""
    groups = {}
    for name, g in case["groups"].items():
        meta = {"regions": {k: np.array(v) for k, v in g["regions"].items()}} if "regions" in g \
            else {}
        groups[name] = Group(name, np.array(g["o"], dtype=float), g["r"], meta=meta)
    ops = {t: [_operator(s, np.array(case["groups"][t]["o"], dtype=float)) for s in seq]
           for t, seq in case["operators"].items()}
    scene = Scene(case["name"], groups, ops, [Phase("golden", 1, case["phase"])], dt=0.01)
    cat = (lambda key: np.concatenate([np.array(case[key][n], dtype=float).reshape(-1, 3)
                                       for n in groups]))
    return scene, cat("p"), cat("v"), cat("accel")


def _assert_golden(a, golden, rtol):
    scale = np.abs(golden).max()
    assert scale > 1.0          # every case has something to get wrong
    np.testing.assert_allclose(a, golden, rtol=rtol, atol=rtol * scale)


def lammps_accel(scene, p, v, phase, **compile_kw):
    deck = compile_deck(scene, **compile_kw)
    run = LammpsRun(deck, None)
    try:
        run.scatter("x", p)
        run.scatter("v", v)
        run.enter_phase(phase)
        f = run.gather_forces()
    finally:
        run.close()
    mass = np.concatenate([np.full(g.n, deck.masses[k]) for k, g in scene.groups.items()])
    return f / mass[:, None], deck


def test_golden_file_is_what_its_script_writes(tmp_path):
    """The committed numbers are the derivation script's output (rerun it into a copy)."""
    import runpy
    import shutil

    script = Path(__file__).parent / "data" / "make_golden.py"
    shutil.copy(script, tmp_path / "make_golden.py")
    runpy.run_path(str(tmp_path / "make_golden.py"), run_name="__main__")
    assert json.loads((tmp_path / "golden_accel.json").read_text())["cases"] == GOLDEN


@pytest.mark.parametrize("name", sorted(CASES))
def test_reference_engine(name):
    case = CASES[name]
    scene, p, v, golden = build(case)
    ref = Reference(scene)
    ref.p, ref.v = p.copy(), v.copy()
    _assert_golden(ref.accelerations(case["phase"]), golden, 1e-12)


@pytest.mark.lammps
@pytest.mark.parametrize("kernels", ["numpy", "numba"])
@pytest.mark.parametrize("native", [True, False], ids=["as-compiled", "all-pairs-in-callback"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_lammps_exact(name, native, kernels, monkeypatch):
    monkeypatch.setenv("RACKSTRESS_KERNELS", kernels)
    case = CASES[name]
    scene, p, v, golden = build(case)
    a, deck = lammps_accel(scene, p, v, case["phase"], mode="exact", native=native)
    how = {r.how for r in deck.realized}
    if name == "collide":       # both realizations of Eq. 10 are exercised
        assert ("lepton" in how) == native and "python" in how
    if name == "force":
        assert how == {"addforce"}
    _assert_golden(a, golden, 1e-10)


@pytest.mark.lammps
def test_lammps_fast_harmonic_bonds_to_first_order():
    case = CASES["bind"]
    scene, p, v, golden = build(case)
    a, deck = lammps_accel(scene, p, v, case["phase"], mode="fast")
    assert {r.how for r in deck.realized} == {"harmonic"} and not deck.python_ops
    bound = np.concatenate([case["harmonic_bound"][n] for n in scene.groups])
    err = np.linalg.norm(a - golden, axis=1)
    assert np.all(err <= bound * (1 + 1e-9) + 1e-12), (err, bound)
    # and the bound is tight enough to mean something: second order, far below the forces
    assert bound.max() < 0.05 * np.abs(golden).max()
    assert err.max() > 0.1 * bound.max()      # harmonic bonds really are not Eq. 12
