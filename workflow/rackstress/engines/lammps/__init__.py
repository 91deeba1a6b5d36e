"""The LAMMPS engine: the deck compiler, the fix external callback, and the runner."""
