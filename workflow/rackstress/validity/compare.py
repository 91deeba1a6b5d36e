"""Particle measures at damped equilibrium against a finite-element reference.

:func:`equilibrate` runs a scene on an engine (the reference engine or LAMMPS, exact or fast
mode) until it is at rest, LAMMPS optionally recording its own per-atom virial;
:func:`measures` computes, on the body's original and final positions, every stress measure the
project offers — the paper's distance from the desired position (robust Kabsch, as
:mod:`rackstress.stress.fit`), the von Mises shear strain η and D²min of the Falk–Langer affine
fit (the definitions of :mod:`rackstress.stress.measures`, cutoff 1.5 spacings, planar
neighbourhoods completed by the deformed normal) and the per-atom virial of the binding forces
(½ Σ_j r_ij ⊗ f_ij, LAMMPS' per-atom split, as its von Mises equivalent); :func:`agreement`
gives the figures of agreement with a reference field:

* ``spearman`` — Spearman rank correlation over the particles where both are defined;
* ``top5_overlap`` — |A ∩ B| / k for the top-k particles of each (k = ⌈5 % of n⌉; ties broken by
  particle order);
* ``max_distance`` — distance (lattice spacings) from the measure's largest particle to the
  nearest particle where the reference is within 1 % of its largest (symmetric bodies have
  several equal maxima).
"""
from __future__ import annotations

import math
import time

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import spearmanr

from rackstress.model.operators import Bind
from rackstress.engines.reference import Reference
from rackstress.scenes.validation import body_index
from rackstress.stress.fit import robust_fit
from rackstress.stress.measures import CUTOFF_FACTOR, RANK_TOL, _bincount3, von_mises_strain

#: Top fraction of particles that make the hot-spot set.
TOP = 0.05
#: A particle is "at the reference's maximum" within this fraction of the peak value.
PEAK_TOL = 0.01


def _engine(scene, engine: str, mode: str):
    if engine == "reference":
        if mode != "exact":
            raise ValueError("the reference engine has one mode, exact (Eq. 5)")
        return Reference(scene)
    if engine == "lammps":
        from rackstress.engines.lammps.deck import compile_deck
        from rackstress.engines.lammps.runner import LammpsRun

        return LammpsRun(compile_deck(scene, mode), None, log=False)
    raise ValueError(f"unknown engine {engine!r} (reference or lammps)")


def equilibrate(scene, tol: float = 1e-7, check_every: int = 500, max_steps: int | None = None,
                engine: str = "reference", mode: str = "exact", steps: int | None = None,
                virial: bool = False):
    """Run ``scene`` on ``engine`` (``reference`` or ``lammps``, ``mode`` exact or fast) until
    at rest; return ``(p, info)``.

    At rest: between two checks (``check_every`` steps apart) no particle moved more than
    ``tol`` × the largest displacement from the original positions. ``max_steps`` defaults to
    ``scene.total_steps``. ``steps``: run exactly that many steps instead (another engine
    repeating a run that came to rest). ``info`` says whether rest was reached, the steps taken
    and the wall time; with ``virial`` (LAMMPS only) also ``info["virial"]``, LAMMPS' own
    per-atom virial (``compute stress/atom NULL virial``, n × 6: xx yy zz xy xz yz) at the end.

    Example
    -------
    >>> from rackstress.scenes import validation as cases
    >>> p, info = equilibrate(cases.cantilever(body="bind", nx=6, ny=2), max_steps=20,
    ...                       check_every=10)
    >>> info["steps"], p.shape
    (20, (12, 3))
    """
    eng = _engine(scene, engine, mode)
    try:
        eng.enter_phase(dict(scene.phases[0].vars))
        o = scene.original_positions()
        max_steps = scene.total_steps if max_steps is None else int(max_steps)
        if steps is not None:
            max_steps = int(steps)
        t0, prev, rest = time.perf_counter(), eng.positions(), False
        while eng.step_count < max_steps:
            eng.advance(min(check_every, max_steps - eng.step_count))
            p = eng.positions()
            disp = float(np.abs(p - o).max())
            moved = float(np.abs(p - prev).max())
            prev = p
            if disp > 0 and moved <= tol * disp:
                rest = True
                if steps is None:
                    break
        wall = time.perf_counter() - t0
        info = {"at_rest": rest, "steps": int(eng.step_count), "time": eng.step_count * scene.dt,
                "wall_s": wall, "engine": engine, "mode": mode,
                "max_displacement": float(np.linalg.norm(prev - o, axis=1).max())}
        if virial:
            info["virial"] = _lammps_virial(eng)
        return prev.copy(), info
    finally:
        eng.close()


def _lammps_virial(run) -> np.ndarray:
    """LAMMPS' per-atom virial stress (``compute stress/atom NULL virial``), global order."""
    run.command("compute rs_virial all stress/atom NULL virial")
    run.command("run 0 post no")
    lmp = run.lmp
    nlocal = int(lmp.extract_global("nlocal"))
    ids = np.array(lmp.numpy.extract_atom("id")[:nlocal], dtype=np.int64)
    s = np.array(lmp.numpy.extract_compute("rs_virial", 1, 2)[:nlocal], dtype=float)
    out = np.full((run.scene.n_particles, 6), np.nan)
    for i, v in run.comm.allgather((ids, s)):
        out[i - 1] = v
    return out


def von_mises_6(s: np.ndarray) -> np.ndarray:
    """Von Mises equivalent of symmetric tensors given as n × 6 (xx yy zz xy xz yz)."""
    xx, yy, zz, xy, xz, yz = np.asarray(s, dtype=float).T
    return np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2)
                   + 3.0 * (xy ** 2 + xz ** 2 + yz ** 2))


def affine_fit(o: np.ndarray, p: np.ndarray, cutoff: float | None = None):
    """(η, D²min) per particle of the Falk–Langer fit over neighbours within ``cutoff``.

    ``cutoff`` defaults to 1.5 × the median nearest-neighbour spacing, as the ``strain``
    measure's. NaN where the neighbourhood is collinear or empty.
    """
    F, (I, d, d0, rank) = _affine(o, p, cutoff)
    n = len(o)
    E = 0.5 * (np.transpose(F, (0, 2, 1)) @ F - np.eye(3))
    eta = von_mises_strain(E)
    r = d - np.einsum("nij,nj->ni", F[I], d0)
    d2 = np.bincount(I, weights=(r * r).sum(axis=1), minlength=n)
    bad = rank < 2
    eta[bad], d2[bad] = np.nan, np.nan
    return eta, d2


def affine_fit_gradient(o: np.ndarray, p: np.ndarray, cutoff: float | None = None):
    """The deformation gradient F (n, 3, 3) of :func:`affine_fit`'s fit; NaN where the
    neighbourhood is collinear or empty."""
    F, (_, _, _, rank) = _affine(o, p, cutoff)
    F[rank < 2] = np.nan
    return F


def _affine(o, p, cutoff):
    n = len(o)
    tree = cKDTree(o)
    spacing = float(np.median(tree.query(o, k=2)[0][:, 1]))
    rc = CUTOFF_FACTOR * spacing if cutoff is None else cutoff
    pairs = tree.query_pairs(rc * (1 + 1e-9), output_type="ndarray")
    I = np.concatenate([pairs[:, 0], pairs[:, 1]])
    J = np.concatenate([pairs[:, 1], pairs[:, 0]])
    d0 = o[J] - o[I]
    V = _bincount3(I, d0, d0, n)
    lam, vec = np.linalg.eigh(V)
    nonzero = lam > RANK_TOL * np.maximum(lam[:, 2:3], np.finfo(float).tiny)
    rank = nonzero.sum(axis=1)
    inv = np.where(nonzero, 1.0 / np.where(nonzero, lam, 1.0), 0.0)
    Vp = np.einsum("nik,nk,njk->nij", vec, inv, vec)
    d = p[J] - p[I]
    F = _bincount3(I, d, d0, n) @ Vp
    planar = rank == 2
    if planar.any():
        t1, t2 = vec[planar, :, 1], vec[planar, :, 2]
        a = np.einsum("nij,nj->ni", F[planar], t1)
        b = np.einsum("nij,nj->ni", F[planar], t2)
        nd = np.cross(a, b)
        nd /= np.where((nn := np.linalg.norm(nd, axis=1, keepdims=True)) > 0, nn, 1.0)
        F[planar] += nd[:, :, None] * np.cross(t1, t2)[:, None, :]
    return F, (I, d, d0, rank)


def bind_virial(scene, p: np.ndarray) -> np.ndarray:
    """Von Mises equivalent of ½ Σ_j r_ij ⊗ f_ij over every bind on each particle (n_total)."""
    n = scene.n_particles
    W = np.zeros((n, 3, 3))
    for target, seq in scene.operators.items():
        for op in seq:
            if not isinstance(op, Bind):
                continue
            pl = op.pairs(scene.groups[target], scene.groups[op.source]).shifted(
                scene.offset(target), scene.offset(op.source))
            f = Bind.accel(p[pl.i], p[pl.j], pl.c, pl.q)
            W += 0.5 * _bincount3(pl.i, p[pl.j] - p[pl.i], f, n)
    xx, yy, zz = W[:, 0, 0], W[:, 1, 1], W[:, 2, 2]
    xy, xz, yz = W[:, 0, 1], W[:, 0, 2], W[:, 1, 2]
    return np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2)
                   + 3.0 * (xy ** 2 + xz ** 2 + yz ** 2))


def measures(scene, p: np.ndarray) -> dict:
    """Every measure on the part (the body group, held particles included) at positions ``p``;
    arrays over the body's particles in group order.
    """
    idx = body_index(scene)
    o = scene.original_positions()[idx]
    q = p[idx]
    eta, d2 = affine_fit(o, q)
    return {"paper": robust_fit(o, q)[2], "strain": eta, "d2min": d2,
            "virial": bind_virial(scene, p)[idx]}


def agreement(values: np.ndarray, reference: np.ndarray, points: np.ndarray,
              top: float = TOP) -> dict:
    """Spearman ρ, top-5 % overlap and distance of the maxima (module docstring)."""
    ok = np.isfinite(values) & np.isfinite(reference)
    v, r, x = values[ok], reference[ok], points[ok]
    if len(v) == 0:                     # the measure was not recorded
        return {"spearman": float("nan"), "top5_overlap": float("nan"),
                "max_distance": float("nan"), "n": 0, "k": 0}
    rho = float(spearmanr(v, r).statistic) if np.ptp(v) > 0 and np.ptp(r) > 0 else float("nan")
    k = max(1, math.ceil(top * len(v)))
    a = set(np.argsort(-v, kind="stable")[:k].tolist())
    b = set(np.argsort(-r, kind="stable")[:k].tolist())
    peaks = x[r >= (1 - PEAK_TOL) * r.max()]
    dist = float(np.linalg.norm(peaks - x[int(np.argmax(v))], axis=1).min())
    return {"spearman": rho, "top5_overlap": len(a & b) / k, "max_distance": dist, "n": int(ok.sum()),
            "k": int(k)}


def effective_modulus(scene, p: np.ndarray) -> float:
    """Young's modulus of a cantilever scene from its tip deflection: E = PL³ / (3 I δ), I = h³/12.

    δ is the mean downward displacement of the loaded (tip) particles; unit thickness.
    """
    g = scene.groups["body"].meta["validation"]
    sl = scene.slice("body")
    mask = np.asarray(scene.operators["body"][0].where, dtype=bool)
    delta = -float(np.mean(p[sl][mask, 1] - scene.groups["body"].o[mask, 1]))
    L, h, P = g["L"], g["h"], g["P"]
    return P * L ** 3 / (3 * (h ** 3 / 12.0) * delta)


def fea_case(scene):
    """The finite-element twin of a validation scene: ``(solver, kwargs, to_fea)``.

    ``solver(density=…, **kwargs)`` is one of :mod:`.fea`'s; ``to_fea(points)`` maps particle
    positions into its coordinates. The continuum body is the union of the particles' lattice
    cells (module docstring of :mod:`rackstress.scenes.validation`), loaded by the same total
    force.
    """
    from rackstress.validity import fea

    g = scene.groups["body"].meta["validation"]
    if g["case"] == "cantilever":
        return fea.cantilever, dict(L=g["L"], h=g["h"], P=g["P"], x0=g["x0"], y0=g["y0"]), \
            (lambda x: x[:, :2])
    if g["case"] == "plate-hole":
        return fea.plate_with_hole, dict(a=g["a"], W=g["W"], sigma=g["sigma"]), \
            (lambda x: x[:, :2])
    sx, sy = g["shift"]
    return fea.l_bracket, dict(w=g["w"], H=g["H"], Lx=g["Lx"], P=g["P"]), \
        (lambda x: x[:, :2] - np.array([sx, sy]))
