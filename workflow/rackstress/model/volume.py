"""The elastic lattice's many-body term: the material's Poisson's ratio, on every cell.

The bindings of a material part (:mod:`rackstress.model.solid`, Eq. 12 on the simple-cubic
lattice's 6 nearest and 12 second neighbours) are central springs of one stiffness k, so the
lattice's continuum limit is C11 = 3k/a, C12 = C44 = k/a: Lamé moduli λ = μ = k/a, Poisson's
ratio 1/4 whatever the material's (the Cauchy relation C12 = C44 of every central pair force).
:class:`Volume` adds to each particle the energy of its own cell's change of volume, made of
quadratic terms in the extensions e_ij = ‖p_j − p_i‖ − L_ij of the particle's own bindings
(docs/calibration.md, "The volumetric term"):

    U = Σ_i Σ_m ½·K_m·θ_m²,     θ_m = Σ_j C_m,ij·e_ij        (K_m = m_i·κ_m, an energy)

* **The strain along an axis.** D_ik = Σ_j β_ij·e_ij over i's bound nearest neighbours along
  axis k, β = 1/(n·L) with n = 2 (central difference) or 1 (one-sided, on a free face): ε_kk
  exactly under every uniform strain, rotation-free (an extension is).
* **Sub-cells.** A particle's cell (the part's points nearer to it than to any other particle,
  φ_k·a along axis k, docs/calibration.md "Walls of any thickness") is split along each axis
  into the span toward its neighbours, s_k = n_k/2 (1 inside, ½ on a face), and what overhangs
  it, h_k = φ_k − s_k. The sub-cell spanned along the axes S and overhanging along the others,
  of volume V_S = Π_S s·Π_rest h (× a³), gets θ_S = Σ_{k∈S} D_k and the modulus λ'_|S| with

      λ'_d = λ_d − μ,    λ_d = 2μν/(1 − (d − 1)·ν)   (λ₃ = λ, λ₂ = 2λμ/(λ + 2μ), λ₁ = E − 2μ)

  — the Lamé modulus of the bulk (d = 3), of a membrane in plane stress (2) and of a fibre in
  uniaxial stress (1), less the bindings' own λ_b = μ: a sub-cell that overhangs a free face
  is free to contract across it, and the bindings there (the face compensation) carry C_b.
  Inside the part this is λ'·(tr ε)² on every cell; the lattice's moduli become C11 = 3k/a + λ',
  C12 = k/a + λ', C44 = k/a, so C44 = (C11 − C12)/2 still holds: isotropic, λ = k/a + λ',
  μ = k/a. Under every uniform strain every cell's energy is the material's, on the faces too.
* **The overhang at its centroid.** The face layer's bindings put the overhanging sub-cell's
  membrane stiffness at the particle, h·a/2 inside its centroid, and its gap below is the only
  other place they reach: a wall in bending is too soft by O(1/n²) (6 % at five layers). On a
  face particle (one free face, normal l) the overhang's in-plane strains are extrapolated to
  its centroid, Dc_k = (1 + h)·D_k − h·G_k, with G_k the strain at the gap's mid-plane from
  the particle's own diagonals toward the inside; its energy ½·V·Dcᵀ·Q·Dc (Q the membrane's
  plane-stress moduli: λ₂, 2μ) replaces the sub-cell's and ½·V·Dᵀ·C_b·D (what the bindings
  carry at the particle: μ, 2μ) is taken off: Q·Dc − C_b·D, five terms instead of one.

A material of E, ν gets (:func:`coefficients`) μ = E/(2(1 + ν)) = k/a on its bindings, c =
μ/(2ρa²) (k = 2c·m, m = ρ·a³; Eq. 12's stiffness at rest is 2c), and κ = V·λ'_d/ρ on its
terms. ν = 0 … 0.45 are met within 0.01 at every spacing measured, from five layers across
(docs/benchmarks/lattice.md); λ'/μ = (4ν − 1)/(1 − 2ν) grows without bound as ν → ½, and above
:data:`NU_MAX` a scene is refused (docs/calibration.md "Near ν = ½").

Every engine realizes the one formula (:meth:`Volume.accel`: each pair (i, j) of i's terms is
pulled with s_ij = Σ_m κ_m·θ_m·C_m,ij along it, −∂(U/m)/∂p), its tangent stiffness
(:meth:`Volume.hessian`, symmetric) and its virial (:meth:`Volume.virial`: i's own terms'
Σ s_ij·d_ij⊗d̂_ij, V_i·λ'·tr ε·I inside under a uniform strain).

Example
-------
>>> from rackstress.model.materials import material
>>> from rackstress.model.units import SYSTEMS
>>> c, cv = coefficients(material("aluminium"), SYSTEMS["mm-N-s"], 1.0)
>>> round(c / 1e12, 4), [round(x * 2.7e-9 / 1e3, 3) for x in cv]   # c [s⁻²], moduli [GPa]
(4.8733, [-8.947, -0.393, 24.768, 26.316])
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from rackstress.errors import SceneError
from rackstress.lib.vec import rowdot
from rackstress.model.operators import OPERATOR_KINDS, Bind, Operator

#: the smallest Poisson's ratio taken: an auxetic material (ν < 0) is not measured
NU_MIN = 0.0
#: the largest Poisson's ratio taken (docs/calibration.md "Near ν = ½": at 0.49 a laterally
#: constrained block of ten layers reads its constrained modulus within 3 %, at 0.499 10 % low)
NU_MAX = 0.49
#: the lattice's own Poisson's ratio without the term (the Cauchy relation of central springs)
LATTICE_NU = 0.25
#: a pair's offset within this fraction of the spacing of a lattice vector is that vector
AXIAL_TOL = 1e-6
#: per group, the last terms made (every engine asks for them)
_TERMS: dict = {}


def lame(E: float, nu: float) -> tuple[float, float]:
    """(λ, μ) of an isotropic material of Young's modulus ``E`` and Poisson's ratio ``nu``."""
    return E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), E / (2.0 * (1.0 + nu))


def check_nu(nu: float, where: str) -> None:
    """Refuse a Poisson's ratio the lattice cannot honestly represent (module doc)."""
    if nu < NU_MIN:
        raise SceneError(
            f"{where}: Poisson's ratio {nu:g} is below {NU_MIN:g}: an auxetic material is not "
            "supported (the lattice's volumetric term is calibrated and measured for ν from 0 "
            "to ½, docs/calibration.md \"The volumetric term\")")
    if nu > NU_MAX:
        raise SceneError(
            f"{where}: Poisson's ratio {nu:g} is above {NU_MAX:g}: a nearly incompressible "
            "material: its bulk modulus is more than 50 times its shear modulus, and a part "
            "that confines it (a support, a pressed face) was measured 10 % off at ν = 0.499 "
            "(docs/calibration.md \"Near ν = ½\"); give nu as at most "
            f"{NU_MAX:g}, or check the part with the FE cross-check (rackstress fea)")


def coefficients(material, units, spacing: float) -> tuple[float, tuple]:
    """(c, (c₁, c₂, c₃, c_μ)): Eq. 12's c of the part's bindings, c = μ/(2ρa²), and the
    term's moduli per unit density: λ'_d/ρ for sub-cells spanned along d = 1, 2, 3 axes and
    μ/ρ (module doc), so that the cubic lattice of ``spacing`` has the ``material``'s E and ν
    in the scene's ``units``."""
    props = material.in_units(units)
    E, nu, rho = props["E"], float(props["nu"]), props["density"]
    check_nu(nu, f"material '{material.name}'")
    _, mu = lame(E, nu)
    a = float(spacing)
    lam = [2.0 * mu * nu / (1.0 - (d - 1) * nu) for d in (1, 2, 3)]
    return mu / (2.0 * rho * a * a), tuple([(x - mu) / rho for x in lam] + [mu / rho])


def direction(g: np.ndarray) -> np.ndarray:
    """The index 0 … 26 of integer lattice offsets (n, 3) in {−1, 0, 1}³ (13: none)."""
    g = np.asarray(g, dtype=np.int64)
    return (g[:, 0] + 1) * 9 + (g[:, 1] + 1) * 3 + (g[:, 2] + 1)


@dataclass(frozen=True)
class VolumeTerms:
    """A group's terms as arrays (module doc): the directed pairs (i, j) they read (sorted
    by i; inside the part the six nearest neighbours), with their rest lengths L; each term's ``owner`` particle, κ (per unit mass) and the
    sparse matrix ``C`` (terms × pairs) of θ = C·e; every term reads its owner's pairs only."""

    i: np.ndarray
    j: np.ndarray
    L: np.ndarray
    owner: np.ndarray
    kappa: np.ndarray
    C: object
    n: int

    def shifted(self, offset: int, n: int) -> "VolumeTerms":
        """The same terms in global indices (the group at ``offset`` of ``n`` particles)."""
        return VolumeTerms(self.i + offset, self.j + offset, self.L, self.owner + offset,
                           self.kappa, self.C, n)


def build(o: np.ndarray, i: np.ndarray, j: np.ndarray, q: np.ndarray, spacing: float,
          phi: np.ndarray, coef, fixed: np.ndarray | None = None) -> VolumeTerms:
    """The terms of the particles ``o`` whose bound pairs are (i, j) (sorted by i, both
    directions) with rest lengths² ``q``, on the cubic lattice of ``spacing``, cells ``phi``
    (n, 3, in spacings) and moduli ``coef`` = (c₁, c₂, c₃, c_μ) (module doc). ``fixed`` (n, 3):
    the directions a support holds each particle in; an overhang across a held direction
    cannot contract there (plane strain: it counts as spanned in the modulus) — unless the
    particle has no neighbour along it at all (one layer: the support only removes the
    sheet's out-of-plane motion, the sheet stays in plane stress)."""
    import scipy.sparse as sp

    n, a = len(o), float(spacing)
    c1, c2, c3, cmu = (float(x) for x in coef)
    cd = (c1, c2, c3)
    L = np.sqrt(q)
    g = np.rint((o[j] - o[i]) / a).astype(np.int64)
    nz = (g != 0).sum(axis=1)
    axial = nz == 1
    axis = np.argmax(np.abs(g), axis=1)
    count = np.zeros((n, 3))
    np.add.at(count, (i[axial], axis[axial]), 1.0)
    s = 0.5 * count
    h = np.maximum(np.asarray(phi, float) - s, 0.0)
    held = np.zeros((n, 3), bool) if fixed is None else np.asarray(fixed, bool)
    # a support across an axis along which the particle has no neighbour at all (a sheet one
    # layer thick held in its normal) holds no face: it only takes the sheet's out-of-plane
    # motion, and both overhangs stay free to contract (plane stress, not plane strain)
    held = held & (count > 0)
    key = i * 27 + direction(g)
    order = np.argsort(key, kind="stable")
    skey = key[order]

    def pair(ii, offset):
        """Index of each particle's pair toward ``offset`` (−1: none)."""
        k = ii * 27 + int(direction(np.asarray(offset).reshape(1, 3))[0])
        pos = np.minimum(np.searchsorted(skey, k), len(skey) - 1)
        return np.where(skey[pos] == k, order[pos], -1) if len(skey) else np.full(len(ii), -1)

    # the face particles whose overhang is measured at its centroid: one free face (normal l,
    # outward σ), both neighbours along the other two axes, the four diagonals inward there
    rows, cols, vals, owner, kappa = [], [], [], [], []
    nterm = [0]

    def add(who, entries, kap):
        """One term per particle of ``who`` (κ ``kap``): entries [(pair index, coefficient)]."""
        if not len(who):
            return
        ids = nterm[0] + np.arange(len(who))
        nterm[0] += len(who)
        owner.append(who)
        kappa.append(np.broadcast_to(np.asarray(kap, float), (len(who),)).copy())
        for p_, c_ in entries:
            ok = p_ >= 0
            rows.append(ids[ok])
            cols.append(p_[ok])
            vals.append(np.broadcast_to(np.asarray(c_, float), (len(who),))[ok])

    beta = np.zeros(len(i))
    beta[axial] = 1.0 / (count[i[axial], axis[axial]] * L[axial])
    ones = (count == 1).sum(axis=1) == 1
    twos = (count == 2).sum(axis=1) == 2
    face = np.flatnonzero(ones & twos)
    l_of = np.argmax(count[face] == 1, axis=1)
    moment = np.zeros(n, dtype=bool)
    plans = []
    for l in range(3):
        for sg in (1, -1):
            el = np.zeros(3, np.int64)
            el[l] = sg
            who = face[l_of == l]
            # the outward side σ: no neighbour there
            who = who[(pair(who, el) < 0) & (pair(who, -el) >= 0)]
            who = who[h[who, l] > 1e-12]
            ks = [k for k in range(3) if k != l]
            diag = {}
            for k in ks:
                ek = np.zeros(3, np.int64)
                ek[k] = 1
                diag[k] = (pair(who, ek), pair(who, -ek), pair(who, ek - el),
                           pair(who, -ek - el))
            ax = pair(who, -el)
            keep = np.all([diag[k][m] >= 0 for k in ks for m in range(4)], axis=0) \
                if len(who) else np.zeros(0, bool)
            who = who[keep]
            if not len(who):
                continue
            moment[who] = True
            plans.append((who, l, ks, {k: tuple(x[keep] for x in diag[k]) for k in ks},
                          ax[keep]))
    # sub-cells: θ_S = Σ_{k∈S} D_k, κ = c_|S|·Π_S s·Π_rest h
    for S in range(1, 8):
        inS = [(S >> k) & 1 for k in range(3)]
        # the modulus of the axes free to contract: an overhang held across counts as spanned
        d = sum(inS) + sum(held[:, k] for k in range(3) if not inS[k])
        w = np.asarray(cd, float)[np.minimum(d, 3) - 1]
        for k in range(3):
            w = w * (s[:, k] if inS[k] else h[:, k])
        if sum(inS) == 2:      # the face particles' overhang: at its centroid (below)
            lk = [k for k in range(3) if not inS[k]][0]
            w = np.where(moment & (count[:, lk] == 1), 0.0, w)
        who = np.flatnonzero(w != 0.0)
        if not len(who):
            continue
        ids = nterm[0] + np.arange(len(who))
        nterm[0] += len(who)
        owner.append(who)
        kappa.append(w[who])
        slot = np.full(n, -1)
        slot[who] = ids
        sel = np.flatnonzero(axial & (slot[i] >= 0))
        sel = sel[np.asarray(inS)[axis[sel]] > 0]
        rows.append(slot[i[sel]])
        cols.append(sel)
        vals.append(beta[sel])
    # the overhang at its centroid: Q·Dc − C_b·D (module doc)
    for who, l, ks, diag, ax in plans:
        hh = h[who, l]
        V = s[who, ks[0]] * s[who, ks[1]] * hh
        D, Dc = {}, {}
        for k in ks:
            pp, pm, dp, dm = diag[k]
            D[k] = [(pp, beta[pp]), (pm, beta[pm])]
            Dc[k] = [(pp, (1 + hh) * beta[pp]), (pm, (1 + hh) * beta[pm]),
                     (dp, -hh / L[dp]), (dm, -hh / L[dm]), (ax, hh / L[ax])]
        add(who, Dc[ks[0]] + Dc[ks[1]], V * (np.where(held[who, l], c3, c2) + cmu))
        for k in ks:
            add(who, Dc[k], 2.0 * V * cmu)
        add(who, D[ks[0]] + D[ks[1]], -V * cmu)
        for k in ks:
            add(who, D[k], -2.0 * V * cmu)
    cat = (lambda xs, dt: np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt))
    cols = cat(cols, np.int64)
    used = np.unique(cols)          # the pairs some term reads (inside: the six nearest)
    C = sp.csr_matrix((cat(vals, float), (cat(rows, np.int64), np.searchsorted(used, cols))),
                      shape=(nterm[0], len(used)))
    C.sum_duplicates()
    return VolumeTerms(i[used], j[used], L[used], cat(owner, np.int64), cat(kappa, float), C, n)


@dataclass(frozen=True)
class Volume(Operator):
    """volume(c₁, c₂, c₃, c_μ) on a material part (module doc): each particle's cell's energy
    of volume change (and its overhang's membrane at its centroid), over the pairs the
    part's ``solid`` binds.

    ``solid`` is the part's bind coefficient (:class:`rackstress.model.solid.Solid`): its
    pairs are the terms' neighbourhoods, its cells (``fractions``) the particles' volumes.
    ``c`` are :func:`coefficients`' moduli per unit density.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> p = np.array([[0.0, 0, 0], [1.1, 0, 0]])          # one pair along x stretched by 0.1
    >>> i, j, L = np.array([0, 1]), np.array([1, 0]), np.array([1.0, 1.0])
    >>> C = sp.csr_matrix(np.eye(2))                      # θ of each end: its pair's extension
    >>> t = VolumeTerms(i, j, L, np.array([0, 1]), np.array([2.0, 2.0]), C, 2)
    >>> Volume.accel(p, t)[0].round(6).tolist()           # pulled toward j by 2·κθ
    [0.4, 0.0, 0.0]
    """

    source: str
    solid: object
    c: tuple
    when: tuple = ()

    kind: ClassVar[str] = "volume"

    def __post_init__(self):
        object.__setattr__(self, "c", tuple(float(x) for x in self.c))

    def label(self) -> str:
        return (f"volume({self.source}, {', '.join(f'{c:g}' for c in self.c)})"
                + self._when())

    def check(self, target, groups) -> None:
        super().check(target, groups)
        where = f"operator volume on '{target}'"
        if self.source != target:
            raise SceneError(f"{where}: a particle's volume is its own part's; source must be "
                             f"'{target}', got '{self.source}'")
        if len(self.c) != 4 or not np.all(np.isfinite(self.c)):
            raise SceneError(f"{where}: needs four finite moduli (sub-cells spanned along 1, "
                             f"2, 3 axes, and μ), got {self.c!r}")
        if getattr(self.solid, "spacing", None) is None:
            raise SceneError(f"{where}: needs the part's solid bindings (a material part)")

    # ------------------------------------------------------------------ the neighbourhoods
    def terms(self, group) -> VolumeTerms:
        """The terms of ``group`` (:func:`build` over the pairs its solid binds, the cells
        from the part's shape). Remembered per group and positions (every engine asks)."""
        import hashlib

        o = np.ascontiguousarray(group.o, dtype=float)
        fixed = np.ascontiguousarray(group.fixed, dtype=bool)
        key = (id(self.solid), self.c, hashlib.sha1(o.tobytes() + fixed.tobytes()).hexdigest())
        hit = _TERMS.get(group.name)
        if hit is not None and hit[0] == key:
            return hit[1]
        pl = Bind(group.name, self.solid).pairs(group, group)
        phi = (np.ones((len(o), 3)) if getattr(self.solid, "part", None) is None
               else self.solid.fractions(o))
        out = build(o, pl.i, pl.j, pl.q, self.solid.spacing, phi, self.c, fixed)
        _TERMS[group.name] = (key, out)
        return out

    # ------------------------------------------------------------------ the formula
    @staticmethod
    def extensions(p, t: VolumeTerms):
        """d = p_j − p_i, ‖d‖ and e = ‖d‖ − L of the terms' pairs."""
        d = p[t.j] - p[t.i]
        r = np.sqrt(rowdot(d, d))
        return d, r, r - t.L

    @staticmethod
    def term_energies(p, t: VolumeTerms) -> np.ndarray:
        """½·κ·θ² of each term (an energy per unit mass of its owner)."""
        th = t.C @ Volume.extensions(p, t)[2]
        return 0.5 * t.kappa * th * th

    @staticmethod
    def energy(p, t: VolumeTerms) -> float:
        """U/m = Σ ½·κ·θ² (an energy per unit mass)."""
        return float(np.sum(Volume.term_energies(p, t)))

    @staticmethod
    def pulls(p, t: VolumeTerms):
        """d, ‖d‖ and the pull s = Cᵀ·(κ·θ) of every pair (∂(U/m)/∂e)."""
        d, r, e = Volume.extensions(p, t)
        return d, r, t.C.T @ (t.kappa * (t.C @ e))

    @staticmethod
    def accel(p, t: VolumeTerms) -> np.ndarray:
        """a = −∂(U/m)/∂p (n, 3): each pair (i, j) pulls i toward j and j toward i with its
        pull s_ij."""
        d, r, s = Volume.pulls(p, t)
        g = s / r
        a = np.zeros((t.n, 3))
        for k in range(3):
            w = g * d[:, k]
            a[:, k] = (np.bincount(t.i, weights=w, minlength=t.n)
                       - np.bincount(t.j, weights=w, minlength=t.n))
        return a

    @staticmethod
    def hessian(p, t: VolumeTerms):
        """∂²(U/m)/∂p² (3n × 3n, CSR, symmetric): Gᵀ·diag(κ)·G with G = C·J (J = ∂e/∂p: row
        (i, j) is d̂ at j, −d̂ at i; G = ∂θ/∂p), plus each pair's s/‖d‖·(I − d̂d̂ᵀ) between its
        two ends (its blocks summed per particle on the diagonal first)."""
        import scipy.sparse as sp

        n, P = t.n, len(t.i)
        d, r, s = Volume.pulls(p, t)
        u = d / r[:, None]
        k3 = np.arange(3)
        Jm = sp.csr_matrix((np.concatenate([u, -u], axis=1).ravel(),
                            (np.repeat(np.arange(P), 6),
                             np.concatenate([3 * t.j[:, None] + k3, 3 * t.i[:, None] + k3],
                                            axis=1).ravel())), shape=(P, 3 * n))
        G = (t.C @ Jm).tocsr()
        H = G.T @ sp.diags(t.kappa) @ G
        w = s / r
        B = (w[:, None, None] * (np.eye(3)[None] - u[:, :, None] * u[:, None, :])).reshape(-1, 9)
        D = np.zeros((n, 9))
        for c in range(9):
            D[:, c] = (np.bincount(t.i, weights=B[:, c], minlength=n)
                       + np.bincount(t.j, weights=B[:, c], minlength=n))
        rows = (3 * t.i[:, None, None] + k3[None, :, None]).repeat(3, axis=2).reshape(-1, 9)
        cols = (3 * t.j[:, None, None] + k3[None, None, :]).repeat(3, axis=1).reshape(-1, 9)
        drow = (3 * np.arange(n)[:, None, None] + k3[None, :, None]).repeat(3, axis=2)
        dcol = (3 * np.arange(n)[:, None, None] + k3[None, None, :]).repeat(3, axis=1)
        geo = sp.csr_matrix((np.concatenate([D.ravel(), -B.ravel(), -B.ravel()]),
                             (np.concatenate([drow.ravel(), rows.ravel(), cols.ravel()]),
                              np.concatenate([dcol.ravel(), cols.ravel(), rows.ravel()]))),
                            shape=(3 * n, 3 * n))
        return (H + geo).tocsr()

    @staticmethod
    def virial(p, t: VolumeTerms, m: np.ndarray) -> np.ndarray:
        """W_i = m_i·Σ_j s_ij·d_ij ⊗ d_ij/‖d_ij‖ over i's own pairs (n, 6, internal Voigt order
        xx yy zz yz xz xy): the virial of i's own terms (their forces' Σ r ⊗ f; ``m`` the
        particles' masses). Under a uniform strain m_i·Σ_S κ_S·θ_S·P_S (P_S the projection on
        the axes of S): V_i·λ'·tr ε·I inside the part."""
        with np.errstate(divide="ignore", invalid="ignore"):
            d, r, s = Volume.pulls(p, t)
            w = m[t.i] * s / r
        out = np.empty((t.n, 6))
        for c, (a, b) in enumerate(((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))):
            out[:, c] = np.bincount(t.i, weights=w * d[:, a] * d[:, b], minlength=t.n)
        return out


def centroid_owners(t: VolumeTerms) -> np.ndarray:
    """Which particles (n, bool) carry their face's overhang at its centroid: a face particle's
    six terms Q·Dc − C_b·D (module doc), the only terms that read a pair off the lattice's
    axes (its diagonals inward), so the owners of a term reading a pair longer than the
    owner's nearest. Their forces already hold the cell's own moment, which the stress
    measure's continuum route restores for the bindings alone (docs/stress.md)."""
    near = np.full(t.n, np.inf)
    np.minimum.at(near, t.i, t.L)
    off_axis = t.L > (1.0 + 0.5 * (np.sqrt(2.0) - 1.0)) * near[t.i]
    C = t.C.tocoo()
    out = np.zeros(t.n, dtype=bool)
    out[t.owner[C.row[off_axis[C.col]]]] = True
    return out


def loaded_overhang(op: "Volume", group, loaded: np.ndarray, axis: int, pressure: float,
                    nu: float) -> np.ndarray:
    """The forces (n, 3, the scene's force unit) a ``pressure`` on the ``loaded`` particles'
    face normal to ``axis`` adds through the cells' overhang (docs/calibration.md "Loaded
    faces"): the overhang is a membrane in plane stress when the face is free; under σ_nn = −p
    it carries the in-plane prestress λ/(λ + 2μ)·σ_nn = −p·ν/(1 − ν) as well, whose virtual
    work −V·σ_pre·δθ over its in-plane strains D_k (the particle's own axial pairs, β per
    pair) gives each in-plane neighbour −V·σ_pre·β·n̂ and the particle the opposite: nothing
    inside a loaded face (the pushes cancel), an outward push along its edge."""
    o = np.asarray(group.o, float)
    n, a = len(o), float(op.solid.spacing)
    pl = Bind(group.name, op.solid).pairs(group, group)
    a2 = a * a
    ax_ = np.abs(pl.q - a2) <= AXIAL_TOL * a2
    i, j = pl.i[ax_], pl.j[ax_]
    d = o[j] - o[i]
    k = np.argmax(np.abs(d), axis=1)
    count = np.zeros((n, 3))
    np.add.at(count, (i, k), 1.0)
    phi = (np.ones((n, 3)) if getattr(op.solid, "part", None) is None
           else op.solid.fractions(o))
    h = np.maximum(phi[:, axis] - 0.5 * count[:, axis], 0.0)
    V = h * a ** 3
    for q in range(3):
        if q != axis:
            V = V * phi[:, q]
    face = np.asarray(loaded, bool) & (count[:, axis] == 1) & (V > 0)
    sel = face[i] & (k != axis)
    i, j, k, d = i[sel], j[sel], k[sel], d[sel]
    L = np.sqrt(pl.q[ax_][sel])
    pre = -float(pressure) * nu / (1.0 - nu)
    f = (-V[i] * pre / (count[i, k] * L))[:, None] * (d / L[:, None])
    F = np.zeros((n, 3))
    for c in range(3):
        F[:, c] = np.bincount(j, weights=f[:, c], minlength=n) - np.bincount(
            i, weights=f[:, c], minlength=n)
    return F


# the scene's check of its operators knows this one too (a Volume exists only once this module
# is imported, so registering here is enough; operators.py cannot import it: it imports that)
OPERATOR_KINDS[Volume.kind] = Volume


def volume_terms(scene):
    """Every volumetric term of ``scene`` in global indices, joined (a part's particles are
    one group's), or None when the scene has none. Remembered for the last scene asked (a
    static solve asks at every evaluation of its forces)."""
    key = tuple((tg, id(op)) for tg, seq in scene.operators.items() for op in seq)
    if _SCENE[0] is not scene or _SCENE[1] != key:     # (the scene is kept: its id stays its)
        _SCENE[:] = [scene, key, _volume_terms(scene)]
    return _SCENE[2]


_SCENE: list = [None, None, None]


def _volume_terms(scene):
    import scipy.sparse as sp

    parts = []
    n = scene.n_particles
    for target, seq in scene.operators.items():
        for op in seq:
            if isinstance(op, Volume) and not op.when:
                parts.append(op.terms(scene.groups[target]).shifted(scene.offset(target), n))
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    cat = lambda name: np.concatenate([getattr(t, name) for t in parts])  # noqa: E731
    return VolumeTerms(cat("i"), cat("j"), cat("L"), cat("owner"), cat("kappa"),
                       sp.block_diag([t.C for t in parts], format="csr"), n)
