"""Supports beyond held directions: rollers on any face, symmetry planes, bolts in holes.

A support that fixes whole axes (held, ``fix = ["z"]``) is a group's ``fixed`` mask: the
engines hold those directions (LAMMPS' ``fix setforce``). Three supports an engineer expects
fix no axis of the part's coordinates, and are constraints instead (a group's
``constraints``):

* :class:`Normals` — each listed particle keeps u·n = 0 for its normal n: a **roller** on a
  face not aligned with x, y or z, a **symmetry** plane, and a **cylindrical** support (a
  bolt that holds the bore radially and axially and lets it turn: two normals a particle,
  radial and axial);
* :class:`Ring` — the listed particles move as one rigid ring that only turns about an axis:
  a **pin** in a hole (the bore stays round and in place, free to rotate: a multi-point
  constraint, u_i = θ · a × (o_i − c)).

:func:`constraint_map` writes all of them, and the fixed axes, as one linear map from the
unknowns q to the displacements, u = T·q + u_p (u_p: the prescribed displacements). T's
columns are orthonormal (each particle's free directions; one column per ring, spread over its
particles), so P = T·Tᵀ projects a force onto what the supports let move: P·f is the
unbalanced force, f − P·f the supports' reaction. Where only axes are fixed, T selects the free
unknowns and the static solve is exactly the boolean mask it was.

Example
-------
>>> import numpy as np
>>> from rackstress.model.particles import Group
>>> g = Group("bar", np.array([[0., 0, 0], [1, 0, 0]]), 0.5)
>>> g.constraints.append(Normals(np.array([1]), np.array([[0.6, 0.8, 0.0]]), "roller"))
>>> cm = ConstraintMap.of_groups([g])
>>> cm.unknowns
5
>>> f = np.array([[0., 0, 0], [7, 1, 2]])      # 5 along the normal, (4, -3, 2) across it
>>> (cm.unbalanced(f).round(12) + 0.0).tolist()
[[0.0, 0.0, 0.0], [4.0, -3.0, 2.0]]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rackstress.errors import SceneError

#: a normal within this of an axis fixes that axis (the engines' fixed mask)
AXIS_TOL = 1e-9


@dataclass(frozen=True)
class Normals:
    """u·n = 0 for particle ``ids[k]`` along the unit normal ``normals[k]`` (group indices;
    a particle may appear with several normals). ``label`` names the support."""

    ids: np.ndarray
    normals: np.ndarray
    label: str = "support"
    #: a cylindrical support's axis (a point on it, its direction): the normals are radial
    #: about it and along it — kept so that another discretization of the part (the FE check's
    #: nodes) takes its own radial directions; None for a plane's normals
    cylinder: tuple | None = None

    def __post_init__(self):
        ids = np.asarray(self.ids, dtype=np.int64).reshape(-1)
        n = np.asarray(self.normals, dtype=float).reshape(-1, 3)
        if len(ids) != len(n):
            raise SceneError(f"{self.label}: {len(ids)} particles but {len(n)} normals")
        length = np.linalg.norm(n, axis=1)
        if np.any(~(length > 0)):
            raise SceneError(f"{self.label}: a normal of zero length")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "normals", n / length[:, None])


@dataclass(frozen=True)
class Ring:
    """The particles ``ids`` move as one rigid ring turning about the axis through ``point``
    along ``axis``: u_i = θ · â × (o_i − point) (a pin in a hole). ``label`` names it."""

    ids: np.ndarray
    point: np.ndarray
    axis: np.ndarray
    label: str = "pin"

    def __post_init__(self):
        a = np.asarray(self.axis, dtype=float).reshape(3)
        if not np.linalg.norm(a) > 0:
            raise SceneError(f"{self.label}: an axis of zero length")
        object.__setattr__(self, "ids", np.unique(np.asarray(self.ids, dtype=np.int64)))
        object.__setattr__(self, "point", np.asarray(self.point, dtype=float).reshape(3))
        object.__setattr__(self, "axis", a / np.linalg.norm(a))


def general(groups) -> list:
    """(group name, constraint) of every constraint of the ``groups`` (a dict or list)."""
    items = groups.items() if isinstance(groups, dict) else ((g.name, g) for g in groups)
    return [(name, c) for name, g in items for c in (getattr(g, "constraints", None) or [])]


def supported(scene) -> np.ndarray:
    """n booleans, global order: the particles a support holds in some way (a fixed axis or a
    constraint)."""
    out = scene.fixed().any(axis=1).copy()
    for name, c in general(scene.groups):
        out[scene.offset(name) + c.ids] = True
    return out


class ConstraintMap:
    """u = T·q + u_p over all particles (module doc); build with :meth:`of_scene`.

    ``T`` (3n × m, CSR) has orthonormal columns; ``free`` is the boolean mask of the unknowns
    when only axes are fixed (T then selects them: ``trivial``), else None.
    """

    def __init__(self, T, prescribed: np.ndarray, free: np.ndarray | None,
                 bases: dict | None = None, ring_particles: np.ndarray | None = None):
        self.T = T
        self.prescribed = prescribed
        self.free = free
        #: {global index: 3×k orthonormal free directions} of the particles a Normals holds
        self.bases = bases or {}
        #: global indices of the particles of pinned rings
        self.ring_particles = np.zeros(0, np.int64) if ring_particles is None else ring_particles

    @property
    def trivial(self) -> bool:
        return self.free is not None

    @property
    def unknowns(self) -> int:
        return self.T.shape[1]

    @classmethod
    def of_scene(cls, scene) -> "ConstraintMap":
        o = scene.original_positions()
        cm = cls.of_groups(list(scene.groups.values()), o)
        cm.prescribed = np.asarray(scene.prescribed(), dtype=float)
        return cm

    @classmethod
    def of_groups(cls, groups: list, o: np.ndarray | None = None) -> "ConstraintMap":
        import scipy.sparse as sp

        fixed = np.concatenate([g.fixed for g in groups])
        n = len(fixed)
        if o is None:
            o = np.concatenate([g.o for g in groups])
        starts = np.cumsum([0] + [g.n for g in groups])[:-1]
        normals: dict = {}
        rings = []
        for g, s in zip(groups, starts):
            for c in getattr(g, "constraints", None) or []:
                if isinstance(c, Normals):
                    for i, nv in zip(c.ids + s, c.normals):
                        normals.setdefault(int(i), []).append(nv)
                elif isinstance(c, Ring):
                    rings.append((c, c.ids + s))
                else:
                    raise SceneError(f"unknown constraint {c!r}")
        in_ring = np.zeros(n, dtype=bool)
        for c, ids in rings:
            clash = ids[in_ring[ids] | fixed[ids].any(axis=1)
                        | np.isin(ids, list(normals))]
            if len(clash):
                raise SceneError(f"{c.label}: {len(clash)} of its particles (global index "
                                 f"{int(clash[0])} first) are held by another support too; a "
                                 "pinned hole's ring moves only as one body: keep the other "
                                 "supports off its bore")
            in_ring[ids] = True
        free = ~fixed.reshape(-1)
        if not normals and not rings:
            return cls(sp.identity(3 * n, format="csr")[:, np.flatnonzero(free)].tocsr(),
                       np.zeros((n, 3)), free)
        rows, cols, vals = [], [], []
        col = 0
        general_p = np.zeros(n, dtype=bool)
        general_p[list(normals)] = True
        plain = ~general_p & ~in_ring
        # plain particles: their free axes, in dof order
        dof = np.flatnonzero((free.reshape(n, 3) & plain[:, None]).reshape(-1))
        rows.append(dof)
        cols.append(np.arange(len(dof)))
        vals.append(np.ones(len(dof)))
        col = len(dof)
        bases = {}
        for i, ns in sorted(normals.items()):
            held = [np.eye(3)[k] for k in range(3) if fixed[i, k]]
            basis = _complement(np.array(ns + held))
            bases[i] = basis.T.reshape(3, -1)
            for b in basis:
                rows.append(3 * i + np.arange(3))
                cols.append(np.full(3, col))
                vals.append(b)
                col += 1
        for c, ids in rings:
            t = np.cross(c.axis, o[ids] - c.point)
            norm = float(np.linalg.norm(t))
            if norm > 0:
                rows.append((3 * ids[:, None] + np.arange(3)).ravel())
                cols.append(np.full(3 * len(ids), col))
                vals.append((t / norm).ravel())
                col += 1
        T = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(3 * n, col))
        T.eliminate_zeros()
        return cls(T, np.zeros((n, 3)), None, bases, np.flatnonzero(in_ring))

    # ---------------------------------------------------------------- the map
    def expand(self, q: np.ndarray) -> np.ndarray:
        """T·q as n×3 displacements."""
        if self.trivial:
            out = np.zeros(len(self.free))
            out[self.free] = q
            return out.reshape(-1, 3)
        return np.asarray(self.T @ q).reshape(-1, 3)

    def restrict(self, f: np.ndarray) -> np.ndarray:
        """Tᵀ·f: the generalized forces on the unknowns (f: n×3)."""
        flat = np.asarray(f, dtype=float).reshape(-1)
        return flat[self.free] if self.trivial else np.asarray(self.T.T @ flat)

    def reduce(self, K):
        """Tᵀ·K·T (CSR): the stiffness on the unknowns."""
        if self.trivial:
            return K[self.free][:, self.free]
        return (self.T.T @ K @ self.T).tocsr()

    def unbalanced(self, f: np.ndarray) -> np.ndarray:
        """P·f (n×3): the part of the forces f the supports let move; f − P·f is their
        reaction."""
        f = np.asarray(f, dtype=float)
        if self.trivial:
            return np.where(self.free.reshape(f.shape), f, 0.0)
        return np.asarray(self.T @ (self.T.T @ f.reshape(-1))).reshape(f.shape)

    def modes(self, B: np.ndarray) -> np.ndarray:
        """Tᵀ·B: the columns of B (3n × k, e.g. rigid-body modes) on the unknowns."""
        return B[self.free] if self.trivial else np.asarray(self.T.T @ B)


def _complement(normals: np.ndarray) -> np.ndarray:
    """Orthonormal rows spanning the directions perpendicular to every row of ``normals``."""
    _, s, vt = np.linalg.svd(np.atleast_2d(normals), full_matrices=True)
    rank = int(np.sum(s > 1e-9 * max(float(s.max()), 1e-300)))
    return vt[rank:]


def axis_of(n: np.ndarray) -> int | None:
    """The axis (0, 1, 2) a unit normal lies along, or None."""
    n = np.asarray(n, dtype=float)
    k = int(np.argmax(np.abs(n)))
    return k if abs(abs(n[k]) - 1.0) <= AXIS_TOL and np.all(
        np.abs(np.delete(n, k)) <= AXIS_TOL) else None
