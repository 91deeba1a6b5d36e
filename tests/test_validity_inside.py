"""The bind-inside body model (within(d) without bindings across free space), the validity
comparison on LAMMPS, and LAMMPS' own per-atom virial — expected values from geometry, the
re-entrant corner's singularity and hand calculation."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rackstress.model.operators import Bind, Dampen, Force, Within, WithinInside
from rackstress.model.particles import Group
from rackstress.model.regions import Box
from rackstress.model.scene import Phase, Scene
from rackstress.scenes import validation as cases
from rackstress.validity import compare


def _bind_pairs(scene):
    op = next(o for o in scene.operators["body"] if isinstance(o, Bind))
    g = scene.groups["body"]
    pl = op.pairs(g, g)
    return {(int(i), int(j)) for i, j in zip(pl.i, pl.j)}, g.o


def test_inside_drops_only_the_binding_through_the_re_entrant_corner():
    w, H, lx = 4, 12, 10
    plain, o = _bind_pairs(cases.l_bracket(body="bind", w=w, H=H, lx=lx))
    inside, _ = _bind_pairs(cases.l_bracket(body="bind-inside", w=w, H=H, lx=lx))
    assert inside < plain
    gone = {tuple(sorted(p)) for p in plain - inside}
    # the one diagonal whose midpoint is the corner (w − ½, H − w − ½) of the cells' union:
    # from the leg's particle (w−1, H−w−1) to the arm's (w, H−w), both ways
    assert len(gone) == 1 and len(plain - inside) == 2
    (a, b), = gone
    mid = (o[a] + o[b]) / 2
    assert np.allclose(mid[:2], (w - 0.5, H - w - 0.5))
    assert np.linalg.norm(o[a] - o[b]) == pytest.approx(math.sqrt(2))


def test_inside_keeps_every_binding_of_a_convex_part():
    # a segment between two points of a convex set lies in it: nothing to drop
    plain, _ = _bind_pairs(cases.cantilever(body="bind", nx=9, ny=4))
    inside, _ = _bind_pairs(cases.cantilever(body="bind-inside", nx=9, ny=4))
    assert plain == inside and len(plain) == 2 * (8 * 4 + 9 * 3 + 2 * 8 * 3)  # 4 bonds a cell


def test_inside_segment_test_by_hand():
    box = Box((0, 0, -1), (2, 2, 1)) - Box((1, 1, -1), (2, 2, 1))   # an L of three unit squares
    c = WithinInside(3.0, 1.0, box)
    a = np.array([[0.5, 0.5, 0], [0.5, 1.5, 0], [0.2, 0.2, 0], [0.5, 0.5, 0]])
    b = np.array([[1.5, 0.5, 0], [1.5, 0.5, 0], [0.8, 0.8, 0], [1.5, 1.5, 0]])
    # in the bottom row; across the notch's corner (1, 1); short, inside; ends in the notch
    assert c.inside(a, b).tolist() == [True, False, True, False]


def test_bind_inside_l_bracket_peaks_at_the_re_entrant_corner():
    """Linear elasticity puts the L's largest strain at the re-entrant corner (σ ~ r^−0.456,
    unbounded); the particle nearest it lies 0.71 spacings away. bind-inside's strain measure
    has its maximum within two spacings of that corner."""
    from rackstress.model.stability import predict

    kw = dict(body="bind-inside", damping=0.06)
    sc = cases.l_bracket(**kw)
    sc = cases.l_bracket(dt=0.5 * predict(sc)["t_max"], steps=20000, **kw)
    p, info = compare.equilibrate(sc, tol=1e-5)
    assert info["at_rest"]
    m = compare.measures(sc, p)
    free = cases.free_mask(sc)
    o = sc.groups["body"].o[free]
    top = o[np.nanargmax(m["strain"][free])]
    g = sc.params
    corner = np.array([g["w"] - 0.5, g["H"] - g["w"] - 0.5])
    assert np.linalg.norm(top[:2] - corner) <= 2.0


@pytest.mark.lammps
def test_lammps_repeats_the_reference_equilibrium():
    sc = cases.l_bracket(body="bind-inside", w=4, H=12, lx=10, damping=0.06, dt=0.05)
    p_ref, info = compare.equilibrate(sc, max_steps=600, check_every=100)
    p, info_l = compare.equilibrate(sc, engine="lammps", steps=info["steps"], check_every=100)
    assert info_l["steps"] == info["steps"] == 600
    assert np.abs(p - p_ref).max() <= 1e-10 * max(1.0, np.abs(p_ref).max())
    assert np.abs(p - sc.original_positions()).max() > 1e-4       # it moved


@pytest.mark.lammps
def test_lammps_virial_of_a_pulled_pair_by_hand():
    """Two particles bound with c, pulled apart by f each: fast mode's harmonic bond (stiffness
    2c) rests at d = 1 + f/2c, and each particle's virial is ½·d·f along x, whose von Mises
    equivalent is |½·d·f|; the binds' ½ Σ r ⊗ f at the same positions is the same number."""
    c, f = 20.0, 0.5
    o = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    ops = {"body": [Force((-f, 0.0, 0.0), where=(True, False)),
                    Force((f, 0.0, 0.0), where=(False, True)),
                    Bind("body", Within(1.5, c)), Dampen(2.0)]}
    sc = Scene("pair", {"body": Group("body", o, 0.5)}, ops, [Phase("pull", 4000)], dt=0.02)
    p, info = compare.equilibrate(sc, engine="lammps", mode="fast", virial=True, tol=1e-9,
                                  check_every=200)
    assert info["at_rest"]
    d = 1 + f / (2 * c)
    assert np.linalg.norm(p[1] - p[0]) == pytest.approx(d, rel=1e-6)
    vm = compare.von_mises_6(info["virial"])
    assert vm == pytest.approx([0.5 * d * f] * 2, rel=1e-6)
    # Eq. 12's force at the harmonic rest differs from f by its linearization: c(d²−1)/d vs 2c(d−1)
    eq12 = c * (d * d - 1) / d
    assert compare.bind_virial(sc, p) == pytest.approx([0.5 * d * eq12] * 2, rel=1e-9)


def test_toml_bind_inside_region(tmp_path):
    """A TOML scene's bind with ``inside``: an L of 8 unit cells (3×3 minus the corner (2, 0))
    has 17 neighbour pairs within 1.5; the diagonal (1, 0)–(2, 1) runs through the notch's
    corner (1.5, 0.5), so 16 remain."""
    from rackstress.errors import SceneError
    from rackstress.scenes.toml import load_toml

    pts = [[i, j, 0] for j in range(3) for i in range(3) if (i, j) != (2, 0)]
    shape = ('{ difference = [{ box = { min = [-0.5, -0.5, -0.5], max = [2.5, 2.5, 0.5] } }, '
             '{ box = { min = [1.5, -0.5, -0.5], max = [2.5, 0.5, 0.5] } }] }')

    def scene(extra):
        f = tmp_path / "l.toml"
        f.write_text(f'name = "l"\ndt = 0.05\nsteps = 10\n[[group]]\nname = "l"\npositions = {pts}\n'
                     'radius = 0.5\n[[operator]]\non = "l"\nop = "bind"\nfrom = "l"\nc = 20\n'
                     + extra)
        return load_toml(str(f))

    def unordered(sc):
        op = sc.operators["l"][0]
        g = sc.groups["l"]
        pl = op.pairs(g, g)
        return {tuple(sorted((int(i), int(j)))) for i, j in zip(pl.i, pl.j)}, g.o

    plain, o = unordered(scene("within = 1.5\n"))
    inside, _ = unordered(scene(f"within = 1.5\ninside = {shape}\n"))
    assert len(plain) == 17 and len(inside) == 16
    (a, b), = plain - inside
    assert sorted(map(tuple, o[[a, b], :2].tolist())) == [(1.0, 0.0), (2.0, 1.0)]
    with pytest.raises(SceneError, match="inside"):
        scene(f"inside = {shape}\n")                 # inside without within
    # an ids region selects particles, not space: refused (it used to drop every binding)
    for ids in ("{ ids = [0, 1, 2] }", "{ union = [{ ids = [0] }, { box = { min = [0, 0, 0], "
                "max = [1, 1, 1] } }] }"):
        with pytest.raises(SceneError, match="'inside'.*an 'ids' region selects particles"):
            scene(f"within = 1.5\ninside = {ids}\n")


def test_fea_square_material_reduces_to_isotropic_and_matches_beam_theory():
    from rackstress.validity import fea

    L, h, P, E, nu = 20.0, 1.0, 1e-3, 1.0, 0.3
    iso = fea.cantilever(L, h, P, density=4, E=E, nu=nu)
    C = (E / (1 - nu ** 2), nu * E / (1 - nu ** 2), E / (2 * (1 + nu)))   # plane stress
    same = fea.cantilever(L, h, P, density=4, stiffness=C)
    tip = np.array([[L, h / 2]])
    # the claim itself, exactly: the square material's stiffness matrix is the isotropic one
    # (plane stress) to round-off
    from skfem import Basis, ElementTriP2, ElementVector, asm, condense
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    basis = Basis(iso.mesh, ElementVector(ElementTriP2()), intorder=4)
    lam, mu = lame_parameters(E, nu)
    K_iso = asm(linear_elasticity(2 * lam * mu / (lam + 2 * mu), mu), basis)
    K_sq = asm(fea._anisotropic(C), basis)
    assert abs(K_sq - K_iso).max() <= 1e-14 * abs(K_iso).max()
    # ... so the two solves differ only by the factorization's round-off, which the clamped
    # beam's condition number κ (about 1.3e8) amplifies: |Δu|/|u| ≤ κ·ε, ε = 2.2e-16 per
    # entry, ×10 for the factor's accumulated rounding (MKL PARDISO on an Intel Xeon: 1.3e-9;
    # on an AMD EPYC: below 1e-9)
    A = condense(K_iso, np.zeros(basis.N),
                 D=basis.get_dofs(lambda x: np.abs(x[0]) < 1e-9).all())[0].toarray()
    bound = 10 * np.linalg.cond(A) * np.finfo(float).eps
    assert same.at(tip)["uy"][0] == pytest.approx(iso.at(tip)["uy"][0], rel=bound)
    # the square lattice's material (k = 2c = 40): E along x = C11 − C12²/C11 = 1.5k, G = C44 = k
    k = 40.0
    C11, C12, C44 = fea.square_lattice_stiffness(k)
    assert (C11, C12, C44) == (2 * k, k, k)
    lat = fea.cantilever(L, h, P, density=4, stiffness=(C11, C12, C44))
    Ex, I = 1.5 * k, h ** 3 / 12
    expected = P * L ** 3 / (3 * Ex * I) + P * L / (5 / 6 * C44 * h)       # Timoshenko
    assert -lat.at(tip)["uy"][0] == pytest.approx(expected, rel=0.01)


def test_fingerprint_sees_the_shape_a_bind_stays_inside():
    """--resume must refuse a scene whose bind-inside region changed: the region (a union of
    boxes, hashed by its description) is part of the operators' fingerprint."""
    from rackstress.model.operators import Bind
    from rackstress.runs.fingerprint import fingerprint

    a = cases.l_bracket(body="bind-inside", w=4, H=12, lx=10)
    b = cases.l_bracket(body="bind-inside", w=4, H=12, lx=10)
    k = next(i for i, op in enumerate(b.operators["body"]) if isinstance(op, Bind))
    op = b.operators["body"][k]
    shape = op.coeff.region
    wider = type(shape)((shape.parts[0], Box((-0.5, 7.0, -0.5), (9.5, 11.5, 0.5))))
    b.operators["body"][k] = Bind(op.source, WithinInside(op.coeff.d, op.coeff.c, wider))
    fa = fingerprint(a, engine="lammps", mode="exact", dump_every=10)
    fb = fingerprint(b, engine="lammps", mode="exact", dump_every=10)
    assert sorted(key for key in fa if fa[key] != fb[key]) == ["operators:body"]
    same = fingerprint(cases.l_bracket(body="bind-inside", w=4, H=12, lx=10), engine="lammps",
                       mode="exact", dump_every=10)
    assert same == fa


def test_binds_inside_different_shapes_are_not_each_others_reverse():
    """Eq. 16's reciprocal pair set is shared only by binds with the same coefficient: two
    WithinInside binds with the same d but different shapes keep their own pairs."""
    from rackstress.model.operators import Bind, WithinInside, reverse_of
    from rackstress.model.regions import Box

    big = Box([-10, -10, -10], [10, 10, 10])
    small = Box([-1, -1, -1], [1, 1, 1])
    same = {"a": [Bind("b", WithinInside(1.5, 20.0, big))],           # read twice from a file
            "b": [Bind("a", WithinInside(1.5, 20.0, Box([-10, -10, -10], [10, 10, 10])))]}
    assert reverse_of(same, "a", 0) == ("b", 0)
    other = {"a": [Bind("b", WithinInside(1.5, 20.0, big))],
             "b": [Bind("a", WithinInside(1.5, 20.0, small))]}
    assert reverse_of(other, "a", 0) is None
