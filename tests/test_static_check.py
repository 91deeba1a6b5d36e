"""The static path's part check and solver (engines/static.py, engines/mechanisms.py,
engines/linear.py): what cannot be held is refused in seconds with exit 2, naming the
particles, where they are and what to do — never 25 Newton steps; the supports' reactions
balance the load; the direct factorization agrees with the iterative solve.

Expected values come from geometry and statics: which rigid motions a line of held particles
leaves (a rotation about that line), the load and its moment about the clamp (P·L)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import child_cpu
from test_faults import QUIET, rs
from test_faults_static import LOOSE, hinge

ROOT = Path(__file__).resolve().parents[1]
CANTILEVER = ROOT / "examples" / "cantilever" / "scene.toml"

#: two 4 × 4 × 4 steel blocks whose only bindings are the four diagonals along (1, 0, 1) where
#: their edges meet (a hinge): the second turns about that line under a load on it
HINGED = """name = "hinged"
units = "mm-N-s"
analysis = "static"

[[group]]
name = "part"
parts = [ { lattice = { shape = [4, 4, 4], spacing = 1.0, origin = [0, 0, 0] } },
          { lattice = { shape = [4, 4, 4], spacing = 1.0, origin = [4, 0, 4] } } ]
spacing = 1.0
material = "steel"

[[support]]
on = "part"
where = { box = { min = [-0.1, -1, -1], max = [0.1, 5, 5] } }

[[load]]
on = "part"
where = { box = { min = [6.9, -1, 3.9], max = [7.1, 5, 8] } }
force = [0, 0, -10]
"""

#: a steel bar 20 × 4 × 4 mm with a strut one particle wide (1 × 1 mm, 5 mm long) on its end,
#: clamped at x = 0; 1 N across the strut's tip (−y): no binding holds it that way
STRUT = """name = "strut"
units = "mm-N-s"
analysis = "static"

[[group]]
name = "bar"
parts = [ { box = { min = [0, 0, 0], max = [20, 4, 4] } },
          { box = { min = [20, 1, 1], max = [25, 2, 2] } } ]
spacing = 1.0
material = "steel"

[[support]]
on = "bar"
where = { box = { min = [0, -1, -1], max = [0.6, 5, 5] } }

[[load]]
on = "bar"
where = { box = { min = [24, 0, 0], max = [26, 3, 3] } }
force = [FX, FY, 0]
"""


def refused(r, out: Path, *words):
    """Exit 2 with one error paragraph holding ``words``, no traceback, no run directory."""
    assert r.returncode == 2, r.stderr
    errors = [line for line in r.stderr.splitlines() if line.startswith("rackstress: error")]
    assert len(errors) == 1, r.stderr
    assert "Traceback" not in r.stderr
    for w in words:
        assert w in errors[0], (w, errors[0])
    assert not (out / "summary.json").exists()


@pytest.mark.parametrize("case", ["floating body", "support on a line", "strut loaded across",
                                  "hinge"])
def test_a_part_that_cannot_be_held_is_refused_in_seconds(tmp_path, case):
    """Each is exit 2 before any Newton step, naming the group, a particle and its place, and
    what to do: a body with no support (its neighbour bar is clamped); a bar held on one line
    of particles along z (it turns about that line, through (0.5, 0.5)); a strut one particle
    wide loaded across itself; a block hinged on one line of bindings (the first step's work
    goes into the regularization)."""
    out = tmp_path / "run"
    if case == "floating body":
        scene = hinge(tmp_path, extra=LOOSE)          # 'loose' has no support and no load
        words = ["'loose'", "held by no support", "floats away", "Add a [[support]]"]
        args = []
    elif case == "support on a line":
        scene, args = hinge(tmp_path), ["--set", "pin=0.1"]
        # the held particles are the line x = y = 0.5: the free motion is a turn about z there
        words = ["'bar'", "turn about the axis along", "through [0.5, 0.5,",
                 "rigid-body motion free"]
    elif case == "strut loaded across":
        scene = tmp_path / "strut.toml"
        scene.write_text(STRUT.replace("FX", "0").replace("FY", "-1"))
        args = []
        words = ["particle 124 at [24.5, 1.5, 1.5]", "carry a load across", "finer spacing"]
    else:
        scene = tmp_path / "hinged.toml"
        scene.write_text(HINGED)
        args = []
        words = ["mechanism", "64 particle(s) of 'part'", "[4.0, 0.0, 4.0]", "Add a support"]
    with child_cpu() as cpu:
        r = rs("run", scene, *args, "--out", out, *QUIET)
    refused(r, out, *words)
    assert "iteration" not in r.stderr
    assert cpu.s < 60, cpu.s             # a process's start, the scene and the check: its work


def test_a_strut_loaded_along_itself_settles_with_a_warning(tmp_path):
    """The same strut pulled along its own line (+x): its bindings hold it that way, so the
    part settles; the run warns that the strut is one particle wide (its bending is not
    represented) and names it."""
    scene = tmp_path / "strut.toml"
    scene.write_text(STRUT.replace("FX", "1").replace("FY", "0"))
    out = tmp_path / "run"
    r = rs("run", scene, "--engine", "reference", "--out", out, *QUIET)
    assert r.returncode == 0, r.stderr
    assert "one particle thick or struts one particle wide" in r.stderr
    import json

    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "settled"
    w = [x for x in s["warnings"] if x["kind"] == "membrane"]
    # the strut's 5 particles, x = 20.5 … 24.5: the diagonals from the first to the bar would
    # run along the strut's own edge at x = 20 (on its surface, not inside): none is kept
    assert len(w) == 1 and w[0]["particles"] == 5


def test_rigid_modes_left_by_hand():
    """Geometry: three held particles on the x axis leave one rigid motion, the turn about
    that axis; one held particle leaves the three turns about it; rollers fixing only z on a
    plane leave the slides in x and y and the turn about z."""
    from rackstress.engines.mechanisms import rigid_modes_left

    x = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 1]])
    held = np.zeros((5, 3), bool)
    held[:3] = True
    left = rigid_modes_left(x, held)
    assert len(left) == 1 and left[0]["kind"] == "rotation"
    assert np.allclose(np.abs(left[0]["axis"]), [1, 0, 0], atol=1e-9)
    assert np.allclose(left[0]["point"][1:], [0, 0], atol=1e-9)     # the axis is y = z = 0
    held[:] = False
    held[4] = True
    left = rigid_modes_left(x, held)
    assert len(left) == 3 and all(m["kind"] == "rotation" for m in left)
    held[:] = False
    held[:4, 2] = True                  # rollers on z = 0: 4 particles, z fixed
    left = rigid_modes_left(x, held)
    kinds = sorted(m["kind"] for m in left)
    assert kinds == ["rotation", "translation", "translation"]


def test_reactions_balance_the_applied_load_and_its_moment():
    """Statics on the cantilever (100 N in −z on the end face at x = 100, clamped at x = 0):
    Σ reactions = (0, 0, +100) N within the settle tolerance, and their moment about the
    origin is −(the load's): the load's is r × F summed, (0, +100·x_end, 0) = (0, 10,000, 0)
    N·mm by hand (its y-arms cancel by symmetry), the deflection changing x_end by ~1e-5."""
    from rackstress.engines.static import TOLERANCE, solve, support_reactions
    from rackstress.scenes.toml import load_toml

    sc = load_toml(CANTILEVER, {"spacing": 2.0})
    res = solve(sc)
    assert res.settled and res.reactions.shape == (sc.n_particles, 3)
    assert not res.reactions[~sc.fixed()].any()              # only on held directions
    total = res.reactions.sum(axis=0)
    assert np.allclose(total, [0, 0, 100.0], atol=TOLERANCE * 100.0)
    s = support_reactions(sc, res)
    assert [r["support"] for r in s["reactions"]] == ["[[support]] #1"]
    assert np.allclose(s["reactions"][0]["force"], total)
    assert np.allclose(s["applied_load"]["force"], [0, 0, -100.0])
    assert np.allclose(s["applied_load"]["moment"], [0, 100.0 * 100.0, 0], rtol=1e-4,
                       atol=1e-3)
    M = np.add(s["reactions"][0]["moment"], s["applied_load"]["moment"])
    # the bindings' forces are central: their moments cancel in pairs, exactly
    assert np.abs(M).max() < TOLERANCE * 100.0 * 100.0


def test_chord_steps_stop_once_one_raises_the_unbalanced_force(monkeypatch):
    """A chord step (the last tangent again, CHORD_BELOW) that raises the largest unbalanced
    force turns chord steps off: new tangents from there. With chord steps allowed at any
    residual (CHORD_BELOW huge), the cantilever at 2 mm under 3,000 N (tip deflection ~17 mm:
    its tangent turns with it) settles, as with the default; taking chord steps on regardless,
    it did not in 25 steps (0.04 … 0.22 of the load), and a public string-light bracket at the
    default went 5.8e-5 ↔ 1.7e-4 of its load for 25 steps. Statics: Σ reactions = the load."""
    from rackstress.engines import static
    from rackstress.scenes.toml import load_toml

    monkeypatch.setattr(static, "CHORD_BELOW", 1e12)
    sc = load_toml(CANTILEVER, {"spacing": 2.0, "load": 3000.0})
    res = static.solve(sc)
    assert res.settled, res.history
    assert np.allclose(res.reactions.sum(axis=0), [0, 0, 3000.0],
                       atol=static.TOLERANCE * 3000.0)


def test_direct_and_iterative_solves_agree_on_the_cantilever():
    """The same Newton step by the direct factorization and by AMG-CG to 1e-10: the tip
    displacements agree to 1e-7 of themselves (two independent linear solvers)."""
    from rackstress.engines import linear, static
    from rackstress.scenes.toml import load_toml

    sc = load_toml(CANTILEVER, {"spacing": 2.0})
    prob = static._problem(sc)
    K, _ = static._tangent(prob.o, prob)
    b = static.forces(sc, prob.o, prob.pairs, prob.F_ext, prob.m).reshape(-1)[prob.free]
    x1 = linear.factorize(K).solve(b)
    x2 = linear.AMG(K, static.rigid_modes(prob.o, prob.free)).solve(b, rtol=1e-12)
    assert np.abs(x1 - x2).max() < 1e-7 * np.abs(x1).max()
    assert linear.backend() == "pardiso"         # the package the project depends on loads


def test_amg_cg_that_stalls_gives_way_to_the_direct_factorization(monkeypatch):
    """Where AMG-CG does not converge within linear.AMG_PATIENCE steps (a part of thin walls:
    the SO-100 base at 155,392 particles did not settle in 5 minutes), the whole tangent is
    factorized from then on, where its plan fits within DIRECT_FLOPS_FALLBACK: the cantilever
    at 2 mm made to take AMG-CG (DIRECT_FLOPS 0) and to give it one step settles by PARDISO
    (the run says so, two factorizations: the hierarchy, then the factor), at the equilibrium
    AMG-CG alone reaches, to 1e-6 of the largest displacement."""
    from rackstress.engines import linear, static
    from rackstress.scenes.toml import load_toml

    monkeypatch.setattr(linear, "DIRECT_FLOPS", 0.0)
    amg = static.solve(load_toml(CANTILEVER, {"spacing": 2.0}))
    monkeypatch.setattr(linear, "AMG_PATIENCE", 1)
    sc = load_toml(CANTILEVER, {"spacing": 2.0})
    switched = static.solve(sc)
    assert amg.solver == "amg-cg" and switched.solver == "pardiso"
    assert amg.settled and switched.settled
    assert switched.factorizations >= 2
    o = sc.original_positions()
    u, w = switched.p - o, amg.p - o
    assert np.abs(u - w).max() <= 1e-6 * np.abs(w).max()


def test_a_solve_that_does_not_settle_says_where_and_names_thin_walls(tmp_path):
    """A solve stopped before its first step (no Newton step allowed) leaves the applied load
    unbalanced: its largest unbalanced force is the load on the strut's tip, particle 124 at
    [24.5, 1.5, 1.5] (the load box, by construction), 1 N of the 1 N applied, in a strut one
    particle wide; exit 6's message says so and what to do."""
    from rackstress.cli import _unbalanced_hint
    from rackstress.engines import static
    from rackstress.scenes import load

    scene = tmp_path / "strut.toml"
    scene.write_text(STRUT.replace("FX", "1").replace("FY", "0"))
    res = static.solve(load(str(scene)), max_iterations=0)
    assert not res.settled
    u = res.unbalanced
    assert u["particle"] == 124 and u["position"] == [24.5, 1.5, 1.5]
    assert u["force"] == pytest.approx(1.0, rel=1e-12)
    assert u["worst"] == 1 and u["in_thin_walls"] == 1 and u["spacing"] == 1.0
    hint = _unbalanced_hint({"unbalanced_at": u})
    assert "particle 124 of 'bar' at (24.5, 1.5, 1.5)" in hint
    assert "walls one particle thick" in hint and "spacing ≤ 0.5" in hint


@pytest.mark.parametrize("poisson", [False, True])
def test_the_energy_the_solver_weighs_steps_by_is_the_potential_of_its_forces(tmp_path, poisson):
    """energy_change (the potential Π whose gradient is −m·a, taken as differences) against
    the forces, an independent path (Eq. 12's kernel, the volumetric term's accel): the central
    difference of Π along a random direction equals −f·v to 1e-6 of itself, with and without
    the volumetric term (ν = 0.33)."""
    from rackstress.engines import static
    from rackstress.scenes import load

    text = (STRUT.replace("FX", "0").replace("FY", "1")
            .replace('material = "steel"', 'material = { E = 70e9, nu = 0.33, density = 2700 }'
                     + ('\npoisson = "material"' if poisson else "")))
    (tmp_path / "s.toml").write_text(text)
    sc = load(str(tmp_path / "s.toml"))
    prob = static._problem(sc)
    assert (prob.volume is not None) == poisson
    rng = np.random.default_rng(7)
    p = prob.o + 0.02 * rng.standard_normal(prob.o.shape)      # bindings stretched and bent
    v = rng.standard_normal(p.shape)
    f = static.forces(sc, p, prob.pairs, prob.F_ext, prob.m)
    h = 1e-5
    slope = static.energy_change(prob, p - h * v, p + h * v) / (2 * h)
    assert slope == pytest.approx(-np.sum(f * v), rel=1e-6)


#: a frame: two 4 mm posts joined by a 3 mm beam at the bottom and, above it, by a wall one
#: particle thick (y = 1.5) spanning the posts; the first post held
FRAME = """name = "frame"
units = "mm-N-s"
analysis = "static"

[[group]]
name = "frame"
parts = [ { box = { min = [0, 0, 0], max = [4, 4, 12] } },
          { box = { min = [16, 0, 0], max = [20, 4, 12] } },
          { box = { min = [4, 0, 0], max = [16, 4, 3] } },
          { box = { min = [4, 1, 3], max = [16, 2, 12] } } ]
spacing = 1.0
material = "aluminium"

[[support]]
on = "frame"
where = { box = { min = [-1, -1, -1], max = [0.6, 5, 13] } }

[[load]]
on = "frame"
where = { box = { min = [19.4, -1, -1], max = [21, 5, 13] } }
force = [0, 1, 0]
"""


def test_a_wall_one_particle_thick_moves_with_its_edges_in_the_first_step(tmp_path):
    """The regularization μ·L: where K has no stiffness (a wall one particle thick, across
    itself) the first step interpolates what binds the wall. The frame's held post turned
    rigidly about z (1 mrad, prescribed) turns the frame rigidly (geometry: no binding
    stretches), the wall spanning its posts included: every particle's first step is that
    rotation's displacement within 2 % of its largest (the junctions' one-sided bindings),
    where ε·diag(K), the regularization before, kept the wall where it was (off by > 50 %)."""
    from rackstress.engines import linear, static
    from rackstress.scenes import load

    (tmp_path / "frame.toml").write_text(FRAME)
    sc = load(str(tmp_path / "frame.toml"))
    prob = static._problem(sc)
    o = prob.o
    wall = static._check_particles(sc, prob)[1]
    assert len(wall) == 12 * 9 and np.all(o[wall, 1] == 1.5)       # 4.5…15.5 × 3.5…11.5
    th = 1e-3
    rot = np.stack([-th * (o[:, 1] - 2.0), th * o[:, 0], np.zeros(len(o))], axis=1)
    held = prob.fixed.any(axis=1)
    u_h = np.zeros(3 * len(o))
    u_h[np.repeat(held, 3)] = rot[held].reshape(-1)
    b = -(static.stiffness(o, prob.pairs, prob.m) @ u_h)[prob.free]
    err = {}
    for spread in (True, False):
        K, _ = static._tangent(o, prob, static.REGULARIZATION, spread)
        step = np.zeros(3 * len(o))
        step[prob.free] = linear.factorize(K).solve(b)
        step = step.reshape(-1, 3) + np.where(held[:, None], rot, 0.0)
        err[spread] = np.abs(step - rot).max(axis=1)[wall].max() / np.abs(rot).max()
    assert err[True] < 0.02
    assert err[False] > 0.5


def test_relaxing_a_strut_one_particle_wide_finds_its_equilibrium(tmp_path):
    """Between Newton steps the particles lacking a direction (the strut's 5) are settled on
    their own, the rest held (static._relax): moved off the equilibrium across the strut
    (where only its tension holds them), they come back to it; and the solve finds the same
    equilibrium with the relaxation as without it, in no more steps."""
    from rackstress.engines import static
    from rackstress.scenes.toml import load_toml

    scene = tmp_path / "strut.toml"
    scene.write_text(STRUT.replace("FX", "1").replace("FY", "0") + """
[[load]]
on = "bar"
where = { box = { min = [18.5, -1, -1], max = [19.5, 5, 5] } }
force = [0, 0, -3]
""")
    runs = {}
    for relax in (False, True):
        static.RELAX, keep = relax, static.RELAX
        try:
            runs[relax] = static.solve(load_toml(scene))
        finally:
            static.RELAX = keep
    old, new = runs[False], runs[True]
    assert old.settled and new.settled and new.iterations <= old.iterations
    sc = load_toml(scene)
    static.check_part(sc)
    cached = static._CHECKS[id(sc)]
    prob = cached["prob"]
    try:
        sets = static._relaxed_sets(sc, prob, cached["membrane"])
        assert [len(s) for s in sets] == [5]
        u = np.abs(old.p - prob.o).max()
        assert np.abs(new.p - old.p).max() <= 1e-6 * u
        moved = old.p.copy()
        # across the strut, by ~100 × its stretch (1 N on a steel strut: 2e-6 mm a binding;
        # Newton's region there: an offset ~0.03 mm stretches it 200× more than its tension)
        moved[sets[0]] += np.array([0.0, 2e-4, -3e-4])
        back, steps, reached = static._relax(prob, moved, sets, goal=1e-7 * old.load)
        assert reached and 1 <= steps <= static.RELAX_STEPS
        assert np.abs(back - old.p).max() <= 1e-6 * u
    finally:
        static.release(sc)
