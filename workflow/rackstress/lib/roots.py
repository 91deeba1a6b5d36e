"""The stability boundary of a two-step recursion, found by bisection on t.

Both integrators' limits (Eq. 5's and the verlet mode's) reduce, for a complex ω², to: the
largest t at which every root μ of a characteristic polynomial lies inside the unit circle.
"""
from __future__ import annotations

import numpy as np


def inside_unit_circle(coeffs) -> bool:
    """True when every root of the polynomial ``coeffs`` (highest power first) has |μ| < 1."""
    return bool(np.abs(np.roots(coeffs)).max() < 1.0)


def largest_stable(stable, hi: float, iters: int = 60) -> float:
    """The boundary of ``stable(t)`` on (0, hi] by bisection (``hi`` itself if it is stable)."""
    if stable(hi):
        return hi
    lo = 0.0
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return lo
