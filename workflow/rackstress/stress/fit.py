"""Best-fit rigid motion of a part: plain Kabsch and a robust (outlier-excluding) Kabsch.

The math lives in :mod:`rackstress.lib.rigid` (its docstring says what each fit does), so that a
run's ``summary.json`` and the stress measures use one and the same fit; this module names the
fits the measures offer.
"""
from __future__ import annotations

from rackstress.lib.rigid import (ROBUST_C, ROBUST_FLOOR, ROBUST_MAX_ITER, rigid_fit,
                                  robust_fit)

__all__ = ["FITS", "ROBUST_C", "ROBUST_FLOOR", "ROBUST_MAX_ITER", "rigid_fit", "robust_fit"]

FITS = {"robust": lambda o, p: robust_fit(o, p)[:3], "kabsch": rigid_fit}
