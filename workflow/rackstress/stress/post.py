"""Post-processing of a run: every stress measure computed once, the peaks, files to explore.

:func:`compute_fields` runs the measures of :mod:`rackstress.stress.measures` over every dumped
frame once — the paper's distance from the desired position (robust fit, Section 5.2), its time
integral, von Mises shear strain and D²min (Falk & Langer), and the virial stress if the dump
holds it, and for parts with a material the von Mises stress from the bindings' forces in the
scene's stress unit, with the stress tensor, principal stresses, factor of safety and binding
strain as :data:`EXTRAS` (docs/stress.md) — and keeps them as a :class:`Fields` (n_frames ×
n_atoms per measure, float64), cached in ``RUNDIR/measures.npz`` so that pictures, report and
files reuse them instead of recomputing. :attr:`Fields.default` is the measure that leads:
``von_mises`` for a scene with a material, else ``paper``.

:func:`peaks` finds, for every group and measure, the largest value over the whole run: value,
iteration, frame, particle (LAMMPS atom id and index in its group) and its position at that
iteration. :func:`stress_warnings` names the parts strained beyond small-strain validity or
stressed beyond yield. :func:`postprocess` writes them into ``summary.json``
(``groups.<name>.peak.<measure>``, ``warnings``, atomically) and writes the VTK time series (``RUNDIR/vtk/run.pvd``) and, on request, a LAMMPS dump
with the measures as named columns (``RUNDIR/stress.dump``; see :mod:`rackstress.stress.export`).

Example
-------
>>> from rackstress.stress.post import postprocess          # doctest: +SKIP
>>> info = postprocess("runs/plane-rack")                   # doctest: +SKIP
>>> info["peak"]["value"], info["peak"]["iteration"]         # doctest: +SKIP
(2.81..., 36)
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rackstress.lib.jsonio import write_json
from rackstress.lib.runfiles import CACHE, STRESS_DUMP, STRESS_JSON, VTK_DIR
from rackstress.stress.dump import StressInputError
from rackstress.stress.measures import (Columns, ParticleStress, VirialStress,
                                        material_parts, measure_columns, measure_frames,
                                        positions, read_bindings, stress_columns)

#: The measures every run gets, in this order (``virial`` too when the dump recorded it).
MEASURES = ("paper", "accumulated", "strain", "d2min")
LABELS = {
    "paper": ("distance from desired position", "length units"),
    "accumulated": ("accumulated distance from desired position", "length × time units"),
    "strain": ("von Mises shear strain", "dimensionless"),
    "d2min": ("non-affine displacement D²min", "length² units"),
    "virial": ("per-atom von Mises stress × volume", "energy units"),
    "von_mises": ("von Mises stress", "stress units"),
    "contact_pressure": ("contact pressure", "stress units"),
}
#: Further measures, computed after the built-in ones by :func:`compute_fields` and carried
#: everywhere the built-in ones go (peaks, VTK point arrays, pictures, report) with no special
#: case: name → fn(run, values) → (n_frames, n_atoms[, k]) array, ``values`` being the measures
#: computed so far (reuse them rather than computing twice). Add with :func:`register_measure`.
EXTRA_MEASURES: dict = {}


def register_measure(name: str, label: str, units: str, fn) -> None:
    """Add a per-particle measure to every run's post-processing (see :data:`EXTRA_MEASURES`).

    Example
    -------
    >>> register_measure("height", "height above the start", "length units",
    ...                  lambda run, values: frame_heights(run))          # doctest: +SKIP
    """
    LABELS[name] = (label, units)
    EXTRA_MEASURES[name] = fn


#: Per-particle fields kept beside the ranked measures (not ranked by their maximum: a tensor,
#: a vector, a factor of safety whose *smallest* value matters): written into the VTK files,
#: kept in float32 (11 values a particle and frame; ``von_mises`` itself stays float64).
EXTRAS = ("stress", "principal", "safety", "bind_strain")
#: Small-strain validity: a binding stretched or shortened by more than this fraction
#: (|d/L0 − 1|) makes the linear-elastic reading of the stress doubtful (warning).
STRAIN_LIMIT = 0.05
#: Largest n_atoms × n_frames post-processed (each measure keeps n_frames × n_atoms float64,
#: five such arrays while computing): about 1 GB at this size.
MAX_VALUES = 25_000_000


class TooLargeError(StressInputError):
    """The run has too many particles × frames to hold its measures in memory."""


#: The fit of the desired position (one for summary, pictures, report and files).
FIT = "robust"
#: 2: a sediment's paper measure is |p − o| (no rest shape, measures.paper_frames);
#: 3: the stress fields (extras) and the scene's units kept beside the measures;
#: 4: von_mises by patch recovery (the measure's default route); 5: the contact's force in the
#: stress of the layers that touch, and the contact pressure
CACHE_VERSION = 5


@dataclass
class Fields:
    """Every measure per frame and particle (id order), with the frames' iterations."""

    steps: np.ndarray                       # (n_frames,) iteration of every dumped frame
    values: dict                            # measure → (n_frames, n_atoms) float64
    fit: str = FIT
    timings: dict = field(default_factory=dict)
    #: measure → its unit where it is not the generic one of :data:`LABELS` (the scene's units)
    units: dict = field(default_factory=dict)
    #: name → (n_frames, n_atoms[, k]) per-particle fields of :data:`EXTRAS`
    extras: dict = field(default_factory=dict)
    #: parts in contact: (n_frames, sides, 4) per side of each contact
    #: (:data:`rackstress.stress.measures.CONTACT_SIDE`), else None
    contact_sides: object = None

    @property
    def measures(self) -> list:
        return list(self.values)

    def unit(self, measure: str) -> str:
        return self.units.get(measure) or LABELS[measure][1]

    def label(self, measure: str) -> str:
        return f"{LABELS[measure][0]} [{self.unit(measure)}]"

    @property
    def default(self) -> str:
        """The measure pictures, headline and peaks lead with: von Mises stress for a scene
        with a material, else the paper's distance from the desired position."""
        return "von_mises" if "von_mises" in self.values else "paper"


# ----------------------------------------------------------------------------- computing
def _stamp(run) -> dict:
    """What the cache depends on: the dump's and data file's size and modification time."""
    out = {"version": CACHE_VERSION, "fit": FIT, "n_frames": int(run.index.n_frames),
           "extra": sorted(EXTRA_MEASURES)}
    for key, path in (("dump", run.index.path), ("data", run.data.path)):
        st = os.stat(path)
        out[key] = [int(st.st_size), int(st.st_mtime_ns)]
    return out


def _load_cache(run, path: Path) -> Fields | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            if json.loads(str(z["stamp"])) != _stamp(run):
                return None
            values = {m: z[m] for m in json.loads(str(z["measures"]))}
            extras = {m: z["x_" + m] for m in json.loads(str(z["extras"]))}
            units = json.loads(str(z["units"]))
            steps = z["steps"]
            sides = z["contact_sides"] if "contact_sides" in z.files else None
    except (OSError, KeyError, ValueError):
        return None
    if not np.array_equal(steps, run.steps):
        return None
    return Fields(steps, values, units=units, extras=extras, contact_sides=sides)


def _save_cache(run, fields: Fields, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}.npz")
    try:
        np.savez(tmp, stamp=json.dumps(_stamp(run)), measures=json.dumps(fields.measures),
                 extras=json.dumps(list(fields.extras)), units=json.dumps(fields.units),
                 steps=fields.steps, **fields.values,
                 **{"x_" + m: v for m, v in fields.extras.items()},
                 **({} if fields.contact_sides is None
                    else {"contact_sides": fields.contact_sides}))
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)       # a cache that cannot be written is only a cache


#: the fields this process computed last (run directory, stamp) → Fields: ``rackstress run``
#: measures once and hands the same arrays to the VTK files, the pictures and the report
_MEMO: dict = {}


def compute_fields(run, cache: bool = True, progress: bool = False,
                   save: bool = False) -> Fields:
    """Every measure of every frame of ``run`` (a :class:`RunData`), computed once.

    Within a process the fields of the last run measured are kept (the same dump and data
    file: :func:`_stamp`), so the post-processing, the pictures and the report of
    ``rackstress run`` share one computation. The measures cost less than writing them down
    (magpod-small: 18 MB of float64 a time, 0.7 s to compress), so no file is written unless
    ``save``.

    Parameters
    ----------
    run : RunData
        From :func:`rackstress.stress.load_run` (or :func:`rackstress.stress.foreign.load_plain`).
    cache : bool
        Reuse ``RUNDIR/measures.npz`` when it was made from the same dump and data file.
    save : bool
        Write ``RUNDIR/measures.npz`` after computing (only where the run directory is
        writable).
    progress : bool
        Show a progress bar on a terminal.

    Returns
    -------
    Fields
        ``values[m]`` is (n_frames, n_atoms): NaN where a measure is undefined.

    Example
    -------
    >>> fields = compute_fields(load_run("runs/plane-rack"))          # doctest: +SKIP
    >>> fields.values["paper"].shape                                  # doctest: +SKIP
    (31, 406)
    """
    path = Path(run.rundir) / CACHE
    key = None
    if not run.truncation:
        try:
            key = (str(Path(run.rundir).resolve()), json.dumps(_stamp(run)))
        except OSError:
            key = None
    if key is not None and key in _MEMO:
        got = _MEMO[key]
        got.timings["cached"] = True
        return got
    if cache and not run.truncation:
        got = _load_cache(run, path)
        if got is not None:
            got.timings["cached"] = True
            return got
    import sys

    t0 = time.perf_counter()
    size = run.n_atoms * run.index.n_frames
    virial = stress_columns(run.index.columns) is not None
    stress = (ParticleStress(run) if material_parts(run) and read_bindings(run) is not None
              else None)
    compact = size > MAX_VALUES and _compactable(run, virial, stress)
    if size > MAX_VALUES and not compact:
        raise TooLargeError(
            f"{run.index.path}: {run.n_atoms} particles × {run.index.n_frames} frames = "
            f"{size:.3g} values per measure, more than the {MAX_VALUES:.3g} the stress "
            "post-processing holds in memory; dump fewer frames (--dump-every) or analyse "
            "a part of the run")
    from rackstress.lib.progress import progress_bar

    tty = bool(progress) and sys.stderr.isatty()
    head = _head(run)                   # the chunks measured while the run was written
    with progress_bar(run.index.n_frames, tty, "measures") as bar:
        bar.unit = "frame"
        if compact:
            got = measure_columns(run, progress=bar.update)
        else:
            got = measure_frames(run, progress=bar.update, head=head)
    if compact:
        size = len(got["cols"]) * run.index.n_frames
        if size > MAX_VALUES:
            raise TooLargeError(
                f"{run.index.path}: {len(got['cols'])} particles that moved or whose "
                f"neighbours moved × {run.index.n_frames} frames = {size:.3g} values per "
                f"measure, more than the {MAX_VALUES:.3g} the stress post-processing holds in "
                "memory; dump fewer frames (--dump-every) or analyse a part of the run")
        values = {m: Columns(got["cols"], got[m], got["rest"][m]) for m in MEASURES}
    else:
        values = {m: got[m] for m in MEASURES}
    if virial:
        values["virial"] = VirialStress(run).run().results.per_particle
    units, extras = {}, {}
    if stress is not None:
        r = stress.run().results
        values["von_mises"] = r.von_mises
        units["von_mises"] = stress.UNITS
        extras = {m: r[m].astype(np.float32) for m in EXTRAS}    # pictures' precision: half
        sides = r.get("contact_sides")
        if "contact_pressure" in r:          # parts in contact: a measure of its own (its
            values["contact_pressure"] = r.contact_pressure      # peaks, pictures, VTK)
            units["contact_pressure"] = stress.UNITS
    u = (run.scene or {}).get("units") or {}
    if u.get("name") not in (None, "paper"):          # the scene's own units, not generic ones
        units.update({"paper": u["length"], "accumulated": f"{u['length']}·{u['time']}",
                      "d2min": f"{u['length']}²"})
    for name, fn in EXTRA_MEASURES.items():
        values[name] = fn(run, values)
    fields = Fields(got["steps"], values, units=units, extras=extras,
                    contact_sides=sides if stress is not None else None)
    fields.timings["compute_s"] = time.perf_counter() - t0
    fields.timings["cached"] = False
    fields.timings["frames_measured_while_running"] = head.used if head is not None else 0
    if head is not None and head.error:
        fields.timings["follow_error"] = head.error
    if save and not run.truncation and not compact:
        _save_cache(run, fields, path)
    if key is not None:
        _MEMO.clear()                 # one run's fields at a time
        _MEMO[key] = fields
    return fields


def _compactable(run, virial: bool, stress) -> bool:
    """Whether the measures can be kept over the moving particles only
    (:func:`~rackstress.stress.measures.measure_columns`): a dump that follows what moves (the
    others rest where particles.data puts them), the built-in measures only (no virial, no
    bindings' stress, no registered measure, which take every column)."""
    return bool(run.index.partial and not virial and stress is None and not EXTRA_MEASURES
                and any(p.kind == "sediment" for p in run.parts.values()))


# ----------------------------------------------------------------------------- while it runs
class Head:
    """Chunks of frames measured while the run was written (:func:`follow`), each with what it
    was measured from: the frames' steps and a CRC of their bytes in the dump. A chunk is
    handed to :func:`~rackstress.stress.measures.measure_frames` only if the finished dump holds
    the same bytes there (a run cut after divergence, or resumed, measures the rest anew).
    The frames' atom tables, parsed from the dump's text to measure them, go with the chunk
    into the finished run's reader (:meth:`chunk`): post-processing's forked VTK writer, plots
    and 3D view read the frames from it, and each parsed those text frames again (0.2-0.3 s
    of CPU each on magpod-small, after the simulation)."""

    def __init__(self):
        self.hood = None
        self.done: dict = {}          # (first frame, count) → ((steps, crc), (paper, strain, d2min))
        self.tables: dict = {}        # frame → its atom table as follow's reader parsed it
        self.used = 0                 # frames handed to measure_frames
        self.error = None             # why follow stopped early, if it did
        self.run = None               # the run as follow last opened it (still being written)
        self.seen: list = []          # (time, frames written) when follow first and last looked
        self.frames = 0               # the frames the finished run will hold

    def saw(self, written: int, now: float | None = None) -> None:
        """Note that the dump holds ``written`` frames at ``now`` (``time.perf_counter()``)."""
        import time

        seen = (time.perf_counter() if now is None else now, written)
        self.seen = [self.seen[0], seen] if self.seen else [seen]

    def seconds_left(self, now: float | None = None) -> float:
        """The run's time left until its last frame, at the pace of the frames written since
        follow first looked (infinite until that pace is known)."""
        import time

        if len(self.seen) < 2 or self.seen[1][1] <= self.seen[0][1]:
            return float("inf")
        (t0, n0), (t1, n1) = self.seen
        now = time.perf_counter() if now is None else now
        return max(0.0, (self.frames - n1) * (t1 - t0) / (n1 - n0) - (now - t1))

    def keep_tables(self, run, ks, frames: int) -> None:
        """Keep the atom tables of frames ``ks`` that ``run``'s reader holds (its cache,
        :meth:`rackstress.stress.dump.RackDumpReader._table`) where the finished run's reader
        would hold them: its ``frames`` within :data:`~rackstress.stress.dump.CACHE_BYTES`."""
        from rackstress.stress.dump import CACHE_BYTES

        held = run.trajectory.__dict__.get("_tables") or {}
        for k in ks:
            if k in held and held[k].nbytes * frames <= CACHE_BYTES:
                self.tables[k] = held[k]

    @staticmethod
    def stamp(run, ks) -> tuple | None:
        """(steps, CRC of the frames' bytes) of frames ``ks`` of ``run``'s dump, or None."""
        import zlib

        idx = run.index
        start, end = getattr(idx, "atoms_start", None), getattr(idx, "atoms_end", None)
        if start is None or end is None:
            return None
        a, b = int(start[ks[0]]), int(end[ks[-1]])
        with open(idx.path, "rb") as fh:
            fh.seek(a)
            crc = zlib.crc32(fh.read(b - a))
        return tuple(int(s) for s in idx.steps[ks[0]:ks[-1] + 1]), crc

    def chunk(self, run, ks):
        got = self.done.get((ks[0], len(ks)))
        try:            # the dump follow read, or the finished (compressed) one: compare bytes
            same = got is not None and self.stamp(run, ks) == got[0]
        except (OSError, ValueError, IndexError, TypeError):
            same = False
        if not same:
            return None
        self.used += len(ks)
        self._hand_tables(run, ks)
        return got[1]

    def _hand_tables(self, run, ks) -> None:
        """The kept tables of frames ``ks`` (the same bytes: :meth:`chunk` compared them) into
        ``run``'s reader cache, where the reader itself would keep them (the whole dump within
        :data:`~rackstress.stress.dump.CACHE_BYTES`)."""
        from rackstress.stress.dump import CACHE_BYTES

        reader = run.trajectory
        if not hasattr(reader, "_table"):
            return
        cache = reader.__dict__.setdefault("_tables", {})
        for k in ks:
            table = self.tables.pop(k, None)
            if table is not None and table.nbytes * run.index.n_frames <= CACHE_BYTES:
                cache.setdefault(k, table)


#: run directory → its :class:`Head` (filled by :func:`follow`, used by :func:`compute_fields`)
_HEADS: dict = {}


def follow(rundir, stop, frames: int, poll: float = 0.2, idle=None) -> None:
    """Measure the run's frames while LAMMPS writes them (``rackstress run``, in the thread of
    :func:`rackstress.render.prepare.prepare_in_background`, on the core the simulation
    leaves idle): every whole chunk of :func:`~rackstress.stress.measures.measure_frames` that
    the dump holds, until ``stop`` (a ``threading.Event``) is set. ``frames``: how many the
    run will write (the chunks are those of the finished run); ``idle()``, if given, is called
    while no whole chunk is new, and ``poll`` seconds waited only when it returns False (it
    did nothing: :func:`rackstress.render.prepare.prepare_in_background`'s imports and
    compression, a step a call). Nothing is written; a failure only leaves the rest to
    post-processing."""
    from rackstress.stress.measures import frame_chunk, measure_chunk, neighbourhoods
    from rackstress.stress.rundata import grown, load_run

    import threading

    key = str(Path(rundir).resolve())
    head = _HEADS[key] = Head()
    head.frames = frames
    dump = Path(rundir) / "trajectory.dump"
    need, chunk, parts, a, failed, run = 1, None, None, 0, 0, None
    main = threading.main_thread()
    # ends when stopped, or when the command ends without stopping it (an error: the
    # interpreter's exit marks the main thread stopped before it waits for this one)
    wait = 0
    while not stop.wait(wait) and main.is_alive():
        try:
            size = dump.stat().st_size
            if size < need:             # not yet the bytes of a new whole chunk: no reading
                wait = 0 if idle is not None and idle() else poll
                continue
            wait = 0
            run = load_run(rundir, allow_truncated=True) if run is None else grown(run)
            head.run = run
            head.saw(run.index.n_frames)
            if head.hood is None:
                parts = list(run.parts.values())
                head.hood = neighbourhoods(run, parts)
                chunk = frame_chunk(run.n_atoms, head.hood, frames)
            while a + chunk <= run.index.n_frames and not stop.is_set() and main.is_alive():
                ks = range(a, a + chunk)
                got = measure_chunk(run, head.hood, parts, ks)
                head.keep_tables(run, ks, frames)
                head.done[(a, chunk)] = (Head.stamp(run, ks), got)
                a += chunk
            # the next chunk's frames, at the bytes a frame has taken so far
            need = size + 1 + (a + chunk - run.index.n_frames) * size // max(run.index.n_frames, 1)
            failed = 0
        except Exception as exc:  # noqa: BLE001 - a head start only: post-processing measures the rest
            failed += 1                 # a frame caught mid-write reads as a bad one: retry
            run = None                  # from a new load_run
            head.error = f"{type(exc).__name__}: {exc}"[:300]
            if failed > 5:
                return


def _head(run):
    return _HEADS.pop(str(Path(run.rundir).resolve()), None)


# ----------------------------------------------------------------------------- peaks
def peaks(run, fields: Fields) -> dict:
    """For every coloured part and measure, the largest value over the whole run and where it was.

    Racks and sediments get none: a rack is the paper's invisible mechanism and a sediment has no
    rest shape, so a distance from a desired position means nothing there (when a run has only
    such groups, as a foreign dump may, every group gets its peaks). Returns ``{group: {measure: record}}`` with record ``{"value", "iteration", "frame",
    "time", "particle" (LAMMPS atom id), "index" (0-based in the group), "position" (x, y, z at
    that iteration), "original" (its original position o), "units"}``, or None for a measure
    undefined on every particle of the group. Ties go to the earliest frame, then the lowest id.
    """
    out, need = {}, {}
    ids = run.data.ids
    for part in run.displayed() or list(run.parts.values()):
        name = part.name
        out[name] = {}
        for m, v in fields.values.items():
            sub = v[:, part.index]
            finite = np.isfinite(sub)
            if not finite.any():
                out[name][m] = None
                continue
            flat = int(np.argmax(np.where(finite, sub, -np.inf)))
            k, j = divmod(flat, sub.shape[1])
            row = int(part.index[j])
            out[name][m] = {"value": float(sub[k, j]), "iteration": int(fields.steps[k]),
                            "frame": int(k), "time": float(fields.steps[k] * run.dt),
                            "particle": int(ids[row]), "index": int(j),
                            "original": [float(x) for x in run.o[row]],
                            "units": fields.unit(m)}
            need.setdefault(k, []).append((name, m, row))
    for k, todo in sorted(need.items()):
        p = positions(run.trajectory[k])
        for name, m, row in todo:
            out[name][m]["position"] = [float(x) for x in p[row]]
    return out


def overall_peak(run, group_peaks: dict, measure: str = "paper") -> dict | None:
    """The largest ``measure`` over the parts pictures colour (not racks, not sediments)."""
    best = None
    for part in run.displayed() or list(run.parts.values()):
        rec = group_peaks.get(part.name, {}).get(measure)
        if rec is not None and (best is None or rec["value"] > best["value"]):
            best = {"group": part.name, "measure": measure, **rec}
    return best


# ----------------------------------------------------------------------------- warnings
#: the warnings post-processing adds to ``summary.json`` (replaced, not repeated, when run again)
STRESS_WARNINGS = ({"kind": "large_strain"}, {"kind": "yield_exceeded"})


def _argmax(v: np.ndarray):
    """(frame, column) of the largest finite value of a (frames × n) array, or None."""
    fin = np.isfinite(v)
    if not fin.any():
        return None
    return divmod(int(np.argmax(np.where(fin, v, -np.inf))), v.shape[1])


def stress_warnings(run, fields: Fields) -> list:
    """The parts strained beyond small-strain validity and the parts stressed beyond yield.

    ``large_strain``: some binding of the part stretched or shortened by more than
    :data:`STRAIN_LIMIT` (|d/L0 − 1|, the bindings' own engineering strain). ``yield_exceeded``:
    the part's von Mises stress above its material's yield strength. Each names the part, the
    particle (LAMMPS atom id), the iteration and the value.
    """
    out = []
    mats = material_parts(run)
    bs, vm = fields.extras.get("bind_strain"), fields.values.get("von_mises")
    for name, rec in mats.items():
        part = run.parts[name]
        if bs is not None and (hit := _argmax(bs[:, part.index])) is not None:
            k, j = hit
            value = float(bs[k, part.index[j]])
            if value > STRAIN_LIMIT:
                pid, it = int(run.data.ids[part.index[j]]), int(fields.steps[k])
                out.append({"kind": "large_strain", "group": name, "particle": pid,
                            "iteration": it, "value": value, "limit": STRAIN_LIMIT,
                            "message": f"part '{name}': a binding of particle {pid} is strained "
                            f"{100 * value:.3g} % (|d/L0 - 1|) at iteration {it}, beyond the "
                            f"~{100 * STRAIN_LIMIT:g} % of small-strain validity: the stress, "
                            "a linear-elastic reading, is doubtful there"})
        y = (rec.get("material") or {}).get("yield")
        if vm is not None and y and (hit := _argmax(vm[:, part.index])) is not None:
            k, j = hit
            value = float(vm[k, part.index[j]])
            if value > y:
                pid, it = int(run.data.ids[part.index[j]]), int(fields.steps[k])
                over = int(np.sum(vm[k, part.index] > y))
                unit = fields.unit("von_mises")
                mat = rec["material"].get("name", "its material")
                out.append({"kind": "yield_exceeded", "group": name, "particle": pid,
                            "iteration": it, "value": value, "yield": float(y), "units": unit,
                            "particles_above": over,
                            "message": f"part '{name}': von Mises stress {value:.4g} {unit} at "
                            f"particle {pid}, iteration {it}, exceeds the yield strength "
                            f"{y:.4g} {unit} of {mat} ({over} particle(s) above yield then); "
                            "the part would yield: a linear-elastic answer beyond it is not "
                            "the real part's"})
    return out


def contact_summary(run, fields: Fields) -> list:
    """Per pair of parts in contact (``[[contact]]``): the largest contact pressure over the
    run — a particle's contact force from the other part over its cell's face a² — where
    (particle, its part) and when, how many particles of each part touch then and the force
    the contact carries then (statics: the load it passes on). Empty without contact."""
    cs = fields.contact_sides
    if cs is None or not cs.shape[1]:
        return []
    from rackstress.stress.measures import contact_parts, read_contacts

    pairs: dict = {}
    for m, a, b in contact_parts(run, read_contacts(run)[0]):
        pairs.setdefault(frozenset((a, b)), []).append((m, a))
    out = []
    unit = fields.unit("von_mises") if "von_mises" in fields.values else "stress units"
    force_unit = ((run.scene or {}).get("units") or {}).get("force", "force units")
    for key, ms in pairs.items():
        parts = [ms[0][1]] + sorted(key - {ms[0][1]})
        peak = np.max([cs[:, m, 0] for m, _ in ms], axis=0)       # per frame
        if not peak.max() > 0:
            out.append({"parts": parts, "touching": False, "units": unit})
            continue
        k = int(np.argmax(peak))
        m, side = max(ms, key=lambda e: cs[k, e[0], 0])
        q = int(cs[k, m, 1])
        out.append({"parts": parts, "touching": True, "peak": float(cs[k, m, 0]),
                    "units": unit, "group": side, "particle": int(run.data.ids[q]),
                    "iteration": int(fields.steps[k]),
                    "particles_touching": {a: int(cs[k, e, 2]) for e, a in ms},
                    "force": {a: cs[k, e, 3:6].tolist() for e, a in ms},
                    "force_units": force_unit})
    return out


def safety(run, fields: Fields, gov: dict | None = None) -> dict:
    """Per part with a yield strength: the smallest factor of safety (yield / von Mises) over
    the run, where and when — by the governing stress's rule (:mod:`.governing`: away from
    singular points, at the governing particle) when ``gov`` (its :func:`~.governing.record`)
    has the part; the smallest over every particle is kept beside it as ``singular_min``."""
    out = {}
    sf = fields.extras.get("safety")
    if sf is None:
        return out
    parts = (gov or {}).get("parts") or {}
    for name in material_parts(run):
        part = run.parts[name]
        hit = _argmax(-sf[:, part.index])
        if hit is None:
            continue
        k, j = hit
        rec = {"min": float(sf[k, part.index[j]]), "iteration": int(fields.steps[k]),
               "particle": int(run.data.ids[part.index[j]]), "frame": int(k)}
        g = (parts.get(name) or {}).get("governing")
        if g is not None and g.get("safety") is not None:
            rec = {"min": g["safety"], "iteration": g["iteration"], "particle": g["particle"],
                   "frame": g["frame"], "rule": "governing", "zone": g["zone"],
                   "singular_min": rec["min"], "singular_particle": rec["particle"]}
        out[name] = rec
    return out


# ----------------------------------------------------------------------------- the step
#: VTK writers still running in the background (output directory → export.VtkJob)
_PENDING: dict = {}


def postprocess(rundir, vtk: bool = True, dump: bool = False, progress: bool = False,
                run=None, out=None, log=None, allow_truncated: bool = False,
                vtk_format: str = "paraview", background: bool = False,
                vtk_measures: str = "all") -> dict:
    """Compute the measures once, write the peaks into ``summary.json`` and the files.

    Parameters
    ----------
    rundir : path
        A run directory (``rackstress run``); ignored when ``run`` is given.
    vtk, dump : bool
        Write ``vtk/run.pvd`` (one ``.vtp`` a frame) and ``stress.dump``.
    vtk_format : {"paraview", "ovito"}
        Compressed (ParaView, pyvista) or the variant OVITO reads (:mod:`.export`).
    vtk_measures : {"all", "default"}
        Every measure in every VTK frame, or the leading one beside ``displacement``
        (``rackstress run``; :data:`.export.MEASURES`).
    background : bool
        Write the VTK files in a forked process and return at once; :func:`wait_files` joins
        it and records its time (``rackstress run``: the pictures are painted meanwhile).
    progress : bool
        Progress bars on a terminal.
    run : RunData, optional
        An already opened run (e.g. a plain LAMMPS data file and dump, :mod:`.foreign`).
    out : path, optional
        Where to write (default: the run directory).

    Returns
    -------
    dict
        What ``stress.json`` holds: the peaks per group, the overall peak of the paper measure,
        the files written and the timings.

    Example
    -------
    >>> postprocess("runs/magpod-small")["peak"]["iteration"]   # doctest: +SKIP
    """
    from rackstress.stress.rundata import load_run

    t0 = time.perf_counter()
    if run is None:
        run = load_run(rundir, allow_truncated=allow_truncated)
    out = Path(out) if out is not None else Path(run.rundir)
    from rackstress.runs.rundir import is_run, own

    if not is_run(out):         # a folder of the user's choosing: never over their own files
        own(out, [STRESS_JSON] + [VTK_DIR] * bool(vtk) + [STRESS_DUMP] * bool(dump),
            "the stress files")
    out.mkdir(parents=True, exist_ok=True)
    fields = compute_fields(run, progress=progress)
    group_peaks = peaks(run, fields)
    from rackstress.stress.governing import record as governing_record
    from rackstress.stress.headline import is_static

    gov = governing_record(run, fields)
    static = is_static(run.rundir)
    info = {"fit": FIT, "measures": {m: {"label": LABELS[m][0], "units": fields.unit(m)}
                                     for m in fields.measures},
            "default_measure": fields.default,
            "frames": len(fields.steps), "first_iteration": int(fields.steps[0]),
            "last_iteration": int(fields.steps[-1]),
            "peak": overall_peak(run, group_peaks, fields.default), "groups": group_peaks,
            "warnings": stress_warnings(run, fields), "safety": safety(run, fields, gov),
            "contact": contact_summary(run, fields),
            "files": {},
            "timings": {"measures_s": fields.timings.get("compute_s", 0.0),
                        "frames_measured_while_running":
                            fields.timings.get("frames_measured_while_running", 0)}}
    if fields.timings.get("follow_error"):
        info["timings"]["follow_error"] = fields.timings["follow_error"]
    if gov:
        info.update(governing=gov["governing"], singular=gov["singular"],
                    error=gov.get("error"), governing_parts=gov["parts"])
    from rackstress.stress import export

    extra = ()
    if vtk and static and vtk_format == "paraview":
        # the part's surface, the stress painted on it (stress/surface.py): made here once,
        # for the VTK directory and for the pictures and 3D view that follow in this process
        from rackstress.stress.surface import SURFACE_VTP, surfaces_for, write_surface

        t, c = time.perf_counter(), time.process_time()
        surfs = surfaces_for(run, fields, notes=info.setdefault("notes", []))
        info["timings"]["surface_s"] = time.perf_counter() - t
        info["timings"]["surface_cpu_s"] = time.process_time() - c
        if not info["notes"]:
            info.pop("notes")
        extra = ((SURFACE_VTP, lambda path: write_surface(surfs, path)),)
        info["files"]["surface"] = f"{VTK_DIR}/{SURFACE_VTP}"
    elif vtk and vtk_format == "paraview" and len(fields.steps) > 1 and \
            "von_mises" in fields.values:
        # a material part in time: each particle's peak over the frames, and when
        # (export.py; the paper's scenes, without a material, write what they wrote)
        extra = ((export.PEAKS_VTP, lambda path: export.write_peaks_over_time(run, fields,
                                                                               path)),)
        info["files"]["peaks_over_time"] = f"{VTK_DIR}/{export.PEAKS_VTP}"
    if vtk and background:
        from rackstress.lib.runfiles import PVD

        _PENDING[str(out.resolve())] = export.VtkJob(run, fields, out / VTK_DIR, vtk_format,
                                                      vtk_measures, extra=extra)
        info["files"]["vtk"] = f"{VTK_DIR}/{PVD}"
    elif vtk:
        t = time.perf_counter()
        pvd = export.write_vtk(run, fields, out / VTK_DIR, progress=progress, fmt=vtk_format,
                               measures=vtk_measures, extra=extra)
        info["files"]["vtk"] = str(pvd.relative_to(out))
        info["timings"]["vtk_s"] = time.perf_counter() - t
    if dump:
        t = time.perf_counter()
        path = export.write_stress_dump(run, fields, out / STRESS_DUMP, progress=progress)
        info["files"]["dump"] = str(path.relative_to(out))
        info["timings"]["dump_s"] = time.perf_counter() - t
    info["timings"]["total_s"] = time.perf_counter() - t0
    write_json(out / STRESS_JSON, info)
    summary_path = Path(run.rundir) / "summary.json"      # the run's own record
    if summary_path.is_file():
        summary = add_to_summary(summary_path, info)
        if info.get("governing") is not None:      # --refine's error bar, where it was kept
            info["error"] = (summary.get("stress") or {}).get("error")
        if static:          # what the end-of-run lines lead with (describe)
            from rackstress.stress.headline import headline

            info["static"] = {"settled": summary.get("settled", True) is not False,
                              "residual": summary.get("residual"),
                              "iterations": summary.get("iterations"),
                              "headline": headline(summary, run.scene, run.rundir)}
    if log is not None:
        for line in describe(info):
            log(line)
    return info


def wait_files(out) -> float | None:
    """Join the VTK writer :func:`postprocess` left running for ``out`` (if any); record its
    wall and CPU time in ``stress.json``; return the wall time. Raises what the writer raised."""
    job = _PENDING.pop(str(Path(out).resolve()), None)
    if job is None:
        return None
    _, wall = job.join()
    path = Path(out) / STRESS_JSON
    try:
        info = json.loads(path.read_text())
        info.setdefault("timings", {})["vtk_s"] = wall
        if job.job.cpu_s is not None:
            info["timings"]["vtk_cpu_s"] = job.job.cpu_s
        write_json(path, info)
    except (OSError, json.JSONDecodeError):
        pass
    return wall


def cancel_files(out) -> None:
    """Stop the VTK writer left running for ``out`` (an error elsewhere ended the command)."""
    job = _PENDING.pop(str(Path(out).resolve()), None)
    if job is not None:
        job.kill()


def add_to_summary(summary_path: Path, info: dict) -> dict:
    """Put the peaks into ``summary.json`` (atomically): ``groups.<name>.peak.<measure>`` and a
    top-level ``stress`` record (fit, overall peak, files)."""
    try:
        summary = json.loads(Path(summary_path).read_text())
    except json.JSONDecodeError as exc:
        raise StressInputError(f"{summary_path}: not valid JSON ({exc})") from None
    summary_before = summary.get("stress") or {}
    groups = summary.setdefault("groups", {})
    for name, rec in info["groups"].items():
        groups.setdefault(name, {})["peak"] = rec
    summary["stress"] = {"fit": info["fit"], "peak": info["peak"], "files": info["files"],
                         "measures": info["measures"],
                         "default_measure": info.get("default_measure", "paper")}
    if info.get("safety"):
        summary["stress"]["safety"] = info["safety"]
    if info.get("governing") is not None or info.get("singular") is not None:
        old = (summary_before or {}).get("error") or {}
        summary["stress"].update(governing=info.get("governing"), singular=info.get("singular"),
                                 zone_parts=info.get("governing_parts"))
        # the error bar of --refine (measured) outlives a post-processing run again
        summary["stress"]["error"] = old if old.get("extrapolated") is not None else \
            info.get("error")
    kinds = {w["kind"] for w in STRESS_WARNINGS}
    kept = [w for w in summary.get("warnings") or [] if w.get("kind") not in kinds]
    summary["warnings"] = kept + list(info.get("warnings") or [])
    write_json(summary_path, summary)
    return summary


def describe(info: dict, governing: bool = True) -> list:
    """Lines for the terminal: the overall peak, and per group the peaks of the paper measure
    and of the strain (the hot-spot measure of an elastic body, README "What the picture
    means"); for a part with a material the governing stress last, in the peak's place
    (``governing``: False leaves it to the caller, who says it at the very end). A static
    run's (``info["static"]``, :func:`describe_static`) say whether it settled and lead with
    its headline."""
    if info.get("static"):
        return describe_static(info, governing)
    lines = []
    pk = info.get("peak")
    gov = info.get("governing")
    if pk and not gov:
        lines.append(f"  peak {pk['measure']} = {pk['value']:.4g} {pk['units']} in {pk['group']} "
                     f"at iteration {pk['iteration']}, particle {pk['particle']} at "
                     f"({', '.join(f'{x:.3g}' for x in pk['position'])})")
    for name, rec in info["groups"].items():
        shown = [f"{m}={p['value']:.4g}{' ' + p['units'] if m == 'von_mises' else ''} "
                 f"(iteration {p['iteration']}, particle {p['particle']})"
                 for m in ("von_mises", "paper", "strain") if (p := rec.get(m)) is not None]
        if shown:
            lines.append(f"  {name:12s} peak " + "; ".join(shown))
    lines.extend(describe_contact(info))
    for name, sf in (info.get("safety") or {}).items():
        if sf.get("rule") == "governing":
            continue                        # said with the governing stress
        lines.append(f"  {name:12s} smallest factor of safety {sf['min']:.3g} (iteration "
                     f"{sf['iteration']}, particle {sf['particle']})")
    for w in info.get("warnings") or []:
        lines.append(f"  warning: {w['message']}")
    for key, path in info["files"].items():
        lines.append(f"  {key}: {path}")
    for note in info.get("notes") or []:
        lines.append(f"  note: {note}")
    if gov and governing:
        lines.extend(describe_governing(info))
    return lines


def describe_static(info: dict, governing: bool = True) -> list:
    """A static run's lines: its headline stress (:func:`rackstress.stress.headline.headline`:
    where in the part's own undeformed coordinates, the smallest factor of safety of the same
    rule) and per group the largest von Mises stress and strain — or, for a run that did not
    settle, that it gives no result (``summary.json`` keeps the numbers of its state). With a
    governing stress its block (:func:`describe_governing`: zone, error bar, singular peak)
    comes last, or, ``governing`` False, is left to the caller (said at the very end)."""
    from rackstress.stress.headline import headline_text

    st = info["static"]
    lines = []
    if not st["settled"]:
        lines.append("  NOT SETTLED: no stress or factor of safety is reported: the state is not "
                     "an equilibrium, do not use its numbers (summary.json keeps them; 'rackstress "
                     "render RUNDIR --allow-unsettled' shows them in the report)")
    else:
        if st.get("headline") and not info.get("governing"):
            lines.append("  " + headline_text(st["headline"]) + " (undeformed coordinates)")
        for name, rec in info["groups"].items():
            shown = [f"{m}={p['value']:.4g}{' ' + p['units'] if m == 'von_mises' else ''} "
                     f"(particle {p['particle']})"
                     for m in ("von_mises", "strain") if (p := rec.get(m)) is not None]
            if shown:
                lines.append(f"  {name:12s} largest " + "; ".join(shown))
        lines.extend(describe_contact(info))
    kinds = {w["kind"] for w in STRESS_WARNINGS}
    for w in info.get("warnings") or []:
        if st["settled"] or w.get("kind") not in kinds:   # no stress of a non-equilibrium
            lines.append(f"  warning: {w['message']}")
    for key, path in info["files"].items():
        lines.append(f"  {key}: {path}")
    for note in info.get("notes") or []:
        lines.append(f"  note: {note}")
    if st["settled"] and info.get("governing") and governing:
        lines.extend(describe_governing(info))
    return lines


def describe_contact(info: dict) -> list:
    """A line per pair of parts in contact (:func:`contact_summary`)."""
    lines = []
    for c in info.get("contact") or []:
        a, b = c["parts"]
        if not c["touching"]:
            lines.append(f"  contact {a}–{b}: the parts never touch")
            continue
        touching = ", ".join(f"{n} of {g}'s" for g, n in c["particles_touching"].items())
        lines.append(f"  contact {a}–{b}: largest contact pressure {c['peak']:.4g} {c['units']} "
                     f"on {c['group']} particle {c['particle']} (iteration {c['iteration']}); "
                     f"{touching} particles pressed then; force on {a} "
                     f"({', '.join(f'{x:.4g}' for x in c['force'][a])}) {c['force_units']}")
    return lines


def describe_governing(info: dict) -> list:
    """The headline lines: the governing stress (where, its safety factor, the zone) — a static
    run's as its headline says it (:func:`rackstress.stress.headline.headline_text`) —, the
    singular peak beside it (spacing-dependent, what to do) and the error bar."""
    from rackstress.stress.governing import describe as gov_lines

    if (info.get("static") or {}).get("settled") is False:
        return []           # not an equilibrium: no stress as a result (describe_static)
    head = (info.get("static") or {}).get("headline")
    lines = gov_lines(info.get("governing"), info.get("singular"), info.get("error"),
                      headline=head is None, static=info.get("static") is not None)
    if head is not None:
        from rackstress.stress.headline import headline_text

        lines.insert(0, "  " + headline_text(head) + " (undeformed coordinates)")
    return lines
