"""Compiled (numba) loops over pairs, each calling its operator's own formula.

The formulas stay where they are, once: ``Bind.factor`` (Eq. 12), ``Collide.factor`` (Eq. 10)
and ``Attract.factor`` (Eq. 14) in :mod:`rackstress.model.operators`. Here they are compiled
(``numba.njit``, inlined) into loops that gather the two particles of a pair, apply the formula
and add the result straight into the accelerations — what the NumPy path of the LAMMPS callback
does with a dozen temporary arrays a term. The NumPy path stays the reference implementation;
``kernels='numpy'`` (or ``RACKSTRESS_KERNELS=numpy``) selects it, and the tests hold the two
equal.

Compiled code is cached on disk (``cache=True``) in ``NUMBA_CACHE_DIR``, which this module sets
to a user-writable place (``$XDG_CACHE_HOME/rackstress/numba``, else
``~/.cache/rackstress/numba``) unless it is set already: the first run compiles (10–20 s), later
ones load (about a second). :func:`warm` compiles or loads everything once and says how long it
took, so that no benchmark counts it inside a figure.

Kernels use ``error_model="numpy"`` (a division by zero gives inf, as in NumPy, and the loops
vectorize); a coincident pair is caught before it gets here.
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

from rackstress.model.operators import Attract, Bind, Collide

KERNEL_CHOICES = ("numba", "numpy")


def cache_dir() -> Path:
    """Where compiled kernels are kept (``NUMBA_CACHE_DIR`` if set)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rackstress" / "numba"


def available() -> bool:
    """Whether numba can be imported here."""
    return nb is not None


def choice(requested: str | None = None) -> str:
    """The kernels to use: ``requested``, else ``RACKSTRESS_KERNELS``, else numba if present."""
    want = requested or os.environ.get("RACKSTRESS_KERNELS") or ("numba" if available()
                                                                  else "numpy")
    if want not in KERNEL_CHOICES:
        raise ValueError(f"unknown kernels '{want}' (choose {' or '.join(KERNEL_CHOICES)})")
    if want == "numba" and not available():
        raise ValueError("kernels 'numba' asked for, but numba is not installed")
    return want



try:
    import numba as nb
except ImportError:    # the NumPy path needs nothing more
    nb = None
else:
    if not os.environ.get("NUMBA_CACHE_DIR"):
        nb.config.CACHE_DIR = str(cache_dir())


def compiled():
    """This module's compiled kernels (raise if numba is missing)."""
    if nb is None:
        raise ValueError("kernels 'numba' asked for, but numba is not installed")
    try:
        cache_dir().mkdir(parents=True, exist_ok=True)
    except OSError:     # an unwritable home (a batch node): compile into the temporary directory
        import tempfile

        os.environ["NUMBA_CACHE_DIR"] = str(Path(tempfile.gettempdir())
                                            / f"rackstress-numba-{os.getuid()}")
        nb.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
        cache_dir().mkdir(parents=True, exist_ok=True)
    return sys.modules[__name__]


def warm() -> dict:
    """Compile (first time) or load (cached) every kernel on tiny inputs; return the seconds
    and the cache directory."""
    t0 = time.perf_counter()
    k = compiled()
    first = not any(cache_dir().rglob("kernels.*.nbi"))
    if first and os.environ.get("PMI_RANK", "0") == "0":
        print(f"rackstress: compiling the callback's kernels (first run only; cached in "
              f"{cache_dir()}) ...", file=sys.stderr, flush=True)
    x = np.array([[0.0, 0.0, 0.0], [1.5, 0.0, 0.0], [0.0, 1.0, 0.0]])
    acc = np.zeros((3, 3))
    r = np.array([0, 1], np.int64)
    s = np.array([1, 2], np.int64)
    one = np.ones(2)
    k.bind_block(x, 0, 1, 1, 2, np.ones((2, 1)), np.ones((2, 1)), np.ones((2, 1)), True, acc)
    k.bind_pairs(x, r, s, r, s, one, one, one, True, acc)
    k.attract_pairs(x, r, s, r, one, acc)
    k.touching(x, r, s, np.full(2, 4.0))
    k.collide(x, r, s, np.full(2, 4.0), 3.0)
    k.dampen(np.ones((3, 3)), r, r, 2.0, acc)
    tag = np.arange(1, 4, dtype=np.int32)    # LAMMPS' atom ids (tagint: int32)
    k.candidates(x, r, s, 2.0, False, tag, 3.0)
    k.overlapping(x, r, s, np.full(2, 4.0))
    k.moved_below(x, 0, 1, 1, 2, x.copy(), 1.0)
    flag, nt = np.zeros(3, np.bool_), np.zeros(1, np.int64)
    k.collide_add(x, r, s, np.full(2, 4.0), 3.0, acc, 1, np.zeros((3, 3)), flag,
                  np.zeros(3, np.int64), nt)
    k.add_natives(np.zeros((3, 3)), np.ones((3, 3)), tag, 3, 1, np.ones((3, 3)), np.ones(3))
    k.add_sparse(np.zeros((3, 3)), np.zeros((3, 3)), flag, np.zeros(3, np.int64), nt,
                 np.ones(3), tag, 3)
    seconds = time.perf_counter() - t0
    if first and os.environ.get("PMI_RANK", "0") == "0":
        print(f"rackstress: kernels compiled in {seconds:.1f} s", file=sys.stderr, flush=True)
    return {"seconds": seconds, "cache_dir": str(cache_dir()), "first_compile": first}


if nb is not None:
    _OPTS = dict(cache=True, error_model="numpy", nogil=True)
    bind_f = nb.njit(inline="always")(Bind.factor)        # Eq. 12
    col_f = nb.njit(inline="always")(Collide.factor)      # Eq. 10
    att_f = nb.njit(inline="always")(Attract.factor)      # Eq. 14

    @nb.njit(**_OPTS)
    def bind_block(x, t0, m, s0, n, qT, cIT, cJT, fold, acc):
        """Every (target t, source s) pair of two groups (serial rows = particles): Eq. 12 on
        t with cIT, and its reverse bind on s with cJT when ``fold``."""
        for s in range(n):
            xs0, xs1, xs2 = x[s0 + s, 0], x[s0 + s, 1], x[s0 + s, 2]
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for t in range(m):
                d0 = xs0 - x[t0 + t, 0]
                d1 = xs1 - x[t0 + t, 1]
                d2_ = xs2 - x[t0 + t, 2]
                w = bind_f(d0 * d0 + d1 * d1 + d2_ * d2_, qT[s, t])
                c = cIT[s, t] * w
                acc[t0 + t, 0] += c * d0
                acc[t0 + t, 1] += c * d1
                acc[t0 + t, 2] += c * d2_
                if fold:
                    cj = cJT[s, t] * w
                    a0 -= cj * d0
                    a1 -= cj * d1
                    a2 -= cj * d2_
            if fold:
                acc[s0 + s, 0] += a0
                acc[s0 + s, 1] += a1
                acc[s0 + s, 2] += a2

    @nb.njit(**_OPTS)
    def bind_pairs(x, ri, rj, ai, aj, cI, cJ, q, fold, acc):
        """Eq. 12 over a pair list: rows ri, rj of x; accumulator rows ai, aj (−1: not here)."""
        for k in range(len(ri)):
            i, j = ri[k], rj[k]
            d0 = x[j, 0] - x[i, 0]
            d1 = x[j, 1] - x[i, 1]
            d2_ = x[j, 2] - x[i, 2]
            w = bind_f(d0 * d0 + d1 * d1 + d2_ * d2_, q[k])
            if ai[k] >= 0:
                c = cI[k] * w
                acc[ai[k], 0] += c * d0
                acc[ai[k], 1] += c * d1
                acc[ai[k], 2] += c * d2_
            if fold and aj[k] >= 0:
                c = cJ[k] * w
                acc[aj[k], 0] -= c * d0
                acc[aj[k], 1] -= c * d1
                acc[aj[k], 2] -= c * d2_

    @nb.njit(**_OPTS)
    def attract_pairs(x, ri, rj, ai, cI, acc):
        """Eq. 14 over a pair list (one-way)."""
        for k in range(len(ri)):
            if ai[k] < 0:
                continue
            i, j = ri[k], rj[k]
            d0 = x[j, 0] - x[i, 0]
            d1 = x[j, 1] - x[i, 1]
            d2_ = x[j, 2] - x[i, 2]
            c = cI[k] * att_f(d0 * d0 + d1 * d1 + d2_ * d2_)
            acc[ai[k], 0] += c * d0
            acc[ai[k], 1] += c * d1
            acc[ai[k], 2] += c * d2_

    @nb.njit(**_OPTS)
    def touching(x, a, b, R2):
        """Eq. 10's support over candidate rows: which pairs overlap (d² < R²), and d²."""
        n = len(a)
        on = np.zeros(n, np.bool_)
        d2 = np.empty(n)
        for k in range(n):
            d0 = x[b[k], 0] - x[a[k], 0]
            d1 = x[b[k], 1] - x[a[k], 1]
            d2_ = x[b[k], 2] - x[a[k], 2]
            d2[k] = d0 * d0 + d1 * d1 + d2_ * d2_
            on[k] = d2[k] < R2[k]
        return on, d2

    @nb.njit(**_OPTS)
    def collide(x, a, b, R2, c):
        """Eq. 10 for overlapping rows (a from b): the contributions, one row per pair."""
        out = np.empty((len(a), 3))
        for k in range(len(a)):
            d0 = x[b[k], 0] - x[a[k], 0]
            d1 = x[b[k], 1] - x[a[k], 1]
            d2_ = x[b[k], 2] - x[a[k], 2]
            w = c * col_f(d0 * d0 + d1 * d1 + d2_ * d2_, R2[k])
            out[k, 0] = w * d0
            out[k, 1] = w * d1
            out[k, 2] = w * d2_
        return out

    @nb.njit(**_OPTS)
    def dampen(v, rows, arows, c, acc):
        """Eq. 9, −c·v, for owned rows into their accumulator rows."""
        for k in range(len(rows)):
            for m in range(3):
                acc[arows[k], m] += -c * v[rows[k], m]


    @nb.njit(**_OPTS)
    def candidates(x, ia, ib, cut, same, tag, wide):
        """Rows (a in ia, b in ib) closer than ``cut`` (d² ≤ cut², as
        :func:`~rackstress.model.operators.contact_candidates`), sorted by the particles
        (``tag``: the atom id of a row) of (a, b), whatever the rows' layout; and the rows of ia
        and of ib with a partner closer than ``wide`` (≥ cut). The cell list holds the larger
        side."""
        if len(ia) > len(ib):
            ob, oa, near_b, near_a = _cells(x, ib, ia, cut, same, wide)
        else:
            oa, ob, near_a, near_b = _cells(x, ia, ib, cut, same, wide)
        # one order whatever the rows' layout: by the particles of (a, b)
        n = len(oa)
        key = np.empty(n, np.int64)
        span = 0
        for k in range(n):
            if tag[ob[k]] >= span:
                span = np.int64(tag[ob[k]]) + 1
        for k in range(n):
            key[k] = np.int64(tag[oa[k]]) * span + tag[ob[k]]
        s = np.argsort(key)
        return oa[s], ob[s], near_a, near_b

    @nb.njit(**_OPTS)
    def _cells(x, ia, ib, cut, same, wide):
        """:func:`candidates`, unsorted: a cell list over the part of ``ib`` inside the bounding
        box of ``ia`` grown by ``wide``, each row of ``ia`` looking in the 27 cells around it.
        ``same``: one group, both orders of every pair, never a row with itself."""
        empty = np.zeros(0, np.int64)
        if len(ia) == 0 or len(ib) == 0:
            return empty, empty, empty, empty
        lo = np.empty(3)
        hi = np.empty(3)
        for m in range(3):
            lo[m] = np.inf
            hi[m] = -np.inf
        for k in range(len(ia)):
            for m in range(3):
                v = x[ia[k], m]
                if v < lo[m]:
                    lo[m] = v
                if v > hi[m]:
                    hi[m] = v
        for m in range(3):
            lo[m] -= wide
            hi[m] += wide
        keep = np.empty(len(ib), np.int64)      # positions in ib
        nb_ = 0
        for k in range(len(ib)):
            r = ib[k]
            if (x[r, 0] >= lo[0] and x[r, 0] <= hi[0] and x[r, 1] >= lo[1]
                    and x[r, 1] <= hi[1] and x[r, 2] >= lo[2] and x[r, 2] <= hi[2]):
                keep[nb_] = k
                nb_ += 1
        if nb_ == 0:
            return empty, empty, empty, empty
        # cells no smaller than wide (a pair within it is in neighbouring cells), at most a
        # few per kept row
        size = wide if wide > 0.0 else 1.0
        nc = np.empty(3, np.int64)
        while True:
            for m in range(3):
                nc[m] = int((hi[m] - lo[m]) / size) + 1
            if nc[0] * nc[1] * nc[2] <= 4 * nb_ + 64:
                break
            size *= 1.5
        ncell = nc[0] * nc[1] * nc[2]
        cell = np.empty(nb_, np.int64)
        count = np.zeros(ncell + 1, np.int64)
        for k in range(nb_):
            r = ib[keep[k]]
            c0 = min(int((x[r, 0] - lo[0]) / size), nc[0] - 1)
            c1 = min(int((x[r, 1] - lo[1]) / size), nc[1] - 1)
            c2 = min(int((x[r, 2] - lo[2]) / size), nc[2] - 1)
            cell[k] = (c0 * nc[1] + c1) * nc[2] + c2
            count[cell[k] + 1] += 1
        for c in range(ncell):
            count[c + 1] += count[c]
        fill = count[:-1].copy()
        order = np.empty(nb_, np.int64)
        for k in range(nb_):
            order[fill[cell[k]]] = keep[k]
            fill[cell[k]] += 1
        cut2 = cut * cut
        wide2 = wide * wide
        near_a = np.zeros(len(ia), np.bool_)
        near_b = np.zeros(len(ib), np.bool_)
        cap = 16 * len(ia) + 16
        oa = np.empty(cap, np.int64)
        ob = np.empty(cap, np.int64)
        n = 0
        for k in range(len(ia)):
            a = ia[k]
            xa0, xa1, xa2 = x[a, 0], x[a, 1], x[a, 2]
            if (xa0 < lo[0] - wide or xa0 > hi[0] + wide or xa1 < lo[1] - wide
                    or xa1 > hi[1] + wide or xa2 < lo[2] - wide or xa2 > hi[2] + wide):
                continue
            c0 = int((xa0 - lo[0]) / size)
            c1 = int((xa1 - lo[1]) / size)
            c2 = int((xa2 - lo[2]) / size)
            for d0 in range(max(c0 - 1, 0), min(c0 + 2, nc[0])):
                for d1 in range(max(c1 - 1, 0), min(c1 + 2, nc[1])):
                    for d2 in range(max(c2 - 1, 0), min(c2 + 2, nc[2])):
                        c = (d0 * nc[1] + d1) * nc[2] + d2
                        for p in range(count[c], count[c + 1]):
                            pb = order[p]
                            b = ib[pb]
                            if same and b == a:
                                continue
                            e0 = x[b, 0] - xa0
                            e1 = x[b, 1] - xa1
                            e2 = x[b, 2] - xa2
                            e = e0 * e0 + e1 * e1 + e2 * e2
                            if e <= wide2:
                                near_a[k] = True
                                near_b[pb] = True
                            if e <= cut2:
                                if n == cap:
                                    cap *= 2
                                    oa2 = np.empty(cap, np.int64)
                                    ob2 = np.empty(cap, np.int64)
                                    oa2[:n] = oa[:n]
                                    ob2[:n] = ob[:n]
                                    oa, ob = oa2, ob2
                                oa[n] = a
                                ob[n] = b
                                n += 1
        return oa[:n], ob[:n], ia[near_a], ib[near_b]

    @nb.njit(**_OPTS)
    def moved_below(x, a0, na, b0, nb_, ref, lim2):
        """Whether every row of the ranges a0..a0+na and b0..b0+nb_ (``ref``: their positions,
        one range after the other) is within √lim2 of where ``ref`` has it."""
        for k in range(na + nb_):
            r = a0 + k if k < na else b0 + k - na
            d0 = x[r, 0] - ref[k, 0]
            d1 = x[r, 1] - ref[k, 1]
            d2 = x[r, 2] - ref[k, 2]
            if d0 * d0 + d1 * d1 + d2 * d2 > lim2:
                return False
        return True

    @nb.njit(**_OPTS)
    def overlapping(x, a, b, R2):
        """Eq. 10's support over candidate rows: the overlapping pairs (d² < R²) and their R²;
        ``bad``: the first coincident pair (d = 0), or −1."""
        n = len(a)
        keep = np.empty(n, np.int64)
        m = 0
        bad = -1
        for k in range(n):
            d0 = x[b[k], 0] - x[a[k], 0]
            d1 = x[b[k], 1] - x[a[k], 1]
            d2_ = x[b[k], 2] - x[a[k], 2]
            d2 = d0 * d0 + d1 * d1 + d2_ * d2_
            if d2 < R2[k]:
                if d2 == 0.0 and bad < 0:
                    bad = m
                keep[m] = k
                m += 1
        keep = keep[:m]
        return a[keep], b[keep], R2[keep], bad

    @nb.njit(**_OPTS)
    def collide_add(x, a, b, R2, c, acc, nacc, sacc, flag, touched, nt):
        """Eq. 10 for overlapping rows (a from b) added in place: rows below ``nacc`` into
        ``acc``, the others into ``sacc`` (same rows), listed once (``flag``) in
        ``touched[:nt[0]]``."""
        for k in range(len(a)):
            i = a[k]
            d0 = x[b[k], 0] - x[i, 0]
            d1 = x[b[k], 1] - x[i, 1]
            d2_ = x[b[k], 2] - x[i, 2]
            w = c * col_f(d0 * d0 + d1 * d1 + d2_ * d2_, R2[k])
            if i < nacc:
                acc[i, 0] += w * d0
                acc[i, 1] += w * d1
                acc[i, 2] += w * d2_
            else:
                if not flag[i]:
                    flag[i] = True
                    touched[nt[0]] = i
                    nt[0] += 1
                sacc[i, 0] += w * d0
                sacc[i, 1] += w * d1
                sacc[i, 2] += w * d2_

    @nb.njit(**_OPTS)
    def add_natives(f, v, tag, n, ident, F, g):
        """Eqs. 8 and 9 as LAMMPS' fix addforce and fix viscous compute them, on rows below
        ``n``: f = (f + F) − γ·v with F, γ of the row's particle (the row itself below
        ``ident``, else atom id ``tag[row]`` − 1)."""
        for r in range(n):
            p = r if r < ident else tag[r] - 1
            for k in range(3):
                f[r, k] = (f[r, k] + F[p, k]) - g[p] * v[r, k]

    @nb.njit(**_OPTS)
    def add_sparse(f, sacc, flag, touched, nt, mass, tag, nfirst):
        """f rows outside the dense accumulator += sacc·m (``mass`` of the particle with atom
        id ``tag[row]``; then sacc cleared), for the rows this step touched; returns the first
        of them at or after ``nfirst`` (a row LAMMPS does not integrate yet), or −1."""
        late = -1
        for k in range(nt[0]):
            r = touched[k]
            m = mass[tag[r] - 1]
            f[r, 0] += sacc[r, 0] * m
            f[r, 1] += sacc[r, 1] * m
            f[r, 2] += sacc[r, 2] * m
            sacc[r, 0] = 0.0
            sacc[r, 1] = 0.0
            sacc[r, 2] = 0.0
            flag[r] = False
            if r >= nfirst and late < 0:
                late = r
        nt[0] = 0
        return late
