"""The errors rackstress raises on purpose: each carries a one-paragraph message for the user."""
from __future__ import annotations


class RackstressError(Exception):
    """Base class: an error whose message is meant to be read by the user as it is."""


class SceneError(RackstressError, ValueError):
    """A scene (built in, from TOML, or from ``--set`` overrides) is malformed or unphysical."""


class DivergenceError(RackstressError):
    """The watchdog stopped a run: a position or velocity became non-finite or left the bound.

    Carries the ``step``, the particle ``index`` (0-based, global), its ``group`` and the index
    within the group, so a summary can record them.
    """

    def __init__(self, message: str, *, step: int, index: int, group: str, local: int,
                 value: float | None = None):
        super().__init__(message)
        self.step, self.index, self.group, self.local, self.value = step, index, group, local, value


class RunDirError(RackstressError):
    """A run directory cannot be used (it holds a finished run, or is not writable)."""
