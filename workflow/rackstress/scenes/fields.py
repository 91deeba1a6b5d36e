"""Field checks of scene files: where a value is (file, table, field) and what it must be.

Shared by :mod:`rackstress.scenes.toml` and :mod:`rackstress.scenes.physical`; every problem is
a :class:`SceneError` naming the file, the table and the field.
"""
from __future__ import annotations

import math

from rackstress.errors import SceneError
from rackstress.lib.suggest import did_you_mean


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
        hint = did_you_mean(unknown[0], allowed)
        raise ctx.error(f"unknown {what} {', '.join(map(repr, unknown))}"
                        f"{' (' + hint + ')' if hint else ''}; allowed: {', '.join(allowed)}")


def _hint(word, names) -> str:
    """``" (did you mean 'X'?)"`` for the closest of ``names``, or ``""``."""
    hint = did_you_mean(str(word), list(names))
    return f" ({hint})" if hint else ""


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


def _array_of_tables(ctx: _Ctx, value, table: str) -> list:
    if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
        raise ctx.error(f"must be an array of tables ([[{table}]] sections), got "
                        f"{_describe(value)}", f"[[{table}]]")
    return value
