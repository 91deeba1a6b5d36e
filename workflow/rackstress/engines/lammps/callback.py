"""Operators LAMMPS has no exact style for, evaluated in NumPy inside one ``fix external``.

Every term computes the paper's *directed* acceleration on the particles a rank owns, from
partners that are local or ghost atoms there, so it needs no reverse communication and stays
correct however the atoms are spread over ranks (the ghost cutoff covers every partner). The
arithmetic is each operator's own (:mod:`rackstress.model.operators`: ``factor``/``accel`` for
the formulas, ``pairs`` for the pair lists and L0², :func:`contact_candidates` and
``Collide.touching`` for the contact search), the same the reference engine uses.

Which term carries an operator is looked up in :data:`TERMS` by the operator's class; adding an
operator is one entry there (and one in the deck compiler's ``REALIZE``).

What depends only on which atom sits in which row (look-ups, each term's pairs, collision
candidates) is kept from one LAMMPS reneighbouring to the next (:class:`Frame`,
:class:`Overlaps`); each step then costs the arithmetic on the pairs and one scatter.

An exception inside a ctypes callback would be printed and ignored, so the callback catches it,
stores it, zeroes its forces and forces LAMMPS' timeout, which stops the run before the next
step; the runner then reports it. Under MPI the ranks agree on failure inside the callback at
fixed points (one reduction of the contact conditions and the failures so far, one of the
failures at the end), so every rank stops after the same step and none waits in a collective
another has left. A bind partner out of ghost reach raises :class:`PartnerLost`, naming the
particle: the runner reports it as a divergence.
"""
from __future__ import annotations

import operator

import numpy as np

from rackstress.lib.vec import fresh_zeros, rowdot
from rackstress.engines.watchdog import first_nonfinite
from rackstress.engines.lammps.deck import _global_int
from rackstress.model import kernels
from rackstress.model.kernels import choice as kernel_choice
from rackstress.model.kernels import compiled as compiled_kernels
from rackstress.model.kernels import warm as warm_kernels
from rackstress.model.operators import (Attract, Bind, Collide, Const, Dampen, Force, Indent,
                                        contact_candidates, contact_groups, phase_active,
                                        reverse_of)
from rackstress.model.volume import Volume


class PartnerLost(RuntimeError):
    """A term's partner is not visible on this rank: the particles flew apart (``index``: the
    global index of a particle of the pair)."""

    def __init__(self, message: str, index: int):
        super().__init__(message, index)
        self.message, self.index = message, int(index)

    def __str__(self):
        return self.message


class NonFiniteForce(PartnerLost):
    """A force on an integrated row is NaN or infinite (``index``: its global index)."""


class Frame:
    """What the callback sees: local and ghost atoms, tag → row look-ups, and per-layout memos.

    LAMMPS exchanges atoms between ranks, rebuilds ghosts and (with ``sort 0``) reorders nothing
    except when it reneighbours, so everything that depends only on which atom sits in which row
    (look-ups, owned rows of a group, each term's selected pairs, collision candidates) is kept
    from one reneighbouring to the next in ``memo``; positions and velocities are re-read every
    step (:meth:`refresh`).
    """

    def __init__(self, lmp, n_total: int, nlocal: int, dense_span: int, mass: np.ndarray,
                 span: int | None = None):
        nghost = lmp.extract_global("nghost")
        nall = nlocal + nghost
        self.nlocal, self.nghost, self.n_total = nlocal, nghost, n_total
        tag = lmp.numpy.extract_atom("id")[:nall]
        #: serial, and row k holds particle k for every k below ``span`` (all particles, or
        #: those before the passive groups, whose rows LAMMPS reorders as they become active:
        #: ``atom_modify first``), so look-ups can be skipped there
        span = n_total if span is None else span
        self.identity = (nlocal == n_total and nall == n_total and dense_span <= span
                         and bool(np.array_equal(tag[:span], np.arange(1, span + 1))))
        self.span = span if self.identity else 0
        #: LAMMPS' atom ids of the rows (the particle of row r is tag[r] − 1)
        self.tag = tag
        self._index = np.arange(n_total) if self.identity and span == n_total else None
        self._row = self._local = None
        #: per-layout results of the terms (selected pairs, candidates, owned rows)
        self.memo = {}
        # the dense accumulator: the owned particles below ``dense_span`` (the groups the bind,
        # attract, dampen and force terms act on); contributions to other owned rows (a
        # collide's target such as MagPod's sediment under a sole) are written sparsely
        if self.identity:
            self.dense_rows = slice(0, dense_span)
            self.acc_rows = dense_span
            self.dense_mass = mass[:dense_span, None]
        else:
            self.dense_rows = np.flatnonzero(self.index[:nlocal] < dense_span)
            self._compact = np.full(nall, -1, dtype=np.int64)
            self._compact[self.dense_rows] = np.arange(len(self.dense_rows))
            self.acc_rows = len(self.dense_rows)
            self.dense_mass = mass[self.index[self.dense_rows], None]
        self.refresh(lmp)

    def refresh(self, lmp=None) -> None:
        """Clear the per-step cache; with ``lmp``, (re)take LAMMPS' position and velocity
        arrays. Between two reneighbourings LAMMPS neither reallocates nor reorders them (atoms
        are exchanged, and arrays grown, only when it reneighbours), so the views taken when
        the frame was built see every step's values in place."""
        if lmp is not None:
            nall = self.nlocal + self.nghost
            self.x = lmp.numpy.extract_atom("x")[:nall]
            # ghosts too: a contact's friction reads its partner's velocity (the deck sends
            # ghost velocities then: comm_modify vel yes)
            self.v = lmp.numpy.extract_atom("v")[:nall]
            #: LAMMPS' force array: the callback adds its forces here itself (fix external's
            #: own add pass over every owned atom never runs: deck.PY_NAPPLY)
            self.f = lmp.numpy.extract_atom("f")[:self.nlocal]
        #: per-step results shared between terms (overlapping pairs of a pair of groups)
        self.cache = {}
        #: pair contributions (rows, values), summed into the accumulator once (:meth:`flush`)
        self.pending = []
        #: contributions to owned rows outside the dense accumulator: (frame rows, values)
        self.sparse = None

    def add(self, rows: np.ndarray, contrib: np.ndarray) -> None:
        """acc[rows] += contrib, deferred to :meth:`flush` (one scatter a step, not one a term)."""
        self.pending.append((rows, contrib))

    def flush(self, acc: np.ndarray) -> None:
        """Sum the pending contributions into ``acc``; contributions to owned rows outside it
        (a collide's sparse target) go to ``sparse``, those to ghost rows are dropped (the
        owning rank computes its own)."""
        if not self.pending:
            return
        rows = np.concatenate([r for r, _ in self.pending])
        contrib = np.concatenate([c for _, c in self.pending])
        self.pending = []
        ar = self.compact(rows)
        if self.identity:
            keep = ar < len(acc)
            beyond = ~keep
        else:
            keep = ar >= 0
            beyond = ~keep & (rows < self.nlocal)
        if beyond.any():
            self.sparse = (rows[beyond], contrib[beyond])
        if self.sparse is not None or not self.identity:
            ar, contrib = ar[keep], contrib[keep]
        for k in range(3):
            acc[:, k] += np.bincount(ar, weights=contrib[:, k], minlength=len(acc))

    @property
    def index(self) -> np.ndarray:
        """The particle (global index) of every row here (made when first needed: the serial
        path needs it only for a few rows, :meth:`particles`)."""
        if self._index is None:
            self._index = self.tag.astype(np.int64) - 1
        return self._index

    def particles(self, rows: np.ndarray) -> np.ndarray:
        """The particles (global indices) of some rows."""
        if self._index is not None:
            return self._index[rows]
        return self.tag[rows].astype(np.int64) - 1

    def compact(self, rows: np.ndarray) -> np.ndarray:
        """Accumulator rows of frame rows (−1: a ghost or a particle outside the dense rows)."""
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
        return self._rows("owned", sl, self.nlocal)

    def seen(self, sl: slice) -> np.ndarray:
        """Rows of the owned and ghost particles of a group."""
        return self._rows("seen", sl, None)

    def _rows(self, kind: str, sl: slice, upto) -> np.ndarray:
        """Rows among the first ``upto`` (all: None) whose particle lies in ``sl`` (memoized)."""
        key = (kind, sl.start, sl.stop)
        if key not in self.memo:
            if self.ident(sl) or (self.identity and sl.start == self.span
                                  and sl.stop == self.n_total):
                # the rows after span hold the particles after span (a permutation of them)
                self.memo[key] = np.arange(sl.start, sl.stop)
            else:
                idx = self.index[:upto]
                self.memo[key] = np.flatnonzero((idx >= sl.start) & (idx < sl.stop))
        return self.memo[key]

    def ident(self, sl: slice) -> bool:
        """Whether the rows of the particles in ``sl`` are their indices."""
        return sl.stop <= self.span

    def rows(self, name, I, J):
        """Rows of the particles I and J here; raise if a partner is not visible on this rank."""
        if self.identity and (not len(I) or max(I.max(), J.max()) < self.span):
            return I, J
        ri, rj = self.row[I], self.row[J]
        if len(ri) and min(ri.min(), rj.min()) < 0:
            k = int(np.flatnonzero((ri < 0) | (rj < 0))[0])
            raise PartnerLost(f"{name}: atom ids {int(I[k]) + 1} and {int(J[k]) + 1} are not "
                              "both visible on this rank", int(I[k]))
        return ri, rj


class PairTerm:
    """Pair forces from a fixed (or per-phase) list of global pairs (bind Eq. 12, attract Eq. 14).

    ``factor`` is the operator's formula (``Bind.factor``, ``Attract.factor``). Each pair
    (I, J) pushes ``cI``·g on I and, where the reverse operator exists with the same pairs (a
    bind and its partner: plane←rack 100 and rack←plane 0.5, or within(d) of a group with
    itself), −``cJ``·g on J, so the geometry g = factor(d², q)·(u − p) is computed once per
    unordered pair.
    """

    def __init__(self, name, factor, I, J, cI, cJ=None, q=None, block=None, compiled=None):
        self.name, self.factor = name, factor
        self.I, self.J, self.cI, self.cJ, self.q = I, J, cI, cJ, q
        #: the compiled kernels (:mod:`rackstress.model.kernels`), or None for NumPy
        self.k = compiled
        #: a block's original positions (target rows, source rows), where L0² comes from
        self.orig = None
        #: (target slice, source slice) when the pairs are every (i, j) of two groups in
        #: row-major order (a Const bind such as host ↔ rack): then it is evaluated by
        #: broadcasting over the block, with no per-pair gathers or scatters.
        self.block = block
        if block is not None:
            ts, ss = block
            m, n = ts.stop - ts.start, ss.stop - ss.start
            # source-major (n, m): the sums over a host's few racks run over rows (fast), the
            # sums over a rack's many hosts along contiguous rows (fast); see lib/vec.py
            self._qT = np.ascontiguousarray(q.reshape(m, n).T)
            self._cIT = _scalar_or(np.ascontiguousarray(cI.reshape(m, n).T))
            self._cJT = None if cJ is None else _scalar_or(
                np.ascontiguousarray(cJ.reshape(m, n).T))
            if compiled is not None:
                self._full = (np.ascontiguousarray(cI.reshape(m, n).T),
                              np.ascontiguousarray((cI if cJ is None else cJ).reshape(m, n).T))

    def _add_block(self, fr: Frame, acc: np.ndarray):
        ts, ss = self.block
        here = fr.ident(ts) and fr.ident(ss)
        if here and self.k is not None:     # rows are particles: one compiled pass
            cIT, cJT = self._full
            self.k.bind_block(fr.x, ts.start, ts.stop - ts.start, ss.start, ss.stop - ss.start,
                              self._qT, cIT, cJT, self._cJT is not None, acc)
            return
        if here:
            xt, xs = fr.x[ts], fr.x[ss]
        else:
            # under MPI every rank that owns a particle of either group evaluates the whole
            # block (both groups are in its ghost reach) and keeps its owned rows' sums
            place = self._placement(fr)
            if place is None:
                return
            rt, rs, ti, ct, si, cs = place
            xt, xs = fr.x[rt], fr.x[rs]
        d = [xs[:, k][:, None] - xt[:, k][None, :] for k in range(3)]   # (n, m): u − p
        w = self.factor(d[0] * d[0] + d[1] * d[1] + d[2] * d[2], self._qT)  # without c
        for k in range(3):
            g = w * d[k]
            if here:
                acc[ts, k] += (self._cIT * g).sum(axis=0)
                if self._cJT is not None:
                    acc[ss, k] -= (self._cJT * g).sum(axis=1)
                continue
            if len(ti):
                acc[ct, k] += (self._cIT * g).sum(axis=0)[ti]
            if self._cJT is not None and len(si):
                acc[cs, k] -= (self._cJT * g).sum(axis=1)[si]

    def _placement(self, fr: Frame):
        """Rows of every particle of the block's groups here, and which of them are owned."""
        key = ("block", id(self))
        if key not in fr.memo:
            ts, ss = self.block
            rt, rs = fr.row[ts], fr.row[ss]
            t_own = (rt >= 0) & (rt < fr.nlocal)
            s_own = ((rs >= 0) & (rs < fr.nlocal) if self._cJT is not None
                     else np.zeros(len(rs), dtype=bool))
            if not (t_own.any() or s_own.any()):
                fr.memo[key] = None
            else:
                missing = np.flatnonzero(np.concatenate([rt, rs]) < 0)
                if len(missing):
                    k = int(missing[0])
                    k = ts.start + k if k < len(rt) else ss.start + k - len(rt)
                    raise PartnerLost(f"{self.name}: atom id {k + 1} is not visible on a rank "
                                      "that owns part of its block", k)
                ti, si = np.flatnonzero(t_own), np.flatnonzero(s_own)
                fr.memo[key] = (rt, rs, ti, fr.compact(rt[ti]), si, fr.compact(rs[si]))
        return fr.memo[key]

    def _selected(self, fr: Frame):
        """The pairs with a particle owned here, as rows (memoized until the next reneighbouring)."""
        key = ("pairs", id(self))
        hit = fr.memo.get(key)
        if hit is None:
            I, J, cI, cJ, q = self.I, self.J, self.cI, self.cJ, self.q
            if not fr.identity:
                sel = fr.local[I] if cJ is None else (fr.local[I] | fr.local[J])
                I, J, cI = I[sel], J[sel], cI[sel]
                cJ = cJ[sel] if cJ is not None else None
                q = q[sel] if q is not None else None
            ri, rj = fr.rows(self.name, I, J)
            if self.k is not None:   # the compiled loop adds into accumulator rows directly
                hit = (ri, rj, fr.compact(ri), fr.compact(rj), cI,
                       cI if cJ is None else cJ, q)
            else:
                hit = (ri, rj, cI[:, None], None if cJ is None else -cJ[:, None], q)
            fr.memo[key] = hit
        return hit

    def add(self, fr: Frame, acc: np.ndarray):
        if self.block is not None:
            return self._add_block(fr, acc)
        if self.k is not None:
            ri, rj, ai, aj, cI, cJ, q = self._selected(fr)
            if q is None:
                self.k.attract_pairs(fr.x, ri, rj, ai, cI, acc)
            else:
                self.k.bind_pairs(fr.x, ri, rj, ai, aj, cI, cJ, q, self.cJ is not None, acc)
            return
        ri, rj, cI, mcJ, q = self._selected(fr)
        diff = fr.x[rj] - fr.x[ri]
        g = self.factor(rowdot(diff, diff), q)[:, None] * diff   # the formula without its c
        fr.add(ri, cI * g)
        if mcJ is not None:
            fr.add(rj, mcJ * g)


def _scalar_or(a: np.ndarray):
    """A constant array as its one value (one multiply per block instead of one per pair)."""
    return float(a.flat[0]) if a.size and np.all(a == a.flat[0]) else a


class Overlaps:
    """Overlapping pairs (d < r_i + r_j, Eq. 10's support) of two groups, every step.

    A Verlet list: candidates within reach + skin are found (:func:`contact_candidates`) only
    when LAMMPS reneighbours, which it does as soon as any atom has moved more than half the
    skin since the last time (``neigh_modify every 1 delay 0 check yes``, the deck's skin). A
    pair that was farther apart than reach + skin then cannot have come within reach, so each
    step only measures the candidates (``Collide.touching``). Shared by the collide terms of
    both directions and by the contact conditions (Eq. 28's damping) of the same two groups.
    Where LAMMPS' skin is wider than the lists' (a deck with passive groups, serial), the lists
    keep their own skin (``own``; :meth:`list_skin`) and each is searched again once one of its
    own particles has moved half of it (:meth:`renew`, once a step): a particle in no list
    never renews one, and two groups walking together keep theirs.

    Resting particles of a passive group are activated (``activate``) one LAMMPS
    reneighbouring before anything can touch them: every list against a passive group is
    searched at each LAMMPS layout's first step (``PyForces._search_lists``) with reach + two of
    LAMMPS' skins S. A resting particle not activated there was farther than that from every
    searching particle; LAMMPS reneighbours before any atom has moved S/2, so at the next
    layout's first search it is still more than reach + 3S/2 away (the searching particles
    moved less than S/2; it did not move) and is activated there if within reach + 2S; then it
    stays more than reach + S away until that layout ends (less than S/2 more), when LAMMPS'
    reordering (``atom_modify first``) puts it among the integrated rows. Renewals in between
    search within reach + the list's skin only.
    """

    def __init__(self, radius: np.ndarray, skin: float, compiled=None, activate=None,
                 passive=None, bed=None, own=None):
        self.radius, self.skin, self.k = radius, skin, compiled
        #: serial, when LAMMPS' skin (``skin``) is wider: the callback's own skin, each list
        #: searched again once one of its own particles has moved half of it (renew)
        self.own = own
        #: the resting particles of the passive groups in cell grids of their original
        #: positions round each searching group (serial, compiled): a search against a
        #: passive group looks only near the searching group
        self.bed = bed
        #: which particles belong to passive groups (activated when first within reach)
        self.passive = np.zeros(len(radius), dtype=bool) if passive is None else passive
        #: called with the candidate rows of every new list (a resting particle that may be
        #: touched before the next reneighbouring must be integrated from now on)
        self.activate = activate
        self._rmax = {}
        #: serial lists between groups whose rows are their particles, with the positions they
        #: were searched at: kept while no atom of the two groups has moved half a skin
        self._kept = {}
        #: the lists the callback renews itself (``own``): list key → (list, positions its
        #: watched rows were searched at, those rows, relative test?, its layout's frame or
        #: None, (h/2)²), see :meth:`renew`
        self._lists = {}
        self._packed = None
        #: the lists' skins where the callback renews them (None: ``own``), see list_skin
        self.bed_skin = self.moving_skin = None
        #: LAMMPS integrates only its first ``nfirst`` rows (PyForces keeps this up to date)
        self.nfirst = len(radius)

    def _reach(self, sl: slice) -> float:
        key = (sl.start, sl.stop)
        if key not in self._rmax:
            self._rmax[key] = float(self.radius[sl].max()) if sl.stop > sl.start else 0.0
        return self._rmax[key]

    def _candidates(self, fr: Frame, A: slice, B: slice):
        """Rows (a in A, b in B, both owned or ghost) within reach + skin, with R² per pair."""
        key = ("cand", A.start, B.start)
        hit = fr.memo.get(key)
        if hit is not None:
            return hit
        mine = self.own is not None and fr.identity
        # the lists' skin: LAMMPS' (its reneighbouring renews them), or in serial the
        # callback's own where LAMMPS' is wider (each list renewed by its own displacement
        # check, :meth:`renew`)
        h = self.list_skin(A, B) if mine else self.skin
        reach = self._reach(A) + self._reach(B)
        cut = reach + h
        # resting particles join the moving group one LAMMPS reneighbouring early (a partner
        # within reach + 2 of LAMMPS' skins), so LAMMPS has put them among the integrated rows
        # (atom_modify first) before anything can touch them; the contact candidates are
        # those within cut
        # (once a layout: a renewal in between need not; every list against a passive group
        # is searched at a layout's first step, _search_lists, and dropped at the next layout)
        passive = self.activate is not None and self._passive(A, B)
        wide = cut
        if passive and ("act", A.start, B.start) not in fr.memo:
            wide = reach + 2 * self.skin
            fr.memo[("act", A.start, B.start)] = True
        stable = (not mine and self.k is not None and wide == cut and fr.ident(A)
                  and fr.ident(B))
        if stable:
            # (LAMMPS' skin renews the lists) a list of two groups whose rows are their
            # particles is searched with two skins of margin (reach + 2 skins) and kept at a
            # later reneighbouring while none of *their* atoms has moved half a skin since the
            # search, once the translation common to both groups is taken off
            # (kernels.moved_below_shifted: a body and its legs walk together): until the
            # next reneighbouring each atom then stays within one skin of where it was
            # searched plus that translation (LAMMPS reneighbours once any atom has moved half
            # a skin), so a pair can have closed by less than two skins and none outside the
            # list can be within reach
            kept = self._kept.get((A.start, B.start))
            if kept is not None and self.k.moved_below_shifted(
                    fr.x, A.start, A.stop - A.start, B.start, B.stop - B.start, kept[0],
                    0.25 * h * h):
                hit = fr.memo[key] = kept[1]
                return hit
            cut = wide = cut + h
        if (self.bed is not None and passive and fr.identity and fr.ident(A)
                and B.start >= fr.span):
            # a group whose rows are its particles against a passive group: the resting
            # particles from the bed's grid, the activated ones from a cell list of their own
            ia = fr.seen(A)
            a, b, near_a, near_b = self.bed.candidates(fr, ia, B, cut, wide, A)
        elif self.k is not None:      # a compiled cell list
            ia, ib = fr.seen(A), fr.seen(B)
            a, b, near_a, near_b = self.k.candidates(fr.x, ia, ib, cut, A == B, fr.tag, wide)
        else:
            ia, ib = fr.seen(A), fr.seen(B)
            a, b = contact_candidates(fr.x[ia], fr.x[ib], wide, same=A == B)
            a, b = ia[a], ib[b]
            order = np.lexsort((fr.index[b], fr.index[a]))
            a, b = a[order], b[order]
            near_a, near_b = a, b
            if wide > cut:
                diff = fr.x[b] - fr.x[a]
                near = rowdot(diff, diff) <= cut * cut
                a, b = a[near], b[near]
        if passive:             # (only passive particles are activated: skip a side without)
            if self._any_passive(A):
                self.activate(fr, near_a)
            if self._any_passive(B):
                self.activate(fr, near_b)
        R2 = (self.radius[fr.particles(a)] + self.radius[fr.particles(b)]) ** 2
        hit = fr.memo[key] = (a, b, R2)
        if stable:
            self._kept[(A.start, B.start)] = (np.concatenate([fr.x[A], fr.x[B]]), hit)
        if mine:
            self._remember(fr, key, A, B, hit, h)
        return hit

    def list_skin(self, A: slice, B: slice) -> float:
        """The skin of the list of groups A and B when the callback renews it itself: a list
        against a passive group (the bed under a sole) ``bed_skin``, else ``moving_skin``
        (both the deck's ``skin`` unless set)."""
        if self._passive(A, B):
            return self.own if self.bed_skin is None else self.bed_skin
        return self.own if self.moving_skin is None else self.moving_skin

    def _watched(self, fr: Frame, A: slice, B: slice, h: float) -> np.ndarray:
        """The rows whose motion can bring a pair of A and B into reach unseen by their list
        (searched now with skin ``h``): a group whose rows are its particles, its rows; a
        passive group, its activated particles, at the rows LAMMPS integrates after
        ``fr.span`` (the resting ones, at rows LAMMPS does not integrate, stay where they
        are until it reorders, which makes a new layout and a new search) — and of those only
        the ones inside the searching group's bounding box grown by reach + h + LAMMPS' skin.
        The list lives only as long as the layout, in which no integrated atom moves more
        than half LAMMPS' skin from where it was at the layout's start (LAMMPS reneighbours
        first), so any two of its positions are less than a skin apart: a particle farther
        than reach + h/2 + a skin from every searching particle now, while those move less
        than h/2, stays out of reach until the list is dropped."""
        # a passive group's rows come after span, the others' before (a list between two
        # passive groups, or with span 0, has both sides in the same rows: watched twice,
        # which only costs)
        parts = []
        for G in ((A,) if A == B else (A, B)):
            if fr.ident(G):
                parts.append(np.arange(G.start, G.stop, dtype=np.int64))
                continue
            stop = max(fr.span, min(self.nfirst, fr.nlocal))
            rows = np.arange(fr.span, stop, dtype=np.int64)
            other = B if G is A else A
            if fr.ident(other) and other != G and len(rows):
                lo, hi = self.k.bbox_rows(fr.x, fr.seen(other)) if self.k is not None else (
                    fr.x[other].min(axis=0), fr.x[other].max(axis=0))
                g = self._reach(A) + self._reach(B) + h + self.skin + 1.0
                xr = fr.x[fr.span:stop]
                rows = rows[((xr >= lo - g) & (xr <= hi + g)).all(axis=1)]
            parts.append(rows)
        return np.concatenate(parts)

    def _remember(self, fr: Frame, key, A: slice, B: slice, hit, h: float) -> None:
        """Keep a list the callback renews itself, with where its particles were searched.

        A list of two groups whose rows are their particles (a body and a leg) is kept across
        LAMMPS' reneighbourings (its rows do not change) and judged by the two groups'
        motion relative to each other (``shifted``); a list against a passive group holds
        rows LAMMPS reorders, so it lives as long as the layout, and the resting particles in
        it do not move, so its particles' own displacement is measured."""
        rows = self._watched(fr, A, B, h)
        shifted = fr.ident(A) and fr.ident(B)
        # h/2 less a margin far above rounding (1e-6 relative), as the step's near sets
        lim2 = (0.5 * h * (1.0 - 1e-6)) ** 2
        self._lists[key] = (hit, np.array(fr.x[rows]), rows, shifted, None if shifted else fr,
                            lim2)
        self._packed = None

    def renew(self, fr: Frame) -> None:
        """Drop from ``fr.memo`` every list the callback renews itself that may now miss a
        pair within reach (the next use searches it again); put back, in a new layout's
        frame, those still good from an earlier one. Once a step, before any list is used.

        A list's particles (:meth:`_watched`) that were not in it were farther apart than
        reach + h when it was searched; while each has moved at most h/2 since (for two
        moving groups once the translation common to them is taken off: distances then
        change by at most twice the bound, see :func:`kernels.moved_below_shifted`), no pair
        outside it has closed in by h, so it holds every pair within reach. Only the list's
        own particles count: a particle in no list (a rack) never renews one, and a list
        whose groups stand still relative to each other is kept however far they travel."""
        if not self._lists:
            return
        stale = [key for key, st in self._lists.items()
                 if st[4] is not None and st[4] is not fr]
        for key in stale:       # lists of rows from another layout
            del self._lists[key]
            self._packed = None
        if not self._lists:
            return
        if self._packed is None:
            keys = list(self._lists)
            sts = [self._lists[key] for key in keys]
            self._packed = (keys, np.concatenate([st[2] for st in sts]),
                            np.cumsum([0] + [len(st[2]) for st in sts]).astype(np.int64),
                            np.ascontiguousarray(np.concatenate([st[1] for st in sts])),
                            np.array([st[3] for st in sts], np.bool_),
                            np.zeros((len(keys), 3)),
                            np.array([st[5] for st in sts]),
                            np.zeros(len(keys), np.bool_))
        keys, rows, roff, ref, shifted, shift, lim2, moved = self._packed
        if self.k is not None:
            self.k.lists_moved(fr.x, rows, roff, ref, shifted, shift, lim2, moved)
        else:
            for L in range(len(keys)):
                d = fr.x[rows[roff[L]:roff[L + 1]]] - ref[roff[L]:roff[L + 1]]
                if shifted[L] and len(d):
                    d = d - 0.5 * (d.min(axis=0) + d.max(axis=0))
                moved[L] = len(d) and not rowdot(d, d).max() <= lim2[L]
        for L, key in enumerate(keys):
            if moved[L]:
                del self._lists[key]
                fr.memo.pop(key, None)
                self._packed = None
            else:
                fr.memo[key] = self._lists[key][0]

    def _any_passive(self, A: slice) -> bool:
        key = ("any passive", A.start, A.stop)
        if key not in self._rmax:
            self._rmax[key] = bool(self.passive[A].any())
        return self._rmax[key]

    def _passive(self, A: slice, B: slice) -> bool:
        key = ("passive", A.start, B.start)
        if key not in self._rmax:
            self._rmax[key] = bool(self.passive[A].any() or self.passive[B].any())
        return self._rmax[key]

    def pairs(self, fr: Frame, t: slice, s: slice, name: str = "collide"):
        """Row pairs (a, b) overlapping now, a owned here in ``t``, b seen here in ``s``, with
        their R²."""
        key = (t.start, s.start)
        hit = fr.cache.get(key)
        if hit is not None:
            return hit
        A, B = (s, t) if t.start > s.start else (t, s)
        a, b, R2 = self._candidates(fr, A, B)
        if self.k is not None:
            a, b, R2, k = self.k.overlapping(fr.x, a, b, R2)
        else:
            diff = fr.x[b] - fr.x[a]
            d2 = rowdot(diff, diff)
            on = Collide.touching(d2, R2)
            a, b, d2, R2 = a[on], b[on], d2[on], R2[on]
            k = int(np.flatnonzero(d2 == 0.0)[0]) if len(d2) and not d2.all() else -1
        if k >= 0:
            raise PartnerLost(f"{name}: atom ids {int(fr.index[a[k]]) + 1} and "
                              f"{int(fr.index[b[k]]) + 1} coincide (Eq. 10 is undefined at d = 0)",
                              int(fr.index[a[k]]))
        both = {(A.start, B.start): (a, b, R2)}
        if A != B:              # the other direction of the same pairs
            both[(B.start, A.start)] = (b, a, R2)
        for k2, (u, w, r2) in both.items():
            if not fr.identity:
                own = u < fr.nlocal
                u, w, r2 = u[own], w[own], r2[own]
            fr.cache[k2] = (u, w, r2)
        return fr.cache[key]


class RestingBed:
    """Where the resting particles of the passive groups are, for the contact search (serial).

    A resting particle never moves until it is activated (Eq. 5 leaves a particle with zero
    velocity and force where it is), so a passive group's particles go into a cell grid of
    their original positions (where LAMMPS holds every resting one), built round each
    searching group within the bed's own box and again when a search would reach beyond it;
    a search against the group then visits only the cells near the searching particles and
    skips the activated ones, which are searched apart in a cell list of their own (they are
    few). The pairs found, and their order (by the particles), are those of a search over
    every particle of the group; the two are merged in compiled code
    (:func:`kernels.bed_join`).

    LAMMPS reorders the passive rows when it reneighbours (``atom_modify first``), so the row
    of each passive particle is kept in ``prow``, brought up to date at each new layout from
    the only rows a reordering changes: those it moved the activated particles to (from the
    old ``nfirst`` to the new) and those they came from. Every row taken from it is checked
    against LAMMPS' atom id; a mismatch rebuilds it from scratch. It starts as the order
    LAMMPS reads the particles in (row p holds particle p), which holds at a fresh run's
    first search; after a resumed run's reordering the first check rebuilds it.
    """

    def __init__(self, n: int, span: int, compiled, origin: np.ndarray):
        self.n, self.span, self.k = n, span, compiled
        #: every particle's original position (the scene's, read-only)
        self.origin = origin
        #: row of every passive particle (index − span), or None until first needed
        self.prow = None
        #: activated particles (global index), and their rows when activated
        self.active = np.zeros(n, dtype=np.bool_)
        self._act = []
        self._pending = []
        self._nfirst = 0
        #: (group start, stop, searching group's start) → (lo, cell size, cells per axis,
        #: cell starts, order, hi)
        self._grids = {}
        #: (group start, stop) → the group's own box (lo, hi) of original positions
        self._boxes = {}
        #: a False flag per row (scratch of kernels.bed_join)
        self._flag = np.zeros(0, dtype=np.bool_)

    def activated(self, fr: Frame, rows: np.ndarray) -> None:
        """Rows of passive particles just added to the moving group."""
        parts = fr.particles(rows)
        self.active[parts] = True
        self._act.append(parts)
        self._pending.append(rows)

    def relayout(self, fr: Frame, nfirst: int) -> None:
        """A new layout (LAMMPS may have reordered): update the rows a reordering changes."""
        if self.prow is not None and fr.identity:
            rows = np.concatenate(self._pending + [np.arange(min(self._nfirst, nfirst), nfirst)])
            rows = rows[(rows >= self.span) & (rows < fr.nlocal)]
            self.prow[fr.tag[rows].astype(np.int64) - 1 - self.span] = rows
        self._pending, self._nfirst = [], nfirst

    def _rebuild(self, fr: Frame) -> None:
        """``prow`` read from this layout (the rows activated in it stay pending: LAMMPS'
        next reordering moves other particles there)."""
        if self.prow is None:
            self.prow = fresh_zeros(self.n - self.span, np.int64)
        self.k.passive_rows(fr.tag, self.span, fr.nlocal, self.prow)

    def _grid(self, fr: Frame, B: slice, ia: np.ndarray, wide: float, A: slice | None):
        """The grid of group B's particles at their original positions, where every resting
        one still is (Eq. 5 leaves a particle with zero velocity and force where it is;
        LAMMPS holds them bit for bit as read, which the passive decks' gathered positions
        rely on too), built from the scene's contiguous array, not from LAMMPS' rows.

        It holds the particles inside a box: round the searching rows ``ia`` grown by
        ``wide`` and twice the first search's reach (its cell size) beyond, and is built
        again, round the rows then, when a search would reach beyond it (every particle
        within ``wide`` of a searching row must be in it): a million-particle bed is not
        sorted into cells for the few thousand under the soles. One grid per searching
        group A (a sole walks, the other stands)."""
        key = (B.start, B.stop, None if A is None else A.start)
        g = self._grids.get(key)
        bkey = (B.start, B.stop)
        if bkey not in self._boxes:     # the bed's own box: no particle of B lies outside it
            self._boxes[bkey] = self.k.bbox_points(self.origin[B])
        blo, bhi = self._boxes[bkey]
        qlo, qhi = self.k.bbox_rows(fr.x, ia)
        if not (np.isfinite(qlo).all() and np.isfinite(qhi).all()):
            qlo, qhi = blo, bhi                                  # (no searching rows)
        # what a search must see: the searching rows' box grown by wide, within the bed's box
        # (a particle flying off — a diverging run — then does not stretch the grid beyond
        # the bed: the grid stays as large as the bed at most)
        nlo, nhi = np.maximum(qlo - wide - 1.0, blo), np.minimum(qhi + wide + 1.0, bhi)
        if g is not None and ((nlo > nhi).any() or ((nlo >= g[0]).all()
                                                    and (nhi <= g[5]).all())):
            return g
        size = wide if g is None else g[1]
        lo = np.maximum(qlo - (wide + 2.0 * size + 1.0), blo - 1.0)
        hi = np.minimum(qhi + (wide + 2.0 * size + 1.0), bhi + 1.0)
        hi = np.maximum(hi, lo)         # far from the bed on an axis: a slab holding no one
        nc = (np.floor((hi - lo) / size).astype(np.int64) + 1)
        start, order = self.k.grid_build(self.origin[B], lo, hi, size, nc)
        g = self._grids[key] = (lo, size, nc, start, order, hi)
        return g

    def candidates(self, fr: Frame, ia: np.ndarray, B: slice, cut: float, wide: float,
                   A: slice | None = None):
        """As :func:`kernels.candidates` of ``ia`` against every particle of passive group
        ``B`` (rows, sorted by particles; near rows of both sides); ``A``: the searching
        group (each has a grid of its own)."""
        for attempt in (0, 1):
            if self.prow is None:
                # LAMMPS reads the particles in order: row p holds particle p until it
                # reorders, and relayout follows every reordering from the first frame on;
                # each row used is checked against LAMMPS' atom id (a miss rebuilds it)
                self.prow = fresh_zeros(self.n - self.span, np.int64)
                self.k.count_from(self.prow, self.span)
            elif attempt:
                self._rebuild(fr)
            lo, size, nc, start, order = self._grid(fr, B, ia, wide, A)[:5]
            sa, sb, snear_a, snear_b, bad = self.k.grid_candidates(
                fr.x, ia, cut, wide, lo, size, nc, start, order, self.active, B.start,
                self.prow, self.span, fr.tag, fr.nlocal)
            if not bad:
                break
        else:
            raise RuntimeError("the rows of the resting particles could not be found")
        act = np.concatenate(self._act) if self._act else np.zeros(0, dtype=np.int64)
        if len(self._act) > 1:
            self._act = [act]
        act = act[(act >= B.start) & (act < B.stop)]
        rows = self.prow[act - self.span]
        if len(rows) and (rows.min() < 0 or not np.array_equal(
                fr.tag[rows].astype(np.int64) - 1, act)):
            self._rebuild(fr)
            rows = self.prow[act - self.span]
        # the activated particles are integrated already (and ia's rows are not passive), so
        # their near rows are only the pairs' own: searched within cut, not wide (which is
        # reach + 2 of LAMMPS' skins at a layout's first search, 18 units in MagPod)
        da, db, dnear_a, dnear_b = self.k.candidates(fr.x, ia, rows, cut, False, fr.tag, cut)
        # merged in particle order, the near rows once each (kernels.bed_join)
        if len(self._flag) < fr.nlocal:
            self._flag = np.zeros(fr.nlocal, dtype=np.bool_)
        return self.k.bed_join(ia, sa, sb, snear_a, snear_b, da, db, dnear_a, dnear_b, fr.tag,
                               self._flag)


# ----------------------------------------------------------------------------- terms
class Term:
    """One Python-realized operator: ``add(fr, acc)`` adds its accelerations when it holds.

    ``gated``: the operator is evaluated only in phases where its phase conditions hold (all
    but the contact-conditioned damping extra, whose conditions gate only the extra).
    """

    gated = True

    def __init__(self, forces: "PyForces", r):
        self.forces, self.r, self.op, self.target = forces, r, r.op, r.target
        self.sl = forces.scene.slice(r.target)
        #: the groups its contact conditions name, and whether its phase conditions hold now
        self.contacts = contact_groups(r.op.when)
        self.phase_ok = False
        #: the last row written by other than a collide (see Frame's dense accumulator)
        self.dense_stop = self.sl.stop

    def add(self, fr: Frame, acc: np.ndarray) -> None:
        raise NotImplementedError


class ForceTerm(Term):
    """A force (Eq. 8) conditioned on a contact: fix addforce cannot test the contact."""

    def add(self, fr, acc):
        if self.forces.holds(fr, self):
            acc[self._rows(fr)] += self.op.vector()

    def _rows(self, fr: Frame) -> np.ndarray:
        """Accumulator rows of the selected particles (memoized per layout)."""
        key = ("force", id(self))
        if key not in fr.memo:
            mask = np.zeros(self.forces.n, dtype=bool)
            mask[self.sl] = self.op.mask(self.sl.stop - self.sl.start)
            fr.memo[key] = (np.flatnonzero(mask[:fr.acc_rows]) if fr.identity
                            else np.flatnonzero(mask[fr.index[fr.dense_rows]]))
        return fr.memo[key]


class DampenTerm(Term):
    """The contact-conditioned extra of a dampen (Eq. 28); its base c is a fix viscous."""

    gated = False

    def add(self, fr, acc):
        if self.forces.holds(fr, self):
            sel = fr.owned(self.sl)
            if self.forces.compiled is not None:
                self.forces.compiled.dampen(fr.v, sel, fr.compact(sel), self.op.extra, acc)
            else:
                acc[fr.compact(sel)] += Dampen.accel(fr.v[sel], self.op.extra)


class CollideTerm(Term):
    """One-way collide (Eq. 10): target atoms owned here against source atoms seen here."""

    def __init__(self, forces, r):
        super().__init__(forces, r)
        self.s = forces.scene.slice(r.op.source)
        self.c = float(r.op.coeff.c)
        #: Coulomb friction (Collide.friction): μ and η, or μ = 0
        self.mu, self.eta = float(r.op.mu), float(r.op.eta)
        self.dense_stop = 0     # writes its (few) target rows sparsely

    def add(self, fr, acc):
        if not self.forces.holds(fr, self):
            return
        a, b, R2 = self.forces.overlaps.pairs(fr, self.sl, self.s, f"collide on {self.target}")
        if not len(a):
            return
        F, k = self.forces, self.forces.compiled
        if self.mu > 0:         # Eq. 10 and the pair's friction, one row per pair
            if k is not None:
                fr.add(a, k.collide_friction(fr.x, fr.v, a, b, R2, self.c, self.mu, self.eta))
            else:
                c = np.full(len(a), self.c)
                fr.add(a, Collide.accel(fr.x[a], fr.x[b], c, R2)
                       + Collide.friction(fr.x[a], fr.x[b], fr.v[a], fr.v[b], c, R2, self.mu,
                                          self.eta))
            return
        if k is not None and fr.identity:   # straight into the accumulators
            k.collide_add(fr.x, a, b, R2, self.c, acc, fr.acc_rows, F.sacc, F.sflag,
                          F.stouched, F.snt)
            return
        fr.add(a, k.collide(fr.x, a, b, R2, self.c) if k is not None
               else Collide.accel(fr.x[a], fr.x[b], self.c, R2))


class BindTerm(Term):
    """bind (Eq. 12) with each pair's L0², the reverse bind folded in when both are here."""

    def __init__(self, forces, r):
        super().__init__(forces, r)
        sc, op = forces.scene, r.op
        self.pair_term = None
        if r.site in forces.folded:        # carried by its reverse's term
            return
        pl = op.pairs(sc.groups[r.target], sc.groups[op.source]).shifted(
            self.sl.start, sc.offset(op.source))
        I, J, c, q = pl.i, pl.j, pl.c, pl.q
        cJ = None
        if op.source == r.target:           # within(d)/const of a group with itself: i<j once
            keep = I < J
            I, J, c, q = I[keep], J[keep], c[keep], q[keep]
            cJ = c
        elif r.site in forces.folded.values():
            rev = forces.op_at(forces.reverse[r.site])
            cJ = np.full(len(I), float(rev.coeff.c))
            self.dense_stop = max(self.dense_stop, sc.slice(op.source).stop)
        block = None
        if isinstance(op.coeff, Const) and op.source != r.target:
            block = (self.sl, sc.slice(op.source))
        self.pair_term = PairTerm(f"bind on {r.target}", Bind.factor, I, J, c, cJ, q, block,
                                  forces.compiled)
        if block is not None:
            self.pair_term.orig = (sc.groups[r.target].o, sc.groups[op.source].o)

    def add(self, fr, acc):
        if self.pair_term is not None and self.forces.holds(fr, self):
            self.pair_term.add(fr, acc)


class AttractTerm(Term):
    """attract (Eq. 14), its pairs following the phase (index-matched regions)."""

    def __init__(self, forces, r):
        super().__init__(forces, r)
        self._by_phase = {}

    def add(self, fr, acc):
        if not self.forces.holds(fr, self):
            return
        self.pair_term.add(fr, acc)

    @property
    def pair_term(self) -> PairTerm:
        """The attracting pairs of the current phase (made once a phase)."""
        phase = self.forces.phase
        key = tuple(sorted(phase.items()))
        if key not in self._by_phase:
            sc, op = self.forces.scene, self.op
            pl = op.pairs(sc.groups[self.target], sc.groups[op.source], phase).shifted(
                self.sl.start, sc.offset(op.source))
            self._by_phase[key] = PairTerm(f"attract on {self.target}", Attract.factor,
                                           pl.i, pl.j, pl.c, compiled=self.forces.compiled)
        return self._by_phase[key]


class VolumeTerm(Term):
    """A material's volumetric term (:class:`rackstress.model.volume.Volume`): its pairs'
    extensions, each term's κ·θ, the pulls Cᵀ·κθ along the pairs, on both ends of each pair
    owned here. Every term reads its owner's pairs only, so a rank that sees a particle and
    its neighbours evaluates its terms (the callback's ghost cutoff spans the bound groups)."""

    def __init__(self, forces, r):
        super().__init__(forces, r)
        sc = forces.scene
        self.t = r.op.terms(sc.groups[r.target]).shifted(self.sl.start, forces.n)
        C = self.t.C
        self.tptr, self.tidx = C.indptr.astype(np.int64), C.indices.astype(np.int64)
        self.tval = C.data.astype(np.float64)
        self._e, self._s = np.zeros(len(self.t.i)), np.zeros(len(self.t.i))

    def add(self, fr, acc):
        if not self.forces.holds(fr, self):
            return
        key = ("volume", id(self))
        if key not in fr.memo:
            ri, rj = fr.rows(f"volume on {self.target}", self.t.i, self.t.j)
            fr.memo[key] = (ri, rj, fr.compact(ri), fr.compact(rj))
        ri, rj, ai, aj = fr.memo[key]
        t, k = self.t, self.forces.compiled
        if k is not None:
            k.volume_pairs(fr.x, ri, rj, t.L, self.tptr, self.tidx, self.tval, t.kappa, ai,
                           aj, self._e, self._s, acc)
            return
        d = fr.x[rj] - fr.x[ri]
        r = np.sqrt(rowdot(d, d))
        s = t.C.T @ (t.kappa * (t.C @ (r - t.L)))
        g = (s / r)[:, None] * d
        fr.add(ri, g)
        fr.add(rj, -g)


def _leading(mask: np.ndarray, bit: int, n: int) -> int:
    """How many leading rows have ``bit`` set, when every row with it comes before every row
    without it (LAMMPS' ``atom_modify first`` order just after it reordered): a bisection."""
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) // 2
        if mask[mid] & bit:
            lo = mid + 1
        else:
            hi = mid
    return lo


class Fused:
    """The terms active in one phase as one compiled pass a step (:func:`kernels.step`).

    Serial, with compiled kernels, when the rows of the groups the terms act on are their
    particles (:attr:`Frame.identity`): the terms become rows of an instruction table, in the
    callback's order of terms, and their pair data is concatenated once a phase (bind blocks,
    bind and attraction pairs, selected force rows). Each step then costs one look-up of the
    contact candidate lists (:class:`Overlaps`, kept between reneighbourings), re-joined only
    when one of them is new (:meth:`_relist`: the others keep their state), and one compiled
    call, its arguments kept while the frame and the lists stay, that finds the overlapping
    pairs of every list once (shared by the collides of both directions and by the contact
    conditions), evaluates every term exactly as its own kernel does, in the same order, and
    writes LAMMPS' force array, with the deck's constant forces and damping (Deck.
    callback_natives) in LAMMPS' order. The sums are therefore those of the term-by-term path,
    bit for bit, whatever the order of LAMMPS' rows (:meth:`make` returns None where a term
    cannot be expressed so: that phase runs term by term).
    """

    #: the near candidates' margin (kernels.step's h) as a fraction of the contact lists' skin
    #: (MagPod: 0.5 of 2 length units)
    MARGIN = 0.25
    #: kernels.step's constant forces and damping when the deck has none for the callback
    NO_NATIVES = (np.zeros((0, 3)), np.zeros(0))

    def __init__(self):
        self.ops, self.fpar, self.conds = [], [], []
        self.block, self.pairs, self.frows = ([], [], []), ([], [], [], [], []), []
        self.nblock = self.npairs = self.nrows = 0
        #: the contact lists: (A, B) slices (A first in the scene), and a name for errors
        self.lists, self.names = [], []
        self._hits = None
        #: the two sets of per-candidate buffers (:meth:`_buffers`) and the one in use
        self._sets, self._set = [None, None], 1
        #: kernels.step's arguments and what they were made for (frame, force array, nfirst)
        self._args = self._key = None

    @classmethod
    def make(cls, forces: "PyForces") -> "Fused | None":
        """The plan of ``forces``' active terms in its current phase, or None."""
        span, acc_rows, scene = forces.span, forces.dense_span, forces.scene
        self = cls()
        ov = forces.overlaps
        self.margin = cls.MARGIN * (ov.own if ov.own is not None else ov.skin)
        for t in forces.active:
            if not t.phase_ok:
                continue            # holds() is false the whole phase
            conds = [self._list(t.sl, scene.slice(g), "contact")[0] for g in t.contacts]
            if isinstance(t, (BindTerm, AttractTerm)):
                pt = t.pair_term
                if pt is None:
                    continue        # carried by its reverse's term
                if not self._pair_term(pt, span, conds):
                    return None
            elif isinstance(t, CollideTerm):
                if t.mu > 0:
                    return None     # friction reads velocities: term by term (CollideTerm)
                L, rev = self._list(t.sl, t.s, f"collide on {t.target}")
                self._op(kernels.OP_COLLIDE, (L, rev), (t.c,), conds)
            elif isinstance(t, DampenTerm):
                if t.sl.stop > min(span, acc_rows):
                    return None
                self._op(kernels.OP_DAMPEN, (t.sl.start, t.sl.stop), (t.op.extra,), conds)
            elif isinstance(t, ForceTerm):
                mask = np.zeros(forces.n, dtype=bool)
                mask[t.sl] = t.op.mask(t.sl.stop - t.sl.start)
                rows = np.flatnonzero(mask[:acc_rows])
                if mask[acc_rows:].any():
                    return None
                self.frows.append(rows)
                self._op(kernels.OP_FORCE, (self.nrows, self.nrows + len(rows)),
                         tuple(float(c) for c in t.op.vector()), conds)
                self.nrows += len(rows)
            else:
                return None
        i64, f64 = np.int64, np.float64
        self.ops = np.array(self.ops, i64).reshape(-1, 8)
        self.fpar = np.array(self.fpar, f64).reshape(-1, 3)
        self.conds = np.array(self.conds + [0], i64)
        join = (lambda parts, dt: np.ascontiguousarray(np.concatenate(parts), dt) if parts
                else np.zeros(0, dt))
        self.bq, self.bcI, self.bcJ = (join(p, f64) for p in self.block)
        self.pi, self.pj = (join(p, i64) for p in self.pairs[:2])
        self.pcI, self.pcJ, self.pq = (join(p, f64) for p in self.pairs[2:])
        self.frows = join(self.frows, i64)
        return self

    def _list(self, t: slice, s: slice, name: str):
        """The contact list of groups t and s (index), and whether t is its second group."""
        A, B = (s, t) if t.start > s.start else (t, s)
        key = (A, B)
        if key not in self.lists:
            self.lists.append(key)
            self.names.append(name)
        return self.lists.index(key), int(t.start > s.start)

    def _op(self, kind, ints, floats, conds):
        row = list(ints) + [0] * (5 - len(ints))
        self.ops.append([kind, *row, len(self.conds), len(self.conds) + len(conds)])
        self.conds += conds
        self.fpar.append(list(floats) + [0.0] * (3 - len(floats)))

    def _pair_term(self, pt: PairTerm, span: int, conds) -> bool:
        if pt.block is not None:
            ts, ss = pt.block
            if max(ts.stop, ss.stop) > span:
                return False
            m, n = ts.stop - ts.start, ss.stop - ss.start
            fold = float(pt._cJT is not None)
            cI, cJ = pt._cIT, pt._cJT if pt._cJT is not None else 0.0
            if isinstance(cI, float) and isinstance(cJ, float) and pt.orig is not None:
                # one coefficient each way: L0² from the original positions, if that gives
                # the pairs' own L0² bit for bit (it is how Bind.pairs computes them)
                ot, os_ = pt.orig
                e = [os_[:, k][:, None] - ot[:, k][None, :] for k in range(3)]
                if np.array_equal(e[0] * e[0] + e[1] * e[1] + e[2] * e[2], pt._qT):
                    o = np.concatenate([ot.T.ravel(), os_.ravel()])
                    for part, a in zip(self.block, (o, np.zeros(len(o)), np.zeros(len(o)))):
                        part.append(a)       # (the coefficient arrays keep the offsets)
                    self._op(kernels.OP_BLOCKC, (ts.start, m, ss.start, n, self.nblock),
                             (fold, cI, cJ), conds)
                    self.nblock += len(o)
                    return True
            cIT, cJT = pt._full
            for part, a in zip(self.block, (pt._qT, cIT, cJT)):
                part.append(a.ravel())
            self._op(kernels.OP_BLOCK, (ts.start, m, ss.start, n, self.nblock), (fold,), conds)
            self.nblock += m * n
            return True
        I, J = pt.I, pt.J
        if len(I) and max(I.max(), J.max()) >= span:
            return False
        attract = pt.q is None
        cJ = pt.cI if pt.cJ is None else pt.cJ
        for part, a in zip(self.pairs, (I, J, pt.cI, cJ, np.zeros(len(I)) if attract else pt.q)):
            part.append(a)
        kind = kernels.OP_ATTRACT if attract else kernels.OP_BIND
        self._op(kind, (self.npairs, self.npairs + len(I)), (float(pt.cJ is not None),), conds)
        self.npairs += len(I)
        return True

    def run(self, forces: "PyForces", fr: Frame, f: np.ndarray) -> int:
        """One step added into ``f``; return the first row written at or after
        ``forces.nfirst`` (one LAMMPS does not integrate yet), or −1."""
        # the same lists (objects) until LAMMPS reneighbours or the callback's own check renews
        # them (Overlaps keeps them in the frame's memo)
        cand = forces.overlaps._candidates
        hits = [cand(fr, A, B) for A, B in self.lists]
        if self._hits is None or not all(map(operator.is_, hits, self._hits)):
            self._relist(forces, fr, hits)
        key = (fr, f, forces.nfirst)
        if self._args is None or not all(map(operator.is_, key, self._key)):
            self._key, self._args = key, self._step_args(forces, fr, f)
        n, L, k = forces.compiled.step(*self._args)
        if L >= 0:
            a, b = fr.particles(self.ca[k:k + 1])[0], fr.particles(self.cb[k:k + 1])[0]
            raise PartnerLost(f"{self.names[L]}: atom ids {int(a) + 1} and {int(b) + 1} "
                              "coincide (Eq. 10 is undefined at d = 0)", int(a))
        return n

    #: kernels.step's per-candidate scratch arrays: (name, columns, dtype)
    _BUFFERS = (("ca", 0, np.int64), ("cb", 0, np.int64), ("cR2", 0, np.float64),
                ("ov", 0, np.int64), ("ovr", 2, np.int64), ("ovd", 4, np.float64),
                ("near", 3, np.int64), ("nR2", 0, np.float64), ("reach2", 0, np.float64))

    def _buffers(self, n: int) -> dict:
        """The set of per-candidate buffers not in use now, grown to hold ``n`` candidates
        (two sets used in turn: the lists' renewal reads the old set while it fills the new
        one, and neither is allocated again, nor its memory faulted in, at every renewal)."""
        sets = self._sets
        spare = 1 - self._set
        if sets[spare] is None or len(sets[spare]["ca"]) < n:
            cap = 2 * n + 64            # room for the lists to grow
            sets[spare] = {name: np.zeros((cap, cols) if cols else cap, dt)
                           for name, cols, dt in self._BUFFERS}
        self._set = spare
        return sets[spare]

    def _relist(self, forces: "PyForces", fr: Frame, hits: list) -> None:
        """Join the contact lists for kernels.step after one of them was renewed (a new list
        object). A list that is the same object as before keeps, moved to its new place, its
        near candidates, their particles' reference positions and its (R + h)², so only the
        new lists are measured in full at the next step (:func:`kernels.relist`)."""
        i64 = np.int64
        index = {} if self._hits is None else {id(h): L for L, h in enumerate(self._hits)}
        kept = np.array([index.get(id(h), -1) for h in hits] + [0], i64)[:-1]
        loff = np.zeros(len(hits) + 1, i64)
        np.cumsum([len(h[0]) for h in hits], out=loff[1:])
        n = int(loff[-1])
        if self._hits is None:      # nothing to keep: an empty old state
            z = np.zeros(1, i64)
            old = (np.zeros(0, i64), np.zeros(0, i64), np.zeros(0), z, np.zeros((0, 3), i64),
                   np.zeros(0), np.zeros(0), z, z, np.zeros(0, i64), z, np.zeros((0, 3)))
        else:
            old = (self.ca, self.cb, self.cR2, self.loff, self.near, self.nR2, self.reach2,
                   self.nnear, self.valid, self.urow, self.uoff, self.uref)
        buf = self._buffers(n)
        for name, _, _ in self._BUFFERS:
            setattr(self, name, buf[name][:n])
        for h, Lo, k0, k1 in zip(hits, kept, loff[:-1], loff[1:]):
            if Lo < 0:          # a new list's candidates (the kept ones' are moved below)
                self.ca[k0:k1], self.cb[k0:k1], self.cR2[k0:k1] = h
        self.urow, self.uoff, self.uref, self.nnear, self.valid = forces.compiled.relist(
            self.ca, self.cb, self.cR2, loff, kept, forces.flag_rows(fr), *old, self.near,
            self.nR2, self.reach2)
        self.loff = loff
        self.ovn = np.zeros(len(hits), i64)
        self._hits = hits
        self._args = None

    def _step_args(self, F: "PyForces", fr: Frame, f: np.ndarray) -> tuple:
        """kernels.step's arguments: the same objects every step of a frame (LAMMPS' arrays
        are views taken when the frame was made) while the contact lists stay."""
        natF, natg3 = F.natives3 if F.natives is not None else self.NO_NATIVES
        nnat = min(F.nfirst, fr.nlocal) if F.natives is not None else 0
        return (fr.x, fr.v, f, F.facc, F.fmass3, self.ops, self.fpar, self.conds, self.bq,
                self.bcI, self.bcJ, self.pi, self.pj, self.pcI, self.pcJ, self.pq, self.frows,
                self.ca, self.cb, self.cR2, self.loff, self.ov, self.ovr, self.ovd, self.ovn,
                self.near, self.nR2, self.reach2, self.nnear, self.valid, self.urow, self.uoff,
                self.uref, self.margin, F.sacc, F.sflag, F.stouched, F.snt, F.mass, fr.tag,
                F.nfirst, natF, natg3, nnat, fr.span)


class IndentTerm(Term):
    """A rigid sphere's push on the target's owned particles (``[[indenter]]``,
    :meth:`Indent.accel`), the sphere's centre that of LAMMPS' step (``Indent.centre_at``,
    as the plugin's rs/indent and the reference engine take it)."""

    def __init__(self, forces, r):
        super().__init__(forces, r)
        self.k = np.asarray(r.op.k, float)
        self.radius = forces.scene.radii()[self.sl]

    def add(self, fr, acc):
        if not self.forces.holds(fr, self):
            return
        sel = fr.owned(self.sl)
        j = fr.tag[sel] - 1 - self.sl.start             # the rows' places in the group
        a = Indent.accel(fr.x[sel], self.radius[j], self.k[j],
                         self.op.centre_at(fr.step), self.op.radius)
        acc[fr.compact(sel)] += a


#: The term realizing each operator class in the callback.
TERMS = {Force: ForceTerm, Dampen: DampenTerm, Collide: CollideTerm, Bind: BindTerm,
         Attract: AttractTerm, Volume: VolumeTerm, Indent: IndentTerm}


class PyForces:
    """The ``fix external`` callback: the sum of all Python-realized operators active now."""

    def __init__(self, lmp, deck, comm=None, kernels: str | None = None):
        """``kernels``: 'numba' (compiled loops, :mod:`rackstress.model.kernels`) or 'numpy'
        (the reference implementation); default ``RACKSTRESS_KERNELS``, else numba if present."""
        self.lmp, self.deck, self.scene, self.comm = lmp, deck, deck.scene, comm
        self.kernels = kernel_choice(kernels)
        self.compiled, self.warm = None, None
        if self.kernels == "numba":
            self.warm = warm_kernels()     # compile once (cached on disk), load afterwards
            self.compiled = compiled_kernels()
        self.n = self.scene.n_particles
        self.radius = self.scene.radii()
        self.mass = np.concatenate([np.full(g.n, deck.masses[name])
                                    for name, g in self.scene.groups.items()])
        self.error = None
        self._keys = None        # contact conditions of the active terms (per phase)
        self._lists = None       # contact lists the phase can use (per phase)
        self._agreed = None      # MPI: this step's agreed contact conditions
        self._fail_here = None
        #: passive particles (deck.passive) join LAMMPS' moving group when first reachable
        self.passive = np.zeros(self.n, dtype=bool)
        for name in getattr(deck, "passive", ()):
            self.passive[self.scene.slice(name)] = True
        self.move_bit = self._move_bit(lmp, deck) if self.passive.any() else None
        self._scan_moving = self.move_bit is not None   # once: a resumed run's moving ones
        self._mask = None        # (frame, LAMMPS' mask array) of the last activation
        #: rows below this are particles (serial): every group before the passive ones, which
        #: LAMMPS keeps first (they are never reordered) when the passive groups come last
        first_passive = min((self.scene.offset(g) for g in getattr(deck, "passive", ())),
                            default=self.n)
        self.span = first_passive if not self.passive[:first_passive].any() and \
            self.passive[first_passive:].all() else 0
        serial = comm is None or comm.Get_size() == 1
        self._mpi = not serial
        self.bed = (RestingBed(self.n, self.span, self.compiled,
                               self.scene.original_positions())
                    if self.move_bit is not None and self.span and self.compiled is not None
                    and serial else None)
        own = getattr(deck, "skin", None)
        lammps_skin = getattr(deck, "lammps_skin", own)
        #: serial, LAMMPS' skin wider than the lists': the lists' own displacement check
        #: (under MPI the lists use LAMMPS' skin, renewed by its reneighbouring)
        self.own = own if own != lammps_skin and serial else None
        self.overlaps = Overlaps(self.radius, lammps_skin, self.compiled,
                                 self._activate if self.move_bit is not None else None,
                                 self.passive, self.bed, self.own)
        #: LAMMPS integrates only its first ``nfirst`` rows (atom_modify first); a force on a
        #: later row (a passive particle activated too late) would be lost: (step, particle)
        self.nfirst = self.n
        self.late = None
        self.activated_late = False
        python = deck.python_ops
        here = {r.site for r in python}
        #: reverse place of every bind here whose reverse is here too; folded[rev] = carrier
        self.reverse, self.folded = {}, {}
        for r in python:
            if isinstance(r.op, Bind):
                rev = reverse_of(self.scene.operators, *r.site)
                if (rev is not None and rev != r.site and r.site not in self.folded
                        and rev in here):
                    self.reverse[r.site] = rev
                    self.folded[rev] = r.site   # rev is carried by r's term
        self.terms = [TERMS[type(r.op)](self, r) for r in python]
        self.phase = {}
        self.active = []
        self.dense_span = max([0] + [t.dense_stop for t in self.terms])
        self._fresh = True
        self.frame = None
        #: the static constant forces and damping the callback adds itself (Deck.callback_natives):
        #: F and γ per particle, over the rows fix nve integrates
        self.natives = deck.natives_per_particle() if deck.callback_natives else None
        if self.compiled is not None:
            # compiled serial path: the sparse (collide-only) rows' accelerations and which of
            # them this step touched
            self.sacc = np.zeros((self.n, 3))
            self.sflag = np.zeros(self.n, dtype=np.bool_)
            self.stouched = np.zeros(self.n, dtype=np.int64)
            self.snt = np.zeros(1, dtype=np.int64)
        #: serial with compiled kernels: each phase's terms as one compiled pass (Fused),
        #: made once a phase (None where a term cannot be expressed so); False: term by term
        self.fuse = self.compiled is not None and (comm is None or comm.Get_size() == 1)
        self._plans, self._plan = {}, None
        self._flags = np.zeros(0, dtype=np.bool_)
        #: the natives' F and γ for the compiled kernels, γ three times (they go over the rows'
        #: x, y, z one after another)
        self.natives3 = (None if self.natives is None or self.compiled is None else
                         (np.ascontiguousarray(self.natives[0]), np.repeat(self.natives[1], 3)))
        if self.fuse:
            self.facc = np.zeros((self.dense_span, 3))
            #: the masses of the dense rows, three times (kernels.step, likewise)
            self.fmass3 = np.repeat(self.mass[:self.dense_span], 3)
        # LAMMPS' own displacement check keeps the per-layout memos valid (Overlaps); with any
        # other neighbour settings every step starts from scratch
        self.verlet = (lmp.extract_setting("neigh_every") == 1
                       and lmp.extract_setting("neigh_delay") == 0
                       and lmp.extract_setting("neigh_dist_check") == 1)

    @staticmethod
    def _move_bit(lmp, deck) -> int:
        """LAMMPS' mask bit of the deck's moving group (group index k has bit 1 << k)."""
        names = list(lmp.available_ids("group"))
        return 1 << names.index(deck.moving)

    def _activate(self, fr: Frame, rows: np.ndarray) -> None:
        """Add the owned passive particles among ``rows`` to the moving group (exact: they are
        at rest with no force until now; fix nve reads the mask every step)."""
        own = rows[rows < fr.nlocal]
        own = own[self.passive[fr.particles(own)]]
        if len(own):
            if self._mask is None or self._mask[0] is not fr:
                # LAMMPS reallocates its per-atom arrays only when it reneighbours (a new
                # frame): one view a frame (extract_atom costs tens of µs)
                self._mask = (fr, self.lmp.numpy.extract_atom("mask"))
            mask = self._mask[1]
            new = own[(mask[own] & self.move_bit) == 0]
            if len(new) and new.max() >= self.nfirst:
                self.activated_late = True   # integrated from LAMMPS' next reordering on
            mask[own] |= self.move_bit
            if self.bed is not None and len(new):
                self.bed.activated(fr, new)

    def _activate_moving(self, fr: Frame) -> None:
        """Once, at the first call: passive particles already moving (a resumed run) join, and
        the resting bed learns of every passive particle already in the moving group
        (LammpsRun.restore puts there those the checkpoint holds displaced or moving)."""
        self._scan_moving = False
        if fr.identity and self.span and self.compiled is not None:
            # the passive rows are those after span
            self._activate(fr, self.compiled.moving_rows(fr.v, self.span, fr.nlocal))
        else:
            own = np.arange(fr.nlocal)
            own = own[self.passive[fr.index[own]]]
            v = fr.v[own]
            self._activate(fr, own[(v[:, 0] != 0.0) | (v[:, 1] != 0.0) | (v[:, 2] != 0.0)])
        if self.bed is not None:
            mask = self.lmp.numpy.extract_atom("mask")[:fr.nlocal]
            rows = np.flatnonzero((mask & self.move_bit) != 0)
            rows = rows[self.passive[fr.particles(rows)]]
            rows = rows[~self.bed.active[fr.particles(rows)]]
            if len(rows):
                self.bed.activated(fr, rows)

    def op_at(self, site):
        return self.scene.operators[site[0]][site[1]]

    # ------------------------------------------------------------------ phase
    def set_phase(self, phase_vars) -> bool:
        """Select the terms active in this phase; return whether the callback has anything to
        do (a term is active, or it adds the deck's constant forces and damping)."""
        self.phase = dict(phase_vars)
        self._keys = None
        self._lists = None
        self._fresh = True     # the fix (and its force array) may be new
        for t in self.terms:
            t.phase_ok = phase_active(t.op.when, self.phase)
        self.active = [t for t in self.terms if not t.gated or t.phase_ok]
        self._plan = None
        return bool(self.active) or self.natives is not None

    def flag_rows(self, fr: Frame) -> np.ndarray:
        """A False flag per row of the frame (scratch of :func:`kernels.members`)."""
        nall = fr.nlocal + fr.nghost
        if len(self._flags) < nall:
            self._flags = np.zeros(nall, dtype=np.bool_)
        return self._flags

    def _fused(self, fr: Frame) -> "Fused | None":
        """This phase's compiled pass, if this step can take it (serial, rows = particles)."""
        if not (self.fuse and fr.identity):
            return None
        if self._plan is None:
            key = tuple(sorted(self.phase.items()))
            if key not in self._plans:
                self._plans[key] = Fused.make(self)
            self._plan = self._plans[key] or False
        return self._plan or None

    def _contact(self, fr: Frame, target: str, group: str) -> bool:
        if self._agreed is not None:            # MPI: agreed on by all ranks this step
            return self._agreed[(target, group)]
        return self._contact_here(fr, target, group)

    def _contact_here(self, fr: Frame, target: str, group: str) -> bool:
        return len(self.overlaps.pairs(fr, self.scene.slice(target), self.scene.slice(group),
                                       "contact")[0]) > 0

    def _contact_keys(self) -> list:
        """(target, group) of every contact condition of the terms active in this phase."""
        if self._keys is None:
            keys = []
            for t in self.active:
                if phase_active(t.op.when, self.phase):
                    keys += [(t.target, g) for g in contact_groups(t.op.when)]
            self._keys = list(dict.fromkeys(keys))
        return self._keys

    def _phase_lists(self) -> list:
        """(A, B) of every contact list this phase can use: each active collide's two groups
        and each contact condition's (per phase)."""
        if self._lists is None:
            sc, lists = self.scene, []
            pairs = [(t.sl, t.s) for t in self.active if isinstance(t, CollideTerm) and t.phase_ok]
            pairs += [(sc.slice(a), sc.slice(b)) for a, b in self._contact_keys()]
            for t, s in pairs:
                AB = (s, t) if t.start > s.start else (t, s)
                if AB not in lists:
                    lists.append(AB)
            self._lists = lists
        return self._lists

    def _search_lists(self, fr: Frame) -> None:
        """Search every list of the phase at a frame's first step (a new LAMMPS layout): a
        list renewed by LAMMPS' reneighbouring is then as old as the frame it measures from (a
        list first searched later in the frame, such as a contact condition asked only once
        another held, could miss a pair that closed in by more than a skin since the frame
        began), and every list against a passive group makes the layout's activation search
        at its first step. (Lists the callback renews itself measure from their own search,
        :meth:`Overlaps.renew`; those kept from an earlier layout are in the memo already,
        which must not stop the others' search.)"""
        if ("all searched",) in fr.memo:
            return
        fr.memo[("all searched",)] = True
        for A, B in self._phase_lists():
            self.overlaps._candidates(fr, A, B)

    def _agree(self, fr, failed: bool) -> bool:
        """MPI: one reduction of this rank's failure and contact conditions; every rank learns
        whether any failed and each condition (a contact anywhere holds everywhere)."""
        from mpi4py import MPI

        keys = self._contact_keys()
        vec = np.zeros(1 + len(keys), dtype=np.int8)
        vec[0] = failed
        if not failed:
            try:
                vec[1:] = [self._contact_here(fr, t, g) for t, g in keys]
            except Exception as exc:  # noqa: BLE001 - agreed on below
                self._fail_here = exc
                vec[0] = 1
        self.comm.Allreduce(MPI.IN_PLACE, vec, op=MPI.MAX)
        self._agreed = {k: bool(b) for k, b in zip(keys, vec[1:])}
        return bool(vec[0])

    def holds(self, fr, term) -> bool:
        """⟨P⟩ (Eq. 4) of a term's conditions now: phase (decided at the phase switch), then
        contacts."""
        if not term.phase_ok:
            return False
        for g in term.contacts:
            if not self._contact(fr, term.target, g):
                return False
        return True

    def _frame(self, nlocal: int) -> Frame:
        """This step's frame: the last one refreshed, or a new layout after a reneighbouring."""
        lmp, fr = self.lmp, self.frame
        ago = lmp.lib.lammps_extract_setting(lmp.lmp, b"neigh_ago")  # (no per-step wrapper)
        if (fr is None or self._fresh or not self.verlet or fr.nlocal != nlocal or ago == 0
                or self._nghost[0] != fr.nghost):
            if self.move_bit is not None and (ago == 0 or self._fresh):
                # LAMMPS has just reordered (atom_modify first): the moving group's rows
                # come first, and only they are integrated until it reorders again
                self.nfirst = _leading(lmp.numpy.extract_atom("mask"), self.move_bit, nlocal)
            fr = self.frame = Frame(lmp, self.n, nlocal, self.dense_span, self.mass, self.span)
            self._nghost = _global_int(lmp, "nghost")
            self.overlaps.nfirst = self.nfirst
            if self.bed is not None:
                self.bed.relayout(fr, self.nfirst)
        else:
            fr.refresh()
        if self.own is not None:    # serial: each list renewed by its own particles' motion
            self.overlaps.renew(fr)
        if self._scan_moving:       # first call: before any search reads the moving set
            self._activate_moving(fr)
        self._search_lists(fr)
        return fr

    # ------------------------------------------------------------------ callback
    def __call__(self, caller, step, nlocal, tag, x, f):
        mpi = self._mpi
        self._fail_here, self._agreed, fr = None, None, None
        try:
            fr = self._frame(nlocal)
            fr.step = int(step)          # LAMMPS' step: an indenter's centre moves with it
            self._fresh = False
        except Exception as exc:  # noqa: BLE001 - agreed on below
            self._fail_here = exc
        # MPI: the contact conditions are agreed on first (one reduction, if there are any);
        # a failure is agreed on at the end in any case (one more)
        failed = (self._agree(fr, self._fail_here is not None)
                  if mpi and self._contact_keys() else self._fail_here is not None)
        if not failed:
            self._evaluate(fr, f)
            if self._fail_here is None:
                self._check_finite(fr, nlocal)
        if mpi:
            from mpi4py import MPI

            failed = self.comm.allreduce(self._fail_here is not None, op=MPI.LOR)
        else:
            failed = self._fail_here is not None
        if failed:
            if self._fail_here is not None and self.error is None:
                self.error = (step, self._fail_here)
            f[:] = 0.0
            # stop LAMMPS before the next step (it checks its timer there; all ranks do this
            # in the same step). This step ends with the forces added so far; its positions
            # were made before them, and its velocities are not kept (the run stops here)
            self.lmp.force_timeout()

    def _check_finite(self, fr, nlocal: int) -> None:
        """A non-finite force on an integrated row (a bound pair that coincides) fails this
        step, before LAMMPS moves any particle with it: the frames kept stay finite and the
        step named is the one it arose in, as on the reference engine (one pass over the moving
        rows' forces, ~1 µs per 1,000 of them)."""
        rows = min(nlocal, self.nfirst)
        k = first_nonfinite(fr.f[:rows])
        if k >= 0:
            atom = int(fr.tag[k])
            self._fail_here = NonFiniteForce(f"the force on atom id {atom} is not finite",
                                             atom - 1)

    def _evaluate(self, fr, f) -> None:
        """This step's forces of the active terms, added into LAMMPS' force array ``fr.f``
        (LAMMPS cleared it at the start of the step; a failure is kept in _fail_here).

        The sums are LAMMPS' own: each row gets f + a·m, as fix external's add pass would have
        done with a·m in its array, so the trajectory is the same bit for bit."""
        try:
            out = fr.f
            plan = self._fused(fr)
            if plan is not None:        # natives and every term in one compiled pass
                self._mark_late(fr, plan.run(self, fr, out))
                return
            if self.natives is not None:
                self._add_natives(fr, out)
            acc = np.zeros((fr.acc_rows, 3))
            for term in self.active:
                term.add(fr, acc)
            fr.flush(acc)
            if fr.identity:
                out[:fr.acc_rows] += acc * fr.dense_mass
            else:
                out[fr.dense_rows] += acc * fr.dense_mass
            if self.compiled is not None and fr.identity:
                r = self.compiled.add_sparse(out, self.sacc, self.sflag, self.stouched, self.snt,
                                             self.mass, fr.tag, self.nfirst)
            else:
                r = self._add_sparse(fr, out)
            self._mark_late(fr, r)
        except Exception as exc:  # noqa: BLE001 - reported by the runner after the chunk
            self._fail_here = exc

    def _mark_late(self, fr: Frame, r: int) -> None:
        """Row ``r`` ≥ 0 got a force though LAMMPS does not integrate it yet: exactness would
        be lost (the step and the particle are kept in ``late``)."""
        if self.move_bit is not None and r >= 0:
            self.late = (int(self.lmp.extract_global("ntimestep")), int(fr.tag[r]) - 1)

    def _add_natives(self, fr: Frame, f) -> None:
        """f = (f + F) − γ·v on the rows LAMMPS integrates (its first ``nfirst``; every other
        row rests: v = 0, and no constant force acts on a passive group): the fixes addforce
        and viscous would do the same arithmetic over every atom (Deck.callback_natives)."""
        F, g = self.natives
        n = min(self.nfirst, fr.nlocal)
        ident = fr.span if fr.identity else 0
        if self.compiled is not None:
            self.compiled.add_natives(f, fr.v, fr.tag, n, ident, *self.natives3)
            return
        p = fr.tag[:n].astype(np.int64) - 1
        f[:n] = (f[:n] + F[p]) - g[p, None] * fr.v[:n]

    def _add_sparse(self, fr: Frame, f) -> int:
        """f rows outside the dense accumulator += this step's sparse contributions; the first
        such row LAMMPS does not integrate yet (at or after ``nfirst``), or −1."""
        if fr.sparse is None:
            return -1
        rows, contrib = fr.sparse
        u, inv = np.unique(rows, return_inverse=True)
        m = self.mass[fr.index[u]]
        for k in range(3):
            f[u, k] += np.bincount(inv, weights=contrib[:, k], minlength=len(u)) * m
        late = u[u >= self.nfirst]
        return int(late[0]) if len(late) else -1
