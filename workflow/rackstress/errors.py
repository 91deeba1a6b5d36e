"""The errors rackstress raises on purpose, and the exit status of each.

Every error carries a one-paragraph message meant to be read by the user as it is, naming the
file, field, step or particle. The ``rackstress`` command exits with:

======  ==========================================================================================
status  meaning
======  ==========================================================================================
0       done
2       bad input: a scene, sweep or option that cannot be used, a run directory that is in use
        (another command holds its lock), holds another run, or a checkpoint that belongs to a
        different run (:class:`SceneError`, :class:`RunDirError`, :class:`ResumeError`); also
        a scene too large for the memory the process may have (estimated up front against
        the machine's free memory, ``ulimit -v`` and the job's limit, or a ``MemoryError``
        met anywhere: one paragraph, never a traceback)
3       the run diverged: the watchdog, LAMMPS (lost atoms, neighbour bins) or the operator
        callback stopped it; ``summary.json`` names the step and particle, frames are kept
        (:class:`DivergenceError`)
4       the run finished, but its pictures could not be rendered (retry ``rackstress render``)
5       the operating system refused a write: disk full, no permission, read-only file system
        (:class:`StorageError`); no temporary file is left, earlier checkpoints stay intact;
        also when the run finished but its stress files or pictures could not be written (the
        run is kept: ``rackstress stress`` / ``render`` once there is space)
6       a static analysis did not settle: its residual force stayed above the tolerance
        (``summary.json`` says ``"status": "not settled"`` with the residual)
1       anything else: a bug (please report the traceback)
======  ==========================================================================================

Under ``mpiexec`` every rank exits with the same status; a failure on one rank that the others
cannot learn of (LAMMPS aborting on one rank) ends all ranks through ``MPI_Abort`` with that
status after one message.
"""
from __future__ import annotations

import errno as _errno

#: Exit statuses of the ``rackstress`` command (see the module docstring).
EXIT_OK, EXIT_BUG, EXIT_INPUT, EXIT_DIVERGED, EXIT_RENDER, EXIT_STORAGE = 0, 1, 2, 3, 4, 5
#: a static analysis that did not reach equilibrium (``summary.json``: ``"settled": false``)
EXIT_UNSETTLED = 6


class RackstressError(Exception):
    """Base class: an error whose message is meant to be read by the user as it is."""

    exit_code = EXIT_INPUT


class SceneError(RackstressError, ValueError):
    """A scene (built in, from TOML, or from ``--set`` overrides) is malformed or unphysical."""


class DivergenceError(RackstressError):
    """A run flew apart: a position or velocity became non-finite or left the watchdog bound,
    LAMMPS lost atoms, or the operator callback lost sight of a partner.

    Carries the ``step``, the particle ``index`` (0-based, global), its ``group`` and the index
    within the group, so a summary can record them.
    """

    exit_code = EXIT_DIVERGED

    def __init__(self, message: str, *, step: int, index: int, group: str, local: int,
                 value: float | None = None):
        super().__init__(message)
        self.step, self.index, self.group, self.local, self.value = step, index, group, local, value

    def __reduce__(self):       # travels between MPI ranks whole
        return (_divergence, (str(self), self.step, self.index, self.group, self.local,
                              self.value))


def _divergence(message, step, index, group, local, value):
    return DivergenceError(message, step=step, index=index, group=group, local=local,
                           value=value)


class RunDirError(RackstressError):
    """A run directory cannot be used: in use, holds another run, or is not a run directory."""


class ResumeError(RunDirError):
    """A checkpoint cannot continue the run asked for (another scene, options it cannot honour)."""


class StorageError(RackstressError, OSError):
    """The operating system refused a write (disk full, permission, read-only file system)."""

    exit_code = EXIT_STORAGE

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message

    def __str__(self):
        return self.message

    def __reduce__(self):       # travels between MPI ranks whole
        return (StorageError, (self.message,))


def os_error_message(exc: OSError, doing: str, path=None) -> str:
    """One paragraph for an OS error: what was being done, the path, the reason, what to do."""
    path = path or exc.filename or "?"
    reason = exc.strerror or str(exc)
    hint = {_errno.ENOSPC: "free space on that file system or choose another --out",
            _errno.EDQUOT: "free space within your quota or choose another --out",
            _errno.EROFS: "the file system is read-only: choose another --out",
            _errno.EACCES: "you may not write there: choose another --out",
            _errno.EPERM: "you may not write there: choose another --out",
            _errno.EFBIG: "the file exceeds the file-size limit (ulimit -f)"}.get(exc.errno,
                                                                                 "")
    return f"could not {doing} {path}: {reason}" + (f"; {hint}" if hint else "")


def storage_error(exc: OSError, doing: str, path=None) -> StorageError:
    """A :class:`StorageError` for ``exc`` (its errno and path kept)."""
    err = StorageError(os_error_message(exc, doing, path))
    err.errno, err.filename = exc.errno, exc.filename
    return err
