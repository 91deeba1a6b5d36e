"""The paper's primitive operators (Section 2.3) as plain data, and their coefficient structures.

An operator acts on a target group and adds an acceleration to it (every particle has unit mass):

=========  ============================  ======================================================
operator   equation                      acceleration on particle p (from particle u)
=========  ============================  ======================================================
force      Eq. 8                         â_i
dampen     Eq. 9                         −c·v
collide    Eqs. 10–11 (erratum: radii)   c·(u−p)·min(0, 1 − (u_r+p_r)²/‖u−p‖²)
bind       Eqs. 12–13                    c·(u−p)·(1 − ‖u_o−p_o‖²/‖u−p‖²)
attract    Eq. 14                        c·(u−p)/‖u−p‖
=========  ============================  ======================================================

Coefficient "matrices" ĉ (m×n) are never stored densely: :class:`Const` (every pair),
:class:`Within` (pairs whose original distance is below d, Eq. 16) and :class:`Matched` (index-
matched attraction regions, Eqs. 27–28). Coefficients are *directed*: the operator on i from j
carries its own c; the reverse interaction, if any, is a separate operator on j.

Conditions make an operator conditional (the paper's ⟨P⟩, Eq. 4): :class:`PhaseIn` (the gait
phase) and :class:`Contact` (some particle of the target overlaps some particle of a group,
Eq. 28's damping). An operator applies only when all its conditions hold; :class:`Dampen` may
instead add ``extra`` to its base coefficient when its conditions hold (10 + 85⟨…⟩).

``integrate`` (Eq. 5) is not an operator of this list: it closes every step of every engine.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Union

import numpy as np

from rackstress.errors import SceneError


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


@dataclass(frozen=True)
class Contact:
    """⟨∃ i, j : ‖col(p_i, 1, group_j)‖ > 0⟩: some target particle overlaps a ``group`` particle."""

    group: str


Condition = Union[PhaseIn, Contact]


def phase_active(conditions, phase: Mapping) -> bool:
    """True when every phase condition holds (contact conditions are the engine's to check)."""
    return all(c.holds(phase) for c in conditions if isinstance(c, PhaseIn))


# --------------------------------------------------------------------------- coefficients
@dataclass(frozen=True)
class Const:
    """ĉ = [c] for every pair (i, j), i ≠ j when target and source are the same group."""

    c: float


@dataclass(frozen=True)
class Within:
    """within(d) of Eq. 16: c for pairs whose *original* distance is < d, never i = j."""

    d: float
    c: float


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


Coefficient = Union[Const, Within, Matched]


# --------------------------------------------------------------------------- operators
@dataclass(frozen=True)
class Force:
    """force(â), Eq. 8: a constant acceleration ``accel`` on the particles selected by ``where``.

    ``where`` is None (all) or a boolean mask over the target group, e.g. Eq. 15's
    ⟨‖o‖² < 10⟩.
    """

    accel: tuple
    where: tuple | None = None
    when: tuple = ()

    kind = "force"


@dataclass(frozen=True)
class Dampen:
    """dampen(c), Eq. 9: −c·v; ``c + extra`` while every condition in ``when`` holds (Eq. 28)."""

    c: float
    extra: float = 0.0
    when: tuple = ()

    kind = "dampen"


@dataclass(frozen=True)
class Collide:
    """collide(u, ĉ), Eqs. 10–11: repulsion c(u−p)·min(0, 1 − R²/d²), R = p_r + u_r."""

    source: str
    coeff: Coefficient
    when: tuple = ()

    kind = "collide"


@dataclass(frozen=True)
class Bind:
    """bind(u, ĉ), Eqs. 12–13: c(u−p)(1 − L0²/d²) with L0 = ‖u_o − p_o‖ per pair."""

    source: str
    coeff: Coefficient
    when: tuple = ()

    kind = "bind"


@dataclass(frozen=True)
class Attract:
    """attract(u, ĉ), Eq. 14: c(u−p)/‖u−p‖ — constant magnitude c per pair, one-way."""

    source: str
    coeff: Coefficient
    when: tuple = ()

    kind = "attract"


Operator = Union[Force, Dampen, Collide, Bind, Attract]
PAIR_OPERATORS = (Collide, Bind, Attract)
OPERATOR_KINDS = {cls.kind: cls for cls in (Force, Dampen, Collide, Bind, Attract)}


def check_operator(op, target: str, groups: Mapping) -> None:
    """Validate one operator against the scene's groups; raise :class:`SceneError` if wrong."""
    where = f"operator {op.kind} on '{target}'"
    for cond in op.when:
        if isinstance(cond, Contact) and cond.group not in groups:
            raise SceneError(f"{where}: contact condition names unknown group '{cond.group}'")
    if isinstance(op, Force):
        if len(op.accel) != 3 or not np.all(np.isfinite(op.accel)):
            raise SceneError(f"{where}: accel must be three finite numbers, got {op.accel!r}")
        if op.where is not None and len(op.where) != groups[target].n:
            raise SceneError(f"{where}: mask has {len(op.where)} entries for "
                             f"{groups[target].n} particles")
        return
    if isinstance(op, Dampen):
        if not (np.isfinite(op.c) and np.isfinite(op.extra)):
            raise SceneError(f"{where}: damping coefficients must be finite")
        return
    if op.source not in groups:
        raise SceneError(f"{where}: source group '{op.source}' does not exist "
                         f"(groups: {', '.join(groups)})")
    coeff = op.coeff
    if not isinstance(coeff, (Const, Within, Matched)):
        raise SceneError(f"{where}: unknown coefficient {coeff!r}")
    if not np.isfinite(coeff.c):
        raise SceneError(f"{where}: coefficient c must be finite, got {coeff.c!r}")
    if isinstance(coeff, Within) and not coeff.d > 0:
        raise SceneError(f"{where}: within(d) needs d > 0, got {coeff.d!r}")
    if isinstance(coeff, Matched) and not isinstance(op, Attract):
        raise SceneError(f"{where}: index-matched coefficients are for attract only")
    if isinstance(op, Collide) and not isinstance(coeff, Const):
        raise SceneError(f"{where}: collide takes a constant coefficient (its reach is the "
                         f"sum of the radii, Eq. 10), not {type(coeff).__name__}")
    if isinstance(op, Attract) and not isinstance(coeff, (Matched, Const)):
        raise SceneError(f"{where}: attract takes a constant or index-matched coefficient")


# --------------------------------------------------------------------------- pair lists
def bind_pairs(op: Bind, target, source) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (i, j, c) triples of a bind's coefficient matrix, from original positions only.

    i indexes the target, j the source; a group bound to itself never pairs i with i.
    """
    same = target is source
    coeff = op.coeff
    if isinstance(coeff, Const):
        i, j = np.meshgrid(np.arange(target.n), np.arange(source.n), indexing="ij")
        i, j = i.ravel(), j.ravel()
    elif isinstance(coeff, Within):
        from scipy.spatial import cKDTree
        # within(d) is a strict '<' (Eq. 16): query to d, then filter exactly.
        sm = cKDTree(target.o).sparse_distance_matrix(cKDTree(source.o), coeff.d,
                                                      output_type="ndarray")
        keep = sm["v"] < coeff.d
        i, j = sm["i"][keep].astype(np.int64), sm["j"][keep].astype(np.int64)
    else:  # pragma: no cover - check_operator rejects it
        raise SceneError(f"bind takes const or within coefficients, not {coeff!r}")
    if same:
        keep = i != j
        i, j = i[keep], j[keep]
    order = np.lexsort((j, i))
    i, j = i[order], j[order]
    return i, j, np.full(len(i), float(coeff.c))


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


def attract_pairs(op: Attract, target, source, phase: Mapping):
    """(i, j, c) of an attract's coefficient matrix in the given phase."""
    coeff = op.coeff
    if isinstance(coeff, Const):
        i, j = np.meshgrid(np.arange(target.n), np.arange(source.n), indexing="ij")
        i, j = i.ravel(), j.ravel()
        if target is source:
            keep = i != j
            i, j = i[keep], j[keep]
    else:
        ti = region_index(target, coeff.target, phase)
        sj = region_index(source, coeff.source, phase)
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
        order = np.lexsort((j, i))
        i, j = i[order], j[order]
    return i, j, np.full(len(i), float(coeff.c))


# --------------------------------------------------------------------------- labels
def describe(op) -> str:
    """The operator as a reader holding the paper writes it (decks, stability messages)."""
    if isinstance(op, Force):
        sel = "all" if op.where is None else f"{int(np.sum(op.where))} selected"
        return f"force({tuple(op.accel)}, {sel})" + _when(op)
    if isinstance(op, Dampen):
        extra = f" + {op.extra:g}<{', '.join(map(_cond, op.when))}>" if op.extra else ""
        return f"dampen({op.c:g}{extra})"
    coeff = op.coeff
    if isinstance(coeff, Within):
        c = f"within({coeff.d:g}) magnitude {coeff.c:g}"
    elif isinstance(coeff, Const):
        c = f"{coeff.c:g}"
    else:
        c = f"{coeff.c:g}<{coeff.target} = {coeff.source} != 0>"
    return f"{op.kind}({op.source}, {c})" + _when(op)


def _cond(c) -> str:
    if isinstance(c, PhaseIn):
        return f"{c.var} in {set(c.values)}"
    return f"contact {c.group}"


def _when(op) -> str:
    return f" when {' and '.join(map(_cond, op.when))}" if op.when else ""
