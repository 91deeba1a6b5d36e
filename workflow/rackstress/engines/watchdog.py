"""The watchdog: a run whose particles become non-finite or leave ``scene.bound`` is stopped,
naming the step, the particle and its group (both engines call it)."""
from __future__ import annotations

import math

import numpy as np

from rackstress.errors import DivergenceError
from rackstress.lib.vec import finite_rows, rowdot
from rackstress.model.scene import Scene


def find_divergence(scene: Scene, p: np.ndarray, v: np.ndarray, o: np.ndarray,
                    index: np.ndarray | None = None) -> dict | None:
    """The watchdog's test: the worst particle that is non-finite or beyond ``scene.bound``.

    ``index`` gives the global particle index of each row when p, v hold only some particles.
    Returns None when all is well.
    """
    if not len(p):
        return None
    # the common case in one pass: every displacement within the bound (so every position
    # finite) and the velocities' sum finite (a NaN or an infinity would make it non-finite)
    dp = p - o
    if rowdot(dp, dp).max() <= scene.bound ** 2 and math.isfinite(float(v.sum())):
        return None
    finite = finite_rows(p) & finite_rows(v)
    disp = np.full(len(p), np.inf)
    dp = p[finite] - o[finite]
    disp[finite] = np.sqrt(rowdot(dp, dp))
    bad = disp > scene.bound
    if not bad.any():
        return None
    rows = np.flatnonzero(bad)
    nonfinite = rows[~finite[rows]]
    row = int(nonfinite[0]) if len(nonfinite) else int(rows[np.argmax(disp[rows])])
    return {"index": int(index[row]) if index is not None else row, "finite": bool(finite[row]),
            "disp": float(disp[row]), "p": p[row].tolist(), "v": v[row].tolist(),
            "count": int(len(rows))}


def divergence_error(scene: Scene, step: int, found: dict) -> DivergenceError:
    """The one-paragraph error for a particle found by :func:`find_divergence`."""
    k = found["index"]
    group, local = scene.group_of(k)
    if not found["finite"]:
        what = f"its position {found['p']} / velocity {found['v']} is not finite"
    else:
        what = (f"it is {found['disp']:.4g} units from its original position, beyond the "
                f"watchdog bound {scene.bound:g}")
    return DivergenceError(
        f"run diverged at step {step}: '{group}' particle {local} (atom id {k + 1}): {what}. "
        f"{found['count']} particle(s) out of bound. A smaller time step (dt = {scene.dt:g} now) "
        "or weaker coefficients keep Eq. 5 stable (t < 2/ω_max); the output written up to here "
        "is kept.", step=step, index=k, group=group, local=local, value=found["disp"])


def check(scene: Scene, p: np.ndarray, v: np.ndarray, o: np.ndarray, step: int) -> None:
    """The watchdog: raise :class:`DivergenceError` if a particle is non-finite or out of bound."""
    found = find_divergence(scene, p, v, o)
    if found is not None:
        raise divergence_error(scene, step, found)


def force_error(scene: Scene, step: int, index: int) -> DivergenceError:
    """The error for a non-finite force on particle ``index`` at ``step`` (both engines find it
    in the step it arises, before any position becomes non-finite: the frames kept are finite).
    """
    group, local = scene.group_of(int(index))
    return DivergenceError(
        f"run diverged at step {step}: the force on '{group}' particle {local} (atom id "
        f"{int(index) + 1}) is not finite: two particles bound or attracted to each other "
        "coincide there (Eq. 12's direction is undefined at d = 0), or a force overflowed. A "
        f"smaller time step (dt = {scene.dt:g} now) or weaker coefficients keep Eq. 5 stable; the "
        "output written up to here is kept.", step=int(step), index=int(index), group=group,
        local=local)


def first_nonfinite(a: np.ndarray) -> int:
    """The first row of ``a`` holding a NaN or an infinity, or −1 (one pass when all is well)."""
    if math.isfinite(float(a.sum())):
        return -1
    bad = np.flatnonzero(~finite_rows(a))
    return int(bad[0]) if len(bad) else -1
