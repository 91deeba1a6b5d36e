"""A fingerprint of everything that determines a run's trajectory, for ``--resume`` to check.

A checkpoint continues a run only if the scene rebuilt for it is the scene the run started
with. Names and parameters are not enough (a TOML scene file can be edited between the kill and
the resume), so the fingerprint hashes what the engines compute from: every group's original
positions and radii (bytes), every operator with its coefficients and conditions (arrays by
their bytes), the schedule, the time step and the watchdog bound, and the run settings (engine,
mode, dump interval). Each part is hashed on its own, so a mismatch names what changed.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np

from rackstress.errors import ResumeError


def _feed(h, x) -> None:
    """Hash ``x`` structurally: arrays by dtype, shape and bytes; dataclasses field by field."""
    if isinstance(x, np.ndarray):
        h.update(f"nd{x.dtype.str}{x.shape}".encode())
        h.update(np.ascontiguousarray(x).tobytes())
    elif dataclasses.is_dataclass(x) and not isinstance(x, type):
        h.update(type(x).__name__.encode())
        for f in dataclasses.fields(x):
            h.update(f.name.encode())
            _feed(h, getattr(x, f.name))
    elif isinstance(x, dict):
        h.update(b"{")
        for k in sorted(x, key=str):
            h.update(str(k).encode())
            _feed(h, x[k])
        h.update(b"}")
    elif isinstance(x, (list, tuple)):
        h.update(b"[")
        for v in x:
            _feed(h, v)
        h.update(b"]")
    elif isinstance(x, (float, np.floating)):
        h.update(float(x).hex().encode())
    elif x is None or isinstance(x, (bool, int, str, np.integer, np.bool_)):
        h.update(repr(x).encode())
    elif callable(x):
        h.update(getattr(x, "__qualname__", type(x).__name__).encode())
    else:
        h.update(repr(x).encode())


def _digest(x) -> str:
    h = hashlib.sha256()
    _feed(h, x)
    return h.hexdigest()[:16]


def fingerprint(scene, *, engine: str, mode: str, dump_every: int) -> dict:
    """Per part, a short hash of what determines the trajectory of ``scene`` run this way.

    Examples
    --------
    >>> from rackstress import scenes
    >>> a = fingerprint(scenes.build("plane-bound", d=2), engine="lammps", mode="exact", dump_every=10)
    >>> b = fingerprint(scenes.build("plane-bound", d=10), engine="lammps", mode="exact", dump_every=10)
    >>> sorted(k for k in a if a[k] != b[k])
    ['operators:plane', 'params']
    """
    fp = {f"group:{name}": _digest([g.kind, g.host, g.o, g.r, getattr(g, "held", None),
                                    getattr(g, "v0", None)])
          for name, g in scene.groups.items()}
    fp.update({f"operators:{t}": _digest(list(seq)) for t, seq in scene.operators.items()})
    fp["schedule"] = _digest([[p.name, p.steps, dict(p.vars)] for p in scene.phases]
                             + [scene.cycles, scene.total_steps])
    fp["dt"] = float(scene.dt).hex()
    fp["integrator"] = str(getattr(scene, "integrator", "euler"))
    fp["bound"] = float(scene.bound).hex()
    # where a scene file lies is no part of the physics (its content is hashed above)
    fp["params"] = _digest({k: v for k, v in (scene.params or {}).items() if k != "file"})
    fp["engine"], fp["mode"], fp["dump_every"] = str(engine), str(mode), int(dump_every)
    return fp


def compare(recorded: dict, now: dict, where: str) -> None:
    """Raise :class:`ResumeError` naming every part that differs between two fingerprints."""
    if not recorded:
        raise ResumeError(f"{where} carries no fingerprint of the run it belongs to (written by an "
                          "older rackstress): it cannot be checked, so it is not resumed")
    keys = sorted(set(recorded) | set(now))
    changed = [k for k in keys if recorded.get(k) != now.get(k)]
    if changed:
        raise ResumeError(
            f"{where} belongs to a different run than the scene rebuilt to resume it: "
            f"{', '.join(_name(k) for k in changed)} changed since the run started. Resuming "
            "would join two different simulations in one trajectory; restore the scene as it "
            "was, or start again with --overwrite")


def _name(key: str) -> str:
    kind, _, rest = key.partition(":")
    if kind == "group":
        return f"group '{rest}' (positions, radii, supports or initial velocity)"
    if kind == "operators":
        return f"the operators on '{rest}'"
    return {"dt": "the time step dt", "params": "the scene parameters",
            "schedule": "the schedule (phases or steps)", "integrator": "the integrator", "bound": "the watchdog bound",
            "dump_every": "the dump interval"}.get(key, key)


def dumps(fp: dict) -> str:
    return json.dumps(fp, sort_keys=True)
