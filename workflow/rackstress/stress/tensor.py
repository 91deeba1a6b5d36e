"""Stress per particle from the bindings' forces, in the scene's units (docs/stress.md).

The bindings of a part are its material: bind (Eq. 12) pulls particle i towards j with the
acceleration c·(1 − L0²/d²)·d, d = p_j − p_i, so with the particle's mass m_i (density ×
volume, ``Group.mass``) the force is f_ij = k_ij·(1 − L0²/d²)·d with k_ij = m_i·c. The
particle's virial is

    W_i = ½ Σ_j d_ij ⊗ f_ij                                   (Irving–Kirkwood, per-atom split)

(force × length; each binding of i is counted once, on i, so that a pair bound both ways gets
½ of its virial on each end) and the plain virial stress is W_i / V_i. That is exact in the mean
— Σ_i W_i = Σ_i V_i σ_i for any equilibrium — and exact per particle inside a uniformly strained
lattice, but a particle on a free surface has no bindings on the outside, so its W_i misses the
share those would carry: on a simple cubic lattice (within 1.5 spacings) a face particle reports
85 % of the stress along its face, an edge particle less. That is where a beam's bending stress
peaks.

**Surface completion** (the default). Linearized, a binding of stiffness k and direction n
answers a uniform strain ε with W = ½ k L0² (n·ε·n) n⊗n, so W_i = A_i ε in Voigt form, with
the particle's *binding moment* A_i = ½ Σ_j k_ij L0² m mᵀ, m = (n_x², n_y², n_z², n_y n_z,
n_x n_z, n_x n_y). Inside the part A_i/V_i is the lattice's stiffness C (for the simple cubic
lattice C11 = 3k/a, C12 = C44 = k/a). The completed stress σ_i = C · A_i⁺ · W_i reads the strain
the particle's own bindings carry (A_i⁺ W_i) and answers it with the part's interior stiffness:
equal to W_i / V_i wherever the particle has every binding, and exact on the surface too for
a uniform or linearly varying (bending) strain. C is the mean A_i/V_i of the part's fully
bound particles (the most bindings); a planar part's A is of rank 3 and the pseudo-inverse keeps
its stress in the plane.

**The cells' own moment** (``continuum``; the default ``patch`` route reads it at the surface). The
virial puts each cell's force at its particle: a cell's own first moment ∫(x − x_i) σ dV =
V·(a²/12)·∇σ (a cube of side a, σ linear) is not there, and equilibrium makes the layers carry
it instead — a member N layers thick in bending reads N²/(N² − 1) × M·z/I (Σ z_l² over the
layers is (N³ − N)·a²/12 against the continuum's N³·a²/12): +12.5 % at N = 3, +1 % at N = 10.
The missing moments are a moment density μ = (a²/12)∇σ inside the part, zero outside; its
jump at a free face is a surface force, carried by the face layer: that layer's virial stress
is too large by μ·n/a = (a/12)·(n·∇)σ for each free face (outward normal n) of the particle.
:func:`surface_moment` subtracts exactly that, with ∇σ fitted by least squares over the
particle's bindings: nothing changes inside the part or under uniform stress; a thin member's
bending stress comes out within a few per cent of beam theory (docs/stress.md, measured).

Everything is vectorized over bindings with :func:`numpy.bincount`; nothing is per particle in
Python.

Example
-------
>>> import numpy as np
>>> o = np.array([[0.0, 0, 0], [1.0, 0, 0]])
>>> p = np.array([[0.0, 0, 0], [1.1, 0, 0]])           # stretched 10 %
>>> i, j = np.array([0, 1]), np.array([1, 0])
>>> W = virial(p, i, j, np.array([2.0, 2.0]), np.array([1.0, 1.0]))
>>> round(float(W[0, 0]), 6)                           # ½ · 1.1 · 2·(1 − 1/1.21)·1.1
0.21
"""
from __future__ import annotations

import numpy as np

from rackstress.lib.cells import lattice_neighbours, lattice_sides

#: Voigt order of the internal 6-vectors (tensor components, not engineering shears)
VOIGT = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
#: Order of the six components of the ``stress`` measure: ParaView's symmetric-tensor order
#: (XX, YY, ZZ, XY, YZ, XZ), so ``vtk/run.pvd``'s ``stress`` array is a tensor there.
TENSOR_ORDER = ("xx", "yy", "zz", "xy", "yz", "xz")
_TO_TENSOR = [0, 1, 2, 5, 3, 4]          # internal Voigt → TENSOR_ORDER
#: A mode of A_i counts as absent below this fraction of A_i's largest (planar, collinear)
RANK_TOL = 1e-9


def _components(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(a ⊗ b + b ⊗ a)/2 of row vectors in internal Voigt order (n, 6)."""
    return np.stack([0.5 * (a[:, r] * b[:, c] + a[:, c] * b[:, r]) for r, c in VOIGT], axis=1)


def virial(p: np.ndarray, i: np.ndarray, j: np.ndarray, k: np.ndarray, L0sq: np.ndarray,
           n: int | None = None, gather=None) -> np.ndarray:
    """W_i = ½ Σ_j d ⊗ f of bindings (i on j) at positions ``p``: (n, 6), internal Voigt order.

    ``k`` is each binding's force coefficient m_i·c (force per length), ``L0sq`` its rest length
    squared; f = k·(1 − L0²/d²)·d (Eq. 12 times the mass), d = p_j − p_i, so d ⊗ f is
    k·(1 − L0²/d²)·d ⊗ d. ``gather``: :func:`incidence` of ``i`` (built once, reused per frame).
    """
    n = len(p) if n is None else n
    d = p[j] - p[i]
    return virial_of(d, np.einsum("ij,ij->i", d, d), k, L0sq,
                     incidence(i, n) if gather is None else gather)


def virial_of(d, d2, k, L0sq, gather) -> np.ndarray:
    """:func:`virial` from the bindings' vectors d and squared lengths d2 (two bound particles
    that coincide — a part that did not settle, collapsed — give a non-finite stress, not a
    NumPy warning on the terminal)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = 0.5 * k * (1.0 - L0sq / d2)
        dd = np.empty((len(d), 6))
        for c, (r, q) in enumerate(VOIGT):
            np.multiply(d[:, r], d[:, q], out=dd[:, c])
        dd *= s[:, None]
    return np.asarray(gather @ dd)


def incidence(i: np.ndarray, n: int):
    """The sparse n × m matrix summing per-binding rows onto their particle i (one C pass)."""
    from scipy.sparse import csr_matrix

    m = len(i)
    return csr_matrix((np.ones(m), (np.asarray(i), np.arange(m))), shape=(n, m))


def volume_virial(p: np.ndarray, terms) -> np.ndarray:
    """W_i of a material's volumetric term (n, 6, internal Voigt order; ``terms`` a
    :class:`rackstress.model.volume.VolumeTerms` whose κ are energies, m·κ): each particle's own
    terms' Σ s·d ⊗ d/‖d‖ (:meth:`rackstress.model.volume.Volume.virial`, derived in
    docs/calibration.md "The stress"). Added to the bindings' virial, it makes the stress the
    material's: under a uniform strain V_i·λ'·tr ε·I inside the part."""
    from rackstress.model.volume import Volume

    return Volume.virial(p, terms, np.ones(terms.n))


def binding_moment(o: np.ndarray, i: np.ndarray, j: np.ndarray, k: np.ndarray,
                   n: int | None = None) -> np.ndarray:
    """A_i = ½ Σ_j k L0² m mᵀ (n, 6, 6) at the original positions ``o`` (module docstring)."""
    n = len(o) if n is None else n
    d = o[j] - o[i]
    m = np.stack([d[:, r] * d[:, c] for r, c in VOIGT], axis=1)   # L0² n_r n_c
    L0sq = np.einsum("ij,ij->i", d, d)
    w = 0.5 * k / L0sq
    A = np.empty((n, 6, 6))
    for r in range(6):
        for c in range(r, 6):
            A[:, r, c] = np.bincount(i, weights=w * m[:, r] * m[:, c], minlength=n)
            A[:, c, r] = A[:, r, c]
    return A


def completion(A: np.ndarray, volume: np.ndarray, parts) -> np.ndarray:
    """The map W_i → σ_i of every particle, (n, 6, 6): C_part · A_i⁺ (module docstring).

    ``parts`` are index arrays; a particle of no part, or with no bindings, maps to NaN.
    """
    n = len(A)
    out = np.full((n, 6, 6), np.nan)
    lam, vec = np.linalg.eigh(A)
    top = lam[:, -1:]
    keep = lam > RANK_TOL * np.maximum(top, np.finfo(float).tiny)
    inv = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
    Apinv = np.einsum("nik,nk,njk->nij", vec, inv, vec)
    for idx in parts:
        idx = np.asarray(idx)
        bound = idx[top[idx, 0] > 0] if len(idx) else idx
        if not len(bound):
            continue
        # the fully bound particles: the largest binding moment per volume (every binding)
        tr = _trace(A[bound]) / volume[bound]
        full = bound[tr >= (1 - 1e-6) * tr.max()]
        C = (A[full] / volume[full][:, None, None]).mean(axis=0)
        out[bound] = C[None] @ Apinv[bound]
    return out


def surface_moment(o: np.ndarray, i: np.ndarray, j: np.ndarray, L0sq: np.ndarray,
                   n: int | None = None):
    """The per-binding weights w of the cells' own moment (module docstring): the correction
    δ_i = Σ_j w_ij (σ_j − σ_i) = (a/12)·Σ_faces (n·∇)σ, ∇σ by least squares over the bindings
    (Σ d dᵀ)⁻¹ Σ d (σ_j − σ_i). The free faces of a particle are the axes of the cubic lattice
    along which it has no nearest-neighbour binding (a particle with none: no correction).
    Returns w (m,), at the original positions ``o``."""
    n = len(o) if n is None else n
    i, j = np.asarray(i), np.asarray(j)
    d = o[j] - o[i]
    M = np.zeros((n, 3, 3))
    for r in range(3):
        for c in range(r, 3):
            M[:, r, c] = np.bincount(i, weights=d[:, r] * d[:, c], minlength=n)
            M[:, c, r] = M[:, r, c]
    a2 = np.full(n, np.inf)
    np.minimum.at(a2, i, L0sq)
    a = np.sqrt(a2[i])                               # the particle's spacing, per binding
    axial = np.abs(L0sq - a2[i]) <= 1e-6 * a2[i]
    u = d / a[:, None]
    ax = np.argmax(np.abs(u), axis=1)
    unit = axial & (np.abs(np.abs(u[np.arange(len(u)), ax]) - 1.0) <= 1e-6)
    side = ax * 2 + (u[np.arange(len(u)), ax] < 0)
    present = np.zeros((n, 6), dtype=bool)
    present[i[unit], side[unit]] = True
    normal = np.zeros((n, 3))                        # Σ of the free faces' outward normals
    for k in range(6):
        normal[~present[:, k], k // 2] += -1.0 if k % 2 else 1.0
    normal[~present.any(axis=1)] = 0.0               # no lattice neighbours: not a lattice site
    ok = np.linalg.matrix_rank(M) == 3
    v = np.zeros((n, 3))
    v[ok] = np.linalg.solve(M[ok], normal[ok][:, :, None])[:, :, 0]   # M symmetric
    v *= (np.sqrt(np.where(np.isfinite(a2), a2, 0.0)) / 12.0)[:, None]
    return np.einsum("ij,ij->i", v[i], d)


def moment_corrected(s: np.ndarray, i: np.ndarray, j: np.ndarray, w: np.ndarray,
                     gather) -> np.ndarray:
    """σ − δ: the virial stresses ``s`` (n, 6) with the cells' own moment restored
    (:func:`surface_moment`'s weights ``w``; ``gather`` = :func:`incidence` of i)."""
    return s - np.asarray(gather @ (w[:, None] * (s[j] - s[i])))


def _trace(A: np.ndarray) -> np.ndarray:
    return np.einsum("nii->n", A)


def to_tensor(s: np.ndarray) -> np.ndarray:
    """Internal Voigt (…, 6) → (…, 3, 3) symmetric tensors."""
    t = np.empty(s.shape[:-1] + (3, 3))
    for c, (r, q) in enumerate(VOIGT):
        t[..., r, q] = s[..., c]
        t[..., q, r] = s[..., c]
    return t


def von_mises(s: np.ndarray) -> np.ndarray:
    """σ_vm = √(½Σ(σ_ii − σ_jj)² + 3Σσ_ij²) of internal-Voigt stresses (…, 6)."""
    xx, yy, zz, yz, xz, xy = np.moveaxis(s, -1, 0)
    return np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2)
                   + 3.0 * (xy ** 2 + xz ** 2 + yz ** 2))


def principal(s: np.ndarray) -> np.ndarray:
    """The three principal stresses, largest first (…, 3); NaN rows stay NaN."""
    t = to_tensor(s)
    bad = ~np.isfinite(t).all(axis=(-1, -2))
    t[bad] = 0.0
    ev = np.linalg.eigvalsh(t)[..., ::-1]
    ev[bad] = np.nan
    return ev


def hooke(E_gl: np.ndarray, E: float, nu: float) -> np.ndarray:
    """σ = λ tr(ε) I + 2μ ε of strain tensors (…, 3, 3) → internal Voigt (…, 6): the material
    route (isotropic E, ν), for comparison with the bindings' stress."""
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    tr = np.trace(E_gl, axis1=-2, axis2=-1)
    s = 2 * mu * E_gl + lam * tr[..., None, None] * np.eye(3)
    return np.stack([s[..., r, c] for r, c in VOIGT], axis=-1)


def stress(p, bindings, W2S=None, volume=None, W=None) -> np.ndarray:
    """Stress (n, 6, internal Voigt) of every particle at positions ``p``.

    ``bindings`` = (i, j, k, L0sq); ``W2S`` the completion maps (:func:`completion`), else the
    plain virial stress W_i / ``volume``; ``W``: the virial, if computed already.
    """
    if W is None:
        i, j, k, L0sq = bindings
        W = virial(p, i, j, k, L0sq, len(p))
    if W2S is None:
        # a particle of no volume (one the measure leaves out: its row is NaN'd after)
        with np.errstate(divide="ignore", invalid="ignore"):
            return W / np.asarray(volume, float)[:, None]
    return np.einsum("nij,nj->ni", W2S, W)


def to_output(s: np.ndarray) -> np.ndarray:
    """Internal Voigt → the ``stress`` measure's component order (:data:`TENSOR_ORDER`)."""
    return s[..., _TO_TENSOR]


# ----------------------------------------------------------------------------- recovery
#: patch recovery: the neighbours within this many spacings enter a particle's fit. Measured
#: (docs/stress.md): 2.5 reads the C-frame's governing stress at 1.006 / 1.003 of FEA at 2 / 1
#: mm and beams' face fibres within 4 %; 1.5 (the bindings' own reach) 1.018 / 1.026 and a
#: 3-layer beam's +4.2 %, a 6-layer one's −10.5 %; at a hole of radius 4 spacings 2.5 reads
#: 0.55 of FEA, 1.5 0.70 (both resolution-limited)
PATCH_RADIUS = 2.5


def free_faces(o: np.ndarray, spacing: float, side: np.ndarray | None = None) -> np.ndarray:
    """Each particle's free faces on its cubic lattice (n, 3): per axis −1 or +1 where the
    lattice neighbour on that side is missing (the cell reaches the surface there), 0 where
    both are particles (or both missing: a wall one particle thick). ``side``: the particles'
    :func:`~rackstress.lib.cells.lattice_sides`, where the caller has them."""
    side = lattice_sides(o, spacing) if side is None else side
    return (~side[:, :, 1]).astype(float) - (~side[:, :, 0]).astype(float)


def recovery_points(o: np.ndarray, spacing: float, faces: np.ndarray | None = None,
                    reach: np.ndarray | None = None) -> np.ndarray:
    """Where a particle's recovered stress is read (n, 3): an interior particle at its centre;
    a particle on the surface at the surface point of its cell — half a spacing out along each
    free face (``faces``, :func:`free_faces`), or ``reach`` (n, 3: the cell's own extent to
    the surface, spacings) where the part's shape is known — so that a face particle reads
    the stress on the face, where an edge or a fillet puts its peak."""
    faces = free_faces(o, spacing) if faces is None else faces
    r = np.full(faces.shape, 0.5) if reach is None else np.asarray(reach, float)
    return np.asarray(o, float) + faces * r * float(spacing)


def patch_recover(o: np.ndarray, s: np.ndarray, spacing: float, points: np.ndarray,
                  mask: np.ndarray | None = None, degree: int = 1,
                  radius: float = PATCH_RADIUS, pairs=None, return_ok: bool = False):
    """Patch recovery of per-particle stresses ``s`` (n, c): around each particle a least-
    squares polynomial (``degree`` 1: 4 terms; 2: 10) of the stresses of the particles within
    ``radius`` spacings (``mask``: only those may enter a fit, e.g. one part), evaluated at its
    ``points`` (n, 3) — superconvergent patch recovery's fit, on the lattice's particles
    instead of Gauss points. A linear field is recovered exactly wherever the patch spans
    three dimensions (a particle whose patch is degenerate keeps its own value).

    >>> g = np.array([[x, y, z] for x in range(6) for y in range(4) for z in range(4)], float)
    >>> s = (2.0 + 3.0 * g[:, 0])[:, None]                   # σ linear along x
    >>> pts = recovery_points(g, 1.0)
    >>> r = patch_recover(g, s, 1.0, pts)
    >>> bool(np.allclose(r[:, 0], 2.0 + 3.0 * pts[:, 0]))     # the face x = 5.5 reads 18.5
    True
    """
    from scipy.spatial import cKDTree

    o = np.asarray(o, float)
    s = np.asarray(s, float)
    n, a = len(o), float(spacing)
    mask = np.ones(n, bool) if mask is None else np.asarray(mask, bool)
    if pairs is None:
        tree = cKDTree(o)
        pr = tree.query_pairs(radius * a * (1 + 1e-9), output_type="ndarray")
        i = np.r_[pr[:, 0], pr[:, 1], np.arange(n)]
        j = np.r_[pr[:, 1], pr[:, 0], np.arange(n)]
    else:
        i, j = pairs
    keep = mask[j] & mask[i] & np.isfinite(s[j]).all(axis=1)
    i, j = i[keep], j[keep]
    d = (o[j] - o[i]) / a
    terms = [np.ones(len(i)), d[:, 0], d[:, 1], d[:, 2]]
    if degree >= 2:
        terms += [d[:, 0] ** 2, d[:, 1] ** 2, d[:, 2] ** 2, d[:, 0] * d[:, 1],
                  d[:, 0] * d[:, 2], d[:, 1] * d[:, 2]]
    phi = np.stack(terms, axis=1)                            # pairs × m
    m = phi.shape[1]
    A = np.zeros((n, m, m))
    for r in range(m):
        for c in range(r, m):
            A[:, r, c] = np.bincount(i, weights=phi[:, r] * phi[:, c], minlength=n)
            A[:, c, r] = A[:, r, c]
    B = np.zeros((n, m, s.shape[1]))
    for r in range(m):
        for c in range(s.shape[1]):
            B[:, r, c] = np.bincount(i, weights=phi[:, r] * s[j, c], minlength=n)
    out = s.copy()
    scale = np.maximum(np.einsum("nii->n", A), 1e-300)
    lam = np.linalg.eigvalsh(A)
    cond_ok = lam[:, 0] > 1e-8 * scale
    e = (np.asarray(points, float) - o) / a
    q = [np.ones(n), e[:, 0], e[:, 1], e[:, 2]]
    if degree >= 2:
        q += [e[:, 0] ** 2, e[:, 1] ** 2, e[:, 2] ** 2, e[:, 0] * e[:, 1], e[:, 0] * e[:, 2],
              e[:, 1] * e[:, 2]]
    q = np.stack(q, axis=1)
    ok = cond_ok & mask
    coef = np.linalg.solve(A[ok], B[ok])                     # k × m × c
    out[ok] = np.einsum("km,kmc->kc", q[ok], coef)
    if return_ok:
        return out, ok
    return out


def interior(faces: np.ndarray) -> np.ndarray:
    """The particles with no free face (:func:`free_faces` all zero): their virial stress has
    every binding, the best samples of the field."""
    return ~np.any(faces != 0, axis=1)


#: a surface cell is the lattice's own box (:func:`regular_cells`) where its extent across
#: each free face is within this many spacings of a whole cell's
REGULAR_EXTENT = 0.15


#: a flat face of a part bound by its bindings alone (:func:`regular_cells`): its cell's extent
#: across the face differs from each in-plane neighbour's by at most this many spacings (a face
#: within 3° of the lattice's plane)
FLAT_FACE_STEP = 0.05


def regular_cells(o: np.ndarray, spacing: float, phi: np.ndarray | None = None,
                  volumetric: bool = True) -> np.ndarray:
    """Which particles' stresses sample the field where they sit (n bool): inside the part
    (no free face); on its surface where the cell ends within the bindings' reach — across
    each free face an extent ``phi`` (n × 3, spacings: ``bindings.npz``'s) within
    :data:`REGULAR_EXTENT` of a whole cell's (the face half a spacing beyond the particle:
    the faces, edges and corners of a box the spacing divides), or, on a flat face (one free
    face), anything short of that (a face the lattice meets at another offset). Not the steps
    of a staircased curved face: a cell that overhangs its particle by more than the
    bindings reach, or a step's corner that a slanted face cuts, reads its stress off the
    field (a round rod in tension up to +15 %, LE10's hole face 0.4 – 0.9 of FEA: docs/stress.md
    "Patch recovery"). Off one cubic lattice (hcp packing), or without ``phi`` (a dynamic
    run), every particle counts as regular.

    A part bound by its bindings alone (``volumetric`` False) also samples a face cell that
    overhangs up to a whole spacing (φ ≤ 1.5) where the face is flat: its four in-plane
    lattice neighbours are free across the same face, with extents within
    :data:`FLAT_FACE_STEP` of its own. Its virial over its cell's volume is the slab's mean
    stress, which stands at the cell's centroid (:func:`sample_points`); left out, the face of
    a wall the lattice meets off-centre was extrapolated from the layers inside, over up to
    1.85 spacings, and read the lattice's bending curvature: +19 … 22 % of beam theory on a
    wall of four layers with φ 1.345 on its face (``rackstress bench walls``, off-centre rows),
    +26 % on the bracket's arm at 0.7 mm. The volumetric lattice holds such a face at its
    centroid already and keeps the rule above (its offsets were fitted to it).

    >>> g = np.array([[x, y, z] for x in range(3) for y in range(3) for z in range(3)], float)
    >>> phi = np.ones((27, 3)); phi[26, 0] = 1.4            # the corner cell overhangs in x
    >>> int(regular_cells(g, 1.0, phi).sum())
    26
    >>> w = np.array([[x, y, z] for x in range(5) for y in range(5) for z in range(3)], float)
    >>> phi = np.ones((75, 3)); phi[w[:, 2] == 2, 2] = 1.35  # a flat top face, off-centre
    >>> int(regular_cells(w, 1.0, phi).sum()), int(regular_cells(w, 1.0, phi, False).sum())
    (50, 59)
    """
    o = np.asarray(o, float)
    n, a = len(o), float(spacing)
    ok = np.ones(n, bool)
    if n < 2 or phi is None or not on_cubic_lattice(o, a):
        return ok
    nb = lattice_neighbours(o, a)
    ff = free_faces(o, a, nb >= 0)
    free = ff != 0
    f = np.nan_to_num(np.asarray(phi, float), nan=1.0)
    whole = np.all(~free | (np.abs(f - 1.0) < REGULAR_EXTENT), axis=1)
    short = (free.sum(axis=1) == 1) & np.all(~free | (f < 1.0 + REGULAR_EXTENT), axis=1)
    if volumetric:
        return whole | short
    return whole | short | _flat_faces(nb, f, ff)


def _flat_faces(nb: np.ndarray, f: np.ndarray, ff: np.ndarray) -> np.ndarray:
    """The face particles of :func:`regular_cells`' flat faces (n bool): one free face (``ff``,
    :func:`free_faces`), its extent across it (``f``) at most 1.5, and four in-plane
    neighbours (``nb``, :func:`~rackstress.lib.cells.lattice_neighbours`) free across the
    same face (an edge's too) with extents within :data:`FLAT_FACE_STEP` of its own."""
    free = ff != 0
    rows = np.arange(len(ff))
    k = np.argmax(free, axis=1)                      # the free axis of a one-face particle
    fk, sk = f[rows, k], ff[rows, k]
    flat = (free.sum(axis=1) == 1) & (fk <= 1.5 + 1e-9)
    for ax in range(3):
        for side in range(2):
            j = nb[:, ax, side]
            jj = np.where(j >= 0, j, 0)
            same = (j >= 0) & (ff[jj, k] == sk) & (np.abs(f[jj, k] - fk) <= FLAT_FACE_STEP + 1e-9)
            flat &= (k == ax) | same                 # the four in-plane neighbours
    return flat


#: where a surface particle's ``continuum`` stress stands, as a sample of the patch fit, along
#: each free face beyond its cell's centroid, in spacings: on a face (one free face)
#: SAMPLE_NU·ν/(1 − ν), on an edge (two) SAMPLE_EDGE + SAMPLE_NU·ν/(1 − ν). Fitted to a bent
#: cantilever's own curvature on walls of four and five layers at ν 0 … 0.45, and measured by
#: ``rackstress bench walls`` on two to eight (φ 0.8 … 1.225; docs/stress.md "Where a sample
#: stands")
SAMPLE_NU = 0.115
SAMPLE_EDGE = -0.194
#: the same for a part bound by its bindings alone (``poisson = "lattice"``, the default: ν = ¼
#: and no volumetric term, whose face cells hold no sub-cell terms): on a face at its cell's
#: centroid, on an edge SAMPLE_BINDINGS_EDGE along each free face. Fitted to the bent
#: cantilevers of ``rackstress bench walls`` bound so (three to ten layers, φ 0.9 … 1.145): the
#: middle and the edges of the top face read beam theory within 7.8 %, the edges had read up
#: to 17.6 % high with the volumetric lattice's shifts (docs/stress.md "Where a sample stands")
SAMPLE_BINDINGS_EDGE = 0.1
#: the cells' extents φ the shifts were measured over; a cell beyond them (a staircase's step,
#: a wall's face a spacing out) is shifted as one at the nearer end
SAMPLE_PHI = (0.8, 1.225)


def sample_points(o: np.ndarray, spacing: float, phi: np.ndarray | None = None,
                  nu: float = 0.25, volumetric: bool = True) -> np.ndarray:
    """Where each particle's ``continuum`` stress stands as a sample of the field (n, 3). A
    particle inside the part: at its centre. On the surface the value is a share of a cell
    that ends off-centre and whose free face's normal strain the particle reads one-sided,
    so in a stress gradient across the face it reads the field at another point: along each
    free face, the centroid of its cell's extent φ ((φ − 1)/2 spacings out on a face, half
    that on an edge) and a shift that grows with the plane-stress ratio ν/(1 − ν) of the
    face's normal strain to its in-plane strains (:data:`SAMPLE_NU`, :data:`SAMPLE_EDGE`).
    A corner (three free faces), a particle off one cubic lattice or without ``phi`` (a
    dynamic run): at its centre. Read as the fit's samples, a bent wall of two to eight
    layers reads its own curvature across its face within 2.3 % (``rackstress bench
    walls``), where its particles' own positions gave −7 … +21 %. A part bound by its
    bindings alone (``volumetric`` False: ``poisson = "lattice"``, ν = ¼) has its own
    offsets: a face at its centroid, an edge :data:`SAMPLE_BINDINGS_EDGE` along each face,
    over φ's whole range (½ … 1½: a face the lattice meets off-centre; the volumetric
    offsets keep φ within :data:`SAMPLE_PHI`, where they were fitted).

    >>> g = np.array([[x, y, z] for x in range(3) for y in range(3) for z in range(3)], float)
    >>> phi = np.ones((27, 3)); phi[22, 0] = phi[25, 0] = 1.2   # cells overhanging in x
    >>> y = sample_points(g, 1.0, phi, nu=0.0)
    >>> y[22].round(3).tolist()                 # (2, 1, 1), a face: its centroid, 0.1 out
    [2.1, 1.0, 1.0]
    >>> y[25].round(3).tolist()                 # (2, 2, 1), an edge: −0.194 + 0.05, −0.194
    [1.856, 1.806, 1.0]
    >>> y[13].tolist(), y[26].tolist()          # inside; a corner
    ([1.0, 1.0, 1.0], [2.0, 2.0, 2.0])
    >>> b = sample_points(g, 1.0, phi, volumetric=False)   # bound by its bindings alone
    >>> b[22].round(3).tolist(), b[25].round(3).tolist()   # the centroid; 0.05 + 0.1, 0.1
    ([2.1, 1.0, 1.0], [2.15, 2.1, 1.0])
    """
    o = np.asarray(o, float)
    a = float(spacing)
    out = o.copy()
    if len(o) < 2 or phi is None or not on_cubic_lattice(o, a):
        return out
    ff = free_faces(o, a)
    nf = np.abs(ff).sum(axis=1)
    # the volumetric offsets were fitted within SAMPLE_PHI; a cell's centroid is its own
    f = np.clip(np.nan_to_num(np.asarray(phi, float), nan=1.0),
                *(SAMPLE_PHI if volumetric else (0.5, 1.5)))
    if volumetric:
        tilt = SAMPLE_NU * nu / (1.0 - nu)
        face = (f - 1.0) / 2 + tilt
        edge = (f - 1.0) / 4 + SAMPLE_EDGE + tilt
    else:
        face = (f - 1.0) / 2
        edge = (f - 1.0) / 4 + SAMPLE_BINDINGS_EDGE
    off = np.where((nf == 1)[:, None], face, np.where((nf == 2)[:, None], edge, 0.0))
    return out + ff * off * a


def patch_matrix(o: np.ndarray, spacing: float, points: np.ndarray, labels=None,
                 radius: float = PATCH_RADIUS, data: np.ndarray | None = None,
                 samples: np.ndarray | None = None):
    """The linear map s → recovered s of :func:`patch_recover` (degree 1) as a sparse n × n
    matrix W (rec = W @ s), built once from the original positions: W_ij = q_iᵀ A_i⁻¹ φ_ij
    with φ_ij = (1, (y_j − o_i)/a), A_i = Σ_j φ_ij φ_ijᵀ and q_i = (1, (x_i − o_i)/a) at the
    recovery point x_i; y_j is where particle j's stress stands as a sample (``samples``,
    :func:`sample_points`; its position where not given). ``labels`` (n): only particles of
    the same label share a patch (one per part; −1: not recovered, W_ii = 1). ``data`` (n bool,
    :func:`regular_cells`): only these particles' stresses enter a fit, as superconvergent patch
    recovery samples at its best points; a particle whose data do not span three dimensions is
    fitted from its whole patch, and one whose whole patch does not keeps its own value.
    """
    from scipy.sparse import diags
    from scipy.spatial import cKDTree

    o = np.asarray(o, float)
    n, a = len(o), float(spacing)
    lab = np.zeros(n, np.int64) if labels is None else np.asarray(labels, np.int64)
    pr = cKDTree(o).query_pairs(radius * a * (1 + 1e-9), output_type="ndarray")
    i = np.r_[pr[:, 0], pr[:, 1], np.arange(n)]
    j = np.r_[pr[:, 1], pr[:, 0], np.arange(n)]
    keep = (lab[i] == lab[j]) & (lab[i] >= 0)
    i, j = i[keep], j[keep]
    flat = flat_axes(o, a, lab)
    W, _ = _patch_weights(o, a, points, lab, flat, i, j, samples)
    if data is None or np.all(data):
        return W
    use = np.asarray(data, bool)[j]
    Wd, fit = _patch_weights(o, a, points, lab, flat, i[use], j[use], samples)
    return diags(fit.astype(float)) @ Wd + diags((~fit).astype(float)) @ W


def _patch_weights(o, a, points, lab, flat, i, j, samples=None):
    """:func:`patch_matrix`'s fit over the directed pairs (i, j): (W, ok), ok where the
    particle's pairs span three dimensions, or the plane of its part where ``flat``
    (:func:`flat_axes`) says it is one layer thick (elsewhere W_ii = 1, its own value); j's
    value stands at ``samples[j]`` (its position where None). Whether the pairs span is
    judged at the particles' positions: a sample's shift (a fraction of a spacing) does not
    make a flat patch a fit."""
    from scipy.sparse import csr_matrix

    n = len(o)

    def moments(phi):
        A = np.zeros((n, 4, 4))
        for r in range(4):
            for c in range(r, 4):
                A[:, r, c] = np.bincount(i, weights=phi[:, r] * phi[:, c], minlength=n)
                A[:, c, r] = A[:, r, c]
        # a part one layer thick along an axis (a membrane, a plate of one layer): its fit is
        # the plane's, (1, two in-plane terms); that axis' term is held at zero (its row and
        # column are empty, its recovery offset is zero), not left singular
        A[:, 1:, 1:] += np.einsum("na,ab->nab", flat.astype(float), np.eye(3))
        lam = np.linalg.eigvalsh(A)
        return A, lam[:, 0] > 1e-8 * np.maximum(lam[:, -1], 1e-300)

    phi = np.column_stack([np.ones(len(i)), (o[j] - o[i]) / a])
    A, ok = moments(phi)
    if samples is not None:
        phi = np.column_stack([np.ones(len(i)), (np.asarray(samples, float)[j] - o[i]) / a])
        A, shifted_ok = moments(phi)
        ok &= shifted_ok
    ok &= lab >= 0
    q = np.column_stack([np.ones(n), (np.asarray(points, float) - o) / a])
    v = np.zeros((n, 4))
    v[ok] = np.linalg.solve(A[ok], q[ok][:, :, None])[:, :, 0]
    w = np.einsum("pm,pm->p", v[i], phi)
    use = ok[i]
    rows = np.r_[i[use], np.flatnonzero(~ok)]
    cols = np.r_[j[use], np.flatnonzero(~ok)]
    vals = np.r_[w[use], np.ones(int((~ok).sum()))]
    return csr_matrix((vals, (rows, cols)), shape=(n, n)), ok


def flat_axes(o: np.ndarray, spacing: float, labels) -> np.ndarray:
    """The axes along which each particle's part (``labels``; −1: none) is one layer thick
    (n × 3 bool): every particle of the part on one lattice plane across that axis.

    >>> g = np.array([[x, y, 0.5] for x in range(3) for y in range(2)], float)
    >>> flat_axes(g, 1.0, np.zeros(6, int))[0].tolist()
    [False, False, True]
    """
    o = np.asarray(o, float)
    lab = np.asarray(labels, np.int64)
    out = np.zeros((len(o), 3), bool)
    for k in np.unique(lab[lab >= 0]):
        m = lab == k
        out[m] = np.ptp(o[m], axis=0) < 1e-6 * float(spacing)
    return out


def cell_reach(phi: np.ndarray) -> np.ndarray:
    """How far each cell reaches past its particle across a free face, in spacings (n, 3):
    φ − ½ of its extent φ along the axis (``bindings.npz``'s ``phi``; NaN: a whole cell, ½),
    in [0, 1]. On an axis with one lattice neighbour the cell spans ½ on that side and the
    rest, up to the part's face, on the free side (``model.solid.axis_fractions``).

    >>> cell_reach(np.array([[1.0, 0.6, np.nan]])).round(2).tolist()
    [[0.5, 0.1, 0.5]]
    """
    return np.clip(np.nan_to_num(np.asarray(phi, float), nan=1.0) - 0.5, 0.0, 1.0)


def part_recovery_points(o: np.ndarray, spacing: float | None = None,
                         phi: np.ndarray | None = None, surface=None) -> np.ndarray:
    """:func:`recovery_points` of one part's particles, their spacing the median nearest-
    neighbour distance when not given; particles off one cubic lattice (hcp packing) are read
    at their centres. ``phi`` (n, 3: the cells' extents, a static run's ``bindings.npz``)
    puts a surface particle's point on its cell's face, :func:`cell_reach` out along each free
    face, where the part's face is; without it (a dynamic run) half a spacing out.
    ``surface`` (vertices, faces: the part's closed surface, ``singular.npz``'s): a point
    that the free faces put outside it is read on it instead (:func:`onto_surface`).

    >>> g = np.array([[x, y, z] for x in range(3) for y in range(3) for z in range(3)], float)
    >>> phi = np.ones((27, 3)); phi[26, 0] = 0.6          # the face 0.1 past the corner in x
    >>> part_recovery_points(g, 1.0, phi)[26].round(2).tolist()
    [2.1, 2.5, 2.5]
    """
    o = np.asarray(o, float)
    if len(o) < 2:
        return o.copy()
    if spacing is None:
        from scipy.spatial import cKDTree

        spacing = float(np.median(cKDTree(o).query(o, k=2)[0][:, 1]))
    if not on_cubic_lattice(o, spacing):
        return o.copy()
    pts = recovery_points(o, spacing, reach=None if phi is None else cell_reach(phi))
    return pts if surface is None else onto_surface(pts, surface, o)


def onto_surface(points: np.ndarray, surface, o: np.ndarray) -> np.ndarray:
    """``points`` (n, 3) outside the closed ``surface`` (vertices, faces) moved to its nearest
    point; those inside or on it kept, and those at their particle ``o`` (interior ones) not
    tested. Each free axis's reach puts a point on the face along that axis, but where two or
    three axes are free on a slanted or curved face their sum lies outside the part (on the
    SO-100 fixed jaw at 1.6 mm, 1,157 of 5,896 surface particles more than a tenth of a
    spacing out; a 3 mm U bracket's governing point 0.64 mm out): read there, the stress is
    extrapolated past the face, and a point off a singular edge's zone may be off the part.

    >>> cube = (np.array([[x, y, z] for x in (0, 2) for y in (0, 2) for z in (0, 2)], float),
    ...         np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
    ...                   [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]))
    >>> onto_surface(np.array([[2.5, 1.0, 1.0], [1.5, 1.0, 1.0]]), cube,
    ...              np.ones((2, 3))).round(6).tolist()
    [[2.0, 1.0, 1.0], [1.5, 1.0, 1.0]]
    """
    import pyvista as pv

    from rackstress.model.regions import inside_surface

    pts = np.array(points, float)
    moved = np.flatnonzero(np.any(pts != np.asarray(o, float), axis=1))
    if not len(moved):
        return pts
    V, F = (np.asarray(x) for x in surface)
    poly = pv.PolyData(np.asarray(V, float),
                       np.hstack([np.full((len(F), 1), 3), F]).astype(np.int64).ravel())
    out = moved[~inside_surface(poly, pts[moved])]
    if len(out):
        _, closest = poly.find_closest_cell(pts[out], return_closest_point=True)
        pts[out] = np.asarray(closest, float).reshape(-1, 3)
    return pts


def on_cubic_lattice(o: np.ndarray, spacing: float) -> bool:
    """Whether the particles ``o`` sit on one cubic lattice of ``spacing`` (to 1e-6 of it),
    as a part's fill puts them; not an hcp packing."""
    lo = o.min(axis=0)
    return bool(np.abs(np.rint((o - lo) / spacing) * spacing + lo - o).max() <= 1e-6 * spacing)
