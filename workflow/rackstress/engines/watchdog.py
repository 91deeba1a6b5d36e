"""The watchdog: a run whose particles become non-finite, leave ``scene.bound`` or, in a part with
a material, move faster than its wave speed (:meth:`Scene.speed_limits`) is stopped, naming the
step, the particle and its group (both engines call it)."""
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
    if rowdot(dp, dp).max() <= scene.bound ** 2 and math.isfinite(float(v.sum())) \
            and not too_fast(scene, v, index).any():
        return None
    finite = finite_rows(p) & finite_rows(v)
    disp = np.full(len(p), np.inf)
    dp = p[finite] - o[finite]
    disp[finite] = np.sqrt(rowdot(dp, dp))
    fast = too_fast(scene, v, index) & finite
    bad = (disp > scene.bound) | fast
    if not bad.any():
        return None
    rows = np.flatnonzero(bad)
    nonfinite = rows[~finite[rows]]
    far = rows[disp[rows] > scene.bound]
    if len(nonfinite):
        row = int(nonfinite[0])
    elif len(far):
        row = int(far[np.argmax(disp[far])])
    else:                                   # the fastest, relative to its material's c
        lim = _limits(scene, index, len(v))
        row = int(rows[np.argmax(rowdot(v[rows], v[rows]) / lim[rows] ** 2)])
    found = {"index": int(index[row]) if index is not None else row,
             "finite": bool(finite[row]), "disp": float(disp[row]), "p": p[row].tolist(),
             "v": v[row].tolist(), "count": int(len(rows))}
    if finite[row] and disp[row] <= scene.bound:
        found["speed"] = float(np.sqrt(rowdot(v[row:row + 1], v[row:row + 1])[0]))
        found["limit"] = float(_limits(scene, index, len(v))[row])
    return found


def _limits(scene: Scene, index: np.ndarray | None, n: int) -> np.ndarray:
    lim = scene.speed_limits()
    return lim[:n] if index is None else lim[index]


def too_fast(scene: Scene, v: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
    """Which rows of ``v`` are faster than their material's wave speed √(E/ρ) (a strain of
    order one: the lattice blew up); all False in a scene without materials."""
    if scene.speed_limits() is None or not len(v):
        return np.zeros(len(v), bool)
    with np.errstate(invalid="ignore"):
        return rowdot(v, v) > _limits(scene, index, len(v)) ** 2


def divergence_error(scene: Scene, step: int, found: dict,
                     since: int | None = None) -> DivergenceError:
    """The one-paragraph error for a particle found by :func:`find_divergence`; ``since``: the
    step of the watchdog's previous look, when it looks only every so many steps (the run went
    wrong after it)."""
    k = found["index"]
    group, local = scene.group_of(k)
    u = scene.units
    speed_unit = f"{u.length}/{u.time}" if u.physical else "units/time"
    if not found["finite"]:
        what = f"its position {found['p']} / velocity {found['v']} is not finite"
    elif "speed" in found:
        what = (f"it moves at {found['speed']:.4g} {speed_unit}, faster than its material's "
                f"wave speed √(E/ρ) = {found['limit']:.4g} {speed_unit}: a strain of order "
                "100 %, the lattice has blown up (a contact or a coefficient too stiff for the "
                "time step, or a load no solid survives)")
    else:
        what = (f"it is {found['disp']:.4g} units from its original position, beyond the "
                f"watchdog bound {scene.bound:g}")
    when = "" if since is None or since >= step - 1 else (
        f" It went wrong after step {since}, the watchdog's previous look.")
    return DivergenceError(
        f"run diverged at step {step}: '{group}' particle {local} (atom id {k + 1}): {what}. "
        f"{found['count']} particle(s) out of bound or too fast.{when} A smaller time step (dt = "
        f"{scene.dt:g} now) or weaker coefficients keep Eq. 5 stable (t < 2/ω_max); the output "
        "written up to here is kept.", step=step, index=k, group=group, local=local,
        value=found["disp"])


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
