"""Names of the files post-processing and rendering derive from a run's trajectory.

They live here, below every layer, because three layers need the same names: ``stress`` writes
them, ``render`` links them from the report, and ``runs`` removes them when a killed run is
resumed (they would otherwise describe the shorter, interrupted trajectory).
"""

#: per-frame measures cached for pictures, report and files (:mod:`rackstress.stress.post`)
CACHE = "measures.npz"
#: the post-processing record: peaks, files written, timings
STRESS_JSON = "stress.json"
#: the trajectory with the measures as named columns
STRESS_DUMP = "stress.dump"
#: one ``.vtp`` a frame and the ParaView collection that lists them
VTK_DIR, PVD = "vtk", "run.pvd"
#: the one-page HTML report (:mod:`rackstress.render.report`)
REPORT = "report.html"
#: Eq. 5's predicted stability limit for the run's scene and time step: written when the run
#: starts (the prediction its time step was checked with), read by the report's stability margin
STABILITY = "stability.json"

#: what ``--resume`` removes before the trajectory grows (written again at the run's end)
DERIVED = (STRESS_DUMP, STRESS_JSON, CACHE, REPORT, VTK_DIR)
#: the bindings of the parts with a material, for their stress (:mod:`rackstress.stress.tensor`):
#: written when the run starts, from the scene (i, j, force coefficient m·c, L0²)
BINDINGS = "bindings.npz"
#: the singular points of the parts with a material (re-entrant edges, support boundaries,
#: point loads: :mod:`rackstress.model.singular`), written when the run starts
SINGULAR = "singular.npz"

#: a static run's equilibrium on LAMMPS (ids and positions), what its ``in.lammps`` reads
EQUILIBRIUM = "equilibrium.dump"

#: Every top-level name a rackstress command writes into a run directory (``run``, ``stress``,
#: ``render``, ``fea``, a batch job). A new run refuses a directory holding one of these names
#: that no run wrote (it would write over the user's file), and in a run directory written
#: before runs kept a manifest (:mod:`rackstress.runs.rundir`) these, and only these, are the
#: run's. A command that writes a new name adds it here; its files are recorded in the manifest
#: either way (the lock's release adopts what the command wrote).
RUN_FILES = ("scene.json", "summary.json", "progress.json", "particles.data", "in.lammps",
             "log.lammps", "trajectory.dump", "trajectory.dump.gz", "boundary.npz", BINDINGS,
             STABILITY, STRESS_JSON, STRESS_DUMP, CACHE, VTK_DIR, REPORT, "view3d.html",
             "figures", "restart", "fea.json", "fea.npz", "job.json", SINGULAR,
             "refine", "offsets", "volume.atoms", EQUILIBRIUM)
