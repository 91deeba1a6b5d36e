"""Points near each other, by cells: which pairs of points are at most r apart, and how many.

Two points at most r apart lie in the same or neighbouring cells of side r, so each point is
compared with those of its own cell and of the 26 around it. This is what ``rackstress run``
needs before its simulation (the scene's coincident particles, the memory estimate's binding
pairs), without scipy.spatial, whose import (0.2 s) is a tenth of a small run's simulation.
"""
from __future__ import annotations

import numpy as np


def _candidates(a: np.ndarray, b: np.ndarray, r: float, half: bool):
    """Batches of index pairs (i into ``a``, j into ``b``) of points in the same or
    neighbouring cells of side ``r``; with ``half`` (``a`` is ``b``), each unordered pair once,
    no point with itself."""
    lo = np.minimum(a.min(axis=0), b.min(axis=0))
    ca = np.floor((a - lo) / r).astype(np.uint64) + np.uint64(1)
    cb = np.floor((b - lo) / r).astype(np.uint64) + np.uint64(1)
    s1, s2 = (int(x) + 3 for x in np.maximum(ca.max(axis=0), cb.max(axis=0))[1:])
    # a cell's key, wrapping modulo 2**64 where the cells are many: a neighbour's key is still
    # the key plus the offset's, and a key shared by far cells only adds candidates
    ka = (ca[:, 0] * np.uint64(s1) + ca[:, 1]) * np.uint64(s2) + ca[:, 2]
    kb = (cb[:, 0] * np.uint64(s1) + cb[:, 1]) * np.uint64(s2) + cb[:, 2]
    order = np.argsort(kb, kind="stable")
    ks = kb[order]
    # the queries in key order too: a sorted needle array is searched in cache order (4 M
    # points: 0.8 s a search unsorted, a tenth of that sorted)
    by = order if half else np.argsort(ka, kind="stable")
    ka = ka[by]
    for d in np.ndindex(3, 3, 3):
        dx, dy, dz = (x - 1 for x in d)
        if half and (dx, dy, dz) < (0, 0, 0):
            continue
        off = np.uint64(((dx * s1 + dy) * s2 + dz) % 2 ** 64)
        first = np.searchsorted(ks, ka + off, "left")
        n = np.searchsorted(ks, ka + off, "right") - first
        if not n.any():
            continue
        i = np.repeat(by, n)
        j = np.repeat(first, n) + np.arange(len(i)) - np.repeat(np.cumsum(n) - n, n)
        j = order[j]
        if half and off == 0:
            keep = j > i
            i, j = i[keep], j[keep]
        yield i, j


def close_pairs(o: np.ndarray, r: float) -> np.ndarray:
    """Every pair (i < j) of the points ``o`` (n, 3) at most ``r`` apart, as an (m, 2) array
    sorted by i then j: what ``cKDTree(o).query_pairs(r)`` finds."""
    o = np.asarray(o, dtype=np.float64)
    if len(o) < 2 or not r > 0 or not np.isfinite(o).all():
        return np.zeros((0, 2), np.int64)
    found = []
    for i, j in _candidates(o, o, r, half=True):
        near = np.sum((o[i] - o[j]) ** 2, axis=1) <= r * r
        found.append(np.stack([i[near], j[near]], axis=1))
    if not found:
        return np.zeros((0, 2), np.int64)
    pairs = np.sort(np.concatenate(found), axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def count_within(a: np.ndarray, b: np.ndarray, r: float) -> int:
    """How many ordered pairs (i of ``a``, j of ``b``) are at most ``r`` apart, a point with
    itself included when ``a`` and ``b`` share it: what
    ``cKDTree(a).count_neighbors(cKDTree(b), r)`` counts."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if not len(a) or not len(b) or not r >= 0:
        return 0
    r = max(float(r), 1e-300)
    return int(sum(np.count_nonzero(np.sum((a[i] - b[j]) ** 2, axis=1) <= r * r)
                   for i, j in _candidates(a, b, r, half=False)))


def any_closer(a: np.ndarray, b: np.ndarray, r: float) -> bool:
    """Whether some point of ``a`` is closer than ``r`` (strictly) to some point of ``b``: what
    ``np.isfinite(cKDTree(b).query(a, distance_upper_bound=r)[0]).any()`` says. Only the
    points of ``b`` within ``r`` of ``a``'s box are put in cells (a foot over a sediment of a
    million particles)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if not len(a) or not len(b) or not r > 0:
        return False
    lo, hi = a.min(axis=0) - r, a.max(axis=0) + r
    b = b[np.all((b >= lo) & (b <= hi), axis=1)]
    if not len(b):
        return False
    return any(bool(np.any(np.sum((a[i] - b[j]) ** 2, axis=1) < r * r))
               for i, j in _candidates(a, b, r, half=False))


def touching_pairs(a: np.ndarray, b: np.ndarray, ra: np.ndarray, rb: np.ndarray,
                   slack: float = 0.0) -> tuple:
    """The pairs of a point of ``a`` and one of ``b`` at most the sum of their radii apart
    (× (1 + ``slack``)): (i, j, R²) with i into ``a``, j into ``b`` and R = ra[i] + rb[j] —
    two parts' particles in contact (Eq. 10 acts within R)."""
    from scipy.spatial import cKDTree

    ra, rb = np.asarray(ra, float), np.asarray(rb, float)
    if not len(a) or not len(b):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    reach = float(ra.max() + rb.max()) * (1.0 + slack)
    dm = cKDTree(a).sparse_distance_matrix(cKDTree(b), reach, output_type="ndarray")
    i, j, d = dm["i"].astype(np.int64), dm["j"].astype(np.int64), dm["v"]
    R2 = (ra[i] + rb[j]) ** 2
    keep = d * d <= R2 * (1.0 + slack) ** 2
    return i[keep], j[keep], R2[keep]


def in_cells(p: np.ndarray, x: np.ndarray, spacing: float, slack: float = 1e-6) -> tuple:
    """The pairs of a point of ``p`` and a particle of ``x`` whose closed cell (the cube of side
    ``spacing`` about it, × (1 + ``slack``)) holds it: (i into ``p``, j into ``x``). Which
    nodes of a finite-element mesh a held or loaded particle's cell covers (the FE check's
    supports, a submodel's engaged surface).

    >>> in_cells(np.array([[0.4, 0, 0], [0.6, 0, 0], [2.0, 0, 0]]),
    ...          np.array([[0.0, 0, 0], [1.0, 0, 0]]), 1.0)
    (array([0, 1]), array([0, 1]))
    """
    p, x = np.asarray(p, dtype=np.float64), np.asarray(x, dtype=np.float64)
    if not len(p) or not len(x) or not spacing > 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    h = 0.5 * float(spacing) * (1.0 + slack)
    found_i, found_j = [], []
    for i, j in _candidates(p, x, 2.0 * h, half=False):
        inside = np.all(np.abs(p[i] - x[j]) <= h, axis=1)
        found_i.append(i[inside])
        found_j.append(j[inside])
    if not found_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i, j = np.concatenate(found_i).astype(np.int64), np.concatenate(found_j).astype(np.int64)
    order = np.lexsort((j, i))
    return i[order], j[order]


def lattice_neighbours(o: np.ndarray, spacing: float) -> np.ndarray:
    """Each particle's lattice neighbours on its cubic lattice (n, 3, 2): per axis, the index
    of the particle at −a and at +a, −1 where there is none."""
    a = float(spacing)
    o = np.asarray(o, float)
    g = np.rint((o - o.min(axis=0)) / a).astype(np.int64) + 1
    at = np.full(tuple(g.max(axis=0) + 2), -1, dtype=np.int32)
    at[g[:, 0], g[:, 1], g[:, 2]] = np.arange(len(o))
    out = np.full((len(o), 3, 2), -1, dtype=np.int64)
    for ax in range(3):
        for h, step in enumerate((-1, 1)):
            n = g.copy()
            n[:, ax] += step
            out[:, ax, h] = at[n[:, 0], n[:, 1], n[:, 2]]
    return out


def lattice_sides(o: np.ndarray, spacing: float) -> np.ndarray:
    """Which lattice neighbours each particle has on its cubic lattice (n, 3, 2): per axis,
    the particle at −a and at +a."""
    return lattice_neighbours(o, spacing) >= 0
