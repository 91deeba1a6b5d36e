"""The peak of a concave curved face (a fillet, a hole) from the particles beneath it.

The lattice's stress is right where its particles are (docs/stress.md "Patch recovery": at
the filleted C frame's fillet a particle's value agrees with FEA at its centre), but at a
fillet of radius ρ a few spacings across the field rises steeply in the last half spacing to
the surface — on that frame FEA's von Mises halves within 0.3·ρ of the arc — and no
polynomial fit of the particles reaches it. Near a circular concave face the field across it
falls like the hoop stress at Kirsch's hole, a constant and terms in (ρ/r)² and (ρ/r)⁴
(r = ρ + x, x the depth below the face); one power between them,

    σ(x) = A + B·(ρ/(ρ + x))³,

fitted by least squares (two unknowns, robust to the lattice's scatter) to the particles'
``continuum`` von Mises stress (at their centres) in a tube along the face's normal, with ρ
from the part's geometry (how far its surface turns across a window of :data:`WINDOW`
spacings, :func:`rackstress.model.singular.concave_turning`), with A, B ≥ 0, gives σ(0), the
face's peak:
the **notch reading**. On exact samples at the lattice's depths (half a spacing and on) it
reads 0.955 / 0.973 / 0.989 of Kirsch's edge value at ρ of 2.5 / 4 / 8 spacings (by hand,
tests/test_notch.py) and 0.96–0.97 of converged FEA's at the filleted C frame's fillet
(ρ = 2, 2.8, 4 spacings); what it reads from the particles, against converged FEA, is
measured by ``rackstress bench validity --concentrations`` and ``rackstress bench
governing``.
"""
from __future__ import annotations

import numpy as np

#: The window across which the surface's turning gives a face's radius, in spacings.
WINDOW = 2.0
#: Faces read: radius from :data:`MIN_RADIUS` (below it the edge is sharp, a singular point:
#: rackstress.model.singular, 1.43 spacings) to :data:`MAX_RADIUS` spacings (flatter faces
#: carry no steep rise the patch fit misses).
MIN_RADIUS = 1.43
MAX_RADIUS = 20.0
#: The tube along a face's normal: particles within :data:`TUBE` spacings of its axis and
#: down to :data:`DEPTH` spacings below the face.
TUBE = 0.75
DEPTH = 3.0
#: A reading needs this many particles at two depths at least half a spacing apart.
MIN_SAMPLES = 3


#: The power of the field's fall across the face (module docstring).
POWER = 3.0


def basis(x, rho: float) -> np.ndarray:
    """The field's shape across a concave face of radius ``rho`` at depth ``x``:
    (ρ/(ρ + x))^:data:`POWER` (module docstring).

    >>> float(basis(0.0, 2.0)), float(basis(2.0, 2.0))
    (1.0, 0.125)
    """
    return (float(rho) / (float(rho) + np.asarray(x, float))) ** POWER


def surface_value(depth, values, rho: float, spacing: float) -> float | None:
    """σ(0) = A + B of :func:`basis`'s two-term fit A + B·(ρ/(ρ + x))³ to ``values`` at
    ``depth`` (least squares with A, B ≥ 0: a von Mises stress, a far field and a rise toward
    the face — where the samples fall toward the face the fit is their mean, not an
    extrapolation below them), or None where the samples cannot carry it (fewer than :data:`MIN_SAMPLES`, or
    their depths within half a spacing of each other).

    >>> x = np.array([0.5, 1.5, 2.5])
    >>> round(surface_value(x, 3.0 + 2.0 * basis(x, 2.0), 2.0, 1.0), 9)   # exact: A + B
    5.0
    """
    x, v = np.asarray(depth, float), np.asarray(values, float)
    ok = np.isfinite(v) & np.isfinite(x)
    x, v = x[ok], v[ok]
    if len(x) < MIN_SAMPLES or np.ptp(x) < 0.5 * spacing:
        return None
    from scipy.optimize import nnls

    A = np.column_stack([np.ones(len(x)), basis(np.maximum(x, 0.0), rho)])
    c, _ = nnls(A, v)
    return float(c[0] + c[1])


def faces(vertices, faces_, spacing: float):
    """The concave curved faces of a closed surface at the scale of ``spacing``: points along
    its concave edges (every half spacing), with the radius there and the unit normal into the
    part: (points (k, 3), radius (k,), normal (k, 3)); only radii between :data:`MIN_RADIUS`
    and :data:`MAX_RADIUS` spacings."""
    from rackstress.model.singular import concave_turning, sample_segments

    E, _, turning, inward = concave_turning(vertices, faces_, spacing, window=WINDOW)
    if not len(E):
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
    with np.errstate(divide="ignore"):
        rho = WINDOW * float(spacing) / turning
    keep = (rho >= MIN_RADIUS * spacing) & (rho <= MAX_RADIUS * spacing)
    pts, which = sample_segments(E[keep], 0.5 * float(spacing))
    return pts, rho[keep][which], inward[keep][which]


def readings(o, values, points, rho, normal, spacing: float) -> np.ndarray:
    """The notch reading (:func:`surface_value`) at each face point from the particles ``o``
    with ``values`` (their continuum von Mises) in its tube (:data:`TUBE`, :data:`DEPTH`);
    NaN where the tube holds too few."""
    from scipy.spatial import cKDTree

    o = np.asarray(o, float)
    a = float(spacing)
    out = np.full(len(points), np.nan)
    if not len(points) or not len(o):
        return out
    tree = cKDTree(o)
    centre = points + 0.5 * DEPTH * a * normal
    reach = np.hypot(0.5 * DEPTH * a, TUBE * a) * (1 + 1e-9)
    for k, near in enumerate(tree.query_ball_point(centre, reach)):
        if not near:
            continue
        near = np.asarray(near)
        rel = o[near] - points[k]
        x = rel @ normal[k]
        off = np.linalg.norm(rel - x[:, None] * normal[k], axis=1)
        m = (off <= TUBE * a) & (x >= 0.0) & (x <= DEPTH * a)
        v = surface_value(x[m], np.asarray(values)[near[m]], float(rho[k]), a)
        if v is not None:
            out[k] = v
    return out
