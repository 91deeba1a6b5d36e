"""Validation scenes: three planar bodies whose linear-elastic answer is known.

``cantilever``, ``plate-hole`` and ``l-bracket`` lay particles (radius 0.5) on a square lattice of
spacing 1 in the x–y plane (z = 0). Each is a body of one material; what makes it rigid or
elastic is the scene option ``body``:

``rack`` (the paper's, Section 3.2)
    body • force • bind(bodyrack, [100]) • dampen(g);  bodyrack • bind(body, [0.5]) • dampen(1)
    — no host–host bindings at all (Eqs. 23–25).
``rack+bind``
    the same plus bind(body, within(d)) (Eq. 16, c = ``bind_c``, d = ``bind_d`` ≈ 1.5 spacings:
    the 8 lattice neighbours).
``bind``
    bind(body, within(d)) alone: a lattice spring network, the body model closest to a
    continuum (Section 3.1's plane with within(2)).

A clamped end is a group ``clamp`` of particles with **no operators**: nothing accelerates them,
so they stay at their original positions for ever (held supports, exact on every engine). The
body's particles are bound to them as to each other, and the rack binds to them as to any host
particle (the clamp is part of the part: :func:`body_index` gives body ∪ clamp).

Loads are ``force`` with ``where`` (Eq. 8) on edge particles, so that their sum equals the
continuum case's traction times the edge length (unit thickness, unit spacing):

=============  ================================================  ===========================
scene          geometry (lattice indices)                        continuum body (FEA)
=============  ================================================  ===========================
cantilever     i < nx, j < ny; clamp i < n_clamp; load (0, −P/ny)  [n_clamp−½, nx−½]×[−½, ny−½],
               on column i = nx−1                                clamped at x = n_clamp−½
plate-hole     |i|, |j| ≤ n, i² + j² ≥ a²; ±σ along x on the       [−n−½, n+½]² minus the disc
               columns i = ±n                                    of radius a
l-bracket      leg i < w, j < H; arm i < lx, H−w ≤ j < H;         the L shifted by (½, n_clamp−½);
               clamp j < n_clamp; (0, −P/w) on column lx−1        fixed along its bottom edge
=============  ================================================  ===========================

Every scene runs ``steps`` iterations of one phase; :func:`rackstress.validity.compare`
runs them to damped equilibrium.
"""
from __future__ import annotations

import numpy as np

from rackstress.errors import SceneError
from rackstress.model.operators import Bind, Const, Dampen, Force, Within
from rackstress.model.particles import Group, rack
from rackstress.model.scene import Phase, Scene

BODIES = ("rack", "rack+bind", "bind")
RADIUS = 0.5


def _grid(ii, jj) -> np.ndarray:
    return np.stack([np.asarray(ii, float), np.asarray(jj, float), np.zeros(len(ii))], axis=1)


def _assemble(name: str, body_o: np.ndarray, clamp_o: np.ndarray | None, loads: list,
              body: str, bind_c: float, bind_d: float, rack_c: float,
              rack_back_c: float, damping: float, rack_damping: float, dt: float, steps: int,
              params: dict, geometry: dict) -> Scene:
    if body not in BODIES:
        raise SceneError(f"scene '{name}': body must be one of {', '.join(BODIES)}, got {body!r}")
    groups = {"body": Group("body", body_o, RADIUS, kind="body",
                            meta={"validation": geometry})}
    if clamp_o is not None and len(clamp_o):
        groups["clamp"] = Group("clamp", clamp_o, RADIUS, kind="body")
    held = "clamp" in groups
    body_ops = [Force(tuple(float(a) for a in accel), where=tuple(bool(m) for m in mask))
                for mask, accel in loads]
    if body in ("rack+bind", "bind"):
        body_ops.append(Bind("body", Within(bind_d, bind_c)))
        if held:
            body_ops.append(Bind("clamp", Within(bind_d, bind_c)))
    ops = {"body": body_ops}
    if body in ("rack", "rack+bind"):
        whole = Group("part", np.concatenate([g.o for g in groups.values()]), RADIUS)
        r = rack(whole, "bodyrack")
        groups["bodyrack"] = Group("bodyrack", r.o, r.r, kind="rack", host="body",
                                   meta=r.meta)
        body_ops.append(Bind("bodyrack", Const(rack_c)))
        ops["bodyrack"] = [Bind("body", Const(rack_back_c))]
        if held:
            ops["bodyrack"].append(Bind("clamp", Const(rack_back_c)))
        ops["bodyrack"].append(Dampen(rack_damping))
    body_ops.append(Dampen(damping))
    return Scene(name, groups, ops, [Phase("load", int(steps))], dt=dt, params=params)


def cantilever(body: str = "rack+bind", nx: int = 40, ny: int = 6, n_clamp: int = 2,
               load: float = 0.05, bind_c: float = 20.0, bind_d: float = 1.5,
               rack_c: float = 100.0, rack_back_c: float = 0.5, damping: float = 0.1,
               rack_damping: float = 1.0, dt: float = 0.02, steps: int = 20000) -> Scene:
    """A cantilever clamped at its left end with total downward load ``load`` at its tip.

    Example
    -------
    >>> s = cantilever(nx=10, ny=3)
    >>> s.groups["body"].n, s.groups["clamp"].n
    (24, 6)
    """
    if nx - n_clamp < 2 or ny < 2 or n_clamp < 1:
        raise SceneError("cantilever needs ny ≥ 2, n_clamp ≥ 1 and at least 2 free columns")
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    i, j = i.ravel(), j.ravel()
    free = i >= n_clamp
    body_o, clamp_o = _grid(i[free], j[free]), _grid(i[~free], j[~free])
    tip = i[free] == nx - 1
    geometry = {"case": "cantilever", "L": float(nx - n_clamp), "h": float(ny), "P": float(load),
                "x0": n_clamp - 0.5, "y0": -0.5}
    params = dict(body=body, nx=nx, ny=ny, n_clamp=n_clamp, load=load, bind_c=bind_c,
                  bind_d=bind_d, rack_c=rack_c, rack_back_c=rack_back_c, damping=damping,
                  rack_damping=rack_damping, dt=dt, steps=steps)
    return _assemble("cantilever", body_o, clamp_o, [(tip, (0.0, -load / ny, 0.0))], body, bind_c,
                     bind_d, rack_c, rack_back_c, damping, rack_damping, dt, steps, params,
                     geometry)


def plate_hole(body: str = "rack+bind", n: int = 12, a: float = 4.0, sigma: float = 0.01,
               bind_c: float = 20.0, bind_d: float = 1.5, rack_c: float = 100.0,
               rack_back_c: float = 0.5, damping: float = 0.1, rack_damping: float = 1.0,
               dt: float = 0.02, steps: int = 20000) -> Scene:
    """A square plate with a central hole of radius ``a``, pulled by ``sigma`` along ±x.

    The load is balanced, so no support is needed; a rigid motion of the plate is left out by
    every measure compared (and by the FEA's symmetry conditions).
    """
    if not 0 < a < n - 1:
        raise SceneError(f"plate-hole: hole radius a = {a} must lie in (0, n − 1 = {n - 1})")
    i, j = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    keep = i ** 2 + j ** 2 >= a ** 2
    i, j = i[keep], j[keep]
    body_o = _grid(i, j)
    geometry = {"case": "plate-hole", "a": float(a), "W": n + 0.5, "sigma": float(sigma)}
    params = dict(body=body, n=n, a=a, sigma=sigma, bind_c=bind_c, bind_d=bind_d,
                  rack_c=rack_c, rack_back_c=rack_back_c, damping=damping,
                  rack_damping=rack_damping, dt=dt, steps=steps)
    loads = [(i == n, (sigma, 0.0, 0.0)), (i == -n, (-sigma, 0.0, 0.0))]
    return _assemble("plate-hole", body_o, None, loads, body, bind_c, bind_d, rack_c,
                     rack_back_c, damping, rack_damping, dt, steps, params, geometry)


def l_bracket(body: str = "rack+bind", w: int = 6, H: int = 26, lx: int = 24, n_clamp: int = 2,
              load: float = 0.02, bind_c: float = 20.0, bind_d: float = 1.5,
              rack_c: float = 100.0, rack_back_c: float = 0.5, damping: float = 0.1,
              rack_damping: float = 1.0, dt: float = 0.02, steps: int = 20000) -> Scene:
    """An L: a vertical leg held along its bottom rows, a horizontal arm loaded down at its end."""
    if not (w >= 2 and H - n_clamp > w and lx > w + 1 and n_clamp >= 1):
        raise SceneError("l-bracket needs w ≥ 2, H − n_clamp > w, lx > w + 1, n_clamp ≥ 1")
    i, j = np.meshgrid(np.arange(lx), np.arange(H), indexing="ij")
    i, j = i.ravel(), j.ravel()
    inside = (i < w) | (j >= H - w)
    i, j = i[inside], j[inside]
    free = j >= n_clamp
    body_o, clamp_o = _grid(i[free], j[free]), _grid(i[~free], j[~free])
    tip = i[free] == lx - 1
    geometry = {"case": "l-bracket", "w": float(w), "H": float(H - n_clamp), "Lx": float(lx),
                "P": float(load), "shift": (-0.5, n_clamp - 0.5),
                "corner": (w - 0.5, H - w - 0.5)}
    params = dict(body=body, w=w, H=H, lx=lx, n_clamp=n_clamp, load=load, bind_c=bind_c,
                  bind_d=bind_d, rack_c=rack_c, rack_back_c=rack_back_c, damping=damping,
                  rack_damping=rack_damping, dt=dt, steps=steps)
    return _assemble("l-bracket", body_o, clamp_o, [(tip, (0.0, -load / w, 0.0))], body, bind_c,
                     bind_d, rack_c, rack_back_c, damping, rack_damping, dt, steps, params,
                     geometry)


def body_index(scene: Scene) -> np.ndarray:
    """Global indices of the part's particles: body, then clamp (if any), in engine order."""
    idx = [np.arange(scene.slice("body").start, scene.slice("body").stop)]
    if "clamp" in scene.groups:
        sl = scene.slice("clamp")
        idx.append(np.arange(sl.start, sl.stop))
    return np.concatenate(idx)


BUILDERS = {"cantilever": cantilever, "plate-hole": plate_hole, "l-bracket": l_bracket}
