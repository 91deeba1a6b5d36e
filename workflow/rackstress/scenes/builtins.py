"""The built-in scenes by name, their parameters, and ``--set key=value`` overrides."""
from __future__ import annotations

import inspect

from rackstress.errors import SceneError
from rackstress.lib.suggest import did_you_mean
from rackstress.scenes.magpod import (magpod, magpod_physical, magpod_physical_small,
                                      magpod_small)
from rackstress.scenes.plane import plane_bound, plane_rack
from rackstress.scenes.large import sediment_large
from rackstress.scenes.validation import cantilever, l_bracket, plate_hole

#: name → builder; each builder's keyword arguments are the scene's parameters (``--set``).
BUILDERS = {
    "plane-bound": plane_bound,
    "plane-rack": plane_rack,
    "magpod": magpod,
    "magpod-small": magpod_small,
    "magpod-physical-small": magpod_physical_small,
    "magpod-physical": magpod_physical,
    "sediment-large": sediment_large,
    # validation cases against linear elasticity (rackstress bench validity)
    "cantilever": cantilever,
    "plate-hole": plate_hole,
    "l-bracket": l_bracket,
}


def parameters(name: str) -> dict:
    """The parameters of a built-in scene with their defaults."""
    sig = inspect.signature(BUILDERS[name])
    return {k: p.default for k, p in sig.parameters.items()}


def parse_value(text: str):
    """A ``--set`` value as TOML would read it (``2``, ``0.5``, ``true``, ``"x"``, ``[1,2]``)."""
    from rackstress.lib.toml import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text  # a bare word: keep it as a string


def parse_overrides(pairs) -> dict:
    out = {}
    for item in pairs or ():
        if "=" not in item:
            raise SceneError(f"--set expects key=value, got '{item}'")
        key, value = item.split("=", 1)
        out[key.strip()] = parse_value(value.strip())
    return out


def build(name: str, **overrides):
    """Build a built-in scene by name with parameter overrides, checking every key.

    Parameters
    ----------
    name : str
        A key of :data:`BUILDERS` (``rackstress scenes`` lists them with their parameters).
    **overrides
        Scene parameters (``--set key=value``); an unknown key or a value of the wrong type is
        a :class:`~rackstress.errors.SceneError` naming the scene and the parameter.

    Returns
    -------
    rackstress.model.scene.Scene

    Examples
    --------
    >>> sc = build("plane-bound", d=2)
    >>> sc.n_particles, sc.params["d"]
    (400, 2)
    """
    if name not in BUILDERS:
        hint = did_you_mean(name, BUILDERS)
        raise SceneError(f"unknown scene '{name}'{' (' + hint + ')' if hint else ''}; built-in scenes: "
                         f"{', '.join(BUILDERS)} (or give the path of a .toml scene file)")
    known = parameters(name)
    unknown = sorted(set(overrides) - set(known))
    if unknown:
        hint = did_you_mean(unknown[0], known)
        raise SceneError(f"scene '{name}' has no parameter {', '.join(map(repr, unknown))}"
                         f"{' (' + hint + ')' if hint else ''}; its parameters are: "
                         f"{', '.join(f'{k}={v!r}' for k, v in known.items())}")
    for key, value in overrides.items():
        default = known[key]
        if isinstance(default, (int, float)) and not isinstance(default, bool):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise SceneError(f"scene '{name}': parameter {key} must be a number, got {value!r}")
            if isinstance(default, int) and not isinstance(default, bool) and value != int(value):
                raise SceneError(f"scene '{name}': parameter {key} must be an integer, got {value!r}")
    try:
        return BUILDERS[name](**overrides)
    except SceneError:
        raise
    except (TypeError, ValueError) as exc:
        raise SceneError(f"scene '{name}' cannot be built with {overrides}: {exc}") from None
