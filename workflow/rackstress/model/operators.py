"""The paper's primitive operators (Section 2.3), each with its physics in one place.

Every particle has unit mass and every operator adds an acceleration. One class per operator
holds everything about it that any engine needs:

=========  ==========================  =====================================================
operator   equation                    acceleration on particle p from particle u
=========  ==========================  =====================================================
force      Eq. 8 (Eq. 15 selection)    â_p
dampen     Eq. 9 (Eq. 28 extra)        −c·v_p
collide    Eqs. 10–11 (radii erratum)  c·(u−p)·min(0, 1 − R²/‖u−p‖²),   R = r_p + r_u
bind       Eqs. 12–13                  c·(u−p)·(1 − L0²/‖u−p‖²),       L0 = ‖u_o − p_o‖
attract    Eq. 14                      c·(u−p)/‖u−p‖                  (constant magnitude c)
integrate  Eq. 5                       v += t·a;  p += t·v            (:func:`integrate`)
indent     (beyond the paper)          k·(R + r_p − ‖p − c‖)·(p − c)/‖p − c‖, a rigid sphere
=========  ==========================  =====================================================

A pair operator's formula is written once, as ``c·factor(d², q)·(u − p)`` with the per-pair
parameter q (R² for collide, L0² for bind, none for attract): :meth:`PairOperator.factor` is the
equation, :meth:`PairOperator.accel` the acceleration kernel on i from j (the reference engine
and the LAMMPS callback both call them), :meth:`PairOperator.jacobian` its linearization (the
stability prediction), :meth:`PairOperator.pairs` the coefficient matrix's pairs with their
per-pair parameter (L0² is computed here and nowhere else), :meth:`Operator.label` its name in
messages and decks. Collisions have no fixed pairs: :func:`contact_candidates` and
:meth:`Collide.touching` are the one contact search every engine uses.

Coefficient "matrices" ĉ (m×n) are never stored densely: :class:`Const` (every pair),
:class:`Within` (pairs whose original distance is below d, Eq. 16; :class:`WithinInside` keeps only
those whose segment stays inside the part's shape) and :class:`Matched` (index-matched attraction
regions, Eqs. 27–28). Coefficients are *directed*: the operator on i from j
carries its own c; the reverse interaction, if any, is a separate operator on j
(:func:`reverse_of` finds it).

Conditions make an operator conditional (the paper's ⟨P⟩, Eq. 4): :class:`PhaseIn` (the gait
phase) and :class:`Contact` (some particle of the target overlaps some particle of a group,
Eq. 28's damping). An operator applies only when all its conditions hold; :class:`Dampen` may
instead add ``extra`` to its base coefficient when its conditions hold (10 + 85⟨…⟩).

Adding an operator is one new class here (its formula, parameters, label, pairs and Jacobian)
plus its realization in each engine's registry (``REALIZE`` in the deck compiler, ``TERMS`` in
the LAMMPS callback, ``KERNELS`` in the reference engine).

Examples
--------
>>> import numpy as np
>>> Collide.accel(np.zeros((1, 3)), np.array([[1.5, 0.0, 0.0]]), 100.0, np.array([4.0]))
array([[-116.66666667,   -0.        ,   -0.        ]])
>>> Bind("rack", Const(100.0)).label()
'bind(rack, 100)'
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Mapping, Union

import numpy as np

from rackstress.errors import SceneError
from rackstress.lib.vec import bbox, inside, rowdot


# --------------------------------------------------------------------------- Eq. 5
def integrate(p: np.ndarray, v: np.ndarray, a: np.ndarray, t: float):
    """Eq. 5 (forward-corrected Euler): v += t·a; p += t·v. Returns the new (p, v).

    Examples
    --------
    >>> import numpy as np
    >>> integrate(np.zeros((1, 3)), np.zeros((1, 3)), np.array([[0.0, 2.0, 0.0]]), 0.5)[0]
    array([[0. , 0.5, 0. ]])
    """
    v = v + t * a
    return p + t * v, v


# --------------------------------------------------------------------------- conditions
@dataclass(frozen=True)
class PhaseIn:
    """⟨var ∈ values⟩ on the current phase's variables (e.g. ``PhaseIn('r', (2, 3))``)."""

    var: str
    values: tuple

    def __post_init__(self):
        object.__setattr__(self, "values", tuple(self.values))

    def holds(self, phase: Mapping) -> bool:
        if self.var not in phase:
            raise SceneError(f"condition needs phase variable '{self.var}', which the phase "
                             f"{dict(phase)} does not set")
        return phase[self.var] in self.values

    def label(self) -> str:
        return f"{self.var} in {set(self.values)}"


@dataclass(frozen=True)
class Contact:
    """⟨∃ i, j : ‖col(p_i, 1, group_j)‖ > 0⟩: some target particle overlaps a ``group`` particle."""

    group: str

    def label(self) -> str:
        return f"contact {self.group}"


Condition = Union[PhaseIn, Contact]


def phase_active(conditions, phase: Mapping) -> bool:
    """True when every phase condition holds (contact conditions are the engine's to check)."""
    return all(c.holds(phase) for c in conditions if isinstance(c, PhaseIn))


def contact_groups(conditions) -> tuple:
    """The groups an operator's contact conditions name (Eq. 28's ⟨leg touches sediment⟩)."""
    return tuple(c.group for c in conditions if isinstance(c, Contact))


# --------------------------------------------------------------------------- coefficients
@dataclass(frozen=True)
class Const:
    """ĉ = [c] for every pair (i, j), i ≠ j when target and source are the same group."""

    c: float

    def label(self) -> str:
        return f"{self.c:g}"


@dataclass(frozen=True)
class Within:
    """within(d) of Eq. 16: c for pairs whose *original* distance is < d, never i = j."""

    d: float
    c: float

    def label(self) -> str:
        return f"within({self.d:g}) magnitude {self.c:g}"


@dataclass(frozen=True)
class Matched:
    """c⟨target_index_i = source_index_j ≠ 0⟩ (Eqs. 27–28).

    ``target`` and ``source`` name index vectors kept in the groups' ``meta['regions']``; a
    name may contain ``{var}`` fields filled from the phase (``'breg{r}'``), which is how the
    active body region follows the gait.
    """

    target: str
    source: str
    c: float

    def label(self) -> str:
        return f"{self.c:g}<{self.target} = {self.source} != 0>"


@dataclass(frozen=True)
class WithinInside(Within):
    """within(d) of Eq. 16 restricted to pairs whose binding segment lies inside ``region``.

    ``region`` (a :class:`rackstress.model.regions.Region`) is the part's shape, the continuum
    its particles fill. A binding that crosses free space — a notch, a hole, the gap at a
    re-entrant corner — is no material: a square lattice's diagonal binding at an L's inner
    corner passes through the corner point itself and would fill the notch, so the part would
    lose the corner's stress concentration (measured: docs/benchmarks/validity.md). A segment is
    inside when every one of its points at 1/32, 2/32, …, 31/32 of its length is an *interior*
    point of the region (its 8 neighbours at ±ε along the diagonals, ε = 10⁻⁶·d, are all in it);
    a segment touching the boundary only at its ends is inside, one through a corner is not.
    :mod:`rackstress.model.inside` decides it without sampling every binding (a filled
    lattice's own cells, then a ray test near the boundary): 10⁶ particles in seconds.

    Example
    -------
    >>> import numpy as np
    >>> from rackstress.model.regions import Box
    >>> L = Box((-.5, -.5, -.5), (.5, 1.5, .5)) | Box((-.5, .5, -.5), (1.5, 1.5, .5))
    >>> c = WithinInside(1.5, 20.0, L)      # an L of three unit cells around (0,0), (0,1), (1,1)
    >>> c.inside(np.array([[0., 0, 0], [0, 0, 0]]), np.array([[0., 1, 0], [1, 1, 0]])).tolist()
    [True, False]
    """

    region: object = None

    def label(self) -> str:
        return f"within({self.d:g}) inside the part magnitude {self.c:g}"

    def inside(self, a: np.ndarray, b: np.ndarray, name: str = "part") -> np.ndarray:
        """Whether each segment a[k]–b[k] lies inside the region (class docstring), by the
        fast lattice/ray test of :mod:`rackstress.model.inside` (same answer as sampling)."""
        from rackstress.model.inside import segments_inside

        return segments_inside(self.region, a, b, self.d, name=name)

    def inside_pairs(self, points: np.ndarray, i: np.ndarray, j: np.ndarray,
                     name: str = "part") -> np.ndarray:
        """:meth:`inside` for the segments points[i[k]]–points[j[k]] (one group's pairs)."""
        from rackstress.model.inside import pairs_inside

        return pairs_inside(self.region, points, i, j, self.d, name=name)


Coefficient = Union[Const, Within, Matched]


@dataclass(frozen=True)
class PairList:
    """The pairs (i on the target, j on the source) of a coefficient matrix, with c per pair and
    the operator's per-pair parameter ``q`` (L0² for bind, None otherwise)."""

    i: np.ndarray
    j: np.ndarray
    c: np.ndarray
    q: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.i)

    def shifted(self, ti: int, sj: int) -> "PairList":
        """The same pairs in global particle indices (group offsets ``ti``, ``sj``)."""
        return PairList(self.i + ti, self.j + sj, self.c, self.q)

    def select(self, keep) -> "PairList":
        return PairList(self.i[keep], self.j[keep], self.c[keep],
                        None if self.q is None else self.q[keep])


def _all_pairs(target, source) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.meshgrid(np.arange(target.n), np.arange(source.n), indexing="ij")
    i, j = i.ravel(), j.ravel()
    if target is source:
        keep = i != j
        i, j = i[keep], j[keep]
    return i, j


def _sorted(i, j):
    """The pairs in (i, j) order (:func:`rackstress.model.inside.sort_pairs`: a compiled
    counting sort, fast for millions)."""
    from rackstress.model.inside import sort_pairs

    return sort_pairs(i, j)


def region_index(group, name: str, phase: Mapping) -> np.ndarray:
    """The integer index vector ``name`` (phase fields filled in) of a group's attraction regions."""
    try:
        key = name.format(**phase)
    except KeyError as exc:
        raise SceneError(f"region name '{name}' needs phase variable {exc}") from None
    regions = group.meta.get("regions", {})
    if key not in regions:
        raise SceneError(f"group '{group.name}' has no attraction region index '{key}' "
                         f"(has: {', '.join(regions) or 'none'})")
    return np.asarray(regions[key])


# --------------------------------------------------------------------------- operators
class Operator:
    """What every operator has: a ``kind`` (the paper's name), conditions ``when``, a label."""

    kind: ClassVar[str] = ""
    #: True for operators acting between pairs of particles (collide, bind, attract)
    pair: ClassVar[bool] = False
    fixed_pairs: ClassVar[bool] = False
    when: tuple = ()

    def label(self) -> str:
        """How the operator is named in messages and deck comments, e.g. ``dampen(1)``."""
        raise NotImplementedError

    def _when(self) -> str:
        return f" when {' and '.join(c.label() for c in self.when)}" if self.when else ""

    def damping(self, holds: bool) -> float:
        """The velocity coefficient γ this operator adds (a ≈ −γ·v; only dampen has one)."""
        return 0.0

    def with_dt(self, dt: float):
        """The operator at the time step ``dt`` (one that counts its own steps: :class:`Indent`)."""
        return self

    def check(self, target: str, groups: Mapping) -> None:
        """Validate against the scene's groups; raise :class:`SceneError` naming what is wrong."""
        for cond in self.when:
            if isinstance(cond, Contact) and cond.group not in groups:
                raise SceneError(f"operator {self.kind} on '{target}': contact condition names "
                                 f"unknown group '{cond.group}'")


@dataclass(frozen=True)
class Force(Operator):
    """force(â), Eq. 8: a constant acceleration ``accel`` on the particles selected by ``where``.

    ``where`` is None (all) or a boolean mask over the target group, e.g. Eq. 15's
    ⟨‖o‖² < 10⟩ (:func:`norm2_below`).

    Examples
    --------
    >>> Force((0.0, 100.0, 0.0), where=(True, False)).label()
    'force((0.0, 100.0, 0.0), 1 selected)'
    """

    accel: tuple
    where: tuple | None = None
    when: tuple = ()

    kind: ClassVar[str] = "force"

    def label(self) -> str:
        sel = "all" if self.where is None else f"{int(np.sum(self.where))} selected"
        return f"force({tuple(self.accel)}, {sel})" + self._when()

    def check(self, target, groups) -> None:
        super().check(target, groups)
        where = f"operator force on '{target}'"
        if len(self.accel) != 3 or not np.all(np.isfinite(self.accel)):
            raise SceneError(f"{where}: accel must be three finite numbers, got {self.accel!r}")
        if self.where is not None and len(self.where) != groups[target].n:
            raise SceneError(f"{where}: mask has {len(self.where)} entries for "
                             f"{groups[target].n} particles")

    def mask(self, n: int) -> np.ndarray:
        """The selected particles of a target group of n (all when ``where`` is None)."""
        return np.ones(n, bool) if self.where is None else np.asarray(self.where, dtype=bool)

    def vector(self) -> np.ndarray:
        """â (Eq. 8) as a float array."""
        return np.asarray(self.accel, dtype=float)


def norm2_below(o: np.ndarray, limit: float) -> tuple:
    """Eq. 15's selection ⟨‖o‖² < limit⟩ over original positions, as a ``Force.where`` mask."""
    o = np.asarray(o, dtype=float)
    return tuple(bool(m) for m in (o ** 2).sum(axis=1) < limit)


@dataclass(frozen=True)
class Dampen(Operator):
    """dampen(c), Eq. 9: −c·v; ``c + extra`` while every condition in ``when`` holds (Eq. 28).

    Examples
    --------
    >>> Dampen(10.0, 85.0, when=(PhaseIn("r", (2, 3)),)).coefficient(True)
    95.0
    """

    c: float
    extra: float = 0.0
    when: tuple = ()

    kind: ClassVar[str] = "dampen"

    def label(self) -> str:
        extra = (f" + {self.extra:g}<{', '.join(c.label() for c in self.when)}>"
                 if self.extra else "")
        return f"dampen({self.c:g}{extra})"

    def check(self, target, groups) -> None:
        super().check(target, groups)
        if not (np.isfinite(self.c) and np.isfinite(self.extra)):
            raise SceneError(f"operator dampen on '{target}': damping coefficients must be finite")

    def coefficient(self, holds: bool) -> float:
        """The damping coefficient now: c, plus ``extra`` when the conditions hold (Eq. 28)."""
        return self.c + (self.extra if (self.extra and holds) else 0.0)

    def damping(self, holds: bool) -> float:
        return self.coefficient(holds)

    @staticmethod
    def accel(v: np.ndarray, c: float) -> np.ndarray:
        """Eq. 9: −c·v."""
        return -c * v


class PairOperator(Operator):
    """An operator on a target group from a ``source`` group with a coefficient matrix ``coeff``.

    Its acceleration on i from j is ``c·factor(d², q)·(u − p)`` (u − p = the vector from i to
    j, d² its square length, q the per-pair parameter of the operator).
    """

    pair: ClassVar[bool] = True
    #: True when the pairs are fixed by the coefficient matrix (bind, attract: :meth:`pairs`),
    #: False when they are found by the contact search as the particles move (collide)
    fixed_pairs: ClassVar[bool] = True
    #: the coefficient structures the operator accepts
    coefficients: ClassVar[tuple] = (Const, Within, Matched)
    source: str
    coeff: Coefficient

    def label(self) -> str:
        return f"{self.kind}({self.source}, {self.coeff.label()})" + self._when()

    def check(self, target, groups) -> None:
        super().check(target, groups)
        where = f"operator {self.kind} on '{target}'"
        if self.source not in groups:
            raise SceneError(f"{where}: source group '{self.source}' does not exist "
                             f"(groups: {', '.join(groups)})")
        coeff = self.coeff
        if not isinstance(coeff, (Const, Within, Matched)):
            raise SceneError(f"{where}: unknown coefficient {coeff!r}")
        if not np.isfinite(coeff.c):
            raise SceneError(f"{where}: coefficient c must be finite, got {coeff.c!r}")
        if isinstance(coeff, Within) and not coeff.d > 0:
            raise SceneError(f"{where}: within(d) needs d > 0, got {coeff.d!r}")
        if isinstance(coeff, Matched) and Matched not in self.coefficients:
            raise SceneError(f"{where}: index-matched coefficients are for attract only")
        if not isinstance(coeff, self.coefficients):
            raise SceneError(f"{where}: {self.coefficient_rule(coeff)}")

    @classmethod
    def coefficient_rule(cls, coeff) -> str:
        """Why ``coeff`` is not a coefficient this operator takes."""
        return f"{cls.kind} takes {', '.join(c.__name__ for c in cls.coefficients)} coefficients"

    # the physics: subclasses define factor; accel and jacobian follow from it
    @staticmethod
    def factor(d2, q):
        """The scalar s of the acceleration c·s·(u − p) for squared distances d2."""
        raise NotImplementedError

    @classmethod
    def accel(cls, p: np.ndarray, u: np.ndarray, c, q=None) -> np.ndarray:
        """The acceleration kernel on i from j for arrays of pairs: c·factor(d², q)·(u − p)."""
        diff = u - p
        return (c * cls.factor(rowdot(diff, diff), q))[:, None] * diff

    def pairs(self, target, source, phase: Mapping | None = None) -> PairList:
        """The (i, j, c, q) of the coefficient matrix (group-local indices, sorted by i, j)."""
        raise NotImplementedError

    @staticmethod
    def _radial(diff: np.ndarray, c: np.ndarray, q: np.ndarray):
        """Jacobian blocks −∂a_p/∂p (n×3×3) of c·(u−p)·(1 − q/d²) and their 2-norms.

        With n = (u − p)/d: B = c·[(1 − q/d²)·(I − nnᵀ) + (1 + q/d²)·nnᵀ].
        """
        d2 = rowdot(diff, diff)
        n = diff / np.sqrt(d2)[:, None]
        nn = n[:, :, None] * n[:, None, :]
        ratio = q / d2
        alpha, beta = 1.0 - ratio, 1.0 + ratio
        B = c[:, None, None] * (alpha[:, None, None] * np.eye(3)[None]
                                + (beta - alpha)[:, None, None] * nn)
        return B, np.abs(c) * beta


@dataclass(frozen=True)
class Collide(PairOperator):
    """collide(u, ĉ), Eqs. 10–11: repulsion c(u−p)·min(0, 1 − R²/d²), R = p_r + u_r.

    The printed Eq. 10 squares the sum of two x coordinates; the prose (particles collide when
    "their distance is [not] greater than the sum of their radii") fixes it to the radii.
    ``q`` is R² per pair.

    Examples
    --------
    >>> import numpy as np
    >>> float(Collide.factor(np.array([2.25]), np.array([4.0]))[0])   # d 1.5, R 2
    -0.7777777777777777
    """

    source: str
    coeff: Coefficient
    when: tuple = ()
    #: Coulomb friction (``[[contact]] friction``): the coefficient μ, and η, the tangential
    #: damping per unit of this side's mass (ζ/m, ζ = γ_t·m_eff: :meth:`friction`); 0: none
    mu: float = 0.0
    eta: float = 0.0

    kind: ClassVar[str] = "collide"
    fixed_pairs: ClassVar[bool] = False
    coefficients: ClassVar[tuple] = (Const,)

    def label(self) -> str:
        fr = f" friction(mu={self.mu:g}, eta={self.eta:.6g})" if self.mu > 0 else ""
        return f"{self.kind}({self.source}, {self.coeff.label()}){fr}" + self._when()

    def check(self, target, groups) -> None:
        super().check(target, groups)
        if not (np.isfinite(self.mu) and self.mu >= 0 and np.isfinite(self.eta)
                and self.eta >= 0):
            raise SceneError(f"operator collide on '{target}': friction needs mu >= 0 and "
                             f"eta >= 0, got mu = {self.mu!r}, eta = {self.eta!r}")

    @staticmethod
    def friction(p, u, vp, vu, c, R2, mu, eta):
        """The regularized Coulomb friction of an overlapping pair on p from u, history-free
        (LAMMPS' pair gran/hooke, tangential linear_nohistory):

            a_t = −min(μ·a_n, η·‖v_t‖)·v_t/‖v_t‖,   a_n = c·(R² − d²)/d  (Eq. 10's magnitude),

        v_t the tangential part of v_p − v_u (across n = (u − p)/d). ``c``: per pair (arrays).

        Examples
        --------
        >>> import numpy as np
        >>> p, u = np.zeros((2, 3)), np.array([[0, -1.5, 0], [0, -1.5, 0]])
        >>> vp = np.array([[1e-3, 0, 0], [10.0, 0, 0]])        # slow: viscous; fast: Coulomb
        >>> a = Collide.friction(p, u, vp, np.zeros((2, 3)), np.full(2, 100.0), np.full(2, 4.0),
        ...                      0.5, 20.0)
        >>> [round(float(x), 6) for x in a[:, 0]], float(np.abs(a[:, 1:]).max())
        ([-0.02, -58.333333], 0.0)
        """
        diff = u - p
        d2 = rowdot(diff, diff)
        an = c * (R2 - d2) / np.sqrt(d2)
        w = vp - vu
        vt = w - (rowdot(w, diff) / d2)[:, None] * diff
        s = np.sqrt(rowdot(vt, vt))
        lim = mu * an
        slip = lim < eta * s
        k = np.full(len(s), float(eta))
        k[slip] = lim[slip] / s[slip]
        return -k[:, None] * vt

    @classmethod
    def coefficient_rule(cls, coeff) -> str:
        return ("collide takes a constant coefficient (its reach is the sum of the radii, "
                f"Eq. 10), not {type(coeff).__name__}")

    @staticmethod
    def factor(d2, q):
        """Eq. 10: min(0, 1 − R²/d²) (q = R², R the sum of the radii)."""
        return np.minimum(0.0, 1.0 - q / d2)

    @staticmethod
    def touching(d2, R2):
        """Eq. 10's support: the pair overlaps (d < R), so its col term is non-zero."""
        return d2 < R2

    @staticmethod
    def jacobian(diff: np.ndarray, c: np.ndarray, R2: np.ndarray):
        """Linearized Eq. 10 for overlapping pairs: Eq. 12's block with L0² → R²."""
        return PairOperator._radial(diff, c, R2)


def cache_of(store: dict, owner) -> dict:
    """``owner``'s entry of ``store`` (a dict by ``id(owner)``), dropped when ``owner`` is
    collected: a later object at the same address must not read the answers of the one before
    (another Solid's shape with the same positions), and a dead one's arrays are not kept."""
    import weakref

    k = id(owner)
    cache = store.get(k)
    if cache is None:
        cache = store[k] = {}
        weakref.finalize(owner, store.pop, k, None)
    return cache


#: the last pairs of each live bind coefficient (:func:`_remembered`, :func:`cache_of`)
_REMEMBERED: dict = {}


def _remembered(coeff, target, source, build) -> PairList:
    """``build(target, source)``, remembered while ``coeff`` (the bind operator's coefficient,
    which with the positions decides the pairs: every ``Bind`` made of it shares them) lives:
    one entry per coefficient, keyed by the groups' original positions (their bytes' digest)
    and whether the two are one group; its arrays read-only, so no caller changes what the
    next one gets."""
    import hashlib

    h = hashlib.sha1(np.ascontiguousarray(target.o, dtype=float).tobytes())
    if source is not target:
        h.update(b"|" + np.ascontiguousarray(source.o, dtype=float).tobytes())
    key = (h.hexdigest(), source is target)
    cache = cache_of(_REMEMBERED, coeff)
    if key not in cache:
        pl = build(target, source)
        for a in (pl.i, pl.j, pl.c, pl.q):
            if a is not None:
                a.setflags(write=False)
        cache.clear()
        cache[key] = pl
    return cache[key]


def forget_pairs() -> None:
    """Drop the remembered pairs (:func:`_remembered`): a run calls it once its engine holds
    what it steps with, so the pairs of a large part (32 bytes each, 18 per particle: 0.6 GB
    at 10⁶ particles) are not kept beside it."""
    _REMEMBERED.clear()


@dataclass(frozen=True)
class Bind(PairOperator):
    """bind(u, ĉ), Eqs. 12–13: c(u−p)(1 − L0²/d²) with L0 = ‖u_o − p_o‖ per pair (q = L0²).

    Examples
    --------
    >>> import numpy as np
    >>> Bind.accel(np.zeros((1, 3)), np.array([[4.0, 0, 0]]), 2.0, np.array([9.0]))
    array([[3.5, 0. , 0. ]])
    """

    source: str
    coeff: Coefficient
    when: tuple = ()

    kind: ClassVar[str] = "bind"
    coefficients: ClassVar[tuple] = (Const, Within)

    @staticmethod
    def factor(d2, q):
        """Eq. 12: 1 − L0²/d² (q = L0², the pair's original squared distance)."""
        return 1.0 - q / d2

    @staticmethod
    def jacobian(diff: np.ndarray, c: np.ndarray, L0sq: np.ndarray):
        """Linearized Eq. 12: c·[(1 − L0²/d²)(I − nnᵀ) + (1 + L0²/d²)nnᵀ] (2c·nnᵀ at rest)."""
        return PairOperator._radial(diff, c, L0sq)

    def pairs(self, target, source, phase: Mapping | None = None) -> PairList:
        """The bound pairs, from original positions only, with L0² per pair (Eqs. 12, 16).

        i indexes the target, j the source; a group bound to itself never pairs i with i.
        Remembered per coefficient and positions (:func:`_remembered`): a run asks for the
        same pairs up to seven times (the loaded faces' overhang, the memory estimate, the deck,
        the solver's problem and its volumetric terms, the engine's check), 2.5 s each at
        160,000 particles of a material solid. The arrays returned are read-only.
        """
        return _remembered(self.coeff, target, source, self._pairs)

    def _pairs(self, target, source) -> PairList:
        coeff = self.coeff
        if isinstance(coeff, Const):
            i, j = _all_pairs(target, source)
        else:
            from scipy.spatial import cKDTree
            # within(d) is a strict '<' (Eq. 16): query to d, then filter exactly.
            if target is source:        # each pair once (i < j), then both directions
                from rackstress.model.inside import lattice_pairs

                ij = lattice_pairs(target.o, coeff.d)   # a filled lattice: no tree needed
                if ij is not None:
                    i, j = ij
                else:
                    ij = cKDTree(target.o).query_pairs(coeff.d, output_type="ndarray")
                    i, j = ij[:, 0].astype(np.int64), ij[:, 1].astype(np.int64)
                    diff = target.o[j] - target.o[i]
                    keep = rowdot(diff, diff) < coeff.d * coeff.d
                    i, j = i[keep], j[keep]
                if isinstance(coeff, WithinInside):     # no binding across free space
                    keep = coeff.inside_pairs(target.o, i, j, name=target.name)
                    i, j = i[keep], j[keep]
                i, j = np.concatenate([i, j]), np.concatenate([j, i])
            else:
                sm = cKDTree(target.o).sparse_distance_matrix(cKDTree(source.o), coeff.d,
                                                              output_type="ndarray")
                keep = sm["v"] < coeff.d
                i, j = sm["i"][keep].astype(np.int64), sm["j"][keep].astype(np.int64)
                if isinstance(coeff, WithinInside):     # no binding across free space
                    keep = coeff.inside(target.o[i], source.o[j], name=target.name)
                    i, j = i[keep], j[keep]
        i, j = _sorted(i, j)
        from rackstress.model.inside import length_sq

        c = np.full(len(i), float(coeff.c))
        weights = getattr(coeff, "weights", None)      # a material solid's face compensation
        if weights is not None and target is source:
            c = c * weights(target.o, i, j)
        return PairList(i, j, c, length_sq(target.o, source.o, i, j))


@dataclass(frozen=True)
class Attract(PairOperator):
    """attract(u, ĉ), Eq. 14: c(u−p)/‖u−p‖ — constant magnitude c per pair, one-way.

    The prose calls the attraction linear in the distance; the formula (constant magnitude) is
    what is implemented.

    Examples
    --------
    >>> import numpy as np
    >>> Attract.accel(np.zeros((1, 3)), np.array([[3.0, 4.0, 0]]), 5.0)
    array([[3., 4., 0.]])
    """

    source: str
    coeff: Coefficient
    when: tuple = ()

    kind: ClassVar[str] = "attract"
    coefficients: ClassVar[tuple] = (Const, Matched)

    @classmethod
    def coefficient_rule(cls, coeff) -> str:
        return "attract takes a constant or index-matched coefficient"

    @staticmethod
    def factor(d2, q=None):
        """Eq. 14: 1/d."""
        return 1.0 / np.sqrt(d2)

    @staticmethod
    def jacobian(diff: np.ndarray, c: np.ndarray, q=None):
        """Linearized Eq. 14: (c/d)·(I − nnᵀ)."""
        d = np.sqrt(rowdot(diff, diff))
        n = diff / d[:, None]
        s = c / d
        return s[:, None, None] * (np.eye(3)[None] - n[:, :, None] * n[:, None, :]), np.abs(s)

    def pairs(self, target, source, phase: Mapping | None = None) -> PairList:
        """The attracting pairs in ``phase`` (Eqs. 14, 27–28: region names follow the phase)."""
        coeff = self.coeff
        if isinstance(coeff, Const):
            i, j = _all_pairs(target, source)
        else:
            ti = region_index(target, coeff.target, phase or {})
            sj = region_index(source, coeff.source, phase or {})
            i_list, j_list = [], []
            for value in np.unique(ti[ti != 0]):
                ii = np.flatnonzero(ti == value)
                jj = np.flatnonzero(sj == value)
                if len(jj):
                    a, b = np.meshgrid(ii, jj, indexing="ij")
                    i_list.append(a.ravel())
                    j_list.append(b.ravel())
            i = np.concatenate(i_list) if i_list else np.zeros(0, np.int64)
            j = np.concatenate(j_list) if j_list else np.zeros(0, np.int64)
            if target is source:  # a particle never attracts itself (0/0 in Eq. 14)
                keep = i != j
                i, j = i[keep], j[keep]
            i, j = _sorted(i, j)
        return PairList(i, j, np.full(len(i), float(coeff.c)))


@dataclass(frozen=True, eq=False)
class Indent(Operator):
    """A rigid sphere pressed on the target (``[[indenter]]``, beyond the paper): a linear
    penalty on each particle its surface reaches,

        a_p = k_p·g_p·(p − c)/‖p − c‖,   g_p = R + r_p − ‖p − c‖ > 0,

    k_p the particle's stiffness per unit of its mass (``k``, one per target particle; 0: the
    sphere does not act on it), r_p its radius (a particle of the top row sits half a spacing
    below the part's surface), c the sphere's centre: ``centre`` + ``travel``·min(n/``steps``, 1)
    at step n (the centre moves linearly over ``steps`` steps, then stays); ``steps`` = 0: at
    ``centre`` + ``travel`` from the start (a static analysis). One-sided: the sphere pushes,
    it does not pull.

    Examples
    --------
    >>> import numpy as np
    >>> op = Indent((0.0, 0.0, 10.0), 10.0, (2.0, 2.0), travel=(0.0, 0.0, -1.0), steps=4)
    >>> op.centre_at(2)
    array([0. , 0. , 9.5])
    >>> p = np.array([[0.0, 0.0, -0.25], [0.0, 5.0, -5.0]])
    >>> Indent.accel(p, np.full(2, 0.5), np.array(op.k), op.centre_at(4), op.radius)
    array([[ 0. ,  0. , -2.5],
           [ 0. ,  0. ,  0. ]])
    """

    centre: tuple
    radius: float
    k: tuple = field(repr=False)
    travel: tuple = (0.0, 0.0, 0.0)
    steps: int = 0
    when: tuple = ()
    #: the travel's time (the scene's load ramp), whose steps ``steps`` is at the scene's dt
    #: (:meth:`with_dt`); None: ``steps`` as given
    ramp: float | None = None
    #: the ramp's stairs (the scene's load ramp: its phases): ``steps`` is their steps' sum
    stairs: int = 1

    kind: ClassVar[str] = "indent"

    def with_dt(self, dt: float):
        if self.ramp is None:
            return self
        from dataclasses import replace

        # each stair round(T/dt) steps, as model.scene.steps_for makes a phase's (the ramp,
        # positive, checked where the scene was read)
        return replace(self, steps=max(1, self.stairs * int(round(self.ramp / self.stairs
                                                                   / float(dt)))))

    def label(self) -> str:
        c = ", ".join(f"{x:g}" for x in self.centre)
        t = ", ".join(f"{x:g}" for x in self.travel)
        return (f"indent(sphere ({c}) R {self.radius:g}, travel ({t}) over {self.steps} steps, "
                f"{int(np.count_nonzero(self.k))} particles)" + self._when())

    def check(self, target, groups) -> None:
        super().check(target, groups)
        where = f"operator indent on '{target}'"
        vals = np.r_[self.centre, self.travel, self.radius]
        if len(self.centre) != 3 or len(self.travel) != 3 or not np.all(np.isfinite(vals)):
            raise SceneError(f"{where}: centre and travel must be three finite numbers each")
        if not self.radius > 0:
            raise SceneError(f"{where}: the sphere's radius must be positive, got {self.radius!r}")
        if len(self.k) != groups[target].n or not np.all(np.asarray(self.k) >= 0):
            raise SceneError(f"{where}: needs a stiffness >= 0 per particle of '{target}'")
        if self.steps < 0:
            raise SceneError(f"{where}: steps must be >= 0, got {self.steps!r}")

    def centre_at(self, step: int) -> np.ndarray:
        """The sphere's centre at step ``step`` (the fraction as the plugin's rs/indent takes it)."""
        c, t = np.asarray(self.centre, float), np.asarray(self.travel, float)
        s = float(step)
        f = 1.0 if self.steps <= 0 or s >= self.steps else s / float(self.steps)
        return c + f * t

    @staticmethod
    def accel(p, r, k, centre, radius):
        """The acceleration of each particle p (radius r, stiffness k per unit mass) from the
        sphere at ``centre``: zero where it does not reach (or k = 0)."""
        d = p - np.asarray(centre, float)[None, :]
        dist = np.sqrt(rowdot(d, d))
        g = (radius + r) - dist
        on = (g > 0) & (k > 0)
        out = np.zeros_like(p)
        out[on] = (k[on] * g[on] / dist[on])[:, None] * d[on]
        return out


OPERATORS = (Force, Dampen, Collide, Bind, Attract)
PAIR_OPERATORS = (Collide, Bind, Attract)
OPERATOR_KINDS = {cls.kind: cls for cls in OPERATORS}
#: not an ``[[operator]]`` of a scene file: ``[[indenter]]`` makes it (scenes/physical.py)
OPERATOR_KINDS[Indent.kind] = Indent


def describe(op) -> str:
    """The operator as a reader holding the paper writes it (decks, stability messages)."""
    return op.label()


def check_operator(op, target: str, groups: Mapping) -> None:
    """Validate one operator against the scene's groups; raise :class:`SceneError` if wrong."""
    op.check(target, groups)


def rack_forces(host: str, bind: float = 0.5, damping: float = 1.0) -> list:
    """rackForces(host) of Eq. 23: a rack group bound back to its host, and damped.

    Examples
    --------
    >>> [op.label() for op in rack_forces("plane")]
    ['bind(plane, 0.5)', 'dampen(1)']
    """
    return [Bind(host, Const(float(bind))), Dampen(float(damping))]


def reverse_of(operators: Mapping, target: str, k: int):
    """The place ``(group, index)`` of the operator forming one reciprocal pair with
    ``operators[target][k]``: the same kind, from ``target`` on its source, with the same
    conditions and coefficient structure. None when there is none (a one-way operator).

    A group acting on itself is its own reverse (ĉ holds both (i, j) and (j, i)).
    """
    op = operators[target][k]
    if op.source == target:
        return (target, k)
    for m, other in enumerate(operators.get(op.source, [])):
        if (type(other) is type(op) and other.source == target and other.when == op.when
                and type(other.coeff) is type(op.coeff)
                and (not isinstance(op.coeff, Within) or other.coeff.d == op.coeff.d)
                and (not isinstance(op.coeff, WithinInside)    # the same shape (by value)
                     or repr(other.coeff.region) == repr(op.coeff.region))):
            return (op.source, m)
    return None


# --------------------------------------------------------------------------- contact search
def contact_candidates(xa: np.ndarray, xb: np.ndarray, cut: float, same: bool = False):
    """Row pairs (a, b) of two point sets closer than ``cut`` (all of them; cKDTree).

    The one contact search of every engine: candidates within reach (the sum of the largest
    radii, plus a skin for a Verlet list) are then measured by :meth:`Collide.touching`. Each
    side is first cut to the other's bounding box grown by ``cut`` (a leg meets a few hundred
    of the sediment's particles, not all). ``same``: xa and xb are one group; both orders of
    every pair are returned, never a particle with itself.
    """
    from scipy.spatial import cKDTree

    empty = np.zeros(0, np.int64)
    if same:
        if len(xa) < 2:
            return empty, empty
        p = cKDTree(xa).query_pairs(cut, output_type="ndarray")
        a, b = p[:, 0].astype(np.int64), p[:, 1].astype(np.int64)
        return np.concatenate([a, b]), np.concatenate([b, a])
    ia, ib = np.arange(len(xa)), np.arange(len(xb))
    for _ in range(2):
        if not len(ia) or not len(ib):
            break
        if len(ib) >= len(ia):
            lo, hi = bbox(xa)
            near = inside(xb, lo - cut, hi + cut)
            ib, xb = ib[near], xb[near]
        else:
            lo, hi = bbox(xb)
            near = inside(xa, lo - cut, hi + cut)
            ia, xa = ia[near], xa[near]
    if not len(ia) or not len(ib):
        return empty, empty
    sm = cKDTree(xa).sparse_distance_matrix(cKDTree(xb), cut, output_type="ndarray")
    return ia[sm["i"]].astype(np.int64), ib[sm["j"]].astype(np.int64)

