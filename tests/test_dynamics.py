"""Time stepping in physical units against analytical answers (rackstress bench dynamics,
docs/benchmarks/dynamics.md): the cantilever's free vibration and a bar striking a wall, on
LAMMPS as ``rackstress run`` steps them."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rackstress.bench import dynamics, program


def test_timoshenko_reference_is_euler_bernoulli_for_a_slender_bar_and_converged():
    """The reference's own check: at L/h = 1000 shear and rotary inertia vanish, so f1–f3 are
    Euler–Bernoulli's (β_nL = 1.8751, 4.6941, 7.8548) within 0.1 %; at L/h = 10 it does not
    move between 400 and 800 elements."""
    slender = dynamics.timoshenko(L=10000.0)
    assert np.allclose(slender / dynamics.euler_bernoulli(L=10000.0), 1, atol=1e-3)
    assert np.allclose(dynamics.timoshenko(n=400) / dynamics.timoshenko(n=800), 1, atol=1e-4)


def test_spectral_peaks_of_a_known_signal():
    t = np.arange(2000) * 2e-6
    x = np.sin(2 * np.pi * 816 * t) + 0.3 * np.sin(2 * np.pi * 4890 * t + 1.0)
    assert np.allclose(dynamics.peaks(t, x, 2), [816, 4890], rtol=2e-3)


@pytest.mark.lammps
def test_cantilever_rings_at_timoshenkos_frequencies():
    """The issue's target: f1–f3 from the run's own tip history within 2 % (1.25 mm: eight
    particles across the 10 mm bar) of the Timoshenko beam's; Euler–Bernoulli's f3 is 12 %
    higher, which the lattice must not follow."""
    r = dynamics.vibration(1.25, echo=lambda *a: None)
    ref = dynamics.timoshenko()
    assert len(r["f"]) == 3
    assert np.allclose(np.asarray(r["f"]) / ref, 1, atol=0.02), r["f"]
    assert r["f"][2] < 0.95 * dynamics.euler_bernoulli()[2]


@pytest.mark.lammps
def test_a_bar_striking_a_wall_carries_rho_c_v_at_the_bar_speed():
    """σ_xx behind the front = −ρ·c·v (2.7e-9 t/mm³ × 5.092e6 mm/s × 1000 mm/s = 13.75 MPa,
    compression) and its arrival at mid-length x/c = 9.82 µs, each within 2 %."""
    r = dynamics.impact(1.25, echo=lambda *a: None)
    c = np.sqrt(70000.0 / 2.7e-9)
    assert r["sigma_expected"] == pytest.approx(-2.7e-9 * c * 1000.0, rel=1e-12)
    assert r["sigma_plateau"] == pytest.approx(-13.75, rel=0.02)
    assert r["arrival"] == pytest.approx(50.0 / c, rel=0.02)


@pytest.mark.lammps
def test_a_runs_peaks_over_time_per_particle_and_when(tmp_path):
    """``rackstress run`` of a dynamic scene writes vtk/peaks_over_time.vtp: each particle's
    largest von Mises stress over the frames (equal to the series' own frame-by-frame values,
    read back by pyvista) and its time; no particle of the struck bar peaks before the wave
    can reach it (x/c, c = √(E/ρ): the front's precursor travels at most at the lattice's
    longitudinal speed, within 10 % of it for this bar)."""
    import subprocess
    import sys

    import pyvista as pv

    out = tmp_path / "impact"
    r = subprocess.run([sys.executable, "-m", "rackstress.cli", "run", str(dynamics.IMPACT),
                        "--out", str(out), "--dump-every", "5", "--no-render", "--no-progress"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    # the error bar is said, but --refine (static parts only: it refuses a dynamic scene) is
    # not offered
    said = r.stdout + r.stderr
    assert "may be off by about" in said and "--refine" not in said, said
    peaks = pv.read(out / "vtk" / "peaks_over_time.vtp")
    series = pv.get_reader(out / "vtk" / "run.pvd")
    frames, steps = [], []
    for t in series.time_values:
        series.set_active_time_value(t)
        m = series.read()[0]
        frames.append(np.asarray(m.point_data["von_mises"])[np.argsort(m.point_data["id"])])
        steps.append(int(round(t)))
    V = np.array(frames)
    order = np.argsort(peaks["id"])
    assert np.allclose(peaks["von_mises_max"][order], V.max(axis=0), rtol=1e-6, atol=1e-6)
    k = np.asarray(peaks["von_mises_max_iteration"])[order]
    assert np.array_equal(k, np.asarray(steps)[V.argmax(axis=0)])
    dt = float(json.loads((out / "summary.json").read_text())["dt"])
    assert np.allclose(peaks["von_mises_max_time"], peaks["von_mises_max_iteration"] * dt)
    # the governing stress frame by frame (the plot's line): its largest over the frames is the
    # run's governing stress, which summary.json found frame by frame in a loop of its own
    from rackstress.stress.governing import over_time
    from rackstress.stress.post import compute_fields
    from rackstress.stress.rundata import load_run

    run = load_run(out)
    series = over_time(run, compute_fields(run, cache=True).values["von_mises"])
    gov = json.loads((out / "summary.json").read_text())["stress"]["governing"]
    assert np.nanmax(series["bar"]) == pytest.approx(gov["value"], rel=1e-12)
    assert len(series["bar"]) == len(steps)
    x = np.asarray(peaks.points)[:, 0]
    c = np.sqrt(70000.0 / 2.7e-9)
    far = x > 10.0
    assert (np.asarray(peaks["von_mises_max_time"])[far] >= 0.9 * x[far] / c).all()


@pytest.mark.lammps
def test_two_bars_in_contact_exchange_their_motion():
    """[[contact]] between two aluminium bars (examples/dynamics/collision.toml, 2 mm): the
    pair's forces are equal and opposite (each side's c = k/(2m)), so the momentum after is the
    momentum before to round-off; the struck bar carries −ρ·c·v/2 (6.87 MPa) within 3 % (the
    lattice's E_eff is 1.5 % stiff at 2 mm: ρ·c within 1 %; the plateau rings by ±0.9 MPa);
    the bars touch for 2L/c (L = n·a, the lattice's bar) within 5 %, and leave with their
    motion exchanged: the striker below 5 % of v, the struck bar above 95 %."""
    r = dynamics.collision(2.0, echo=lambda *a: None)
    assert r["momentum_ratio"] == pytest.approx(1.0, abs=1e-6)
    assert r["sigma_expected"] == pytest.approx(-6.875, rel=1e-3)
    assert r["sigma_plateau"] == pytest.approx(r["sigma_expected"], rel=0.03)
    assert r["contact"] == pytest.approx(2 * 52.0 / np.sqrt(70000.0 / 2.7e-9), rel=0.05)
    left, right = r["velocity_after"]
    assert abs(left) < 50.0 and right > 950.0


def test_contact_tables_are_checked(tmp_path):
    """[[contact]] names two different material parts, its friction is a number >= 0 and its
    stiffness factor is positive; each refusal names the table and the key."""
    from rackstress.errors import SceneError
    from rackstress.scenes.toml import load_toml

    base = dynamics.COLLISION.read_text()
    cases = {
        'between = ["left", "left"]': ("[[contact]] #1", "between", "itself"),
        'between = ["left", "floor"]': ("[[contact]] #1", "unknown group 'floor'"),
        'between = ["left", "right"]\nfriction = -0.3': ("[[contact]] #1", "friction",
                                                         ">= 0"),
        'between = ["left", "right"]\nfriction = "a"': ("[[contact]] #1", "friction",
                                                        "finite number"),
        'between = ["left", "right"]\nstiffness = -1': ("[[contact]] #1", "stiffness"),
        'between = "left"': ("[[contact]] #1", "between", "two groups"),
    }
    for table, words in cases.items():
        f = tmp_path / "c.toml"
        f.write_text(base.replace('between = ["left", "right"]', table))
        with pytest.raises(SceneError) as exc:
            load_toml(f)
        for w in words:
            assert w in str(exc.value), (table, str(exc.value))
    # a paper group (no material) is refused with what to use instead
    paper = tmp_path / "p.toml"
    paper.write_text('name = "p"\nsteps = 1\n[[group]]\nname = "a"\npositions = [[0, 0, 0]]\n'
                     'radius = 0.5\n[[group]]\nname = "b"\npositions = [[3, 0, 0]]\n'
                     'radius = 0.5\n[[contact]]\nbetween = ["a", "b"]\n')
    with pytest.raises(SceneError) as exc:
        load_toml(paper)
    assert "not a material part" in str(exc.value) and "collide" in str(exc.value)


@pytest.mark.lammps
def test_a_contact_too_stiff_for_the_step_is_a_divergence_naming_its_step(tmp_path):
    """A contact a million times stiffer, run at the lattice's time step (--allow-unstable):
    the bars start touching at zero force, close by v·dt in the first step, and the pair's
    spring k = 10⁶·E*·a throws each first-layer particle at Δv = (k/m)·(v·dt)·dt in the
    second, far beyond its material's wave speed √(E/ρ) (hand calculation below). The run stops
    as diverged (exit 3) naming that step, the particle and both speeds; on LAMMPS, which looks
    every hundred steps, at its first look, saying after which step it went wrong."""
    import re

    from test_faults import rs

    from rackstress.model.materials import PRESETS

    al = PRESETS["aluminium"]
    a, v, dt = 5.0, 1000.0, 1.8e-7                     # mm, mm/s, s
    e_star = al.E / 1e6 / (2 * (1 - al.nu ** 2))       # MPa: two equal materials
    m = al.density * 1e-12 * a ** 3                     # t (kg → t, m³ → mm³)
    jump = 1e6 * e_star * a / m * (v * dt) * dt        # mm/s
    c = (al.E / al.density) ** 0.5 * 1000.0             # mm/s
    assert jump > 3 * c
    scene = tmp_path / "stiff.toml"
    scene.write_text(dynamics.COLLISION.read_text()
                     .replace("spacing = 2.0 ", "spacing = 5.0 ")
                     .replace('between = ["left", "right"]',
                              'between = ["left", "right"]\nstiffness = 1e6'))
    for engine in ("reference", "lammps"):
        out = tmp_path / engine
        r = rs("run", scene, "--out", out, "--engine", engine, "--dt", dt, "--allow-unstable",
               "--steps", 300, "--no-render")
        assert r.returncode == 3, r.stderr
        s = json.loads((out / "summary.json").read_text())
        assert s["status"] == "diverged", s
        msg = s["error"]["message"]
        assert "faster than its material's wave speed" in msg and "mm/s" in msg, msg
        assert s["error"]["group"] in ("left", "right")
        got = [float(x) for x in re.findall(r"(?:moves at|√\(E/ρ\) =) ([\d.e+]+) mm/s", msg)]
        assert got[1] == pytest.approx(c, rel=1e-3)
        if engine == "reference":                      # looks every step: the step itself
            assert s["error"]["step"] == 2, msg
            assert got[0] == pytest.approx(jump, rel=0.02), msg
        else:
            assert s["error"]["step"] == 100 and "went wrong after step 0" in msg, msg


def _frame(rundir, last: bool):
    """Positions (id order) of a run's first or last dumped frame, from the dump's own text."""
    from conftest import dump_text, trajectory

    frames = dump_text(trajectory(rundir)).split("ITEM: TIMESTEP")[1:]
    body = (frames[-1] if last else frames[0]).split("ITEM: ATOMS", 1)[1]
    cols = body.splitlines()[0].split()
    rows = np.array([ln.split() for ln in body.splitlines()[1:] if ln.strip()], float)
    p = rows[:, [cols.index(k) for k in ("x", "y", "z")]]
    return p[np.argsort(rows[:, cols.index("id")].astype(int))]


@pytest.mark.lammps
@pytest.mark.mpi
def test_contact_runs_alike_on_the_reference_engine_and_lammps_under_mpi(tmp_path):
    """The two bars in contact, 120 steps (the wave well into both): LAMMPS on two ranks
    reaches the reference engine's positions to round-off (the contact as the plugin's
    rs/collide, one fix a side). At step 60, mid-contact, the layer of each bar that touches
    reads the compression the layer behind it does, σ_xx = −ρ·c·v/2 (6.87 MPa by hand; within 15 %: the
    penalty contact rings about it, measured 6 %), and its contact pressure is ρ·c·v/2 too —
    the contact's force counted once (its cells' share of the bar is half: the surface passes
    through the particles; counted twice it read 13.6)."""
    import subprocess
    import sys
    from pathlib import Path

    mpiexec = Path(sys.executable).parent / "mpiexec"
    common = [str(dynamics.COLLISION), "--steps", "120", "--dump-every", "60", "--no-render",
              "--no-progress"]
    ref = subprocess.run([sys.executable, "-m", "rackstress.cli", "run", *common, "--engine",
                          "reference", "--out", str(tmp_path / "ref")],
                         capture_output=True, text=True)
    assert ref.returncode == 0, ref.stderr
    mpi = subprocess.run([str(mpiexec), "-n", "2", sys.executable, "-m", "rackstress.cli",
                          "run", *common, "--out", str(tmp_path / "mpi")],
                         capture_output=True, text=True)
    assert mpi.returncode == 0, mpi.stderr
    deck = (tmp_path / "mpi" / "in.lammps").read_text()
    assert "rs/collide" in deck and "pair_style lepton" not in deck   # compiled, one a side
    a, b = _frame(tmp_path / "ref", last=True), _frame(tmp_path / "mpi", last=True)
    moved = np.abs(a - _frame(tmp_path / "ref", last=False)).max()
    assert moved > 1e-3                       # the bars moved and pressed: not a trivial check
    assert np.abs(a - b).max() < 1e-9 * 100.0
    from rackstress.model.materials import PRESETS
    from rackstress.stress.measures import ParticleStress
    from rackstress.stress.rundata import load_run

    al = PRESETS["aluminium"]
    half = al.density * (al.E / al.density) ** 0.5 * 1.0 / 2 / 1e6        # MPa at 1 m/s
    run = load_run(tmp_path / "mpi")
    k = list(run.steps).index(60)
    r = ParticleStress(run, method="virial").run().results
    for name, face_x, behind_x in (("left", 50.0, 46.0), ("right", 52.0, 56.0)):
        idx = run.parts[name].index
        face = idx[np.isclose(run.o[idx, 0], face_x)]
        behind = idx[np.isclose(run.o[idx, 0], behind_x)]
        assert len(face) == len(behind) == 25
        assert -r.stress[k][face, 0].mean() == pytest.approx(half, rel=0.15), name
        assert -r.stress[k][behind, 0].mean() == pytest.approx(half, rel=0.15), name
        assert r.contact_pressure[k][face].mean() == pytest.approx(half, rel=0.15), name


@pytest.mark.lammps
def test_the_drop_example_lands_and_bounces_without_passing_through():
    """examples/dynamics/drop.toml at 2 mm: the bracket arrives at √(2·g·0.5 m) = 3,132 mm/s,
    its leg never sinks into the steel floor by more than a fifth of a spacing (the contact
    holds; measured 0.003 mm), and it leaves moving up no faster than it came (no energy
    made; measured 34 mm/s: the rest rings in the arm and turns the bracket)."""
    from rackstress.scenes import load

    sc = load(str(dynamics.repository_file("examples", "dynamics", "drop.toml")),
              {"spacing": 2.0})
    b, f = sc.slice("bracket"), sc.slice("floor")
    v0 = float(sc.groups["bracket"].v0[0, 1])
    assert v0 == pytest.approx(-np.sqrt(2 * 9810 * 500), rel=1e-9)
    t, gap, com = [], [], []

    def sample(time_, p):
        t.append(time_)
        gap.append(float(p[b, 1].min() - p[f, 1].max()))
        com.append(float(p[b, 1].mean()))

    dynamics._stepped(dynamics.repository_file("examples", "dynamics", "drop.toml"), 2.0,
                      None, 5, sample)
    t, gap, com = np.asarray(t), np.asarray(gap), np.asarray(com)
    assert gap.min() > 2.0 - 0.2 * 2.0            # R = 2 mm: two radii of 1 mm
    v_end = np.polyfit(t[-20:], com[-20:], 1)[0]
    assert 0 < v_end < abs(v0)


#: aluminium's and gravity's data (mm-N-s: MPa, t/mm³, mm/s²) and the drop (mm)
AL_E, AL_NU, AL_RHO, G, HEIGHT = 70000.0, 0.33, 2.7e-9, 9810.0, 500.0


def _lmp_on(rundir, into):
    """Plain ``lmp -in in.lammps`` (the venv's, serial) on a copy of a run's deck — the deck
    ``rackstress deck`` writes for the same scene (the bench checks they are equal)."""
    import shutil
    import subprocess

    into.mkdir()
    for name in ("in.lammps", "particles.data"):
        shutil.copy(rundir / name, into / name)
    r = subprocess.run([str(program("lmp")), "-in", "in.lammps", "-screen", "none"],
                       cwd=into, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return into / "trajectory.dump"


@pytest.fixture(scope="module")
def drop3(tmp_path_factory):
    """The bench's drop row at 3 mm (the quick variant's spacing), a frame every 100 steps,
    from ``rackstress run`` as a user runs it: (row, the run's directory)."""
    root = tmp_path_factory.mktemp("drop3")
    r = dynamics.drop(3.0, engines=(), root=root, echo=lambda *a: None, dump_every=100)
    (serial,) = [p / "serial" for p in root.iterdir()]
    return r, serial


@pytest.mark.lammps
def test_the_drop_bench_row_lands_as_physics_says_and_plain_lmp_steps_it_alike(drop3, tmp_path):
    """The bench's drop row at 3 mm (the quick variant's spacing), from ``rackstress run`` as
    a user runs it. By hand: the floor box 50 × 6 × 36 mm on the lattice through
    (−8.5, −4.5, −8.5) holds 17 × 2 × 12 = 408 sites; the bracket arrives at √(2·g·h) =
    3,132 mm/s (its first frames' mean velocity within 1 %) and its centre of mass never moves
    faster than that plus what gravity adds over the run, g·T = 3.9 mm/s (no energy made by
    the contact); it ends slower than it came. No bracket particle reaches its peak von Mises
    before a wave from the floor can reach it: its height above the leg's end over the
    dilatational speed c_p = √(E(1 − ν)/((1 + ν)(1 − 2ν)ρ)) = 6,198 m/s, the fastest a
    signal crosses the elastic solid (90 % of it: the lattice's own speed is within a few
    percent). Plain ``lmp`` on the same deck dumps the serial run's frames to the dump's
    precision."""
    import pyvista as pv

    r, serial = drop3
    assert r["floor"] == 17 * 2 * 12 and r["bracket"] == r["particles"] - 408 > 0
    v0 = np.sqrt(2 * G * HEIGHT)
    assert r["speed"] == pytest.approx(v0, rel=1e-12)
    T = r["steps"] * r["dt"]
    assert T == pytest.approx(4.0e-4, rel=0.01)
    vel = r["velocity"]
    assert vel["v_start"] == pytest.approx(-v0, rel=0.01)
    assert vel["v_min"] >= -(v0 + G * T) * (1 + 1e-9)
    assert abs(vel["v_end"]) < v0
    assert r["peak"]["units"] == "MPa" and 0 < r["peak"]["time"] <= T * (1 + 1e-9)
    assert r["contact"]["units"] == "MPa" and r["contact"]["peak"] > 0
    assert r["contact"]["group"] in ("bracket", "floor")
    pk = pv.read(serial / "vtk" / "peaks_over_time.vtp")
    brk = np.asarray(pk["group_id"]) == np.asarray(pk["group_id"])[np.argmin(pk["id"])]
    y = np.asarray(pk.points)[brk, 1]
    c_p = np.sqrt(AL_E * (1 - AL_NU) / ((1 + AL_NU) * (1 - 2 * AL_NU) * AL_RHO))
    assert c_p == pytest.approx(6.198e6, rel=1e-3)
    assert (np.asarray(pk["von_mises_max_time"])[brk] >= 0.9 * (y - y.min()) / c_p).all()
    # plain lmp on the run's deck: the same frames
    from rackstress.stress.rundata import load_run

    o = load_run(serial).o
    cmp = dynamics._compare(dynamics._frames_of(_lmp_on(serial, tmp_path / "lmp"), o),
                            dynamics._frames_of(dynamics._trajectory(serial), o))
    assert cmp["frames"] >= r["frames"] - 1 >= 19             # 1,973 steps, every 100th
    assert cmp["to_dump_precision"], cmp


@pytest.mark.lammps
@pytest.mark.mpi
def test_the_drop_under_mpiexec_steps_as_the_serial_run_does(drop3, tmp_path):
    """The serial run's deck (the one ``rackstress deck`` writes: the compiled plugin's styles,
    no Python) under ``mpiexec -n 2 lmp``: the run's own frames to the dump's precision, the
    particles split over two ranks. (``mpiexec -n 2 rackstress run`` itself: the bench, at
    ~20,000 particles; at 3 mm its command alone takes longer than this test may.)"""
    import shutil
    import subprocess

    _, serial = drop3
    two = tmp_path / "two"
    two.mkdir()
    for name in ("in.lammps", "particles.data"):
        shutil.copy(serial / name, two / name)
    assert "rs/" in (two / "in.lammps").read_text()
    r = subprocess.run([str(program("mpiexec")), "-n", "2", str(program("lmp")),
                        "-in", "in.lammps", "-log", "log.lammps", "-screen", "none"], cwd=two,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    import re

    grid = re.search(r"(\d+) by (\d+) by (\d+) MPI processor grid",
                     (two / "log.lammps").read_text())
    assert grid and np.prod([int(x) for x in grid.groups()]) == 2
    from rackstress.stress.rundata import load_run

    o = load_run(serial).o
    ref = dynamics._frames_of(dynamics._trajectory(serial), o)
    cmp = dynamics._compare(dynamics._frames_of(two / "trajectory.dump", o), ref)
    assert cmp["frames"] >= len(ref[0]) - 1 >= 19 and cmp["to_dump_precision"], cmp


@pytest.mark.lammps
def test_the_pin_joint_bench_row_bears_the_load_and_plain_lmp_checks_its_equilibrium(tmp_path):
    """The bench's pin-joint row at 2 mm (the quick variant's): settled, by at least one
    active set; the pin bears on the lug's hole with more than the mean bearing pressure of
    the quarter model, F/4 over the half hole's projected area (d/2)·(t/2): 1,250 N / 25 mm²
    = 50 MPa (the close fit's cosine distribution peaks at 4/π of it); and the equilibrium's
    deck in plain ``lmp`` leaves the run's own unbalanced force, to round-off."""
    r = dynamics.assembly(2.0, engines=("lmp",), root=tmp_path, echo=lambda *a: None)
    assert r["status"] == "settled" and r["residual"] <= 1e-6
    assert r["contact_sets"] >= 1 and r["iterations"] >= 1
    on_lug = max(v for k, v in r["contact"].items() if "lug" in k)    # either side's record
    assert on_lug > 1250.0 / (5.0 * 5.0)
    assert r["contact_peak"] >= on_lug
    assert r["governing"] > 0 and r["governing_part"] in ("lug", "clevis", "pin")
    assert r["lmp"]["residual"] == pytest.approx(r["lmp"]["residual_run"], rel=1e-6)
