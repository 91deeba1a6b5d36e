"""Scenes from TOML files: a built-in scene with parameters, or an explicit scene.

Two forms (``rackstress run FILE.toml``; ``--set KEY=VALUE`` overrides win over the file):

(a) a built-in scene with parameters::

        scene = "plane-rack"
        [params]
        plane_bind = 100.0
        steps = 600

    Every key of ``[params]`` and every ``--set`` key must be a parameter of the built-in scene.

(b) an explicit scene, the paper's model written out::

        name = "two-blobs"
        dt = 0.01          # Eq. 5's t            (default 0.01)
        cycles = 1         # schedule repeats    (default 1)
        bound = 1e4        # watchdog distance   (default 1e4)
        steps = 300        # only without [[phase]] tables (default 1200)

        [[group]]          # a particle vector: exactly one of positions / lattice / rack
        name = "a"
        kind = "part"                                    # optional
        lattice = { shape = [3, 3, 3], spacing = 1.0, origin = [0, 0, 0] }
        # positions = [[0, 0, 0], [1, 0, 0]]
        radius = 0.5                                     # a number or one per particle
        regions = { areg = [0, 1, 2, ...] }              # optional attraction-region indices

        [[group]]
        name = "arack"
        rack = "a"         # rack(a) of Eq. 22; optional offset (default 5), radius (default 1)

        [[operator]]       # operators of a group, composed in file order (Eqs. 2-3)
        on = "a"
        op = "force"       # force | dampen | collide | bind | attract
        accel = [1, 0, 0]
        where = { norm2_lt = 10 }      # or { ids = [0, 4] }; optional
        when = { r = [2, 3] }          # optional: PhaseIn conditions
        contact = "sediment"           # optional: Contact condition

        # dampen: c, extra (c + extra while the conditions hold, Eq. 28)
        # collide / bind / attract: from, c; bind: within = d (Eq. 16);
        # attract: match = ["aregion", "breg{r}"] (index-matched regions, Eqs. 27-28)

        [[phase]]          # optional; default one phase "run" of ``steps`` iterations
        name = "4-6"
        steps = 1200
        vars = { r = 4, l = 6 }

    ``--set`` may give ``dt``, ``steps``, ``cycles`` and ``bound``. With ``[[phase]]`` tables,
    ``steps`` is the total number of iterations (the schedule repeated or cut short).

Every problem is a :class:`SceneError` whose message names the file and the table and field.
"""
from __future__ import annotations

import math
import re
import string

import numpy as np

from rackstress.model import operators as ops_mod
from rackstress.lib.toml import tomllib
from rackstress.errors import SceneError
from rackstress.model.operators import (Attract, Bind, Collide, Const, Contact, Dampen, Force, Matched, PhaseIn,
                        Within)
from rackstress.model.particles import RACK_OFFSET, RACK_RADIUS, Group, lattice, rack
from rackstress.model.scene import Phase, Scene

#: Defaults of an explicit scene's top-level settings.
DEFAULTS = {"dt": 0.01, "cycles": 1, "bound": 1.0e4, "steps": 1200}
#: Keys ``--set`` may override in an explicit scene.
OVERRIDABLE = ("dt", "steps", "cycles", "bound")

_TOP_KEYS = ("name", "dt", "cycles", "bound", "steps", "group", "operator", "phase")
_BUILTIN_KEYS = ("scene", "params")
_GROUP_KEYS = ("name", "kind", "positions", "lattice", "rack", "radius", "offset", "regions")
_LATTICE_KEYS = ("shape", "spacing", "origin")
_PHASE_KEYS = ("name", "steps", "vars")
_COMMON_OP_KEYS = ("on", "op", "when", "contact")
_OP_KEYS = {
    "force": ("accel", "where"),
    "dampen": ("c", "extra"),
    "collide": ("from", "c"),
    "bind": ("from", "c", "within"),
    "attract": ("from", "c", "match"),
}


# --------------------------------------------------------------------------- field checks
class _Ctx:
    """Where we are in the file, for messages: ``file: [[group]] 'a' (#2): radius: ...``."""

    def __init__(self, file: str, where: str = ""):
        self.file, self.where = file, where

    def at(self, where: str) -> "_Ctx":
        return _Ctx(self.file, where)

    def error(self, msg: str, field: str | None = None) -> SceneError:
        parts = [self.file]
        if self.where:
            parts.append(self.where)
        if field:
            parts.append(field)
        return SceneError(": ".join(parts) + ": " + msg)


def _describe(value) -> str:
    return f"{value!r} ({_type_name(value)})"


def _type_name(value) -> str:
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string",
            list: "an array", dict: "a table"}.get(type(value), type(value).__name__)


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _check_keys(ctx: _Ctx, table: dict, allowed, what: str = "key") -> None:
    unknown = [k for k in table if k not in allowed]
    if unknown:
        raise ctx.error(f"unknown {what} {', '.join(map(repr, unknown))}; allowed: "
                        f"{', '.join(allowed)}")


def _table(ctx: _Ctx, value, field: str) -> dict:
    if not isinstance(value, dict):
        raise ctx.error(f"must be a table, got {_describe(value)}", field)
    return value


def _string(ctx: _Ctx, value, field: str) -> str:
    if not isinstance(value, str) or not value:
        raise ctx.error(f"must be a non-empty string, got {_describe(value)}", field)
    return value


def _number(ctx: _Ctx, value, field: str, positive: bool = False) -> float:
    if not _is_number(value) or not math.isfinite(value):
        raise ctx.error(f"must be a finite number, got {_describe(value)}", field)
    if positive and not value > 0:
        raise ctx.error(f"must be positive, got {value!r}", field)
    return float(value)


def _integer(ctx: _Ctx, value, field: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ctx.error(f"must be an integer, got {_describe(value)}", field)
    if value < minimum:
        raise ctx.error(f"must be >= {minimum}, got {value!r}", field)
    return int(value)


def _vec3(ctx: _Ctx, value, field: str) -> tuple:
    if (not isinstance(value, list) or len(value) != 3
            or not all(_is_number(x) and math.isfinite(x) for x in value)):
        raise ctx.error(f"must be three finite numbers [x, y, z], got {value!r}", field)
    return tuple(float(x) for x in value)


def _require(ctx: _Ctx, table: dict, field: str):
    if field not in table:
        raise ctx.error(f"missing required field '{field}'")
    return table[field]


# --------------------------------------------------------------------------- entry point
def load_toml(path, overrides: dict | None = None) -> Scene:
    """The scene described by the TOML file ``path``, with ``--set`` ``overrides`` applied."""
    overrides = dict(overrides or {})
    file = str(path)
    ctx = _Ctx(file)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise SceneError(f"{file}: no such scene file") from None
    except IsADirectoryError:
        raise SceneError(f"{file}: is a directory, not a scene file") from None
    except OSError as exc:
        raise SceneError(f"{file}: cannot read the scene file: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise SceneError(f"{file}: is not UTF-8 text ({exc.reason} at byte {exc.start}); a TOML "
                         "file must be UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(_decode_message(file, exc)) from None

    if "scene" in data:
        return _load_builtin(ctx, data, overrides)
    return _load_explicit(ctx, data, overrides)


def _decode_message(file: str, exc) -> str:
    """'file: line L, column C: invalid TOML: <what>' from a TOMLDecodeError (3.11 or 3.14)."""
    text = str(exc)
    line, col = getattr(exc, "lineno", None), getattr(exc, "colno", None)
    what = getattr(exc, "msg", None)
    m = re.search(r"\s*\(at line (\d+), column (\d+)\)\s*$", text)
    if m:
        line = line or int(m.group(1))
        col = col or int(m.group(2))
        what = what or text[:m.start()]
    elif re.search(r"\(at end of document\)\s*$", text):
        what = what or re.sub(r"\s*\(at end of document\)\s*$", "", text)
        return f"{file}: at the end of the file: invalid TOML: {what}"
    what = what or text
    if line is None:
        return f"{file}: invalid TOML: {what}"
    return f"{file}: line {line}, column {col}: invalid TOML: {what}"


# --------------------------------------------------------------------------- form (a)
def _load_builtin(ctx: _Ctx, data: dict, overrides: dict) -> Scene:
    from rackstress.scenes import builtins as scenes

    _check_keys(ctx.at("top level"), data, _BUILTIN_KEYS,
                "key (a file naming a built-in scene takes only 'scene' and [params])")
    name = _string(ctx, data["scene"], "scene")
    if name not in scenes.BUILDERS:
        raise ctx.error(f"unknown built-in scene '{name}'; built-in scenes: "
                        f"{', '.join(scenes.BUILDERS)} (or describe the scene explicitly with "
                        "[[group]] and [[operator]] tables)", "scene")
    params = dict(_table(ctx, data.get("params", {}), "[params]"))
    known = scenes.parameters(name)
    listing = ", ".join(f"{k}={v!r}" for k, v in known.items())
    for source, table in (("[params]", params), ("--set", overrides)):
        for key in table:
            if key not in known:
                raise ctx.error(f"scene '{name}' has no parameter '{key}'; its parameters are: "
                                f"{listing}", source)
    merged = {**params, **overrides}
    try:
        return scenes.build(name, **merged)
    except SceneError as exc:
        raise SceneError(f"{ctx.file}: {exc}") from None


# --------------------------------------------------------------------------- form (b)
def _load_explicit(ctx: _Ctx, data: dict, overrides: dict) -> Scene:
    _check_keys(ctx.at("top level"), data, _TOP_KEYS)
    if "group" not in data:
        raise ctx.error("an explicit scene needs at least one [[group]] table (or name a "
                        "built-in scene with scene = \"...\")")
    name = _string(ctx, _require(ctx.at("top level"), data, "name"), "name")

    bad = [k for k in overrides if k not in OVERRIDABLE]
    if bad:
        raise ctx.error(f"cannot override {', '.join(map(repr, bad))} of an explicit scene; "
                        f"--set takes only {', '.join(OVERRIDABLE)} (edit the file for the rest)",
                        "--set")
    settings = {}
    for key in ("dt", "cycles", "bound", "steps"):
        if key in overrides:
            where, value = f"--set {key}", overrides[key]
        elif key in data:
            where, value = key, data[key]
        else:
            settings[key] = DEFAULTS[key]
            continue
        if key in ("cycles", "steps"):
            settings[key] = _integer(ctx, value, where, 1 if key == "cycles" else 0)
        else:
            settings[key] = _number(ctx, value, where, positive=True)

    groups = _groups(ctx, data["group"])
    phases = _phases(ctx, data, settings)
    operators = _operators(ctx, data.get("operator", []), groups, phases)

    params = {"file": ctx.file, "dt": settings["dt"], "cycles": settings["cycles"],
              "bound": settings["bound"]}
    try:
        scene = Scene(name, groups, operators, phases, dt=settings["dt"],
                      cycles=settings["cycles"], bound=settings["bound"], params=params)
        if "phase" not in data:
            scene.params["steps"] = settings["steps"]
        elif "steps" in overrides:
            if scene.steps_per_cycle == 0 and settings["steps"] > 0:
                raise ctx.error(f"cannot run {settings['steps']} steps: every [[phase]] has "
                                "steps = 0", "--set steps")
            scene = scene.with_steps(settings["steps"])
    except SceneError as exc:
        raise SceneError(f"{ctx.file}: {exc}") from None
    return scene


def _array_of_tables(ctx: _Ctx, value, table: str) -> list:
    if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
        raise ctx.error(f"must be an array of tables ([[{table}]] sections), got "
                        f"{_describe(value)}", f"[[{table}]]")
    return value


def _groups(ctx: _Ctx, value) -> dict:
    tables = _array_of_tables(ctx, value, "group")
    if not tables:
        raise ctx.error("an explicit scene needs at least one [[group]] table")
    names, gctx = [], []
    for k, t in enumerate(tables, 1):
        c = ctx.at(f"[[group]] #{k}")
        _check_keys(c, t, _GROUP_KEYS)
        name = _string(c, _require(c, t, "name"), "name")
        if name in names:
            raise c.error(f"group name '{name}' is used twice (groups: {', '.join(names)})",
                          "name")
        names.append(name)
        gctx.append(ctx.at(f"[[group]] #{k} '{name}'"))

    built: dict = {}
    # Plain groups first, then racks (a rack's host may come later in the file); the particle
    # order of the scene is the file order.
    for t, c in zip(tables, gctx):
        if "rack" not in t:
            built[t["name"]] = _plain_group(c, t)
    for t, c in zip(tables, gctx):
        if "rack" in t:
            built[t["name"]] = _rack_group(c, t, built, names)
    return {name: built[name] for name in names}


def _kind(c: _Ctx, t: dict, default: str) -> str:
    return _string(c, t["kind"], "kind") if "kind" in t else default


def _radii(c: _Ctx, value, n: int) -> np.ndarray:
    if _is_number(value):
        r = np.full(n, float(value))
    elif isinstance(value, list):
        if len(value) != n:
            raise c.error(f"has {len(value)} entries for {n} particles", "radius")
        for i, x in enumerate(value):
            if not _is_number(x):
                raise c.error(f"entry {i} must be a number, got {_describe(x)}", "radius")
        r = np.asarray(value, dtype=float)
    else:
        raise c.error(f"must be a number or an array of numbers, got {_describe(value)}",
                      "radius")
    bad = np.flatnonzero(~(np.isfinite(r) & (r > 0)))
    if len(bad):
        i = int(bad[0])
        which = "" if _is_number(value) else f"particle {i}: "
        raise c.error(f"{which}radius {float(r[i])!r} is not allowed; a radius must be a positive finite "
                      "number (the paper's r is in R+, Eq. 1)", "radius")
    return r


def _plain_group(c: _Ctx, t: dict) -> Group:
    has = [k for k in ("positions", "lattice") if k in t]
    if len(has) != 1:
        raise c.error("needs exactly one of 'positions', 'lattice' or 'rack'"
                      + (f" (got {' and '.join(has)})" if has else ""))
    if "offset" in t:
        raise c.error("'offset' is for rack groups (rack = \"<host>\") only", "offset")
    if "positions" in t:
        pos = t["positions"]
        if not isinstance(pos, list) or not pos:
            raise c.error(f"must be a non-empty array of [x, y, z], got {_describe(pos)}",
                          "positions")
        o = np.array([_vec3(c, p, f"positions[{i}]") for i, p in enumerate(pos)], dtype=float)
    else:
        lat = _table(c, t["lattice"], "lattice")
        lc = c.at(f"{c.where}: lattice")
        _check_keys(lc, lat, _LATTICE_KEYS)
        shape = _require(lc, lat, "shape")
        if not isinstance(shape, list) or len(shape) != 3:
            raise lc.error(f"must be [nx, ny, nz], got {shape!r}", "shape")
        shape = [_integer(lc, s, "shape", 1) for s in shape]
        spacing = _number(lc, lat.get("spacing", 1.0), "spacing", positive=True)
        origin = _vec3(lc, lat.get("origin", [0.0, 0.0, 0.0]), "origin")
        o = lattice(shape, spacing, origin)
    r = _radii(c, _require(c, t, "radius"), len(o))
    g = _wrap(c, lambda: Group(t["name"], o, r, kind=_kind(c, t, "part")))
    _regions(c, t, g)
    return g


def _rack_group(c: _Ctx, t: dict, built: dict, names: list) -> Group:
    for other in ("positions", "lattice"):
        if other in t:
            raise c.error(f"a rack group takes no '{other}': its particles are placed by "
                          "rack(host), Eqs. 18-22")
    host = _string(c, t["rack"], "rack")
    if host not in names:
        raise c.error(f"host group '{host}' does not exist (groups: {', '.join(names)})", "rack")
    if host not in built:
        raise c.error(f"host group '{host}' is itself a rack group; a rack's host must be a "
                      "group with positions or a lattice", "rack")
    offset = _number(c, t.get("offset", RACK_OFFSET), "offset")
    if offset < 0:
        raise c.error(f"must be >= 0, got {offset!r}", "offset")
    radius = RACK_RADIUS
    if "radius" in t:
        if not _is_number(t["radius"]):
            raise c.error(f"a rack radius must be one number, got {_describe(t['radius'])}",
                          "radius")
        radius = float(_radii(c, t["radius"], 6)[0])
    g = _wrap(c, lambda: rack(built[host], t["name"], offset=offset, radius=radius))
    g.kind = _kind(c, t, "rack")
    _regions(c, t, g)
    return g


def _regions(c: _Ctx, t: dict, g: Group) -> None:
    if "regions" not in t:
        return
    regions = _table(c, t["regions"], "regions")
    out = {}
    for key, idx in regions.items():
        field = f"regions.{key}"
        if (not isinstance(idx, list)
                or not all(isinstance(x, int) and not isinstance(x, bool) for x in idx)):
            raise c.error(f"must be an array of integers (0 = not in the region), got "
                          f"{_describe(idx)}", field)
        if len(idx) != g.n:
            raise c.error(f"has {len(idx)} entries for the group's {g.n} particles", field)
        out[key] = np.asarray(idx, dtype=np.int64)
    g.meta["regions"] = out


def _wrap(c: _Ctx, make):
    try:
        return make()
    except SceneError as exc:
        raise c.error(str(exc)) from None


def _phases(ctx: _Ctx, data: dict, settings: dict) -> list:
    if "phase" not in data:
        return [Phase("run", settings["steps"], {})]
    if "steps" in data:
        raise ctx.error("top-level 'steps' cannot be combined with [[phase]] tables: each "
                        "phase sets its own steps (--set steps=N runs N iterations in all)",
                        "steps")
    tables = _array_of_tables(ctx, data["phase"], "phase")
    if not tables:
        raise ctx.error("[[phase]] is empty; give at least one phase or leave it out")
    phases, names = [], []
    for k, t in enumerate(tables, 1):
        c = ctx.at(f"[[phase]] #{k}")
        _check_keys(c, t, _PHASE_KEYS)
        name = _string(c, _require(c, t, "name"), "name")
        c = ctx.at(f"[[phase]] #{k} '{name}'")
        if name in names:
            raise c.error(f"phase name '{name}' is used twice", "name")
        names.append(name)
        steps = _integer(c, _require(c, t, "steps"), "steps", 0)
        pvars = dict(_table(c, t.get("vars", {}), "vars"))
        for key, val in pvars.items():
            if not (isinstance(val, (int, float, str, bool))):
                raise c.error(f"must be a number, string or boolean, got {_describe(val)}",
                              f"vars.{key}")
        phases.append(Phase(name, steps, pvars))
    return phases


def _operators(ctx: _Ctx, value, groups: dict, phases: list) -> dict:
    tables = _array_of_tables(ctx, value, "operator")
    out: dict = {}
    kinds = ", ".join(_OP_KEYS)
    for k, t in enumerate(tables, 1):
        c = ctx.at(f"[[operator]] #{k}")
        on = _string(c, _require(c, t, "on"), "on")
        c = ctx.at(f"[[operator]] #{k} (on '{on}')")
        if on not in groups:
            raise c.error(f"unknown group '{on}' (groups: {', '.join(groups)})", "on")
        kind = _string(c, _require(c, t, "op"), "op")
        if kind not in _OP_KEYS:
            raise c.error(f"unknown operator '{kind}'; known operators: {kinds}")
        _check_keys(c, t, _COMMON_OP_KEYS + _OP_KEYS[kind], f"key for {kind}")
        when = _conditions(c, t, groups, phases)
        op = _operator(c, kind, t, on, groups, when, phases)
        try:
            ops_mod.check_operator(op, on, groups)
        except SceneError as exc:
            raise c.error(str(exc)) from None
        out.setdefault(on, []).append(op)
    return {name: out[name] for name in groups if name in out}


def _conditions(c: _Ctx, t: dict, groups: dict, phases: list) -> tuple:
    conds = []
    if "when" in t:
        when = _table(c, t["when"], "when")
        if not when:
            raise c.error("is empty; give { var = [values] } or leave it out", "when")
        for var, values in when.items():
            field = f"when.{var}"
            if not isinstance(values, list):
                values = [values]
            if not values:
                raise c.error("has no values: the operator would never apply", field)
            for v in values:
                if not isinstance(v, (int, float, str, bool)):
                    raise c.error(f"values must be numbers, strings or booleans, got "
                                  f"{_describe(v)}", field)
            missing = [p.name for p in phases if var not in p.vars]
            if missing:
                raise c.error(f"phase variable '{var}' is not set by phase(s) "
                              f"{', '.join(map(repr, missing))} (set it in their vars)", field)
            conds.append(PhaseIn(var, tuple(values)))
    if "contact" in t:
        group = _string(c, t["contact"], "contact")
        if group not in groups:
            raise c.error(f"unknown group '{group}' (groups: {', '.join(groups)})", "contact")
        conds.append(Contact(group))
    return tuple(conds)


def _source(c: _Ctx, t: dict, groups: dict) -> str:
    src = _string(c, _require(c, t, "from"), "from")
    if src not in groups:
        raise c.error(f"unknown source group '{src}' (groups: {', '.join(groups)})", "from")
    return src


def _operator(c: _Ctx, kind: str, t: dict, on: str, groups: dict, when: tuple, phases: list):
    n = groups[on].n
    if kind == "force":
        accel = _vec3(c, _require(c, t, "accel"), "accel")
        where = None
        if "where" in t:
            w = _table(c, t["where"], "where")
            wc = c.at(f"{c.where}: where")
            _check_keys(wc, w, ("norm2_lt", "ids"))
            if len(w) != 1:
                raise c.error("needs exactly one of norm2_lt = value or ids = [...]", "where")
            if "norm2_lt" in w:
                lim = _number(wc, w["norm2_lt"], "norm2_lt")
                mask = (groups[on].o ** 2).sum(axis=1) < lim
            else:
                ids = w["ids"]
                if not isinstance(ids, list):
                    raise wc.error(f"must be an array of particle indices, got {_describe(ids)}",
                                   "ids")
                mask = np.zeros(n, dtype=bool)
                for i in ids:
                    if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < n:
                        raise wc.error(f"index {i!r} is not a particle of '{on}' (0..{n - 1})",
                                       "ids")
                    mask[i] = True
            where = tuple(bool(m) for m in mask)
        return Force(accel, where=where, when=when)
    if kind == "dampen":
        cc = _number(c, _require(c, t, "c"), "c")
        extra = _number(c, t.get("extra", 0.0), "extra")
        if when and extra == 0.0:
            raise c.error("a dampen's conditions (when/contact) gate only its 'extra' term "
                          "(c + extra while they hold, Eq. 28); give extra, or drop the "
                          "conditions", "when" if "when" in t else "contact")
        return Dampen(cc, extra=extra, when=when)
    src = _source(c, t, groups)
    cc = _number(c, _require(c, t, "c"), "c")
    if kind == "collide":
        return Collide(src, Const(cc), when=when)
    if kind == "bind":
        if "within" in t:
            return Bind(src, Within(_number(c, t["within"], "within", positive=True), cc),
                        when=when)
        return Bind(src, Const(cc), when=when)
    # attract
    if "match" not in t:
        return Attract(src, Const(cc), when=when)
    match = t["match"]
    if (not isinstance(match, list) or len(match) != 2
            or not all(isinstance(m, str) and m for m in match)):
        raise c.error(f"must be [\"<target region>\", \"<source region>\"], got {match!r}",
                      "match")
    coeff = Matched(match[0], match[1], cc)
    for name in match:
        try:
            fields = [f for _, f, _, _ in string.Formatter().parse(name) if f is not None]
        except ValueError as exc:
            raise c.error(f"region name '{name}' is malformed ({exc})", "match") from None
        for fld in fields:
            if not fld.isidentifier():
                raise c.error(f"region name '{name}' has a field {{{fld}}}; fields must be "
                              "phase variable names like {r}", "match")
    # Every phase in which the operator can apply must resolve both region names (catches
    # typos before the run starts).
    for phase in phases:
        if not ops_mod.phase_active(when, phase.vars):
            continue
        for gname, rname in ((on, match[0]), (src, match[1])):
            try:
                ops_mod.region_index(groups[gname], rname, phase.vars)
            except SceneError as exc:
                raise c.error(f"in phase '{phase.name}': {exc}", "match") from None
    return Attract(src, coeff, when=when)
