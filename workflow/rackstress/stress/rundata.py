"""A run directory as an MDAnalysis Universe: topology, parts, original positions, frames.

:func:`load_run` reads ``scene.json`` (groups → atom types and id ranges), ``particles.data``
(the topology, through MDAnalysis' DATA parser with ``atom_style="id resid type x y z"``, and the
original positions o at full precision) and indexes ``trajectory.dump`` or a finished run's
``trajectory.dump.gz`` (read frame by frame by
:class:`~rackstress.stress.dump.RackDumpReader`). It checks that the three agree — atom count,
ids, the type of every atom, the groups' id ranges — and raises a
:class:`~rackstress.stress.dump.StressInputError` naming the file when they do not.

Parts: every group of ``scene.json`` is a part of its own for stress purposes, a rack included
(a rack rides on its host, but its own few particles are fitted separately). Pictures leave the
racks out (:meth:`RunData.displayed`): they are the paper's invisible mechanism, not structure.
A group of kind ``sediment`` is a loose material with no rest shape (no forces between its
particles), so it is drawn as grey context and studied in the footprints plot instead.
"""
from __future__ import annotations

import json
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rackstress.stress.dump import (DataFile, DataMismatchError, FrameIndex, RackDumpReader, StressInputError,
                   index_dump, read_data_file)

SCENE, DATA, DUMP = "scene.json", "particles.data", "trajectory.dump"


@dataclass
class Part:
    name: str
    kind: str
    host: str | None
    type: int
    mol: int
    index: np.ndarray      # 0-based positions in the id-sorted atom order

    @property
    def n(self) -> int:
        return len(self.index)


@dataclass
class RunData:
    rundir: Path
    scene: dict
    data: DataFile
    index: FrameIndex
    parts: dict                      # name → Part, in scene order
    universe: object = field(repr=False, default=None)

    @property
    def o(self) -> np.ndarray:
        """Original positions (float64, id order)."""
        return self.data.positions

    @property
    def n_atoms(self) -> int:
        return len(self.data.ids)

    @property
    def steps(self) -> np.ndarray:
        return self.index.steps

    @property
    def dt(self) -> float:
        return float(self.scene.get("dt") or 1.0)

    @property
    def time_unit(self) -> str | None:
        """The scene's unit of time ("s") in physical units, None in the paper's (its time is
        iterations × t, no unit)."""
        units = self.scene.get("units") if isinstance(self.scene, dict) else None
        return units.get("time") if isinstance(units, dict) and units.get("time") else None

    @property
    def trajectory(self):
        return self.universe.trajectory

    @property
    def truncation(self) -> str | None:
        return self.index.truncation

    def displayed(self) -> list:
        """Parts drawn coloured by stress: every part but racks and sediments."""
        return [p for p in self.parts.values() if p.kind not in ("rack", "sediment")]

    def context(self) -> list:
        """Parts drawn as plain grey context (sediments)."""
        return [p for p in self.parts.values() if p.kind == "sediment"]

    def nearest_frames(self, iterations) -> list:
        """For each requested iteration: (requested, frame index, step of that frame)."""
        out = []
        for it in iterations:
            k = int(np.argmin(np.abs(self.steps - int(it))))
            out.append((int(it), k, int(self.steps[k])))
        return out


def load_run(rundir, allow_truncated: bool = False) -> RunData:
    """Open a run directory for analysis; see the module docstring for what is checked.

    Parameters
    ----------
    rundir : path
        A directory written by ``rackstress run`` (``scene.json``, ``particles.data``,
        ``trajectory.dump``).
    allow_truncated : bool
        Read the whole frames of a dump whose last frame was cut (a full disk, a kill).

    Returns
    -------
    RunData
        The MDAnalysis Universe (float64 positions, streamed by frame), its parts by name, the
        original positions ``o`` and the run's ``dt``.

    Examples
    --------
    ``docs/api.md`` (run as a test) opens a plane-rack run: ``sorted(load_run(out).parts)`` is
    ``['plane', 'planerack']``.
    """
    rundir = Path(rundir)
    if not rundir.is_dir():
        raise StressInputError(f"{rundir}: no such run directory")
    from rackstress.engines.dumpio import dump_path

    dump = dump_path(rundir, DUMP)         # trajectory.dump, or a finished run's .gz
    for name in (SCENE, DATA, dump.name):
        if not (rundir / name).is_file():
            raise StressInputError(f"{rundir}: no {name}; is this a run directory "
                                   "(made by 'rackstress run')?")
    if not _KEEP:
        return _open_run(rundir, dump, allow_truncated)
    key = _files_key(rundir, dump, allow_truncated)
    if key is not None and key in _OPENED:
        return _OPENED[key]
    run = _open_run(rundir, dump, allow_truncated)
    _OPENED.clear()                   # one run directory kept open at a time
    if key is not None:
        _OPENED[key] = run
    return run


#: within :func:`kept_open`: the run opened last (its files unchanged: :func:`_files_key`)
_OPENED: dict = {}
_KEEP: list = []


@contextmanager
def kept_open():
    """Within this block :func:`load_run` opens a run directory once and hands the same
    RunData to every caller while its files are unchanged: ``rackstress run``'s
    post-processing and pictures (the run directory locked meanwhile) read particles.data,
    index the dump and parse the topology once (sediment-large: seconds)."""
    _KEEP.append(True)
    try:
        yield
    finally:
        _KEEP.pop()
        if not _KEEP:
            _OPENED.clear()


def _files_key(rundir: Path, dump: Path, allow_truncated: bool):
    """What an opened run depends on: its three files' inode, size and modification time."""
    import os

    try:
        stats = [os.stat(path) for path in (rundir / SCENE, rundir / DATA, dump)]
    except OSError:
        return None
    return (str(rundir.resolve()), bool(allow_truncated),
            tuple((st.st_ino, st.st_size, st.st_mtime_ns) for st in stats))


def _open_run(rundir: Path, dump: Path, allow_truncated: bool) -> RunData:
    import MDAnalysis as mda

    try:
        scene = json.loads((rundir / SCENE).read_text())
    except json.JSONDecodeError as exc:
        raise StressInputError(f"{rundir / SCENE}: not valid JSON ({exc})") from None
    data = read_data_file(rundir / DATA)
    # a rackstress dump may follow what moves: a particle a frame does not hold rests at its
    # original position (engines/dumpio.py), which the data file gives
    index = index_dump(dump, allow_truncated, partial=True)
    n = len(data.ids)
    if index.n_atoms > n or (index.n_atoms < n and not index.partial):
        raise DataMismatchError(f"{dump} has {index.n_atoms} atoms per frame but "
                                f"{rundir / DATA} has {n}: the dump and the data file are not of "
                                "the same run")
    parts = _parts(scene, data, rundir)
    dt = float(scene.get("dt") or 1.0)
    u = mda.Universe(str(rundir / DATA), str(dump), topology_format="DATA",
                     atom_style="id resid type x y z", format=RackDumpReader, index=index,
                     rest=data, dt=dt)
    if not np.array_equal(u.atoms.ids, data.ids):
        raise DataMismatchError(f"{rundir / DATA}: MDAnalysis reads its atoms in another order "
                                "than by id; rackstress data files list atoms by id")
    ts = u.trajectory[0]
    if not np.array_equal(ts.data["ids"], data.ids):
        bad = np.flatnonzero(ts.data["ids"] != data.ids)[0]
        raise DataMismatchError(f"{dump} (step {index.steps[0]}) has atom id "
                                f"{ts.data['ids'][bad]} where {rundir / DATA} has "
                                f"{data.ids[bad]}: the files are not of the same run")
    if not np.array_equal(ts.data["types"], data.types):
        bad = int(np.flatnonzero(ts.data["types"] != data.types)[0])
        raise DataMismatchError(f"atom {data.ids[bad]} has type {ts.data['types'][bad]} in "
                                f"{dump} but type {data.types[bad]} in {rundir / DATA}: "
                                "the files are not of the same run")
    return RunData(rundir, scene, data, index, parts, u)


def grown(run: RunData, allow_truncated: bool = True) -> RunData:
    """``run`` (from :func:`load_run`) with the frames its dump holds now: the dump indexed
    again and a new reader on it, the data file and the topology as they were read (a run
    still being written: :func:`rackstress.stress.post.follow`, a third of a new
    :func:`load_run`'s time)."""
    from dataclasses import replace

    dump = run.index.path
    index = index_dump(dump, allow_truncated, partial=True)
    run.universe.load_new(str(dump), format=RackDumpReader, index=index, rest=run.data,
                          dt=run.dt)
    return replace(run, index=index)


def _parts(scene: dict, data: DataFile, rundir: Path) -> dict:
    groups = scene.get("groups")
    if not groups:
        raise StressInputError(f"{rundir / SCENE}: no 'groups' (made by an older rackstress?)")
    parts, total = {}, 0
    id_pos = {int(i): k for k, i in enumerate(data.ids)}
    for g in groups:
        first, n = int(g["first_id"]), int(g["n"])
        try:
            index = np.array([id_pos[i] for i in range(first, first + n)], dtype=np.int64)
        except KeyError as exc:
            raise DataMismatchError(f"{rundir / SCENE}: group '{g['name']}' claims ids {first}.."
                                    f"{first + n - 1} but {rundir / DATA} has no atom "
                                    f"{exc.args[0]}") from None
        types = np.unique(data.types[index])
        if types.tolist() != [int(g["type"])]:
            raise DataMismatchError(f"{rundir / SCENE}: group '{g['name']}' has type {g['type']} "
                                    f"but its atoms in {rundir / DATA} have type(s) "
                                    f"{types.tolist()}")
        parts[g["name"]] = Part(g["name"], g.get("kind", "part"), g.get("host"), int(g["type"]),
                                int(g.get("mol", 0)), index)
        total += n
    if total != len(data.ids):
        raise DataMismatchError(f"{rundir / SCENE}: the groups hold {total} particles but "
                                f"{rundir / DATA} has {len(data.ids)}")
    return parts


def _by_row(run, ids, values, out: np.ndarray) -> np.ndarray:
    """``values`` (one per atom id of ``ids``) into ``out``'s rows in the run's id order; ids
    the run does not hold are skipped."""
    row = {int(i): k for k, i in enumerate(run.data.ids)}
    for i, v in zip(ids, values):
        if int(i) in row:
            out[row[int(i)]] = v
    return out


def face_stress(run) -> np.ndarray | None:
    """The normal stress a pressure puts on each pressed face (n×3 along x, y, z, id order, the
    scene's stress unit, at full load; ``boundary.npz`` → ``face_ids``, ``face_stress``), or
    None where the run pressed none (or was written before the record)."""
    path = Path(run.rundir) / "boundary.npz"
    if not path.is_file():
        return None
    with np.load(path) as z:
        if "face_ids" not in z.files or not len(z["face_ids"]):
            return None
        return _by_row(run, z["face_ids"], z["face_stress"], np.zeros((run.n_atoms, 3)))


def boundary_rows(run) -> tuple[np.ndarray, np.ndarray]:
    """The run's ``boundary.npz`` per particle (id order): the directions each is held in
    (n×3 booleans) and the load on it (n×3); all False and zero without the file."""
    n = run.n_atoms
    held, loads = np.zeros((n, 3), bool), np.zeros((n, 3))
    path = Path(run.rundir) / "boundary.npz"
    if path.is_file():
        with np.load(path) as z:
            _by_row(run, z["held_ids"], z["held_mask"], held)
            _by_row(run, z["load_ids"], z["load_force"], loads)
    return held, loads


def face_supports(held: np.ndarray) -> np.ndarray:
    """The directions a support holds each particle of one part across a face (k×3 bool), from
    its rows of :func:`boundary_rows`' ``held``: not a direction held on every particle of the
    part — a membrane kept in its plane is a constraint of the model, not a face's support.

    >>> held = np.array([[False, True, True], [False, False, True]])    # z held on both
    >>> face_supports(held).tolist()
    [[False, True, False], [False, False, False]]
    """
    held = np.asarray(held, bool)
    return held & ~held.all(axis=0)


#: The Poisson's ratio of the elastic lattice without the volumetric term (docs/calibration.md:
#: central bindings on the cubic lattice, whatever the material)
LATTICE_NU = 0.25


def volumetric(volume, part) -> bool:
    """Whether the run's volumetric terms ``volume`` (``measures.read_volume_terms``, or None)
    act on the part (``poisson = "material"``): else it is bound by its bindings alone."""
    return volume is not None and bool(np.isin(volume.owner, part.index).any())


def lattice_nu(volume, part, mat: dict) -> float:
    """The Poisson's ratio a part's particles were solved with: the material's (``mat``) where
    the run's volumetric terms ``volume`` (``measures.read_volume_terms``, or None) act on the
    part (``poisson = "material"``), else the bindings' :data:`LATTICE_NU`. The notch
    submodel takes it for its cut, the patch fit for where its samples stand."""
    if volumetric(volume, part):
        return float(mat.get("nu", LATTICE_NU))
    return LATTICE_NU
