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


from rackstress.lib.jit import cache_dir  # noqa: E402,F401 - one place (lib/jit.py)


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


def warm(part: str = "all") -> dict:
    """Compile (first time) or load (cached) every kernel on tiny inputs; return the seconds
    and the cache directory. ``part``: ``"step"`` the fused step with the bind block and the bed
    join, ``"rest"`` every other kernel, about half a first compile each (20 s): two processes
    compiling one each fill an empty cache in half the time (the test suite does so before its
    workers start)."""
    if part not in ("all", "step", "rest"):
        raise ValueError(f"unknown part '{part}' of the kernels (all, step or rest)")
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
    tag = np.arange(1, 4, dtype=np.int32)    # LAMMPS' atom ids (tagint: int32)
    flag, nt = np.zeros(3, np.bool_), np.zeros(1, np.int64)
    if part != "step":
        k.bind_pairs(x, r, s, r, s, one, one, one, True, acc)
        k.attract_pairs(x, r, s, r, one, acc)
        k.volume_pairs(x, r, s, one, np.array([0, 2], np.int64), r, one, np.ones(1), r, s,
                       np.zeros(2), np.zeros(2), acc)
        k.touching(x, r, s, np.full(2, 4.0))
        k.collide(x, r, s, np.full(2, 4.0), 3.0)
        k.collide_friction(x, np.ones((3, 3)), r, s, np.full(2, 4.0), 3.0, 0.5, 0.1)
        k.dampen(np.ones((3, 3)), r, r, 2.0, acc)
        k.candidates(x, r, s, 2.0, False, tag, 3.0)
        k.overlapping(x, r, s, np.full(2, 4.0))
        k.moved_below_shifted(x, 0, 1, 1, 2, x.copy(), 1.0)
        k.lists_moved(x, np.arange(3, dtype=np.int64), np.array([0, 3], np.int64), x.copy(),
                      np.ones(1, np.bool_), np.zeros((1, 3)), np.ones(1), np.zeros(1, np.bool_))
        k.passive_rows(tag, 1, 3, np.zeros(2, np.int64))
        k.count_from(np.zeros(2, np.int64), 1)
        k.moving_rows(x, 0, 3)
        rows3 = np.arange(3, dtype=np.int64)
        k.bbox_points(x)
        k.bbox_rows(x, rows3)
        o = x.copy()
        o.flags.writeable = False       # as Scene.original_positions() is
        lo, nc = np.full(3, -1.0), np.array([2, 2, 2], np.int64)
        start, order = k.grid_build(o, lo, np.full(3, 3.0), 2.0, nc)
        k.bbox_points(o)
        k.grid_candidates(x, r, 2.0, 3.0, lo, 2.0, nc, start, order, np.zeros(3, np.bool_), 0,
                          rows3, 0, tag, 3)
        k.collide_add(x, r, s, np.full(2, 4.0), 3.0, acc, 1, np.zeros((3, 3)), flag,
                      np.zeros(3, np.int64), nt)
        k.add_natives(np.zeros((3, 3)), np.ones((3, 3)), tag, 3, 1, np.ones((3, 3)), np.ones(9))
        k.add_sparse(np.zeros((3, 3)), np.zeros((3, 3)), flag, np.zeros(3, np.int64), nt,
                     np.ones(3), tag, 3)
        k.members(r, s, np.zeros(3, np.bool_))
        k.relist(r.copy(), s.copy(), np.ones(2), np.array([0, 1, 2], np.int64),
                 np.array([-1, 0], np.int64), np.zeros(3, np.bool_), r, s, np.ones(2),
                 np.array([0, 2], np.int64), np.zeros((2, 3), np.int64),
                 np.zeros(2), np.zeros(2), np.zeros(1, np.int64), np.ones(1, np.int64), r,
                 np.array([0, 2], np.int64), np.zeros((2, 3)), np.zeros((2, 3), np.int64),
                 np.zeros(2), np.zeros(2))
        k.within_bound(x, np.ones((3, 3)), o, np.arange(1, 4, dtype=np.int64), 4.0)
        k.within_bound(x, np.ones((3, 3)), o, tag, 4.0)      # LAMMPS' ids, as the runner has them
    if part != "rest":            # the step's half: 12 + 3.8 + 4.8 s of a cold compile's 40
        k.bind_block(x, 0, 1, 1, 2, np.ones((2, 1)), np.ones((2, 1)), np.ones((2, 1)), True, acc)
        k.bed_join(r, r, s, np.ones(2, np.bool_), s, r, s, r, s, tag, np.zeros(3, np.bool_))
        # one instruction of every kind through the fused step (the types LAMMPS' arrays have)
        ops = np.array([[OP_BLOCK, 0, 1, 1, 2, 0, 0, 0], [OP_BIND, 0, 2, 0, 0, 0, 0, 0],
                        [OP_ATTRACT, 0, 2, 0, 0, 0, 0, 0], [OP_COLLIDE, 0, 1, 0, 0, 0, 0, 1],
                        [OP_DAMPEN, 0, 3, 0, 0, 0, 0, 1], [OP_FORCE, 0, 1, 0, 0, 0, 0, 0],
                        [OP_BLOCKC, 0, 1, 1, 1, 0, 0, 0]], np.int64)
        k.step(x, np.ones((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)), np.ones(9), ops,
               np.ones((len(ops), 3)), np.zeros(1, np.int64), np.ones(2), np.ones(2), np.ones(2),
               r, s, one, one, one, np.zeros(1, np.int64), r, s, np.full(2, 4.0),
               np.array([0, 2], np.int64), np.zeros(2, np.int64), np.zeros((2, 2), np.int64),
               np.zeros((2, 4)),
               np.zeros(1, np.int64), np.zeros((2, 3), np.int64), np.zeros(2), np.zeros(2),
               np.zeros(1, np.int64), np.zeros(1, np.int64), np.array([0, 1, 2], np.int64),
               np.array([0, 3], np.int64),
               np.zeros((3, 3)), 0.5, np.zeros((3, 3)), flag, np.zeros(3, np.int64), nt,
               np.ones(3), tag, 3, np.zeros((3, 3)), np.zeros(9), 3, 1)
    seconds = time.perf_counter() - t0
    if first and os.environ.get("PMI_RANK", "0") == "0":
        print(f"rackstress: kernels compiled in {seconds:.1f} s", file=sys.stderr, flush=True)
    return {"seconds": seconds, "cache_dir": str(cache_dir()), "first_compile": first}


if nb is not None:
    _OPTS = dict(cache=True, error_model="numpy", nogil=True)
    bind_f = nb.njit(inline="always")(Bind.factor)        # Eq. 12
    col_f = nb.njit(inline="always")(Collide.factor)      # Eq. 10
    att_f = nb.njit(inline="always")(Attract.factor)      # Eq. 14

    @nb.njit(inline="always")
    def _tile_columns(xf, af, r0, k, x0, x1, x2, a0, a1, a2):
        """The positions and accumulator rows r0..r0+k of a tile of a bind block's targets as
        contiguous columns (copies: no arithmetic), so that the pass over them vectorizes
        (``xf``, ``af``: the (n, 3) arrays' rows one after another, whose stride-3 reads
        vectorize too)."""
        xt = xf[3 * r0:3 * (r0 + k)]
        at = af[3 * r0:3 * (r0 + k)]
        for u in range(k):
            x0[u] = xt[3 * u]
            x1[u] = xt[3 * u + 1]
            x2[u] = xt[3 * u + 2]
            a0[u] = at[3 * u]
            a1[u] = at[3 * u + 1]
            a2[u] = at[3 * u + 2]

    @nb.njit(inline="always")
    def _store_targets(af, r0, k, a0, a1, a2):
        """A tile's accumulator columns back into its rows (``af``: the rows one after
        another)."""
        at = af[3 * r0:3 * (r0 + k)]
        for u in range(k):
            at[3 * u] = a0[u]
            at[3 * u + 1] = a1[u]
            at[3 * u + 2] = a2[u]

    #: a bind block's targets are taken this many at a time (their columns and the reverse
    #: binds' terms of four sources stay in the first-level cache)
    _TILE = 128

    @nb.njit(inline="always")
    def _fold_tile(F, g, P0, P1, P2, k):
        """The reverse binds' sums of the four sources g..g+3 (``F``: their running sums),
        continued over the k targets of a tile in target order (``P[j]``: source g + j's
        terms). Each sum stays sequential (no reassociation); the four sources' twelve sums
        are independent chains, so that the pass is not bound by one addition's latency (rows
        of ``P`` past the last source may hold an earlier group's terms: they only reach F's
        padding rows, which are never read)."""
        f00, f01, f02 = F[g, 0], F[g, 1], F[g, 2]
        f10, f11, f12 = F[g + 1, 0], F[g + 1, 1], F[g + 1, 2]
        f20, f21, f22 = F[g + 2, 0], F[g + 2, 1], F[g + 2, 2]
        f30, f31, f32 = F[g + 3, 0], F[g + 3, 1], F[g + 3, 2]
        for u in range(k):
            f00 -= P0[0, u]
            f01 -= P1[0, u]
            f02 -= P2[0, u]
            f10 -= P0[1, u]
            f11 -= P1[1, u]
            f12 -= P2[1, u]
            f20 -= P0[2, u]
            f21 -= P1[2, u]
            f22 -= P2[2, u]
            f30 -= P0[3, u]
            f31 -= P1[3, u]
            f32 -= P2[3, u]
        F[g, 0], F[g, 1], F[g, 2] = f00, f01, f02
        F[g + 1, 0], F[g + 1, 1], F[g + 1, 2] = f10, f11, f12
        F[g + 2, 0], F[g + 2, 1], F[g + 2, 2] = f20, f21, f22
        F[g + 3, 0], F[g + 3, 1], F[g + 3, 2] = f30, f31, f32

    @nb.njit(inline="always")
    def _fold_tile3(F, g, P0, P1, P2, k):
        """:func:`_fold_tile` for three sources g..g+2 (a block of 3, 6, 9 ... sources: no
        chain on padding)."""
        f00, f01, f02 = F[g, 0], F[g, 1], F[g, 2]
        f10, f11, f12 = F[g + 1, 0], F[g + 1, 1], F[g + 1, 2]
        f20, f21, f22 = F[g + 2, 0], F[g + 2, 1], F[g + 2, 2]
        for u in range(k):
            f00 -= P0[0, u]
            f01 -= P1[0, u]
            f02 -= P2[0, u]
            f10 -= P0[1, u]
            f11 -= P1[1, u]
            f12 -= P2[1, u]
            f20 -= P0[2, u]
            f21 -= P1[2, u]
            f22 -= P2[2, u]
        F[g, 0], F[g, 1], F[g, 2] = f00, f01, f02
        F[g + 1, 0], F[g + 1, 1], F[g + 1, 2] = f10, f11, f12
        F[g + 2, 0], F[g + 2, 1], F[g + 2, 2] = f20, f21, f22

    @nb.njit(inline="always")
    def _store_sources(acc, s0, n, F):
        """Each source's reverse-bind sum added to its accumulator row once, after the block."""
        for s in range(n):
            acc[s0 + s, 0] += F[s, 0]
            acc[s0 + s, 1] += F[s, 1]
            acc[s0 + s, 2] += F[s, 2]

    @nb.njit(**_OPTS)
    def bind_block(x, t0, m, s0, n, qT, cIT, cJT, fold, acc):
        """Every (target t, source s) pair of two groups (serial rows = particles): Eq. 12 on
        t with cIT, and its reverse bind on s with cJT when ``fold``.

        The order of the sums is fixed: a target's acceleration gains its sources' terms in
        source order (s = 0, 1, ...), a source's in target order (t = 0, 1, ...) starting from
        0, each source's sum added to its accumulator row once, after the block. The targets
        are taken a tile at a time (their positions and rows copied into contiguous columns:
        no arithmetic), and within a tile the sources one after another, so that the pass over
        a tile's targets (a division each) vectorizes; the sources' sums continue tile after
        tile in target order (:func:`_fold_tile`). Neither order depends on the tiling.
        """
        T = max(1, min(_TILE, m))
        x0, x1, x2, a0, a1, a2 = (np.empty(T), np.empty(T), np.empty(T), np.empty(T),
                                  np.empty(T), np.empty(T))
        P0 = np.zeros((4, T))
        P1 = np.zeros((4, T))
        P2 = np.zeros((4, T))
        F = np.zeros((n + 3, 3))
        G = 3 if n % 4 != 0 and n % 3 == 0 else 4      # sources whose sums run together
        xf, af = x.reshape(x.size), acc.reshape(acc.size)    # views (C-contiguous only)
        for a in range(0, m, T):
            k = min(T, m - a)
            _tile_columns(xf, af, t0 + a, k, x0, x1, x2, a0, a1, a2)
            for g in range(0, n, G):
                for s in range(g, min(g + G, n)):
                    xs0, xs1, xs2 = x[s0 + s, 0], x[s0 + s, 1], x[s0 + s, 2]
                    q = qT[s, a:a + k]
                    c = cIT[s, a:a + k]
                    cj = cJT[s, a:a + k]
                    p0, p1, p2 = P0[s - g], P1[s - g], P2[s - g]
                    if fold:
                        for u in range(k):
                            d0 = xs0 - x0[u]
                            d1 = xs1 - x1[u]
                            d2_ = xs2 - x2[u]
                            w = bind_f(d0 * d0 + d1 * d1 + d2_ * d2_, q[u])
                            ct = c[u] * w
                            a0[u] += ct * d0
                            a1[u] += ct * d1
                            a2[u] += ct * d2_
                            e = cj[u] * w
                            p0[u] = e * d0
                            p1[u] = e * d1
                            p2[u] = e * d2_
                    else:
                        for u in range(k):
                            d0 = xs0 - x0[u]
                            d1 = xs1 - x1[u]
                            d2_ = xs2 - x2[u]
                            ct = c[u] * bind_f(d0 * d0 + d1 * d1 + d2_ * d2_, q[u])
                            a0[u] += ct * d0
                            a1[u] += ct * d1
                            a2[u] += ct * d2_
                if fold:
                    if G == 3:
                        _fold_tile3(F, g, P0, P1, P2, k)
                    else:
                        _fold_tile(F, g, P0, P1, P2, k)
            _store_targets(af, t0 + a, k, a0, a1, a2)
        if fold:
            _store_sources(acc, s0, n, F)

    @nb.njit(**_OPTS)
    def bind_block_const(x, t0, m, s0, n, o, cI, cJ, fold, acc):
        """:func:`bind_block` with one coefficient each way (``cI``, ``cJ``: Const binds such
        as host ↔ rack) and each pair's L0² computed from the original positions ``o`` (the
        targets' x, y, z columns, then the sources' rows: 3m + 3n values) as
        :meth:`Bind.pairs` computes it, (u_o − p_o)·(u_o − p_o) in the order x, y, z — the same
        numbers, read from 3(m + n) values instead of 3mn. Sums in :func:`bind_block`'s
        order, in its tiles."""
        T = max(1, min(_TILE, m))
        x0, x1, x2, a0, a1, a2 = (np.empty(T), np.empty(T), np.empty(T), np.empty(T),
                                  np.empty(T), np.empty(T))
        P0 = np.zeros((4, T))
        P1 = np.zeros((4, T))
        P2 = np.zeros((4, T))
        F = np.zeros((n + 3, 3))
        G = 3 if n % 4 != 0 and n % 3 == 0 else 4      # sources whose sums run together
        xf, af = x.reshape(x.size), acc.reshape(acc.size)    # views (C-contiguous only)
        for a in range(0, m, T):
            k = min(T, m - a)
            _tile_columns(xf, af, t0 + a, k, x0, x1, x2, a0, a1, a2)
            o0, o1, o2 = o[a:a + k], o[m + a:m + a + k], o[2 * m + a:2 * m + a + k]
            for g in range(0, n, G):
                for s in range(g, min(g + G, n)):
                    xs0, xs1, xs2 = x[s0 + s, 0], x[s0 + s, 1], x[s0 + s, 2]
                    os0, os1, os2 = o[3 * m + 3 * s], o[3 * m + 3 * s + 1], o[3 * m + 3 * s + 2]
                    p0, p1, p2 = P0[s - g], P1[s - g], P2[s - g]
                    if fold:
                        for u in range(k):
                            e0 = os0 - o0[u]
                            e1 = os1 - o1[u]
                            e2 = os2 - o2[u]
                            d0 = xs0 - x0[u]
                            d1 = xs1 - x1[u]
                            d2_ = xs2 - x2[u]
                            w = bind_f(d0 * d0 + d1 * d1 + d2_ * d2_,
                                       e0 * e0 + e1 * e1 + e2 * e2)
                            ct = cI * w
                            a0[u] += ct * d0
                            a1[u] += ct * d1
                            a2[u] += ct * d2_
                            e = cJ * w
                            p0[u] = e * d0
                            p1[u] = e * d1
                            p2[u] = e * d2_
                    else:
                        for u in range(k):
                            e0 = os0 - o0[u]
                            e1 = os1 - o1[u]
                            e2 = os2 - o2[u]
                            d0 = xs0 - x0[u]
                            d1 = xs1 - x1[u]
                            d2_ = xs2 - x2[u]
                            ct = cI * bind_f(d0 * d0 + d1 * d1 + d2_ * d2_,
                                             e0 * e0 + e1 * e1 + e2 * e2)
                            a0[u] += ct * d0
                            a1[u] += ct * d1
                            a2[u] += ct * d2_
                if fold:
                    if G == 3:
                        _fold_tile3(F, g, P0, P1, P2, k)
                    else:
                        _fold_tile(F, g, P0, P1, P2, k)
            _store_targets(af, t0 + a, k, a0, a1, a2)
        if fold:
            _store_sources(acc, s0, n, F)

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
    def volume_pairs(x, ri, rj, L, tptr, tidx, tval, kappa, ai, aj, e, s, acc):
        """A material's volumetric term (:class:`rackstress.model.volume.Volume`) over its
        pairs (rows ri, rj of x, rest lengths L) and terms (CSR tptr, tidx, tval: θ = C·e,
        κ per term): e = ‖d‖ − L, the pulls s = Cᵀ·(κ·θ), and each pair's s·d/‖d‖ added to
        accumulator row ai and taken from aj (−1: not here). ``e`` and ``s`` are scratch of
        one entry a pair."""
        for p in range(len(ri)):
            i, j = ri[p], rj[p]
            d0 = x[j, 0] - x[i, 0]
            d1 = x[j, 1] - x[i, 1]
            d2_ = x[j, 2] - x[i, 2]
            e[p] = np.sqrt(d0 * d0 + d1 * d1 + d2_ * d2_) - L[p]
            s[p] = 0.0
        for m in range(len(kappa)):
            th = 0.0
            for k in range(tptr[m], tptr[m + 1]):
                th += tval[k] * e[tidx[k]]
            t = kappa[m] * th
            for k in range(tptr[m], tptr[m + 1]):
                s[tidx[k]] += t * tval[k]
        for p in range(len(ri)):
            if s[p] == 0.0:
                continue
            i, j = ri[p], rj[p]
            d0 = x[j, 0] - x[i, 0]
            d1 = x[j, 1] - x[i, 1]
            d2_ = x[j, 2] - x[i, 2]
            g = s[p] / (e[p] + L[p])
            if ai[p] >= 0:
                acc[ai[p], 0] += g * d0
                acc[ai[p], 1] += g * d1
                acc[ai[p], 2] += g * d2_
            if aj[p] >= 0:
                acc[aj[p], 0] -= g * d0
                acc[aj[p], 1] -= g * d1
                acc[aj[p], 2] -= g * d2_

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
    def collide_friction(x, v, a, b, R2, c, mu, eta):
        """Eq. 10 and the pair's Coulomb friction (Collide.friction) for overlapping rows (a
        from b): the contributions, one row per pair."""
        out = np.empty((len(a), 3))
        for k in range(len(a)):
            i, j = a[k], b[k]
            d0 = x[j, 0] - x[i, 0]
            d1 = x[j, 1] - x[i, 1]
            d2_ = x[j, 2] - x[i, 2]
            dd = d0 * d0 + d1 * d1 + d2_ * d2_
            w = c * col_f(dd, R2[k])
            an = c * (R2[k] - dd) / np.sqrt(dd)
            w0 = v[i, 0] - v[j, 0]
            w1 = v[i, 1] - v[j, 1]
            w2 = v[i, 2] - v[j, 2]
            pr = (w0 * d0 + w1 * d1 + w2 * d2_) / dd
            t0 = w0 - pr * d0
            t1 = w1 - pr * d1
            t2 = w2 - pr * d2_
            s = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
            lim = mu * an
            f = lim / s if lim < eta * s else eta
            out[k, 0] = w * d0 - f * t0
            out[k, 1] = w * d1 - f * t1
            out[k, 2] = w * d2_ - f * t2
        return out

    @nb.njit(**_OPTS)
    def dampen(v, rows, arows, c, acc):
        """Eq. 9, −c·v, for owned rows into their accumulator rows."""
        for k in range(len(rows)):
            for m in range(3):
                acc[arows[k], m] += -c * v[rows[k], m]


    @nb.njit(inline="always")
    def _cell_sort(cell, ncell):
        """A stable counting sort of points by cell: the cells' starts (CSR, ncell + 1) and
        the points' indices k in cell order (within a cell, in k order)."""
        start = np.zeros(ncell + 1, np.int64)
        for k in range(len(cell)):
            start[cell[k] + 1] += 1
        for c in range(ncell):
            start[c + 1] += start[c]
        fill = start[:-1].copy()
        order = np.empty(len(cell), np.int64)
        for k in range(len(cell)):
            order[fill[cell[k]]] = k
            fill[cell[k]] += 1
        return start, order

    @nb.njit(**_OPTS)
    def candidates(x, ia, ib, cut, same, tag, wide):
        """Rows (a in ia, b in ib) closer than ``cut`` (d² ≤ cut², as
        :func:`~rackstress.model.operators.contact_candidates`), sorted by the particles
        (``tag``: the atom id of a row) of (a, b), whatever the rows' layout; and the rows of ia
        and of ib with a partner closer than ``wide`` (≥ cut), in their order there.

        Only where the two sides can meet is looked at: the rows of ``ib`` inside the bounding
        box of ``ia`` grown by ``wide`` go into a cell grid of cells about wide/2 on a side,
        and only the rows of ``ia`` inside that grid's box grown by ``wide`` look into the
        cells around them (two bodies touching at a joint search the joint only). The rows
        of ``ia`` are visited by particle, and each one's partners are put in particle order
        as found (nearly sorted already: the cells are visited with x fastest, as lattice ids
        run), so the pairs come out in the order a full sort would give them.
        ``same``: one group, both orders of every pair, never a row with itself."""
        empty = np.zeros(0, np.int64)
        na_, nb0 = len(ia), len(ib)
        if na_ == 0 or nb0 == 0:
            return empty, empty, empty, empty
        lo = np.empty(3)
        hi = np.empty(3)
        for m in range(3):
            lo[m] = np.inf
            hi[m] = -np.inf
        for k in range(na_):
            for m in range(3):
                v = x[ia[k], m]
                if v < lo[m]:
                    lo[m] = v
                if v > hi[m]:
                    hi[m] = v
        for m in range(3):
            lo[m] -= wide
            hi[m] += wide
        keep = np.empty(nb0, np.int64)          # positions in ib
        nb_ = 0
        blo = np.empty(3)
        bhi = np.empty(3)
        for m in range(3):
            blo[m] = np.inf
            bhi[m] = -np.inf
        for k in range(nb0):
            r = ib[k]
            if (x[r, 0] >= lo[0] and x[r, 0] <= hi[0] and x[r, 1] >= lo[1]
                    and x[r, 1] <= hi[1] and x[r, 2] >= lo[2] and x[r, 2] <= hi[2]):
                keep[nb_] = k
                nb_ += 1
                for m in range(3):
                    if x[r, m] < blo[m]:
                        blo[m] = x[r, m]
                    if x[r, m] > bhi[m]:
                        bhi[m] = x[r, m]
        if nb_ == 0:
            return empty, empty, empty, empty
        # the rows of ia that can have a partner: inside the kept rows' box grown by wide,
        # in particle order
        sel = np.empty(na_, np.int64)           # positions in ia
        ns = 0
        for k in range(na_):
            a = ia[k]
            if (x[a, 0] >= blo[0] - wide and x[a, 0] <= bhi[0] + wide
                    and x[a, 1] >= blo[1] - wide and x[a, 1] <= bhi[1] + wide
                    and x[a, 2] >= blo[2] - wide and x[a, 2] <= bhi[2] + wide):
                sel[ns] = k
                ns += 1
        sel = sel[:ns]
        ordered = True
        for k in range(1, ns):
            if tag[ia[sel[k]]] < tag[ia[sel[k - 1]]]:
                ordered = False
                break
        if not ordered:
            tk = np.empty(ns, np.int64)
            for k in range(ns):
                tk[k] = tag[ia[sel[k]]]
            sel = sel[np.argsort(tk, kind="mergesort")]
        # cells about wide/2 on a side (a pair within wide is at most nr cells apart in each
        # direction), at most a few per kept row
        size = 0.5 * wide if wide > 0.0 else 1.0
        nc = np.empty(3, np.int64)
        while True:
            for m in range(3):
                nc[m] = int((bhi[m] - blo[m]) / size) + 1
            if nc[0] * nc[1] * nc[2] <= 4 * nb_ + 64:
                break
            size *= 1.5
        nr = int(np.ceil(wide / size)) if wide > 0.0 else 1
        ncell = nc[0] * nc[1] * nc[2]
        cell = np.empty(nb_, np.int64)
        for k in range(nb_):                     # cell (c2 · nc1 + c1) · nc0 + c0: x fastest
            r = ib[keep[k]]
            c0 = min(int((x[r, 0] - blo[0]) / size), nc[0] - 1)
            c1 = min(int((x[r, 1] - blo[1]) / size), nc[1] - 1)
            c2 = min(int((x[r, 2] - blo[2]) / size), nc[2] - 1)
            cell[k] = (c2 * nc[1] + c1) * nc[0] + c0
        count, by_cell = _cell_sort(cell, ncell)
        order = keep[by_cell]
        cut2 = cut * cut
        wide2 = wide * wide
        near_a = np.zeros(na_, np.bool_)
        near_b = np.zeros(nb0, np.bool_)
        cap = 16 * ns + 16
        oa = np.empty(cap, np.int64)
        ob = np.empty(cap, np.int64)
        n = 0
        for q in range(ns):
            k = sel[q]
            a = ia[k]
            xa0, xa1, xa2 = x[a, 0], x[a, 1], x[a, 2]
            c0 = int(np.floor((xa0 - blo[0]) / size))
            c1 = int(np.floor((xa1 - blo[1]) / size))
            c2 = int(np.floor((xa2 - blo[2]) / size))
            first = n
            for d2 in range(max(c2 - nr, 0), min(c2 + nr + 1, nc[2])):
                for d1 in range(max(c1 - nr, 0), min(c1 + nr + 1, nc[1])):
                    for d0 in range(max(c0 - nr, 0), min(c0 + nr + 1, nc[0])):
                        c = (d2 * nc[1] + d1) * nc[0] + d0
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
                                # insertion into this row's partners, by particle
                                t = tag[b]
                                j = n
                                while j > first and tag[ob[j - 1]] > t:
                                    ob[j] = ob[j - 1]
                                    j -= 1
                                ob[j] = b
                                oa[n] = a
                                n += 1
        return oa[:n], ob[:n], ia[near_a], ib[near_b]

    @nb.njit(**_OPTS)
    def passive_rows(tag, span, nlocal, prow):
        """prow[p − span] = the row holding particle p (atom id p + 1), for the rows from
        ``span`` on; −1 for a particle not here."""
        for k in range(len(prow)):
            prow[k] = -1
        for r in range(span, nlocal):
            prow[tag[r] - 1 - span] = r

    @nb.njit(**_OPTS)
    def count_from(out, start):
        """out[k] = start + k (np.arange into a given array)."""
        for k in range(len(out)):
            out[k] = start + k

    @nb.njit(**_OPTS)
    def moving_rows(v, start, stop):
        """Rows in start..stop with a nonzero velocity."""
        out = np.empty(stop - start, np.int64)
        n = 0
        for r in range(start, stop):
            if v[r, 0] != 0.0 or v[r, 1] != 0.0 or v[r, 2] != 0.0:
                out[n] = r
                n += 1
        return out[:n]

    @nb.njit(**_OPTS)
    def bbox_rows(x, rows):
        """The bounding box (lo, hi) of x[rows]."""
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for k in range(len(rows)):
            for d in range(3):
                v = x[rows[k], d]
                if v < lo[d]:
                    lo[d] = v
                if v > hi[d]:
                    hi[d] = v
        return lo, hi

    @nb.njit(**_OPTS)
    def bbox_points(p):
        """The bounding box (lo, hi) of the points p (m, 3)."""
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for k in range(p.shape[0]):
            for d in range(3):
                v = p[k, d]
                if v < lo[d]:
                    lo[d] = v
                if v > hi[d]:
                    hi[d] = v
        return lo, hi

    @nb.njit(**_OPTS)
    def grid_build(p, lo, hi, size, nc):
        """A cell grid of the points p (m, 3) inside the box lo..hi (which stay where they
        are): cell starts (CSR) and the indices k of those points in cell order (cells of edge
        ``size`` from ``lo``, ``nc`` per axis, x slowest)."""
        m = p.shape[0]
        ncell = nc[0] * nc[1] * nc[2]
        cell = np.empty(m, np.int64)
        idx = np.empty(m, np.int64)
        n = 0
        for k in range(m):
            if not (p[k, 0] >= lo[0] and p[k, 0] <= hi[0] and p[k, 1] >= lo[1]
                    and p[k, 1] <= hi[1] and p[k, 2] >= lo[2] and p[k, 2] <= hi[2]):
                continue
            c0 = min(int((p[k, 0] - lo[0]) / size), nc[0] - 1)
            c1 = min(int((p[k, 1] - lo[1]) / size), nc[1] - 1)
            c2 = min(int((p[k, 2] - lo[2]) / size), nc[2] - 1)
            cell[n] = (c0 * nc[1] + c1) * nc[2] + c2
            idx[n] = k
            n += 1
        start, order = _cell_sort(cell[:n], ncell)
        return start, idx[order]

    @nb.njit(**_OPTS)
    def grid_candidates(x, ia, cut, wide, lo, size, nc, start, order, active, b0, prow,
                        span, tag, nlocal):
        """:func:`candidates` of rows ``ia`` against the resting particles of a group in a
        grid of :func:`grid_build` (point k: particle b0 + k, at x[prow[b0 + k − span]], where
        it has been since the start; the ``active`` ones skipped): pairs (rows) grouped by the
        searching row in the order of ``ia``, which rows of ia have a partner within ``wide``,
        the rows of the group's particles within ``wide`` (repeated), and whether a
        particle's row (``prow[p − span]``) did not hold it (atom id ``tag``)."""
        cut2 = cut * cut
        wide2 = wide * wide
        near_a = np.zeros(len(ia), np.bool_)
        cap = 16 * len(ia) + 16
        oa = np.empty(cap, np.int64)
        ob = np.empty(cap, np.int64)
        nbr = np.empty(cap, np.int64)
        n = 0
        m = 0
        lohi = np.empty((3, 2), np.int64)
        for k in range(len(ia)):
            a = ia[k]
            xa0, xa1, xa2 = x[a, 0], x[a, 1], x[a, 2]
            empty = False
            for d in range(3):
                l_ = np.floor((x[a, d] - wide - lo[d]) / size)
                h_ = np.floor((x[a, d] + wide - lo[d]) / size)
                if h_ < 0 or l_ > nc[d] - 1:
                    empty = True
                    break
                lohi[d, 0] = max(int(l_), 0)
                lohi[d, 1] = min(int(h_), nc[d] - 1)
            if empty:
                continue
            for c0 in range(lohi[0, 0], lohi[0, 1] + 1):
                for c1 in range(lohi[1, 0], lohi[1, 1] + 1):
                    for c2 in range(lohi[2, 0], lohi[2, 1] + 1):
                        c = (c0 * nc[1] + c1) * nc[2] + c2
                        for q in range(start[c], start[c + 1]):
                            j = order[q]
                            p = b0 + j
                            if active[p]:
                                continue
                            r = prow[p - span]
                            if r < 0 or r >= nlocal or tag[r] != p + 1:
                                return oa[:0], ob[:0], near_a, nbr[:0], True
                            e0 = x[r, 0] - xa0
                            e1 = x[r, 1] - xa1
                            e2 = x[r, 2] - xa2
                            e = e0 * e0 + e1 * e1 + e2 * e2
                            if e > wide2:
                                continue
                            near_a[k] = True
                            if m == len(nbr):
                                nbr2 = np.empty(2 * m, np.int64)
                                nbr2[:m] = nbr[:m]
                                nbr = nbr2
                            nbr[m] = r
                            m += 1
                            if e <= cut2:
                                if n == len(oa):
                                    oa2 = np.empty(2 * n, np.int64)
                                    ob2 = np.empty(2 * n, np.int64)
                                    oa2[:n] = oa[:n]
                                    ob2[:n] = ob[:n]
                                    oa, ob = oa2, ob2
                                oa[n] = a
                                ob[n] = r
                                n += 1
        return oa[:n], ob[:n], near_a, nbr[:m], False

    @nb.njit(**_OPTS)
    def bed_join(ia, sa, sb, snear_a, snear_b, da, db, dnear_a, dnear_b, tag, flag):
        """The resting bed's search as one search over the whole group would give it
        (:meth:`RestingBed.candidates`): the pairs from the grid of resting particles
        (``sa, sb``: grouped by searching row in the order of ``ia``, which is by particle;
        partners in cell order) and from the activated ones (``da, db``: sorted by particles),
        merged in particle order (a, then b: ``tag`` is a row's atom id); the searching rows
        with a partner (``ia[snear_a]`` and ``dnear_a``, once each, in row order); the
        resting rows within reach (``snear_b``, repeated: once each, in row order) and then
        ``dnear_b``. ``flag``: False over every row (left so)."""
        n = len(sa) + len(da)
        oa = np.empty(n, np.int64)
        ob = np.empty(n, np.int64)
        m = 0
        i = 0
        j = 0
        while i < len(sa) or j < len(da):
            # the next searching row: the smaller particle of the two heads
            if j >= len(da) or (i < len(sa) and tag[sa[i]] <= tag[da[j]]):
                a = sa[i]
            else:
                a = da[j]
            first = m
            while i < len(sa) and sa[i] == a:   # its resting partners, by particle
                b = sb[i]
                t = tag[b]
                k = m
                while k > first and tag[ob[k - 1]] > t:
                    ob[k] = ob[k - 1]
                    k -= 1
                ob[k] = b
                oa[m] = a
                m += 1
                i += 1
            mid = m
            while j < len(da) and da[j] == a:   # its activated partners (sorted): merged
                b = db[j]
                t = tag[b]
                k = m
                while k > mid and tag[ob[k - 1]] > t:
                    ob[k] = ob[k - 1]
                    k -= 1
                ob[k] = b
                oa[m] = a
                m += 1
                j += 1
            if mid > first and m > mid:         # both kinds: one insertion pass over all
                for q in range(first + 1, m):
                    b = ob[q]
                    t = tag[b]
                    k = q
                    while k > first and tag[ob[k - 1]] > t:
                        ob[k] = ob[k - 1]
                        k -= 1
                    ob[k] = b
        na = 0
        for k in range(len(ia)):
            if snear_a[k] and not flag[ia[k]]:
                flag[ia[k]] = True
                na += 1
        for k in range(len(dnear_a)):
            if not flag[dnear_a[k]]:
                flag[dnear_a[k]] = True
                na += 1
        near_a = np.empty(na, np.int64)
        q = 0
        for k in range(len(ia)):
            if snear_a[k] and flag[ia[k]]:
                flag[ia[k]] = False
                near_a[q] = ia[k]
                q += 1
        for k in range(len(dnear_a)):
            if flag[dnear_a[k]]:
                flag[dnear_a[k]] = False
                near_a[q] = dnear_a[k]
                q += 1
        near_a = np.sort(near_a)
        nb_ = 0
        rows = np.empty(len(snear_b), np.int64)
        for k in range(len(snear_b)):
            r = snear_b[k]
            if not flag[r]:
                flag[r] = True
                rows[nb_] = r
                nb_ += 1
        for k in range(nb_):
            flag[rows[k]] = False
        near_b = np.empty(nb_ + len(dnear_b), np.int64)
        near_b[:nb_] = np.sort(rows[:nb_])
        near_b[nb_:] = dnear_b
        return oa[:m], ob[:m], near_a, near_b

    @nb.njit(**_OPTS)
    def moved_below_shifted(x, a0, na, b0, nb_, ref, lim2):
        """Whether every row of the ranges a0..a0+na and b0..b0+nb_ is within √lim2 of where
        ``ref`` has it (their positions, one range after the other) *once one common
        translation t is taken off*: t is the centre of the displacements' bounding box.
        Distances between these rows change by at most twice that bound, whatever t
        (|Δ(x_b − x_a)| = |(Δx_b − t) − (Δx_a − t)|), so a contact list of two groups that
        move together (a body and its legs) is judged by their relative motion only."""
        n = na + nb_
        lo = np.empty(3)
        hi = np.empty(3)
        for m in range(3):
            lo[m] = np.inf
            hi[m] = -np.inf
        for k in range(n):
            r = a0 + k if k < na else b0 + k - na
            for m in range(3):
                d = x[r, m] - ref[k, m]
                if d < lo[m]:
                    lo[m] = d
                if d > hi[m]:
                    hi[m] = d
        if n == 0:
            return True
        t0 = 0.5 * (lo[0] + hi[0])
        t1 = 0.5 * (lo[1] + hi[1])
        t2 = 0.5 * (lo[2] + hi[2])
        for k in range(n):
            r = a0 + k if k < na else b0 + k - na
            d0 = x[r, 0] - ref[k, 0] - t0
            d1 = x[r, 1] - ref[k, 1] - t1
            d2 = x[r, 2] - ref[k, 2] - t2
            if not (d0 * d0 + d1 * d1 + d2 * d2 <= lim2):
                return False
        return True

    @nb.njit(inline="always")
    def _centre(x, rows, ref, k0, k1):
        """The centre of the bounding box of the displacements x[rows[k]] − ref[k],
        k0 ≤ k < k1: the one translation taken off when rows are judged by their motion
        relative to each other."""
        lo0 = lo1 = lo2 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        for k in range(k0, k1):
            r = rows[k]
            d0 = x[r, 0] - ref[k, 0]
            d1 = x[r, 1] - ref[k, 1]
            d2 = x[r, 2] - ref[k, 2]
            lo0 = min(lo0, d0)
            hi0 = max(hi0, d0)
            lo1 = min(lo1, d1)
            hi1 = max(hi1, d1)
            lo2 = min(lo2, d2)
            hi2 = max(hi2, d2)
        return 0.5 * (lo0 + hi0), 0.5 * (lo1 + hi1), 0.5 * (lo2 + hi2)

    @nb.njit(inline="always")
    def _farthest(x, rows, ref, k0, k1, t0, t1, t2):
        """The largest |x[rows[k]] − ref[k] − t|² over k0 ≤ k < k1 (NaN positions are left to
        the watchdog, as LAMMPS' own displacement check leaves them)."""
        worst = 0.0
        for k in range(k0, k1):
            r = rows[k]
            d0 = x[r, 0] - ref[k, 0] - t0
            d1 = x[r, 1] - ref[k, 1] - t1
            d2 = x[r, 2] - ref[k, 2] - t2
            worst = max(worst, d0 * d0 + d1 * d1 + d2 * d2)
        return worst

    @nb.njit(**_OPTS)
    def lists_moved(x, rows, roff, ref, shifted, shift, lim2, moved):
        """Which contact lists must be searched again: ``moved[L]`` is set when a row of list
        L (``rows[roff[L]:roff[L + 1]]``; their positions when it was searched: ``ref``, row
        for row) is farther than √lim2[L] from there; for a list with ``shifted[L]``, once one
        translation t common to its rows is taken off (any t bounds the change of every
        distance between them by twice the largest |Δx − t|: the one that held at the last
        step, ``shift[L]``, is tried first, one pass; then the centre of the displacements'
        bounding box, as :func:`moved_below_shifted`, kept in ``shift[L]`` when it holds)."""
        for L in range(len(roff) - 1):
            k0, k1 = roff[L], roff[L + 1]
            w = _farthest(x, rows, ref, k0, k1, shift[L, 0], shift[L, 1], shift[L, 2])
            if w <= lim2[L]:
                moved[L] = False
                continue
            moved[L] = True
            if not shifted[L]:
                continue
            t0, t1, t2 = _centre(x, rows, ref, k0, k1)
            if _farthest(x, rows, ref, k0, k1, t0, t1, t2) <= lim2[L]:
                moved[L] = False
                shift[L, 0] = t0
                shift[L, 1] = t1
                shift[L, 2] = t2

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
        ``touched[:nt[0]]``. (Written out in the loop, as in :func:`step`: a helper taking
        the arrays cost a reference count update per array and pair.)"""
        for k in range(len(a)):
            i, j = a[k], b[k]
            d0 = x[j, 0] - x[i, 0]
            d1 = x[j, 1] - x[i, 1]
            d2_ = x[j, 2] - x[i, 2]
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


if nb is not None:
    @nb.njit(**_OPTS)
    def within_bound(x, v, o, tag, bound2):
        """The watchdog's common case in one pass: every row's particle (atom id ``tag[row]``)
        within √bound2 of its original position ``o`` and its velocity finite. False sends the
        caller to the full test (:func:`~rackstress.engines.watchdog.find_divergence`), which
        names the particle."""
        for r in range(len(tag)):
            p = tag[r] - 1
            d0 = x[r, 0] - o[p, 0]
            d1 = x[r, 1] - o[p, 1]
            d2 = x[r, 2] - o[p, 2]
            if not d0 * d0 + d1 * d1 + d2 * d2 <= bound2:      # also NaN
                return False
            if not (np.isfinite(v[r, 0]) and np.isfinite(v[r, 1]) and np.isfinite(v[r, 2])):
                return False
        return True

    @nb.njit(**_OPTS)
    def members(a, b, flag):
        """The distinct rows of ``a`` and ``b`` (``flag``: False over every row; left so)."""
        out = np.empty(len(a) + len(b), np.int64)
        n = 0
        for arr in (a, b):
            for k in range(len(arr)):
                r = arr[k]
                if not flag[r]:
                    flag[r] = True
                    out[n] = r
                    n += 1
        for k in range(n):
            flag[out[k]] = False
        return out[:n]


if nb is not None:
    @nb.njit(**_OPTS)
    def relist(ca, cb, cR2, loff, kept, flag, o_ca, o_cb, o_cR2, o_loff, o_near, o_nR2,
               o_reach2, o_nnear, o_valid, o_urow, o_uoff, o_uref, near, nR2, reach2):
        """:func:`step`'s per-list state for the joined contact lists ``ca, cb, cR2`` (list L
        at ``loff[L]:loff[L+1]``; the new lists' candidates already in place) after some were
        renewed: list L is old list ``kept[L]`` (−1: a new list) whose candidates and state
        (``o_*``) it keeps, moved to its new place — its particles' rows, their reference
        positions and, if it was measured, its near candidates (their candidate indices
        shifted), their R² and the list's (R + h)² — into ``near``, ``nR2``, ``reach2``; a new
        list gets its distinct rows (as :func:`members`; ``flag``: False over every row, left
        so) and is measured in full at the next step (``valid`` 0).
        Returns (urow, uoff, uref, nnear, valid)."""
        nl = len(loff) - 1
        for L in range(nl):
            Lo = kept[L]
            if Lo >= 0:
                k0, o0 = loff[L], o_loff[Lo]
                for j in range(loff[L + 1] - k0):
                    ca[k0 + j] = o_ca[o0 + j]
                    cb[k0 + j] = o_cb[o0 + j]
                    cR2[k0 + j] = o_cR2[o0 + j]
        cap = 0
        for L in range(nl):
            Lo = kept[L]
            cap += (o_uoff[Lo + 1] - o_uoff[Lo]) if Lo >= 0 else 2 * (loff[L + 1] - loff[L])
        urow = np.empty(cap, np.int64)
        uoff = np.zeros(nl + 1, np.int64)
        n = 0
        for L in range(nl):
            Lo = kept[L]
            if Lo >= 0:
                for u in range(o_uoff[Lo], o_uoff[Lo + 1]):
                    urow[n] = o_urow[u]
                    n += 1
            else:
                n0 = n
                for arr in (ca, cb):
                    for k in range(loff[L], loff[L + 1]):
                        r = arr[k]
                        if not flag[r]:
                            flag[r] = True
                            urow[n] = r
                            n += 1
                for u in range(n0, n):
                    flag[urow[u]] = False
            uoff[L + 1] = n
        uref = np.zeros((n, 3))
        nnear = np.zeros(nl, np.int64)
        valid = np.zeros(nl, np.int64)
        for L in range(nl):
            Lo = kept[L]
            if Lo < 0 or o_valid[Lo] == 0:
                continue
            k0, o0, nn = loff[L], o_loff[Lo], o_nnear[Lo]
            for j in range(nn):
                near[k0 + j, 0] = o_near[o0 + j, 0]
                near[k0 + j, 1] = o_near[o0 + j, 1]
                near[k0 + j, 2] = o_near[o0 + j, 2] + (k0 - o0)
                nR2[k0 + j] = o_nR2[o0 + j]
            for j in range(loff[L + 1] - k0):
                reach2[k0 + j] = o_reach2[o0 + j]
            for j in range(uoff[L + 1] - uoff[L]):
                for m3 in range(3):
                    uref[uoff[L] + j, m3] = o_uref[o_uoff[Lo] + j, m3]
            nnear[L] = nn
            valid[L] = 1
        return urow[:n], uoff, uref, nnear, valid


#: Instruction kinds of :func:`step` (column 0 of its ``ops`` table).
OP_BLOCK, OP_BIND, OP_ATTRACT, OP_COLLIDE, OP_DAMPEN, OP_FORCE, OP_BLOCKC = range(7)

if nb is not None:
    @nb.njit(inline="always")
    def _natives(f, v, tag, r0, r1, ident, F, g3):
        """:func:`add_natives` on rows r0..r1 − 1 (``g3``: γ per particle, three times), on
        the arrays' rows one after another: the rows below ``ident`` (their own particles)
        in one pass that vectorizes."""
        fa, va, Fa = f.reshape(f.size), v.reshape(v.size), F.reshape(F.size)
        for i in range(3 * r0, 3 * max(r0, min(r1, ident))):
            fa[i] = (fa[i] + Fa[i]) - g3[i] * va[i]
        for r in range(max(r0, ident), r1):
            p = tag[r] - 1
            for k in range(3):
                f[r, k] = (f[r, k] + F[p, k]) - g3[3 * p + k] * v[r, k]

    @nb.njit(**_OPTS)
    def add_natives(f, v, tag, n, ident, F, g3):
        """Eqs. 8 and 9 as LAMMPS' fix addforce and fix viscous compute them, on rows below
        ``n``: f = (f + F) − γ·v with F, γ of the row's particle (the row itself below
        ``ident``, else atom id ``tag[row]`` − 1; ``g3``: γ per particle, three times), the
        term-by-term path's call of what :func:`step` does inline."""
        _natives(f, v, tag, 0, n, ident, F, g3)

    @nb.njit(inline="always")
    def _within(x, urow, uref, u0, u1, lim2):
        """Whether the rows urow[u0:u1] are each within √lim2 of ``uref`` — as they are, or
        once one common translation t (the centre of their displacements' bounding box) is
        taken off: either bounds the change of every distance between them by 2√lim2 (as
        :func:`moved_below_shifted` argues), so a list of two groups that move together is
        judged by their relative motion only. NaN is not within."""
        inside = True
        for u in range(u0, u1):
            r = urow[u]
            e0 = x[r, 0] - uref[u, 0]
            e1 = x[r, 1] - uref[u, 1]
            e2 = x[r, 2] - uref[u, 2]
            if not e0 * e0 + e1 * e1 + e2 * e2 <= lim2:
                inside = False
                break
        if inside:
            return True
        t0, t1, t2 = _centre(x, urow, uref, u0, u1)
        for u in range(u0, u1):
            r = urow[u]
            e0 = x[r, 0] - uref[u, 0] - t0
            e1 = x[r, 1] - uref[u, 1] - t1
            e2 = x[r, 2] - uref[u, 2] - t2
            if not e0 * e0 + e1 * e1 + e2 * e2 <= lim2:
                return False
        return True

    @nb.njit(**_OPTS)
    def step(x, v, f, acc, dmass3, ops, fpar, conds, bq, bcI, bcJ, pi, pj, pcI, pcJ, pq, frows,
             ca, cb, cR2, loff, ov, ovr, ovd, ovn, near, nR2, reach2, nnear, valid, urow, uoff,
             uref, h, sacc, sflag, stouched, snt, mass, tag, nfirst, natF, natg3, nnat, ident):
        """One callback step of the serial path (rows of the dense groups = particles): every
        active term of the phase, in the terms' order, then, on each row of LAMMPS' ``f``,
        the deck's constant forces and damping as :func:`add_natives` adds them (rows below
        ``nnat``, ``natF`` per particle, ``natg3`` its γ three times; none if 0) followed by
        the terms' a·m (``dmass3``: the dense rows' masses, three times).

        ``ops`` (one row a term, in the order of the callback's terms): kind (``OP_*``; a
        Const bind block is ``OP_BLOCKC``: its L0² from the original positions in ``bq``),
        five integer arguments, and the range ``conds[cs:ce]`` of contact lists that must
        overlap (⟨contact⟩ of Eq. 4) for the term to act; ``fpar``: its floats (c, or a
        force's vector). The contact lists are candidate pairs ``ca, cb, cR2`` (list L is
        ``loff[L]:loff[L+1]``, sorted by particles); their overlapping pairs (Eq. 10's
        support, d² < R²) are found once here, into ``ov``/``ovn`` (their rows in ``ovr``),
        and serve every collide (both directions) and every contact condition of the step:
        with each one its difference d = x_b − x_a and Eq. 10's factor min(0, 1 − R²/d²)
        (``ovd``), which a collide of either direction scales by its c (the reverse
        direction's difference is −d and its d² the same, exactly: IEEE subtraction is
        antisymmetric), so a pair's Eq. 10 is evaluated once a step, not once per direction.
        Only a list's *near* candidates are measured (rows ``near[loff[L]:loff[L] +
        nnear[L]]``: their two rows and candidate index, their R² in ``nR2``, in list order:
        those closer than R + ``h`` when the list's particles, ``urow[uoff[L]:uoff[L+1]]``,
        were at ``uref``); while none of them has moved h/2 since — as they are or relative
        to one common translation (:func:`_within`) — no other candidate can overlap (its
        gap, ≥ h then, has closed by less than h), and once one has — or the list is new
        (``valid[L] = 0``; then each candidate's (R + h)² is kept in ``reach2``) — every
        candidate is measured and the near ones chosen again. The overlapping pairs, and
        their order, are those of a pass over every candidate.

        Each term adds exactly what its own kernel adds (:func:`bind_block` or
        :func:`bind_block_const`, :func:`bind_pairs`, :func:`attract_pairs`,
        :func:`collide_add`, :func:`dampen`, a force's vector), in the same order, so the
        sums are those of the term-by-term path. Then f += acc·m on the dense rows, in the
        pass that adds the natives and clears ``acc`` (zero on entry, zero on return), and
        the sparse rows as :func:`add_sparse`.

        Returns (:func:`add_sparse`'s first row at or after ``nfirst``, or −1; L; k): L ≥ 0
        names a list whose candidate k coincides (d = 0, Eq. 10 undefined); then only the
        natives are added.
        """
        nacc = acc.shape[0]
        nl = len(loff) - 1
        # each particle may move h/2 less a margin far above rounding (1e-6 relative)
        lim2 = (0.5 * h * (1.0 - 1e-6)) ** 2
        for L in range(nl):
            base = loff[L]
            ok = valid[L] != 0
            if ok:
                ok = _within(x, urow, uref, uoff[L], uoff[L + 1], lim2)
            if not ok:      # measure every candidate, keep the near ones and where they are
                if valid[L] == 0:       # a new list: each candidate's (R + h)², once
                    for k in range(loff[L], loff[L + 1]):
                        reach = np.sqrt(cR2[k]) + h
                        reach2[k] = reach * reach
                nn = 0
                for k in range(loff[L], loff[L + 1]):
                    a, b = ca[k], cb[k]
                    d0 = x[b, 0] - x[a, 0]
                    d1 = x[b, 1] - x[a, 1]
                    d2_ = x[b, 2] - x[a, 2]
                    if d0 * d0 + d1 * d1 + d2_ * d2_ < reach2[k]:
                        near[base + nn, 0] = a
                        near[base + nn, 1] = b
                        near[base + nn, 2] = k
                        nR2[base + nn] = cR2[k]
                        nn += 1
                nnear[L] = nn
                for u in range(uoff[L], uoff[L + 1]):
                    r = urow[u]
                    uref[u, 0] = x[r, 0]
                    uref[u, 1] = x[r, 1]
                    uref[u, 2] = x[r, 2]
                valid[L] = 1
            cnt = 0
            for p in range(base, base + nnear[L]):
                a, b = near[p, 0], near[p, 1]
                d0 = x[b, 0] - x[a, 0]
                d1 = x[b, 1] - x[a, 1]
                d2_ = x[b, 2] - x[a, 2]
                d2 = d0 * d0 + d1 * d1 + d2_ * d2_
                if d2 < nR2[p]:
                    if d2 == 0.0:
                        valid[L] = 0
                        _natives(f, v, tag, 0, nnat, ident, natF, natg3)
                        return -1, L, near[p, 2]
                    q = base + cnt
                    ov[q] = near[p, 2]
                    ovr[q, 0] = a
                    ovr[q, 1] = b
                    ovd[q, 0] = d0
                    ovd[q, 1] = d1
                    ovd[q, 2] = d2_
                    ovd[q, 3] = col_f(d2, nR2[p])
                    cnt += 1
            ovn[L] = cnt
        for o in range(ops.shape[0]):
            held = True
            for c in range(ops[o, 6], ops[o, 7]):
                if ovn[conds[c]] == 0:
                    held = False
                    break
            if not held:
                continue
            kind = ops[o, 0]
            if kind == OP_BLOCK:
                t0, m, s0, n, off = ops[o, 1], ops[o, 2], ops[o, 3], ops[o, 4], ops[o, 5]
                e = off + n * m
                bind_block(x, t0, m, s0, n, bq[off:e].reshape((n, m)),
                           bcI[off:e].reshape((n, m)), bcJ[off:e].reshape((n, m)),
                           fpar[o, 0] != 0.0, acc)
            elif kind == OP_BLOCKC:
                t0, m, s0, n, off = ops[o, 1], ops[o, 2], ops[o, 3], ops[o, 4], ops[o, 5]
                bind_block_const(x, t0, m, s0, n, bq[off:off + 3 * (m + n)], fpar[o, 1],
                                 fpar[o, 2], fpar[o, 0] != 0.0, acc)
            elif kind == OP_BIND:
                k0, k1 = ops[o, 1], ops[o, 2]
                bind_pairs(x, pi[k0:k1], pj[k0:k1], pi[k0:k1], pj[k0:k1], pcI[k0:k1],
                           pcJ[k0:k1], pq[k0:k1], fpar[o, 0] != 0.0, acc)
            elif kind == OP_ATTRACT:
                k0, k1 = ops[o, 1], ops[o, 2]
                attract_pairs(x, pi[k0:k1], pj[k0:k1], pi[k0:k1], pcI[k0:k1], acc)
            elif kind == OP_COLLIDE:
                L, rev = ops[o, 1], ops[o, 2]
                c = fpar[o, 0]
                for p in range(loff[L], loff[L] + ovn[L]):
                    # Eq. 10 on i from its partner, as collide_add computes it: w·(x_s − x_i)
                    w = c * ovd[p, 3]
                    if rev == 0:
                        i = ovr[p, 0]
                        d0, d1, d2_ = ovd[p, 0], ovd[p, 1], ovd[p, 2]
                    else:
                        i = ovr[p, 1]
                        d0, d1, d2_ = -ovd[p, 0], -ovd[p, 1], -ovd[p, 2]
                    if i < nacc:
                        acc[i, 0] += w * d0
                        acc[i, 1] += w * d1
                        acc[i, 2] += w * d2_
                    else:
                        if not sflag[i]:
                            sflag[i] = True
                            stouched[snt[0]] = i
                            snt[0] += 1
                        sacc[i, 0] += w * d0
                        sacc[i, 1] += w * d1
                        sacc[i, 2] += w * d2_
            elif kind == OP_DAMPEN:
                c = fpar[o, 0]
                for r in range(ops[o, 1], ops[o, 2]):
                    for m3 in range(3):
                        acc[r, m3] += -c * v[r, m3]
            elif kind == OP_FORCE:
                for k in range(ops[o, 1], ops[o, 2]):
                    r = frows[k]
                    acc[r, 0] = acc[r, 0] + fpar[o, 0]
                    acc[r, 1] = acc[r, 1] + fpar[o, 1]
                    acc[r, 2] = acc[r, 2] + fpar[o, 2]
        # f = ((f + F) − γ·v) + acc·m on the dense rows, one pass (acc left zero for the next
        # step), then the natives alone on the other rows, then the sparse rows' acc·m
        # (on the arrays' rows one after another: the passes over rows that are their own
        # particles vectorize; dmass3, natg3: a row's mass and γ three times)
        fa, aa, va = f.reshape(f.size), acc.reshape(acc.size), v.reshape(v.size)
        Fa = natF.reshape(natF.size)
        n1 = min(nnat, nacc)
        i1 = 3 * min(n1, ident)
        for i in range(i1):
            fa[i] = ((fa[i] + Fa[i]) - natg3[i] * va[i]) + aa[i] * dmass3[i]
            aa[i] = 0.0
        for r in range(min(n1, ident), n1):
            p = tag[r] - 1
            for m3 in range(3):
                i, j = 3 * r + m3, 3 * p + m3
                fa[i] = ((fa[i] + Fa[j]) - natg3[j] * va[i]) + aa[i] * dmass3[i]
                aa[i] = 0.0
        for i in range(3 * n1, 3 * nacc):
            fa[i] += aa[i] * dmass3[i]
            aa[i] = 0.0
        _natives(f, v, tag, nacc, nnat, ident, natF, natg3)
        return add_sparse(f, sacc, sflag, stouched, snt, mass, tag, nfirst), -1, -1
