"""``sediment-large``: MagPod on a sediment of a million particles (the paper's future
work, "millions of particles").

The robot is :func:`~rackstress.scenes.magpod.magpod`'s, unchanged; the sediment is
``sediment_nx × sediment_nz`` = 1100 × 910 = 1,001,000 particles by default (3300 × 2730 units at
spacing 3), with the robot ``sediment_back`` columns in from its rear edge and centred across
it. The track is longer (x, the walking direction) than wide, so that a bisection by particle
count cuts across x and leaves the robot whole on one rank. Sediment
particles only feel the legs (Eq. 31) and their own damping, so nearly all of the domain is
passive: the active region (body, legs, racks, and the sediment under the feet) is a few
hundred units across.

``balance`` names the load balancing the LAMMPS engine applies under MPI
(:func:`rackstress.engines.lammps.deck.balance_commands`): ``"rcb"`` (default) — ``comm_style tiled`` and
a recursive-bisection ``balance`` that weighs each moving particle (the robot, and sediment once
touched) ``robot_weight`` times a resting sediment particle (a moving particle carries the
operators: binds to the racks, attraction, collisions), so that the ranks' work is even; ``"shift"`` — ``balance shift xz`` on the particle counts;
``"none"`` — LAMMPS' default even split of the box. It changes nothing in serial.

``robot_weight`` is at least :data:`ROBOT_WEIGHT` here, not the decks' 20 (MagPod's): a resting
particle of this bed costs almost nothing per step (LAMMPS passes over it only at its ~9
reneighbourings of 1200 steps, ~20 ns each: ~0.15 ns a step), a moving one ~24 ns a step (1 rank,
measured), a ratio of ~160. At 20 a million resting particles outweigh the robot, the cut misses
it and one rank holds all 4,346 moving particles while the other idles at every step's exchange:
2 ranks were slower than 1. By default the robot weighs as much as the whole bed (``robot_weight``
= resting / moving particles, at least :data:`ROBOT_WEIGHT`): the weighted median along the track
then lies inside the robot, near the bed's rear edge, so LAMMPS' bisection (which keeps the cut
leaving the squarest halves) cuts across the track instead, at z = 0, through the robot and the
bed alike: each rank holds half of each, on any length of bed. At a fixed 150 the 4,004,000-particle
bed (``sediment_nx=4400``) was cut across x, 5,600 units from the robot, which stayed whole on
one rank (4,055 / 0 moving particles).

Run it with a sparse trajectory: a frame of a million particles is ~40 MB of text, e.g.
``mpiexec -n 2 rackstress run sediment-large --dump-every 1200 --no-render``.
"""
from __future__ import annotations

from rackstress.model.scene import Scene
from rackstress.scenes.magpod import magpod

#: How many resting sediment particles a moving one weighs in ``balance rcb`` (module doc).
ROBOT_WEIGHT = 150.0


def sediment_large(sediment_nx: int = 1100, sediment_nz: int = 910, sediment_back: int = 25,
                   phase_steps: int = 1200, cycles: int = 1, dt: float = 0.01,
                   sediment_radius: float = 2.0, sediment_spacing: float = 3.0,
                   balance: str = "rcb", robot_weight: float | None = None) -> Scene:
    """MagPod on a ``sediment_nx × sediment_nz`` sediment (default 1,001,000 particles), one cycle."""
    kw = {k: v for k, v in locals().items()}
    if balance not in ("rcb", "shift", "none"):
        from rackstress.errors import SceneError

        raise SceneError(f"sediment-large: balance must be rcb, shift or none, got {balance!r}")
    if robot_weight is not None and (isinstance(robot_weight, bool)
                                     or not isinstance(robot_weight, (int, float))
                                     or not robot_weight > 0):
        from rackstress.errors import SceneError

        raise SceneError(f"sediment-large: robot_weight must be a positive number, got "
                         f"{robot_weight!r}")
    scene = magpod(sediment_nx=sediment_nx, sediment_nz=sediment_nz, sediment_back=sediment_back,
                   phase_steps=phase_steps, cycles=cycles, dt=dt,
                   sediment_radius=sediment_radius, sediment_spacing=sediment_spacing,
                   name="sediment-large")
    if kw["robot_weight"] is None:     # as much as the whole bed (module doc)
        resting = scene.groups["sediment"].n
        kw["robot_weight"] = max(ROBOT_WEIGHT, float(round(resting / (scene.n_particles - resting))))
    scene.params = dict(kw)        # this builder's own keywords, so --set/rebuilds round-trip
    return scene
