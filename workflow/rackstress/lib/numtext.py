"""Numbers from text, compiled: a dump frame's atom lines as float64, bit for bit what
``np.fromstring(text, sep=" ")`` gives, in a fraction of its time.

A LAMMPS dump frame is whitespace-separated decimal numbers (``1 1 1 -18.2305 17 -1.5e-05``).
Each token's digits make an exact integer m (at most 17 significant digits, m ≤ 2**53) and its decimals
and exponent one power of ten p (|p| ≤ 22, exact as a double); its value is m · 10**p or
m / 10**-p in one IEEE operation on exact operands: the correctly rounded double, which is
strtod's, and so NumPy's (Clinger's fast path). A text with any other token — more digits,
a larger exponent, nan, a stray character — is left to NumPy (:func:`numbers` returns None).

The loop is compiled with numba and cached on disk (lib/jit.py) by :func:`warm`, which
:func:`rackstress.stress.kernels.warm` calls (``rackstress run``'s head start, the first run's
compile apart); :func:`numbers` uses it only once it is loaded in this process, so no reader
ever waits for a compile. Importing this module imports no numba: a reader in a process that
has not loaded it does not load it for this.
"""
from __future__ import annotations

import numpy as np

#: 10**q exactly, q = 0..22 (each one a double)
_POW10 = np.array([float(10 ** q) for q in range(23)])
#: :func:`_numbers` compiled, once :func:`warm` has compiled or loaded it in this process
_compiled = None


def _numbers(b, out, pow10):  # pragma: no cover - compiled
    """The whitespace-separated decimal numbers of the bytes ``b`` into ``out``; their
    count, or -1 at the first token not read exactly here."""
    n, i, size = 0, 0, len(b)
    while i < size:
        c = b[i]
        if c == 32 or c == 10 or c == 9 or c == 13:
            i += 1
            continue
        neg = c == 45
        if neg:
            i += 1
        m, digits, sig, frac, dot = 0, 0, 0, 0, False
        while i < size:
            c = b[i]
            if 48 <= c <= 57:
                if m > 0 or c != 48:        # leading zeros: no digit of m
                    if sig == 17:
                        return -1
                    sig += 1
                m = m * 10 + (c - 48)
                digits += 1
                if dot:
                    frac += 1
            elif c == 46 and not dot:
                dot = True
            else:
                break
            i += 1
        if digits == 0:
            return -1
        ex = 0
        if i < size and (b[i] == 101 or b[i] == 69):
            i += 1
            xneg = False
            if i < size and (b[i] == 45 or b[i] == 43):
                xneg = b[i] == 45
                i += 1
            xd = 0
            while i < size and 48 <= b[i] <= 57:
                if xd == 3:
                    return -1
                ex = ex * 10 + (b[i] - 48)
                xd += 1
                i += 1
            if xd == 0:
                return -1
            if xneg:
                ex = -ex
        if i < size and not (b[i] == 32 or b[i] == 10 or b[i] == 9 or b[i] == 13):
            return -1
        p = ex - frac
        if p > 22 or p < -22 or m > 9007199254740992:
            return -1
        v = float(m)
        v = v * pow10[p] if p >= 0 else v / pow10[-p]
        out[n] = -v if neg else v
        n += 1
    return n


def warm() -> None:
    """Compile (a first run on a machine) or load the loop."""
    global _compiled
    from rackstress.lib.jit import numba_or_none

    nb = numba_or_none()
    if nb is None:
        return
    if _compiled is None:
        _compiled = nb.njit(cache=True, nogil=True)(_numbers)
    _compiled(np.frombuffer(b"1", dtype=np.uint8), np.empty(1), _POW10)


def ready() -> bool:
    """Whether the loop is loaded in this process (:func:`warm`)."""
    return _compiled is not None and bool(_compiled.signatures)


def numbers(text) -> np.ndarray | None:
    """The whitespace-separated numbers of ``text`` (bytes) as float64, bit for bit
    ``np.fromstring(text, sep=" ")``; None where this cannot say (the loop not loaded here,
    or a token not read exactly: module docstring), and the caller parses with NumPy."""
    if not ready():
        return None
    b = np.frombuffer(text, dtype=np.uint8)
    out = np.empty(len(b) // 2 + 1)
    n = _compiled(b, out, _POW10)
    return None if n < 0 else out[:n].copy()
