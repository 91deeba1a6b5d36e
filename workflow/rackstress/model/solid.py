"""The elastic solid: a part with a material becomes the validated bind lattice.

A part filled on the simple-cubic lattice of spacing a is bound to its neighbours within 1.5·a
(the 6 nearest and 12 second neighbours, Eq. 16), only where the binding does not cross free
space (:class:`rackstress.model.operators.WithinInside`). Its coefficient comes from the
material (docs/calibration.md):

* Eq. 12's stiffness along a binding at rest is 2c (an acceleration per length, DESIGN §6), so
  one binding is a spring of k = 2·c·m between particles of mass m = ρ·a³;
* the lattice with equal first and second neighbour springs is isotropic in the continuum
  limit: C11 = 3k/a, C12 = C44 = k/a, hence λ = μ = k/a and ν = 1/4 (E = 2.5·k/a);
* so E = 5·c·ρ·a², and a material of Young's modulus E gets ``c = E / (5·ρ·a²)``
  (:func:`bind_coefficient`): the lattice's ν is 1/4 whatever the material's (the default,
  ``poisson = "lattice"``);
* with ``poisson = "material"`` the volumetric term (:mod:`rackstress.model.volume`) adds λ'
  to λ, so the bindings carry the material's shear modulus, μ = E/(2(1 + ν)) = k/a, and
  c = E / (4·(1 + ν)·ρ·a²) (:func:`rackstress.model.volume.coefficients`).

At a free face the second-neighbour bindings that would leave the part are missing, and the
face layer is softer than the bulk (a bar of N particles across is 2/(3N) too soft in tension).
:class:`Solid` gives every missing second-neighbour binding's half that lies inside the part
(the half-spacing skin between the outer particle centres and the surface) to its mirror image
about the face, so a bar of any N is as stiff as the continuum: measured in
docs/calibration.md, the cantilever's tip deflection agrees at spacings 2, 1 and 0.5 mm.

A wall is rarely a whole number of spacings thick: each boundary particle's cell is its own
share of the part (:func:`axis_fractions`, from the part's shape), and the bindings in a face
layer are weighted so the layer is as stiff as that share (:func:`fraction_weights`, derived
in docs/calibration.md "Walls of any thickness"): the cantilever's 10 mm at spacing 0.7
(14.3 layers) or 1.5 (6.7) bends as 10 mm, not as n·a.

Example
-------
>>> from rackstress.model.materials import material
>>> from rackstress.model.units import SYSTEMS
>>> round(bind_coefficient(material("aluminium"), SYSTEMS["mm-N-s"], 1.0) / 1e12, 4)
5.1852
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rackstress.errors import SceneError
from rackstress.model.operators import WithinInside, cache_of

#: E = LATTICE_E · k / a for the simple-cubic lattice with equal 1st/2nd-neighbour springs
#: alone (no volumetric term: ν = 1/4)
LATTICE_E = 2.5
#: the lattice's own Poisson's ratio without the volumetric term (C12 / (C11 + C12))
LATTICE_NU = 0.25
#: what a missing second-neighbour binding at a face gives the face-parallel nearest binding
#: along its projection: half of it lies inside the part (the half-spacing skin), and a
#: nearest binding carries twice a diagonal's C11 (k·n_x⁴·ℓ²: 1 against 1/2), so ½·½ = ¼
FACE_SHARE = 0.25
#: the last inside test of each live Solid (by id, ``operators.cache_of``): its pairs are
#: asked for several times per run
_INSIDE: dict = {}
#: the last boundary fractions of each live Solid (by id)
_FRACTIONS: dict = {}
#: the lattice test's answer for a group's own pairs, per live Solid (one entry: the last pairs)
_PAIRS: dict = {}
#: bisection steps finding a free face's distance along an axis (precision a / 2**steps:
#: 1e-12 spacings, so a face on the lattice's own half-cell reads ½ to a double's digits)
FACE_STEPS = 40
#: within this many spacings of 0 or ½ a free face is there (regions' closing tolerance)
FACE_SNAP = 1e-6
#: distinct binding weights of a solid at most: the plugin gives each its own bond type and
#: fix (engines/lammps/deck.py MAX_PAIR_TYPES)
WEIGHT_LEVELS = 16
#: bind reach of a solid, in spacings: the 18 neighbours of the cubic lattice (1 and √2)
REACH = 1.5


def bind_coefficient(material, units, spacing: float) -> float:
    """c of Eq. 12 making the cubic lattice of ``spacing`` as stiff as ``material`` in
    tension: c = E / (5·ρ·a²) in the scene's ``units`` (k = 2·c·m, m = ρ·a³, E = 2.5·k/a), the
    lattice's own ν = 1/4. With the volumetric term (``poisson = "material"``) the bindings
    carry the shear modulus instead: :func:`rackstress.model.volume.coefficients`."""
    props = material.in_units(units)
    a = float(spacing)
    return props["E"] / (2.0 * LATTICE_E * props["density"] * a * a)


@dataclass(frozen=True)
class Solid(WithinInside):
    """within(1.5·a) inside the part, with the face compensation of the module doc.

    ``region`` None: the part is convex (a box, a lattice block), so no binding between two of
    its particles crosses free space and none is tested. ``spacing``: the lattice's a.
    """

    spacing: float = 1.0
    material: str = ""
    #: the part's own shape (also for a convex one, whose ``region`` is None): the boundary
    #: cells' fractions (:func:`axis_fractions`) come from it; None: every cell is whole
    part: object = field(default=None, compare=False, repr=False)

    def label(self) -> str:
        return (f"solid {self.material} within({self.d:g}) inside the part magnitude "
                f"{self.c:g}")

    def inside(self, a, b):
        """WithinInside's test, remembered: a run asks for the same pairs several times (the
        memory estimate, the deck, the solver, the engine's check, the load-path warning)."""
        a, b = np.asarray(a, float).reshape(-1, 3), np.asarray(b, float).reshape(-1, 3)
        if self.region is None:
            return np.ones(len(a), dtype=bool)
        import hashlib

        key = hashlib.sha1(a.tobytes() + b.tobytes()).hexdigest()
        cache = cache_of(_INSIDE, self)
        if key not in cache:
            cache.clear()
            cache[key] = super().inside(a, b)
        return cache[key]

    def inside_pairs(self, points, i, j, name: str = "part") -> np.ndarray:
        """:meth:`inside` for a group's own pairs (WithinInside's lattice test): every pair
        of a convex part (``region`` None) is inside, none is tested."""
        if self.region is None:
            return np.ones(len(i), dtype=bool)
        import hashlib

        h = hashlib.sha1(np.ascontiguousarray(points, dtype=float).tobytes())
        for x in (i, j):
            h.update(np.ascontiguousarray(x, dtype=np.int64).tobytes())
        key = h.hexdigest()
        # remembered like inside(): the scene's memory estimate, the deck and the static solver
        # each ask for the same pairs (3 × 3.4 s at 1,000,000 particles)
        cache = cache_of(_PAIRS, self)
        if key not in cache:
            cache.clear()
            cache[key] = super().inside_pairs(points, i, j, name=name)
        return cache[key]

    def weights(self, o: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Per-binding factor on c: 1, plus ½ for each missing second-neighbour binding whose
        mirror about a free face this binding is (module doc), times the boundary cells'
        thickness factor (:func:`fraction_weights`) when the part's shape is known."""
        w = face_weights(o, i, j, self.spacing)
        if self.part is not None:
            w = levels(w * fraction_weights(o, i, j, self.fractions(o), self.spacing, w))
        return w

    def fractions(self, o: np.ndarray) -> np.ndarray:
        """:func:`axis_fractions` of the particles ``o`` in ``part`` (remembered per positions)."""
        import hashlib

        o = np.ascontiguousarray(o, dtype=float)
        key = ("fractions", hashlib.sha1(o.tobytes()).hexdigest())
        cache = cache_of(_FRACTIONS, self)
        if key not in cache:
            cache.clear()
            cache[key] = axis_fractions(o, self.spacing, self.part)
        return cache[key]


def face_weights(o: np.ndarray, i: np.ndarray, j: np.ndarray, spacing: float) -> np.ndarray:
    """The face compensation of :class:`Solid` for the directed pairs (i, j) of one group on
    a cubic lattice of ``spacing`` (positions ``o``). A binding present in both directions gets
    the same factor both ways (the rule is symmetric in i and j)."""
    a = float(spacing)
    g = _sites(o, a, "face compensation")
    span = g.max(axis=0) + 3
    key = lambda x: (x[..., 0] + 1) + span[0] * ((x[..., 1] + 1) + span[1] * (x[..., 2] + 1))
    d = g[j] - g[i]
    pair_key = key(g[i]) * 32 + _dir_index(d)
    order = np.argsort(pair_key)
    sorted_keys = pair_key[order]
    w = np.ones(len(i))
    n = len(o)
    # the directions each particle has bindings in (a missing one: no partner, or crosses out)
    dir_idx = _dir_index(d)
    has = {}
    for dd in _DIAGONALS + _AXES:
        has[dd] = np.zeros(n, bool)
        has[dd][i[dir_idx == _dir_index(dd)[0]]] = True

    def lookup(src, dvec):
        q = key(g[src]) * 32 + _dir_index(np.tile(dvec, (len(src), 1)))
        pos = np.searchsorted(sorted_keys, q)
        pos = np.minimum(pos, len(sorted_keys) - 1)
        ok = sorted_keys[pos] == q
        return order[pos], ok

    for dd in _DIAGONALS:
        missing = np.flatnonzero(~has[dd])
        if not len(missing):
            continue
        dv = np.asarray(dd)
        axes = np.flatnonzero(dv)
        # project onto the face: zero the components along which the particle is on a face
        # (no axial neighbour there); a face-parallel binding remains only across one face
        keep = np.ones((len(missing), 3), dtype=np.int64)
        for ax in axes:
            e = tuple(int(dv[ax]) if k == ax else 0 for k in range(3))
            keep[~has[e][missing], ax] = 0
        proj = keep * dv
        one = np.abs(proj).sum(axis=1) == 1
        src, row_of = missing[one], proj[one]
        for row in np.unique(row_of, axis=0):
            s = src[np.all(row_of == row, axis=1)]
            idx, ok = lookup(s, row)
            np.add.at(w, idx[ok], FACE_SHARE)
            back, ok2 = lookup(j[idx[ok]], -row)     # the same binding from its other end
            np.add.at(w, back[ok2], FACE_SHARE)
    return w


_AXES = [tuple(int(k == ax) * s for k in range(3)) for ax in range(3) for s in (1, -1)]
_DIAGONALS = [d for d in ((x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1))
              if sum(map(abs, d)) == 2]


def _sites(o: np.ndarray, a: float, what: str) -> np.ndarray:
    """Integer lattice sites of the particles ``o`` (n, 3) on the cubic lattice of spacing
    ``a`` from their lowest corner; a SceneError naming ``what`` needs it if they are not."""
    lo = o.min(axis=0)
    g = np.rint((o - lo) / a).astype(np.int64)
    if np.abs(g * a + lo - o).max() > 1e-6 * a:
        raise SceneError(f"a solid's {what}: its particles must sit on one cubic lattice "
                         "(packing = \"cubic\")")
    return g


def _dir_index(d) -> np.ndarray:
    d = np.asarray(d, dtype=np.int64).reshape(-1, 3)
    return (d[:, 0] + 1) * 9 + (d[:, 1] + 1) * 3 + (d[:, 2] + 1)


def axis_fractions(o: np.ndarray, spacing: float, part) -> np.ndarray:
    """Each particle's cell extent along x, y and z in spacings (n, 3): what its cell of the
    part really is (docs/calibration.md "Walls of any thickness").

    A particle owns the part's points nearer to it than to any other particle. Along an axis
    on which both lattice neighbours are particles that is ±a/2: φ = 1. Where a neighbour is
    missing (its site is outside the part) the cell reaches the part's surface, at the distance
    t ∈ [0, a) along that axis found by bisection on ``part.mask``; so φ = (e⁻ + e⁺)/a with
    e = a/2 or t on each side. A wall of thickness t_w filled with n layers then adds up to
    Σ φ·a = t_w whatever t_w/a is, where the lattice alone represents n·a.
    """
    from rackstress.lib.cells import lattice_sides

    a = float(spacing)
    o = np.asarray(o, dtype=float)
    _sites(o, a, "boundary cells")              # on one cubic lattice, or a SceneError
    sides = lattice_sides(o, a)
    ext = np.full((len(o), 3), a)
    # the six directions' free sides bisected together: one inside test per step for all of
    # them, 40 calls where there were 240 (a mesh's test: 2.1× faster on four real parts)
    rows, steps, cols = [], [], []
    for ax in range(3):
        for sgn in (1, -1):
            free = np.flatnonzero(~sides[:, ax, (sgn + 1) // 2])
            step = np.zeros(3)
            step[ax] = sgn * a
            rows.append(free)
            steps.append(np.broadcast_to(step, (len(free), 3)))
            cols.append(np.full(len(free), ax))
    free, step, axis = np.concatenate(rows), np.concatenate(steps), np.concatenate(cols)
    if len(free):
        lo_t, hi_t = np.zeros(len(free)), np.ones(len(free))
        for _ in range(FACE_STEPS):            # inside at lo_t, outside at hi_t (in spacings)
            mid = 0.5 * (lo_t + hi_t)
            ins = np.asarray(part.mask(o[free] + mid[:, None] * step), dtype=bool)
            lo_t = np.where(ins, mid, lo_t)
            hi_t = np.where(ins, hi_t, mid)
        t = 0.5 * (lo_t + hi_t)
        # a face on the particle or on its half cell reads there exactly: the shapes'
        # masks are closed up to regions.TOL × their size, which bisection finds too
        t = np.where(np.abs(t - 0.5) < FACE_SNAP, 0.5, np.where(t < FACE_SNAP, 0.0, t))
        np.add.at(ext, (free, axis), (t - 0.5) * a)
    return ext / a


def fraction_weights(o: np.ndarray, i: np.ndarray, j: np.ndarray, phi: np.ndarray,
                     spacing: float, base: np.ndarray | None = None) -> np.ndarray:
    """The factor on each binding (i, j) that makes a boundary layer as stiff as the slab of
    the part it stands for (docs/calibration.md "Walls of any thickness").

    For a free face normal to axis n, with the face compensation, the face layer of a cubic
    lattice carries 1.5 k·a² of membrane stiffness per particle (energy/ε²): 0.75 from its
    nearest bindings in the face, 0.5 from its diagonals in the face and 0.25 from its half
    of the diagonals to the layer below. Those to the layer below span a gap that is all
    material: they keep their weight. The layer's cell is φ_n·a thick, so the bindings in it
    carry 1.5·φ_n − 0.25: its diagonals take φ_n (then its in-face shear, all theirs, is
    exact too) and its nearest bindings h = (4·φ_n − 1)/3. A binding lying in the face of
    several axes (an edge) takes the product; φ_n of a pair is its ends' mean.

    In a sheet one layer thick (no neighbour on either side along an axis m) a face is a row:
    it has no diagonals in it, and its nearest bindings carry the face compensation of both
    the sheet's faces and the row's, ``base`` (:func:`face_weights`; 2.5 on a straight edge).
    The row's energy is then h·base + 0.5 (its diagonals to the next row) against
    φ_n·(base + 0.5), so **h = φ_n − (1 − φ_n)·0.5/base** — (6·φ_n − 1)/5 on a straight edge,
    where the 3D rule's (4·φ_n − 1)/3 left a half-cell edge 11 % too soft and its stress read
    10 % low (measured: a one-layer plate in uniform tension, docs/calibration.md).
    """
    a = float(spacing)
    d = np.rint((o[j] - o[i]) / a).astype(np.int64)
    ones = (d != 0).sum(axis=1)
    w = np.ones(len(i))
    if base is not None:            # no neighbour on either side along an axis: a sheet
        from rackstress.lib.cells import lattice_sides

        lone = ~lattice_sides(o, a).any(axis=2)
    else:
        lone = None
    for ax in range(3):
        f = 0.5 * (phi[i, ax] + phi[j, ax])
        along = d[:, ax] == 0
        nearest = np.maximum((4.0 * f - 1.0) / 3.0, 0.25 * f)
        if lone is not None:
            # a nearest binding along t in the face of ax, both ends in a sheet one layer
            # thick along the third axis m: the row's own rule
            t = np.argmax(np.abs(d), axis=1)
            m = 3 - ax - t
            row = along & (ones == 1) & (t != ax) & (m >= 0) & (m <= 2)
            mm = np.clip(m, 0, 2)
            row &= lone[i, mm] & lone[j, mm]
            if row.any():
                b = np.maximum(np.asarray(base, float), 1e-12)
                nearest = np.where(row, np.maximum(f - (1.0 - f) * 0.5 / b, 0.25 * f), nearest)
        w = np.where(along, w * np.where(ones == 1, nearest, f), w)
    return w


def _kmeans_table_numpy(S1, S2, C, m: int, n: int) -> np.ndarray:
    """The dynamic programme of :func:`levels`: D[q, b], the least weighted sum of squares of
    the sorted values [0, b) in q clusters, and arg[q, b], where its last cluster starts
    (prefix sums S1, S2, C of value·count, value²·count, count); returns arg."""
    def cost(a, b):        # clusters rv[a:b] (arrays a, scalar b): weighted sum of squares
        s1, s2, c = S1[b] - S1[a], S2[b] - S2[a], C[b] - C[a]
        return s2 - s1 * s1 / c

    D = np.full((m + 1, n + 1), np.inf)
    arg = np.zeros((m + 1, n + 1), dtype=np.int64)
    D[0, 0] = 0.0
    for q in range(1, m + 1):
        for b in range(q, n + 1):
            a = np.arange(q - 1, b)
            tot = D[q - 1, a] + cost(a, b)
            t = int(np.argmin(tot))
            D[q, b], arg[q, b] = tot[t], a[t]
    return arg


def _kmeans_table_compiled():
    """:func:`_kmeans_table_numpy` compiled (numba), the same operations in the same order
    (the same table to the bit): 0.05 s instead of 1.4 s for 3,600 distinct weights (the
    SO-ARM upper arm at 1.9 mm); None without numba."""
    from rackstress.lib.jit import numba_or_none

    nb = numba_or_none()
    if nb is None:
        return None

    @nb.njit(cache=True, nogil=True)
    def table(S1, S2, C, m, n):
        D = np.full((m + 1, n + 1), np.inf)
        arg = np.zeros((m + 1, n + 1), dtype=np.int64)
        D[0, 0] = 0.0
        for q in range(1, m + 1):
            for b in range(q, n + 1):
                best, at = np.inf, q - 1
                for a in range(q - 1, b):
                    s1, s2, c = S1[b] - S1[a], S2[b] - S2[a], C[b] - C[a]
                    t = D[q - 1, a] + (s2 - s1 * s1 / c)
                    if t < best:
                        best, at = t, a
                D[q, b], arg[q, b] = best, at
        return arg

    return table


#: the compiled table, built on first use
_KMEANS = None


def _kmeans_table(S1, S2, C, m: int, n: int) -> np.ndarray:
    global _KMEANS
    if _KMEANS is None:
        _KMEANS = _kmeans_table_compiled() or _kmeans_table_numpy
    return _KMEANS(S1, S2, C, int(m), int(n))


def levels(w: np.ndarray, k: int = WEIGHT_LEVELS) -> np.ndarray:
    """``w`` with at most ``k`` distinct values: the most common value (the interior's 1) kept
    exact, the others (first rounded to 4 significant digits) split into k − 1 clusters by
    optimal 1D k-means (dynamic programming over the sorted values, weighted by their counts),
    each replaced by its cluster's weighted mean so each cluster's summed stiffness is kept.
    Unchanged when it has ``k`` values or fewer."""
    vals, inv, cnt = np.unique(w, return_inverse=True, return_counts=True)
    if len(vals) <= k:
        return w
    mode = int(np.argmax(cnt))
    rest = np.flatnonzero(np.arange(len(vals)) != mode)
    r = np.asarray([float(f"{x:.4g}") for x in vals[rest]])
    rv, rinv = np.unique(r, return_inverse=True)
    rc = np.bincount(rinv, weights=cnt[rest])
    n, m = len(rv), min(k - 1, len(rv))
    S1 = np.r_[0.0, np.cumsum(rc * rv)]
    S2 = np.r_[0.0, np.cumsum(rc * rv * rv)]
    C = np.r_[0.0, np.cumsum(rc)]
    arg = _kmeans_table(S1, S2, C, m, n)
    label, b = np.empty(n, dtype=np.int64), n
    for q in range(m, 0, -1):
        a = arg[q, b]
        label[a:b] = q - 1
        b = a
    centre = np.bincount(label, weights=rc * rv) / np.bincount(label, weights=rc)
    out = vals.copy()
    out[rest] = centre[label[rinv]]
    return out[inv.reshape(-1)]
