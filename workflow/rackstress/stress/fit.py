"""Best-fit rigid motion of a part: plain Kabsch and a robust (outlier-excluding) Kabsch.

The paper's "desired position" of a particle is its original position o carried by its part's
current rigid motion (docs/model.md, "Desired position"). Which rigid motion? Two answers, both built on
:func:`rackstress.lib.rigid.best_fit` (Kabsch via ``scipy.spatial.transform.Rotation.align_vectors``):

``kabsch``
    R, t minimizing Σ‖p_i − (R o_i + t)‖² over all particles of the part: what ``summary.json``'s
    ``max_deformation`` reports. A local deformation drags this fit a little, so a particle that
    did not move relative to its neighbours can still show a small distance.

``robust`` (default)
    The same fit, repeated on the particles that follow the part's rigid motion: after each fit,
    the particles whose distance exceeds ``c`` times the median distance (c = 3) are left out of
    the next fit, until the set no longer changes. The median keeps at least half of the part in
    every fit. When some particles moved rigidly and others did not (a local bump, a bent toe),
    the fit lands on the rigid ones exactly, so the bump's particles show exactly their own
    displacement and the rest exactly zero. On a part deformed everywhere it fits the least
    deformed core — "desired" is what the bulk of the part says.

A rigid motion gives zero (to round-off, ~1e-15 of the part's size) under both.
"""
from __future__ import annotations

import numpy as np

from rackstress.lib.rigid import best_fit

#: Distances above ``ROBUST_C`` × median leave a particle out of the next robust fit.
ROBUST_C = 3.0
#: Distances below this fraction of the part's size count as zero when choosing the inliers.
ROBUST_FLOOR = 1e-9
ROBUST_MAX_ITER = 25


def rigid_fit(o: np.ndarray, p: np.ndarray):
    """(R, t, distances) of the plain Kabsch fit."""
    R, t = best_fit(o, p)
    return R, t, np.linalg.norm(p - (o @ R.T + t), axis=1)


def robust_fit(o: np.ndarray, p: np.ndarray, c: float = ROBUST_C, floor: float = ROBUST_FLOOR,
               max_iter: int = ROBUST_MAX_ITER):
    """(R, t, distances, inliers) of the robust fit described in the module docstring."""
    n = len(o)
    inl = np.ones(n, dtype=bool)
    if n < 4:
        R, t, d = rigid_fit(o, p)
        return R, t, d, inl
    size = float(np.sqrt(((o - o.mean(axis=0)) ** 2).sum(axis=1).mean())) or 1.0
    tol = floor * size
    for _ in range(max_iter):
        R, t = best_fit(o[inl], p[inl])
        d = np.linalg.norm(p - (o @ R.T + t), axis=1)
        new = d <= max(c * float(np.median(d)), tol)
        if np.array_equal(new, inl) or new.sum() < 3:
            break
        inl = new
    return R, t, d, inl


FITS = {"robust": lambda o, p: robust_fit(o, p)[:3], "kabsch": rigid_fit}
