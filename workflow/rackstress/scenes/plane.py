"""The plane experiments of Section 3: ``plane-bound`` (Eq. 17, Fig. 1), ``plane-rack`` (Eq. 26, Fig. 2).

Choices the paper leaves open, all parameters:

* the plane lies in the x–z plane (y is up, as for MagPod), one corner at the origin, so that
  the pull (0, 100, 0) on ⟨‖o‖² < 10⟩ (Eq. 15) lifts the corner nearest the origin;
* ``spacing = 1``: with it, within(2) binds each particle to its 8 neighbours (Fig. 1b),
  within(10) to a disc of up to ~300 of the 400 (about half of the plane, Fig. 1c) and
  within(100) to all (Fig. 1d); the pull then acts on the 11 particles with i² + k² < 10;
* ``radius = 0.5`` (touching spheres); it matters only for the rack placement (Eqs. 18–21).
"""
from __future__ import annotations

import numpy as np

from rackstress.model.operators import Bind, Const, Dampen, Force, Within, norm2_below, rack_forces
from rackstress.model.particles import Group, lattice, rack
from rackstress.model.scene import Phase, Scene


def plane_group(n: int = 20, spacing: float = 1.0, radius: float = 0.5) -> Group:
    return Group("plane", lattice((n, 1, n), spacing), radius, kind="plane")


def pull(plane: Group, accel: float = 100.0, radius2: float = 10.0) -> Force:
    """force(pull), Eq. 15: (0, accel, 0) on particles with ‖o‖² < radius2."""
    return Force((0.0, float(accel), 0.0), where=norm2_below(plane.o, radius2))


def plane_bound(d: float = 10.0, magnitude: float = 20.0, n: int = 20, spacing: float = 1.0,
                radius: float = 0.5, pull_accel: float = 100.0, pull_radius2: float = 10.0,
                damping: float = 1.0, dt: float = 0.01, steps: int = 1200) -> Scene:
    """Eq. 17: plane • force(pull) • bind(plane, within(d)) • dampen(1) • integrate(0.01)."""
    plane = plane_group(n, spacing, radius)
    ops = {"plane": [pull(plane, pull_accel, pull_radius2),
                     Bind("plane", Within(d, magnitude)),
                     Dampen(damping)]}
    params = dict(d=d, magnitude=magnitude, n=n, spacing=spacing, radius=radius,
                  pull_accel=pull_accel, pull_radius2=pull_radius2, damping=damping, dt=dt,
                  steps=steps)
    return Scene("plane-bound", {"plane": plane}, ops, [Phase("pull", int(steps))], dt=dt,
                 params=params)


def plane_rack(n: int = 20, spacing: float = 1.0, radius: float = 0.5, plane_bind: float = 100.0,
               rack_bind: float = 0.5, rack_offset: float = 5.0, pull_accel: float = 100.0,
               pull_radius2: float = 10.0, damping: float = 1.0, rack_damping: float = 1.0,
               dt: float = 0.01, steps: int = 1200) -> Scene:
    """Eqs. 24–26: plane • planeForces() beside planerack • rackForces(plane), then integrate.

    planeForces = force(pull) • bind(planerack, [100]) • dampen(1)            (Eq. 25)
    rackForces(plane) = bind(plane, [0.5]) • dampen(1)                          (Eq. 23)
    """
    plane = plane_group(n, spacing, radius)
    planerack = rack(plane, "planerack", offset=rack_offset)
    ops = {
        "plane": [pull(plane, pull_accel, pull_radius2),
                  Bind("planerack", Const(plane_bind)),
                  Dampen(damping)],
        "planerack": rack_forces("plane", rack_bind, rack_damping),
    }
    params = dict(n=n, spacing=spacing, radius=radius, plane_bind=plane_bind,
                  rack_bind=rack_bind, rack_offset=rack_offset, pull_accel=pull_accel,
                  pull_radius2=pull_radius2, damping=damping, rack_damping=rack_damping, dt=dt,
                  steps=steps)
    return Scene("plane-rack", {"plane": plane, "planerack": planerack}, ops,
                 [Phase("pull", int(steps))], dt=dt, params=params)


def pulled_mask(scene: Scene) -> np.ndarray:
    """Which plane particles the pull acts on (for analyses of the plane experiments)."""
    return np.asarray(scene.operators["plane"][0].where, dtype=bool)
