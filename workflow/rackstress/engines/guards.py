"""Guard rails: checks of a finished run that warn about scenes that did not do what they meant.

Both are warnings, not errors: the run is kept, each finding is printed and recorded in
``summary.json`` under ``warnings`` (a list of ``{"kind", "message", ...}``).

``force_on_rack``
    A ``force`` operator acts on a rack group (``kind = "rack"`` or ``rack = "<host>"``). Rack
    particles are a part's frame (Section 3.2, Eqs. 18–23): the host is bound to them with a
    large coefficient, so a force on them drags the whole part past anything it collides with
    (collisions act on the host, never on the rack). Put loads such as gravity on the host.

``pass_through``
    Particles of two colliding groups passed through each other. At step 0 the two groups are
    apart along some direction n (the one with the widest gap of: the axes, the line joining
    their centres, the line joining their closest particles). A group went through the other
    when its centre lies beyond the far side (along n) of the part of the other that is in its
    way — the other's particles within its extent across n; if none is, it went around. So a
    block that falls through a bracket's arm is caught as soon as its centre is below the arm,
    however far the rest of the bracket reaches. The collision (Eq. 10) was too weak for the
    speed, or the time step too large: raise the collision coefficient c, lower dt or the
    speed. Checked on the frames of ``trajectory.dump`` (at most :data:`MAX_FRAMES`, evenly
    spread, the last always), for every pair of groups with a ``collide`` between them,
    neither a rack, that were apart at step 0.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from rackstress.model.operators import Collide, Dampen, Force

#: Frames of a trajectory the pass-through check reads at most (evenly spread, last included).
MAX_FRAMES = 30


def is_rack(group) -> bool:
    return group.host is not None or group.kind == "rack"


def force_on_racks(scene) -> list[dict]:
    """A warning for every ``force`` operator on a rack group."""
    out = []
    for target, seq in scene.operators.items():
        g = scene.groups[target]
        if not is_rack(g):
            continue
        for op in seq:
            if isinstance(op, Force):
                n = g.n if op.where is None else int(np.sum(op.where))
                host = f" of '{g.host}'" if g.host else ""
                out.append({
                    "kind": "force_on_rack", "group": target, "accel": list(op.accel),
                    "message": (
                        f"an external force {tuple(op.accel)} acts on the {n} rack particle(s) "
                        f"of '{target}'{host}: rack particles are the part's frame (Section "
                        "3.2), and a force on them drags the whole part past what it collides "
                        "with (collisions act on the host, not on its rack). Put loads such as "
                        "gravity on the host group instead.")})
    return out


def colliding_pairs(scene) -> list[tuple[str, str]]:
    """Unordered pairs of different, non-rack groups with a ``collide`` between them."""
    pairs = []
    for target, seq in scene.operators.items():
        for op in seq:
            if isinstance(op, Collide) and op.source != target:
                a, b = sorted((target, op.source), key=list(scene.groups).index)
                if (a, b) not in pairs and not is_rack(scene.groups[a]) \
                        and not is_rack(scene.groups[b]):
                    pairs.append((a, b))
    return pairs


def _separation(pa, pb):
    """The direction n (from group a to group b) that separates them best at step 0 — the
    coordinate axes, the line joining their centres, and the line joining their closest
    particles are tried — as (n, gap), gap = min(pb·n) − max(pa·n); None if none separates."""
    from scipy.spatial import cKDTree

    d, j = cKDTree(pb).query(pa)
    i = int(np.argmin(d))
    cands = list(np.eye(3)) + list(-np.eye(3)) + [pb.mean(axis=0) - pa.mean(axis=0),
                                                   pb[j[i]] - pa[i]]
    best = None
    for n in cands:
        norm = np.linalg.norm(n)
        if not norm > 0:
            continue
        n = n / norm
        gap = (pb @ n).min() - (pa @ n).max()
        if gap > 0 and (best is None or gap > best[1]):
            best = (n, gap)
    return best


def _went_through(p_moving, p_obstacle, r_moving, n, across, proj=None, q_moving=None) -> bool:
    """Whether the moving group, on the +n side of the obstacle at step 0, has its centre
    beyond the obstacle's far side (along −n) of the part in its way: the obstacle particles
    inside the moving group's extent across n (radii included); none there means it went
    around, not through. ``proj``: the obstacle's projections (p_obstacle @ across,
    p_obstacle @ n) kept up to date by :class:`_Projected` (a resting sediment of a million
    particles is not projected again every frame); ``q_moving``: p_moving @ across, so kept."""
    qm = p_moving @ across if q_moving is None else q_moving
    qo, along = proj if proj is not None else (p_obstacle @ across, None)
    lo, hi = qm.min(axis=0) - r_moving, qm.max(axis=0) + r_moving
    in_way = np.all((qo >= lo) & (qo <= hi), axis=1)
    if not in_way.any():
        return False
    far = along[in_way] if along is not None else p_obstacle[in_way] @ n
    return float(p_moving.mean(axis=0) @ n) < float(far.min())


class _Projected:
    """A group's projections on (across, n) over the frames, re-projecting only the rows that
    moved since the frame before (a row's projection is a function of that row alone, so the
    values are those of projecting the whole group)."""

    def __init__(self, p0: np.ndarray, n: np.ndarray, across: np.ndarray):
        self.n, self.across = n, across
        self.p = p0.copy()
        self.q, self.s = p0 @ across, p0 @ n

    def at(self, p: np.ndarray) -> tuple:
        moved = np.flatnonzero((p != self.p).any(axis=1))
        if len(moved):
            pm = p[moved]
            self.p[moved] = pm
            self.q[moved], self.s[moved] = pm @ self.across, pm @ self.n
        return self.q, self.s


def pass_through(scene, frames) -> list[dict]:
    """Pairs of colliding groups that passed through each other (module doc), from
    ``frames``: an iterable of (step, positions in global order), the first at step 0."""
    pairs = colliding_pairs(scene)
    if not pairs:
        return []
    frames = iter(frames)
    try:
        _, p0 = next(frames)
    except StopIteration:
        return []
    setup = {}
    for a, b in pairs:
        sep = _separation(p0[scene.slice(a)], p0[scene.slice(b)])
        if sep is None:                       # not apart at step 0: cannot judge
            continue
        n = sep[0]
        u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        across = np.column_stack([u, np.cross(n, u)])
        setup[(a, b)] = (n, across, _Projected(p0[scene.slice(a)], -n, across),
                         _Projected(p0[scene.slice(b)], -n, across))
    found = {}
    for step, p in frames:
        for (a, b), (n, across, proj_a, proj_b) in setup.items():
            if (a, b) in found:
                continue
            pa, pb = p[scene.slice(a)], p[scene.slice(b)]
            if not (np.isfinite(pa).all() and np.isfinite(pb).all()):
                continue
            ra, rb = scene.groups[a].r.max(), scene.groups[b].r.max()
            # b (on a's +n side) through a, or a (on b's −n side) through b
            qa, sa = proj_a.at(pa)
            qb, sb = proj_b.at(pb)
            if _went_through(pb, pa, rb, n, across, (qa, -sa), qb):
                mover, obstacle = b, a
            elif _went_through(pa, pb, ra, -n, across, (qb, sb), qa):
                mover, obstacle = a, b
            else:
                continue
            found[(a, b)] = {
                "kind": "pass_through", "groups": [a, b], "step": int(step),
                "message": (
                    f"'{mover}' passed through '{obstacle}' by step {int(step)}, though they "
                    f"collide: the centre of '{mover}' is beyond the far side of the part of "
                    f"'{obstacle}' in its way. The collision (Eq. 10) did not stop it: raise "
                    f"its coefficient c, or lower dt (now {scene.dt:g}) or the speed.")}
    return list(found.values())


def dump_frames(path, o: np.ndarray, max_frames: int = MAX_FRAMES):
    """(step, positions sorted by atom id) of up to ``max_frames`` frames of a rackstress dump
    (:func:`rackstress.engines.dumpio.read_frames`: a particle a frame does not hold is at its
    original position ``o``), evenly spread, the first and the last always; a frame cut short
    at the end of the file (a killed run) is skipped."""
    from rackstress.engines.dumpio import read_frames

    path = Path(path)
    with open(path, "rb") as fh:
        k = sum(chunk.count(b"ITEM: TIMESTEP") for chunk in iter(lambda: fh.read(1 << 22), b""))
    if not k:
        return
    want = set(np.unique(np.linspace(0, k - 1, min(k, max_frames)).round().astype(int)).tolist())
    yield from read_frames(path, o, want)


def verlet_lag(scene, engine: str) -> list[dict]:
    """The verlet mode on LAMMPS folds each group's constant damping into the scene exactly,
    but a damping ``extra`` switched on by a condition (Eq. 28, MagPod's legs in contact) is
    applied with the velocity half a step old: first order in that term, so the run differs
    from the reference engine's verlet mode by O(t) (:mod:`rackstress.model.verlet`)."""
    if engine != "lammps" or getattr(scene, "integrator", "euler") != "verlet":
        return []
    lagged = sorted({target for target, seq in scene.operators.items() for op in seq
                     if isinstance(op, Dampen) and op.when and op.extra})
    if not lagged:
        return []
    return [{"kind": "verlet_lagged_damping", "groups": lagged,
             "message": f"the verlet mode on LAMMPS applies the conditional damping of "
                        f"{', '.join(repr(g) for g in lagged)} (Eq. 28) with the velocity half "
                        "a step old: first order in that term, so this run differs from the "
                        "reference engine's verlet mode by O(t) (on magpod-small up to 0.06 at "
                        "t = 0.0025, docs/benchmarks/accuracy.md); --engine reference "
                        "evaluates it exactly"}]


def check_run(scene, out, echo: bool = True, engine: str | None = None) -> list[dict]:
    """Every guard-rail warning of the finished run in directory ``out``.

    Parameters
    ----------
    scene : Scene
        The scene that ran.
    out : path
        Its run directory (``trajectory.dump`` is read for the pass-through check).
    echo : bool
        Print each warning to stderr.
    engine : str, optional
        The engine that ran it (``"lammps"``: the verlet mode's lagged damping is reported).

    Returns
    -------
    list of dict
        What ``summary.json`` records under ``warnings``: ``kind`` (``pass_through``,
        ``force_on_rack`` or ``verlet_lagged_damping``), ``message`` and the groups (and step)
        concerned.

    Example
    -------
    >>> check_run(scene, "runs/bracket")       # doctest: +SKIP
    []
    """
    from rackstress.scenes.physical import held_load_warnings

    found = force_on_racks(scene) + verlet_lag(scene, engine or "") + held_load_warnings(scene)
    dump = Path(out) / "trajectory.dump"
    if colliding_pairs(scene) and dump.exists():
        found += pass_through(scene, dump_frames(dump, scene.original_positions()))
    if echo:
        say(scene.name, found)
    return found


def say(name: str, found: list[dict]) -> None:
    """Print each guard-rail warning of scene ``name`` to stderr, one line each (what
    :func:`check_run` says, and ``rackstress run`` for warnings checked beside it)."""
    for w in found:
        print(f"rackstress: warning: {name}: {w['message']}", file=sys.stderr)
