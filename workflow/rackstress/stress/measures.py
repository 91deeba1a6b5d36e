"""Per-particle stress measures, one MDAnalysis ``AnalysisBase`` class each, over a run's frames.

Every class takes a :class:`~rackstress.stress.rundata.RunData` (from :func:`load_run`), streams
its trajectory frame by frame (only one frame's positions are ever held) and leaves in
``self.results``: ``steps`` (iteration of every analysed frame), ``per_particle`` (n_frames × n_atoms,
float64, the measure per particle; NaN where it is undefined or for parts not analysed) and
``per_part`` (name → {"max", "mean"} over the frames). ``UNITS`` and ``LABEL`` say what it is.

The measures and what they mean
-------------------------------
``paper`` — :class:`DesiredPositionDistance`
    Section 5.2 / docs/model.md, "Desired position": the distance of a particle from its desired position, its
    original position carried by its part's best-fit rigid motion (:mod:`.fit`; robust Kabsch
    by default). Zero for a rigid motion of the part; for a local deformation, the local
    displacement itself. It sees any departure from the rest shape — including a part bending
    as a whole, where every particle is far from where the rigid fit puts it although the
    neighbourhood of each is only gently strained. Length units.
``accumulated`` — :class:`AccumulatedDistance`
    "the magnitude and the duration of local deformations" (Section 5.2): the time integral
    ∫ d_i dt of the paper's distance (trapezoid rule over the dumped frames, t = step × dt), so a
    deformation held long weighs as much as a larger one held briefly. Length × time units.
``strain`` — :class:`VonMisesStrain`
    The local von Mises shear strain as OVITO's atomic-strain modifier computes it: per
    particle, the neighbours within a cutoff in the original configuration (1.5 × the part's
    typical spacing by default), the best-fit affine deformation gradient
    F = (Σ d d₀ᵀ)(Σ d₀ d₀ᵀ)⁻¹ (Falk & Langer 1998), E = ½(FᵀF − I) and
    η = √(E_xy² + E_yz² + E_xz² + ((E_xx−E_yy)² + (E_yy−E_zz)² + (E_zz−E_xx)²)/6).
    Dimensionless. It measures shape change of the neighbourhood only: it is zero for a rigid
    motion *and* for a neighbourhood that is displaced but not distorted, e.g. a toe that is
    bent rigidly about a hinge shows strain only at the hinge while the paper's measure paints
    the whole toe. Conversely a uniform stretch of a whole part shows everywhere in η but, under
    the paper's measure, grows from zero at the centre to its largest at the ends.
    A planar neighbourhood (the plane scenes, the sediment, one-layer feet) has a singular
    Σ d₀ d₀ᵀ: there F is fitted in the plane (pseudo-inverse) and completed by carrying the
    plane's normal to the deformed plane's unit normal, so E is the in-plane (membrane) strain
    with no thickness change. A particle with a collinear or empty neighbourhood gets NaN.
``d2min`` — :class:`NonAffineD2min`
    D²min = Σ_j ‖d_j − F d₀_j‖² of the same fit (Falk & Langer): the part of the neighbours'
    motion no affine deformation explains — local rearrangement or sharp bending. Zero for any
    uniform deformation, which the paper's measure does not ignore. Length² units.
``virial`` — :class:`VirialStress`
    LAMMPS' per-atom stress (``compute stress/atom``, columns ``c_NAME[1..6]`` = xx yy zz xy xz yz
    in the dump), shown as its von Mises equivalent √(½Σ(σ_ii−σ_jj)² + 3Σσ_ij²). It is force ×
    distance per particle (stress × volume, energy units), includes the forces that hold the
    parts together however far they deform, and so differs from the paper's measure where a
    large force holds a small deformation (stiff binds to a rack) or the reverse. Only if the
    run recorded it; rackstress runs do not by default.

:class:`PartMotion` is the companion for plots: each part's centre of mass and bounding box per
frame, and for a sediment the vertical displacement of its particles (footprints).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from MDAnalysis.analysis.base import AnalysisBase
from scipy.spatial import cKDTree

from rackstress.stress import tensor as T
from rackstress.stress.dump import DumpColumnsError, StressInputError
from rackstress.stress.fit import FITS
from rackstress.stress.rundata import (boundary_rows, face_stress, face_supports, lattice_nu,
                                       volumetric)

#: Cutoff of the strain neighbourhood in units of the part's typical (median nearest) spacing.
CUTOFF_FACTOR = 1.5
#: Relative eigenvalue below which Σ d₀ d₀ᵀ counts as singular (planar/collinear neighbourhood).
RANK_TOL = 1e-9
#: Vertical axis (MagPod and the planes: y is up).
UP = 1


def positions(ts) -> np.ndarray:
    """Float64 positions of a frame (``RackDumpReader`` keeps them; else MDAnalysis' float32)."""
    p = ts.data.get("positions64") if hasattr(ts, "data") else None
    return np.asarray(p if p is not None else ts.positions, dtype=np.float64)


class _RunAnalysis(AnalysisBase):
    """Shared plumbing: parts, steps, per-particle values, per-part summaries."""

    NAME = ""
    LABEL = ""
    UNITS = ""

    def __init__(self, run, parts=None, **kwargs):
        super().__init__(run.trajectory, **kwargs)
        self.run_data = run
        names = list(run.parts) if parts is None else list(parts)
        unknown = [n for n in names if n not in run.parts]
        if unknown:
            raise StressInputError(f"no part(s) {', '.join(unknown)} in {run.rundir}; parts: "
                                   f"{', '.join(run.parts)}")
        self.parts = [run.parts[n] for n in names]

    def _prepare(self):
        self.results.steps = np.zeros(self.n_frames, dtype=np.int64)
        self.results.per_particle = np.full((self.n_frames, self.run_data.n_atoms), np.nan)

    def _single_frame(self):
        k = self._frame_index
        self.results.steps[k] = int(self._ts.data.get("step", self._ts.frame))
        self.results.per_particle[k] = self._measure(positions(self._ts))

    def _measure(self, p: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _conclude(self):
        vals = self.results.per_particle
        self.results.per_part = {}
        for part in self.parts:
            v = vals[:, part.index]
            ok = np.isfinite(v).any(axis=1)
            with np.errstate(all="ignore"):
                vmax = np.where(ok, np.nanmax(np.where(np.isfinite(v), v, -np.inf), axis=1),
                                np.nan)
                vmean = np.where(ok, np.nansum(v, axis=1) / np.maximum(
                    np.isfinite(v).sum(axis=1), 1), np.nan)
            self.results.per_part[part.name] = {"max": vmax, "mean": vmean}
        self.results.units = self.UNITS
        self.results.label = self.LABEL


class DesiredPositionDistance(_RunAnalysis):
    """The paper's measure: distance from the desired position (see module docstring).

    Parameters
    ----------
    run : rackstress.stress.rundata.RunData
        A run opened by :func:`rackstress.stress.load_run`.
    parts : list of str, optional
        The parts to analyse (default: every part with a rest shape; racks and sediment not).
    fit : {"robust", "plain"}
        The best-fit rigid motion that carries the original positions (``lib/rigid.py``).

    Examples
    --------
    ``docs/api.md`` runs a plane-rack scene and reads ``DesiredPositionDistance(run).run()``:
    ``results.per_particle`` is frames × particles, ``results.per_part[name]["max"]`` per frame.
    """

    NAME = "paper"
    LABEL = "distance from desired position"
    UNITS = "length units"

    def __init__(self, run, parts=None, fit: str = "robust", **kwargs):
        super().__init__(run, parts, **kwargs)
        if fit not in FITS:
            raise StressInputError(f"unknown fit '{fit}'; choose one of {', '.join(FITS)}")
        self.fit = fit
        self._o = run.o

    def _distance(self, p: np.ndarray) -> np.ndarray:
        out = np.full(len(p), np.nan)
        fit = FITS[self.fit]
        for part in self.parts:
            idx = part.index
            out[idx] = fit(self._o[idx], p[idx])[2]
        return out

    def _measure(self, p):
        return self._distance(p)


class AccumulatedDistance(DesiredPositionDistance):
    """∫ distance dt per particle: the paper's "magnitude and duration" (module docstring).

    ``results.distance`` keeps the instantaneous distance of every frame as well. Analyse every
    frame (the default): the integral uses the frames it is given.
    """

    NAME = "accumulated"
    LABEL = "accumulated distance from desired position"
    UNITS = "length × time units"

    def _prepare(self):
        super()._prepare()
        self.results.distance = np.full_like(self.results.per_particle, np.nan)
        self._acc = np.zeros(self.run_data.n_atoms)
        self._prev = None

    def _measure(self, p):
        d = self._distance(p)
        t = self.results.steps[self._frame_index] * self.run_data.dt
        if self._prev is not None:
            d_prev, t_prev = self._prev
            self._acc += 0.5 * (np.nan_to_num(d) + np.nan_to_num(d_prev)) * (t - t_prev)
        self._prev = (d, t)
        self.results.distance[self._frame_index] = d
        acc = self._acc.copy()
        acc[~np.isfinite(d)] = np.nan
        return acc


# ----------------------------------------------------------------------------- local strain
def von_mises_strain(E: np.ndarray) -> np.ndarray:
    """η of Green–Lagrange strain tensors E (..., 3, 3), as OVITO defines it."""
    xx, yy, zz = E[..., 0, 0], E[..., 1, 1], E[..., 2, 2]
    return np.sqrt(E[..., 0, 1] ** 2 + E[..., 1, 2] ** 2 + E[..., 0, 2] ** 2
                   + ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2) / 6.0)


def _bincount3(i: np.ndarray, a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Σ over pairs with first index i of the outer products a bᵀ, per particle: (n, 3, 3)."""
    out = np.empty((n, 3, 3))
    for r in range(3):
        for c in range(3):
            out[:, r, c] = np.bincount(i, weights=a[:, r] * b[:, c], minlength=n)
    return out


class Neighbourhoods:
    """Each particle's strain neighbourhood in the original configuration (Falk–Langer): the
    pairs (I, J) within the cutoff of each part, d₀ = o_J − o_I, the pseudo-inverse of
    V = Σ d₀ d₀ᵀ, its rank and, for a planar neighbourhood, the plane's basis t1, t2 and normal
    n0; ``valid`` where the fit is defined (rank ≥ 2, in an analysed part)."""

    def __init__(self, run, parts, cutoff=None, cutoff_factor: float = CUTOFF_FACTOR,
                 cutoffs: dict | None = None):
        o, n = run.o, run.n_atoms
        I, J = [], []
        self.cutoffs = {}
        for part in parts:
            if part.n < 2:
                continue
            po = o[part.index]
            tree = cKDTree(po)
            if cutoffs and part.name in cutoffs:    # a part's cutoff from all its particles
                rc = cutoffs[part.name]
            else:
                spacing = float(np.median(tree.query(po, k=2)[0][:, 1]))
                rc = cutoff if cutoff is not None else cutoff_factor * spacing
            self.cutoffs[part.name] = rc
            pairs = tree.query_pairs(rc * (1 + 1e-9), output_type="ndarray")
            if len(pairs):
                gi, gj = part.index[pairs[:, 0]], part.index[pairs[:, 1]]
                I += [gi, gj]
                J += [gj, gi]
        self.I = np.concatenate(I) if I else np.zeros(0, dtype=np.int64)
        self.J = np.concatenate(J) if J else np.zeros(0, dtype=np.int64)
        self.d0 = o[self.J] - o[self.I]
        V = _bincount3(self.I, self.d0, self.d0, n)
        lam, vec = np.linalg.eigh(V)                      # ascending eigenvalues
        top = lam[:, 2:3]
        nonzero = lam > RANK_TOL * np.maximum(top, np.finfo(float).tiny)
        self.rank = nonzero.sum(axis=1)
        inv = np.where(nonzero, 1.0 / np.where(nonzero, lam, 1.0), 0.0)
        self.Vpinv = np.einsum("nik,nk,njk->nij", vec, inv, vec)
        # planar neighbourhoods: in-plane basis t1, t2 and normal n0 = t1 × t2
        self.t1, self.t2 = vec[:, :, 1], vec[:, :, 2]
        self.n0 = np.cross(self.t1, self.t2)
        in_parts = np.zeros(n, dtype=bool)
        for part in parts:
            in_parts[part.index] = True
        self.in_parts = in_parts
        self.valid = (self.rank >= 2) & in_parts
        self._csr = None

    def csr(self):
        """(indptr, neighbours): each particle's J in the order of the pairs (CSR), the order
        in which the NumPy path sums them."""
        if self._csr is None:
            order = np.argsort(self.I, kind="stable")
            indptr = np.zeros(len(self.in_parts) + 1, dtype=np.int64)
            np.cumsum(np.bincount(self.I, minlength=len(self.in_parts)), out=indptr[1:])
            self._csr = (indptr, np.ascontiguousarray(self.J[order], dtype=np.int64))
        return self._csr


def neighbourhoods(run, parts, cutoff=None, cutoff_factor: float = CUTOFF_FACTOR):
    """The :class:`Neighbourhoods` of ``parts`` (one search, shared by η and D²min)."""
    return Neighbourhoods(run, parts, cutoff, cutoff_factor)


class _AffineStrain(_RunAnalysis):
    """Falk–Langer affine fit of each particle's neighbourhood; results: both η and D²min."""

    def __init__(self, run, parts=None, cutoff: float | None = None,
                 cutoff_factor: float = CUTOFF_FACTOR, **kwargs):
        super().__init__(run, parts, **kwargs)
        if cutoff is not None and not cutoff > 0:
            raise StressInputError(f"strain cutoff must be positive, got {cutoff}")
        self.cutoff, self.cutoff_factor = cutoff, float(cutoff_factor)

    def _prepare(self):
        super()._prepare()
        hood = neighbourhoods(self.run_data, self.parts, self.cutoff, self.cutoff_factor)
        self.results.cutoffs = hood.cutoffs
        self._I, self._J, self._d0 = hood.I, hood.J, hood.d0
        self._Vpinv, self._rank = hood.Vpinv, hood.rank
        self._t1, self._t2, self._n0 = hood.t1, hood.t2, hood.n0
        self._valid, self._in_parts = hood.valid, hood.in_parts
        n = self.run_data.n_atoms
        self.results.von_mises = np.full((self.n_frames, n), np.nan)
        self.results.d2min = np.full((self.n_frames, n), np.nan)

    def deformation_gradient(self, p: np.ndarray) -> np.ndarray:
        """Best-fit F of every particle's neighbourhood at positions p (n, 3, 3)."""
        n = len(p)
        d = p[self._J] - p[self._I]
        W = _bincount3(self._I, d, self._d0, n)
        F = W @ self._Vpinv
        planar = self._rank == 2
        if planar.any():
            a = np.einsum("nij,nj->ni", F[planar], self._t1[planar])
            b = np.einsum("nij,nj->ni", F[planar], self._t2[planar])
            nd = np.cross(a, b)
            norm = np.linalg.norm(nd, axis=1, keepdims=True)
            nd = nd / np.where(norm > 0, norm, 1.0)
            F[planar] += nd[:, :, None] * self._n0[planar][:, None, :]
        return F

    def _measure(self, p):
        n = len(p)
        F = self.deformation_gradient(p)
        E = 0.5 * (np.transpose(F, (0, 2, 1)) @ F - np.eye(3))
        eta = von_mises_strain(E)
        d = p[self._J] - p[self._I]
        r = d - np.einsum("nij,nj->ni", F[self._I], self._d0)
        d2 = np.bincount(self._I, weights=(r * r).sum(axis=1), minlength=n)
        eta[~self._valid] = np.nan
        d2[~self._valid] = np.nan
        k = self._frame_index
        self.results.von_mises[k], self.results.d2min[k] = eta, d2
        return eta if self.NAME == "strain" else d2


class VonMisesStrain(_AffineStrain):
    """Local von Mises shear strain η (module docstring); ``results.d2min`` comes along."""

    NAME = "strain"
    LABEL = "von Mises shear strain"
    UNITS = "dimensionless"


class NonAffineD2min(_AffineStrain):
    """Non-affine squared displacement D²min (module docstring); ``results.von_mises`` too."""

    NAME = "d2min"
    LABEL = "non-affine displacement D²min"
    UNITS = "length² units"


# ----------------------------------------------------------------------------- all at once
#: Bytes of temporaries one chunk of frames may take in :func:`measure_frames`.
CHUNK_BYTES = 128 * 2 ** 20


def _mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Stacks of 3 × 3 products A @ B, written out (np.matmul loops over tiny matrices)."""
    return (A[..., :, 0, None] * B[..., None, 0, :] + A[..., :, 1, None] * B[..., None, 1, :]
            + A[..., :, 2, None] * B[..., None, 2, :])


def _mv(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Stacks of 3 × 3 matrix-vector products A @ v, written out."""
    return A[..., 0] * v[..., 0, None] + A[..., 1] * v[..., 1, None] + A[..., 2] * v[..., 2, None]


def strain_frames(hood: Neighbourhoods, o: np.ndarray, P: np.ndarray):
    """η and D²min of :class:`VonMisesStrain` for frames ``P`` (f, n, 3) at once: (f, n) each.

    Only neighbourhoods where something moved are fitted. A particle whose neighbours and itself
    are all at their original positions in a frame has d = d₀ for every pair, so W = V, F = I
    (full rank: V V⁻¹; planar: the in-plane projector V V⁺ plus n₀ n₀ᵀ) and η = D²min = 0
    exactly; they are set so rather than fitted (the resting sediment of a MagPod run).
    Σ over pairs is one sparse product for all frames of the chunk."""
    from scipy.sparse import csr_matrix

    nf, n = P.shape[:2]
    eta = np.zeros((nf, n))
    d2 = np.zeros((nf, n))
    I, J, d0 = hood.I, hood.J, hood.d0
    off = (P != o[None]).any(axis=2)                              # (f, n) moved rows
    if off.any() and len(I):
        touched = off.any(axis=0)
        tp = np.zeros(n, dtype=bool)                              # fits needed: I or a J moved
        np.logical_or.at(tp, I, touched[J])
        tp |= touched & hood.valid
        sel = tp[I]
        Is, Js, d0s = I[sel], J[sel], d0[sel]
        rows = np.flatnonzero(tp)
        local = np.full(n, -1, dtype=np.int64)
        local[rows] = np.arange(len(rows))
        A = csr_matrix((np.ones(len(Is)), (local[Is], np.arange(len(Is)))),
                       shape=(len(rows), len(Is)))
        Q = np.ascontiguousarray(P.transpose(1, 0, 2))             # (n, f, 3): rows gather whole
        d = Q[Js] - Q[Is]                                         # (m, f, 3)
        X = (d[:, :, :, None] * d0s[:, None, None, :]).reshape(len(Is), nf * 9)
        W = (A @ X).reshape(len(rows), nf, 3, 3)
        F = _mm(W, hood.Vpinv[rows][:, None])                     # (r, f, 3, 3)
        planar = hood.rank[rows] == 2
        if planar.any():
            t1, t2, n0 = hood.t1[rows][planar], hood.t2[rows][planar], hood.n0[rows][planar]
            Fp = F[planar]
            a = _mv(Fp, t1[:, None])
            b = _mv(Fp, t2[:, None])
            nd = np.cross(a, b)
            norm = np.sqrt((nd * nd).sum(axis=2, keepdims=True))
            nd = nd / np.where(norm > 0, norm, 1.0)
            F[planar] = Fp + nd[:, :, :, None] * n0[:, None, None, :]
        E = 0.5 * (_mm(F.transpose(0, 1, 3, 2), F) - np.eye(3))
        eta[:, rows] = von_mises_strain(E).T
        r = d - _mv(F[local[Is]], d0s[:, None])
        rr = (r * r).sum(axis=2)                                  # (m, f)
        d2[:, rows] = (A @ rr).T
    eta[:, ~hood.valid] = np.nan
    d2[:, ~hood.valid] = np.nan
    return eta, d2


def paper_frames(run, P: np.ndarray, parts, fit: str = "robust") -> np.ndarray:
    """The paper's distance (:class:`DesiredPositionDistance`) for frames ``P`` at once: each
    part's fits of every frame (:func:`rackstress.lib.rigid.robust_fit_frames`, compiled:
    :func:`rackstress.stress.kernels.robust_fit_frames`). A
    sediment has no rest shape (module docstring of :mod:`.rundata`): its desired position is
    its original position, so its distance is |p − o| (zero where it rests)."""
    from rackstress.stress.kernels import robust_fit_frames

    o = run.o
    out = np.full(P.shape[:2], np.nan)
    for part in parts:
        idx = part.index
        if part.kind == "sediment":
            out[:, idx] = np.linalg.norm(P[:, idx] - o[idx][None], axis=2)
        elif fit == "robust":
            out[:, idx] = robust_fit_frames(o[idx], P[:, idx])
        else:
            out[:, idx] = np.stack([FITS[fit](o[idx], p[idx])[2] for p in P])
    return out


def frame_positions(run, ks) -> np.ndarray:
    """Positions of frames ``ks`` stacked (len(ks), n, 3), float64."""
    return np.stack([positions(run.trajectory[k]) for k in ks])


def strain(hood: Neighbourhoods, o: np.ndarray, P: np.ndarray):
    """(η, D²min) of frames ``P``: the compiled loop (:mod:`rackstress.stress.kernels`) where
    numba is present, else :func:`strain_frames`; the two agree to round-off (tests)."""
    from rackstress.stress import kernels

    if kernels.available():
        kernels.wait_warm()
        return kernels.strain(hood, o, P)
    return strain_frames(hood, o, P)


def measure_frames(run, progress=None, head=None) -> dict:
    """Every default measure of every frame, computed together in chunks of frames: ``steps``,
    ``paper``, ``accumulated``, ``strain``, ``d2min`` ((frames, n_atoms) each): the values of
    :class:`AccumulatedDistance` and :class:`VonMisesStrain` (robust fit, default cutoff) to
    round-off, without their per-frame overhead. ``progress``: called with the frames done.
    ``head``: chunks already measured while the run was written
    (:func:`rackstress.stress.post.follow`): ``head.hood`` and ``head.chunk(run, ks)`` → the
    (paper, strain, d2min) of frames ``ks`` or None; those are the values this function
    computes for the same frames (the same calls on the same positions)."""
    parts = list(run.parts.values())
    nf, n = run.index.n_frames, run.n_atoms
    hood = getattr(head, "hood", None) or neighbourhoods(run, parts)
    steps = np.asarray(run.steps, dtype=np.int64)
    out = {m: np.empty((nf, n)) for m in ("paper", "strain", "d2min")}
    chunk = frame_chunk(n, hood, nf)
    for a in range(0, nf, chunk):
        ks = range(a, min(nf, a + chunk))
        got = head.chunk(run, ks) if head is not None else None
        if got is None:
            got = measure_chunk(run, hood, parts, ks)
        out["paper"][a:a + len(ks)], out["strain"][a:a + len(ks)], \
            out["d2min"][a:a + len(ks)] = got
        if progress is not None:
            progress(len(ks))
    out["accumulated"] = _accumulate(out["paper"], steps, run.dt)
    out["steps"] = steps
    return out


def frame_chunk(n: int, hood: Neighbourhoods, nf: int) -> int:
    """Frames measured together by :func:`measure_frames` (temporaries within CHUNK_BYTES)."""
    per_frame = max(n * 24 * 4, len(hood.I) * 8 * 30, 1)
    return int(max(1, min(nf, CHUNK_BYTES // per_frame)))


def measure_chunk(run, hood: Neighbourhoods, parts, ks) -> tuple:
    """(paper, strain, d2min) of frames ``ks``, (len(ks), n_atoms) each."""
    P = frame_positions(run, ks)
    return (paper_frames(run, P, parts), *strain(hood, run.o, P))


def _accumulate(d: np.ndarray, steps: np.ndarray, dt: float) -> np.ndarray:
    """∫ d dt by the trapezoid rule, summed frame after frame as AccumulatedDistance does."""
    dn = np.nan_to_num(d)
    t = steps * dt
    acc = np.zeros(d.shape)
    if len(d) > 1:
        inc = 0.5 * (dn[1:] + dn[:-1]) * np.diff(t)[:, None]
        acc[1:] = np.cumsum(inc, axis=0)
    acc[~np.isfinite(d)] = np.nan
    return acc


# ----------------------------------------------------------------------------- moving columns
class Columns:
    """(n_frames, n_atoms) values of which only the columns ``cols`` (sorted atom rows) vary
    from frame to frame; every other column holds ``rest`` in every frame. A resting sediment
    of a million particles costs its moving few thousand columns, not n_frames × a million.
    Indexing as the dense array would: ``v[k]`` (a frame), ``v[:, idx]``, ``v[k, idx]``."""

    ndim = 2
    dtype = np.dtype(np.float64)

    def __init__(self, cols: np.ndarray, data: np.ndarray, rest: np.ndarray):
        self.cols, self.data, self.rest = np.asarray(cols, dtype=np.int64), data, rest

    @property
    def shape(self) -> tuple:
        return (self.data.shape[0], len(self.rest))

    def __len__(self) -> int:
        return self.data.shape[0]

    def _where(self, idx: np.ndarray):
        pos = np.searchsorted(self.cols, idx)
        pos = np.minimum(pos, max(len(self.cols) - 1, 0))
        hit = (self.cols[pos] == idx) if len(self.cols) else np.zeros(len(idx), dtype=bool)
        return pos[hit], hit

    def __getitem__(self, key):
        if isinstance(key, (int, np.integer)):
            out = self.rest.copy()
            out[self.cols] = self.data[key]
            return out
        if isinstance(key, slice):
            return Columns(self.cols, self.data[key], self.rest)
        if isinstance(key, tuple) and len(key) == 2:
            frames, idx = key
            idx = np.arange(len(self.rest))[idx] if isinstance(idx, slice) else \
                np.asarray(idx, dtype=np.int64)
            pos, hit = self._where(idx)
            got = self.data[frames]
            if got.ndim == 1:
                out = self.rest[idx].copy()
                out[hit] = got[pos]
            else:
                out = np.repeat(self.rest[idx][None], got.shape[0], axis=0)
                out[:, hit] = got[:, pos]
            return out
        raise TypeError(f"Columns cannot be indexed by {key!r}")

    def __array__(self, dtype=None, copy=None):
        out = np.repeat(self.rest[None], self.data.shape[0], axis=0)
        out[:, self.cols] = self.data
        return out if dtype is None else out.astype(dtype)


def moved_rows(run) -> np.ndarray:
    """Which particles are away from their original position in some frame (n_atoms bool)."""
    o = run.o
    moved = np.zeros(run.n_atoms, dtype=bool)
    for k in range(run.index.n_frames):
        moved |= (positions(run.trajectory[k]) != o).any(axis=1)
    return moved


def _near(tree, points: np.ndarray, r: float) -> np.ndarray:
    """Rows of ``tree`` within ``r`` of any of ``points`` (as the pairs within r are found)."""
    if not len(points):
        return np.zeros(0, dtype=np.int64)
    hits = tree.query_ball_point(points, r * (1 + 1e-9), return_sorted=False)
    return np.unique(np.fromiter((j for h in hits for j in h), dtype=np.int64))


def _valid_everywhere(po: np.ndarray, tree, rc: float) -> np.ndarray:
    """Where a part's strain fit is defined (rank of Σ d₀ d₀ᵀ ≥ 2, as :class:`Neighbourhoods`
    finds it), for every particle of the part: from its pairs within rc, the six distinct
    terms of Σ d₀ d₀ᵀ summed from both ends."""
    pairs = tree.query_pairs(rc * (1 + 1e-9), output_type="ndarray")
    n = len(po)
    V = np.zeros((n, 3, 3))
    if len(pairs):
        d = po[pairs[:, 1]] - po[pairs[:, 0]]
        for r in range(3):
            for c in range(r, 3):
                w = d[:, r] * d[:, c]
                V[:, r, c] = (np.bincount(pairs[:, 0], weights=w, minlength=n)
                              + np.bincount(pairs[:, 1], weights=w, minlength=n))
                V[:, c, r] = V[:, r, c]
    lam = np.linalg.eigvalsh(V)
    top = lam[:, 2:3]
    return (lam > RANK_TOL * np.maximum(top, np.finfo(float).tiny)).sum(axis=1) >= 2


def measure_columns(run, progress=None) -> dict:
    """:func:`measure_frames` over the particles whose measures can differ from their resting
    value: every particle of a part with a rest shape, and of a sediment the particles that
    moved in some frame and their strain neighbours (within the part's cutoff). A sediment
    particle that never moved, nor any neighbour of it, has p = o in every frame, so its
    distance |p − o| and its integral are 0 and its η and D²min are 0 (F = I exactly,
    :func:`strain_frames`) or NaN where its fit is undefined. Only those neighbours' original
    positions enter the fits, so the values of the moving columns are the dense path's (to the
    order of summation). Returns ``cols`` (sorted rows), ``steps``, per measure
    (frames, len(cols)) values and ``rest`` (n_atoms,) resting values per measure."""
    from types import SimpleNamespace

    o, n, nf = run.o, run.n_atoms, run.index.n_frames
    moved = moved_rows(run)
    cols = np.zeros(n, dtype=bool)           # computed and kept
    need = np.zeros(n, dtype=bool)           # computed as neighbours of what is kept
    valid_rest = np.ones(n, dtype=bool)
    cutoffs = {}
    for part in run.parts.values():
        idx = part.index
        if part.kind != "sediment" or part.n < 2:
            cols[idx] = True
            continue
        po = o[idx]
        tree = cKDTree(po)
        rc = CUTOFF_FACTOR * float(np.median(tree.query(po, k=2)[0][:, 1]))
        cutoffs[part.name] = rc
        m = np.flatnonzero(moved[idx])
        c = np.union1d(m, _near(tree, po[m], rc))
        u = np.union1d(c, _near(tree, po[c], rc))
        cols[idx[c]] = True
        need[idx[u]] = True
        valid_rest[idx] = _valid_everywhere(po, tree, rc)
    need |= cols
    U = np.flatnonzero(need)
    local = np.full(n, -1, dtype=np.int64)
    local[U] = np.arange(len(U))
    parts = [SimpleNamespace(name=p.name, kind=p.kind, index=local[p.index[need[p.index]]],
                             n=int(need[p.index].sum())) for p in run.parts.values()]
    sub = SimpleNamespace(o=o[U], n_atoms=len(U))
    hood = Neighbourhoods(sub, parts, cutoffs=cutoffs)
    keep = local[np.flatnonzero(cols)]
    steps = np.asarray(run.steps, dtype=np.int64)
    out = {m: np.empty((nf, len(keep))) for m in ("paper", "strain", "d2min")}
    chunk = frame_chunk(len(U), hood, nf)
    for a in range(0, nf, chunk):
        ks = range(a, min(nf, a + chunk))
        P = np.stack([positions(run.trajectory[k])[U] for k in ks])
        out["paper"][a:a + len(ks)] = paper_frames(sub, P, parts)[:, keep]
        eta, d2 = strain(hood, sub.o, P)
        out["strain"][a:a + len(ks)], out["d2min"][a:a + len(ks)] = eta[:, keep], d2[:, keep]
        if progress is not None:
            progress(len(ks))
    out["accumulated"] = _accumulate(out["paper"], steps, run.dt)
    out["steps"], out["cols"] = steps, np.flatnonzero(cols)
    undefined = np.where(valid_rest, 0.0, np.nan)
    out["rest"] = {"paper": np.zeros(n), "accumulated": np.zeros(n), "strain": undefined,
                   "d2min": undefined.copy()}
    return out


# ----------------------------------------------------------------------------- virial
_STRESS_COL = re.compile(r"^c_(.+)\[([1-6])\]$")


def stress_columns(columns) -> list | None:
    """The six per-atom stress columns c_NAME[1]..c_NAME[6] of a dump, or None."""
    found = {}
    for c in columns:
        m = _STRESS_COL.match(c)
        if m:
            found.setdefault(m.group(1), {})[int(m.group(2))] = c
    for name, cols in found.items():
        if len(cols) == 6:
            return [cols[k] for k in range(1, 7)]
    return None


class VirialStress(_RunAnalysis):
    """Von Mises equivalent of LAMMPS' per-atom stress; ``results.pressure`` = −tr σ / 3."""

    NAME = "virial"
    LABEL = "per-atom von Mises stress × volume"
    UNITS = "energy units"

    def __init__(self, run, parts=None, **kwargs):
        super().__init__(run, parts, **kwargs)
        cols = stress_columns(run.index.columns)
        if cols is None:
            raise DumpColumnsError(
                f"{run.index.path}: the run did not record per-atom virial stress (its columns "
                f"are '{' '.join(run.index.columns)}'); the 'virial' measure needs six columns "
                "c_NAME[1]..c_NAME[6] from 'compute NAME all stress/atom NULL' in the dump. Use "
                "--measure paper, accumulated, strain or d2min for this run.")
        self.columns = cols

    def _prepare(self):
        super()._prepare()
        self.results.pressure = np.full_like(self.results.per_particle, np.nan)

    def _measure(self, p):
        s = np.stack([self._ts.data[c] for c in self.columns], axis=1)
        xx, yy, zz, xy, xz, yz = s.T
        vm = np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2)
                     + 3.0 * (xy ** 2 + xz ** 2 + yz ** 2))
        mask = np.zeros(len(p), dtype=bool)
        for part in self.parts:
            mask[part.index] = True
        vm[~mask] = np.nan
        pr = -(xx + yy + zz) / 3.0
        pr[~mask] = np.nan
        self.results.pressure[self._frame_index] = pr
        return vm


# ----------------------------------------------------------------------------- stress
def material_parts(run) -> dict:
    """Part name → its ``scene.json`` record, for the parts with a material and a volume."""
    return {g["name"]: g for g in (run.scene or {}).get("groups", [])
            if g.get("material") and g.get("volume") and g["name"] in run.parts}


def stress_unit(run) -> str:
    """The scene's stress unit (``scene.json`` ``units.stress``; "stress units" if none)."""
    u = (run.scene or {}).get("units") or {}
    return u.get("stress") if u.get("name") not in (None, "paper") else "stress units"


#: what ``ParticleStress.results.contact_sides`` holds per frame and side of a contact: the
#: largest contact pressure on that side's particles from the other part, the particle (row),
#: how many of its particles it presses, the total force the other part puts on it (x, y, z)
CONTACT_SIDE = ("peak", "particle", "touching", "fx", "fy", "fz")


class ParticleStress(_RunAnalysis):
    """Stress per particle from the bindings' forces, in the scene's stress unit.

    For the parts with a material (``scene.json``: ``material``, ``volume``) and the run's
    ``bindings.npz`` (written when the run starts): the bindings' virial per particle volume
    W_i/V_i with each free face's cell moment restored (``"continuum"``), then recovered by a
    linear least-squares fit over each particle's patch (2.5 spacings, in its plane for a part
    one layer thick; its regular cells', :func:`rackstress.stress.tensor.regular_cells`, each
    where its value stands, :func:`rackstress.stress.tensor.sample_points`) evaluated at its
    recovery point — its centre inside the part, the surface point of its cell on the surface
    (``method="patch"``, the default: the stress where an engineer reads it, on the face);
    ``"continuum"`` at the particle centres; ``"virial"``: the plain W_i/V_i, exact in every
    section sum; ``"completed"``: surface-completed — each measured against converged FEA
    in docs/stress.md (:mod:`rackstress.stress.tensor`).
    ``results``: ``per_particle`` and ``von_mises`` (n_frames × n_atoms), ``stress`` (n_frames ×
    n_atoms × 6, xx yy zz xy yz xz), ``principal`` (× 3, largest first), ``safety`` (yield / von
    Mises where the material gives a yield) and ``bind_strain`` (each particle's largest binding
    strain |d/L0 − 1|, the small-strain check). NaN on the other parts.

    Examples
    --------
    >>> s = ParticleStress(load_run("runs/bar")).run()                     # doctest: +SKIP
    >>> s.results.von_mises[-1].max(), s.results.units                     # doctest: +SKIP
    (27.1, 'MPa')
    """

    NAME = "von_mises"
    LABEL = "von Mises stress"
    UNITS = "stress units"
    METHODS = ("patch", "continuum", "virial", "completed")

    def __init__(self, run, parts=None, method: str = "patch", **kwargs):
        mats = material_parts(run)
        super().__init__(run, list(mats) if parts is None else parts, **kwargs)
        if method not in self.METHODS:
            raise StressInputError(f"unknown stress method '{method}'; choose one of "
                                   f"{', '.join(self.METHODS)}")
        self.method = method
        self.UNITS = stress_unit(run)
        self.bindings = read_bindings(run)
        self.volume = read_volume_terms(run)
        self.contacts = read_contacts(run)
        self._mat = mats

    def _prepare(self):
        super()._prepare()
        run, n = self.run_data, self.run_data.n_atoms
        shape = (self.n_frames, n)
        self.results.von_mises = self.results.per_particle
        self.results.stress = np.full(shape + (6,), np.nan)
        self.results.principal = np.full(shape + (3,), np.nan)
        self.results.safety = np.full(shape, np.nan)
        self.results.bind_strain = np.full(shape, np.nan)
        if self.contacts is not None:
            self.results.contact_pressure = np.full(shape, np.nan)
            self.results.contact_sides = np.zeros((self.n_frames, len(self.contacts[0]),
                                                   len(CONTACT_SIDE)))
        V = np.full(n, np.nan)
        self._yield = np.full(n, np.nan)
        mine = [p for p in self.parts if p.name in self._mat]
        for part in mine:
            rec = self._mat[part.name]
            V[part.index] = float(rec["volume"])
            y = rec["material"].get("yield")
            if y:
                self._yield[part.index] = float(y)
        self._mask = np.zeros(n, dtype=bool)
        for part in mine:
            self._mask[part.index] = True
        b = self.bindings
        if b is not None:                    # only the bindings on the analysed particles,
            keep = self._mask[b[0]]          # grouped by particle (np.maximum.reduceat below)
            order = np.argsort(b[0][keep], kind="stable")
            b = tuple(x[keep][order] for x in b)
            i = b[0]
            self._starts = np.flatnonzero(np.r_[True, i[1:] != i[:-1]]) if len(i) else i
        self._b = b
        if b is None or not len(b[0]):
            self._W2S = None
            self._mask[:] = False
            return
        self._area = V ** (2.0 / 3.0)        # a whole cell's face: the contact's area a²
        Vi = read_volumes(run)               # each cell's own share of the part, if written
        self._V = V if Vi is None else np.where(np.isfinite(Vi) & self._mask, Vi, V)
        with np.errstate(divide="ignore", invalid="ignore"):   # the cells' shares (_contact)
            self._share = np.clip(self._V / V, 0.0, 1.0)
        self._gather = T.incidence(b[0], n)
        self._wm = None
        if self.method == "completed":
            A = T.binding_moment(run.o, b[0], b[1], b[2], n)
            # the interior's stiffness per whole cell (a boundary cell's own share is not it)
            self._W2S = T.completion(A, V, [p.index for p in mine])
        else:
            self._W2S = None
            if self.method in ("continuum", "patch"):
                self._wm = T.surface_moment(run.o, b[0], b[1], b[3], n)
                if self.volume is not None:
                    # where the volumetric term holds a face's overhang at its centroid,
                    # the cell's own moment is in its forces: not restored a second time
                    # (docs/stress.md "The cells' own moment", with the material's ν)
                    from rackstress.model.volume import centroid_owners

                    self._wm = np.where(centroid_owners(self.volume)[b[0]], 0.0, self._wm)
        self._held_faces = self._pressed = self._mirror = None
        if self.method in ("continuum", "patch"):
            a2 = np.full(n, np.inf)
            np.minimum.at(a2, b[0], b[3])            # each particle's nearest binding
            phi = read_fractions(run)                # both read the cells' extents and
            held, loads = boundary_rows(run)         # the supports, once
            faces = self._held_free_faces(run, mine, a2, phi, held)
            self._held_faces = self._support_faces(run, b, faces, phi, held.copy(), loads)
            self._mirror = self._mirror_shears(faces, phi, held)
            if self.volume is not None and (run.scene or {}).get("analysis") == "static":
                self._pressed = self._pressed_faces(run, mine, phi, held)
        self._patch = None
        if self.method == "patch":
            labels = np.full(n, -1, np.int64)
            points = np.asarray(run.o, float).copy()
            # the fits sample the regular cells, and the ones a support holds across a face (its
            # force in their stress; face_supports): docs/stress.md "Patch recovery"
            data = np.zeros(n, bool)
            samples = np.asarray(run.o, float).copy()
            for k, part in enumerate(mine):
                idx = np.asarray(part.index)
                labels[idx] = k
                data[idx] = face_supports(held[idx]).any(axis=1)
                # read on the part's face, where its cells end (φ)
                points[idx] = recovery_points_of(run, part)
                ap = a2[idx][np.isfinite(a2[idx])]
                if len(ap):
                    sp = float(np.sqrt(np.median(ap)))
                    part_phi = None if phi is None else phi[idx]
                    vol = volumetric(self.volume, part)
                    data[idx] |= T.regular_cells(run.o[idx], sp, part_phi, vol)
                    # each sample where its value stands; a held one at its particle (its
                    # support's force is in it)
                    nu = lattice_nu(self.volume, part, self._mat[part.name]["material"])
                    y = T.sample_points(run.o[idx], sp, part_phi, nu, vol)
                    samples[idx] = np.where(held[idx].any(axis=1)[:, None], run.o[idx], y)
            self.points = points
            a = float(np.sqrt(np.median(a2[np.isfinite(a2)])))
            self._patch = T.patch_matrix(run.o, a, points, labels, data=data,
                                         samples=samples)

    def _held_free_faces(self, run, mine, a2, phi, held):
        """The free faces of the cells a support holds across, or None: (n×3, per axis −1 or
        +1 where the particle is held along it and its lattice neighbour on that side is
        missing, 0 elsewhere; n, its part's spacing), what :meth:`_support_faces` and
        :meth:`_mirror_shears` read. Static runs (``phi`` written) only. ``a2``: each
        particle's nearest binding's squared length (its part's spacing)."""
        if phi is None or not held.any():
            return None
        faces, spacing = np.zeros((run.n_atoms, 3)), np.full(run.n_atoms, np.nan)
        for part in mine:
            idx = np.asarray(part.index)
            h = held[idx] & self._mask[idx, None]
            if not h.any() or not np.isfinite(a2[idx]).any():
                continue
            spacing[idx] = float(np.sqrt(np.median(a2[idx][np.isfinite(a2[idx])])))
            faces[idx] = np.where(h, T.free_faces(run.o[idx], spacing[idx[0]]), 0.0)
        return (faces, spacing) if faces.any() else None

    def _support_faces(self, run, b, faces, phi, held, loads):
        """The particles a support holds across a face of their cell (a roller, a symmetry
        plane, a clamp: a held direction along which the lattice neighbour is missing), or
        None: (rows, held n×3 mask, offset n×3 to the face, load n×3, the bindings acting on
        the rows and their incidence). The support's force acts on that face as the missing
        half of the bindings would: without it the layer held half a spacing off a symmetry
        plane read half the stress across the plane. The face lies (φ − ½)·a beyond the
        particle (φ its cell's extent along the axis, ``read_fractions``): a particle on the
        plane itself has half a cell, its stress whole already, and gets nothing. Static runs
        (``phi`` written) only: a dynamic run's loads at a frame are not in its files.
        ``faces``: :meth:`_held_free_faces`; ``phi``, ``held``, ``loads``: the run's
        ``read_fractions`` and ``boundary_rows``."""
        if b is None or not len(b[0]) or faces is None:
            return None
        held &= self._mask[:, None]
        side, spacing = faces
        reach = T.cell_reach(phi) * np.nan_to_num(spacing)[:, None]
        off = side * reach
        rows = np.flatnonzero(np.any(off != 0.0, axis=1))
        if not len(rows):
            return None
        at = np.full(run.n_atoms, -1, np.int64)
        at[rows] = np.arange(len(rows))
        sel = np.flatnonzero(at[b[0]] >= 0)             # the bindings acting on them
        return rows, held[rows], off[rows], loads[rows], sel, T.incidence(at[b[0][sel]],
                                                                           len(rows))

    def _mirror_shears(self, faces, phi, held) -> np.ndarray | None:
        """The shear components to read as zero (n, 6 bool), or None: σ_nt of a particle on a
        plane a support holds it across (a roller, a symmetry plane: held along n, its lattice
        neighbour across n missing, its cell ending at the particle, φ_n = ½) for each axis t
        the support leaves free. Its mirror image's bindings, which the support stands for,
        would cancel the shear its own bindings put in its virial; the plane carries none. Where
        the plane meets a free face the particle's bindings are one-sided and read a shear
        that grows with refinement: LE1's particle at D, on its symmetry plane and the
        membrane's inner edge, read σ_xy 20 … 23 MPa at 50 … 12.5 mm, its von Mises 8 % above
        its σ_yy (bench nafems' scene, by hand). A clamp (held along t too) keeps its shear.
        ``faces``: :meth:`_held_free_faces`."""
        if faces is None:
            return None
        on = (faces[0] != 0) & (np.abs(np.nan_to_num(phi, nan=1.0) - 0.5) < 1e-6)
        out = np.zeros((len(on), 6), bool)
        for c, (n_, t) in enumerate(T.VOIGT):
            if n_ != t:
                out[:, c] = (on[:, n_] & ~held[:, t]) | (on[:, t] & ~held[:, n_])
        return out if out.any() else None

    def _pressed_faces(self, run, mine, phi, held) -> np.ndarray | None:
        """The stress a pressure puts on the cells it presses that their bindings and terms do
        not carry (n, 6), or None (docs/stress.md "A pressed face"). The bindings reach
        inward only, so a pressed layer's virial carries σ_nn over the inner part of its cell;
        the overhang beyond the particle, (φ − ½)·a thick, carries σ_nn = −p as well and, held
        in its plane by the layer, the prestress λ/(λ + 2μ)·σ_nn = ν/(1 − ν)·σ_nn along each
        axis the layer has a neighbour on, whose push the forces already apply
        (model.volume.loaded_overhang). Each is added over the cell's share (φ − ½)/φ, but
        not across a face a support holds: the support's force there, the push included, is
        counted on that face already (:meth:`_support_virial`). ``phi``, ``held``: the run's
        ``read_fractions`` and ``boundary_rows``."""
        fs = face_stress(run)
        if fs is None:
            return None
        out = np.zeros((run.n_atoms, 6))
        for part in mine:
            idx = np.asarray(part.index)
            if not np.any(fs[idx]):
                continue
            rec = self._mat[part.name]
            nu = float(rec["material"]["nu"])
            side = T.lattice_sides(run.o[idx], float(rec["spacing"]))
            one = side.sum(axis=2) == 1
            # a face a support holds across carries its share already: the support's force,
            # the push included, on that face (_support_virial)
            has = side.any(axis=2) & ~(one & held[idx])
            f = np.ones((len(idx), 3)) if phi is None else np.nan_to_num(phi[idx], nan=1.0)
            M = np.zeros((len(idx), 3, 3))
            for k in range(3):
                sn = np.where(one[:, k] & ~held[idx, k], fs[idx, k], 0.0) \
                    * np.clip(f[:, k] - 0.5, 0.0, 1.0) / np.maximum(f[:, k], 1e-12)
                M[:, k, k] += sn
                for q in range(3):
                    if q != k:
                        M[:, q, q] += nu / (1.0 - nu) * sn * has[:, q]
            out[idx] = np.stack([M[:, r, c] for r, c in T.VOIGT], axis=1)
        return out

    def _support_virial(self, p, d, d2) -> np.ndarray:
        """W of the supports' forces on the faces they hold (n, 6): Σ_k x_k ⊗ R_k symmetrized,
        R = −(the bindings', the volumetric term's and the load's force) in the held
        directions, x_k the vector from the particle to the face across axis k where it is
        held there, else (a clamp's shear) the held faces' mean point (``_support_faces``)."""
        rows, held, off, loads, sel, gather = self._held_faces
        k, q = self._b[2][sel], self._b[3][sel]
        with np.errstate(divide="ignore", invalid="ignore"):
            f = (k * (1.0 - q / d2[sel]))[:, None] * d[sel]
        F = np.asarray(gather @ f)
        if self.volume is not None:      # its κ are m·κ (read_volume_terms): forces
            from rackstress.model.volume import Volume

            F = F + Volume.accel(p, self.volume)[rows]
        R = -np.where(held, F + loads, 0.0)
        mean = off / np.maximum((off != 0.0).sum(axis=1, keepdims=True), 1)
        M = np.zeros((len(rows), 3, 3))
        for k in range(3):
            at = np.where((off[:, k] != 0.0)[:, None], np.eye(3)[k] * off[:, k:k + 1], mean)
            M[:, :, k] = at * R[:, k:k + 1]
        W = np.zeros((len(p), 6))
        W[rows] = np.stack([0.5 * (M[:, r, c] + M[:, c, r]) for r, c in T.VOIGT], axis=1)
        return W

    def _measure(self, p):
        k, out = self._frame_index, np.full(len(p), np.nan)
        if not self._mask.any():
            return out
        b = self._b
        d = p[b[1]] - p[b[0]]
        d2 = np.einsum("ij,ij->i", d, d)
        s = T.stress(p, b, self._W2S, self._V, W=T.virial_of(d, d2, b[2], b[3], self._gather))
        if self.volume is not None:       # the material's Poisson's ratio: its own virial
            with np.errstate(divide="ignore", invalid="ignore"):   # V = 0 off the mask
                s = s + T.volume_virial(p, self.volume) / self._V[:, None]
        if self.contacts is not None:     # the contact's force on the layers that touch
            s = s + self._contact(p, k)
        if self._held_faces is not None:  # a support's force on the face it holds
            with np.errstate(divide="ignore", invalid="ignore"):   # V = 0 off the mask
                s = s + self._support_virial(p, d, d2) / self._V[:, None]
        if self._pressed is not None and self._ts.frame > 0:   # (frame 0: not yet loaded)
            s = s + self._pressed
        if self._wm is not None:
            s = T.moment_corrected(s, b[0], b[1], self._wm, self._gather)
        if self._mirror is not None:      # no shear on a plane a roller holds
            s = np.where(self._mirror, 0.0, s)
        if self._patch is not None:
            s[~self._mask] = 0.0
            s = np.asarray(self._patch @ s)
            if self._mirror is not None:  # nor where the fit reads it, on that plane
                s = np.where(self._mirror, 0.0, s)
        s[~self._mask] = np.nan
        vm = T.von_mises(s)
        self.results.stress[k] = T.to_output(s)
        self.results.principal[k] = T.principal(s)
        with np.errstate(divide="ignore", invalid="ignore"):
            self.results.safety[k] = np.where(vm > 0, self._yield / vm, np.inf)
        self.results.safety[k][~np.isfinite(self._yield) | ~self._mask] = np.nan
        strain = np.abs(np.sqrt(d2 / b[3]) - 1.0)
        bs = np.full(len(p), np.nan)
        bs[b[0][self._starts]] = np.maximum.reduceat(strain, self._starts)
        bs[~self._mask] = np.nan
        self.results.bind_strain[k] = bs
        return vm


    def _contact(self, p: np.ndarray, k: int) -> np.ndarray:
        """The contacts' virial per particle volume at ``p`` (n, 6): a pair in contact is a
        binding of length R (:func:`contact_pairs`), its force shared by both particles'
        virials as a binding's, as far as its line lies inside each particle's cell; into
        ``results.contact_pressure`` each particle's contact force over its cell's face area a²
        (zero where nothing touches), and into ``results.contact_sides`` per side of each
        contact its largest pressure, that particle, the particles it presses and its total
        force (:data:`CONTACT_SIDE`)."""
        i, j, kc, R2, side = contact_pairs(p, self.contacts)
        n = len(p)
        d = p[j] - p[i]
        d2 = np.einsum("ij,ij->i", d, d)
        # the part of the pair's line inside the particle's own cell: half of it where the
        # cell is whole (the part's surface half a spacing beyond the particle, the contact's
        # force crossing the cell as a binding's does), none where the surface passes through
        # the particle (a cell whose share of the part is half: its stress, the bindings'
        # virial over that share, already carries the force the contact puts on it);
        # between, (2·share − 1)
        w = np.clip(2.0 * self._share[i] - 1.0, 0.0, 1.0)
        W = T.virial_of(d, d2, kc * w, R2, T.incidence(i, n))
        f = (kc * (1.0 - R2 / d2))[:, None] * d if len(i) else np.zeros((0, 3))
        F = np.stack([np.bincount(i, weights=f[:, c], minlength=n) for c in range(3)], axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            pc = np.linalg.norm(F, axis=1) / self._area
            out = W / self._V[:, None]
        pc[~self._mask] = np.nan
        self.results.contact_pressure[k] = pc
        for m, (st, _, _) in enumerate(self.contacts[0]):
            on = side == m
            Fs = np.stack([np.bincount(i[on] - st.start, weights=f[on, c],
                                       minlength=st.stop - st.start) for c in range(3)], axis=1)
            ps = np.linalg.norm(Fs, axis=1) / self._area[st]
            top = int(np.argmax(ps)) if len(ps) else 0
            self.results.contact_sides[k, m] = (ps[top] if len(ps) else 0.0, st.start + top,
                                                np.count_nonzero(ps > 0), *Fs.sum(axis=0))
        out[~self._mask] = 0.0
        return out


def bindings_array(rundir, key: str, shape: tuple, rows=slice(None)):
    """The array ``key`` of the run directory's ``bindings.npz`` (its ``rows``: one part's
    slice) as float64 when it has ``shape``, or None: a file without it (written before it
    was) or of another run."""
    from rackstress.lib.runfiles import BINDINGS

    path = Path(rundir) / BINDINGS
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        if key not in z.files:
            return None
        x = z[key][rows].astype(np.float64)
    return x if x.shape == shape else None


def read_fractions(run):
    """Each particle's cell extent per axis in spacings (n, 3) from the run's ``bindings.npz``
    (``phi``, :func:`rackstress.runs.run.fractions_of`: static runs), or None."""
    return bindings_array(run.rundir, "phi", (run.n_atoms, 3))


def read_surface(rundir, name: str):
    """The part ``name``'s closed surface (vertices, faces) as the run kept it in
    ``singular.npz`` (:func:`rackstress.runs.run.write_singular`), or None (no such file, a
    part without a material or without a surface: a box, a lattice)."""
    from rackstress.lib.runfiles import SINGULAR

    try:
        with np.load(Path(rundir) / SINGULAR, allow_pickle=False) as z:
            k = [str(v) for v in z["parts"]].index(name)
            return z[f"surface_{k}_vertices"], z[f"surface_{k}_faces"]
    except (OSError, KeyError, ValueError):
        return None


def recovery_points_of(run, part) -> np.ndarray:
    """Where the ``von_mises`` measure (patch route) reads the stress of the particles of
    ``part`` (a :class:`~rackstress.stress.rundata.Part`):
    :func:`rackstress.stress.tensor.part_recovery_points` with the run's cell extents
    (``read_fractions``) and the part's surface (``read_surface``), as
    :class:`ParticleStress` reads them."""
    # kept on the run, once per part: the governing stress, its plot and the pictures each
    # ask, and moving the points onto the surface takes a quarter second on 20,000 particles
    kept = run.__dict__.setdefault("_recovery_points", {})
    idx = np.asarray(part.index)
    key = (part.name, len(idx), int(idx[0]) if len(idx) else -1)
    if key not in kept:
        phi = read_fractions(run)
        kept[key] = T.part_recovery_points(run.o[idx], phi=None if phi is None else phi[idx],
                                           surface=read_surface(run.rundir, part.name))
        kept[key].setflags(write=False)
    return kept[key]


def read_volumes(run):
    """Each particle's volume from the run's ``bindings.npz`` (``V``: the boundary cells' own
    share of the part, docs/calibration.md), or None for a file without it."""
    return bindings_array(run.rundir, "V", (run.n_atoms,))


def read_volume_terms(run):
    """The volumetric terms of the run's ``bindings.npz`` (:func:`rackstress.runs.run.
    write_bindings`: a material's Poisson's ratio) as a :class:`rackstress.model.volume.
    VolumeTerms` with m·κ for κ (energies: its virial is a force × length), or None."""
    import scipy.sparse as sp

    from rackstress.lib.runfiles import BINDINGS
    from rackstress.model.volume import VolumeTerms

    path = Path(run.rundir) / BINDINGS
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        if "vi" not in z.files:
            return None
        n = run.n_atoms
        i, j = z["vi"].astype(np.int64), z["vj"].astype(np.int64)
        owner, K = z["vowner"].astype(np.int64), z["vK"].astype(np.float64)
        if len(i) and (min(i.min(), j.min()) < 0 or max(i.max(), j.max()) >= n):
            raise StressInputError(f"{path}: a volumetric term names particle "
                                   f"{int(max(i.max(), j.max()))} but the run has {n}: the file "
                                   "is not of this run")
        C = sp.csr_matrix((z["vC_data"], z["vC_indices"], z["vC_indptr"]),
                          shape=(len(owner), len(i)))
        return VolumeTerms(i, j, z["vL"].astype(np.float64), owner, K, C, n)


def read_contacts(run):
    """The material contacts of the run's ``bindings.npz`` (:func:`rackstress.runs.run.
    write_bindings`): a list of (target rows, source rows, m·c) per side of each contact and
    every particle's radius, or None for a run without contact."""
    from rackstress.lib.runfiles import BINDINGS

    path = Path(run.rundir) / BINDINGS
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        if "ct" not in z.files:
            return None
        ct, ck, r = z["ct"].astype(np.int64), z["ck"].astype(np.float64), z["r"]
    if len(r) != run.n_atoms or (len(ct) and ct.max() > run.n_atoms):
        raise StressInputError(f"{path}: its contacts name particles beyond the run's "
                               f"{run.n_atoms}: the file is not of this run")
    return [(slice(int(a), int(b)), slice(int(c), int(d)), float(k))
            for (a, b, c, d), k in zip(ct, ck)], np.asarray(r, np.float64)


def contact_parts(run, sides) -> list:
    """(side index, target part, source part) of each side of ``sides`` (from
    :func:`read_contacts`) whose two parts the run has: the parts a contact is between."""
    names = {p.index[0]: name for name, p in run.parts.items() if len(p.index)}
    return [(m, names[st.start], names[ss.start]) for m, (st, ss, _k) in enumerate(sides)
            if st.start in names and ss.start in names]


def contact_pairs(p: np.ndarray, contacts) -> tuple:
    """The pairs in contact at ``p`` (``contacts`` from :func:`read_contacts`), each listed
    from both ends as a binding is: (i, j, m·c, R², side) with R the sum of the two radii and
    side the contact's entry it belongs to, the pairs within R (Eq. 10 acts there alone, zero
    at R; in contact it is Eq. 12 with L0 = R: :func:`rackstress.lib.cells.touching_pairs`)."""
    from rackstress.lib.cells import touching_pairs

    sides, r = contacts
    I, J, K, Q, S = [], [], [], [], []
    for side, (st, ss, k) in enumerate(sides):
        i, j, R2 = touching_pairs(p[st], p[ss], r[st], r[ss])
        I.append(i + st.start), J.append(j + ss.start), K.append(np.full(len(i), k))
        Q.append(R2), S.append(np.full(len(i), side))
    return tuple(np.concatenate(x) if x else np.zeros(0) for x in (I, J, K, Q, S))


def read_bindings(run):
    """(i, j, k, L0²) of the run's ``bindings.npz`` (ids → id-order rows), or None."""
    from rackstress.lib.runfiles import BINDINGS

    path = Path(run.rundir) / BINDINGS
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            i, j, k, q = (z[x] for x in ("i", "j", "k", "L0sq"))
    except (OSError, KeyError, ValueError) as exc:
        raise StressInputError(f"{path}: not a bindings file rackstress wrote ({exc}); run the "
                               "scene again to write it") from None
    n = run.n_atoms
    if len(i) and (min(i.min(), j.min()) < 0 or max(i.max(), j.max()) >= n):
        raise StressInputError(f"{path}: a binding names particle "
                               f"{int(max(i.max(), j.max()))} but the run has {n}: the file is "
                               "not of this run")
    return i.astype(np.int64), j.astype(np.int64), k.astype(np.float64), q.astype(np.float64)


# ----------------------------------------------------------------------------- motion
def _columns(index: np.ndarray):
    """``index`` as a slice where it is a run of consecutive numbers (a view, no copy), else
    itself."""
    index = np.asarray(index)
    if len(index) and index[-1] - index[0] == len(index) - 1 \
            and (len(index) == 1 or (np.diff(index) == 1).all()):
        return slice(int(index[0]), int(index[-1]) + 1)
    return index


class PartMotion(AnalysisBase):
    """Per part and frame: centre of mass and bounding box; per sediment: footprints.

    ``results.com``, ``results.lo``, ``results.hi``: (n_frames, n_parts, 3) in ``results.names``
    order; ``results.footprints[name]``: ``final_dy`` (vertical displacement p_y − o_y at the last
    analysed frame) and ``min_dy`` (the deepest it reached) per sediment particle.
    """

    def __init__(self, run, **kwargs):
        super().__init__(run.trajectory, **kwargs)
        self.run_data = run

    def _prepare(self):
        run = self.run_data
        self.results.names = list(run.parts)
        shape = (self.n_frames, len(run.parts), 3)
        self.results.com = np.zeros(shape)
        self.results.lo, self.results.hi = np.zeros(shape), np.zeros(shape)
        self.results.steps = np.zeros(self.n_frames, dtype=np.int64)
        masses = run.data.masses
        types = np.asarray(run.data.types, dtype=np.int64)    # LAMMPS types: 1, 2, …
        top = int(types.max()) if len(types) else 0
        by_type = np.array([float(masses.get(t, 1.0)) for t in range(top + 1)])
        self._w = by_type[types]        # a table, not a dict look-up a particle (a million: 0.2 s)
        self._sed = [p for p in run.parts.values() if p.kind == "sediment"]
        self.results.footprints = {p.name: {"final_dy": np.zeros(p.n), "min_dy": np.zeros(p.n)}
                                   for p in self._sed}
        # what each frame reuses, taken once: each part's columns of the frame's transpose (a
        # slice where its particles are consecutive, as a data file numbers them), its weights
        # and their sum, each sediment's rest heights. Per frame the positions are transposed
        # once (3 × n): a part's reductions then run along contiguous rows, a tenth of the
        # cost of reducing (n, 3) down its columns (magpod-small's 101 frames: 53 → 12 ms).
        self._parts = [(_columns(part.index), self._w[part.index], self._w[part.index].sum())
                       for part in run.parts.values()]
        o = run.o
        self._rest = [(_columns(part.index), o[part.index, UP], self.results.footprints[part.name])
                       for part in self._sed]

    def _single_frame(self):
        k, p = self._frame_index, positions(self._ts)
        self.results.steps[k] = int(self._ts.data.get("step", self._ts.frame))
        com, lo, hi = self.results.com[k], self.results.lo[k], self.results.hi[k]
        pt = np.ascontiguousarray(p.T)
        for j, (cols, w, total) in enumerate(self._parts):
            q = pt[:, cols]
            com[j] = (q @ w) / total
            lo[j], hi[j] = q.min(axis=1), q.max(axis=1)
        for cols, o_up, fp in self._rest:
            dy = pt[UP, cols] - o_up
            fp["final_dy"] = dy
            np.minimum(fp["min_dy"], dy, out=fp["min_dy"])

    def _conclude(self):
        pass


#: measure name → analysis class (what ``rackstress render --measure`` offers).
MEASURES = {cls.NAME: cls for cls in (DesiredPositionDistance, AccumulatedDistance,
                                      VonMisesStrain, NonAffineD2min, VirialStress,
                                      ParticleStress)}
