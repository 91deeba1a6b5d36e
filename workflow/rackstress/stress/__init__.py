"""Per-particle stress of a run: reading its dump through MDAnalysis, and the stress measures.

* :mod:`.dump` — :class:`RackDumpReader` (an MDAnalysis reader: float64, streamed by frame) and
  the errors for bad dumps and data files;
* :mod:`.rundata` — :func:`load_run`: a run directory as a Universe with its parts;
* :mod:`.fit` — best-fit rigid motion of a part (Kabsch), plain and robust;
* :mod:`.measures` — one MDAnalysis ``AnalysisBase`` class per measure: the paper's distance
  from the desired position and its time integral, von Mises shear strain, D²min, virial stress,
  the stress of parts with a material in the scene's units (:class:`ParticleStress`), and the
  parts' motion (centre of mass, footprints);
* :mod:`.tensor` — stress per particle from the bindings' forces (virial), von Mises, principal;
* :mod:`.post` — every measure computed once per run (cached), the peaks of every group and
  measure into ``summary.json``, ``rackstress stress``;
* :mod:`.export` — the VTK time series (``vtk/run.pvd``) and the LAMMPS dump with the measures
  as named columns (``stress.dump``) for ParaView, OVITO and pyvista;
* :mod:`.foreign` — a plain LAMMPS data file and dump (not written by rackstress) as a run.
"""
# The names below load on first use (PEP 562): ``rackstress run`` imports
# ``rackstress.stress.kernels`` before its simulation, and MDAnalysis (a few tenths of a second)
# then loads beside the simulation instead of before it (render.prepare).
_FROM = {
    "dump": ("DataMismatchError", "DumpColumnsError", "DumpError", "RackDumpReader",
             "StressInputError", "TruncatedDumpError", "index_dump", "read_data_file"),
    "fit": ("robust_fit", "rigid_fit"),
    "measures": ("MEASURES", "AccumulatedDistance", "DesiredPositionDistance", "NonAffineD2min",
                 "ParticleStress", "PartMotion", "VirialStress", "VonMisesStrain",
                 "von_mises_strain"),
    "rundata": ("Part", "RunData", "load_run"),
}
_WHERE = {name: mod for mod, names in _FROM.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name):
    mod = _WHERE.get(name)
    if mod is None:
        raise AttributeError(f"module 'rackstress.stress' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f"rackstress.stress.{mod}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_WHERE))
