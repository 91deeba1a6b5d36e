"""Operators LAMMPS has no exact style for, evaluated in NumPy inside one ``fix external``.

Every term computes the paper's *directed* acceleration on the particles a rank owns, from
partners that are local or ghost atoms there, so it needs no reverse communication and stays
correct however the atoms are spread over ranks (the ghost cutoff covers every partner). The
same functions as the reference engine (:mod:`rackstress.reference`) do the arithmetic.

An exception inside a ctypes callback would be printed and ignored, so the callback catches it,
stores it and zeroes its forces; the runner checks ``error`` after every chunk and stops.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ._vec import bbox, inside, rowdot
from .deck import reverse_of
from .operators import (Attract, Bind, Collide, Const, Contact, Dampen, Force, attract_pairs,
                        bind_pairs, phase_active)
from .reference import col


class Frame:
    """What one callback invocation sees: local and ghost atoms, and tag → row look-ups."""

    def __init__(self, lmp, n_total: int, nlocal: int):
        nghost = lmp.extract_global("nghost")
        nall = nlocal + nghost
        self.nlocal, self.n_total = nlocal, n_total
        self.x = lmp.numpy.extract_atom("x")[:nall]
        self.v = lmp.numpy.extract_atom("v")[:nlocal]
        tag = lmp.numpy.extract_atom("id")[:nall]
        #: serial with unsorted atoms: row k holds particle k, so look-ups can be skipped
        self.identity = (nlocal == n_total and nall == n_total
                         and bool(np.array_equal(tag, np.arange(1, n_total + 1))))
        self.index = np.arange(n_total) if self.identity else tag.astype(np.int64) - 1
        self._row = self._local = None
        #: per-step results shared between terms (collision pairs of a pair of groups)
        self.cache = {}
        self.span_rows = None

    def use_span(self, span: int) -> int:
        """Accumulate only for owned particles with global index < ``span`` (the groups the
        Python operators act on); return how many rows the accumulator needs."""
        if self.identity:
            return span
        self.span_rows = np.flatnonzero(self.index[:self.nlocal] < span)
        self._compact = np.full(len(self.index), -1, dtype=np.int64)
        self._compact[self.span_rows] = np.arange(len(self.span_rows))
        return len(self.span_rows)

    def compact(self, rows: np.ndarray) -> np.ndarray:
        """Accumulator rows of frame rows (−1: a ghost or a particle outside the span)."""
        return rows if self.identity else self._compact[rows]

    @property
    def row(self) -> np.ndarray:
        """Global particle index → row here (−1 if not here); the owned copy wins over ghosts."""
        if self._row is None:
            self._row = np.full(self.n_total, -1, dtype=np.int64)
            nall = len(self.index)
            self._row[self.index[::-1]] = np.arange(nall)[::-1]
        return self._row

    @property
    def local(self) -> np.ndarray:
        """Global particle index → owned by this rank."""
        if self._local is None:
            self._local = np.zeros(self.n_total, dtype=bool)
            self._local[self.index[:self.nlocal]] = True
        return self._local

    def owned(self, sl: slice) -> np.ndarray:
        """Rows of the owned particles of a group (its global index slice)."""
        if self.identity:
            return np.arange(sl.start, sl.stop)
        own = self.index[:self.nlocal]
        return np.flatnonzero((own >= sl.start) & (own < sl.stop))

    def seen(self, sl: slice) -> np.ndarray:
        """Rows of the owned and ghost particles of a group."""
        if self.identity:
            return np.arange(sl.start, sl.stop)
        return np.flatnonzero((self.index >= sl.start) & (self.index < sl.stop))

    def rows(self, name, I, J):
        """Rows of the particles I and J here; raise if a partner is not visible on this rank."""
        if self.identity:
            return I, J
        ri, rj = self.row[I], self.row[J]
        if len(ri) and min(ri.min(), rj.min()) < 0:
            k = int(np.flatnonzero((ri < 0) | (rj < 0))[0])
            raise RuntimeError(f"{name}: particles {int(I[k])} and {int(J[k])} are not both "
                               "visible on this rank (raise the ghost cutoff)")
        return ri, rj


def _add_rows(fr, acc, rows, contrib):
    """acc[rows] += contrib for the rows owned here (ghost rows carry no force of ours)."""
    rows = fr.compact(rows)
    if not fr.identity:
        own = rows >= 0
        rows, contrib = rows[own], contrib[own]
    if not len(rows):
        return
    for k in range(3):
        acc[:, k] += np.bincount(rows, weights=contrib[:, k], minlength=len(acc))


class PairTerm:
    """Pair forces from a fixed (or per-phase) list of global pairs (bind Eq. 12, attract Eq. 14).

    Each pair (I, J) pushes ``cI``·g on I and, where the reverse operator exists with the same
    pairs (a bind and its partner: plane←rack 100 and rack←plane 0.5, or within(d) of a group
    with itself), −``cJ``·g on J, so the geometry g is computed once per unordered pair.
    """

    def __init__(self, name, I, J, cI, cJ=None, L0sq=None, block=None):
        self.name, self.I, self.J, self.cI, self.cJ, self.L0sq = name, I, J, cI, cJ, L0sq
        #: (target slice, source slice) when the pairs are every (i, j) of two groups in
        #: row-major order (a Const bind such as host ↔ rack): then a serial frame is served by
        #: broadcasting over the m×n block, with no gathers or scatters.
        self.block = block

    def _add_block(self, fr: Frame, acc: np.ndarray):
        ts, ss = self.block
        m, n = ts.stop - ts.start, ss.stop - ss.start
        diff = fr.x[ss][None, :, :] - fr.x[ts][:, None, :]          # (m, n, 3): u − p
        d2 = diff[:, :, 0] ** 2 + diff[:, :, 1] ** 2 + diff[:, :, 2] ** 2
        g = (1.0 - self.L0sq.reshape(m, n) / d2)[:, :, None] * diff  # Eq. 12 without c
        acc[ts] += np.einsum("ij,ijk->ik", self.cI.reshape(m, n), g)
        if self.cJ is not None:
            acc[ss] -= np.einsum("ij,ijk->jk", self.cJ.reshape(m, n), g)

    def add(self, fr: Frame, acc: np.ndarray):
        if self.block is not None and fr.identity:
            return self._add_block(fr, acc)
        I, J, cI, cJ, L0sq = self.I, self.J, self.cI, self.cJ, self.L0sq
        if not fr.identity:
            sel = fr.local[I] if cJ is None else (fr.local[I] | fr.local[J])
            I, J, cI = I[sel], J[sel], cI[sel]
            cJ = cJ[sel] if cJ is not None else None
            L0sq = L0sq[sel] if L0sq is not None else None
        ri, rj = fr.rows(self.name, I, J)
        diff = fr.x[rj] - fr.x[ri]
        d2 = rowdot(diff, diff)
        if L0sq is not None:
            g = (1.0 - L0sq / d2)[:, None] * diff        # Eq. 12 without its coefficient
        else:
            g = diff / np.sqrt(d2)[:, None]              # Eq. 14 without its coefficient
        _add_rows(fr, acc, ri, cI[:, None] * g)
        if cJ is not None:
            _add_rows(fr, acc, rj, -cJ[:, None] * g)


class CollideTerm:
    """One-way collide (Eq. 10): target atoms owned here against source atoms seen here."""

    def __init__(self, name, target_slice, source_slice, c, radius):
        self.name, self.t, self.s, self.c, self.radius = name, target_slice, source_slice, c, radius
        self.reach = float(radius[target_slice].max() + radius[source_slice].max())

    def pairs(self, fr: Frame):
        """Row pairs (a, b), a owned here in the target, b in the source, overlapping (d < R).

        In a serial frame the pairs of (target, source) are the transpose of those of
        (source, target), so the two directions of a one-way pair share one search a step.
        """
        if fr.identity:
            hit = fr.cache.get((self.s.start, self.t.start))
            if hit is not None:
                return hit[1], hit[0]
        idx_t, idx_s = fr.owned(self.t), fr.seen(self.s)
        if not len(idx_t) or not len(idx_s):
            return idx_t[:0], idx_s[:0]
        reach = self.reach
        # each side only where the other's bounding box (grown by the reach) is: a leg meets a
        # few hundred of the body's or the sediment's particles, not all of them
        xt = fr.x[self.t] if fr.identity else fr.x[idx_t]    # views when rows are particles
        xs = fr.x[self.s] if fr.identity else fr.x[idx_s]
        # the larger side is scanned once, against the smaller side's box
        for _ in range(2):
            if len(xs) >= len(xt):
                lo, hi = bbox(xt)
                near = inside(xs, lo - reach, hi + reach)
                idx_s, xs = idx_s[near], xs[near]
            else:
                lo, hi = bbox(xs)
                near = inside(xt, lo - reach, hi + reach)
                idx_t, xt = idx_t[near], xt[near]
            if not len(idx_s) or not len(idx_t):
                return idx_t[:0], idx_s[:0]
        sm = cKDTree(xt).sparse_distance_matrix(cKDTree(xs), reach, output_type="ndarray")
        a, b = idx_t[sm["i"]], idx_s[sm["j"]]
        keep = (fr.index[a] != fr.index[b]) & \
               (sm["v"] < self.radius[fr.index[a]] + self.radius[fr.index[b]])
        out = a[keep], b[keep]
        if fr.identity:
            fr.cache[(self.t.start, self.s.start)] = out
        return out

    def add(self, fr: Frame, acc: np.ndarray):
        a, b = self.pairs(fr)
        contrib = col(fr.x[a], fr.x[b], self.radius[fr.index[a]], self.radius[fr.index[b]], self.c)
        _add_rows(fr, acc, a, contrib)


class PyForces:
    """The ``fix external`` callback: the sum of all Python-realized operators active now."""

    def __init__(self, lmp, deck, comm=None):
        self.lmp, self.deck, self.scene, self.comm = lmp, deck, deck.scene, comm
        self.n = self.scene.n_particles
        self.radius = self.scene.radii()
        self.mass = np.concatenate([np.full(g.n, deck.masses[name])
                                    for name, g in self.scene.groups.items()])
        self.error = None
        self.terms = []    # (realized, term-or-None)
        self._attract = {}
        o = self.scene.original_positions()
        folded = {}
        for r in deck.python_ops:
            if isinstance(r.op, Bind):
                rev = reverse_of(r.op, r.target, self.scene)
                if (rev is not None and rev is not r.op and id(r.op) not in folded
                        and any(q.op is rev for q in deck.python_ops)):
                    folded[id(rev)] = r.op   # rev is carried by r.op's term
        for r in deck.python_ops:
            op, target = r.op, r.target
            sl = self.scene.slice(target)
            if isinstance(op, Bind):
                if id(op) in folded:          # carried by its reverse's term
                    self.terms.append((r, None))
                    continue
                i, j, c = bind_pairs(op, self.scene.groups[target], self.scene.groups[op.source])
                I, J = i + sl.start, j + self.scene.offset(op.source)
                cJ = None
                if op.source == target:       # within(d)/const of a group with itself: i<j once
                    keep = I < J
                    I, J, c = I[keep], J[keep], c[keep]
                    cJ = c
                elif any(v is op for v in folded.values()):
                    rev = reverse_of(op, target, self.scene)
                    cJ = np.full(len(I), float(rev.coeff.c))
                d = o[J] - o[I]
                block = None
                if isinstance(op.coeff, Const) and op.source != target:
                    block = (sl, self.scene.slice(op.source))
                self.terms.append((r, PairTerm(f"bind on {target}", I, J, c, cJ,
                                               rowdot(d, d), block)))
            elif isinstance(op, Collide):
                self.terms.append((r, CollideTerm(f"collide on {target}", sl,
                                                  self.scene.slice(op.source), float(op.coeff.c),
                                                  self.radius)))
            else:
                self.terms.append((r, None))
        self.phase = {}
        self.active = []
        # rows a Python operator can write: the target groups (a folded bind writes its
        # reverse's target, which is a Python operator's target too)
        self.span = max((self.scene.slice(r.target).stop for r in deck.python_ops), default=0)
        self._fresh = True

    # ------------------------------------------------------------------ phase
    def set_phase(self, phase_vars) -> bool:
        """Select the terms active in this phase; return whether any are."""
        self.phase = dict(phase_vars)
        self._fresh = True     # the fix (and its force array) may be new
        self.active = [(r, t) for r, t in self.terms
                       if isinstance(r.op, Dampen) or phase_active(r.op.when, self.phase)]
        return bool(self.active)

    def _attract_term(self, r):
        key = (id(r.op), tuple(sorted(self.phase.items())))
        if key not in self._attract:
            sc = self.scene
            i, j, c = attract_pairs(r.op, sc.groups[r.target], sc.groups[r.op.source], self.phase)
            self._attract[key] = PairTerm(f"attract on {r.target}", i + sc.offset(r.target),
                                          j + sc.offset(r.op.source), c)
        return self._attract[key]

    def _contact(self, fr: Frame, target: str, group: str) -> bool:
        term = CollideTerm("contact", self.scene.slice(target), self.scene.slice(group), 0.0,
                           self.radius)
        here = len(term.pairs(fr)[0]) > 0
        if self.comm is not None and self.comm.Get_size() > 1:
            from mpi4py import MPI

            here = self.comm.allreduce(here, op=MPI.LOR)
        return here

    def _holds(self, fr, r) -> bool:
        if not phase_active(r.op.when, self.phase):
            return False
        return all(self._contact(fr, r.target, c.group) for c in r.op.when
                   if isinstance(c, Contact))

    # ------------------------------------------------------------------ callback
    def __call__(self, caller, step, nlocal, tag, x, f):
        try:
            fr = Frame(self.lmp, self.n, nlocal)
            # serial: only the groups the Python operators act on get forces from here, the rest
            # (MagPod's 30,000 sediment particles) is never touched after one zeroing
            rows = fr.use_span(self.span)
            if fr.identity and self._fresh:
                f[:] = 0.0
                self._fresh = False
            acc = np.zeros((rows, 3))
            for r, term in self.active:
                op = r.op
                if isinstance(op, Dampen):       # only the contact-conditioned extra is here
                    if self._holds(fr, r):
                        sel = fr.owned(self.scene.slice(r.target))
                        acc[fr.compact(sel)] -= op.extra * fr.v[sel]
                elif isinstance(op, Force):
                    if self._holds(fr, r):
                        sl = self.scene.slice(r.target)
                        mask = np.zeros(self.n, dtype=bool)
                        mask[sl] = True if op.where is None else np.asarray(op.where, bool)
                        acc[mask[:rows] if fr.identity else mask[fr.index[fr.span_rows]]] += \
                            np.asarray(op.accel, float)
                elif not self._holds(fr, r):
                    continue
                elif isinstance(op, Attract):
                    self._attract_term(r).add(fr, acc)
                elif term is not None:
                    term.add(fr, acc)
            if fr.identity:
                f[:rows] = acc * self.mass[:rows, None]
            else:               # atoms migrate between ranks: every row is written every step
                f[:] = 0.0
                f[fr.span_rows] = acc * self.mass[fr.index[fr.span_rows], None]
        except Exception as exc:  # noqa: BLE001 - reported by the runner after the chunk
            if self.error is None:
                self.error = (step, exc)
            f[:] = 0.0
