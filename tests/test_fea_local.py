"""The FE check's local refinement at its governing point (validity.solid.local_peak): the
classical submodel about it, its cut displaced by the global FE solution. Expected values from
Peterson's chart and from the geometry of the facets."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rackstress.validity import solid

W, L, T, R_HOLE = 20.0, 60.0, 2.0, 3.0          # mm: d/W = 0.3
E, NU, S = 70000.0, 0.3, 10.0                   # MPa; S the gross tension


def _plate(sections: int):
    box = trimesh.creation.box([L, W, T])
    box.apply_translation([L / 2, 0, T / 2])
    cyl = trimesh.creation.cylinder(radius=R_HOLE, height=4 * T, sections=sections)
    cyl.apply_translation([L / 2, 0, T / 2])
    part = trimesh.boolean.difference([box, cyl], engine="manifold")
    return np.asarray(part.vertices), np.asarray(part.faces)


def test_a_coarse_fe_refined_locally_reads_petersons_hole():
    """A plate with a hole (d/W = 0.3, 256 facets round it) pulled at 10 MPa, solved by the
    FE check's P2 elements at a coarse 3 mm: its governing stress at the hole is off
    Peterson's chart 4.1 (K_tn = 3 − 3.14(d/W) + 3.667(d/W)² − 1.527(d/W)³ on the net section)
    by over 5 %; refined locally it reads within 4 % (a plate as thick as 2/3 of the hole's
    radius is within a few per cent of plane stress at its mid-plane), and moves under 1 %
    between its two meshes."""
    v, f = _plate(256)
    p, t = solid.surface_mesh(v, f, 3.0, None, None)
    P = p.T
    fixed = np.zeros((len(P), 3), bool)
    fixed[P[:, 0] < 1e-6] = True
    end = P[:, 0] > L - 1e-6
    forces = np.zeros((len(P), 3))
    forces[end, 0] = S * W * T / end.sum()
    sol = solid.solve(p, t, E, NU, fixed, forces)
    sing = solid.Singular(points=np.concatenate([P[fixed[:, 0]], P[end]]), zone=6.0, rule="",
                          spacing=1.0)
    gov = solid.governing(sol.mesh.X, sol.nodal()["von_mises"], sing)
    d = 2 * R_HOLE / W
    want = (3 - 3.14 * d + 3.667 * d ** 2 - 1.527 * d ** 3) * S * W / (W - 2 * R_HOLE)
    assert abs(gov["value"] / want - 1) > 0.05                 # the coarse FE's own reading
    lp = solid.local_peak(v, f, sol, gov["position"], sing, E, NU)
    assert lp["value"] == pytest.approx(want, rel=0.04)
    assert abs(np.hypot(lp["position"][0] - L / 2, lp["position"][1]) - R_HOLE) < 0.05
    assert abs(lp["position"][0] - L / 2) < 0.5                # on the hole's side, across x
    assert lp["moved"] < 0.01 and lp["note"] is None


@pytest.mark.parametrize("sections", [16, 24])
def test_the_facets_of_a_hole_turn_inward_by_360_over_their_number(sections):
    """A hole of n facets: each edge between two of them turns inward by 360°/n (the material
    wraps round it); the plate's outer edges turn outward and are not counted."""
    v, f = _plate(sections)
    on_hole = [L / 2, R_HOLE * np.cos(np.pi / sections), T / 2]     # mid-facet, on y > 0
    assert solid.facet_kink(v, f, on_hole, 1.5) == pytest.approx(360 / sections, abs=1e-3)
    assert solid.facet_kink(v, f, [5.0, 0.0, T], 1.0) == 0.0            # the flat top face


def test_a_refinement_that_does_not_end_is_stopped_and_said(tmp_path):
    """gmsh's surface classification does not end on some pieces of a file's facets and
    cannot be interrupted in its process: the refinement runs in a child process, and one
    given too little time is stopped, with a RuntimeError saying so (the FE check then
    reports it as ``local_note``), and no child is left running."""
    import multiprocessing

    v, f = _plate(64)
    p, t = solid.surface_mesh(v, f, 4.0, None, None)
    P = p.T
    fixed = np.zeros((len(P), 3), bool)
    fixed[P[:, 0] < 1e-6] = True
    forces = np.zeros((len(P), 3))
    forces[P[:, 0] > L - 1e-6, 0] = 1.0
    sol = solid.solve(p, t, E, NU, fixed, forces)
    sing = solid.Singular(points=P[fixed[:, 0]], zone=6.0, rule="", spacing=1.0)
    with pytest.raises(RuntimeError, match="had not meshed the ball after"):
        solid.local_peak(v, f, sol, [L / 2, R_HOLE, T / 2], sing, E, NU, timeout=0.01)
    assert not multiprocessing.active_children()


def _uniform_tension_bar(size: float):
    """A 20 × 12 × 12 mm bar (its corner at the origin) meshed by the FE check at ``size``, and
    the exact uniform tension field S along x on it: u = S/E (x, −ν y, −ν z)."""
    from rackstress.lib.tet import Solution, Tet2, project_strain

    box = trimesh.creation.box([20.0, 12.0, 12.0])
    box.apply_translation([10.0, 6.0, 6.0])
    p, t = solid.surface_mesh(np.asarray(box.vertices), np.asarray(box.faces), size, None, None)
    mesh = Tet2(p.T, t.T)

    def field(X):
        X = np.asarray(X, float)
        return S / E * np.stack([X[:, 0], -NU * X[:, 1], -NU * X[:, 2]], axis=1)

    U = field(mesh.X)
    return box, Solution(mesh, U, project_strain(mesh, U), E, NU), field


def test_a_support_inside_the_refined_ball_stays_a_support():
    """The local refinement's ball about a point 1 mm from the bar's supported end x = 0
    (a roller there; the bar pulled at S along x) reaches that end face. The face is held,
    not free: where the held particles' cells (spacing 1 mm, the first layer at x = ½) cover
    the ball's nodes, they are displaced along x (the roller's direction) by the global
    field, as its cut is, and the exact
    uniform field (which P2 elements hold exactly) reads S. Taken as free surface, as before,
    the face carries no σ_xx, the stress beside it falls, and the ball walks away from the
    support (its two meshes then read 16 % apart, measured while building this)."""
    box, sol, field = _uniform_tension_bar(1.5)
    v, f = np.asarray(box.vertices), np.asarray(box.faces)
    sing = solid.Singular(points=np.array([[20.0, 6.0, 6.0]]), zone=2.0, rule="",
                          spacing=1.0)
    g = np.arange(0.5, 12.0, 1.0)
    held = np.array([[0.5, y, z] for y in g for z in g])
    centre = [1.0, 0.0, 6.0]                     # on the side face y = 0
    roller = np.tile([True, False, False], (len(held), 1))       # held along x only
    lp = solid.local_peak(v, f, sol, centre, sing, E, NU, bears=(held, roller, 1.0))
    assert lp["radius"] > 1.5                    # the ball reaches the end face
    assert lp["value"] == pytest.approx(S, rel=1e-6)
    assert lp["coarser_value"] == pytest.approx(S, rel=1e-6)
    free = solid.local_peak(v, f, sol, centre, sing, E, NU)
    assert abs(free["coarser_value"] / S - 1) > 0.05
