"""Guard rails: checks of a finished run that warn about scenes that did not do what they meant.

Both are warnings, not errors: the run is kept, each finding is printed and recorded in
``summary.json`` under ``warnings`` (a list of ``{"kind", "message", ...}``).

``force_on_rack``
    A ``force`` operator acts on a rack group (``kind = "rack"`` or ``rack = "<host>"``). Rack
    particles are a part's frame (Section 3.2, Eqs. 18–23): the host is bound to them with a
    large coefficient, so a force on them drags the whole part past anything it collides with
    (collisions act on the host, never on the rack). Put loads such as gravity on the host.

``pass_through``
    Particles of two colliding groups passed through each other: a group's centre of mass
    crossed the other's along the line that joined them at step 0, while the two groups still
    overlapped seen along that line (their extents across it intersect) — so it went through,
    not around. The collision (Eq. 10) is too weak for the speed, or the time step too large,
    to stop it: raise the collision coefficient c, lower dt or the speed. Checked on the
    frames of ``trajectory.dump`` (at most :data:`MAX_FRAMES`, evenly spread, the last always),
    for every pair of groups with a ``collide`` between them, neither a rack, that were apart
    along that line at step 0.
"""
from __future__ import annotations

import sys
from itertools import islice
from pathlib import Path

import numpy as np

from rackstress.model.operators import Collide, Force

#: Frames of a trajectory the pass-through check reads at most (evenly spread, last included).
MAX_FRAMES = 60


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
        pa, pb = p0[scene.slice(a)], p0[scene.slice(b)]
        d = pb.mean(axis=0) - pa.mean(axis=0)
        if not np.linalg.norm(d) > 0:
            continue
        n = d / np.linalg.norm(d)
        if not (pa @ n).max() < (pb @ n).min():     # not apart along the line: cannot judge
            continue
        u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        setup[(a, b)] = (n, np.column_stack([u, np.cross(n, u)]))
    found = {}
    for step, p in frames:
        for (a, b), (n, across) in setup.items():
            if (a, b) in found:
                continue
            pa, pb = p[scene.slice(a)], p[scene.slice(b)]
            if not (np.isfinite(pa).all() and np.isfinite(pb).all()):
                continue
            if (pb.mean(axis=0) - pa.mean(axis=0)) @ n >= 0:
                continue
            qa, qb = pa @ across, pb @ across
            if np.all(qa.max(axis=0) >= qb.min(axis=0)) and np.all(qb.max(axis=0) >= qa.min(axis=0)):
                found[(a, b)] = {
                    "kind": "pass_through", "groups": [a, b], "step": int(step),
                    "message": (
                        f"'{a}' and '{b}' collide, yet they passed through each other by step "
                        f"{int(step)}: the centre of '{a}' crossed the centre of '{b}' along "
                        f"the line joining them at step 0 while they still overlapped across "
                        "it. The collision (Eq. 10) did not stop them: raise its coefficient "
                        f"c, or lower dt (now {scene.dt:g}) or the speed.")}
    return list(found.values())


def dump_frames(path, n_atoms: int, max_frames: int = MAX_FRAMES):
    """(step, positions sorted by atom id) of up to ``max_frames`` frames of a rackstress dump
    (``id type mol x y z``), evenly spread, the first and the last always; a frame cut short
    at the end of the file (a killed run) is skipped."""
    path = Path(path)
    steps = []
    with open(path, "rb") as fh:
        while True:
            head = list(islice(fh, 9))
            if len(head) < 9:
                break
            steps.append(int(head[1]))
            if sum(1 for _ in islice(fh, n_atoms)) < n_atoms:
                steps.pop()
                break
    if not steps:
        return
    k = len(steps)
    want = set(np.unique(np.linspace(0, k - 1, min(k, max_frames)).round().astype(int)).tolist())
    with open(path, "rb") as fh:
        for idx in range(k):
            head = list(islice(fh, 9))
            if idx not in want:
                for _ in islice(fh, n_atoms):
                    pass
                continue
            rows = np.array(b" ".join(islice(fh, n_atoms)).split(), dtype=float)
            rows = rows.reshape(n_atoms, -1)
            order = np.argsort(rows[:, 0], kind="stable")
            yield int(head[1]), rows[order, 3:6]


def check_run(scene, out, echo: bool = True) -> list[dict]:
    """Every guard-rail warning of the finished run in directory ``out`` (printed to stderr
    when ``echo``): what ``summary.json`` records under ``warnings``."""
    found = force_on_racks(scene)
    dump = Path(out) / "trajectory.dump"
    if colliding_pairs(scene) and dump.exists():
        found += pass_through(scene, dump_frames(dump, scene.n_particles))
    if echo:
        for w in found:
            print(f"rackstress: warning: {scene.name}: {w['message']}", file=sys.stderr)
    return found
