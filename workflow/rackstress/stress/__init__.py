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
from rackstress.stress.dump import (DataMismatchError, DumpColumnsError, DumpError, RackDumpReader,
                   StressInputError, TruncatedDumpError, index_dump, read_data_file)
from rackstress.stress.fit import robust_fit, rigid_fit
from rackstress.stress.measures import (MEASURES, AccumulatedDistance, DesiredPositionDistance, NonAffineD2min,
                       ParticleStress, PartMotion, VirialStress, VonMisesStrain, von_mises_strain)
from rackstress.stress.rundata import Part, RunData, load_run

__all__ = [
    "AccumulatedDistance", "DataMismatchError", "DesiredPositionDistance", "DumpColumnsError",
    "DumpError", "MEASURES", "NonAffineD2min", "Part", "ParticleStress", "PartMotion", "RackDumpReader",
    "RunData", "StressInputError", "TruncatedDumpError", "VirialStress", "VonMisesStrain",
    "index_dump", "load_run", "read_data_file", "rigid_fit", "robust_fit", "von_mises_strain",
]
