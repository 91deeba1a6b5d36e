"""Scenes: the built-in ones (:mod:`.builtins`) and TOML scene files (:mod:`.toml`).

``load(spec, overrides)`` is the one entry point: a built-in name or a ``.toml`` path.
"""
from __future__ import annotations

from pathlib import Path

from rackstress.scenes.builtins import (BUILDERS, build, parameters, parse_overrides,
                                        parse_value)
from rackstress.scenes.toml import load_toml

__all__ = ["BUILDERS", "build", "load", "load_toml", "parameters", "parse_overrides",
           "parse_value"]


def load(spec: str, overrides: dict | None = None):
    """A scene from a built-in name or a ``.toml`` file path, with ``--set`` overrides applied."""
    overrides = dict(overrides or {})
    if spec.endswith(".toml") or Path(spec).is_file():
        return load_toml(spec, overrides)
    return build(spec, **overrides)
