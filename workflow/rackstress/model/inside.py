"""The fast ``bind … within … inside`` test: which binding segments stay inside the part.

:class:`rackstress.model.operators.WithinInside` keeps a binding when its segment is inside the
part's shape: every point of it at 1/32 … 31/32 of its length is an *interior* point (its 8
neighbours at ±ε along the diagonals are in the region) or a point of a flat face (the 4 on one
side of one axis are) — :func:`sampled`, 248 region tests a binding. That is exact enough but slow (70 s at 17,600 particles on a mesh). This module gives the
same answer with almost no region tests, in three steps:

1. **The lattice's own cells.** A filled part's particles sit on a cubic lattice of spacing s
   (:func:`lattice_of` finds it from the positions). Each site owns the cube of side s around
   it. A segment between two sites passes through the closed cells :func:`touched_cells` lists
   (exact, in rational arithmetic: a face neighbour touches its two end cells, a diagonal
   through an edge's midpoint the four around that edge, …).
2. **Solid sites.** A site is *solid* when its 8 diagonal neighbours at ±δ (δ = s/50) are in the
   region: one :meth:`Region.grid_mask` per diagonal over the whole grid (a mesh: VTK's scan
   conversion, ~10⁷ sites a second). A segment all of whose touched cells have solid sites is
   kept without further test: the region's boundary stays out of those cells unless it has a
   concave feature (hole, notch, slot) of radius below ~0.7 s that passes between sites —
   which the lattice cannot represent either (its fill would not see it).
3. **The doubtful rest** — segments touching a cell whose site is outside or on the boundary,
   i.e. the re-entrant corners and the staircase of curved or sloped faces — are decided
   exactly: on a mesh (:class:`~rackstress.model.regions.Surface`) whose end sites are solid, by
   VTK's OBB-tree segment–triangle test on the segment and its 8 copies moved by ±ε along the
   diagonals (no hit keeps it: both ends are inside, so a segment that neither crosses nor
   grazes the surface stays in the part); the few with a hit — a real crossing, or a segment
   passing within VTK's tolerance (~10⁻⁵ of the part) of an edge — and anything else, by
   :func:`sampled`, so a dropped binding is always one the sampling test drops.

Points that are not on one cubic lattice (hcp packing, the paper's random sediment, two groups
on different grids) go through :func:`sampled` alone.

Example
-------
>>> import numpy as np
>>> from rackstress.model.regions import Box
>>> L = Box((-.5, -.5, -.5), (.5, 1.5, .5)) | Box((-.5, .5, -.5), (1.5, 1.5, .5))
>>> a = np.array([[0., 0, 0], [0, 0, 0]]); b = np.array([[0., 1, 0], [1, 1, 0]])
>>> segments_inside(L, a, b, 1.5).tolist()
[True, False]
"""
from __future__ import annotations

import sys
import time
from fractions import Fraction
from functools import lru_cache

import numpy as np

#: Points of a segment tested by :func:`sampled`: k/SAMPLES for k = 1 … SAMPLES − 1.
SAMPLES = 32
#: Segments per chunk of :func:`sampled` (its memory: CHUNK · 248 points).
CHUNK = 4096
#: A site is solid when its diagonal neighbours at ±DELTA·s are in the region.
DELTA = 0.02
#: The lattice's grid may hold at most this many sites per point (else: not a filled part).
GRID_PER_POINT = 64
#: Work of at least this many segments reports itself (a bar on a terminal, else one line).
REPORT_AT = 200_000

_DIAG = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)

from rackstress.lib.jit import numba_or_none

nb = numba_or_none()      # None: the NumPy paths serve (numba is a dependency)
#: Pairs from which :func:`length_sq` and :func:`sort_pairs` take their compiled kernels: below
#: it NumPy takes well under a second, less than compiling them on a fresh cache (~8 s, which
#: README's first command would wait before its first step: magpod-small's binds have ~10⁵ pairs)
COMPILED_FROM = 2_000_000

if nb is not None:
    @nb.njit(cache=True, parallel=True, nogil=True)
    def _certain_nb(ijk, i, j, m, w, ptr, offs, strides, solid):  # pragma: no cover
        """Step 2 per pair, on both cores: every touched cell's site is solid."""
        n = len(i)
        out = np.ones(n, dtype=np.bool_)
        for k in nb.prange(n):
            a, b = i[k], j[k]
            code = ((ijk[b, 0] - ijk[a, 0] + m) * w + ijk[b, 1] - ijk[a, 1] + m) * w \
                + ijk[b, 2] - ijk[a, 2] + m
            base = (ijk[a, 0] + 1) * strides[0] + (ijk[a, 1] + 1) * strides[1] \
                + (ijk[a, 2] + 1) * strides[2]
            for t in range(ptr[code], ptr[code + 1]):
                if not solid[base + offs[t]]:
                    out[k] = False
                    break
        return out

    @nb.njit(cache=True, parallel=True, nogil=True)
    def _max_offset_nb(ijk, i, j):  # pragma: no cover
        """The largest |Δijk| component over the pairs."""
        m = 0
        for k in nb.prange(len(i)):
            for c in range(3):
                v = abs(ijk[j[k], c] - ijk[i[k], c])
                m = max(m, v)
        return m

    @nb.njit(cache=True, parallel=True, nogil=True)
    def _length_sq_nb(a, b, i, j):  # pragma: no cover
        out = np.empty(len(i))
        for k in nb.prange(len(i)):
            x = b[j[k], 0] - a[i[k], 0]
            y = b[j[k], 1] - a[i[k], 1]
            z = b[j[k], 2] - a[i[k], 2]
            out[k] = x * x + y * y + z * z
        return out

    @nb.njit(cache=True, nogil=True)
    def _sort_pairs_nb(i, j, n):  # pragma: no cover
        """(i, j) in (i, j) order: a counting sort on i, then each particle's few partners
        sorted in place (insertion sort: ≤ 18 on a lattice) — O(m), where a sort of the
        combined keys is O(m log m)."""
        m = len(i)
        start = np.zeros(n + 1, dtype=np.int64)
        for k in range(m):
            start[i[k] + 1] += 1
        for r in range(n):
            start[r + 1] += start[r]
        pos = start[:-1].copy()
        oi = np.empty(m, dtype=np.int64)
        oj = np.empty(m, dtype=np.int64)
        for k in range(m):
            r = i[k]
            oj[pos[r]] = j[k]
            pos[r] += 1
        for r in range(n):
            lo, hi = start[r], start[r + 1]
            for a in range(lo, hi):
                oi[a] = r
            for a in range(lo + 1, hi):
                v = oj[a]
                b = a - 1
                while b >= lo and oj[b] > v:
                    oj[b + 1] = oj[b]
                    b -= 1
                oj[b + 1] = v
        return oi, oj


def length_sq(a: np.ndarray, b: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """‖b[j] − a[i]‖² per pair (compiled, no n × 3 temporaries, when numba is there); the
    same arithmetic as the NumPy expression, so the same bits."""
    if nb is not None and len(i) >= COMPILED_FROM:
        return _length_sq_nb(np.ascontiguousarray(a, float), np.ascontiguousarray(b, float),
                             np.asarray(i, np.int64), np.asarray(j, np.int64))
    d = b[j] - a[i]
    return d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]


def sort_pairs(i: np.ndarray, j: np.ndarray):
    """The pairs (i, j) in (i, j) order, as int64 (compiled counting sort when numba is
    there; else one sort of the combined key)."""
    i, j = np.asarray(i, np.int64), np.asarray(j, np.int64)
    if not len(i):
        return i, j
    n = int(max(i.max(), j.max())) + 1
    if nb is not None and len(i) >= COMPILED_FROM:
        return _sort_pairs_nb(i, j, n)
    key = np.sort(i * n + j)
    return key // n, key % n


def lattice_pairs(o: np.ndarray, d: float):
    """(i, j), i < j, int64: every pair of ``o`` closer than ``d`` (strictly, Eq. 16), when
    ``o`` lies on one cubic lattice; else None (the caller's k-d tree serves). The same set
    as :meth:`scipy.spatial.cKDTree.query_pairs` with the strict filter, without a tree: a
    pair of lattice sites is one of the few integer offsets shorter than d, looked up in a
    dense grid of the sites (a pair within 10⁻⁶·d of d is tested on its coordinates)."""
    o = np.asarray(o, float).reshape(-1, 3)
    n = len(o)
    if n < 2:
        return None
    # the spacing: the smallest non-zero coordinate step between successive particles (a
    # fill lists its sites row by row; a guess that is not the grid's fails the check below)
    step = np.abs(np.diff(o, axis=0))
    step = step[step > 1e-9 * max(float(np.abs(o).max()), 1e-300)]
    if not len(step):
        return None
    s = float(step.min())
    del step
    lo = o.min(axis=0)
    ijk = np.rint((o - lo) / s).astype(np.int64)
    if np.abs(lo + ijk * s - o).max() > 1e-6 * s:
        return None
    r = int(np.floor(d / s * (1 + 1e-6)))
    dims = ijk.max(axis=0) + 1 + 2 * r
    if float(np.prod(dims.astype(float))) > GRID_PER_POINT * n + 1000:
        return None
    strides = np.array([1, dims[0], dims[0] * dims[1]], dtype=np.int64)
    grid = np.full(int(np.prod(dims)), -1, dtype=np.int64)
    flat = (ijk + r) @ strides
    grid[flat] = np.arange(n)
    if not np.array_equal(grid[flat], np.arange(n)):
        return None                              # two particles on one site
    I, J = [], []
    for off in np.ndindex(2 * r + 1, 2 * r + 1, 2 * r + 1):
        D = np.array(off) - r
        if tuple(D) <= (0, 0, 0):                # each unordered offset once
            continue
        L = float(np.sqrt((D * D).sum())) * s
        if L >= d * (1 + 1e-6):
            continue
        q = grid[flat + int(D @ strides)]
        p = np.flatnonzero(q >= 0)
        q = q[p]
        if abs(L - d) <= 1e-6 * d:               # on the edge of d: its coordinates decide
            diff = o[q] - o[p]
            keep = np.einsum("ij,ij->i", diff, diff) < d * d
            p, q = p[keep], q[keep]
        I.append(np.minimum(p, q))
        J.append(np.maximum(p, q))
    if not I:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(I), np.concatenate(J)


#: the 8 diagonal neighbours in a flat face's half-space through the point: the 4 on one side
#: of one axis (a face of the part through a sample point, its outward normal along that axis)
_HALVES = np.array([_DIAG[:, ax] == sign for ax in range(3) for sign in (-1.0, 1.0)])


def sampled(region, a: np.ndarray, b: np.ndarray, d: float) -> np.ndarray:
    """Whether each segment a[k]–b[k] lies inside ``region`` by sampling: its points at
    1/32 … 31/32 are interior points of the region (all 8 diagonal neighbours at ε = 10⁻⁶·d in
    it) or points of a flat face of it (exactly the 4 on one side of one axis in it). The
    definition the fast path (:func:`segments_inside`) reproduces, and its reference.

    A face point counts: a lattice layer that falls on the part's face (the bracket's 3 mm leg
    at spacing 0.4: sites at 0.2 … 3.0) lies on the closed part, and its in-face bindings cross
    no free space — taken for crossings, 20,377 of the bracket's 361,620 bindings were dropped
    and the face layer hung on the interior alone. A point at a re-entrant corner or edge
    (6 of 8 in) or in free space (0) still drops the segment.
    """
    a, b = np.asarray(a, float).reshape(-1, 3), np.asarray(b, float).reshape(-1, 3)
    t = np.arange(1, SAMPLES) / SAMPLES
    offs = 1e-6 * float(d) * _DIAG
    out = np.ones(len(a), dtype=bool)
    for s in range(0, len(a), CHUNK):
        aa, bb = a[s:s + CHUNK], b[s:s + CHUNK]
        pts = aa[:, None, None, :] + t[None, :, None, None] * (bb - aa)[:, None, None, :] \
            + offs[None, None, :, :]
        ok = region.mask(pts.reshape(-1, 3)).reshape(len(aa), len(t), len(_DIAG))
        point = ok.all(axis=2)
        for half in _HALVES:
            point |= (ok == half).all(axis=2)
        out[s:s + CHUNK] = point.all(axis=1)
    return out


def lattice_of(points: np.ndarray, a: np.ndarray, b: np.ndarray):
    """(origin, spacing, ijk) when every one of ``points`` is origin + ijk·spacing on one
    cubic grid (ijk int64 n×3), else None. The spacing is guessed from the segments a–b (some
    of them): the smallest non-zero coordinate difference (a face or edge neighbour); a guess
    that is not the grid's spacing fails the check, and the caller samples instead.
    """
    p = np.asarray(points, float).reshape(-1, 3)
    if not len(p) or not len(a):
        return None
    k = slice(0, 200_000)
    diff = np.abs(np.asarray(b[k], float) - np.asarray(a[k], float))
    scale = max(float(np.abs(p).max()), float(diff.max()), 1e-300)
    nz = diff[diff > 1e-9 * scale]
    if not len(nz):
        return None
    s = float(nz.min())
    lo = p.min(axis=0)
    ijk = np.rint((p - lo) / s).astype(np.int64)
    if np.abs(lo + ijk * s - p).max() > 1e-6 * s:
        return None
    if float(np.prod(ijk.max(axis=0) + 3.0)) > GRID_PER_POINT * len(p) + 1000:
        return None
    return lo, s, ijk


@lru_cache(maxsize=256)
def touched_cells(offset: tuple) -> np.ndarray:
    """The cells (integer offsets from the start site) whose closed cube [c − ½, c + ½]³ meets
    the open segment from 0 to ``offset`` (lattice units), in exact rational arithmetic."""
    D = [int(x) for x in offset]
    ranges = [range(min(0, x) - 1, max(0, x) + 2) for x in D]
    out = []
    half = Fraction(1, 2)
    for cx in ranges[0]:
        for cy in ranges[1]:
            for cz in ranges[2]:
                lo, hi, ok = Fraction(0), Fraction(1), True
                for c, x in zip((cx, cy, cz), D):
                    if x == 0:
                        ok = ok and abs(c) <= half
                        continue
                    t0, t1 = sorted(((Fraction(c) - half) / x, (Fraction(c) + half) / x))
                    lo, hi = max(lo, t0), min(hi, t1)
                # the open (0, 1) meets [lo, hi]: lo ≤ hi, lo < 1, hi > 0
                if ok and lo <= hi and lo < 1 and hi > 0:
                    out.append((cx, cy, cz))
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def _solid_sites(region, origin, s: float, dims, bar=None) -> np.ndarray:
    """Flat bool over the grid origin + (i, j, k)·s (x fastest): all 8 diagonal neighbours at
    ±DELTA·s are in ``region``."""
    out = None
    for off in _DIAG * (DELTA * s):
        m = np.asarray(region.grid_mask(np.asarray(origin) + off, (s, s, s), dims), dtype=bool)
        out = m if out is None else (out & m)
        if bar is not None:
            bar.update(1)
    return out


def _ray_hits(polydata, a: np.ndarray, b: np.ndarray, eps: float) -> np.ndarray:
    """Whether each segment a[k]–b[k], or one of its 8 copies moved by ±eps along the
    diagonals, meets the surface (VTK's OBB tree). The copies make a segment that only grazes
    an edge of the surface (through a re-entrant corner) count, as :func:`sampled`'s diagonal
    neighbours do."""
    from vtkmodules.vtkCommonCore import vtkIdList, vtkPoints
    from vtkmodules.vtkFiltersGeneral import vtkOBBTree

    obb = vtkOBBTree()
    obb.SetDataSet(polydata)
    obb.BuildLocator()
    pts, ids = vtkPoints(), vtkIdList()
    hit = np.zeros(len(a), dtype=bool)
    shifts = np.vstack([np.zeros((1, 3)), eps * _DIAG])
    for k in range(len(a)):
        for sh in shifts:
            obb.IntersectWithLine((a[k] + sh).tolist(), (b[k] + sh).tolist(), pts, ids)
            if ids.GetNumberOfIds() > 0:
                hit[k] = True
                break
    return hit


def segments_inside(region, a: np.ndarray, b: np.ndarray, d: float, name: str = "part",
                    report=None) -> np.ndarray:
    """Whether each segment a[k]–b[k] lies inside ``region`` (module docstring: the same
    answer as :func:`sampled`, fast on a filled lattice).

    ``report``: None (default) reports work of ≥ :data:`REPORT_AT` segments — a tqdm bar on a
    terminal, else one line on stderr; False never; True always.

    Example
    -------
    >>> import numpy as np
    >>> from rackstress.model.regions import Box
    >>> box = Box((-.5, -.5, -.5), (2.5, .5, .5))
    >>> segments_inside(box, np.zeros((1, 3)), np.array([[2., 0, 0]]), 2.5).tolist()
    [True]
    """
    a, b = np.asarray(a, float).reshape(-1, 3), np.asarray(b, float).reshape(-1, 3)
    pts = np.concatenate([a, b])
    k = np.arange(len(a))
    return pairs_inside(region, pts, k, k + len(a), d, name=name, report=report)


def pairs_inside(region, points: np.ndarray, i: np.ndarray, j: np.ndarray, d: float,
                 name: str = "part", report=None) -> np.ndarray:
    """Whether each segment points[i[k]]–points[j[k]] lies inside ``region``: as
    :func:`segments_inside`, without gathering the segments' coordinates (a million
    particles' bindings: one lattice index per particle, not per binding end)."""
    o = np.asarray(points, float).reshape(-1, 3)
    i, j = np.asarray(i, np.int64), np.asarray(j, np.int64)
    n = len(i)
    out = np.zeros(n, dtype=bool)
    if n == 0:
        return out
    t0 = time.perf_counter()
    loud = (n >= REPORT_AT) if report is None else bool(report)
    lat = lattice_of(o, o[i[:200_000]], o[j[:200_000]])
    if lat is None:
        out[:] = sampled(region, o[i], o[j], d)
        _say(loud, name, n, n, 0, int((~out).sum()), time.perf_counter() - t0)
        return out
    lo, s, ijk = lat
    bar = None
    if loud and sys.stderr.isatty():            # stages: 8 solid-site passes, cells, rays, samples
        from rackstress.lib.progress import progress_bar

        bar = progress_bar(11, True, f"bind inside {name}")
        bar.unit = "stage"
    try:
        out, doubt, rayed = _decide(region, o, i, j, d, lo, s, ijk, bar)
    finally:
        if bar is not None:
            bar.close()
    _say(loud, name, n, doubt, rayed, int((~out).sum()), time.perf_counter() - t0)
    return out


def _tick(bar) -> None:
    if bar is not None:
        bar.update(1)


def _decide(region, o, i, j, d, lo, s, ijk, bar):
    """Steps 1–3 of the module docstring for the segments o[i]–o[j] on the lattice (lo, s,
    ijk): (inside, how many were doubtful, how many of those were ray-tested)."""
    n = len(i)
    out = np.zeros(n, dtype=bool)
    # the site grid, one cell of margin all round (a touched cell lies within it)
    dims = tuple(int(x) for x in ijk.max(axis=0) + 3)
    solid = _solid_sites(region, lo - s, s, dims, bar)
    strides = np.array([1, dims[0], dims[0] * dims[1]], dtype=np.int64)
    flat = (ijk + 1) @ strides
    fa, fb = flat[i], flat[j]
    certain = _certain(ijk, i, j, fa, strides, solid)
    out[certain] = True
    doubt = np.flatnonzero(~certain)
    ends_solid = solid[fa[doubt]] & solid[fb[doubt]]
    # a mesh region (regions.Surface: its closed triangle surface) gets the ray test
    mesh = getattr(region, "polydata", None)
    rayed = doubt[ends_solid] if mesh is not None else doubt[:0]
    rest = np.setdiff1d(doubt, rayed, assume_unique=True)
    _tick(bar)
    if len(rayed):
        hits = _ray_hits(mesh, o[i[rayed]], o[j[rayed]], 1e-6 * float(d))
        out[rayed[~hits]] = True
        rest = np.union1d(rest, rayed[hits])        # a hit within VTK's tolerance: sample it
    _tick(bar)
    if len(rest):
        out[rest] = sampled(region, o[i[rest]], o[j[rest]], d)
    _tick(bar)
    return out, len(doubt), len(rayed)


def _certain(ijk, i, j, fa, strides, solid) -> np.ndarray:
    """Step 2: whether every cell a segment touches has a solid site (numba on both cores;
    else NumPy by offset class)."""
    n = len(i)
    if nb is not None and n >= 10_000:
        m = int(_max_offset_nb(ijk, i, j))
        w = 2 * m + 1
        ptr, offs = [0], []
        for code in range(w ** 3):
            key = (code // w ** 2 - m, code // w % w - m, code % w - m)
            cells = touched_cells(key) if max(map(abs, key)) <= 3 else None
            if cells is None:
                ptr.append(ptr[-1])
                continue
            offs.extend(int(x) for x in cells @ strides)
            ptr.append(len(offs))
        if m <= 3:
            return _certain_nb(ijk, i, j, m, w, np.array(ptr, np.int64),
                               np.array(offs, np.int64), strides, solid)
    D = ijk[j] - ijk[i]
    m = int(np.abs(D).max())
    w = 2 * m + 1
    code = ((D[:, 0] + m) * w + D[:, 1] + m) * w + D[:, 2] + m
    del D
    certain = np.ones(n, dtype=bool)
    for k in np.flatnonzero(np.bincount(code)):
        rows = np.flatnonzero(code == k)
        key = (k // w ** 2 - m, k // w % w - m, k % w - m)
        for c in touched_cells(key):
            certain[rows] &= solid[fa[rows] + int(c @ strides)]
    return certain


def _say(loud: bool, name: str, n: int, doubt: int, rayed: int, dropped: int, secs: float):
    """One line on stderr: how much the inside test did (work ≥ REPORT_AT, or asked)."""
    if loud:
        print(f"rackstress: bind inside {name}: {n:,} bindings, {doubt:,} near the boundary "
              f"tested ({rayed:,} by ray), {dropped:,} cross free space and are dropped "
              f"({secs:.1f} s)", file=sys.stderr, flush=True)
