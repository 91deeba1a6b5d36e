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
``bind-inside``
    bind(body, within(d) inside the part) (:class:`~rackstress.model.operators.WithinInside`):
    the same network without the bindings that cross free space. On a square lattice the
    diagonal binding at a re-entrant corner runs through the corner point and fills the notch;
    this body has none (the L-bracket loses 2 of its 1818 bindings, the others none), so it
    keeps the corner's stress concentration.

A clamped end is a set of **held** particles of the body (``Group.held``: held at their original
positions on every engine). The body's particles are bound to them as to each other, and the
rack binds to them as to any host particle; :func:`free_mask` tells them apart.

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
from rackstress.model.operators import Bind, Const, Dampen, Force, Within, WithinInside
from rackstress.model.particles import Group, rack
from rackstress.model.regions import Box, Cylinder
from rackstress.model.scene import Phase, Scene

BODIES = ("rack", "rack+bind", "bind", "bind-inside")
RADIUS = 0.5


def _grid(ii, jj) -> np.ndarray:
    return np.stack([np.asarray(ii, float), np.asarray(jj, float), np.zeros(len(ii))], axis=1)


def _assemble(name: str, body_o: np.ndarray, held: np.ndarray | None, loads: list,
              body: str, bind_c: float, bind_d: float, rack_c: float,
              rack_back_c: float, damping: float, rack_damping: float, dt: float, steps: int,
              params: dict, geometry: dict, shape=None) -> Scene:
    if body not in BODIES:
        raise SceneError(f"scene '{name}': body must be one of {', '.join(BODIES)}, got {body!r}")
    groups = {"body": Group("body", body_o, RADIUS, kind="body", held=held,
                            meta={"validation": geometry})}
    body_ops = [Force(tuple(float(a) for a in accel), where=tuple(bool(m) for m in mask))
                for mask, accel in loads]
    if body in ("rack+bind", "bind"):
        body_ops.append(Bind("body", Within(bind_d, bind_c)))
    if body == "bind-inside":
        body_ops.append(Bind("body", WithinInside(bind_d, bind_c, shape)))
    ops = {"body": body_ops}
    if body in ("rack", "rack+bind"):
        groups["bodyrack"] = rack(groups["body"], "bodyrack")
        body_ops.append(Bind("bodyrack", Const(rack_c)))
        ops["bodyrack"] = [Bind("body", Const(rack_back_c)), Dampen(rack_damping)]
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
    >>> s.groups["body"].n, int(s.groups["body"].held.sum())
    (30, 6)
    """
    if nx - n_clamp < 2 or ny < 2 or n_clamp < 1:
        raise SceneError("cantilever needs ny ≥ 2, n_clamp ≥ 1 and at least 2 free columns")
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    i, j = i.ravel(), j.ravel()
    body_o, held = _grid(i, j), i < n_clamp
    tip = i == nx - 1
    geometry = {"case": "cantilever", "L": float(nx - n_clamp), "h": float(ny), "P": float(load),
                "x0": n_clamp - 0.5, "y0": -0.5}
    params = dict(body=body, nx=nx, ny=ny, n_clamp=n_clamp, load=load, bind_c=bind_c,
                  bind_d=bind_d, rack_c=rack_c, rack_back_c=rack_back_c, damping=damping,
                  rack_damping=rack_damping, dt=dt, steps=steps)
    shape = Box((-0.5, -0.5, -0.5), (nx - 0.5, ny - 0.5, 0.5))     # the lattice cells' union
    return _assemble("cantilever", body_o, held, [(tip, (0.0, -load / ny, 0.0))], body, bind_c,
                     bind_d, rack_c, rack_back_c, damping, rack_damping, dt, steps, params,
                     geometry, shape)


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
    shape = (Box((-n - 0.5, -n - 0.5, -0.5), (n + 0.5, n + 0.5, 0.5))
             - Cylinder((0.0, 0.0, -1.0), (0.0, 0.0, 1.0), a))      # the FEA's plate
    return _assemble("plate-hole", body_o, None, loads, body, bind_c, bind_d, rack_c,
                     rack_back_c, damping, rack_damping, dt, steps, params, geometry, shape)


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
    body_o, held = _grid(i, j), j < n_clamp
    tip = i == lx - 1
    geometry = {"case": "l-bracket", "w": float(w), "H": float(H - n_clamp), "Lx": float(lx),
                "P": float(load), "shift": (-0.5, n_clamp - 0.5),
                "corner": (w - 0.5, H - w - 0.5)}
    params = dict(body=body, w=w, H=H, lx=lx, n_clamp=n_clamp, load=load, bind_c=bind_c,
                  bind_d=bind_d, rack_c=rack_c, rack_back_c=rack_back_c, damping=damping,
                  rack_damping=rack_damping, dt=dt, steps=steps)
    shape = (Box((-0.5, -0.5, -0.5), (w - 0.5, H - 0.5, 0.5))          # leg
             | Box((-0.5, H - w - 0.5, -0.5), (lx - 0.5, H - 0.5, 0.5)))  # arm
    return _assemble("l-bracket", body_o, held, [(tip, (0.0, -load / w, 0.0))], body, bind_c,
                     bind_d, rack_c, rack_back_c, damping, rack_damping, dt, steps, params,
                     geometry, shape)


def body_index(scene: Scene) -> np.ndarray:
    """Global indices of the part's particles (the body group, held ones included)."""
    sl = scene.slice("body")
    return np.arange(sl.start, sl.stop)


def free_mask(scene: Scene) -> np.ndarray:
    """Which of the body's particles are free (not held): the ones compared with FEA."""
    return ~np.asarray(scene.groups["body"].held, dtype=bool)


BUILDERS = {"cantilever": cantilever, "plate-hole": plate_hole, "l-bracket": l_bracket}
