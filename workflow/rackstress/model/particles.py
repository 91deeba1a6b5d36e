"""Particle groups (the paper's particle vectors, Eq. 1) and rack construction (Eqs. 18–22).

A particle is the 5-tuple (o, p, v, a, r). A :class:`Group` holds the parts that define it —
original positions ``o`` and radii ``r`` — while the moving state (p, v, a) lives in the engine,
one array over all particles, so every engine sees the same particle order.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rackstress.errors import SceneError

#: The paper's rack offset: "the distance from a rack particle to the corresponding face of the
#: bounding box is five units" (Section 3.2). The printed Eq. 21 puts them on the faces; the errata
#: of docs/model.md follow the prose. A parameter of :func:`rack`.
RACK_OFFSET = 5.0
#: Radius of a rack particle, Eq. 22.
RACK_RADIUS = 1.0


@dataclass
class Group:
    """A named particle vector: ``o`` (n×3 original positions) and ``r`` (n radii).

    ``kind`` names the part's role for the LAMMPS data file (body, leg, rack, sediment, plane);
    ``host`` is the group a rack group belongs to (Section 3.2), else ``None``.
    """

    name: str
    o: np.ndarray
    r: np.ndarray
    kind: str = "part"
    host: str | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.o = np.ascontiguousarray(self.o, dtype=np.float64).reshape(-1, 3)
        r = np.asarray(self.r, dtype=np.float64)
        if r.ndim == 0:
            r = np.full(len(self.o), float(r))
        self.r = np.ascontiguousarray(r.reshape(-1))
        if len(self.r) != len(self.o):
            raise SceneError(f"group '{self.name}': {len(self.o)} positions but {len(self.r)} radii")
        if len(self.o) == 0:
            raise SceneError(f"group '{self.name}' has no particles")
        if not np.all(np.isfinite(self.o)):
            i = int(np.flatnonzero(~np.isfinite(self.o).all(axis=1))[0])
            raise SceneError(f"group '{self.name}': particle {i} has a non-finite position {self.o[i]}")
        if not np.all(self.r > 0):
            i = int(np.flatnonzero(~(self.r > 0))[0])
            raise SceneError(
                f"group '{self.name}': particle {i} has radius {self.r[i]!r}; a radius must be "
                "positive (the paper's r is in R+, Eq. 1)")

    @property
    def n(self) -> int:
        return len(self.o)


def bounds(o: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """min(p) and max(p) of Eqs. 18–19: the bounding box of the particles, radii included."""
    return (o - r[:, None]).min(axis=0), (o + r[:, None]).max(axis=0)


def rck(o: np.ndarray, r: np.ndarray, offset: float = RACK_OFFSET) -> np.ndarray:
    """Positions of the six rack particles (Eq. 21, with the prose's offset outside each face).

    Order as Eq. 21: −x, −y, −z, +x, +y, +z faces, each centred on the box centre ctr (Eq. 20).
    """
    lo, hi = bounds(o, r)
    ctr = 0.5 * (lo + hi)
    out = np.tile(ctr, (6, 1))
    for axis in range(3):
        out[axis, axis] = lo[axis] - offset
        out[axis + 3, axis] = hi[axis] + offset
    return out


def rack(host: Group, name: str | None = None, offset: float = RACK_OFFSET,
         radius: float = RACK_RADIUS) -> Group:
    """rack(p) of Eq. 22: six particles around ``host``, original = current position, radius 1."""
    return Group(name or f"{host.name}rack", rck(host.o, host.r, offset), radius,
                 kind="rack", host=host.name, meta={"offset": offset})


def lattice(shape, spacing: float = 1.0, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Positions of a simple-cubic block ``shape = (nx, ny, nz)``, x fastest, from ``origin``."""
    nx, ny, nz = (int(s) for s in shape)
    if min(nx, ny, nz) < 1:
        raise SceneError(f"lattice shape {tuple(shape)} must be positive in every axis")
    if not spacing > 0:
        raise SceneError(f"lattice spacing {spacing!r} must be positive")
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    pts = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1) * float(spacing)
    return pts + np.asarray(origin, dtype=float)
