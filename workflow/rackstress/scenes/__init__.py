"""Scenes: the built-in ones (:mod:`.builtins`) and TOML scene files (:mod:`.toml`).

``load(spec, overrides)`` is the one entry point: a built-in name or a ``.toml`` path.
"""
from __future__ import annotations

from pathlib import Path

from rackstress.scenes.builtins import (BUILDERS, build, parameters, parse_overrides,
                                        parse_value)
from rackstress.scenes.toml import load_toml

__all__ = ["BUILDERS", "RECORDED_ONLY", "build", "load", "load_toml", "parameters",
           "parse_overrides", "parse_value"]

#: The parameters a run records in ``scene.json``'s ``params`` that are not its scene's
#: ``--set`` values but how it was run or filled (``spacing_scale``: ``--refine``,
#: ``lattice_shift``: ``--offsets``); a scene read again from its file leaves them out
RECORDED_ONLY = ("file", "integrator", "dt", "analysis", "spacing_scale", "lattice_shift",
                 "steps")


def load(spec: str, overrides: dict | None = None, spacing_scale: float = 1.0,
         lattice_shift=None):
    """A scene from a built-in name or a ``.toml`` file path, with ``--set`` overrides applied.

    Parameters
    ----------
    spec : str
        A built-in scene's name (:func:`build`) or the path of a TOML scene file (format:
        ``docs/scenes.md``; :func:`rackstress.scenes.toml.load_toml`).
    overrides : dict, optional
        Parameter values by name: a built-in scene's parameters or a file's ``[params]``.
    spacing_scale : float
        A scene file's parts filled at their spacing times this (``rackstress run --refine``);
        built-in scenes take no other than 1.
    lattice_shift : sequence of 3 floats, optional
        A scene file's filled parts on a lattice moved by these fractions of their spacing
        (``rackstress run --offsets``); built-in scenes take none.

    Returns
    -------
    rackstress.model.scene.Scene

    Examples
    --------
    >>> load("plane-rack", {"plane_bind": 50.0}).params["plane_bind"]
    50.0
    """
    overrides = dict(overrides or {})
    if spec.endswith(".toml") or Path(spec).is_file():
        return load_toml(spec, overrides, spacing_scale=spacing_scale,
                         lattice_shift=lattice_shift)
    if spacing_scale != 1.0 or lattice_shift is not None:
        from rackstress.errors import SceneError

        raise SceneError(f"scene '{spec}' is a built-in scene: --refine and --offsets refill "
                         "the parts of a scene file (.toml) filled from a mesh or shape at a "
                         "spacing")
    return build(spec, **overrides)
