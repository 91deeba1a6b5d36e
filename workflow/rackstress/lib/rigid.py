"""Best-fit rigid motion of a part and the paper's "desired position" (Section 5.2, docs/model.md, "Desired position").

The desired position of a particle is its original position carried by its part's current rigid
motion. Which rigid motion? Two answers, both built on :func:`best_fit` (Kabsch: the rotation R
and translation t minimizing Σ‖p_i − (R o_i + t)‖², from
``scipy.spatial.transform.Rotation.align_vectors``):

plain (:func:`rigid_fit`, :func:`deformation`)
    The least-squares fit over all particles of the part. A local deformation drags this fit a
    little, so a particle that did not move relative to its neighbours still shows a small
    distance.
robust (:func:`robust_fit`, :func:`robust_deformation`; what ``summary.json``, the pictures,
the report and the VTK files all use)
    The same fit, repeated on the particles that follow the part's rigid motion: after each fit,
    the particles whose distance exceeds ``c`` times the median distance (c = 3) are left out of
    the next fit, until the set no longer changes. The median keeps at least half of the part in
    every fit. When some particles moved rigidly and others did not (a local bump, a bent toe),
    the fit lands on the rigid ones exactly, so the bump's particles show exactly their own
    displacement and the rest exactly zero. On a part deformed everywhere it fits the least
    deformed core — "desired" is what the bulk of the part says.

A rigid motion gives zero (to round-off, ~1e-15 of the part's size) under both. This module is
in ``lib`` so that the run's summary (``runs``) and the stress measures (``stress``) share one fit.
"""
from __future__ import annotations

import warnings

import numpy as np

#: Distances above ``ROBUST_C`` × median leave a particle out of the next robust fit.
ROBUST_C = 3.0
#: Distances below this fraction of the part's size count as zero when choosing the inliers.
ROBUST_FLOOR = 1e-9
ROBUST_MAX_ITER = 25


def best_fit(o: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) with p ≈ o·Rᵀ + t in the least-squares sense (equal weights)."""
    co, cp = o.mean(axis=0), p.mean(axis=0)
    if len(o) < 2:
        return np.eye(3), cp - co
    from scipy.spatial.transform import Rotation   # 0.2 s to import: not at a run's start

    with warnings.catch_warnings():  # collinear sets: any rotation about the line is optimal
        warnings.simplefilter("ignore", UserWarning)
        rot, _ = Rotation.align_vectors(p - cp, o - co)
    R = rot.as_matrix()
    return R, cp - co @ R.T


def kabsch(o: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of :func:`best_fit` by the SVD of the 3 × 3 covariance directly (Kabsch 1976,
    reflection excluded): the same minimizer without scipy's per-call overhead, for the robust
    fit's repeated fits over every part and frame of a run."""
    co, cp = o.mean(axis=0), p.mean(axis=0)
    if len(o) < 2:
        return np.eye(3), cp - co
    H = (o - co).T @ (p - cp)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cp - co @ R.T


def rigid_fit(o: np.ndarray, p: np.ndarray):
    """(R, t, distances) of the plain Kabsch fit."""
    R, t = best_fit(o, p)
    return R, t, np.linalg.norm(p - (o @ R.T + t), axis=1)


def robust_floor(o: np.ndarray, floor: float = ROBUST_FLOOR) -> float:
    """The distance below which the robust fit counts a particle's distance as zero when it
    chooses the inliers: ``floor`` × the part's size (its particles' RMS distance from their
    centre)."""
    return floor * (float(np.sqrt(((o - o.mean(axis=0)) ** 2).sum(axis=1).mean())) or 1.0)


def robust_fit(o: np.ndarray, p: np.ndarray, c: float = ROBUST_C, floor: float = ROBUST_FLOOR,
               max_iter: int = ROBUST_MAX_ITER):
    """(R, t, distances, inliers) of the robust fit described in the module docstring.

    Example
    -------
    >>> o = np.array([[x, 0.0, z] for x in range(5) for z in range(5)])
    >>> p = o.copy(); p[0, 1] += 1.0             # lift one corner: a local bump
    >>> d = robust_fit(o, p)[2]
    >>> round(float(d[0]), 12), float(d[1:].max()) < 1e-12
    (1.0, True)
    """
    n = len(o)
    inl = np.ones(n, dtype=bool)
    if n < 4:
        R, t, d = rigid_fit(o, p)
        return R, t, d, inl
    tol = robust_floor(o, floor)
    for _ in range(max_iter):
        R, t = kabsch(o[inl], p[inl])
        d = np.linalg.norm(p - (o @ R.T + t), axis=1)
        new = d <= max(c * float(np.median(d)), tol)
        if np.array_equal(new, inl) or new.sum() < 3:
            break
        inl = new
    return R, t, d, inl


def desired_positions(o: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The original positions carried by the plain best-fit rigid motion of o onto p."""
    R, t = best_fit(o, p)
    return o @ R.T + t


def deformation(o: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Per-particle distance from the desired position under the plain fit."""
    return np.linalg.norm(p - desired_positions(o, p), axis=1)


def robust_deformation(o: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Per-particle distance from the desired position under the robust fit: the paper's
    stress measure as the pictures, the report, the VTK files and ``summary.json`` give it."""
    return robust_fit(o, p)[2]


def max_deformation(o: np.ndarray, p: np.ndarray) -> float:
    """Largest distance of a particle from its desired position, robust fit (0 for a rigid
    motion): ``summary.json``'s ``max_deformation``, the same number as the paper measure of the
    pictures at that frame."""
    return float(robust_deformation(o, p).max())


def kabsch_frames(H: np.ndarray, co: np.ndarray, cp: np.ndarray) -> tuple:
    """(R, t), (f, 3, 3) and (f, 3), of :func:`kabsch` for many fits at once, from each fit's
    cross-covariance H = Σ (o − co)(p − cp)ᵀ (f, 3, 3) and centroids co, cp (f, 3): one
    batched SVD (reflection excluded)."""
    U, _, Vt = np.linalg.svd(H)
    V, Ut = Vt.transpose(0, 2, 1), U.transpose(0, 2, 1)
    det = np.sign(np.linalg.det(np.matmul(V, Ut)))
    D = np.ones((len(H), 3))
    D[:, 2] = np.where(det == 0, 1.0, det)
    R = np.matmul(V * D[:, None, :], Ut)                              # V diag(1,1,d) Uᵀ
    return R, cp - np.einsum("fk,fjk->fj", co, R)


def robust_fit_frames(o: np.ndarray, P: np.ndarray, c: float = ROBUST_C,
                      floor: float = ROBUST_FLOOR, max_iter: int = ROBUST_MAX_ITER) -> np.ndarray:
    """Distances of :func:`robust_fit` for many frames at once: ``P`` is (frames, n, 3), the
    result (frames, n). The same iteration frame by frame (each frame keeps its own inlier set
    and stops when that set no longer changes), with the Kabsch fits of every frame still
    iterating done as one batched SVD: the per-call overhead of thousands of 3 × 3 fits (a part
    and a frame each) is what the robust measure cost.

    Example
    -------
    >>> o = np.array([[x, 0.0, z] for x in range(5) for z in range(5)])
    >>> p = o.copy(); p[0, 1] += 1.0
    >>> d = robust_fit_frames(o, np.stack([o, p]))
    >>> float(d[0].max()) < 1e-12, round(float(d[1, 0]), 12), float(d[1, 1:].max()) < 1e-12
    (True, 1.0, True)
    """
    P = np.asarray(P, dtype=np.float64)
    nf, n = P.shape[:2]
    if n < 4:
        return np.stack([rigid_fit(o, p)[2] for p in P]) if nf else np.zeros((0, n))
    tol = robust_floor(o, floor)
    inl = np.ones((nf, n), dtype=bool)
    d = np.empty((nf, n))
    todo = np.arange(nf)
    for _ in range(max_iter):
        if not len(todo):
            break
        w = inl[todo].astype(np.float64)                              # (f, n)
        cnt = w.sum(axis=1)[:, None]
        Pt = P[todo]
        co = (w @ o) / cnt                                            # (f, 3)
        cp = np.einsum("fn,fnk->fk", w, Pt) / cnt
        X = (o[None] - co[:, None]) * w[:, :, None]
        H = np.matmul(X.transpose(0, 2, 1), Pt - cp[:, None])         # (f, 3, 3)
        R, t = kabsch_frames(H, co, cp)
        dd = np.linalg.norm(Pt - (np.einsum("nk,fjk->fnj", o, R) + t[:, None]), axis=2)
        d[todo] = dd
        new = dd <= np.maximum(c * np.median(dd, axis=1), tol)[:, None]
        done = (new == inl[todo]).all(axis=1) | (new.sum(axis=1) < 3)
        inl[todo[~done]] = new[~done]
        todo = todo[~done]
    return d
