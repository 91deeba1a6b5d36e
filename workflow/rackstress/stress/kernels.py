"""The strain measures' one loop, compiled: η and D²min of every particle and frame in one pass.

:class:`rackstress.stress.measures.VonMisesStrain` states the fit (Falk & Langer: F = W V⁺ with
W = Σ d d₀ᵀ over the neighbourhood, η of E = ½(FᵀF − I), D²min = Σ ‖d − F d₀‖²) in NumPy, a
dozen temporary arrays over every pair and frame; here the same arithmetic runs pair by pair
without them (``numba.njit``, cached on disk where :mod:`rackstress.model.kernels` keeps its
kernels, so only the first run on a machine compiles it: :func:`warm`). A particle that rests
with all its neighbours in a frame gets η = D²min = 0 without a fit: d = d₀ for each of its
pairs, so W = V and F = I exactly. Without numba, :func:`available` is False and the NumPy
path (:func:`rackstress.stress.measures.strain_frames`) serves.
"""
from __future__ import annotations

import time

import numpy as np

try:
    from rackstress.model import kernels as _model_kernels  # noqa: F401 - sets NUMBA_CACHE_DIR
    import numba as nb
except ImportError:  # pragma: no cover - numba is a dependency; the NumPy path stays
    nb = None


def available() -> bool:
    """Whether the compiled loop can be used (numba importable)."""
    return nb is not None


if nb is not None:
    @nb.njit(cache=True, error_model="numpy", nogil=True)
    def _strain(P, o, indptr, nbr, Vp, rank, t1, t2, n0, valid, eta, d2):  # pragma: no cover
        nf, n = P.shape[0], P.shape[1]
        W = np.empty((3, 3))
        F = np.empty((3, 3))
        for f in range(nf):
            for i in range(n):
                if not valid[i]:
                    eta[f, i] = np.nan
                    d2[f, i] = np.nan
                    continue
                still = True
                for c in range(3):
                    if P[f, i, c] != o[i, c]:
                        still = False
                for k in range(indptr[i], indptr[i + 1]):
                    j = nbr[k]
                    for c in range(3):
                        if P[f, j, c] != o[j, c]:
                            still = False
                if still:
                    eta[f, i] = 0.0
                    d2[f, i] = 0.0
                    continue
                W[:, :] = 0.0
                for k in range(indptr[i], indptr[i + 1]):
                    j = nbr[k]
                    for a in range(3):
                        da = P[f, j, a] - P[f, i, a]
                        for b in range(3):
                            W[a, b] += da * (o[j, b] - o[i, b])
                for a in range(3):
                    for b in range(3):
                        F[a, b] = W[a, 0] * Vp[i, 0, b] + W[a, 1] * Vp[i, 1, b] \
                            + W[a, 2] * Vp[i, 2, b]
                if rank[i] == 2:
                    # planar neighbourhood: carry the normal n0 to the deformed plane's normal
                    av = np.zeros(3)
                    bv = np.zeros(3)
                    for a in range(3):
                        for b in range(3):
                            av[a] += F[a, b] * t1[i, b]
                            bv[a] += F[a, b] * t2[i, b]
                    nx = av[1] * bv[2] - av[2] * bv[1]
                    ny = av[2] * bv[0] - av[0] * bv[2]
                    nz = av[0] * bv[1] - av[1] * bv[0]
                    nn = np.sqrt(nx * nx + ny * ny + nz * nz)
                    if nn > 0:
                        nx, ny, nz = nx / nn, ny / nn, nz / nn
                    for b in range(3):
                        F[0, b] += nx * n0[i, b]
                        F[1, b] += ny * n0[i, b]
                        F[2, b] += nz * n0[i, b]
                # E = ½(FᵀF − I), η as OVITO defines it
                E00 = 0.5 * (F[0, 0] * F[0, 0] + F[1, 0] * F[1, 0] + F[2, 0] * F[2, 0] - 1.0)
                E11 = 0.5 * (F[0, 1] * F[0, 1] + F[1, 1] * F[1, 1] + F[2, 1] * F[2, 1] - 1.0)
                E22 = 0.5 * (F[0, 2] * F[0, 2] + F[1, 2] * F[1, 2] + F[2, 2] * F[2, 2] - 1.0)
                E01 = 0.5 * (F[0, 0] * F[0, 1] + F[1, 0] * F[1, 1] + F[2, 0] * F[2, 1])
                E12 = 0.5 * (F[0, 1] * F[0, 2] + F[1, 1] * F[1, 2] + F[2, 1] * F[2, 2])
                E02 = 0.5 * (F[0, 0] * F[0, 2] + F[1, 0] * F[1, 2] + F[2, 0] * F[2, 2])
                eta[f, i] = np.sqrt(E01 ** 2 + E12 ** 2 + E02 ** 2
                                    + ((E00 - E11) ** 2 + (E11 - E22) ** 2
                                       + (E22 - E00) ** 2) / 6.0)
                s = 0.0
                for k in range(indptr[i], indptr[i + 1]):
                    j = nbr[k]
                    for a in range(3):
                        r = (P[f, j, a] - P[f, i, a]) - (F[a, 0] * (o[j, 0] - o[i, 0])
                                                         + F[a, 1] * (o[j, 1] - o[i, 1])
                                                         + F[a, 2] * (o[j, 2] - o[i, 2]))
                        s += r * r
                d2[f, i] = s


if nb is not None:
    @nb.njit(cache=True, error_model="numpy", nogil=True)
    def _robust_cross(o, P, inl, todo, H, co, cp):  # pragma: no cover - compiled
        """Each fit's centroids and cross-covariance over its inliers (frames ``todo``)."""
        n = o.shape[0]
        for m in range(len(todo)):
            f = todo[m]
            cnt = 0.0
            for a in range(3):
                co[m, a] = 0.0
                cp[m, a] = 0.0
            for i in range(n):
                if inl[f, i]:
                    cnt += 1.0
                    for a in range(3):
                        co[m, a] += o[i, a]
                        cp[m, a] += P[f, i, a]
            for a in range(3):
                co[m, a] /= cnt
                cp[m, a] /= cnt
            for a in range(3):
                for b in range(3):
                    H[m, a, b] = 0.0
            for i in range(n):
                if inl[f, i]:
                    for a in range(3):
                        x = o[i, a] - co[m, a]
                        for b in range(3):
                            H[m, a, b] += x * (P[f, i, b] - cp[m, b])

    @nb.njit(cache=True, error_model="numpy", nogil=True)
    def _robust_dist(o, P, R, t, todo, d):  # pragma: no cover - compiled
        """|p − (R o + t)| of every particle of frames ``todo``."""
        n = o.shape[0]
        for m in range(len(todo)):
            f = todo[m]
            for i in range(n):
                ss = 0.0
                for a in range(3):
                    r = P[f, i, a] - ((o[i, 0] * R[m, a, 0] + o[i, 1] * R[m, a, 1]
                                       + o[i, 2] * R[m, a, 2]) + t[m, a])
                    ss += r * r
                d[f, i] = np.sqrt(ss)

    @nb.njit(cache=True, error_model="numpy", nogil=True)
    def _robust_keep(d, limit, todo, inl, done):  # pragma: no cover - compiled
        """The next inliers (d ≤ limit) of frames ``todo``; ``done`` where they are the same
        set, or fewer than 3 (then the set is kept)."""
        n = d.shape[1]
        for m in range(len(todo)):
            f = todo[m]
            same, kept = True, 0
            for i in range(n):
                k = d[f, i] <= limit[m]
                kept += k
                if k != inl[f, i]:
                    same = False
            done[m] = same or kept < 3
            if not done[m]:
                for i in range(n):
                    inl[f, i] = d[f, i] <= limit[m]


def robust_fit_frames(o: np.ndarray, P: np.ndarray) -> np.ndarray:
    """:func:`rackstress.lib.rigid.robust_fit_frames` (the paper measure's robust fit, the
    definition) with its passes over the particles compiled: each iteration's centroids and
    cross-covariances, distances and next inliers are plain loops (no temporary array over
    frames × particles), the fits themselves the same batched SVD
    (:func:`rackstress.lib.rigid.kabsch_frames`) and the medians NumPy's (magpod-small's 101
    frames: 0.26 s of CPU → 0.04 s). The same arithmetic up to summation order: the two agree
    to round-off (tests). Parts of fewer than 4 particles, and a machine without numba, take
    the NumPy path."""
    from rackstress.lib import rigid

    P = np.asarray(P, dtype=np.float64)
    nf, n = P.shape[:2]
    if nb is None or n < 4:
        return rigid.robust_fit_frames(o, P)
    o = np.ascontiguousarray(o, dtype=np.float64)
    P = np.ascontiguousarray(P)
    tol = rigid.robust_floor(o)
    inl = np.ones((nf, n), dtype=bool)
    d = np.empty((nf, n))
    todo = np.arange(nf)
    for _ in range(rigid.ROBUST_MAX_ITER):
        if not len(todo):
            break
        H, co, cp = np.empty((len(todo), 3, 3)), np.empty((len(todo), 3)), np.empty((len(todo), 3))
        _robust_cross(o, P, inl, todo, H, co, cp)
        R, t = rigid.kabsch_frames(H, co, cp)
        _robust_dist(o, P, np.ascontiguousarray(R), np.ascontiguousarray(t), todo, d)
        limit = np.maximum(rigid.ROBUST_C * np.median(d[todo], axis=1), tol)
        done = np.empty(len(todo), dtype=bool)
        _robust_keep(d, limit, todo, inl, done)
        todo = todo[~done]
    return d


def strain(hood, o: np.ndarray, P: np.ndarray):
    """(η, D²min), each (frames, n), of frames ``P`` (frames, n, 3) over ``hood``'s
    neighbourhoods (:class:`rackstress.stress.measures.Neighbourhoods`)."""
    indptr, nbr = hood.csr()
    P = np.ascontiguousarray(P, dtype=np.float64)
    eta = np.empty(P.shape[:2])
    d2 = np.empty(P.shape[:2])
    _strain(P, np.ascontiguousarray(o), indptr, nbr, hood.Vpinv, hood.rank.astype(np.int64),
            np.ascontiguousarray(hood.t1), np.ascontiguousarray(hood.t2), hood.n0,
            hood.valid, eta, d2)
    return eta, d2


def warm() -> float:
    """Compile (first run on a machine) or load the loops (strain, the robust fit) and the
    dump's number parser (:mod:`rackstress.lib.numtext`); return the seconds it took."""
    t = time.perf_counter()
    if nb is not None:
        from types import SimpleNamespace

        z = np.zeros((1, 3))
        hood = SimpleNamespace(csr=lambda: (np.zeros(2, np.int64), np.zeros(0, np.int64)),
                               Vpinv=np.zeros((1, 3, 3)), rank=np.zeros(1, np.int64), t1=z,
                               t2=z, n0=z, valid=np.zeros(1, bool))
        strain(hood, z, z[None])
        o = np.eye(4, 3)
        robust_fit_frames(o, o[None])
        from rackstress.lib import numtext

        numtext.warm()              # the dump's number parser, loaded with it
    return time.perf_counter() - t


# whether the loop is cached, and compiling it apart: numba-free, for ``rackstress run``'s start
from rackstress.stress.warming import compiled, wait_warm, warm_in_background  # noqa: E402,F401
