"""Atom types and molecule IDs of a scene: one atom type per group, one molecule per part.

A rack group shares the molecule of its host (the part it makes rigid), so a LAMMPS data file or
an MDAnalysis Universe reads "body + bodyrack" as one molecule with two atom types.
"""
from __future__ import annotations

import numpy as np

from rackstress.model.scene import Scene


def group_types(scene: Scene) -> dict:
    """group name → LAMMPS atom type (1-based, in group order)."""
    return {name: k + 1 for k, name in enumerate(scene.groups)}


def group_mols(scene: Scene) -> dict:
    """group name → molecule ID: hosts numbered in order, racks take their host's ID."""
    mols, next_id = {}, 1
    for name, g in scene.groups.items():
        if g.host is None:
            mols[name] = next_id
            next_id += 1
    for name, g in scene.groups.items():
        if g.host is not None:
            mols[name] = mols[g.host]
    return mols


def per_particle(scene: Scene, table: dict) -> np.ndarray:
    """Expand a group → value table to one value per particle in global order."""
    return np.concatenate([np.full(g.n, table[name]) for name, g in scene.groups.items()])
