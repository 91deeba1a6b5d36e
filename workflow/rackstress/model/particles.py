"""Particle groups (the paper's particle vectors, Eq. 1) and rack construction (Eqs. 18–22).

A particle is the 5-tuple (o, p, v, a, r). A :class:`Group` holds the parts that define it —
original positions ``o`` and radii ``r`` — while the moving state (p, v, a) lives in the engine,
one array over all particles, so every engine sees the same particle order.

Beyond the paper: a group may hold some particles at their original positions (``held``, a
fixed support: zero acceleration and zero velocity, never moving, like LAMMPS' ``fix setforce 0 0
0`` with zero velocity) and start with an initial velocity ``v0`` (the paper's v at step 0).

Id order: lattices and filled parts are numbered from 0, x fastest, then y, then z.
"""
from __future__ import annotations

import math
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

    ``kind`` names the part's role (docs/scenes.md: ``rack`` and ``sediment`` change what the
    pictures and guard rails do); ``host`` is the group a rack group belongs to (Section 3.2),
    else ``None``. ``held`` (n booleans, default none) marks the particles held at their
    original positions (supports); ``v0`` (n×3, default zero) is the velocity at step 0.

    Example
    -------
    >>> g = Group("beam", lattice((4, 1, 1)), 0.5, held=[True, False, False, False],
    ...           v0=[0.0, -1.0, 0.0])
    >>> int(g.held.sum()), g.v0[1].tolist()
    (1, [0.0, -1.0, 0.0])
    """

    name: str
    o: np.ndarray
    r: np.ndarray
    kind: str = "part"
    host: str | None = None
    meta: dict = field(default_factory=dict)
    held: np.ndarray | None = None
    v0: np.ndarray | None = None
    #: the part's material (:mod:`rackstress.model.materials`), None for the paper's unit-mass
    #: particles
    material: object = None
    #: volume each particle stands for, in the scene's length unit cubed (a filled lattice:
    #: spacing³ cubic, spacing³/√2 hcp); None where the scene has no material
    volume: float | None = None
    #: n×3 booleans: the directions in which a particle is held at its original position (a
    #: roller or a symmetry plane fixes one or two; ``held`` is all three); None: as ``held``
    fixed: np.ndarray | None = None
    #: n×3 prescribed displacements of the fixed directions (static analysis), None: zero
    u0: np.ndarray | None = None
    #: supports that fix no axis: rollers on any face, symmetry planes, pins in holes
    #: (:mod:`rackstress.model.constraints`; static analysis only)
    constraints: list = field(default_factory=list)

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
        n = len(self.o)
        held = np.zeros(n, dtype=bool) if self.held is None else np.asarray(self.held)
        if held.dtype != bool or held.shape != (n,):
            raise SceneError(f"group '{self.name}': held must be {n} booleans (one per "
                             f"particle), got shape {held.shape} of {held.dtype}")
        fixed = np.zeros((n, 3), bool) if self.fixed is None else np.asarray(self.fixed)
        if fixed.dtype != bool or fixed.shape != (n, 3):
            raise SceneError(f"group '{self.name}': fixed must be n×3 booleans (the held "
                             f"directions of each particle), got shape {fixed.shape}")
        fixed = fixed | held[:, None]
        held = fixed.all(axis=1)          # held: every direction fixed
        self.held = np.ascontiguousarray(held)
        self.fixed = np.ascontiguousarray(fixed)
        if self.u0 is not None:
            u0 = np.asarray(self.u0, dtype=np.float64)
            if u0.shape != (n, 3) or not np.all(np.isfinite(u0)):
                raise SceneError(f"group '{self.name}': u0 must be n×3 finite displacements")
            self.u0 = np.ascontiguousarray(np.where(fixed, u0, 0.0))
        v0 = np.zeros((n, 3)) if self.v0 is None else np.asarray(self.v0, dtype=np.float64)
        if v0.shape == (3,):
            v0 = np.tile(v0, (n, 1))
        if v0.shape != (n, 3) or not np.all(np.isfinite(v0)):
            raise SceneError(f"group '{self.name}': v0 must be three finite numbers or one "
                             f"[vx, vy, vz] per particle, got shape {v0.shape}")
        # a held particle never moves: its velocity is zero from the start
        v0 = np.where(fixed, 0.0, v0)
        self.v0 = np.ascontiguousarray(v0)

    @property
    def n(self) -> int:
        return len(self.o)

    def mass(self, units) -> float:
        """Mass of one particle in the unit system ``units`` (the scene's): density × volume
        for a part with a material, else the paper's unit mass."""
        if self.material is None or self.volume is None:
            return 1.0
        return self.material.in_units(units)["density"] * self.volume


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
    from rackstress.lib.resources import BUILD_BYTES_PER_PARTICLE, require_memory

    n = nx * ny * nz
    require_memory(n * BUILD_BYTES_PER_PARTICLE,
                   f"a lattice of {nx} x {ny} x {nz} = {n:,} particles")
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    pts = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1) * float(spacing)
    return pts + np.asarray(origin, dtype=float)


# --------------------------------------------------------------------------- filled parts
#: Packings a part can be filled with: simple cubic, or hexagonal close packing (nearest
#: neighbours ``spacing`` apart in both; hcp holds √2 times as many particles per volume).
PACKINGS = ("cubic", "hcp")
#: The most particles one filled part may have: more is almost always a unit mistake (a mesh
#: in millimetres filled at spacing 1e-3), and would not fit in memory anyway.
MAX_PARTICLES = 10_000_000


def _axis(lo: float, hi: float, pitch: float, origin: float | None):
    """Grid coordinates along one axis covering [lo, hi]: centred in it, or through ``origin``."""
    ext = hi - lo
    if origin is None:
        n = max(1, int(round(ext / pitch)))
        first = lo + 0.5 * (ext - (n - 1) * pitch)
        return first + pitch * np.arange(n)
    k0 = math.ceil((lo - origin) / pitch - 1e-9)
    k1 = math.floor((hi - origin) / pitch + 1e-9)
    return origin + pitch * np.arange(k0, k1 + 1)


def lattice_points(lo, hi, spacing: float, packing: str = "cubic", origin=None, z_slice=None):
    """Lattice points covering the box [lo, hi], in id order: x fastest, then y, then z.

    ``cubic``: the simple-cubic grid of ``spacing``, centred in the box (or through ``origin``).
    ``hcp``: hexagonal close packing with nearest neighbours ``spacing`` apart: close-packed
    layers stacked along y (ABAB, layer distance spacing·√(2/3)); in a layer rows run along x
    (spacing apart), row distance spacing·√3/2 along z, every other row shifted by spacing/2;
    B layers shifted by (spacing/2, spacing·√3/6) in (x, z). Returns (points, shape) with
    ``shape = (nx, ny, nz)`` of the index grid; ``z_slice`` limits the z indices (chunks).
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    s = float(spacing)
    org = [None] * 3 if origin is None else [float(x) for x in origin]
    if packing == "cubic":
        xs, ys, zs = (_axis(lo[k], hi[k], s, org[k]) for k in range(3))
        shape = (len(xs), len(ys), len(zs))
        if z_slice is not None:
            zs = zs[z_slice]
        z, y, x = np.meshgrid(zs, ys, xs, indexing="ij")
        return np.column_stack([x.ravel(), y.ravel(), z.ravel()]), shape
    if packing != "hcp":
        raise SceneError(f"unknown packing '{packing}'; packings: {', '.join(PACKINGS)}")
    hy, hz = s * math.sqrt(2.0 / 3.0), s * math.sqrt(3.0) / 2.0
    # one extra column/row each side: shifted rows and layers reach half a pitch further
    xs = _axis(lo[0] - s, hi[0] + s, s, org[0])
    ys = _axis(lo[1], hi[1], hy, org[1])
    zs = _axis(lo[2] - hz, hi[2] + hz, hz, org[2])
    shape = (len(xs), len(ys), len(zs))
    kz = np.arange(len(zs))
    if z_slice is not None:
        kz = kz[z_slice]
    k, j, i = np.meshgrid(kz, np.arange(len(ys)), np.arange(len(xs)), indexing="ij")
    layer_b = (j % 2).astype(float)
    x = xs[i] + 0.5 * s * (k % 2) + 0.5 * s * layer_b
    y = ys[j]
    z = zs[k] + (s * math.sqrt(3.0) / 6.0) * layer_b
    return np.column_stack([x.ravel(), y.ravel(), z.ravel()]), shape


def fill(region, spacing: float, packing: str = "cubic", origin=None, name: str = "part",
         max_particles: int = MAX_PARTICLES, shift=None) -> np.ndarray:
    """Particle centres filling ``region`` (a solid region: mesh, box, sphere, … or their
    combination) on a lattice of ``spacing``, in id order (x fastest, then y, then z).

    ``shift`` (three fractions of the spacing) moves the lattice from its origin — the one
    given, or the one centred in the region's box — by ``shift`` × ``spacing``: the same part
    filled at another lattice offset (``rackstress run --offsets``).

    Every centre lies inside the region (its ``mask``); a cubic fill holds about
    volume/spacing³ particles, an hcp fill √2 times that. ``name`` (the mesh file or group)
    is named in errors.

    Raises
    ------
    SceneError
        for an unbounded region, a spacing larger than the part, a part that would exceed
        ``max_particles`` (usually a unit mistake), or a region no lattice point falls in.

    Example
    -------
    >>> from rackstress.model.regions import Box
    >>> len(fill(Box([0, 0, 0], [4, 2, 2]), 1.0))
    16
    """
    if packing not in PACKINGS:
        raise SceneError(f"{name}: unknown packing '{packing}'; packings: {', '.join(PACKINGS)}")
    s = float(spacing)
    if not (math.isfinite(s) and s > 0):
        raise SceneError(f"{name}: spacing must be a positive number, got {spacing!r}")
    b = region.bounds()
    if b is None:
        raise SceneError(f"{name}: a half-space or a list of ids has no inside to fill; fill a "
                         "bounded shape (mesh, box, sphere, cylinder) or intersect with one")
    lo, hi = (np.asarray(x, float) for x in b)
    ext = hi - lo
    if ext.min() < s:
        raise SceneError(
            f"{name}: spacing {s:g} is larger than the part, whose bounding box is "
            f"{np.round(ext, 6).tolist()} (smallest extent {ext.min():.6g}); a part needs at "
            "least two particles across its thinnest feature: use spacing ≤ "
            f"{ext.min() / 2:.6g}, or check the mesh's units (scale)")
    density = 1.0 if packing == "cubic" else math.sqrt(2.0)
    volume = getattr(region, "volume", None)
    # counted as logarithms: at a spacing of 1e-300 the count itself overflows a double
    log_box = float(np.sum(np.log10(ext) - math.log10(s))) + math.log10(density)
    log_est = (math.log10(volume) - 3 * math.log10(s) + math.log10(density)
               if volume and volume > 0 else log_box)
    if log_est > math.log10(max_particles) or log_box > math.log10(20 * max_particles):
        e = math.floor(log_est)
        about = f"{10 ** log_est:.3g}" if log_est < 300 else f"{10 ** (log_est - e):.3g}e+{e}"
        raise SceneError(
            f"{name}: filling it at spacing {s:g} would make about {about} particles "
            f"(bounding box {np.round(ext, 6).tolist()}), more than the {max_particles:,} a "
            "part may have: the spacing is too small for the part, or the mesh is in other "
            "units than intended: give a larger spacing, or scale (e.g. 0.001 for millimetres "
            "to metres)")
    if shift is not None:
        if origin is None:
            origin = [float(_axis(lo[k], hi[k], s, None)[0]) for k in range(3)]
        origin = np.asarray(origin, float) + s * np.asarray(shift, float)
    _, shape = lattice_points(lo, hi, s, packing, origin, z_slice=slice(0, 0))
    nx, ny, nz = shape
    per_slab = 2 * max(1, int(1_000_000 // max(1, nx * ny)))   # even: hcp parities line up
    out = []
    for k0 in range(0, nz, per_slab):
        k1 = min(nz, k0 + per_slab)
        pts, _ = lattice_points(lo, hi, s, packing, origin, z_slice=slice(k0, k1))
        out.append(pts[_slab_mask(region, pts, (nx, ny, k1 - k0), k0, s, packing)])
    o = np.concatenate(out) if out else np.zeros((0, 3))
    if not len(o):
        raise SceneError(f"{name}: no lattice point at spacing {s:g} falls inside the part; "
                         "use a smaller spacing")
    return o


def _slab_mask(region, pts, dims, k0: int, s: float, packing: str) -> np.ndarray:
    """Which of a slab's lattice points (z indices k0 …) lie in ``region``, asked as regular
    grids (:meth:`Region.grid_mask`): the cubic slab is one; an hcp slab is four, one per
    parity of layer (j) and row (k), each a rectangular grid of pitch (s, 2·hy, 2·hz)."""
    nx, ny, nk = dims
    if packing == "cubic":
        return region.grid_mask(pts[0], (s, s, s), dims)
    grid = pts.reshape(nk, ny, nx, 3)
    hy, hz = s * math.sqrt(2.0 / 3.0), s * math.sqrt(3.0) / 2.0
    mask = np.zeros((nk, ny, nx), dtype=bool)
    for pj in (0, 1):
        for pk in (0, 1):
            sub = grid[pk::2, pj::2, :]
            if not sub.size:
                continue
            m = region.grid_mask(sub[0, 0, 0], (s, 2 * hy, 2 * hz), (nx, sub.shape[1], sub.shape[0]))
            mask[pk::2, pj::2, :] = m.reshape(sub.shape[0], sub.shape[1], nx)
    return mask.ravel()


def union_positions(*blocks, tol: float = 1e-9) -> np.ndarray:
    """Positions of several parts in order; a particle coinciding (within ``tol`` times the
    extent) with an earlier one is dropped, so overlapping parts do not stack particles."""
    from scipy.spatial import cKDTree

    blocks = [np.asarray(b, float).reshape(-1, 3) for b in blocks if len(b)]
    if not blocks:
        return np.zeros((0, 3))
    out = [blocks[0]]
    for b in blocks[1:]:
        have = np.concatenate(out)
        scale = max(1.0, float(np.ptp(np.concatenate([have, b]), axis=0).max()))
        d, _ = cKDTree(have).query(b, distance_upper_bound=tol * scale)
        out.append(b[~np.isfinite(d)])
    return np.concatenate(out)
