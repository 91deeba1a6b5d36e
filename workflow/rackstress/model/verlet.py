"""A second-order integration mode beside Eq. 5: leapfrog with trapezoidal damping ("verlet").

Eq. 5 (``v += t·a; p += t·v``) is the paper's and stays the default (``Scene.integrator =
"euler"``). Its positions obey p_{n+1} − 2p_n + p_{n−1} = t²·a_n — Störmer–Verlet — but it is
first order all the same, for two reasons: it starts from v₀ where a leapfrog needs v_{−½}, and
its damping −γv uses the velocity half a step old. ``integrator = "verlet"`` fixes both:

    v_{n+½} = [(1 − γt/2)·v_{n−½} + t·a_c(p_n)] / (1 + γt/2),     p_{n+1} = p_n + t·v_{n+½},
    v_½     = v₀ + (t/2)·a(p₀, v₀)/(1 + γt/2)        (the first step: velocity Verlet's half kick),

where a = a_c − γv splits every operator's acceleration into the velocity-free part a_c (force,
collide, bind, attract) and the damping (Eq. 9; per particle, conditions evaluated at p_n).
The damping is the trapezoidal average of v_{n−½} and v_{n+½}, so the scheme is second order
for damped scenes too and reduces to velocity Verlet without damping.

**Stability** (x'' = −λx − γx'): the amplification matrix has determinant
q = (1 − γt/2)/(1 + γt/2) ∈ (−1, 1) and trace 1 + q − λt²/(1 + γt/2); Jury's test gives
λt² < 4 whatever γ ≥ 0, i.e. **t < 2/ω**: damping never limits it (Eq. 5's limit is
4/(γ + √(γ² + 4λ)), below 2/ω whenever γ > 0). :func:`t_limit_verlet`.

**On LAMMPS** the same recursion is Eq. 5 on a *scaled* scene: every operator on a group whose
damping is γ multiplied by s = 1/(1 + γt/2) (then γ' = sγ and a_c' = s·a_c give exactly the
update above), run by ``fix nve`` started from v₀ without Eq. 5's half-step shift — LAMMPS'
velocity Verlet evaluates ``fix viscous`` with the half-step velocity v_{n+½}, which is what the
scaled recursion needs (:func:`scaled_scene`). A damping ``extra`` that switches on a contact
condition (MagPod's legs, Eq. 28) cannot be folded into a fixed s: there the base damping is
folded and the extra stays lagged (first order in that term alone); the reference engine
evaluates it exactly.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from rackstress.errors import SceneError
from rackstress.lib.roots import inside_unit_circle, largest_stable
from rackstress.model.operators import Attract, Bind, Collide, Dampen, Force

INTEGRATORS = ("euler", "verlet")


def integrate_verlet(p: np.ndarray, v_half: np.ndarray, a_c: np.ndarray, gamma: np.ndarray,
                     t: float) -> tuple[np.ndarray, np.ndarray]:
    """One step of the module's recursion: returns (p_{n+1}, v_{n+½}) from v_{n−½}, a_c(p_n), γ."""
    g = np.asarray(gamma, dtype=float)[:, None] * (0.5 * t)
    v = ((1.0 - g) * v_half + t * a_c) / (1.0 + g)
    return p + t * v, v


def t_limit_verlet(lam, gamma: float = 0.0) -> float:
    """Largest stable t of the verlet mode for x'' = −λx − γx' (module docstring): 2/√λ.

    Complex λ (directed couplings): the boundary of max|μ| < 1 of
    μ² − (1 + q − λt²/(1 + γt/2))μ + q = 0 by bisection.

    Example
    -------
    >>> t_limit_verlet(400.0, 10.0)     # 2/ω; Eq. 5 would allow 4/(10 + √1700) ≈ 0.078
    0.1
    """
    lam = complex(lam)
    gamma = max(0.0, float(gamma))
    if lam.real < 0 or abs(lam) == 0:
        return math.inf
    if abs(lam.imag) <= 1e-12 * abs(lam):
        return 2.0 / math.sqrt(lam.real)

    def stable(t):
        s = 1.0 / (1.0 + 0.5 * gamma * t)
        q = (1.0 - 0.5 * gamma * t) * s
        return inside_unit_circle([1.0, -(1.0 + q - s * lam * t * t), q])

    return largest_stable(stable, 8.0 / math.sqrt(abs(lam)))


def modified_frequency(omega: float, t: float) -> float:
    """The frequency at which Eq. 5 *and* the verlet mode carry an undamped mode of frequency ω.

    Both obey p_{n+1} − 2p_n + p_{n−1} = t²·a(p_n) on such a mode (module docstring), whose
    solutions rotate by θ per step with cos θ = 1 − ω²t²/2: ω̃ = θ/t = ω(1 + ω²t²/24 + …). The
    two schemes differ only in their start and their damping (first order in Eq. 5), never in
    this phase, so a lightly damped stiff mode leaves both with the same error ∝ ω³t²·T, and
    Eq. 5's error over the verlet mode's is at most about 1 + A/(B·t) (README, "What the
    picture means"; ``scripts/phase_error.py`` shows no other two-stage splitting does better
    at the same cost). NaN beyond the stability limit ωt ≥ 2.

    Example
    -------
    >>> round(modified_frequency(10.0, 0.01) / 10.0 - 1.0, 6)    # ≈ ω²t²/24
    0.000417
    """
    c = 1.0 - 0.5 * (omega * t) ** 2
    return math.acos(c) / t if -1.0 < c <= 1.0 else math.nan


def group_damping(scene) -> dict:
    """Unconditional damping γ of each group (sum of its dampen coefficients, Eq. 9)."""
    out = {}
    for name in scene.groups:
        out[name] = float(sum(op.c for op in scene.operators.get(name, [])
                              if isinstance(op, Dampen) and not op.when))
        for op in scene.operators.get(name, []):
            if isinstance(op, Dampen) and op.when:
                out[name] += float(op.c)   # the base of a conditional dampen always acts
    return out


def _scale(op, s: float):
    if isinstance(op, Force):
        return dataclasses.replace(op, accel=tuple(s * float(a) for a in op.accel))
    if isinstance(op, Dampen):
        return dataclasses.replace(op, c=s * op.c, extra=s * op.extra)
    if isinstance(op, (Collide, Bind, Attract)):
        return dataclasses.replace(op, coeff=dataclasses.replace(op.coeff, c=s * op.coeff.c))
    if getattr(op, "kind", "") == "volume":     # a material part's many-body term
        return dataclasses.replace(op, c=tuple(s * c for c in op.c))
    raise SceneError(f"verlet mode cannot scale operator {op!r}")  # pragma: no cover


def scaled_scene(scene):
    """The scene whose Eq. 5 recursion, started by fix nve from v₀ (no half-step shift), is the
    verlet mode.

    Every operator on a group with damping γ is multiplied by 1/(1 + γ·dt/2); the result has
    ``integrator = "euler"`` and is what the LAMMPS deck compiles (module docstring).
    """
    gam = group_damping(scene)
    ops = {}
    for target, seq in scene.operators.items():
        s = 1.0 / (1.0 + 0.5 * gam.get(target, 0.0) * scene.dt)
        ops[target] = [_scale(op, s) if s != 1.0 else op for op in seq]
    return dataclasses.replace(scene, operators=ops, integrator="euler")


__all__ = ["INTEGRATORS", "integrate_verlet", "t_limit_verlet", "modified_frequency", "group_damping", "scaled_scene"]
