"""The part check of a static analysis: what the supports and the bindings leave free to move.

Before Newton's method runs (:mod:`rackstress.engines.static`) the part is checked in three
ways, each naming particles, where they are (undeformed, in the part's coordinates), their
group, and what to do:

1. **Bodies held by nothing or by too little.** Each connected set of bound particles (a
   *body*: a component of the binding graph) has six rigid-body modes; the held directions of
   its particles must remove all six. The 6 × 6 Gram matrix of the rigid modes restricted to
   the held directions is singular exactly when some rigid motion moves no held direction: a
   body with no support floats; one held on a line of particles turns about it; one held by
   rollers in one direction slides (:func:`rigid_modes_left`).
2. **Particles held by fewer bindings than directions.** A particle's 3 × 3 stiffness block at
   rest is Σ 2·c·m·n nᵀ over its bindings (Eq. 12 linearized, DESIGN §6) plus its held
   directions: of rank 2 in a wall one particle thick (no binding across it), of rank 1 at the
   end of a strut one particle wide. Such a wall is a membrane: the lattice has no stiffness
   across it. Loaded across that direction it has no equilibrium (refused); unloaded, the
   solve holds it where the rest of the part puts it, and the run warns
   (:func:`local_mechanisms`).
3. **Loaded mechanisms of whole clusters** (a block hinged on one line of particles, a wall one
   particle thick between two thick ones): found by the first linear solve, which carries a
   regularization μ·L (:data:`rackstress.engines.static.REGULARIZATION`). A loaded
   mechanism is held by that alone, so it takes nearly all the step's work; a part held by its
   bindings gives it ~μ·λ_L/λ_K of it (L the bindings' Laplacian)
   (:func:`mechanism_particles`).

Example
-------
>>> import numpy as np
>>> o = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
>>> held = np.zeros((3, 3), bool); held[:2] = True       # two particles held: a line
>>> free = rigid_modes_left(o, held)
>>> len(free), free[0]["kind"]
(1, 'rotation')
"""
from __future__ import annotations

import numpy as np

#: a rigid mode is left free when its held-direction Gram eigenvalue is below this × the largest
RIGID_TOL = 1e-9
#: a particle lacks a direction when its block's eigenvalue is below this × its largest
LOCAL_TOL = 1e-8
#: share of the first step's work taken by the regularization above which a load drives a
#: mechanism (a part held by its bindings: ~μ·λ_L/λ_K, far below it)
MECHANISM_SHARE = 0.5
#: where a group has more mechanism particles than this, the message names this many places
NAMED = 3


def components(n: int, I: np.ndarray, J: np.ndarray):
    """(count, label per particle) of the binding graph's connected components: the bodies."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    graph = sp.coo_matrix((np.ones(len(I)), (I, J)), shape=(n, n)).tocsr()
    return connected_components(graph, directed=False)


def _mode_rows(x: np.ndarray, centre: np.ndarray, size: float) -> np.ndarray:
    """(n, 3, 6): the six rigid modes' displacement of each particle (translations, then
    rotations about ``centre`` scaled by 1/``size``), row k for direction k."""
    d = (x - centre) / size
    R = np.zeros((len(x), 3, 6))
    R[:, 0, 0] = R[:, 1, 1] = R[:, 2, 2] = 1.0
    # u = ω × d: u_x = ω_y d_z − ω_z d_y, u_y = ω_z d_x − ω_x d_z, u_z = ω_x d_y − ω_y d_x
    R[:, 0, 4], R[:, 0, 5] = d[:, 2], -d[:, 1]
    R[:, 1, 5], R[:, 1, 3] = d[:, 0], -d[:, 2]
    R[:, 2, 3], R[:, 2, 4] = d[:, 1], -d[:, 0]
    return R


def rigid_modes_left(x: np.ndarray, held: np.ndarray, rows=None) -> list[dict]:
    """The rigid-body motions of the body with particles ``x`` (n, 3) that move none of its
    ``held`` directions (n, 3 booleans): each ``{"kind": "translation" | "rotation", "axis":
    unit vector, "point": a point on the rotation axis}``. Empty: the supports hold it.
    ``rows``: a function of the modes' rows (n, 3, 6) giving the held rows instead (supports
    that hold no whole axis: :mod:`rackstress.model.constraints`)."""
    x = np.asarray(x, float)
    centre = x.mean(axis=0)
    size = max(float(np.abs(x - centre).max()), 1e-300)
    R = _mode_rows(x, centre, size)
    R = R[held] if rows is None else rows(R)            # (held directions, 6)
    G = R.T @ R
    w, V = np.linalg.eigh(G)
    top = max(float(w[-1]), 1.0)
    out = []
    for k in np.flatnonzero(w <= RIGID_TOL * top):
        v = V[:, k]
        t, om = v[:3], v[3:] / size
        if np.linalg.norm(om) * size < 1e-6 * max(np.linalg.norm(t), 1e-300):
            out.append({"kind": "translation", "axis": t / np.linalg.norm(t), "point": centre})
        else:
            q = centre + np.cross(om, t) / float(om @ om)
            out.append({"kind": "rotation", "axis": om / np.linalg.norm(om), "point": q})
    return out


def local_blocks(n: int, o: np.ndarray, I, J, C, m) -> np.ndarray:
    """(n, 3, 3): each particle's stiffness block at rest, Σ 2·c·m·n nᵀ over its bindings."""
    d = o[J] - o[I]
    u = d / np.linalg.norm(d, axis=1)[:, None]
    w = 2.0 * np.asarray(C) * m[I]
    D = np.zeros((n, 9))
    outer = (u[:, :, None] * u[:, None, :]).reshape(-1, 9) * w[:, None]
    for k in range(9):
        D[:, k] = np.bincount(I, weights=outer[:, k], minlength=n)
    return D.reshape(n, 3, 3)


def local_mechanisms(D: np.ndarray, fixed: np.ndarray):
    """Particles whose block (with their held directions added) lacks a direction: (index,
    rank, the missing directions as an (k, 3, 3) projector onto them)."""
    A = D.copy()
    scale = np.maximum(np.trace(D, axis1=1, axis2=2), 1e-300)
    for k in range(3):
        A[:, k, k] += np.where(fixed[:, k], scale, 0.0)
    w, V = np.linalg.eigh(A)
    top = np.maximum(w[:, -1], 1e-300)
    lacking = w < LOCAL_TOL * top[:, None]
    bad = np.flatnonzero(lacking.any(axis=1) & (D.reshape(len(D), -1).any(axis=1)))
    rank = 3 - lacking[bad].sum(axis=1)
    P = np.zeros((len(bad), 3, 3))
    for c in range(3):
        v = V[bad, :, c] * lacking[bad, c][:, None]
        P += v[:, :, None] * v[:, None, :]
    return bad, rank, P


def where(scene, idx: np.ndarray) -> str:
    """Words for a set of particles: group, count, first particle and position, the box."""
    o = scene.original_positions()
    idx = np.asarray(idx)
    g, local = scene.group_of(int(idx[0]))
    p = np.round(o[idx[0]], 4).tolist()
    text = f"{len(idx)} particle(s) of '{g}' (particle {local} at {p}"
    if len(idx) > 1:
        lo, hi = np.round(o[idx].min(axis=0), 3).tolist(), np.round(o[idx].max(axis=0), 3).tolist()
        text += f"; within {lo} … {hi}"
    return text + ")"


def clusters(scene, idx: np.ndarray, I: np.ndarray, J: np.ndarray) -> list[np.ndarray]:
    """``idx`` split into the groups bound to each other, largest first."""
    if len(idx) == 0:
        return []
    n = scene.n_particles
    mark = np.zeros(n, bool)
    mark[idx] = True
    keep = mark[I] & mark[J]
    count, label = components(n, I[keep], J[keep])
    lab = label[idx]
    out = [idx[lab == c] for c in np.unique(lab)]
    return sorted(out, key=len, reverse=True)


def mechanism_particles(per: np.ndarray) -> np.ndarray:
    """The particles a loaded mechanism moves: those holding ≥ 1 % of the regularization's
    energy (``per``: each particle's share)."""
    return np.flatnonzero(per >= 0.01 * per.max()) if per.max() > 0 else np.zeros(0, int)
