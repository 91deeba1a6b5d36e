"""The rigid spheres of ``[[indenter]]`` (:class:`rackstress.model.operators.Indent`) in a
static analysis: a penalty whose particles in contact change with the positions.

Each sphere (centre c, radius R) pushes every particle its surface reaches radially out,
f_i = k_i·g_i·n̂_i, g_i = R + r_i − ‖p_i − c‖ > 0, n̂_i = (p_i − c)/‖p_i − c‖, with k_i = m_i
times the operator's stiffness per unit mass and r_i the particle's radius (half a spacing: a
particle of the top row sits half a spacing below the part's surface). Energy ½·k·g², tangent
per particle K_i = −∂f_i/∂p_i = k·n̂n̂ᵀ − k·g/r·(I − n̂n̂ᵀ) (the second: the push turning with n̂).

The static solver settles it by active sets, as the material contacts
(engines/static.py ``_update_contacts``): the particles in contact are held as two-sided
springs while Newton's method converges, then the set is taken anew at the state reached
until it no longer changes (4–7 Newton steps and 2–3 sets for Hertz's sphere on a block,
docs/calibration.md "Contact").
"""
from __future__ import annotations

import numpy as np

from rackstress.model.operators import Indent


def indents(scene):
    """(target, its slice, the ``Indent`` operator) of every ``[[indenter]]`` of ``scene``."""
    for target, seq in scene.operators.items():
        for op in seq:
            if isinstance(op, Indent):
                yield target, scene.slice(target), op


class Indenters:
    """Every ``Indent`` operator of a scene at its full travel, as global per-particle rows."""

    def __init__(self, scene):
        idx, k, c, R, r = [], [], [], [], []
        m, radii = scene.masses(), scene.radii()
        for _, sl, op in indents(scene):
            kk = np.asarray(op.k, float)
            sel = np.flatnonzero(kk > 0)
            idx.append(sel + sl.start)
            k.append(kk[sel] * m[sel + sl.start])
            c.append(np.repeat(op.centre_at(op.steps)[None, :], len(sel), axis=0))
            R.append(np.full(len(sel), float(op.radius)))
            r.append(radii[sel + sl.start])
        cat = (lambda x, shape: np.concatenate(x) if x else np.zeros(shape))
        self.idx = cat(idx, 0).astype(np.int64)
        self.k, self.centre = cat(k, 0), cat(c, (0, 3))
        self.reach = cat(R, 0) + cat(r, 0)
        self.n = scene.n_particles
        #: rows of ``idx`` held in contact (two-sided) while the solver holds a set; None: g > 0
        self.active: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.idx)

    def _geometry(self, p):
        d = p[self.idx] - self.centre
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        return d, r, self.reach - r

    def touching(self, p) -> np.ndarray:
        return self._geometry(p)[2] > 0

    def _mask(self, g):
        return self.active if self.active is not None else g > 0

    def force(self, p) -> np.ndarray:
        """n×3 force of the spheres on each particle (one-sided, or the held set's)."""
        d, r, g = self._geometry(p)
        m = self._mask(g)
        out = np.zeros((self.n, 3))
        np.add.at(out, self.idx[m], (self.k[m] * g[m] / r[m])[:, None] * d[m])
        return out

    def energy(self, p) -> float:
        _, _, g = self._geometry(p)
        m = self._mask(g)
        return float(0.5 * np.sum(self.k[m] * g[m] ** 2))

    def stiffness(self, p):
        """K = −∂f/∂p (3n × 3n CSR, block diagonal)."""
        import scipy.sparse as sp

        d, r, g = self._geometry(p)
        m = np.flatnonzero(self._mask(g))
        nn = d[m] / r[m, None]
        k, geo = self.k[m], self.k[m] * g[m] / r[m]
        B = (k + geo)[:, None, None] * nn[:, :, None] * nn[:, None, :] \
            - geo[:, None, None] * np.eye(3)[None]
        rows3 = np.arange(3)
        at = self.idx[m]
        rows = (3 * at[:, None, None] + rows3[None, :, None]).repeat(3, axis=2)
        cols = (3 * at[:, None, None] + rows3[None, None, :]).repeat(3, axis=1)
        return sp.csr_matrix((B.ravel(), (rows.ravel(), cols.ravel())),
                             shape=(3 * self.n, 3 * self.n))

    def update(self, p) -> bool:
        """The active set taken anew at ``p``; whether it changed."""
        new = self.touching(p)
        changed = self.active is None or not np.array_equal(new, self.active)
        self.active = new
        return changed

    def in_contact(self, p) -> int:
        """The particles the spheres push at ``p`` (one-sided)."""
        return int(np.count_nonzero(self.touching(p)))


def indenter_forces(scene, p: np.ndarray) -> list[dict]:
    """``summary.json``'s ``indenters``: per ``Indent`` operator (``[[indenter]]``) the total
    force the sphere applies on its part at ``p`` (scene units), its moment about the origin,
    the particles it pushes and its centre."""
    out = []
    m, radii = scene.masses(), scene.radii()
    for target, sl, op in indents(scene):
        c = op.centre_at(op.steps)
        a = Indent.accel(p[sl], radii[sl], np.asarray(op.k, float), c, op.radius)
        f = m[sl, None] * a
        out.append({"group": target, "centre": c.tolist(), "radius": float(op.radius),
                    "force": f.sum(axis=0).tolist(),
                    "moment": np.cross(p[sl], f).sum(axis=0).tolist(),
                    "particles": int(np.count_nonzero(np.any(a != 0, axis=1)))})
    return out
