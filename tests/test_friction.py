"""Coulomb friction on a [[contact]] (``friction = μ``): regularized and history-free, as
LAMMPS' pair gran/hooke (model.operators.Collide.friction; docs/calibration.md "Friction").

A block of a soft solid (E = 10 MPa, 1000 kg/m³: a step of 5 µs) on a held floor under gravity
tilted by θ — an incline without a staircase face —, both lattices aligned, so each of the
block's bottom particles rides on the top of a floor particle.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

SCENE = '''
name = "slide"
units = "mm-N-s"
analysis = "dynamic"
steps = {steps}

[[group]]
name = "block"
fill = {{ box = {{ min = [0, {y0}, 0], max = [{L}, {y1}, {W}] }} }}
spacing = 1.0
origin = [0.5, {yb}, 0.5]
material = {{ E = 1e7, nu = 0.3, density = 1000, name = "gel" }}
{velocity}

[[group]]
name = "floor"
fill = {{ box = {{ min = [-3, -2.01, -2], max = [{FL}, 0.01, {FW}] }} }}
spacing = 1.0
origin = [0.5, 0, 0.5]
material = {{ E = 1e7, nu = 0.3, density = 1000, name = "gel" }}
{support}

[[load]]
on = "block"
gravity = [{gx}, {gy}, 0]

[[contact]]
between = ["block", "floor"]
{friction}
'''

HELD = '[[support]]\non = "floor"\nwhere = { box = { min = [-10, -10, -10], max = [100, 1, 100] } }'


def slide_scene(tmp_path, theta=40.0, mu=0.3, steps=300, L=10, H=5, W=6, held=True,
                velocity=None, overlap=0.0, name="slide.toml"):
    """The block (L × H × W particles) on the floor, gravity 9810 mm/s² at θ from the normal."""
    from rackstress.scenes import load

    th = math.radians(theta)
    yb = 1.0 - overlap                 # R = 1: the two radii
    text = SCENE.format(steps=steps, L=L, W=W, y0=yb - 0.5, y1=yb + H - 0.5, yb=yb,
                        FL=L + 20 if held else L + 7, FW=W + 2,
                        velocity=f"velocity = {list(velocity)}" if velocity else "",
                        support=HELD if held else "",
                        gx=9810 * math.sin(th), gy=-9810 * math.cos(th),
                        friction=f"friction = {mu}" if mu is not None else "")
    path = tmp_path / name
    path.write_text(text)
    return load(str(path))


def test_friction_is_checked(tmp_path):
    """friction is a number >= 0, refused naming the field; a static analysis refuses it."""
    from rackstress.errors import SceneError

    for bad, words in (("-0.2", (">= 0",)), ('"x"', ("finite number",)), ("true", ())):
        with pytest.raises(SceneError) as exc:
            slide_scene(tmp_path, mu=bad)
        assert "[[contact]] #1" in str(exc.value) and "friction" in str(exc.value)
        for w in words:
            assert w in str(exc.value), str(exc.value)
    sc = slide_scene(tmp_path, mu=0.3)
    ops = {t: [op for op in seq if op.kind == "collide"][0] for t, seq in sc.operators.items()}
    mb, mf = sc.groups["block"].mass(sc.units), sc.groups["floor"].mass(sc.units)
    # each side's η·m is the pair's ζ = √(k·m_eff) (k = 2·m·c), and μ the table's
    assert ops["block"].mu == ops["floor"].mu == 0.3
    assert ops["block"].eta * mb == pytest.approx(ops["floor"].eta * mf, rel=1e-12)
    k = 2 * mb * ops["block"].coeff.c
    assert ops["block"].eta * mb == pytest.approx(math.sqrt(k * mb * mf / (mb + mf)), rel=1e-12)
    static = (tmp_path / "slide.toml").read_text().replace('"dynamic"', '"static"')
    (tmp_path / "static.toml").write_text(static)
    from rackstress.scenes import load
    with pytest.raises(SceneError) as exc:
        load(str(tmp_path / "static.toml"))
    assert "friction" in str(exc.value) and "dynamic" in str(exc.value)
    # Eq. 5's velocities are what it reads: the second-order mode refuses it
    from rackstress.cli import _load_scene
    with pytest.raises(SceneError) as exc:
        _load_scene(str(tmp_path / "slide.toml"), None, None, (), "verlet")
    assert "friction" in str(exc.value) and "'euler'" in str(exc.value)


def test_friction_pair_forces_are_equal_and_opposite():
    """Both sides' terms of a pair (c·m and η·m equal) sum to zero, in either regime."""
    from rackstress.model.operators import Collide

    rng = np.random.default_rng(1)
    p, u = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    vp, vu = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    R2 = 1.1 * np.sum((u - p) ** 2, axis=1)
    mp, mu_ = 2.0, 5.0
    for eta_f in (0.1, 100.0):                # Coulomb-limited, then viscous
        cp, cu = np.full(50, 10.0 / mp), np.full(50, 10.0 / mu_)
        fp = mp * Collide.friction(p, u, vp, vu, cp, R2, 0.4, eta_f / mp)
        fu = mu_ * Collide.friction(u, p, vu, vp, cu, R2, 0.4, eta_f / mu_)
        assert np.abs(fp + fu).max() < 1e-12 * np.abs(fp).max()
        assert np.abs(np.sum(fp * (u - p), axis=1)).max() < 1e-12   # tangential


FREE = dict(theta=30.0, mu=0.4, steps=300, held=False, velocity=(5.0, 0.0, 2.0), L=5, H=2, W=3,
            overlap=1e-5)


@pytest.mark.lammps
def test_friction_runs_alike_on_every_engine(tmp_path, monkeypatch):
    """Two free parts sliding under friction (both sides' velocities read), 300 steps: the
    compiled plugin and the callback (numba and NumPy kernels) reach the reference engine's
    positions to round-off (measured 5e-15 to 1.2e-14 mm), and friction moves them by
    micrometres (not a trivial check)."""
    from conftest import lammps_finals, reference_final

    sc = slide_scene(tmp_path, **FREE)
    ref = reference_final(sc)
    none = reference_final(slide_scene(tmp_path, **dict(FREE, mu=None), name="none.toml"))
    assert np.abs(ref - none).max() > 1e-3
    for plugin, kernels, text, p in lammps_finals(sc, monkeypatch):
        assert "comm_modify vel yes" in text and "pair_style lepton" not in text
        assert ("friction 0.4" in text) == plugin
        assert np.abs(p - ref).max() < 1e-12, (plugin, kernels)


@pytest.mark.lammps
@pytest.mark.mpi
def test_friction_runs_alike_under_mpi(tmp_path):
    """The same on two ranks (the plugin; the pairs across the ranks' boundary read their
    ghosts' velocities: comm_modify vel yes)."""
    from conftest import lammps_under_mpi, reference_final

    sc = slide_scene(tmp_path, **FREE)
    got = lammps_under_mpi(tmp_path, "from test_friction import slide_scene, FREE\n"
                           "from pathlib import Path\nimport os\n"
                           f"d = Path({str(tmp_path)!r}) / f'rank-{{os.getpid()}}'\n"
                           "d.mkdir()\nscenes_ = {'free': slide_scene(d, **FREE)}",
                           plugin=True)
    p, counts = got["free"]
    assert min(counts) > 0
    assert np.abs(p - reference_final(sc)).max() < 1e-12


def _slide(tmp_path, theta, mu, steps=1000):
    """The block's mean x over the run (plugin), and the scene."""
    from rackstress.engines.driver import drive
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    sc = slide_scene(tmp_path, theta=theta, mu=mu, steps=steps)
    b = sc.slice("block")
    x0 = sc.original_positions()[b, 0].mean()
    t, x = [], []
    run = LammpsRun(compile_deck(sc, "exact"), None)

    def sample(e):
        t.append(e.step_count * sc.dt)
        x.append(e.positions()[b, 0].mean() - x0)

    drive(run, check_every=10, on_chunk=sample)
    run.close()
    return sc, np.array(t), np.array(x)


@pytest.mark.lammps
@pytest.mark.parametrize("theta, mu", [(40.0, 0.0), (40.0, 0.3), (30.0, 0.3), (45.0, 0.5)])
def test_a_block_slides_down_an_incline_at_g_sin_minus_mu_cos(tmp_path, theta, mu):
    """tan θ > μ: the block slides at g(sin θ − μ cos θ), from its centre of mass over 1000
    steps (5 ms; it moves 0.03–0.07 spacings). Its bottom particles ride on the floor
    particles' tops, which pushes them on along x by |g_y|(1 + μ²)·s/R per unit mass at an
    offset s (the lattice's own, measured with μ = 0): the fit is the solution of
    ẍ = a + ω²x, ω² = |g_y|(1 + μ²)/R, after the first fifth (the contacts taking up the
    weight). Measured 0.997, 1.015, 1.010, 1.020 of the analytical value."""
    sc, t, x = _slide(tmp_path, theta, mu if mu else None)
    th = math.radians(theta)
    gy = 9810 * math.cos(th)
    w = math.sqrt(gy * (1 + mu * mu) / 1.0)
    s = t >= 0.2 * t[-1]
    B = np.column_stack([np.cosh(w * t[s]), np.sinh(w * t[s]) / w,
                         (np.cosh(w * t[s]) - 1) / w ** 2])
    a = np.linalg.lstsq(B, x[s], rcond=None)[0][2]
    assert a == pytest.approx(9810 * (math.sin(th) - mu * math.cos(th)), rel=0.03)


@pytest.mark.lammps
def test_a_block_stays_on_an_incline_below_its_friction_angle(tmp_path):
    """tan θ < μ (20°, μ = 0.5): the block stays; it creeps at about the viscous branch's
    M·g sin θ/(n·ζ) (0.3 mm/s here; measured 0.7 with the contacts' ringing), 8 % of the
    distance it would slide without friction in the same 5 ms (2.9 of 36 µm)."""
    sc, t, x = _slide(tmp_path, 20.0, 0.5)
    free = 0.5 * 9810 * math.sin(math.radians(20.0)) * t[-1] ** 2
    assert 0 <= x[-1] < 0.1 * free


@pytest.mark.lammps
@pytest.mark.mpi
def test_friction_deck_in_plain_lmp(tmp_path):
    """``rackstress deck`` of the two free parts sliding under friction, run by the venv's
    plain ``lmp`` and ``mpiexec -n 2 lmp`` (the plugin's ``rs/collide ... friction``, ghost
    velocities sent): the reference engine's trajectory, frame by frame, to the dump's
    precision."""
    import shutil

    from conftest import trajectory
    from test_plugin import _cli, _frames, _lmp, _same_to_dump_precision

    slide_scene(tmp_path, **FREE)
    f = tmp_path / "slide.toml"
    _cli("run", str(f), "--engine", "reference", "--out", str(tmp_path / "ref"),
         "--no-render", "--no-progress")
    ref = _frames(trajectory(tmp_path / "ref"))
    _cli("deck", str(f), "--out", str(tmp_path / "deck1"))
    text = (tmp_path / "deck1" / "in.lammps").read_text()
    assert " rs/collide " in text and " friction 0.4 " in text and "comm_modify vel yes" in text
    shutil.copytree(tmp_path / "deck1", tmp_path / "deck2")
    _same_to_dump_precision(_lmp(tmp_path / "deck1", 1), ref)
    _same_to_dump_precision(_lmp(tmp_path / "deck2", 2), ref)
