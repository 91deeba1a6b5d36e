"""Linear-elastic FEA of a run's own part: the same shape, supports and loads, on tetrahedra.

``rackstress fea RUNDIR`` (:func:`check_run`) answers "is the particle picture right on *my*
part?" with an independent solution of the same problem:

* **shape** — a mesh part (its STL, placed as in the scene) is meshed into tetrahedra by gmsh
  (the surface reparametrized and remeshed at the FE size, then the volume; a surface gmsh
  cannot reparametrize is first rebuilt by fTetWild, :func:`clean_surface`); a part filled
  from boxes, spheres, … (or a mesh gmsh refuses) is the union of its particles' lattice cells,
  each cube cut into 6 tetrahedra (Freudenthal: conforming across faces);
* **material** — E, ν of the part's material (``summary.json``), else given;
* **supports** — every FE node inside (the closed cell of) a held particle is fixed in that
  particle's fixed directions (``held_mask``: rollers and symmetry planes fix some);
* **loads** — each loaded particle's force is spread over the FE nodes in its cell with weights
  w_k (Σ w_k = 1, Σ w_k x_k = x_p: the least-norm correction of equal weights), so the total
  force and its moment about any point are the particles' exactly; a cell holding too few nodes,
  or nodes so nearly on one plane that a weight exceeds :data:`LOAD_WEIGHT_MAX`, gives its
  force to the vertices of the tetrahedron holding the particle (barycentric: the same two
  sums);
* **solution** — quadratic tetrahedra (P2, scikit-fem), one sparse direct solve; the strain is
  the L2 projection of the displacement gradient onto continuous P2, σ = λ tr ε I + 2μ ε, and
  σ_vm = √(3 J₂(σ)).

Agreement (:func:`agreement`): Spearman ρ and top-5 % overlap of the particle measure against
FEA's σ_vm at the particles' original positions (:func:`rackstress.validity.compare.agreement`),
and the peak ratio *away from singular points*: particles within one wall thickness t of a
re-entrant (concave) edge of the FE boundary, of a held or of a loaded particle are left out of
the peaks. σ is unbounded at a sharp re-entrant edge and under a concentrated load or support
in the continuum, so a peak there measures the mesh, not the part; by Saint-Venant's principle
such a local disturbance has decayed about one thickness of the member away, where both
models converge. t is the part's own (:func:`wall_thickness`: the median over the particles of
the shortest chord through the part along x, y or z), so the same points are compared at every
spacing. A ``strain`` measure
(von Mises shear strain η) is turned into stress by σ_vm = 2√3·G·η (exact for isotropic linear
elasticity: both are √J₂ of the deviator), G = E / 2(1 + ν).

Example
-------
>>> import numpy as np
>>> from rackstress.validity.solid import cell_mesh, solve
>>> o = np.array([[x, 0.0, 0.0] for x in range(4)])          # a 4 × 1 × 1 bar of cells
>>> p, t = cell_mesh(o, 1.0)
>>> sol = solve(p, t, E=1.0, nu=0.0, fixed=p[:, 0] < -0.49, forces=None)   # doctest: +SKIP
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rackstress.errors import RackstressError
from rackstress.lib.tet import (FLAT_TET, POOR_SLIVERS, SLIVER_AREA, SLIVER_Q,  # noqa: F401
                                Solution, _faces_once, _twice_areas, drop_slivers,
                                gmsh_volume, hooke, project_strain, tet_volumes, von_mises)
from rackstress.lib.resources import cpu_children
from rackstress.model.singular import wall_thickness  # noqa: F401 - the part's length, one home

#: The governing stress is read at least this many spacings from a singular point (a
#: re-entrant edge, a support, a load): the headline's rule, used by the FE check until the
#: run records its own singular set and zone (``summary.json`` → ``stress.governing.zone``)
ZONE_SPACINGS = 2.0
#: the distance bands of the agreement, in spacings from the nearest singular point
BANDS = ((0.0, 1.0), (1.0, 2.0), (2.0, 5.0), (5.0, float("inf")))
#: An FE boundary edge is re-entrant when its dihedral angle is concave by more than this.
CONCAVE_DEG = 20.0
#: a surface's facets meeting at more than this (and at most CONCAVE_DEG) tessellate a curved
#: face: a fillet or a hole, where the FE mesh is refined as at re-entrant edges
CURVED_DEG = 1.0
#: Targets for a 3D part against tetrahedral FEA: the particles rank the stresses as FEA does
#: and find the same hot spots (docs/fea.md).
TARGET = {"spearman": 0.8, "top5_overlap": 0.5, "peak_ratio_error": 0.15}
#: FE size in spacings (gmsh's largest element edge; cells are cut at the spacing): P2
#: elements 2 spacings long carry a linear stress each, and near re-entrant edges they are
#: graded down to :data:`NEAR_SPACINGS` (docs/fea.md, the sizes measured)
SIZE_SPACINGS = 2.0
#: FE size at the re-entrant edges, in spacings
NEAR_SPACINGS = 0.35
#: near a re-entrant edge the FE size is this fraction of the distance to it (between the
#: near and the far size): a quarter of the governing zone's 2 spacings at its boundary
GRADE = 0.25
#: the second, coarser mesh that says how far the FE's own answer moved: sizes × this
COARSER = 2 ** 0.5
#: memory of the FE solution per tetrahedron beyond the process's own (numbering, assembly,
#: multigrid hierarchy, projection, evaluation; peak RSS measured on the C-frame: 16.8 kB at
#: 39,193 tetrahedra, 17.9 kB at 15,494)
BYTES_PER_ELEMENT = 18.0e3
#: and what it takes whatever the mesh (gmsh, the imports' first touches)
MEMORY_FLOOR = 150e6
#: tetrahedra gmsh makes per size³ of volume (measured: 86,534 in the 18,000 mm³ C-frame at
#: size 1 mm)
TETS_PER_SIZE3 = 4.8
#: FE systems up to this many unknowns are solved directly (SuperLU), larger by AMG-CG
DIRECT_DOFS = 20_000
#: A mesh gmsh remeshed from the file (well-shaped) is solved by conjugate gradients first
#: (:func:`solve_part`), whatever the direct factor's size: README's bracket at FE sizes 2.83
#: and 2 (125,310 and 249,894 unknowns) took 3.5 and 7.2 s of CPU by conjugate gradients
#: against 6.1 s by PARDISO (its factor within DIRECT_FLOPS: 7.6e10 flop) and 11.3 s (the
#: analysis that refused the factor, 4.4 s, then conjugate gradients), the same governing
#: stress to 14 digits (measured 2026-12-02). A mesh inside the file's own facets or fTetWild's
#: is not (the SO-100 base's 82,656 unknowns: 752 steps), so there the factor's size decides
#: (:func:`solve`'s ``method="remeshed"``).
REMESHED_CG = True
#: the finer FE mesh's budget of tetrahedra: the FE check's target of ≤ 60 s of one core and ≤ 2 GB for a
#: 20,000-particle part, with both FE sizes (measured on the finger's lower link: 179,215
#: tetrahedra took 59.5 s of CPU and 2.4 GB, 68,822 took 21.6 s; at a budget of 80,000 the
#: solo12 hip took 113 s and 1.95 GB with both sizes on a loaded machine). Where the grading to
#: :data:`NEAR_SPACINGS` at re-entrant edges and curved faces would exceed it (a part curved
#: all over refines everywhere), the finest size is raised until it fits
#: (:func:`near_size_within`); ``fea.json`` → ``fe_budget`` says so
FE_ELEMENTS = 50_000


# --------------------------------------------------------------------------- meshes
def cell_mesh(o: np.ndarray, spacing: float):
    """Tetrahedra of the union of the lattice cells (cubes of side ``spacing``) centred on
    ``o``: (p 3×N, t 4×M). Each cube is cut into the 6 tetrahedra around its main diagonal
    (Freudenthal), the same way in every cube, so faces match."""
    o = np.asarray(o, float).reshape(-1, 3)
    s = float(spacing)
    lo = o.min(axis=0) - s / 2
    ijk = np.rint((o - o.min(axis=0)) / s).astype(np.int64)
    dims = ijk.max(axis=0) + 2                     # corner grid
    c = {d: (ijk[:, 0] + d[0]) + dims[0] * ((ijk[:, 1] + d[1]) + dims[1] * (ijk[:, 2] + d[2]))
         for d in [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]}
    tets = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        path = [(0, 0, 0)]
        for ax in perm:
            nxt = list(path[-1])
            nxt[ax] = 1
            path.append(tuple(nxt))
        tets.append(np.stack([c[v] for v in path]))
    t = np.concatenate(tets, axis=1)
    used, t = np.unique(t, return_inverse=True)
    t = t.reshape(4, -1)
    i = used % dims[0]
    j = (used // dims[0]) % dims[1]
    k = used // (dims[0] * dims[1])
    p = (lo[:, None] + s * np.stack([i, j, k]).astype(float))
    # orient every tetrahedron positively
    swap = tet_volumes(p.T, t.T) < 0
    t[1, swap], t[2, swap] = t[2, swap].copy(), t[1, swap].copy()
    return p, t


def surface_mesh(vertices: np.ndarray, faces: np.ndarray, size: float, near=None,
                 near_size: float | None = None, info: dict | None = None,
                 reparametrize: bool = True):
    """Tetrahedra of the closed surface (vertices, triangles) by gmsh, largest edge ``size``:
    (p 3×N, t 4×M). Slivers are removed (:func:`drop_slivers`), the surface is classified into
    patches (40° feature angle), each reparametrized and remeshed, then the volume meshed
    (gmsh runs headless, quietly). ``near`` (k×3 points, the re-entrant edges sampled):
    elements of :data:`GRADE` × the distance d from them, between ``near_size`` and ``size``
    — the stress falls steeply there, and the governing stress is read a few spacings away.

    Where gmsh cannot reparametrize the surface (a patch that is not a disc: "Wrong topology
    of boundary mesh for parametrization"; a remeshed thin wall whose two faces cross:
    "overlapping facets"; tiny facets side by side, on which its classification does not
    end), the volume is meshed inside the file's own triangles: the same closed surface, its
    facets as the file has them, not refined at the features, nor graded inside (graded
    towards the file's coarse facets, gmsh took over 80 s on the finger's upper link, 0.5 s
    without). Before, such a part fell back on the particles' cells cut in 8 (minutes, up to
    8 GB). Halving the file's long edges first made gmsh's volume mesher run for minutes on
    the thin triangles it leaves. Tiny facets side by side are welded first (:func:`weld`).
    Now such a surface is first rebuilt by fTetWild (:func:`clean_surface`, edges
    ``near_size``) and gmsh fills that; the file's own triangles remain the way where
    pytetwild is not installed or fails. Zero-area triangles side by side that neither
    :func:`drop_slivers` nor :func:`weld` removes go to fTetWild at once (it takes the file as
    a soup of triangles): before, gmsh refused them and the FE check fell back on the cells
    (a trial surface of the SO-100 base: 196 s of CPU, 10.7 GB); without pytetwild they are
    a ``ValueError`` naming where.
    ``info`` (a dict) receives ``surface``: which way was taken (and fTetWild's edge and
    envelope where it made the surface, :func:`clean_surface`; ``cut``: how its own
    tetrahedra were cut, :func:`own_tetrahedra`); ``reparametrize=False``
    goes that way at once (the FE check's second size, where the first could not)."""
    v = np.asarray(vertices, float)
    f = drop_slivers(v, faces)
    tiny = SLIVER_AREA * float(np.ptp(v, axis=0).max()) ** 2
    left = _twice_areas(v, f) <= tiny
    if left.any():       # tiny facets side by side: weld their corners, if it stays closed
        w, g = weld(v, f)
        if g is not None:
            v, f = w, drop_slivers(w, g)
            left = _twice_areas(v, f) <= tiny
    flat_why = None
    if left.any():
        e = v[f[left]] - v[np.roll(f[left], 1, axis=1)]
        flat = _twice_areas(v, f[left]) <= FLAT * (e ** 2).sum(axis=2).max(axis=1)
        if flat.any():    # three collinear points: no tetrahedron can have it as a face
            at = np.round(v[f[left][flat][0]].mean(axis=0), 4).tolist()
            flat_why = (f"{int(flat.sum())} zero-area triangle(s) side by side remain (e.g. "
                        f"at {at}), which gmsh cannot mesh")
    info = {} if info is None else info
    why = None
    if flat_why:          # fTetWild takes a triangle soup: its surface has none of them
        why = flat_why
    elif not reparametrize:
        why = "it could not at the other FE size"
    elif not left.any():   # gmsh's classification did not end in 10 minutes on a tiny pair
        from rackstress.lib import forked

        try:
            out = forked.call(lambda: _gmsh_volume(v, f, size, near, near_size,
                                                   reparametrize=True), GMSH_TIMEOUT_S)
            info["surface"] = "remeshed by gmsh"
            return out
        except forked.Timeout:
            why = f"gmsh had not remeshed it after {GMSH_TIMEOUT_S:.0f} s"
        except Exception as exc:  # noqa: BLE001 - gmsh's own error: its words, below
            why = str(exc)
    else:
        why = f"{int(left.sum())} tiny facets side by side"
    try:
        V, F, own = clean_surface(v, f, near_size if near_size and near_size < size else size,
                                  info=info)
    except ImportError:       # no pytetwild (the fem extra installs it): the file's facets
        pass
    except Exception as exc:  # noqa: BLE001 - fTetWild's own error: said, then the file's
        why = f"{why}; fTetWild failed too: {exc}"
    else:
        tw = f"(gmsh could not reparametrize the file's surface: {why})"
        try:
            loose = open_edges(F)
            if loose:       # gmsh's tetrahedra would meet there at an edge only: a hinge
                raise RuntimeError(f"{loose} of its edges are not shared by two triangles")
            p, t = _gmsh_volume(V, F, size, None, None, reparametrize=False, netgen=True)
            got, want = np.abs(tet_volumes(p.T, t.T)).sum(), enclosed_volume(V, F)
            if abs(got / want - 1) > FILL_TOL:
                raise RuntimeError(f"its tetrahedra hold {got / want:.2%} of the surface's "
                                   "volume")
            info["surface"] = f"the volume inside fTetWild's surface of the file {tw}"
            return p, t
        except Exception as exc:  # noqa: BLE001 - gmsh's words, said: fTetWild's own mesh
            n = len(own[1])
            if not own[2] and n > OWN_MOST * FE_ELEMENTS:
                # the second size could bisect too few of them (under half): coarser ones
                # (the fixed jaw's 13,398 cut into 8 made 107,184, 62.5 s of CPU and 1.89 GB)
                try:
                    own = clean_surface(v, f, size, coarser=(
                        BISECT_GROWTH * n / (OWN_AIM * FE_ELEMENTS)) ** (1 / 3), info=info)[2]
                except Exception as err:  # noqa: BLE001 - fTetWild's own words: say them
                    why = f"{why}; fTetWild failed at a coarser size: {err}"
                    own = None
            if own is not None:
                p, t, cut = own_tetrahedra(own)
                info["surface"] = (f"fTetWild's own tetrahedra{cut} {tw}; gmsh could not "
                                   f"fill fTetWild's surface: {exc}")
                info["cut"] = cut
                return p, t
    if flat_why:          # inside the file's own triangles gmsh cannot mesh them either
        raise ValueError(why)
    info["surface"] = (f"the volume inside the file's own triangles (gmsh could not "
                       f"reparametrize the surface: {why})")
    return _gmsh_volume(v, f, size, None, None, reparametrize=False)


#: seconds gmsh may take to remesh a part's surface and fill it (in a child process,
#: rackstress.lib.forked) before the FE check takes fTetWild's surface instead: on the
#: concentrations bench's round shoulder (a torus of 256 × 64 facets as its fillet) gmsh's
#: volume meshing at FE size 1.6 mm had not ended after 10 minutes (measured while building
#: this); a corpus part's takes 1–5 s
GMSH_TIMEOUT_S = 60.0
#: tetrahedra gmsh fills inside fTetWild's surface, per triangle of it (the fixed jaw: 74,000
#: in 28,152 triangles cut from 7,038, 2.6; 15,300 in the 7,038: 2.2): the surface's edge is
#: raised until the finer mesh fits :data:`FE_ELEMENTS` (the SO-100 base's at 3.5 mm made
#: 964,128 tetrahedra, 149 s of CPU)
TETS_PER_TRIANGLE = 2.6
#: gmsh's tetrahedra inside fTetWild's surface must hold its volume to this (an SO-100 base's
#: once held none: "gmsh made no tetrahedra"); else fTetWild's own are used
FILL_TOL = 1e-3
#: fTetWild's tetrahedra must hold the file's volume to this, else the file's own triangles
#: are filled (measured: the fixed jaw 0.9953–0.9972, the SO-100 base's union 0.971–0.991;
#: its four bodies as the file has them, touching face to face, once 0.918: a body lost)
TETWILD_VOLUME_TOL = 0.03
#: the share of the budget of tetrahedra the second FE size aims at where fTetWild's own are
#: bisected in part (:func:`_bisect_within`), and fTetWild's coarser rebuild once bisected
#: (:data:`OWN_MOST`): at 1.25 × the budget the SO-100 base's 62,232 took 65.2 s of CPU under
#: load 3.5, over the 60 s target
OWN_AIM = 0.85
#: tetrahedra a tetrahedron of fTetWild's becomes, all bisected at their longest edge and their
#: neighbours as conformity needs (:func:`rackstress.lib.tet.bisect`; the SO-100 base's
#: 9,298: 39,964, 4.30): where 8 times as many would exceed the budget, the second FE size
#: bisects them instead (where all would, as many as fit: :func:`_bisect_within`), and
#: fTetWild runs once (a coarser second run was 17–24 s of the base's 59–72 s of CPU)
BISECT_GROWTH = 4.3
#: more of fTetWild's own tetrahedra than this share of the budget are made again, coarser
#: (aiming at :data:`OWN_AIM` of it once bisected): the second FE size could bisect only
#: about half of them or fewer. Up to it fTetWild runs once: the fixed jaw's 13,398, of which
#: those on the surface and the largest are bisected, within the budget
OWN_MOST = 0.3
#: fTetWild's envelope, × the edge length asked: its surface stays this close to the file's
#: (the fixed jaw at edge 2.47 mm: 0.49 mm, a third of its particles' spacing)
ENVELOPE = 0.2
#: fTetWild's mesh optimisation stops at this energy (AMIPS; its default 10) and after this
#: many passes (its default 80): measured on the fixed jaw at 1.75 mm, defaults 203 s, these
#: 49 s, both without slivers (quality ≥ 0.06)
TETWILD_ENERGY, TETWILD_PASSES = 20.0, 20
_CLEAN: dict = {}


def tetwild_cache() -> Path:
    """Where fTetWild's meshes are kept (:func:`_tetwild`): ``$XDG_CACHE_HOME/rackstress/
    ftetwild``, else ``~/.cache/rackstress/ftetwild``."""
    from rackstress.lib.jit import cache_root

    return cache_root() / "ftetwild"


def _tetwild(v: np.ndarray, f: np.ndarray, edge: float, envelope: float):
    """fTetWild's tetrahedra (X k×3, t m×4) of the volume inside (v, f), edges about
    ``edge``, its surface within ``envelope`` of (v, f), in a process of its own: it writes
    ``_tracked_surface.stl`` into its working directory (a temporary one here, not the
    user's), and a crash or a hang of its C++ ends that process, not the FE check.

    fTetWild is not deterministic (six runs on the SO-100 fixed jaw's file, the same
    settings, one thread: six meshes of 12,619–13,047 tetrahedra, also on one CPU with address
    randomisation off: a known trait of fTetWild itself), so the FE check of the same part would
    differ from run to run by its mesh alone (its local reading by up to 16 %). Its mesh is
    kept (:func:`tetwild_cache`, by the triangles, the settings and pytetwild's version) and
    taken again: checking a part again gives the same FE. A file there that cannot be read is
    made again; where the cache cannot be written, the mesh is not kept."""
    import hashlib
    import os
    import subprocess
    import sys
    import tempfile
    import zipfile
    from importlib.metadata import version

    v, f = np.ascontiguousarray(v, float), np.ascontiguousarray(f, np.int32)
    key = hashlib.sha256(b"".join([
        v.tobytes(), f.tobytes(),
        np.array([edge, envelope, TETWILD_ENERGY, TETWILD_PASSES], float).tobytes(),
        version("pytetwild").encode()])).hexdigest()[:32]
    kept = tetwild_cache() / f"{key}.npz"
    try:
        with np.load(kept) as d:
            return np.asarray(d["X"], float), np.asarray(d["t"], np.int64)
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        pass
    diag = float(np.linalg.norm(np.ptp(v, axis=0)))
    code = ("import numpy as np, pytetwild\n"
            "d = np.load('in.npz')\n"
            "X, t = pytetwild.tetrahedralize(d['v'], d['f'], edge_length_abs=float(d['edge']), "
            "epsilon=float(d['eps']), stop_energy=float(d['energy']), "
            "num_opt_iter=int(d['passes']), coarsen=True, num_threads=1)\n"
            "np.savez('out.npz', X=X, t=t)\n")
    with tempfile.TemporaryDirectory(prefix="rs-tetwild-") as tmp:
        np.savez(Path(tmp) / "in.npz", v=v, f=f, edge=edge, eps=envelope / diag,
                 energy=TETWILD_ENERGY, passes=TETWILD_PASSES)
        out = subprocess.run([sys.executable, "-c", code], cwd=tmp, capture_output=True,
                             text=True, timeout=TETWILD_TIMEOUT)
        if out.returncode != 0:
            tail = (out.stderr.strip().splitlines() or ["no message"])[-1]
            raise RuntimeError(f"fTetWild ended with exit code {out.returncode}: {tail}")
        d = np.load(Path(tmp) / "out.npz")
        X, t = np.asarray(d["X"], float), np.asarray(d["t"], np.int64)
    try:
        kept.parent.mkdir(parents=True, exist_ok=True)
        part = kept.with_name(f".{key}.{os.getpid()}.npz")
        np.savez(part, X=X, t=t)
        os.replace(part, kept)
    except OSError:
        pass
    return X, t


#: seconds fTetWild may take before the FE check gives up on it (the fixed jaw: 24 s)
TETWILD_TIMEOUT = 600.0


def open_edges(F: np.ndarray) -> int:
    """How many edges of the triangles F (m×3) are not shared by exactly two of them (0: a
    closed manifold surface; fTetWild's surface of the SO-100 base's four bodies had some
    where two of them touch along an edge, and the FE's conjugate gradients inside gmsh's
    filling of it did not converge in 2,000 steps).

    >>> open_edges(np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]))   # a tetrahedron
    0
    >>> open_edges(np.array([[0, 1, 2]]))
    3
    """
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, n = np.unique(e, axis=0, return_counts=True)
    return int((n != 2).sum())


def boundary_triangles(X: np.ndarray, t: np.ndarray):
    """The boundary of the tetrahedra t (M×4) of the points X (N×3): the faces that belong to
    one tetrahedron only, each turned to face away from its fourth corner (outwards).
    Returns (the points they use, k; the triangles m×3 numbered over those points)."""
    faces, once = _faces_once(t)
    opposite = np.concatenate([t[:, 0], t[:, 1], t[:, 2], t[:, 3]])
    b, d = faces[once], opposite[once]
    n = np.cross(X[b[:, 1]] - X[b[:, 0]], X[b[:, 2]] - X[b[:, 0]])
    inward = np.einsum("ij,ij->i", n, X[d] - X[b[:, 0]]) > 0
    b[inward] = b[inward][:, [0, 2, 1]]
    used, bi = np.unique(b, return_inverse=True)
    return used, bi.reshape(-1, 3)


def enclosed_volume(V: np.ndarray, F: np.ndarray) -> float:
    """The volume inside the closed triangulated surface (V k×3, F m×3; positive when its
    triangles face outwards), by the divergence theorem."""
    return float(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6)


def own_tetrahedra(own) -> tuple[np.ndarray, np.ndarray, str]:
    """fTetWild's own tetrahedra (``clean_surface``'s third item) as (p 3×N, t 4×M, how they
    were cut), the FE mesh where gmsh cannot fill fTetWild's surface. Where its surface was
    cut in four (the second FE size), each is cut into 8 (edges halved), or where 8 times as
    many would exceed :data:`FE_ELEMENTS`, bisected at its longest edge (about
    :data:`BISECT_GROWTH` times as many, edges about 1/1.6 as long)."""
    X, t, finer = own
    how = ""
    if finer:
        from rackstress.lib.tet import bisect, refine

        n = len(t)
        if 8 * n <= FE_ELEMENTS:
            X, t = refine(X, t)
            how = ", each cut into 8"
        elif BISECT_GROWTH * n <= FE_ELEMENTS:
            X, t = bisect(X, t)
            how = ", each bisected at its longest edge"
        else:
            X, t = _bisect_within(X, t)
            how = (f", {len(t) / n:.1f} times as many by bisecting those on the surface "
                   "(the largest first) within the budget" if len(t) > n else
                   ", not cut (no bisection of them fitted the budget)")
    return np.ascontiguousarray(X.T), np.ascontiguousarray(t.T), how


def _bisect_within(X: np.ndarray, t: np.ndarray):
    """(X, t) with as many tetrahedra bisected at their longest edges as keeps the mesh within
    :data:`OWN_AIM` × :data:`FE_ELEMENTS`: those with a face on the surface first (the
    stress and its governing point are there), the largest first, then the inner ones; the
    count a bisection makes (with the neighbours conformity cuts) is found by trying, at most
    four times (0.2 s each at 40,000)."""
    from rackstress.lib.tet import bisect

    n, aim = len(t), OWN_AIM * FE_ELEMENTS
    outer = _faces_once(t)[1].reshape(4, n).any(axis=0)
    order = np.lexsort((-np.abs(tet_volumes(X, t)), ~outer))
    m = int(max(aim - n, 0) / (BISECT_GROWTH - 1))
    best = (X, t)
    for _ in range(4):
        if m < 1:
            break
        Y, u = bisect(X, t, order[:m])
        if len(u) <= FE_ELEMENTS:
            best = (Y, u)
            if len(u) >= 0.9 * aim:
                break
        m = min(n, int(m * (aim - n) / max(len(u) - n, 1)))
    return best


def clean_surface(v: np.ndarray, f: np.ndarray, edge: float, coarser: float = 1.0,
                  info: dict | None = None):
    """A closed surface of well-shaped triangles around the volume of (v, f), for a file's
    surface gmsh cannot reparametrize: the boundary of fTetWild's tetrahedra (Hu et al., "Fast
    Tetrahedral Meshing in the Wild", 2020; ``pytetwild``), edges about ``edge``, within
    :data:`ENVELOPE` × ``edge`` of the file's triangles. gmsh then fills it
    (:func:`_gmsh_volume`) as it fills a file's own triangles, but its facets are no longer
    slivers, so neither are the tetrahedra on them. The first surface of a file is kept: asked
    again at a finer edge (the FE check's second size), each triangle is cut into four, so both
    FE meshes fill the same shape and their difference is the FE's own convergence.

    Returns (vertices k×3, triangles m×3, outward) and fTetWild's own tetrahedra (X, t, and
    whether the surface was cut: then they are to be cut too, :func:`own_tetrahedra`), the
    mesh where gmsh cannot fill the surface (:func:`surface_mesh`). ``coarser`` > 1 makes the
    file's surface again, its edges that many times the last one's, its envelope the same
    (its own tetrahedra then fit the budget when cut). ``info`` (a dict) receives
    ``ftetwild_edge`` and ``ftetwild_envelope``: the edge fTetWild was asked for (raised to
    fit the budget; before the second size cuts it) and its envelope."""
    import hashlib
    import importlib.util

    if importlib.util.find_spec("pytetwild") is None:
        raise ImportError("pytetwild is not installed")
    v = np.ascontiguousarray(v, float)
    f = np.ascontiguousarray(f, np.int32)
    key = hashlib.sha1(v.tobytes() + f.tobytes()).hexdigest()
    if key not in _CLEAN or coarser > 1:
        # within the FE budget: the finer mesh's surface (these triangles cut in four) is
        # filled with about TETS_PER_TRIANGLE tetrahedra a triangle
        # (the envelope stays that of the edge asked: the shape no coarser than the FE's)
        area = 0.5 * float(_twice_areas(v, f).sum())
        most = FE_ELEMENTS / (4 * TETS_PER_TRIANGLE)
        envelope = ENVELOPE * float(edge)
        edge = max(float(edge), math.sqrt(4 * area / (math.sqrt(3) * most)))
        if key in _CLEAN:          # made coarser: its edges, not its envelope
            edge, envelope = coarser * _CLEAN[key][2], _CLEAN[key][5]
        X, t = _tetwild(v, f, edge, envelope)
        vol = tet_volumes(X, t)
        held, want = np.abs(vol).sum(), abs(enclosed_volume(v, f))
        if abs(held / want - 1) > TETWILD_VOLUME_TOL:
            raise RuntimeError(f"fTetWild's tetrahedra hold {held / want:.1%} of the file's "
                               "volume")
        used, bi = boundary_triangles(X, t)
        neg = vol < 0
        t[neg] = t[neg][:, [0, 2, 1, 3]]     # fTetWild's come inverted: positive volumes
        _CLEAN.clear()                        # one part at a time
        _CLEAN[key] = (X[used], bi, edge, X, t, envelope)
    V, F, e, X, t, envelope = _CLEAN[key]
    if info is not None:
        info.update(ftetwild_edge=float(e), ftetwild_envelope=float(envelope))
    finer = e > 1.2 * edge
    if finer:
        import trimesh

        V, F = trimesh.remesh.subdivide(V, F)
    return V, F, (X, t, finer)


#: corners closer than this × the part's size are welded into one where tiny facets remain
WELD = 1e-4


def weld(v: np.ndarray, f: np.ndarray, rel: float = WELD):
    """(vertices, triangles) with the vertices closer than ``rel`` × the part's size merged
    (each cluster at its first vertex) and the triangles that collapse dropped; (v, None) if
    the result is not a closed, consistently oriented surface. The finger's upper link
    (199 mm): 56 pairs of corners within 0.02 mm, 60 triangles of 0.002–0.013 mm edges gone,
    its volume 155,020.995 → 155,021.084 mm³; gmsh meshes it (with those facets its volume
    mesher did not end in 2 minutes)."""
    import scipy.sparse as sp
    import trimesh
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    v, f = np.asarray(v, float), np.asarray(f, np.int64)
    pr = cKDTree(v).query_pairs(rel * float(np.ptp(v, axis=0).max()), output_type="ndarray")
    if not len(pr):
        return v, None
    n = len(v)
    k, lab = connected_components(sp.coo_matrix((np.ones(len(pr)), (pr[:, 0], pr[:, 1])),
                                                shape=(n, n)), directed=False)
    first = np.full(k, -1, np.int64)
    first[lab[::-1]] = np.arange(n)[::-1]
    g = lab[f]
    g = g[(g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])]
    w = v[first]
    m = trimesh.Trimesh(w, g, process=False)
    if not (m.is_watertight and m.is_winding_consistent):
        return v, None
    return w, g


#: a tiny triangle (:data:`SLIVER_AREA`) is flat when twice its area ≤ this × its longest
#: edge² (its height under 1 % of its length; three collinear points: 0)
FLAT = 1e-2


def _gmsh_volume(v, f, size, near, near_size, reparametrize: bool, netgen: bool = False):
    """:func:`rackstress.lib.tet.gmsh_volume` graded at :data:`GRADE`."""
    return gmsh_volume(v, f, size, near, near_size, reparametrize, netgen, grade=GRADE)


def mesh_quality(p: np.ndarray, t: np.ndarray) -> dict:
    """Each tetrahedron's quality q = 6·√2·V / ℓ³ (ℓ the root mean square of its six edges;
    1 for a regular tetrahedron, 0 for a flat one) over the mesh (p N×3, t M×4, a
    :class:`~rackstress.lib.tet.Tet2`'s ``p`` and ``t``): its minimum, median, the share
    of slivers (q < :data:`SLIVER_Q`) and whether the mesh is poor (that share above
    :data:`POOR_SLIVERS`). A regular tetrahedron:

    >>> p = np.array([[0, 0, 0], [1, 0, 0], [0.5, 3 ** 0.5 / 2, 0],
    ...               [0.5, 3 ** 0.5 / 6, (2 / 3) ** 0.5]])
    >>> q = mesh_quality(p, np.array([[0, 1, 2, 3]]))
    >>> round(q["min"], 12), q["sliver_share"], q["poor"]
    (1.0, 0.0, False)
    """
    from rackstress.lib.tet import quality

    q = quality(p, t)
    share = float(np.mean(q < SLIVER_Q))
    return {"min": float(q.min()), "median": float(np.median(q)), "sliver_share": share,
            "sliver_q": SLIVER_Q, "poor_share": POOR_SLIVERS, "poor": share > POOR_SLIVERS}


def surface_features(vertices: np.ndarray, faces: np.ndarray, step: float):
    """Points every ``step`` along the re-entrant edges (concave by > :data:`CONCAVE_DEG`) of a
    closed triangulated surface, and along its curved faces' facet edges (bent by
    :data:`CURVED_DEG` … CONCAVE_DEG: a fillet, a hole, tessellated): (concave k×3, curved
    m×3). Stress concentrates at both; the FE mesh is refined there."""
    import trimesh

    tm = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64),
                         process=True)
    if not len(tm.face_adjacency):
        return np.zeros((0, 3)), np.zeros((0, 3))
    ang = np.degrees(tm.face_adjacency_angles)
    concave = ~tm.face_adjacency_convex & (ang > CONCAVE_DEG)
    curved = (ang > CURVED_DEG) & (ang <= CONCAVE_DEG)

    def sample(edges):
        out = []
        for a, b in edges:
            A, B = tm.vertices[a], tm.vertices[b]
            n = max(2, int(np.ceil(np.linalg.norm(B - A) / step)) + 1)
            out.append(A + np.linspace(0.0, 1.0, n)[:, None] * (B - A))
        return np.unique(np.vstack(out), axis=0) if out else np.zeros((0, 3))

    return sample(tm.face_adjacency_edges[concave]), sample(tm.face_adjacency_edges[curved])


# --------------------------------------------------------------------------- general supports
@dataclass
class CellConstraints:
    """The supports of a part that hold no whole axis — :mod:`rackstress.model.constraints`'
    :class:`~rackstress.model.constraints.Normals` (a roller or a symmetry plane at an angle,
    a cylindrical hole) and :class:`~rackstress.model.constraints.Ring` (a pinned hole) over
    the particles at ``x`` (``items``' ids index ``x``) — carried to the FE nodes with the
    meaning the particle model gives them: every FE node inside (the closed cell of) a
    particle a constraint lists is held by it (:meth:`on_nodes`).

    * a plane's normal: the node keeps u·n = 0;
    * a cylindrical support: u·r̂ = 0 and u·â = 0 with r̂ the node's own radial direction
      about the axis (not the particle's: a turn of the bore stays free);
    * a pinned hole: all its nodes move as one rigid ring turning about the axis,
      u = θ · â × (x − c), θ one unknown (a node in a ring's cell is held by the ring only:
      a fixed node beside it would lock the turn the pin leaves free).
    """

    x: np.ndarray
    spacing: float
    items: list

    def __bool__(self) -> bool:
        return bool(self.items)

    def on_nodes(self, X: np.ndarray, fixed: np.ndarray):
        """(constraints over the node indices of ``X`` (n×3), ``fixed`` without the ring
        nodes): the items as :class:`Normals` and :class:`Ring` of the FE nodes."""
        from scipy.spatial import cKDTree

        from rackstress.model.constraints import Normals, Ring

        X = np.asarray(X, float)
        fixed = np.array(fixed, bool)
        h = 0.5 * float(self.spacing) * (1 + 1e-6)
        tree = cKDTree(X)

        def nodes_of(ids):
            """(node, particle) pairs: the node inside the particle's closed cell."""
            ids = np.asarray(ids, np.int64)
            pts = np.asarray(self.x, float)[ids]
            cand = tree.query_ball_point(pts, h * math.sqrt(3))
            nn = np.fromiter((k for c in cand for k in c), np.int64)
            pp = np.repeat(np.arange(len(ids)), [len(c) for c in cand])
            inside = np.all(np.abs(X[nn] - pts[pp]) <= h, axis=1)
            return nn[inside], pp[inside]

        out, ring_nodes = [], np.zeros(len(X), bool)
        for c in self.items:
            if isinstance(c, Ring):
                nn, _ = nodes_of(c.ids)
                nn = np.unique(nn)
                nn = nn[~ring_nodes[nn]]                 # a node in two rings: the first's
                if len(nn):
                    ring_nodes[nn] = True
                    out.append(Ring(nn, c.point, c.axis, c.label))
        for c in self.items:
            if isinstance(c, Ring):
                continue
            nn, pp = nodes_of(c.ids)
            keep = ~ring_nodes[nn]
            nn, pp = nn[keep], pp[keep]
            if c.cylinder is not None:                   # the node's own radial direction
                point, axis = (np.asarray(a, float) for a in c.cylinder)
                axis = axis / np.linalg.norm(axis)
                nn = np.unique(nn)
                rel = X[nn] - point
                radial = rel - np.outer(rel @ axis, axis)
                rho = np.linalg.norm(radial, axis=1)
                on = rho <= 1e-9 * max(float(rho.max(initial=0.0)), 1e-300)
                radial[on] = 0.0
                radial[~on] /= rho[~on, None]
                held = fixed[nn].copy()
                held[on] = True                          # on the axis: no turn, held
                fixed[nn] = held
                ids = np.r_[nn[~on], nn]
                normals = np.r_[radial[~on], np.tile(axis, (len(nn), 1))]
            else:                                        # each node once per distinct normal
                pairs = np.unique(np.c_[nn, np.round(c.normals[pp], 12)], axis=0)
                ids, normals = pairs[:, 0].astype(np.int64), pairs[:, 1:]
            if len(ids):
                out.append(Normals(ids, normals, c.label))
        fixed[ring_nodes] = False
        return out, fixed


def constraint_map(X: np.ndarray, fixed: np.ndarray, items: list):
    """T (3n × m, CSR, orthonormal columns) with u = T·q over the FE nodes at ``X``:
    :class:`rackstress.model.constraints.ConstraintMap` — the particle model's own map — of
    the nodes as one group (fixed axes, normals, rigid rings)."""
    from types import SimpleNamespace

    from rackstress.model.constraints import ConstraintMap

    g = SimpleNamespace(name="fe", o=np.asarray(X, float), n=len(X),
                        fixed=np.asarray(fixed, bool), constraints=list(items))
    return ConstraintMap.of_groups([g], g.o)


# --------------------------------------------------------------------------- solution
def _on_nodes(mesh, a: np.ndarray | None, n_vertices: int, kind: str) -> np.ndarray:
    """``a`` given per vertex (N rows) or per P2 node: per P2 node. A midpoint is fixed in a
    direction when both its edge's vertices are; forces given per vertex stay there."""
    n = mesh.n_nodes
    if a is None:
        return np.zeros((n, 3), bool if kind == "fixed" else float)
    a = np.asarray(a)
    if a.ndim == 1:
        a = np.repeat(a[:, None], 3, axis=1)
    if len(a) == n:
        return a
    if len(a) != n_vertices:
        raise ValueError(f"{kind}: {len(a)} rows for {n_vertices} vertices and {n} nodes")
    out = np.zeros((n, 3), a.dtype)
    out[:n_vertices] = a
    if kind == "fixed":
        out[n_vertices:] = a[mesh.edges[:, 0]] & a[mesh.edges[:, 1]]
    return out


def solve(p, t, E: float, nu: float, fixed, forces, echo=None,
          constraints: CellConstraints | None = None, method: str = "auto") -> Solution:
    """Linear elasticity on the tetrahedra (p 3×N, t 4×M) with P2 elements
    (:mod:`rackstress.lib.tet`).

    ``fixed``: bool over the vertices (N×3: a direction fixed; N: all three) or over the P2
    nodes (``Tet2.X``); ``forces``: nodal forces (N×3 at the vertices, or per P2 node; None:
    none); ``constraints``: supports that hold no whole axis (:class:`CellConstraints` of
    particles, or :class:`~rackstress.model.constraints.Normals` and ``Ring`` over the P2
    nodes), imposed exactly by u = T·q (:func:`constraint_map`): Tᵀ·K·T q = Tᵀ·f.
    ``method``: ``"remeshed"`` — conjugate gradients above :data:`DIRECT_DOFS` unknowns, the
    ``"auto"`` choice where they do not converge (:data:`REMESHED_CG`); ``"auto"`` — up to
    :data:`DIRECT_DOFS` unknowns SuperLU, above it MKL PARDISO where its own estimate of the
    factor fits :data:`DIRECT_MEMORY` and ``engines.linear``'s work limit
    (:func:`rackstress.engines.linear.plan_direct`), else conjugate gradients preconditioned by
    a two-grid cycle (P2 smoothing, AMG on P1; with constraints, the cycle of K with each
    constrained node's held directions stiffened by its own diagonal, seen through T);
    ``"direct"`` or ``"cg"`` force one. A mesh inside an STL's own facets is poorly shaped: the
    SO-100 base's 82,656 unknowns took 752 conjugate-gradient steps (39 s of CPU).
    """
    import time

    from threadpoolctl import threadpool_limits

    from rackstress.lib.tet import Tet2, eliminate, solve_cg

    c0 = time.process_time()
    P = np.asarray(p, float)
    mesh = Tet2(P.T, np.asarray(t).T)
    fx = _on_nodes(mesh, fixed, P.shape[1], "fixed").astype(bool)
    f = _on_nodes(mesh, forces, P.shape[1], "forces").astype(float)
    items = []
    if isinstance(constraints, CellConstraints):
        items, fx = constraints.on_nodes(mesh.X, fx)
    elif constraints:                   # Normals and Ring over the P2 nodes (``Tet2.X``)
        items = list(constraints)
    if not fx.any() and not items:
        raise ValueError("no FE node is fixed: the part is not supported")
    if items:
        return _solve_constrained(mesh, P, E, nu, fx, f, items, method, c0)
    # BLAS threads only spin in the conjugate gradients' vector operations: one is faster
    # (3x less CPU measured on a loaded two-core machine)
    stages = {}
    with threadpool_limits(1):
        K = eliminate(mesh.stiffness(E, nu), fx).tocsr()      # one copy: the solver's
        M = mesh.mass()
        mesh.release()                                         # the assembly's pattern
        f[fx] = 0.0
        dofs = 3 * mesh.n_nodes
        stages["assembly"] = time.process_time() - c0
        plan = _direct_plan(K, method)
        solver = _solver_name(plan)
        if plan is not None:
            u, its = _solve_direct(plan, K, f.ravel()), 0
        else:
            try:
                u, its = solve_cg(mesh, K, f.ravel(), fx)
            except RuntimeError:
                plan = _direct_plan(K, "auto") if method == "remeshed" else None
                if plan is None:
                    raise
                solver = _solver_name(plan)
                u, its = _solve_direct(plan, K, f.ravel()), 0
        del K
        stages["solve"] = time.process_time() - c0 - stages["assembly"]
        u = u.reshape(-1, 3)
        eps = project_strain(mesh, u, M)
        stages["projection"] = time.process_time() - c0 - stages["assembly"] - stages["solve"]
    return Solution(mesh, u, eps, float(E), float(nu),
                    {"vertices": int(P.shape[1]), "tetrahedra": int(mesh.n_elements),
                     "nodes": int(mesh.n_nodes), "dofs": int(dofs), "cg_iterations": int(its),
                     "solver": solver, "method": method, "cpu_s": time.process_time() - c0,
                     "stages_cpu_s": stages})


def next_method(info: dict, method: str) -> str:
    """The ``method`` of :func:`solve` for :func:`check_run`'s next, finer FE mesh, from the
    last one's ``info``: ``"cg"`` where conjugate gradients served because the direct factor
    was refused at this size (PARDISO's own estimate after its analysis: the hip's 206,406
    unknowns 1.5 GB, 3.6e11 flop) — the finer mesh's is larger still, so its analysis (7 s of
    CPU on the hip) is not made again; else ``method`` unchanged. A remeshed mesh's conjugate
    gradients were chosen first, not forced (:data:`REMESHED_CG`): the finer mesh keeps that
    choice and its direct fallback.

    >>> next_method({"solver": "cg", "dofs": 10**6, "method": "auto"}, "auto")
    'cg'
    >>> next_method({"solver": "cg", "dofs": 10**6, "method": "remeshed"}, "auto")
    'auto'
    """
    if (info["solver"] == "cg" and info["dofs"] > DIRECT_DOFS
            and info.get("method") != "remeshed"):
        return "cg"
    return method


def _direct_plan(K, method: str):
    """"superlu", an analysed PARDISO factorization, or None (conjugate gradients) for the
    system ``K`` under ``method`` (:func:`solve`)."""
    if method == "cg":
        return None
    n = K.shape[0]
    if method == "remeshed":
        return "superlu" if n <= DIRECT_DOFS else None
    if n <= DIRECT_DOFS or (method == "direct" and n <= 4 * DIRECT_DOFS):
        return "superlu"
    from rackstress.engines.linear import Pardiso, backend, plan_direct

    if method == "direct":
        return Pardiso(K.tocsr()).analyse() if backend() == "pardiso" else "superlu"
    avail, _ = available_bytes()
    return plan_direct(K.tocsr(), available=int(min(avail, DIRECT_MEMORY)))


def _solver_name(plan) -> str:
    """What :func:`solve` records as its solver for a :func:`_direct_plan`."""
    if plan is None:
        return "cg"
    return plan if isinstance(plan, str) else plan.kind


def _solve_direct(plan, A, b: np.ndarray) -> np.ndarray:
    """A·x = b by a :func:`_direct_plan` that is not None (SuperLU, or PARDISO's analysed
    factorization, freed after)."""
    import scipy.sparse.linalg as spla

    if plan == "superlu":
        return spla.spsolve(A.tocsc(), b)
    try:
        return plan.factor().solve(b)
    finally:
        plan.free()


#: the memory the FE's direct factorization may count on (half of it for the factor,
#: ``engines.linear.DIRECT_MEMORY_SHARE``): the FE check's target of 2 GB in all
DIRECT_MEMORY = 2 * 2 ** 30


def _solve_constrained(mesh, P, E, nu, fx, f, items, method, c0) -> Solution:
    """:func:`solve` with supports that hold no whole axis: u = T·q (:func:`constraint_map`),
    Tᵀ·K·T q = Tᵀ·f, directly where it fits (:func:`_direct_plan`), else by conjugate gradients
    preconditioned by Tᵀ·M⁻¹·T, M the two-grid cycle of K with the fixed axes eliminated and
    each constrained node's held directions (I − B·Bᵀ, B its free basis; every direction of a
    ring's node) stiffened by its own diagonal block's trace — as K + α·N·Nᵀ tends to the
    constrained operator on T's range when α grows. Records each ring's turn θ (rad)."""
    import time

    import scipy.sparse.linalg as spla
    from threadpoolctl import threadpool_limits

    from rackstress.model.constraints import Ring
    from rackstress.lib.tet import eliminate, p_multigrid

    stages = {}
    n = mesh.n_nodes
    with threadpool_limits(1):
        cm = constraint_map(mesh.X, fx, items)
        T = cm.T.tocsr()
        K = mesh.stiffness(E, nu)
        M = mesh.mass()
        A = (T.T @ K.tocsr() @ T).tocsr()
        b = T.T @ f.ravel()
        dofs = A.shape[0]
        stages["assembly"] = time.process_time() - c0
        plan = _direct_plan(A, method)
        solver = _solver_name(plan)
        if plan is not None:
            mesh.release()
            del K
            q, its = _solve_direct(plan, A, b), 0
        else:
            from rackstress.lib.tet import CG_RTOL

            K = eliminate(K, fx)
            mesh.release()
            rows = np.repeat(np.arange(n), np.diff(K.indptr))
            on = np.flatnonzero(rows == K.indices)                   # the diagonal blocks
            held = np.zeros((n, 3, 3))
            for i, B in cm.bases.items():
                held[i] = np.eye(3) - B @ B.T
            held[cm.ring_particles] = np.eye(3)
            node = rows[on]
            trace = np.trace(K.data[on], axis1=1, axis2=2)
            K.data[on] += trace[:, None, None] * held[node]
            _, Mk = p_multigrid(mesh, K, fx)
            del K
            pre = spla.LinearOperator(A.shape, matvec=lambda r: T.T @ (Mk @ (T @ r)))
            it = [0]

            def count(_):
                it[0] += 1

            q, info = spla.cg(A, b, rtol=CG_RTOL, atol=0.0, maxiter=2000, M=pre,
                              callback=count)
            if info != 0:
                raise RuntimeError(f"the FE solve did not converge (conjugate gradients, "
                                   f"{info} steps)")
            its = it[0]
        del A
        stages["solve"] = time.process_time() - c0 - stages["assembly"]
        u = np.asarray(T @ q).reshape(-1, 3)
        eps = project_strain(mesh, u, M)
        stages["projection"] = time.process_time() - c0 - stages["assembly"] - stages["solve"]
    rings = []
    for c in items:
        if isinstance(c, Ring):
            r = mesh.X[c.ids] - c.point
            t = np.cross(c.axis, r)
            k = int(np.argmax(np.linalg.norm(t, axis=1)))
            rings.append({"label": c.label, "nodes": int(len(c.ids)),
                          "turn_rad": float(u[c.ids[k]] @ t[k] / (t[k] @ t[k]))})
    return Solution(mesh, u, eps, float(E), float(nu),
                    {"vertices": int(P.shape[1]), "tetrahedra": int(mesh.n_elements),
                     "nodes": int(mesh.n_nodes), "dofs": int(dofs), "cg_iterations": int(its),
                     "constrained_nodes": int(sum(len(np.unique(c.ids)) for c in items)),
                     "rings": rings,
                     "solver": solver, "cpu_s": time.process_time() - c0, "stages_cpu_s": stages})


# --------------------------------------------------------------------------- boundary
#: a loaded particle's least-norm weights over the FE nodes in its cell are used only while
#: none exceeds this in size (a weight beyond 1 pulls a node against the load); beyond it the
#: tetrahedron holding the particle takes the force (barycentric weights in [0, 1], the same
#: force and moment). Nodes nearly on one plane (a cell cut by the surface's triangles, the
#: particle off it) gave weights up to 59,246 on the fixed jaw inside fTetWild's surface:
#: one node moved 1.06 mm (the part's largest displacement elsewhere 0.089 mm) and read
#: 4,517 MPa under a 10 N load
LOAD_WEIGHT_MAX = 1.0


def nodal_forces(p: np.ndarray, t: np.ndarray, x: np.ndarray, F: np.ndarray,
                 spacing: float) -> np.ndarray:
    """N×3 vertex forces carrying the particle forces F at x with the same total force and
    moment (module docstring)."""
    from scipy.spatial import cKDTree

    P = p.T
    out = np.zeros_like(P)
    tree = cKDTree(P)
    h = 0.5 * spacing * (1 + 1e-9)
    mesh = None
    for xk, Fk in zip(np.asarray(x, float), np.asarray(F, float)):
        near = np.asarray(tree.query_ball_point(xk, h * math.sqrt(3)), dtype=np.int64)
        near = near[np.all(np.abs(P[near] - xk) <= h, axis=1)] if len(near) else near
        w = None
        if len(near) >= 4:
            A = np.vstack([np.ones(len(near)), P[near].T])          # 4 × m
            if np.linalg.matrix_rank(A) == 4:
                w0 = np.full(len(near), 1.0 / len(near))
                r = np.r_[1.0, xk] - A @ w0
                try:
                    w = w0 + A.T @ np.linalg.solve(A @ A.T, r)
                except np.linalg.LinAlgError:     # nodes on one plane to rounding (a file's
                    w = None                      # facet, solo-upper-leg): the tetrahedron's
                if w is not None and np.abs(w).max() > LOAD_WEIGHT_MAX:
                    w = None                      # nodes nearly on one plane: see the constant
        if w is None:                                  # the tetrahedron holding it
            if mesh is None:
                from rackstress.lib.tet import Tet2

                mesh = Tet2(P, np.asarray(t).T)
            e, lam = mesh.locate(xk[None])
            near, w = mesh.t[e[0]], lam[0]
        out[near] += w[:, None] * Fk[None, :]
    return out


def fixed_nodes(p: np.ndarray, x: np.ndarray, mask: np.ndarray, spacing: float) -> np.ndarray:
    """N×3 bool: a vertex inside the closed cell of a held particle gets its fixed directions."""
    from rackstress.lib.cells import in_cells

    P = p.T
    out = np.zeros((len(P), 3), dtype=bool)
    i, j = in_cells(P, x, spacing)
    np.logical_or.at(out, i, np.asarray(mask, bool)[j])
    return out


def boundary_from_scene(scene) -> dict:
    """The arrays of ``boundary.npz`` (CONTRACT.md) derived from a scene: held particles (all
    three directions, or a group's ``fixed`` directions where it has them) and the ``force``
    operators' accelerations × the particles' mass (``Group.mass(scene.units)``)."""
    from rackstress.model.operators import Force

    held_ids, held_mask, load_ids, load_force = [], [], [], []
    units = getattr(scene, "units", None)
    for name, g in scene.groups.items():
        off = scene.offset(name)
        fixed = getattr(g, "fixed", None)
        if fixed is not None and np.ndim(fixed) == 2:
            fx = np.asarray(fixed, bool)
        else:
            fx = np.repeat((np.zeros(len(g.o), bool) if g.held is None
                            else np.asarray(g.held, bool))[:, None], 3, axis=1)
        k = np.flatnonzero(fx.any(axis=1))
        held_ids.append(off + k + 1)
        held_mask.append(fx[k])
        F = np.zeros((len(g.o), 3))
        m = g.mass(units) if hasattr(g, "mass") and units is not None else 1.0
        for op in scene.operators.get(name, []):
            if isinstance(op, Force):
                sel = np.ones(len(g.o), bool) if op.where is None else np.asarray(op.where, bool)
                F[sel] += np.asarray(op.accel, float) * np.broadcast_to(m, (len(g.o),))[sel, None]
        k = np.flatnonzero(np.any(F != 0, axis=1))
        load_ids.append(off + k + 1)
        load_force.append(F[k])
    return {"held_ids": np.concatenate(held_ids).astype(np.int64),
            "held_mask": np.concatenate(held_mask).reshape(-1, 3),
            "load_ids": np.concatenate(load_ids).astype(np.int64),
            "load_force": np.concatenate(load_force).reshape(-1, 3),
            "units": getattr(units, "name", "paper")}


# --------------------------------------------------------------------------- agreement
def concave_edges(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Midpoints (k×3) of the FE boundary's re-entrant edges (concave by > CONCAVE_DEG)."""
    import trimesh

    P = p.T
    used, tri = boundary_triangles(P, np.asarray(t).T)
    tm = trimesh.Trimesh(P[used], tri, process=False)
    adj = tm.face_adjacency
    concave = ~tm.face_adjacency_convex & (np.degrees(tm.face_adjacency_angles) > CONCAVE_DEG)
    e = tm.face_adjacency_edges[concave]
    return tm.vertices[e].mean(axis=1) if len(adj) else np.zeros((0, 3))


@dataclass
class Singular:
    """Where the continuum's stress is unbounded, and how far from it a stress is read.

    ``points`` (k×3): the re-entrant edges sampled, the held and the loaded particles;
    ``zone``: the exclusion distance (a length) of the governing stress; ``rule``: the rule in
    one sentence, as the report states it; ``source``: where the set comes from
    (``"singular.npz"``, the run's own, the headline's; ``"fe surface"`` without it)."""

    points: np.ndarray
    zone: float
    rule: str
    spacing: float
    source: str = "fe surface"

    def distance(self, x: np.ndarray) -> np.ndarray:
        """Distance of each point (n×3) to the nearest singular point (inf: none)."""
        from scipy.spatial import cKDTree

        x = np.asarray(x, float).reshape(-1, 3)
        if not len(self.points):
            return np.full(len(x), np.inf)
        return cKDTree(self.points).query(x)[0]


def singular_points(concave: np.ndarray, held_x: np.ndarray, load_x: np.ndarray,
                    spacing: float) -> Singular:
    """The FE check's singular set until the run records its own: re-entrant edges (of the
    part's surface) and the edges of supports and loads on it (``concave``), held and loaded
    particles; the zone :data:`ZONE_SPACINGS` spacings."""
    pts = np.concatenate([np.asarray(x, float).reshape(-1, 3) for x in (concave, held_x, load_x)])
    zone = ZONE_SPACINGS * float(spacing)
    return Singular(pts, zone, f"stresses within {ZONE_SPACINGS:g} spacings ({zone:.3g}) of a "
                    "re-entrant edge, a support or a load are left out of the governing "
                    "stress: the continuum's stress is unbounded there", float(spacing))


def run_singular(rundir, name: str, fe: Singular, loads: np.ndarray) -> Singular:
    """The headline's singular set and zone where the run recorded them (``singular.npz``:
    :func:`rackstress.stress.governing.read_singular`: the part's sharp re-entrant edges, its
    supports' boundary and point loads; the zone max(2 spacings, 0.4 × the wall thickness)),
    with the loaded particles added (``loads``, k×3: the FE carries each particle's load as
    nodal point forces, unbounded there in the FE, not in the lattice); ``fe`` — the FE
    surface's own concave edges, supports and loads, 2 spacings — for a run without
    ``singular.npz``. The FE surface's concave edges are not added to the run's set: a
    tessellated fillet would be singular for the FE check and not for the headline."""
    from rackstress.stress.governing import read_singular, zone

    got = (read_singular(rundir) or {}).get(name)
    if got is None:
        return fe
    spacing, wall, sing = got
    z = zone(spacing, wall)
    return Singular(np.concatenate([sing.points, np.asarray(loads, float).reshape(-1, 3)]), z,
                    f"stresses within {z:.3g} (max of {ZONE_SPACINGS:g} spacings and 0.4 of the "
                    "wall thickness) of a sharp re-entrant edge, a support's boundary or a "
                    "point load are left out of the governing stress, as in the headline "
                    "(and, for the FE, of the loaded particles): the continuum's stress is "
                    "unbounded there", float(spacing), "singular.npz")


def region_edges(o: np.ndarray, sel: np.ndarray, spacing: float,
                 phi: np.ndarray | None = None) -> np.ndarray:
    """Points on the edges of a support or a load region on the part's surface (k×3): for each
    particle of the region (``sel``, bool over ``o``) on the surface with a nearest neighbour
    outside the region, the midpoint of their recovery points — where the region's cells
    end, on the surface: the line where a fixed or a loaded face meets a free one, singular
    in the continuum. ``phi``: the cells' extents (:func:`_particle_points`)."""
    from scipy.spatial import cKDTree

    from rackstress.stress.tensor import part_recovery_points

    sel = np.asarray(sel, bool)
    if not sel.any() or sel.all():
        return np.zeros((0, 3))
    a = float(spacing)
    pts = part_recovery_points(o, a, phi)
    on_surface = np.any(np.abs(pts - o) > 1e-9 * a, axis=1)
    pr = cKDTree(o).query_pairs(1.01 * a, output_type="ndarray")
    if not len(pr):
        return np.zeros((0, 3))
    i, j = np.r_[pr[:, 0], pr[:, 1]], np.r_[pr[:, 1], pr[:, 0]]
    edge = sel[i] & ~sel[j] & on_surface[i]
    return np.unique(0.5 * (pts[i[edge]] + pts[j[edge]]), axis=0)


def bands(values: np.ndarray, fea_vm: np.ndarray, dist: np.ndarray, spacing: float,
          edges=BANDS) -> list:
    """Agreement by distance from the singular points, in spacings (``edges``: (lo, hi)
    pairs): per band the particles in it, Spearman ρ, the peak ratio (particles' largest over
    FEA's largest in the band) and the median of |particle − FEA| over FEA's largest.

    >>> d = np.array([0.5, 1.5, 3.0, 4.0, 9.0, 12.0])
    >>> b = bands(np.array([9, 4, 3, 2, 1, 1.0]), np.array([5, 4, 3, 2, 1, 1.1]), d, 1.0)
    >>> [(x["band"], x["n"], x["peak_ratio"]) for x in b]
    [('0-1', 1, 1.8), ('1-2', 1, 1.0), ('2-5', 2, 1.0), ('>5', 2, 0.9090909090909091)]
    """
    from scipy.stats import spearmanr

    out = []
    d = np.asarray(dist, float) / float(spacing)
    for lo, hi in edges:
        sel = (d >= lo) & (d < hi) & np.isfinite(values) & np.isfinite(fea_vm)
        v, f = np.asarray(values)[sel], np.asarray(fea_vm)[sel]
        row = {"band": f"{lo:g}-{hi:g}" if np.isfinite(hi) else f">{lo:g}", "lo": lo,
               "hi": hi if np.isfinite(hi) else None, "n": int(sel.sum()),
               "spearman": None, "peak_ratio": None, "median_error": None,
               "peak_particles": None, "peak_fea": None}
        if len(v):
            row.update(peak_particles=float(v.max()), peak_fea=float(f.max()),
                       peak_ratio=float(v.max() / f.max()) if f.max() > 0 else None,
                       median_error=float(np.median(np.abs(v - f)) / f.max())
                       if f.max() > 0 else None)
            if len(v) > 2 and np.ptp(v) > 0 and np.ptp(f) > 0:
                row["spearman"] = float(spearmanr(v, f).statistic)
        out.append(row)
    return out


def governing(fe_x: np.ndarray, fe_vm: np.ndarray, singular: Singular,
              points: np.ndarray | None = None, at_points: np.ndarray | None = None) -> dict:
    """The FE's governing stress: its largest von Mises stress at least the zone away from
    every singular point, and where — over the FE's own nodes ``fe_x`` (``fe_vm``) and,
    where given, its field at the particles' read points ``points`` (``at_points``: the
    points the run's headline reads, under the same rule).

    A stress that rises toward a singular point is largest at the zone's edge. The nodes of
    a coarse FE mesh stand up to an element size inside that edge, so their largest alone
    read the FE's field low where the particles read it at their own, finer points: on the
    SO-100 shoulder bracket the FE's nodes gave 0.239 MPa, its field at the run's governing
    point (read 0.04 mm outside the zone) 0.300 (``rackstress fea``, measured while building this).

    >>> s = Singular(np.zeros((1, 3)), 1.0, "one", 1.0)
    >>> x = np.array([[0.5, 0, 0], [1.5, 0, 0], [2.5, 0, 0]])       # σ = 1/r, nodes
    >>> governing(x, 1 / x[:, 0], s)["value"]
    0.6666666666666666
    >>> p = np.array([[1.05, 0, 0], [0.9, 0, 0]])                     # read points
    >>> round(governing(x, 1 / x[:, 0], s, p, 1 / p[:, 0])["value"], 4)
    0.9524
    """
    x, vm = np.asarray(fe_x, float), np.asarray(fe_vm, float)
    if points is not None and at_points is not None:
        x = np.concatenate([x, np.asarray(points, float).reshape(-1, 3)])
        vm = np.concatenate([vm, np.asarray(at_points, float)])
    away = (singular.distance(x) >= singular.zone) & np.isfinite(vm)
    if not away.any():
        return {"value": None, "position": None}
    k = np.flatnonzero(away)[int(np.argmax(vm[away]))]
    return {"value": float(vm[k]), "position": x[k].tolist()}


#: The FE check's local refinement at its governing point (the classical global–local
#: submodel, the same as the particles' notch reading: stress/notch.py ``submodel``): the
#: part's true shape in a ball of this many of the FE's element sizes there, its cut
#: displaced by the FE's own (P2) displacement field, graded to :data:`LOCAL_FINE` of the
#: ball's radius at its centre. The FE check's global mesh is graded at edges and curved
#: faces only to a budget (a corpus part's 6.25 mm fillet met 2 mm edges of fTetWild's
#: surface, its governing stress still rising 8 % between FE sizes); the ball's is not.
LOCAL_ELEMENTS = 3.0
#: ... its mesh size at the centre, × the ball's radius: the reading at the first, and at the
#: second how far it moved (the local peak's own convergence)
LOCAL_FINE = (1 / 12, 1 / 24)
#: ... the most balls it moves through, each to the largest stress within a third of its
#: radius, until that is its centre
LOCAL_BALLS = 3
#: ... the ball's radius × these in turn where gmsh cannot mesh it: notch.RADII's, then two
#: larger (one list: each radius tried once, at most seven balls)
LOCAL_RADII = (1.0, 1.1, 0.9, 1.25, 0.8, 1.3, 1.6)
#: ... a local reading that moved more than this between its two meshes beside facets that
#: turn inward by at least :data:`LOCAL_KINK_DEG` is said not to converge, and why
#: (:func:`facet_kink`)
LOCAL_MOVED = 0.03
LOCAL_KINK_DEG = 5.0


def element_size_at(mesh, x) -> float:
    """The mean edge length of the tetrahedra (``mesh.p``, ``mesh.t``) at the vertex nearest
    the point ``x``."""
    P, T = np.asarray(mesh.p, float), np.asarray(mesh.t)
    k = int(np.argmin(np.linalg.norm(P - np.asarray(x, float), axis=1)))
    t = T[(T == k).any(axis=1)]
    if not len(t):
        return float(np.ptp(P, axis=0).max())
    e = [np.linalg.norm(P[t[:, a]] - P[t[:, b]], axis=1) for a in range(4) for b in range(a)]
    return float(np.mean(e))


def _local_reading(sub, centre, R: float, singular: Singular):
    """The submodel's largest nodal von Mises stress on the part's own surface (not its cut)
    within a third of ``R`` of ``centre`` and the zone away from every singular point:
    (value, position), or (None, None) (:func:`rackstress.stress.notch.surface_peak`, the
    notch reading's rule)."""
    from rackstress.stress.notch import surface_peak

    return surface_peak(sub, centre, R, lambda X: singular.distance(X) >= singular.zone)


#: ... the most seconds the local refinement may take: gmsh's classification of a piece's
#: surface does not end on some (an SO-100 upper arm's ball: 7 minutes, killed; the base's
#: another time), and it cannot be interrupted in the process, so the refinement runs in a
#: child process. It takes 3–10 s where it ends (the corpus, bench parts); 20 s keeps the
#: check within its minute on a 20,000-particle part
LOCAL_TIMEOUT_S = 20.0


def local_peak(vertices, faces, sol, centre, singular: Singular, E: float, nu: float,
               echo=None, timeout: float = LOCAL_TIMEOUT_S, bears=None) -> dict:
    """:func:`_local_peak` in a forked child process (:func:`rackstress.lib.forked.call`),
    stopped after ``timeout`` seconds (RuntimeError saying so)."""
    from rackstress.lib import forked

    if echo:
        echo(f"fea: refining locally at {[round(float(x), 3) for x in centre]} …")
    try:
        return forked.call(lambda: _local_peak(vertices, faces, sol, centre, singular, E, nu,
                                               bears), timeout)
    except forked.Timeout:
        raise RuntimeError(f"gmsh had not meshed the ball after {timeout:.0f} s (its surface "
                           "classification does not end on some pieces of a file's facets): "
                           "not refined") from None


def _local_peak(vertices, faces, sol, centre, singular: Singular, E: float,
                nu: float, bears=None) -> dict:
    """The FE's governing stress refined locally (:data:`LOCAL_ELEMENTS`): the classical
    submodel about the FE's governing point ``centre``, its cut displaced by the FE solution
    ``sol``, read on the part's surface (:func:`_local_reading`), moved to the largest within
    a third of the ball's radius (at most :data:`LOCAL_BALLS` balls), then solved again twice
    as fine there (:data:`LOCAL_FINE`): how far it moved. ``bears`` = (x k×3, directions
    k×3, spacing): the particles held (in the directions held) or loaded (all three); the
    ball's nodes in their cells are displaced by ``sol`` in those directions, as its cut is
    (a support's face inside the ball is not free surface).

    Returns ``value``, ``position``, ``radius`` of the ball, ``fine`` (the finer mesh size),
    ``coarser_value`` and ``moved``. Raises ImportError without gmsh or manifold3d (the
    ``fem`` extra), RuntimeError where gmsh cannot mesh the ball."""
    from rackstress.stress.notch import submodel

    c = np.asarray(centre, float)
    R = LOCAL_ELEMENTS * element_size_at(sol.mesh, c)

    def displace(X):
        return sol.at(X)["displacement"]

    def solved(at, fine):          # the ball's sphere can cut the facets into overlapping ones
        return submodel(vertices, faces, at, None, None, R, R, E, nu, radius=R,
                        displace=displace, fine=fine * R, bears=bears, radii=LOCAL_RADII)

    seen = []
    for _ in range(LOCAL_BALLS):
        sub = coarse = solved(c, LOCAL_FINE[0])
        value, at = _local_reading(sub, c, R, singular)
        if value is None:
            raise RuntimeError("no point of the ball's surface lies clear of the singular "
                               "points")
        seen.append(c)
        if np.linalg.norm(at - c) <= R / 6 or any(np.linalg.norm(at - q) <= R / 6
                                                  for q in seen):
            break
        c = at
    fine = solved(c, LOCAL_FINE[1])
    if len(fine.mesh.X) == len(coarse.mesh.X):
        # gmsh could not remesh the piece (its facets), filled it inside them, ungraded: the
        # same mesh twice says nothing of convergence
        return {"value": value, "position": np.asarray(at).tolist(), "radius": R,
                "fine": None, "coarser_value": None, "moved": None,
                "facet_kink_deg": facet_kink(vertices, faces, at, R / 3),
                "note": "not refined: gmsh could not remesh the ball's piece of the file's "
                        "surface and filled it inside its own facets, ungraded"}
    fine_value, fine_at = _local_reading(fine, c, R, singular)
    if fine_value is None:
        fine_value, fine_at = value, at
    moved = abs(fine_value - value) / fine_value if fine_value else None
    kink = facet_kink(vertices, faces, fine_at, R / 3)
    note = None
    if kink >= LOCAL_KINK_DEG and moved is not None and moved > LOCAL_MOVED:
        note = (f"not converged: the file's facets turn inward by up to {kink:.0f}° there, and "
                "a faceted fillet's FE stress rises with every refinement (each facet edge a "
                "shallow re-entrant corner); the smooth fillet is not in the file: an STL "
                "exported with finer facets reads it")
    return {"value": fine_value, "position": np.asarray(fine_at).tolist(), "radius": R,
            "fine": LOCAL_FINE[1] * R, "coarser_value": value, "moved": moved,
            "facet_kink_deg": kink, "note": note}


def facet_kink(vertices, faces, x, radius: float) -> float:
    """The largest angle (degrees) by which two of the surface's facets turn inward at an
    edge within ``radius`` of ``x`` (0: none). A faceted fillet is a chain of such shallow
    re-entrant edges, each a mild singularity of the FE's stress: its value there rises with
    every refinement (a corpus part's 6.25 mm fillet, facets meeting at 15–18°: +7 % each
    time the local mesh was halved, measured while building this), so a converged reading
    needs the smooth surface, which an STL does not hold."""
    import trimesh

    m = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces), process=True)
    mid = m.vertices[m.face_adjacency_edges].mean(axis=1)
    near = (np.linalg.norm(mid - np.asarray(x, float), axis=1) <= radius) \
        & ~m.face_adjacency_convex
    return float(np.degrees(m.face_adjacency_angles[near]).max()) if near.any() else 0.0


def agreement(values: np.ndarray, fea_vm: np.ndarray, points: np.ndarray, zone: float,
              singular: np.ndarray, to_stress: float | None = None) -> dict:
    """ρ, top-5 % overlap (:func:`rackstress.validity.compare.agreement`) and the peak ratio
    away from ``singular`` points (k×3), those within ``zone`` (a length) left out: particle
    peak × ``to_stress`` / FEA peak."""
    from scipy.spatial import cKDTree

    from rackstress.validity.compare import agreement as ranks

    out = ranks(np.asarray(values, float), np.asarray(fea_vm, float), points)
    away = np.ones(len(points), dtype=bool)
    if len(singular):
        d, _ = cKDTree(singular).query(points)
        away = d > zone
    out["n_away"] = int(away.sum())
    out["zone"] = float(zone)
    if to_stress is not None and away.any():
        pv, fv = float(np.nanmax(values[away])) * to_stress, float(np.nanmax(fea_vm[away]))
        out.update(peak_particle=pv, peak_fea=fv, peak_ratio=pv / fv)
    else:
        out.update(peak_particle=None, peak_fea=None, peak_ratio=None)
    return out


def _json_default(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x))


def write_json(path: Path, data: dict) -> None:
    tmp = Path(path).with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_json_default))
    tmp.replace(path)


class FEAMemoryError(RackstressError):
    """The FE model would not fit in the memory this process may use (exit 2: choose a
    coarser ``--size``)."""


def available_bytes() -> tuple[float, str]:
    """The memory this process may still take, and what limits it: the smaller of the
    system's available memory (``/proc/meminfo`` MemAvailable) and, under ``ulimit -v``, the
    address space left (RLIMIT_AS − VmSize)."""
    import resource

    avail, why = float("inf"), "no limit known"
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail, why = float(line.split()[1]) * 1024, "the system's available memory"
    except OSError:
        pass
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        used = 0.0
        try:
            for line in Path("/proc/self/status").read_text().splitlines():
                if line.startswith("VmSize:"):
                    used = float(line.split()[1]) * 1024
        except OSError:
            pass
        if soft - used < avail:
            avail, why = max(0.0, soft - used), f"the address-space limit (ulimit -v {soft // 1024})"
    return avail, why


def memory_needed(n_elements: int) -> float:
    """Bytes the FE solution of ``n_elements`` P2 tetrahedra takes beyond what the process
    holds: :data:`BYTES_PER_ELEMENT` each (measured: assembly, AMG hierarchy, projection)."""
    return BYTES_PER_ELEMENT * float(n_elements) + MEMORY_FLOOR


def elements_expected(volume: float, size: float) -> float:
    """Tetrahedra gmsh makes of ``volume`` at largest edge ``size`` (measured
    :data:`TETS_PER_SIZE3` per size³), before any refinement."""
    return TETS_PER_SIZE3 * float(volume) / float(size) ** 3


def graded_elements(x: np.ndarray, cell_volume: float, near: np.ndarray, size: float,
                    near_size: float) -> float:
    """Tetrahedra gmsh makes in the volume sampled by the points ``x`` (each standing for
    ``cell_volume``) under :func:`surface_mesh`'s size field h = clip(GRADE·d, near_size,
    size), d the distance to ``near``: :data:`TETS_PER_SIZE3` · Σ cell_volume / h³. On the
    finger's lower link: 64,292 and 168,744 expected, 68,822 and 179,215 made."""
    from scipy.spatial import cKDTree

    x = np.asarray(x, float).reshape(-1, 3)
    near = np.asarray(near, float).reshape(-1, 3)
    d = cKDTree(near).query(x)[0] if len(near) else np.full(len(x), np.inf)
    h = np.clip(GRADE * d, near_size, size)
    return float(TETS_PER_SIZE3 * cell_volume * np.sum(1.0 / h ** 3))


def near_size_within(x, cell_volume, near, size, near_size, budget=FE_ELEMENTS):
    """The finest FE size, ``near_size`` or the smallest larger one (up to ``size``: no
    grading) whose graded mesh is expected within ``budget`` tetrahedra
    (:func:`graded_elements`), and that expectation."""
    n = graded_elements(x, cell_volume, near, size, near_size)
    if n <= budget or near_size >= size:
        return near_size, n
    lo, hi = math.log(near_size), math.log(size)
    coarsest = graded_elements(x, cell_volume, near, size, size)
    if coarsest > budget:
        return size, coarsest
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if graded_elements(x, cell_volume, near, size, math.exp(mid)) > budget:
            lo = mid
        else:
            hi = mid
    return math.exp(hi), graded_elements(x, cell_volume, near, size, math.exp(hi))


def check_memory(n_elements: float, size: float, what: str) -> None:
    """Refuse (:class:`FEAMemoryError`) an FE model that would not fit, saying how much it
    needs and which ``--size`` would fit."""
    need = memory_needed(n_elements)
    avail, why = available_bytes()
    if need <= avail:
        return
    fit = size * (need / max(avail - MEMORY_FLOOR, 1.0)) ** (1 / 3) * 1.1 \
        if avail > MEMORY_FLOOR else None
    raise FEAMemoryError(
        f"the FE model ({what}: about {n_elements:,.0f} quadratic tetrahedra at FE size "
        f"{size:.3g}) needs about {need / 2**30:.2f} GB of memory and {avail / 2**30:.2f} GB "
        f"is free ({why}). Reduce it with a coarser FE mesh"
        + (f": --size {fit:.3g} needs about {memory_needed(n_elements * (size / fit) ** 3) / 2**30:.2f} GB"
           if fit else "")
        + ", or check a run at a larger spacing (fewer particles), or free memory")


def solve_part(o, spacing, shape, held_x, held_mask, load_x, load_F, E, nu, size=None,
               near=None, near_size=None, what="FE mesh", refined: bool = False,
               constraints: CellConstraints | None = None, reparametrize: bool = True,
               method: str = "auto"):
    """FEA of a part: its shape (a mesh :class:`~rackstress.model.regions.Surface` → gmsh,
    refined to ``near_size`` around the points ``near``; else the union of the cells of
    ``o``), nodes in held particles' cells fixed in ``held_mask``'s directions, the particle
    forces spread to the nodes. Returns (Solution, how it was meshed, a note or None, nodal
    forces, fixed nodes). The mesh is checked against the memory free before it is solved
    (:func:`check_memory`)."""
    from rackstress.model.regions import Surface

    how, note, got, remeshed = "cells", None, {}, False
    h = float(size) if size else SIZE_SPACINGS * spacing
    if isinstance(shape, Surface):
        try:
            pd = shape.polydata
            p, t = surface_mesh(np.asarray(pd.points), np.asarray(pd.regular_faces), h,
                                near, near_size, info=got, reparametrize=reparametrize)
            how = f"gmsh tetrahedra of {Path(shape.name).name}"
            if "own triangles" in got.get("surface", ""):
                how += " inside its own triangles"
                note = got["surface"]
            elif "inside fTetWild's surface" in got.get("surface", ""):
                how += " inside fTetWild's surface"
                note = got["surface"]
            elif "fTetWild's own" in got.get("surface", ""):
                how = f"fTetWild's tetrahedra of {Path(shape.name).name}{got['cut']}"
                note = got["surface"]
            else:
                remeshed = True                 # gmsh remeshed the file: well-shaped
        except MemoryError:
            raise
        except Exception as exc:  # noqa: BLE001 - gmsh refused the surface: say so, use cells
            note = f"gmsh could not mesh {shape.name} ({exc}); the union of the cells is used"
    if how == "cells":
        p, t = cell_mesh(o, spacing)
        how = "the union of the particles' cells (6 tetrahedra a cube)"
        h = spacing
        if refined:                               # the cells' second mesh: each cut in 8
            from rackstress.lib.tet import refine

            check_memory(8 * t.shape[1], h / 2, what)
            q, u = refine(p.T, t.T)
            p, t, h = q.T, u.T, h / 2
            how += ", each cut into 8"
    check_memory(t.shape[1], h, what)
    fixed = fixed_nodes(p, held_x, held_mask, spacing)
    forces = nodal_forces(p, t, load_x, load_F, spacing)
    try:
        if REMESHED_CG and remeshed and method == "auto" and not constraints:
            method = "remeshed"
        sol = solve(p, t, E, nu, fixed, forces, constraints=constraints, method=method)
    except MemoryError:
        avail, why = available_bytes()
        raise FEAMemoryError(
            f"the FE model ({what}: {t.shape[1]:,} quadratic tetrahedra at FE size {h:.3g}) ran "
            f"out of memory ({avail / 2**30:.2f} GB free now, {why}; about "
            f"{memory_needed(t.shape[1]) / 2**30:.2f} GB was expected). Reduce it with a "
            f"coarser FE mesh (--size {1.3 * h:.3g} or more) or free memory") from None
    sol.info["size"] = h
    if "fTetWild" in how and "ftetwild_edge" in got:      # fTetWild's surface, not graded
        sol.info.update(ftetwild_edge=got["ftetwild_edge"],
                        ftetwild_envelope=got["ftetwild_envelope"])
    return sol, how, note, forces, fixed


# --------------------------------------------------------------------------- a run directory
class _Recorded:
    """A run's parts from its own record (scene.json's groups, the original positions) when
    its scene cannot be rebuilt here (a scene file changed or gone): enough for the FEA of
    the particles' cells, with boundary.npz's supports and loads."""

    class _Group:
        def __init__(self, name, o):
            self.name, self.o, self.n, self.meta = name, o, len(o), {}

    def __init__(self, rundir: Path):
        from rackstress.stress.rundata import load_run

        rec = json.loads((rundir / "scene.json").read_text())
        o = np.asarray(load_run(rundir).o, float)
        self._slices = {g["name"]: slice(g["first_id"] - 1, g["first_id"] - 1 + g["n"])
                        for g in rec["groups"]}
        self.groups = {n: self._Group(n, o[sl]) for n, sl in self._slices.items()}
        self.operators = {}

    def slice(self, name: str) -> slice:
        return self._slices[name]


def _part_group(scene, summary: dict, boundary: dict, group: str | None) -> str:
    if group is not None:
        if group not in scene.groups:
            raise ValueError(f"no group '{group}' in the run (groups: {', '.join(scene.groups)})")
        return group
    mats = [n for n, g in (summary.get("groups") or {}).items() if isinstance(g, dict)
            and g.get("material")]
    if mats:
        return max(mats, key=lambda n: scene.groups[n].n)
    ids = np.concatenate([boundary["held_ids"], boundary["load_ids"]]) - 1
    best = None
    for name in scene.groups:
        sl = scene.slice(name)
        k = int(((ids >= sl.start) & (ids < sl.stop)).sum())
        if k and (best is None or scene.groups[name].n > scene.groups[best].n):
            best = name
    if best is None:
        raise ValueError("no group has supports or loads: nothing for the FEA to solve")
    return best


def _shape(scene, name: str):
    """The part's shape: the scene's solid (a filled region) or its bind-inside region."""
    from rackstress.model.operators import Bind, WithinInside

    g = scene.groups[name]
    shape = (g.meta.get("solid") or {}).get("shape") if isinstance(g.meta, dict) else None
    if shape is None:
        for op in scene.operators.get(name, []):
            if isinstance(op, Bind) and isinstance(op.coeff, WithinInside) and op.source == name:
                shape = op.coeff.region
    return shape


def _spacing(scene, name: str) -> float:
    from scipy.spatial import cKDTree

    g = scene.groups[name]
    s = (g.meta.get("solid") or {}).get("spacing") if isinstance(g.meta, dict) else None
    if s:
        return float(s)
    d, _ = cKDTree(g.o).query(g.o, k=2)
    return float(np.median(d[:, 1]))


def _boundary(rundir: Path, scene) -> tuple[dict, str]:
    path = rundir / "boundary.npz"
    if path.is_file():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}, "boundary.npz"
    return boundary_from_scene(scene), "the scene (no boundary.npz)"


def _particle_measure(rundir: Path, sl: slice, measure: str | None):
    """The measure at the last frame, from the post-processing's fields: ``measures.npz`` is
    only a cache (written on request), so the fields are computed when it is absent."""
    from rackstress.stress.post import compute_fields
    from rackstress.stress.rundata import load_run

    values = compute_fields(load_run(rundir), cache=True).values
    names = [m for m in ("von_mises", "strain") if m in values]
    if measure is None:
        if not names:
            raise ValueError(f"{rundir}: the run's measures have neither von_mises nor strain")
        measure = names[0]
    if measure not in values:
        raise ValueError(f"{rundir}: the run has no measure '{measure}'")
    return measure, np.asarray(values[measure][-1], float)[sl]


def _particle_displacement(rundir: Path, sl: slice):
    try:
        from rackstress.stress.rundata import load_run

        rd = load_run(rundir)
        rd.trajectory[-1]
        order = np.argsort(rd.universe.atoms.ids)
        return (np.asarray(rd.universe.atoms.positions, float)[order] - rd.o)[sl]
    except Exception:  # noqa: BLE001 - the displacement is shown when it can be read
        return None


def compared_state(summary: dict, rundir, allow_unsettled: bool = False,
                   allow_dynamic: bool = False) -> str:
    """What the FE check compares, in a sentence; a refusal (ValueError, exit 2) for a static
    run that did not settle (``summary.json`` → ``status``) or a dynamic run, unless allowed.

    The FE solution is a static equilibrium: against a state that is not one (a part still
    moving, a solve stopped short) its agreement measures the motion, not the picture."""
    status = summary.get("status")
    if summary.get("analysis") == "static":
        if status == "settled":
            return "the static equilibrium"
        why = (f"{rundir}: the static analysis did not settle (summary.json: status "
               f"\"{status}\", residual {summary.get('residual', float('nan')):.2g} of the "
               "applied load)")
        if not allow_unsettled:
            raise ValueError(why + ": its state is not an equilibrium, and the FE solution "
                             "is one, so their agreement would measure the unbalanced forces. "
                             "Settle it first (docs/faults.md), or pass --allow-unsettled to "
                             "compare it anyway, labelled as such")
        return f"a state that did not settle (residual {summary.get('residual', 0):.2g})"
    where = f"step {summary.get('steps')} of {summary.get('steps_requested')}"
    if not allow_dynamic:
        raise ValueError(f"{rundir}: a dynamic run (status \"{status}\", analysis not "
                         f"static): its last frame ({where}) is a moving state, and the FE "
                         "solution is the static equilibrium under the same supports and "
                         "loads, so their agreement would measure the motion. Run the scene "
                         "with analysis = \"static\", or pass --allow-dynamic to compare "
                         "the last frame anyway, labelled as such")
    return (f"the last frame of a dynamic run ({where}) against the static FE solution: "
            "agreement only as far as that frame is at rest")


def check_run(rundir, E: float | None = None, nu: float | None = None,
              size: float | None = None, group: str | None = None,
              measure: str | None = None, echo=print, keep: bool = False,
              allow_unsettled: bool = False, allow_dynamic: bool = False,
              converge: bool = True, local: bool = True) -> dict:
    """Solve a run's part by FEA and compare it with the particle measure (module docstring).

    Refuses a static run that did not settle and a dynamic run (:func:`compared_state`)
    unless allowed, and an FE model that would not fit in memory (:class:`FEAMemoryError`).
    With ``converge`` the part is solved at two FE sizes (× :data:`COARSER`), and the change
    of the FE's governing stress between them is reported; with ``local`` (a mesh part) it is
    refined locally too (:func:`local_peak`: ``governing`` → ``local``). Writes ``fea.json`` (the
    agreement overall and by distance band, the governing point, how the FEA was set up),
    ``fea.npz`` (``fea_von_mises``, ``fea_displacement`` per particle of the part, the
    particle measure), ``vtk/fea.vtp`` (the part's particles with both fields as point
    arrays), ``vtk/fea_mesh.vtu`` (the FE mesh with ``von_mises`` and ``displacement``),
    ``figures/fea.png`` (both fields on one colour scale) and the report's "Finite-element
    check" section.

    Example
    -------
    ``rackstress fea runs/bracket`` (docs/fea.md).
    """
    import time

    from rackstress.model.regions import Surface
    from rackstress.runs.resume import rebuild_scene

    t0, c0 = time.perf_counter(), time.process_time() + cpu_children()
    rundir = Path(rundir)
    summary = json.loads((rundir / "summary.json").read_text())
    state = compared_state(summary, rundir, allow_unsettled, allow_dynamic)
    rebuilt = None
    try:
        scene = rebuild_scene(rundir)
    except Exception as exc:  # noqa: BLE001 - the run's own record still serves (cells)
        scene, rebuilt = _Recorded(rundir), f"the scene could not be rebuilt ({exc})"
        if not (rundir / "boundary.npz").is_file():
            raise ValueError(f"{rebuilt} and the run has no boundary.npz") from None
    bnd, bsource = _boundary(rundir, scene)
    if rebuilt and len(bnd.get("constrained_ids", ())):  # pinned, cylindrical, oblique rollers
        raise ValueError(
            f"{rundir}: {rebuilt}, and its supports hold {len(bnd['constrained_ids'])} "
            "particle(s) in directions that are not x, y or z (a pinned or cylindrical hole, "
            "a roller or symmetry plane at an angle): their axes and normals are the scene's "
            "(boundary.npz records only which particles), so the FE check cannot model them. "
            "Restore the scene file the run was made from, or run it again")
    name = _part_group(scene, summary, bnd, group)
    g, sl = scene.groups[name], scene.slice(name)
    spacing = _spacing(scene, name)
    constraints = CellConstraints(g.o, spacing, list(getattr(g, "constraints", None) or []))
    mat = ((summary.get("groups") or {}).get(name) or {}).get("material") or {}
    E_ = float(E if E is not None else mat.get("E", 1.0))
    nu_ = float(nu if nu is not None else mat.get("nu", 0.3))
    shape = None if rebuilt else _shape(scene, name)
    hk = np.asarray(bnd["held_ids"], np.int64) - 1 - sl.start
    hin = (hk >= 0) & (hk < g.n)
    lk = np.asarray(bnd["load_ids"], np.int64) - 1 - sl.start
    lin = (lk >= 0) & (lk < g.n)
    if not lin.any():
        raise ValueError(f"part '{name}' carries no external load (boundary: {bsource}); a "
                         "load that reaches it by contact from another group is not modelled "
                         "by the FEA")
    held_x, load_x = g.o[hk[hin]], g.o[lk[lin]]
    held_mask = np.asarray(bnd["held_mask"], bool)[hin]
    h = float(size) if size else SIZE_SPACINGS * spacing
    near_size = NEAR_SPACINGS * spacing * (h / (SIZE_SPACINGS * spacing))
    curved = np.zeros((0, 3))
    if isinstance(shape, Surface):
        pd = shape.polydata
        concave, curved = surface_features(np.asarray(pd.points),
                                           np.asarray(pd.regular_faces), near_size)
    else:
        concave = concave_edges(*cell_mesh(g.o, spacing))
    # a support fixed in every direction has an edge where the stress is unbounded; a roller
    # or a symmetry plane (some directions free) is a smooth boundary, not singular
    full = held_mask.all(axis=1)
    held_sel = np.zeros(g.n, bool)
    held_sel[hk[hin][full]] = True
    load_sel = np.zeros(g.n, bool)
    load_sel[lk[lin]] = True
    # the part's cells' extents as the run wrote them (runs.run.fractions_of), which put each
    # surface particle's recovery point on the part's face; None for a dynamic run
    from rackstress.stress.measures import bindings_array

    phi = bindings_array(rundir, "phi", (g.n, 3), sl)
    edges = np.concatenate([region_edges(g.o, held_sel, spacing, phi),
                            region_edges(g.o, load_sel, spacing, phi)])
    singular = singular_points(np.concatenate([concave, edges]), held_x[full], load_x,
                               spacing)
    singular = run_singular(rundir, name, singular, load_x)
    volume = g.n * spacing ** 3
    sizes = [h * COARSER, h] if converge else [h]
    check_memory(elements_expected(volume, h), h, "expected before meshing")
    near = np.concatenate([concave, curved, edges])
    wanted = near_size
    budget = None
    if isinstance(shape, Surface):
        near_size, expected = near_size_within(g.o, spacing ** 3, near, h, near_size)
        budget = {"elements": FE_ELEMENTS, "expected": expected, "near_size": near_size,
                  "near_size_wanted": wanted, "raised": near_size > wanted}
        if near_size > wanted:
            echo(f"fea: {name}: the grading to {wanted:.3g} at edges and curved faces would "
                 f"make about {graded_elements(g.o, spacing ** 3, near, h, wanted):,.0f} "
                 f"tetrahedra; graded to {near_size:.3g} instead, within the budget of "
                 f"{FE_ELEMENTS:,}")
    sols, reparam, note, method = [], True, None, "auto"
    for k, hs in enumerate(sizes):
        echo(f"fea: {name}: meshing and solving at FE size {hs:.3g} "
             f"({k + 1} of {len(sizes)}) …")
        try:
            sol, how_k, note_k, forces_k, fixed_k = solve_part(
                g.o, spacing, shape, held_x, held_mask, load_x,
                np.asarray(bnd["load_force"], float)[lin], E_, nu_, hs,
                near, near_size * hs / h, what=f"FE size {hs:.3g}", constraints=constraints,
                reparametrize=reparam, method=method)
        except RuntimeError as exc:        # the FE solve itself (conjugate gradients)
            if not sols:
                raise ValueError(f"the FE check of part '{name}' failed at FE size {hs:.3g}: "
                                 f"{exc}. Try another FE size (--size), or --no-converge"
                                 ) from None
            note = "; ".join(x for x in (note, f"not solved at FE size {hs:.3g}: {exc}; "
                                         "the coarser FE mesh is the reference, its "
                                         "convergence not measured") if x)
            echo(f"fea: {name}: FE size {hs:.3g} failed ({exc}); the coarser mesh is kept")
            break
        how, forces, fixed = how_k, forces_k, fixed_k
        sols.append(sol)
        method = next_method(sol.info, method)
        note = note or note_k                  # the first mesh's: why gmsh took that way
        reparam = "inside its own triangles" not in how and "fTetWild" not in how
        if "inside its own triangles" in how and k == 0 and len(sizes) > 1:
            # inside the file's own facets the FE size changes only the interior: the same
            # mesh again would say nothing of convergence, at twice the cost
            note = "; ".join(x for x in (note, "one FE mesh: inside the file's own facets "
                                         "another FE size gives nearly the same mesh, so "
                                         "the FE's convergence is not measured") if x)
            break
        if how.startswith("the union"):          # cells: the second mesh is each cut in 8
            if converge:
                echo(f"fea: {name}: solving again with each tetrahedron cut into 8 …")
                try:
                    sols.append(solve_part(
                        g.o, spacing, shape, held_x, held_mask,
                        load_x, np.asarray(bnd["load_force"], float)[lin], E_, nu_,
                        what="cells cut into 8", refined=True, constraints=constraints,
                        method=method)[0])
                    how += " (and each cut into 8)"
                except FEAMemoryError as exc:
                    note = "; ".join(x for x in (note, f"not solved at a second size: {exc}")
                                     if x)
            break
    sol = sols[-1]
    mname, values = _particle_measure(rundir, sl, measure)
    from rackstress.stress.measures import read_surface

    points = _particle_points(g.o, spacing, mname, phi, read_surface(rundir, name))
    res = sol.at(points)
    G = E_ / (2 * (1 + nu_))
    to_stress = 1.0 if mname == "von_mises" else (2 * math.sqrt(3) * G if mat or E else None)
    sv = values * to_stress if to_stress is not None else None
    dist = singular.distance(points)
    agree = agreement(values, res["von_mises"], points, singular.zone, singular.points,
                      to_stress)
    # the FE's field at its nodes and where the particles are read (governing's docstring)
    fe_gov = [governing(s_.mesh.X, s_.nodal()["von_mises"], singular, points,
                        (res if s_ is sol else s_.at(points))["von_mises"]) for s_ in sols]
    gov = dict(fe_gov[-1])
    if len(sols) > 1 and fe_gov[0]["value"] and gov["value"]:
        gov["coarser"] = {"size": sols[0].info["size"], "value": fe_gov[0]["value"],
                          "position": fe_gov[0]["position"]}
        gov["moved"] = abs(gov["value"] - fe_gov[0]["value"]) / gov["value"]
    if local and gov["value"] and isinstance(shape, Surface):
        pd = shape.polydata
        try:
            gov["local"] = local_peak(np.asarray(pd.points), np.asarray(pd.regular_faces), sol,
                                      gov["position"], singular, E_, nu_, echo=echo,
                                      bears=(np.concatenate([held_x, load_x]),
                                             np.concatenate([held_mask, np.ones_like(
                                                 load_x, dtype=bool)]), spacing))
        except ImportError as exc:
            gov["local_note"] = (f"{exc.name or exc} is not installed: the local refinement "
                                 "needs the fem extra")
        except RuntimeError as exc:             # gmsh's own words
            gov["local_note"] = f"no local refinement: {exc}"
    if sv is not None and gov["value"]:
        k = int(np.argmin(np.linalg.norm(points - np.asarray(gov["position"]), axis=1)))
        away = dist >= singular.zone
        kp = np.flatnonzero(away)[int(np.nanargmax(sv[away]))] if away.any() else None
        gov.update(particle=int(sl.start + k + 1), particle_position=points[k].tolist(),
                   particle_distance=float(np.linalg.norm(points[k] - gov["position"])),
                   particle_value=float(sv[k]), ratio=float(sv[k] / gov["value"]),
                   particles_governing=None if kp is None else float(sv[kp]),
                   particles_governing_ratio=None if kp is None else float(sv[kp] / gov["value"]))
    F_tot = np.asarray(bnd["load_force"], float)[lin].sum(axis=0)
    quality = mesh_quality(sol.mesh.p, sol.mesh.t)
    if quality["poor"]:
        quality["why"] = (f"{100 * quality['sliver_share']:.0f} % of the FE's tetrahedra are "
                          f"slivers (quality < {SLIVER_Q:g}; median {quality['median']:.2f}, a "
                          f"regular one 1)" + (": the mesh is the file's own coarse facets "
                                               "filled" if "own triangles" in how else "")
                          + "; its stress is not a reference, and this comparison says "
                          "nothing of the particles. gmsh remeshes a surface of well-shaped "
                          "facets: an STL exported again with a maximum edge length (a "
                          "setting of most CAD exporters) may let it")
    data = {
        "group": name, "particles": int(g.n), "spacing": spacing, "measure": mname,
        "to_stress": to_stress, "units": str(bnd.get("units", summary.get("units", "paper"))),
        "stress_unit": _stress_unit(summary, bnd), "compared": state,
        "material": {"E": E_, "nu": nu_, "from": "summary.json" if mat else
                     ("options" if E is not None else "default (E = 1, ν = 0.3)")},
        "boundary": bsource, "mesh": how, "fe": sol.info, "fe_budget": budget,
        "fe_meshes": [s_.info for s_ in sols],
        "note": "; ".join(x for x in (rebuilt and rebuilt + ": the part is the union of its "
                                      "particles' cells", note) if x) or None,
        "held_particles": int(hin.sum()), "fixed_fe_nodes": int(fixed.any(axis=1).sum()),
        "constrained": [{"label": c.label, "kind": type(c).__name__.lower(),
                         "particles": int(len(np.unique(c.ids)))} for c in constraints.items],
        "constrained_fe_nodes": sol.info.get("constrained_nodes", 0),
        "rings": sol.info.get("rings", []),
        "loaded_particles": int(lin.sum()), "total_force": F_tot,
        "fe_total_force": forces.sum(axis=0),
        "zone": {"length": singular.zone, "spacings": singular.zone / spacing,
                 "rule": singular.rule, "singular_points": int(len(singular.points)),
                 "source": singular.source},
        "agreement": agree,
        "bands": bands(sv if sv is not None else values, res["von_mises"], dist, spacing),
        "governing": gov, "target": TARGET, "fe_quality": quality,
        "fea_peak_von_mises": float(res["von_mises"].max()),
        "fea_max_displacement": float(np.linalg.norm(res["displacement"], axis=1).max()),
    }
    data["wall_s"] = time.perf_counter() - t0
    data["cpu_s"] = time.process_time() + cpu_children() - c0   # fTetWild's process included
    disp = _particle_displacement(rundir, sl)
    _write_outputs(rundir, points, values, mname, res, disp, sol, data)
    if keep:          # for a benchmark's other stress routes: the same points and FEA field
        data.update(_o=g.o, _points=points, _fea_vm=res["von_mises"], _singular=singular,
                    _values=values, _slice=sl, _zone=singular.zone, _sol=sol)
    return data


def _stress_unit(summary: dict, bnd: dict) -> str:
    units = str(bnd.get("units", summary.get("units", "paper")))
    return {"mm-N-s": "MPa", "SI": "Pa"}.get(units, "stress units")


def _particle_points(o: np.ndarray, spacing: float, mname: str,
                     phi: np.ndarray | None = None, surface=None) -> np.ndarray:
    """Where each particle's measure is read: the stress's recovery point (the default
    ``patch`` route: the centre inside the part, its cell's surface point on the surface,
    :func:`rackstress.stress.tensor.part_recovery_points` with the cells' extents ``phi`` and
    the part's ``surface``, as the run's measure reads it), else the particle's position."""
    if mname == "von_mises":
        from rackstress.stress.tensor import part_recovery_points

        return part_recovery_points(o, spacing, phi, surface)
    return np.asarray(o, float)


def _write_outputs(rundir: Path, o, values, mname, res, disp, sol, data) -> None:
    import pyvista as pv

    np.savez(rundir / "fea.npz", fea_von_mises=res["von_mises"],
             fea_displacement=res["displacement"], points=o, **{mname: values})
    (rundir / "vtk").mkdir(exist_ok=True)
    cloud = pv.PolyData(np.ascontiguousarray(o))
    cloud.point_data["fea_von_mises"] = res["von_mises"]
    cloud.point_data["fea_displacement"] = res["displacement"]
    cloud.point_data[mname] = values
    if disp is not None:
        cloud.point_data["displacement"] = disp
    cloud.save(rundir / "vtk" / "fea.vtp")
    m = sol.mesh
    nv = len(m.p)
    grid = pv.UnstructuredGrid({pv.CellType.TETRA: m.t.copy()}, m.p.copy())
    nodal = sol.nodal()
    grid.point_data["von_mises"] = nodal["von_mises"][:nv]
    grid.point_data["displacement"] = nodal["displacement"][:nv]
    grid.save(rundir / "vtk" / "fea_mesh.vtu")
    (rundir / "figures").mkdir(exist_ok=True)
    picture(o, values * (data["to_stress"] or 1.0), mname, res["von_mises"],
            rundir / "figures" / "fea.png", data)
    data["files"] = ["fea.json", "fea.npz", "vtk/fea.vtp", "vtk/fea_mesh.vtu", "figures/fea.png"]
    write_json(rundir / "fea.json", data)


def colour_limit(values: np.ndarray, fea_vm: np.ndarray) -> float:
    """The one upper limit of both panels of fea.png: the larger of the two fields' 99.5th
    percentiles, so neither panel's hot spot is clipped more than the other's."""
    v = [np.nanpercentile(x, 99.5) for x in (values, fea_vm) if np.isfinite(x).any()]
    return float(max(v)) if v and max(v) > 0 else 1.0


def picture(o, values, mname, fea_vm, path: Path, data: dict):
    """The particle stress and FEA's von Mises side by side on one colour scale (grey to red
    as the report's pictures; viewed along the part's thinnest axis) with one colour bar in
    the run's stress unit; returns the figure's two colour limits (for a test)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axis = int(np.argmin(np.ptp(o, axis=0)))
    a, b = [k for k in range(3) if k != axis]
    order = np.argsort(o[:, axis])              # the near side drawn last
    fig, axes = plt.subplots(1, 2, figsize=(11, 5), constrained_layout=True)
    ag = data["agreement"]
    unit = data.get("stress_unit") or "stress units"
    label = "von Mises stress" if data.get("to_stress") is not None else mname
    vmax = colour_limit(values, fea_vm) if data.get("to_stress") is not None else None
    limits = []
    for ax, v, title in ((axes[0], values, f"particles: {mname}"),
                         (axes[1], fea_vm, "FEA: von Mises stress")):
        sc = ax.scatter(o[order, a], o[order, b], c=v[order], s=8, cmap="Reds",
                        vmin=0, vmax=vmax if vmax is not None else np.nanpercentile(v, 99.5))
        limits.append(sc.get_clim())
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("xyz"[a])
        ax.set_ylabel("xyz"[b])
        if vmax is None:
            fig.colorbar(sc, ax=ax, shrink=0.8)
    if vmax is not None:
        fig.colorbar(sc, ax=list(axes), shrink=0.8, label=f"{label} [{unit}]")
    gv = data.get("governing") or {}
    fig.suptitle(f"{data['group']}: Spearman ρ = {ag['spearman']:.3f}, top-5 % overlap = "
                 f"{ag['top5_overlap']:.2f}" + ("" if gv.get("ratio") is None else
                                                f", at FEA's governing point "
                                                f"{gv['ratio']:.3f}"))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return limits
