"""rackstress: particle-system stress visualization with rack particles, backed by LAMMPS.

The data flows one way: scene → deck → run → dump → stress → pictures.
"""
from rackstress.errors import DivergenceError, RackstressError, SceneError
from rackstress.lib.mpi import threads as _threads
from rackstress.model.operators import (Attract, Bind, Collide, Const, Contact, Dampen, Force, Matched, PhaseIn,
                        Within, WithinInside)
from rackstress.model.particles import Group, lattice, rack
from rackstress.model.scene import Phase, Scene

_threads()      # MPI, when it starts: the main thread alone calls it (lib/mpi.py, THREAD_LEVEL)
__version__ = "0.1.0"
__all__ = ["Attract", "Bind", "Collide", "Const", "Contact", "Dampen", "DivergenceError",
           "Force", "Group", "Matched", "Phase", "PhaseIn", "RackstressError", "Scene",
           "SceneError", "Within", "WithinInside", "lattice", "rack"]
