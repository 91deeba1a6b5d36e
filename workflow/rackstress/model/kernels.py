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

