"""rackstress: particle-system stress visualization with rack particles, backed by LAMMPS.

The data flows one way: scene → deck → run → dump → stress → pictures.
"""
from .errors import DivergenceError, RackstressError, SceneError
from .operators import (Attract, Bind, Collide, Const, Contact, Dampen, Force, Matched, PhaseIn,
                        Within)
from .particles import Group, lattice, rack
from .scene import Phase, Scene

__version__ = "0.1.0"
__all__ = ["Attract", "Bind", "Collide", "Const", "Contact", "Dampen", "DivergenceError",
           "Force", "Group", "Matched", "Phase", "PhaseIn", "RackstressError", "Scene",
           "SceneError", "Within", "lattice", "rack"]
