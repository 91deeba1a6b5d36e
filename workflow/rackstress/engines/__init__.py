"""Engines that step a scene: the reference engine (NumPy) and LAMMPS (deck, callback, runner)."""
