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
        # collide / bind / attract: from, c; bind: within = d (Eq. 16), inside = { region }
        #   (only pairs whose segment stays in the region: no binding across a notch);
        # attract: match = ["aregion", "breg{r}"] (index-matched regions, Eqs. 27-28)

        [[phase]]          # optional; default one phase "run" of ``steps`` iterations
        name = "4-6"
        steps = 1200
        vars = { r = 4, l = 6 }

    ``--set`` may give ``dt``, ``steps``, ``duration``, ``cycles``, ``bound`` and every name of
    the scene's own ``[params]``. With ``[[phase]]`` tables, ``steps`` is the total number of
    iterations (the schedule repeated or cut short).

    Beyond the paper's model: parts filled from meshes and shapes (``mesh``, ``fill``, ``parts``,
    ``spacing``, ``packing``), regions by shape wherever particles are selected (``where``,
    ``held``, ``regions``), supports (``held``), initial velocities (``velocity``), the scene's
    own ``[params]`` referred to as ``"$name"`` or ``"$(expression)"`` from any numeric field,
    and ``duration`` (physical time) instead of ``steps``. docs/scenes.md is the reference: every
    key, its type, default and meaning.

Every problem is a :class:`SceneError` whose message names the file and the table and field.

Example
-------
>>> from rackstress.scenes.toml import load_toml                  # doctest: +SKIP
>>> scene = load_toml("examples/bracket/scene.toml", {"speed": 8.0})   # doctest: +SKIP
"""
from __future__ import annotations

import ast
import contextvars
import math
import operator as _op
import re
import string
from pathlib import Path

import numpy as np

from rackstress.model import operators as ops_mod
from rackstress.lib.toml import tomllib
from rackstress.errors import SceneError
from rackstress.lib.suggest import did_you_mean
from rackstress.model.operators import (Attract, Bind, Collide, Const, Contact, Dampen, Force, Matched, PhaseIn,
                        Within)
from rackstress.model import regions as rg
from rackstress.model.particles import (PACKINGS, RACK_OFFSET, RACK_RADIUS, Group, fill,
                                        lattice, rack, union_positions)
from rackstress.model.scene import Phase, Scene, steps_for

#: Defaults of an explicit scene's top-level settings.
DEFAULTS = {"dt": 0.01, "cycles": 1, "bound": 1.0e4, "steps": 1200}
#: Keys ``--set`` may override in an explicit scene (besides the names of its ``[params]``).
OVERRIDABLE = ("dt", "steps", "duration", "cycles", "bound")
#: Of those, what a static analysis does not use (``rackstress scenes`` leaves them out)
STATIC_UNUSED = ("dt", "steps", "duration", "cycles")

_TOP_KEYS = ("name", "dt", "cycles", "bound", "steps", "duration", "params", "group",
             "operator", "phase", "units", "analysis", "load", "support", "budget", "contact",
             "indenter")
#: ``--set`` keys of every explicit scene besides OVERRIDABLE, unless its [params] has them:
#: ``spacing`` (every filled part's lattice spacing) and ``budget`` (the particles a part
#: whose spacing is chosen from its walls may have)
_SIZING = ("spacing", "budget")
#: ``--set`` keys of every explicit scene with material parts, unless its [params] has them:
#: ``poisson`` ("lattice" or "material"), the Poisson's ratio of every material part whose
#: table does not say (``rackstress bench parts --set poisson=material`` on the corpus)
_PART_DEFAULTS = ("poisson",)
_BUILTIN_KEYS = ("scene", "params")
#: How a plain group's particles are made: exactly one of these (or ``rack``).
_SOURCES = ("positions", "lattice", "mesh", "fill", "parts")
_GROUP_KEYS = ("name", "kind", "rack", "offset") + _SOURCES + (
    "spacing", "packing", "origin", "translate", "rotate", "scale", "radius", "regions", "held",
    "velocity", "material", "solid", "poisson", "bodies")
_LATTICE_KEYS = ("shape", "spacing", "origin")
_PHASE_KEYS = ("name", "steps", "duration", "vars")
#: Region shapes (docs/scenes.md "Regions"): the one key a region table names.
REGION_KEYS = ("box", "sphere", "cylinder", "plane", "mesh", "ids", "norm2_lt", "hole", "face",
               "union", "intersection", "difference")
#: keys that go with a mesh: its placement, and what a file of several bodies is (mesh.BODIES)
_MESH_PLACEMENT = ("translate", "rotate", "scale", "bodies")
_COMMON_OP_KEYS = ("on", "op", "when", "contact")
_OP_KEYS = {
    "force": ("accel", "where"),
    "dampen": ("c", "extra"),
    "collide": ("from", "c"),
    "bind": ("from", "c", "within", "inside"),
    "attract": ("from", "c", "match"),
}


# --------------------------------------------------------------------------- field checks
from rackstress.scenes.fields import (_Ctx, _array_of_tables, _check_keys, _describe, _hint,  # noqa: E402,F401
                                      _integer, _is_number, _number, _require, _string, _table,
                                      _type_name, _vec3)


# --------------------------------------------------------------------------- entry point
#: What every filled part's spacing is multiplied by while a scene file is read
#: (:func:`load_toml`'s ``spacing_scale``: ``rackstress run --refine``'s finer run).
_SPACING_SCALE = contextvars.ContextVar("spacing_scale", default=1.0)


#: The fractions of its spacing by which every filled part's lattice is moved while a scene
#: file is read (:func:`load_toml`'s ``lattice_shift``: ``rackstress run --offsets``).
_LATTICE_SHIFT = contextvars.ContextVar("lattice_shift", default=None)


#: The Poisson's ratio of a material part that does not say (``poisson``): :func:`load_toml`'s
#: ``poisson`` ("lattice" unless a caller, e.g. ``rackstress bench lattice``, asks otherwise).
_POISSON = contextvars.ContextVar("poisson", default="lattice")


def load_toml(path, overrides: dict | None = None, spacing_scale: float = 1.0,
              poisson: str | None = None, lattice_shift=None) -> Scene:
    """The scene described by the TOML file ``path``, with ``--set`` ``overrides`` applied;
    every part filled from a mesh or shape at its ``spacing`` × ``spacing_scale``
    (``rackstress run --refine``), recorded as the parameter ``spacing_scale``; ``poisson``
    ("lattice" or "material") for the material parts whose table does not say;
    ``lattice_shift`` (three fractions of a spacing, ``rackstress run --offsets``) moves every
    filled part's lattice by that much of its spacing, recorded as the parameter
    ``lattice_shift``."""
    if lattice_shift is not None:
        shift = [float(x) for x in lattice_shift]
        token = _LATTICE_SHIFT.set(shift)
        try:
            scene = load_toml(path, overrides, spacing_scale, poisson)
        finally:
            _LATTICE_SHIFT.reset(token)
        scene.params["lattice_shift"] = shift
        return scene
    if poisson is not None:
        token = _POISSON.set(poisson)
        try:
            return load_toml(path, overrides, spacing_scale)
        finally:
            _POISSON.reset(token)
    if spacing_scale != 1.0:
        base = _spacing_parameter(path, overrides)
        if base is not None:
            # the scene's own ``spacing`` parameter scaled, as ``--set spacing=…`` would set
            # it: every filled part takes it, and what the scene derives from it (a lattice
            # origin half a spacing off a symmetry plane) follows
            scene = load_toml(path, {**(overrides or {}), "spacing": base * spacing_scale})
            if "spacing" in scene.params:       # recorded as given, with the scale beside it
                scene.params["spacing"] = base  # (a resume rebuilds it the same way)
        else:
            token = _SPACING_SCALE.set(float(spacing_scale))
            try:
                scene = load_toml(path, overrides)
            finally:
                _SPACING_SCALE.reset(token)
        scene.params["spacing_scale"] = float(spacing_scale)
        return scene
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


def _spacing_parameter(path, overrides: dict | None) -> float | None:
    """The value of an explicit scene's ``spacing`` parameter (``--set`` or its [params]), or
    None when it has none (or the file does not read: the load that follows says why)."""
    if overrides and overrides.get("spacing") is not None:
        value = overrides["spacing"]
    else:
        try:
            with open(path, "rb") as fh:
                data = tomllib.load(fh)
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            return None
        if "scene" in data:
            return None
        value = (data.get("params") or {}).get("spacing")
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) \
        and value > 0 else None


def scene_parameters(path) -> dict:
    """The parameters ``--set`` takes for the scene file ``path``, with their defaults: a
    built-in scene's (its file's [params] applied), or an explicit scene's top-level settings
    and own [params] (``rackstress scenes FILE.toml``)."""
    from rackstress.scenes import builtins

    file = str(path)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{file}: cannot read the scene file: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(_decode_message(file, exc)) from None
    params = dict(data.get("params", {})) if isinstance(data.get("params", {}), dict) else {}
    if "scene" in data:
        name = data["scene"]
        if name not in builtins.BUILDERS:
            raise SceneError(f"{file}: scene: unknown built-in scene {name!r}")
        return {**builtins.parameters(name), **params}
    settings = {k: data.get(k, DEFAULTS.get(k)) for k in OVERRIDABLE}
    if "duration" in data and "steps" not in data:
        settings.pop("steps")          # the run's length is its duration
    groups = [g for g in data.get("group", []) if isinstance(g, dict)
              and any(k in g for k in ("mesh", "fill", "parts"))]
    if groups and "spacing" not in params:
        settings["spacing"] = next((g["spacing"] for g in groups if "spacing" in g),
                                   "chosen from the walls")
        if any("spacing" not in g and "mesh" in g for g in groups):
            from rackstress.scenes.features import BUDGET

            settings["budget"] = data.get("budget", BUDGET)
    if any("material" in g for g in data.get("group", []) if isinstance(g, dict)) \
            and "poisson" not in params:
        settings["poisson"] = "lattice"       # for the parts that do not say
    if data.get("analysis") == "static":
        for k in STATIC_UNUSED:        # an equilibrium has no time step, length or cycles
            settings.pop(k, None)
    return {**{k: v for k, v in settings.items() if v is not None}, **params}


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
        raise ctx.error(f"unknown built-in scene '{name}'{_hint(name, scenes.BUILDERS)}; "
                        f"built-in scenes: {', '.join(scenes.BUILDERS)} (or describe the scene "
                        "explicitly with "
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


# --------------------------------------------------------------------------- [params]
#: Names a scene's [params] may not take: they are the scene's top-level settings.
_RESERVED = OVERRIDABLE
_PARAM_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
#: Bounds on a parameter expression (a scene file is input from anyone: no expression may take
#: unbounded time or memory): its length, and the integers it makes (beyond, floats, which
#: overflow with a message instead of growing without end: "$(9**9**9**9)").
MAX_EXPRESSION, MAX_INT = 1000, 2**63


def _pow(a, b):
    """``a ** b`` in bounded time: integers only while the result stays below ``MAX_INT``."""
    if isinstance(a, int) and isinstance(b, int) and 0 <= b <= 64 and (
            a in (0, 1, -1) or abs(a).bit_length() * b <= 64):
        return a ** b
    out = float(a) ** float(b)          # OverflowError past 1e308, never a long computation
    if isinstance(out, complex):
        raise ValueError(f"{a!r} ** {b!r} is not a real number")
    return out


def _bounded(value):
    """An integer past ``MAX_INT`` becomes a float (OverflowError past 1e308)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= MAX_INT:
        return float(value)
    return value


_BINOPS = {ast.Add: _op.add, ast.Sub: _op.sub, ast.Mult: _op.mul, ast.Div: _op.truediv,
           ast.Pow: _pow, ast.Mod: _op.mod}
_UNOPS = {ast.USub: _op.neg, ast.UAdd: _op.pos}
_FUNCS = {"sqrt": math.sqrt, "sin": math.sin, "cos": math.cos, "tan": math.tan,
          "radians": math.radians, "abs": abs, "min": min, "max": max}


def _scene_params(ctx: _Ctx, data: dict, overrides: dict) -> tuple[dict, dict]:
    """(params, settings overrides): the file's [params] with --set applied, and the --set
    keys that are top-level settings."""
    table = dict(_table(ctx, data.get("params", {}), "[params]"))
    for key, value in table.items():
        if key in _RESERVED:
            raise ctx.error(f"'{key}' is a top-level setting of the scene, not a parameter: "
                            f"set {key} = ... at the top level (--set {key}=... works on it "
                            "as well)", f"[params] {key}")
        if not _PARAM_NAME.match(key):
            raise ctx.error("a parameter name must be letters, digits and _ (not starting "
                            "with a digit)", f"[params] {key}")
        if not isinstance(value, (int, float, str, bool)) or (
                _is_number(value) and not math.isfinite(value)):
            raise ctx.error(f"a parameter must be a finite number, a string or a boolean, got "
                            f"{_describe(value)}", f"[params] {key}")
        _plain_param(ctx, key, value, f"[params] {key}")
    settings = {}
    for key, value in overrides.items():
        if key in OVERRIDABLE:
            settings[key] = value
            continue
        if key in _SIZING + _PART_DEFAULTS and key not in table:
            settings[key] = value     # every filled part's spacing; the budget; material ν
            continue
        if key not in table:
            listing = ", ".join(f"{k}={v!r}" for k, v in table.items()) or "none"
            hint = did_you_mean(key, [*OVERRIDABLE, *_SIZING, *_PART_DEFAULTS, *table])
            raise ctx.error(f"the scene has no parameter '{key}'"
                            f"{' (' + hint + ')' if hint else ''}; --set takes "
                            f"{', '.join(OVERRIDABLE + _SIZING + _PART_DEFAULTS)} and the "
                            "scene's [params]: "
                            f"{listing}", "--set")
        default = table[key]
        if _is_number(default) and not _is_number(value):
            raise ctx.error(f"parameter {key} must be a number (its default is {default!r}), "
                            f"got {_describe(value)}", f"--set {key}")
        if isinstance(default, bool) and not isinstance(value, bool):
            raise ctx.error(f"parameter {key} must be true or false, got {_describe(value)}",
                            f"--set {key}")
        _plain_param(ctx, key, value, f"--set {key}")
        table[key] = value
    return table, settings


def _plain_param(ctx: _Ctx, key: str, value, where: str) -> None:
    """A parameter's value is a plain value: an expression or reference there (``"$(1/0)"``,
    ``"$nosuch"``, ``"$other"``: a cycle) would be evaluated nowhere, so it is refused here."""
    if isinstance(value, str) and value.lstrip().startswith("$"):
        raise ctx.error(f"parameter '{key}' is {value!r}, an expression or a reference; a "
                        "parameter's value must be a plain number, string or boolean (e.g. "
                        f"{key} = 2.5). Expressions belong in the fields that use parameters: "
                        f"write e.g. \"$({key} * 2)\" there, or compute the value here", where)


def _names_particles(region) -> bool:
    """Whether a region (or a part of a combination) selects particles by index (``ids``)."""
    from rackstress.model.regions import Ids

    return isinstance(region, Ids) or any(_names_particles(p)
                                          for p in getattr(region, "parts", ()))


def _evaluate(text: str, params: dict, where: str, ctx: _Ctx):
    """The value of a parameter reference: ``$name`` or ``$(expression)`` over [params]."""
    body = text[1:].strip()
    if len(body) > MAX_EXPRESSION:
        raise ctx.error(f"'{text[:40]}…' is {len(body)} characters long; a parameter expression "
                        f"may have at most {MAX_EXPRESSION}", where)
    if body.startswith("(") and body.endswith(")"):
        body = body[1:-1]
    elif not _PARAM_NAME.match(body):
        raise ctx.error(f"'{text}' is not a parameter reference; write \"$name\" or "
                        "\"$(expression)\", e.g. \"$(2 * height + 1)\"", where)
    try:
        tree = ast.parse(body, mode="eval")
    except (RecursionError, MemoryError):
        raise ctx.error(f"'{text[:40]}': the expression is nested too deeply", where) from None
    except SyntaxError:
        raise ctx.error(f"'{text}': the expression is not valid (use numbers, [params] names, "
                        "+ - * / ** %, parentheses and sqrt sin cos tan radians abs min max)",
                        where) from None

    def ev(node):
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Constant) and _is_number(node.value):
            return node.value
        if isinstance(node, ast.Name):
            if node.id in params:
                value = params[node.id]
                if node is not tree.body and not _is_number(value):
                    raise ctx.error(f"'{text}' computes with parameter '{node.id}', which is "
                                    f"{_describe(value)}, not a number", where)
                return value
            if node.id == "pi":
                return math.pi
            listing = ", ".join(params) or "none"
            hint = did_you_mean(node.id, params)
            raise ctx.error(f"'{text}' refers to '{node.id}', which is not in [params] "
                            f"({hint + ' ' if hint else ''}defined: {listing})", where)
        if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
            return _bounded(_BINOPS[type(node.op)](ev(node.left), ev(node.right)))
        if isinstance(node, ast.UnaryOp) and type(node.op) in _UNOPS:
            return _UNOPS[type(node.op)](ev(node.operand))
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and node.func.id in _FUNCS and not node.keywords):
            return _bounded(_FUNCS[node.func.id](*(ev(a) for a in node.args)))
        raise ctx.error(f"'{text}': {ast.unparse(node)!r} is not allowed in a parameter "
                        "expression (numbers, [params] names, + - * / ** %, parentheses, "
                        "sqrt sin cos tan radians abs min max)", where)

    try:
        value = ev(tree)
    except SceneError:
        raise                           # already names the file, field and reference
    except OverflowError:
        raise ctx.error(f"'{text}' cannot be evaluated: its value (or a step of it) is beyond "
                        "the largest number, about 1.8e308", where) from None
    except (ArithmeticError, TypeError, ValueError) as exc:
        raise ctx.error(f"'{text}' cannot be evaluated: {exc}", where) from None
    except (RecursionError, MemoryError):
        raise ctx.error(f"'{text[:40]}': the expression is nested too deeply", where) from None
    if isinstance(value, float) and not math.isfinite(value):
        raise ctx.error(f"'{text}' evaluates to {value!r}", where)
    return value


def _substitute(ctx: _Ctx, data, params: dict, path: str = ""):
    """``data`` with every string starting with ``$`` replaced by its parameter's value."""
    if isinstance(data, dict):
        return {k: _substitute(ctx, v, params, _join(path, k)) for k, v in data.items()}
    if isinstance(data, list):
        return [_substitute(ctx, v, params, f"{path}[{i}]") for i, v in enumerate(data)]
    if isinstance(data, str) and data.startswith("$"):
        return _evaluate(data, params, path or "value", ctx)
    return data


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


# --------------------------------------------------------------------------- form (b)
def _load_explicit(ctx: _Ctx, data: dict, overrides: dict) -> Scene:
    _check_keys(ctx.at("top level"), data, _TOP_KEYS)
    if "group" not in data:
        raise ctx.error("an explicit scene needs at least one [[group]] table (or name a "
                        "built-in scene with scene = \"...\")")
    user, set_settings = _scene_params(ctx, data, overrides)
    body = {k: v for k, v in data.items() if k != "params"}
    body = _substitute(ctx, body, user)
    set_settings = _substitute(ctx, set_settings, user, "--set")
    return _build_explicit(ctx, body, set_settings, user)


def _build_explicit(ctx: _Ctx, data: dict, overrides: dict, user: dict) -> Scene:
    name = _string(ctx, _require(ctx.at("top level"), data, "name"), "name")
    settings = {}
    for key in ("dt", "cycles", "bound", "steps", "duration"):
        if key in overrides:
            where, value = f"--set {key}", overrides[key]
        elif key in data:
            where, value = key, data[key]
        else:
            if key in DEFAULTS:
                settings[key] = DEFAULTS[key]
            continue
        if key in ("cycles", "steps"):
            settings[key] = _integer(ctx, value, where, 1 if key == "cycles" else 0)
        elif key == "duration":
            settings[key] = _number(ctx, value, where)
            if settings[key] < 0:
                raise ctx.error(f"must be >= 0, got {value!r}", where)
        else:
            settings[key] = _number(ctx, value, where, positive=True)
    if "steps" in data and "duration" in data:
        raise ctx.error("give steps (iterations) or duration (physical time), not both",
                        "duration")
    # the run's length: --set wins over the file; duration (time) or steps (iterations)
    if "duration" in overrides or ("duration" in data and "steps" not in overrides):
        length = ("duration", settings["duration"])
    elif "steps" in overrides or "steps" in data:
        length = ("steps", settings["steps"])
    else:
        length = None
    dt = settings["dt"]

    base = Path(ctx.file).resolve().parent
    from rackstress.scenes import physical

    unit_system = physical.scene_units(ctx, data)
    # --set poisson=…: every material part whose table does not say (a part's own
    # ``poisson`` wins, as over the default)
    poisson = overrides.get("poisson")
    if poisson is not None and poisson not in ("lattice", "material"):
        raise ctx.error(f"must be \"lattice\" (the bindings' own ν = 1/4) or \"material\" "
                        f"(the material's ν through the volumetric term, "
                        f"docs/calibration.md), got {_describe(poisson)}", "--set poisson")
    token = None if poisson is None else _POISSON.set(poisson)
    try:
        groups = _groups(ctx, data["group"], base, _sizing(ctx, data, overrides))
    finally:
        if token is not None:
            _POISSON.reset(token)
    if poisson is not None and not any(getattr(g, "material", None) for g in groups.values()):
        raise ctx.error("'poisson' chooses the Poisson's ratio of a material part's lattice, "
                        "and this scene has no [[group]] with a material", "--set poisson")
    physical.check_materials(ctx, groups, unit_system)
    region_of = lambda c, value, field, g=None: _region(c, value, field, base, g)  # noqa: E731
    select = lambda c, value, field, o, g=None: _mask(c, region_of(c, value, field, g), o, field)  # noqa: E731
    physical.supports(ctx, data.get("support", []), groups, select, region_of)
    indenter = data.get("indenter", [])
    ramp = physical.ramp_of(ctx, data.get("load", [])
                            + (indenter if isinstance(indenter, list) else []))
    if ramp is not None:
        settings["ramp"] = physical.ramp_phases(ctx, data, ramp, length, dt)
    phases = _phases(ctx, data, settings, length)
    operators = _operators(ctx, data.get("operator", []), groups, phases, base)
    operators = physical.solids(ctx, groups, operators, unit_system)
    operators = physical.loads(ctx, data.get("load", []), groups, operators, unit_system,
                               select, ramp)
    operators = physical.contacts(ctx, data.get("contact", []), groups, operators, unit_system)
    analysis = physical.analysis_of(ctx, data, groups, operators, ramp)
    if "indenter" in data:
        operators = physical.indenters(ctx, indenter, groups, operators, unit_system, ramp, dt,
                                       analysis)
    if analysis == "static" and any(getattr(op, "mu", 0.0) > 0 for seq in operators.values()
                                    for op in seq):
        raise ctx.error("friction acts on sliding parts in time (analysis = \"dynamic\"); a "
                        "static analysis solves frictionless contact: remove 'friction' or "
                        "declare analysis = \"dynamic\"", "[[contact]] friction")
    physical.check_constraints(ctx, groups, analysis)

    # --set spacing=…, budget=… and poisson=… are recorded with the scene's own parameters, so
    # that `rackstress fea` and a resume rebuild the part the run solved
    params = {"file": ctx.file, "dt": dt, "cycles": settings["cycles"],
              "bound": settings["bound"],
              **{k: overrides[k] for k in _SIZING + _PART_DEFAULTS
                 if overrides.get(k) is not None}, **user}
    try:
        scene = Scene(name, groups, operators, phases, dt=dt, cycles=settings["cycles"],
                      bound=settings["bound"], params=params, units=unit_system,
                      analysis=analysis)
        if analysis == "static":
            scene.params["analysis"] = "static"
        elif unit_system.physical and "dt" not in data and "dt" not in overrides:
            # physical time: a solid's bindings are stiff (ω ~ 10⁶/s for aluminium at 1 mm);
            # half the predicted stability limit of Eq. 5, durations kept
            from rackstress.model.stability import predict

            scene = scene.with_dt(0.5 * predict(scene)["t_max"])
        if "phase" not in data:
            if length and length[0] == "duration":
                scene.params["duration"] = length[1]
            scene.params["steps"] = phases[0].steps
        elif length is not None and (length[0] == "duration" or "steps" in overrides):
            total = length[1] if length[0] == "steps" else steps_for(length[1], dt)
            if scene.steps_per_cycle == 0 and total > 0:
                raise ctx.error(f"cannot run {total} steps: every [[phase]] has "
                                "steps = 0", f"--set {length[0]}" if length[0] in overrides
                                else length[0])
            scene = scene.with_steps(total)
            if length[0] == "duration":
                scene.duration = length[1]
                scene.params["duration"] = length[1]
    except SceneError as exc:
        raise SceneError(f"{ctx.file}: {exc}") from None
    return scene


def _groups(ctx: _Ctx, value, base: Path, sizing: dict | None = None) -> dict:
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
            built[t["name"]] = _plain_group(c, t, base, sizing)
    for t, c in zip(tables, gctx):
        if "rack" in t:
            built[t["name"]] = _rack_group(c, t, built, names, base)
    return {name: built[name] for name in names}


#: Group kinds (docs/scenes.md "kind"): ``rack`` and ``sediment`` change what the pictures, the
#: stress measures and the guard rails do with a group; the others are parts, named as the
#: built-in scenes name theirs.
KINDS = ("part", "rack", "sediment", "body", "leg", "plane")


def _kind(c: _Ctx, t: dict, default: str) -> str:
    if "kind" not in t:
        return default
    kind = _string(c, t["kind"], "kind")
    if kind not in KINDS:
        raise c.error(f"unknown kind '{kind}'{_hint(kind, KINDS)}; kinds: {', '.join(KINDS)} "
                      "(rack: not drawn, "
                      "no stress; sediment: drawn grey, footprints; the others: a part "
                      "coloured by its stress)", "kind")
    return kind


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


def _plain_group(c: _Ctx, t: dict, base: Path, sizing: dict | None = None) -> Group:
    sizing = sizing or {}
    has = [k for k in _SOURCES if k in t]
    if len(has) != 1:
        raise c.error(f"needs exactly one of {', '.join(map(repr, _SOURCES))} or 'rack'"
                      + (f" (got {' and '.join(has)})" if has else ""))
    if "offset" in t:
        raise c.error("'offset' is for rack groups (rack = \"<host>\") only", "offset")
    source = has[0]
    filled = source in ("mesh", "fill", "parts")
    overlap = None                   # sites a part in contact before it holds (_claim_sites)
    for key in ("spacing", "packing", "origin"):
        if key in t and not filled:
            raise c.error(f"'{key}' is for parts filled from a mesh or shape (mesh, fill, "
                          f"parts); a {source} sets its own particles", key)
    for key in _MESH_PLACEMENT:
        if key in t and source != "mesh":
            raise c.error(f"'{key}' places a group's mesh (mesh = \"file\"); inside fill or "
                          "parts give it next to each mesh", key)
    spacing, geometry = None, None
    if source == "positions":
        pos = t["positions"]
        if not isinstance(pos, list) or not pos:
            raise c.error(f"must be a non-empty array of [x, y, z], got {_describe(pos)}",
                          "positions")
        o = np.array([_vec3(c, p, f"positions[{i}]") for i, p in enumerate(pos)], dtype=float)
    elif source == "lattice":
        if _SPACING_SCALE.get() != 1.0 and "material" in t:
            raise c.error("a lattice = { shape, spacing } part cannot be refined (its particles "
                          "are counted by its shape); fill it from a box instead (fill = { box "
                          "= ... }) to run it with --refine", "lattice")
        o, spacing = _lattice(c, t["lattice"], "lattice")
        packing, shape = "cubic", None
    else:
        if sizing.get("spacing") is not None:        # --set spacing=... : every filled part
            spacing = _number(c, sizing["spacing"], "--set spacing", positive=True) \
                * _SPACING_SCALE.get()
        elif "spacing" in t:
            spacing = _number(c, t["spacing"], "spacing", positive=True) \
                * _SPACING_SCALE.get()
        elif source != "mesh":
            raise c.error("missing required field 'spacing' (a part filled from shapes needs "
                          "its lattice spacing; a part from one mesh gets one chosen from its "
                          "walls when it has none)")
        packing = t.get("packing", "cubic")
        if packing not in PACKINGS:
            raise c.error(f"must be one of {', '.join(PACKINGS)}, got {_describe(packing)}",
                          "packing")
        origin = _vec3(c, t["origin"], "origin") if "origin" in t else None
        solids, blocks = [], []
        if source == "mesh":
            solids.append(_region(c, {k: t[k] for k in ("mesh",) + _MESH_PLACEMENT if k in t},
                                  "mesh", base))
            spacing, geometry = _mesh_sizing(c, t, solids[0], spacing, sizing)
        elif source == "fill":
            solids.append(_region(c, t["fill"], "fill", base))
        else:
            parts = t["parts"]
            if not isinstance(parts, list) or not parts:
                raise c.error("must be a non-empty array of parts ({ mesh = ... }, { box = ... "
                              "}, { lattice = { ... } }, { positions = [...] }, ...)", "parts")
            for i, part in enumerate(parts):
                field = f"parts[{i}]"
                part = _table(c, part, field)
                if "lattice" in part:
                    _check_keys(c.at(f"{c.where}: {field}"), part, ("lattice",))
                    blocks.append(_lattice(c, part["lattice"], f"{field}.lattice")[0])
                elif "positions" in part:
                    _check_keys(c.at(f"{c.where}: {field}"), part, ("positions",))
                    pos = part["positions"]
                    if not isinstance(pos, list) or not pos:
                        raise c.error("must be a non-empty array of [x, y, z]",
                                      f"{field}.positions")
                    blocks.append(np.array([_vec3(c, p, f"{field}.positions[{j}]")
                                            for j, p in enumerate(pos)], dtype=float))
                else:
                    solids.append(_region(c, part, field, base))
        what = f"{c.file}: {c.where}"
        filled_o = []
        if solids:
            region = solids[0] if len(solids) == 1 else rg.Union(solids)
            names = [getattr(s, "name", None) for s in solids if isinstance(s, rg.Surface)]
            if names:
                what += f" (mesh {', '.join(names)})"
            own = origin
            origin = _shared_origin(t, spacing, packing, origin, sizing)
            # --offsets: every part's lattice moved by the same fractions of its spacing (a
            # part in contact on a shared lattice takes it as moved already)
            shift = _LATTICE_SHIFT.get() if origin is own else None
            try:
                filled_o = [fill(region, spacing, packing, origin, name=what, shift=shift)]
            except SceneError as exc:
                raise SceneError(str(exc)) from None
        o = union_positions(*filled_o, *blocks)
        if solids and not blocks:
            o, lost = _claim_sites(c, t["name"], o, spacing, packing, sizing)
            if lost:
                overlap = {"kind": "contact_overlap", "groups": [t["name"]], "sites": lost,
                           "message": f"part '{t['name']}': {lost} of its lattice sites lie "
                           "inside a part it is in contact with, filled before it, and are "
                           "that part's: the two are drawn overlapping (or share a face a "
                           "site lies on)"}
        shape = None if blocks or not solids else (solids[0] if len(solids) == 1
                                                    else rg.Union(solids))
    if "radius" in t:
        r = _radii(c, t["radius"], len(o))
    elif spacing is not None:
        r = np.full(len(o), spacing / 2.0)
    else:
        raise c.error("missing required field 'radius' (positions have no spacing to take "
                      "spacing/2 from)")
    held = _held(c, t, o, base, geometry)
    v0 = _vec3(c, t["velocity"], "velocity") if "velocity" in t else None
    g = _wrap(c, lambda: Group(t["name"], o, r, kind=_kind(c, t, "part"), held=held, v0=v0))
    if geometry is not None:
        g.meta["part"] = geometry
    if overlap:
        g.meta.setdefault("warnings", []).append(overlap)
    _regions(c, t, g, base)
    if source == "mesh":        # the part's own surface, placed: the report paints on it
        from dataclasses import asdict

        from rackstress.scenes.mesh import placement

        file = Path(t["mesh"]) if Path(t["mesh"]).is_absolute() else base / t["mesh"]
        g.meta["mesh"] = {"file": str(file.resolve()), **asdict(placement(
            *(t.get(k) for k in ("scale", "rotate", "translate"))))}
    if "poisson" in t and "material" not in t:
        raise c.error("'poisson' chooses the Poisson's ratio of a material part's lattice; "
                      "give the part a material", "poisson")
    if "material" in t or "solid" in t:
        if source == "positions":
            raise c.error("a material part is a filled lattice (mesh, fill, parts or lattice), "
                          "whose spacing sets each particle's volume; positions have none",
                          "material" if "material" in t else "solid")
        if "material" not in t:
            raise c.error("'solid' says whether a material part is bound as the elastic "
                          "lattice; give the part a material", "solid")
        from rackstress.model.materials import material

        try:
            g.material = material(t["material"])
        except SceneError as exc:
            raise c.error(str(exc), "material") from None
        if packing != "cubic":
            raise c.error("a material part is calibrated on the simple-cubic lattice "
                          "(docs/calibration.md): leave packing at \"cubic\"", "packing")
        g.volume = float(spacing) ** 3
        solid = t.get("solid", True)
        if not isinstance(solid, bool):
            raise c.error(f"must be true or false, got {_describe(solid)}", "solid")
        poisson = t.get("poisson", _POISSON.get())
        if poisson not in ("lattice", "material"):
            raise c.error(f"must be \"lattice\" (the bindings' own ν = 1/4, the default) or "
                          f"\"material\" (the material's ν through the volumetric term, "
                          f"docs/calibration.md), got {_describe(poisson)}", "poisson")
        g.meta["solid"] = {"spacing": float(spacing), "shape": shape, "bind": solid,
                           "poisson": poisson}
    return g


def _sizing(ctx: _Ctx, data: dict, overrides: dict) -> dict:
    """``--set spacing=...`` (every filled part's spacing) and the particle ``budget`` of a
    part whose spacing is chosen from its walls (top-level key, or ``--set budget=...``)."""
    from rackstress.scenes.features import BUDGET

    out = {"spacing": overrides.get("spacing"), "budget": BUDGET,
           "contact": _contact_names(data), "lattice": {}}
    for where, table in (("budget", data), ("--set budget", overrides)):
        if "budget" in table:
            out["budget"] = _integer(ctx, table["budget"], where, 1)
    return out


def _contact_names(data: dict) -> list:
    """The groups a ``[[contact]]`` table names, in file order (malformed tables are left to
    :func:`rackstress.scenes.physical.contacts`, which names the fault)."""
    out = []
    tables = data.get("contact", [])
    for t in tables if isinstance(tables, list) else []:
        between = t.get("between") if isinstance(t, dict) else None
        if isinstance(between, list):
            out += [b for b in between if isinstance(b, str) and b not in out]
    return out


def _shared_origin(t: dict, spacing, packing: str, origin, sizing: dict):
    """Parts in contact share one lattice: a part named in a ``[[contact]]`` that gives no
    ``origin`` is filled through the lattice of the first such part filled before it at the
    same spacing (cubic packing), so that no two of their particles start closer than a
    spacing — the contact's R — and flat faces that meet start touching at zero force.
    (Each part centred in its own box started a real plate's nearest particles 0.06 mm
    pressed into the base under it: the contact pushed with 7.7e5 N before any load.)"""
    shared = sizing.get("lattice") or {}
    if (origin is None and packing == "cubic" and t["name"] in sizing.get("contact", ())
            and shared.get("origin") is not None
            and abs(shared["spacing"] - spacing) <= 1e-9 * spacing):
        return shared["origin"]
    return origin


def _claim_sites(c: _Ctx, name: str, o: np.ndarray, spacing, packing: str, sizing: dict):
    """``o`` of a part in contact without the lattice sites an earlier part in contact holds
    (two parts drawn overlapping, or sharing a face a site lies on: the site is the earlier
    part's); the part's lattice recorded for those after it (:func:`_shared_origin`).
    Returns (o, how many sites it gave up)."""
    if name not in sizing.get("contact", ()) or packing != "cubic" or spacing is None \
            or not len(o):
        return o, 0
    shared = sizing.setdefault("lattice", {})
    if shared.get("origin") is None:
        shared.update(origin=[float(x) for x in o[0]], spacing=float(spacing), taken=[])
    lost = 0
    if shared["taken"] and abs(shared["spacing"] - spacing) <= 1e-9 * spacing:
        from scipy.spatial import cKDTree

        d, _ = cKDTree(np.concatenate(shared["taken"])).query(o)
        keep = d > 1e-6 * spacing
        lost = int((~keep).sum())
        if keep.sum() == 0:
            raise c.error(f"every particle of '{name}' lies where a part before it in contact "
                          "already has one: the two parts are drawn one inside the other")
        o = o[keep]
    shared["taken"].append(o)
    return o, lost


def _mesh_sizing(c: _Ctx, t: dict, surface, spacing, sizing: dict):
    """(spacing, the part's named-feature finder) of a part from one mesh: the spacing given,
    or one chosen from its walls within the particle budget
    (:func:`rackstress.scenes.features.choose_spacing`); its walls thinner than three
    spacings go into ``sizing["notes"]``, said by ``rackstress run``."""
    from rackstress.scenes import features as ft

    walls = ft.wall_thickness(surface)
    choice = None
    if spacing is None:
        choice = ft.choose_spacing(surface.volume, walls, sizing.get("budget", ft.BUDGET))
        spacing = choice["spacing"] * _SPACING_SCALE.get()      # --refine: spacing/√2
    geometry = ft.PartGeometry(surface, spacing)
    thin = walls.thinner_than(ft.ACROSS * spacing)
    if thin:           # named only when there is something to say (the features cost ~0.5 s)
        thin = walls.thinner_than(ft.ACROSS * spacing, geometry.features)
    geometry.choice, geometry.thin = choice, thin
    return spacing, geometry


def _lattice(c: _Ctx, value, field: str):
    lat = _table(c, value, field)
    lc = c.at(f"{c.where}: {field}")
    _check_keys(lc, lat, _LATTICE_KEYS)
    shape = _require(lc, lat, "shape")
    if not isinstance(shape, list) or len(shape) != 3:
        raise lc.error(f"must be [nx, ny, nz], got {shape!r}", "shape")
    shape = [_integer(lc, s, "shape", 1) for s in shape]
    spacing = _number(lc, lat.get("spacing", 1.0), "spacing", positive=True)
    origin = _vec3(lc, lat.get("origin", [0.0, 0.0, 0.0]), "origin")
    return _wrap(lc, lambda: lattice(shape, spacing, origin)), spacing


def _held(c: _Ctx, t: dict, o: np.ndarray, base: Path, geometry=None):
    if "held" not in t:
        return None
    region = _region(c, t["held"], "held", base, geometry)
    mask = _mask(c, region, o, "held")
    if not mask.any():
        raise c.error("selects no particle of the group: a support must hold at least one "
                      "(check the region against the group's positions)", "held")
    return mask


def _mask(c: _Ctx, region, o: np.ndarray, field: str) -> np.ndarray:
    try:
        return region.mask(o)
    except SceneError as exc:
        raise c.error(str(exc), field) from None


def _rack_group(c: _Ctx, t: dict, built: dict, names: list, base: Path) -> Group:
    for other in _SOURCES + ("spacing", "packing", "origin", "held") + _MESH_PLACEMENT:
        if other in t:
            raise c.error(f"a rack group takes no '{other}': its particles are placed by "
                          "rack(host), Eqs. 18-22")
    host = _string(c, t["rack"], "rack")
    if host not in names:
        raise c.error(f"host group '{host}' does not exist (groups: {', '.join(names)})", "rack")
    if host not in built:
        raise c.error(f"host group '{host}' is itself a rack group; a rack's host must be a "
                      "group with its own particles", "rack")
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
    # a rack moves with its part: it starts with the host's velocity when that is one vector
    hv = built[host].v0[~built[host].held]
    v0 = _vec3(c, t["velocity"], "velocity") if "velocity" in t else (
        hv[0] if len(hv) and np.all(hv == hv[0]) else None)
    if v0 is not None:
        g = _wrap(c, lambda: Group(g.name, g.o, g.r, g.kind, g.host, g.meta, None, v0))
    _regions(c, t, g, base)
    return g


def _regions(c: _Ctx, t: dict, g: Group, base: Path) -> None:
    if "regions" not in t:
        return
    regions = _table(c, t["regions"], "regions")
    out = {}
    for key, idx in regions.items():
        field = f"regions.{key}"
        if isinstance(idx, dict):                 # one shape: index 1 inside, 0 outside
            out[key] = _mask(c, _region(c, idx, field, base, g), g.o, field).astype(np.int64)
            continue
        if isinstance(idx, list) and idx and all(isinstance(x, dict) for x in idx):
            shapes = [_region(c, x, f"{field}[{i}]", base, g) for i, x in enumerate(idx)]
            try:
                out[key] = rg.index_vector(shapes, g.o)
            except SceneError as exc:
                raise c.error(str(exc), field) from None
            continue
        if (not isinstance(idx, list)
                or not all(isinstance(x, int) and not isinstance(x, bool) for x in idx)):
            raise c.error(f"must be an array of integers (0 = not in the region), a region "
                          f"table or an array of region tables, got {_describe(idx)}", field)
        if len(idx) != g.n:
            raise c.error(f"has {len(idx)} entries for the group's {g.n} particles", field)
        out[key] = np.asarray(idx, dtype=np.int64)
    g.meta["regions"] = out


# --------------------------------------------------------------------------- regions
def _region(c: _Ctx, value, field: str, base: Path, part=None):
    """A region (docs/scenes.md "Regions") from its table: exactly one shape key. ``part``:
    the group whose particles it selects (a named ``hole`` or ``face`` is its mesh's)."""
    t = _table(c, value, field)
    shape = [k for k in REGION_KEYS if k in t]
    if len(shape) != 1:
        raise c.error(f"a region needs exactly one of {', '.join(REGION_KEYS)}"
                      + (f" (got {' and '.join(shape)})" if shape else
                         f" (got {', '.join(map(repr, t)) or 'an empty table'})"), field)
    kind = shape[0]
    allowed = (kind,) + (_MESH_PLACEMENT if kind == "mesh" else ())
    _check_keys(c.at(f"{c.where}: {field}"), t, allowed, f"key for a {kind} region")
    v = t[kind]
    f = field if field == kind else f"{field}.{kind}"
    try:
        if kind == "box":
            b = _table(c, v, f)
            _check_keys(c.at(f"{c.where}: {f}"), b, ("min", "max"))
            return rg.Box(_vec3(c, _require(c.at(f"{c.where}: {f}"), b, "min"), f"{f}.min"),
                          _vec3(c, _require(c.at(f"{c.where}: {f}"), b, "max"), f"{f}.max"))
        if kind == "sphere":
            b = _table(c, v, f)
            _check_keys(c.at(f"{c.where}: {f}"), b, ("centre", "center", "radius"))
            centre = b.get("centre", b.get("center"))
            if centre is None:
                raise c.error("missing required field 'centre'", f)
            return rg.Sphere(_vec3(c, centre, f"{f}.centre"),
                             _number(c, _require(c.at(f"{c.where}: {f}"), b, "radius"),
                                     f"{f}.radius", positive=True))
        if kind == "cylinder":
            b = _table(c, v, f)
            _check_keys(c.at(f"{c.where}: {f}"), b, ("start", "end", "radius"))
            req = c.at(f"{c.where}: {f}")
            return rg.Cylinder(_vec3(c, _require(req, b, "start"), f"{f}.start"),
                               _vec3(c, _require(req, b, "end"), f"{f}.end"),
                               _number(c, _require(req, b, "radius"), f"{f}.radius",
                                       positive=True))
        if kind == "plane":
            b = _table(c, v, f)
            _check_keys(c.at(f"{c.where}: {f}"), b, ("point", "normal"))
            req = c.at(f"{c.where}: {f}")
            return rg.HalfSpace(_vec3(c, _require(req, b, "point"), f"{f}.point"),
                                _vec3(c, _require(req, b, "normal"), f"{f}.normal"))
        if kind == "norm2_lt":
            return rg.Norm2Below(_number(c, v, f))
        if kind in ("hole", "face"):
            geo = _part_geometry(part)
            if geo is None:
                what = f"group '{part.name}'" if part is not None else "this selection"
                raise c.error(f"a {kind} is named on a part's mesh (rackstress inspect FILE "
                              f"lists them); {what} is not made from one mesh (mesh = "
                              "\"file\"): select its particles by shape (box, cylinder, ...)", f)
            return geo.region(kind, v)
        if kind == "ids":
            if not isinstance(v, list):
                raise c.error(f"must be an array of particle indices, got {_describe(v)}", f)
            for i in v:
                if isinstance(i, bool) or not isinstance(i, int):
                    raise c.error(f"index {i!r} is not an integer", f)
            return rg.Ids(v)
        if kind == "mesh":
            from rackstress.scenes.mesh import BODIES, read_surface

            file = _string(c, v, f)
            scale = t.get("scale")
            if scale is not None and not (_is_number(scale) or isinstance(scale, list)):
                raise c.error(f"must be a number or [sx, sy, sz], got {_describe(scale)}",
                              f"{field}.scale")
            rot = _vec3(c, t["rotate"], f"{field}.rotate") if "rotate" in t else None
            tr = _vec3(c, t["translate"], f"{field}.translate") if "translate" in t else None
            bodies = t.get("bodies", "one")
            if bodies not in BODIES:
                raise c.error(f"must be one of {', '.join(map(repr, BODIES))} (\"united\": the "
                              f"union of the file's bodies is the part), got "
                              f"{_describe(bodies)}", "bodies" if field == kind else f"{field}.bodies")
            return read_surface(file, scale=scale, rotate=rot, translate=tr, base=base,
                                bodies=bodies)
        # union / intersection / difference
        if not isinstance(v, list) or not v:
            raise c.error(f"must be a non-empty array of region tables, got {_describe(v)}", f)
        parts = [_region(c, x, f"{f}[{i}]", base, part) for i, x in enumerate(v)]
        if kind == "difference" and len(parts) < 2:
            raise c.error("needs at least two regions: the first minus the others", f)
        return {"union": rg.Union, "intersection": rg.Intersection,
                "difference": rg.Difference}[kind](parts)
    except SceneError as exc:
        if str(exc).startswith(c.file):
            raise
        raise c.error(str(exc), f) from None


def _part_geometry(part):
    """The named-feature finder of a group made from one mesh (None otherwise): a built
    group's ``meta["part"]``, or the finder itself (a group's ``held``, before the group)."""
    if part is None:
        return None
    if hasattr(part, "region"):
        return part
    return (getattr(part, "meta", None) or {}).get("part")


def _wrap(c: _Ctx, make):
    try:
        return make()
    except SceneError as exc:
        raise c.error(str(exc)) from None


def _phases(ctx: _Ctx, data: dict, settings: dict, length) -> list:
    dt = settings["dt"]
    if "ramp" in settings:
        return settings["ramp"]
    if "phase" not in data:
        if length is not None and length[0] == "duration":
            return [Phase("run", steps_for(length[1], dt), {}, length[1])]
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
        if ("steps" in t) == ("duration" in t):
            raise c.error("needs exactly one of 'steps' (iterations) or 'duration' (physical time)")
        duration = None
        if "steps" in t:
            steps = _integer(c, t["steps"], "steps", 0)
        else:
            duration = _number(c, t["duration"], "duration")
            if duration < 0:
                raise c.error(f"must be >= 0, got {duration!r}", "duration")
            steps = steps_for(duration, dt)
        pvars = dict(_table(c, t.get("vars", {}), "vars"))
        for key, val in pvars.items():
            if not (isinstance(val, (int, float, str, bool))):
                raise c.error(f"must be a number, string or boolean, got {_describe(val)}",
                              f"vars.{key}")
        phases.append(Phase(name, steps, pvars, duration))
    return phases


def _operators(ctx: _Ctx, value, groups: dict, phases: list, base: Path) -> dict:
    tables = _array_of_tables(ctx, value, "operator")
    out: dict = {}
    kinds = ", ".join(_OP_KEYS)
    for k, t in enumerate(tables, 1):
        c = ctx.at(f"[[operator]] #{k}")
        on = _string(c, _require(c, t, "on"), "on")
        c = ctx.at(f"[[operator]] #{k} (on '{on}')")
        if on not in groups:
            raise c.error(f"unknown group '{on}'{_hint(on, groups)} (groups: "
                          f"{', '.join(groups)})", "on")
        kind = _string(c, _require(c, t, "op"), "op")
        if kind not in _OP_KEYS:
            raise c.error(f"unknown operator '{kind}'{_hint(kind, _OP_KEYS)}; known operators: "
                          f"{kinds}")
        _check_keys(c, t, _COMMON_OP_KEYS + _OP_KEYS[kind], f"key for {kind}")
        when = _conditions(c, t, groups, phases)
        op = _operator(c, kind, t, on, groups, when, phases, base)
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
            raise c.error(f"unknown group '{group}'{_hint(group, groups)} (groups: "
                          f"{', '.join(groups)})", "contact")
        conds.append(Contact(group))
    return tuple(conds)


def _source(c: _Ctx, t: dict, groups: dict) -> str:
    src = _string(c, _require(c, t, "from"), "from")
    if src not in groups:
        raise c.error(f"unknown source group '{src}'{_hint(src, groups)} (groups: "
                      f"{', '.join(groups)})", "from")
    return src


def _operator(c: _Ctx, kind: str, t: dict, on: str, groups: dict, when: tuple, phases: list,
              base: Path):
    if kind == "force":
        accel = _vec3(c, _require(c, t, "accel"), "accel")
        where = None
        if "where" in t:
            mask = _mask(c, _region(c, t["where"], "where", base, groups[on]), groups[on].o,
                         "where")
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
            d = _number(c, t["within"], "within", positive=True)
            if "inside" in t:       # no binding across free space (WithinInside)
                shape = _region(c, t["inside"], "inside", base)
                if _names_particles(shape):
                    raise c.error("'inside' is the part's shape, tested at points along each "
                                  "binding's segment; an 'ids' region selects particles, not "
                                  "space: give a box, sphere, cylinder, half-space, mesh or a "
                                  "combination of them", "inside")
                return Bind(src, ops_mod.WithinInside(d, cc, shape), when=when)
            return Bind(src, Within(d, cc), when=when)
        if "inside" in t:
            raise c.error("'inside' restricts within(d)'s pairs to those whose segment stays "
                          "in the part; give 'within' too", "inside")
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
