"""Checkpoints of long LAMMPS runs and ``rackstress run --resume RUNDIR``.

A run started with ``restart_every = N`` writes, every N steps (at the first chunk boundary
at or after each multiple of N) and at its end, into ``RUNDIR/restart/``:

* ``state-<step>.restart`` — a LAMMPS restart file (``write_restart ... noinit``, so writing
  it changes nothing in the run), for anyone who wants to go on with LAMMPS alone;
* ``state-<step>.npz`` — the exact state rackstress resumes from: positions ``x``, LAMMPS
  velocities ``v`` and the last step's forces ``f``, float64 in global particle order. LAMMPS'
  ``fix nve`` holds v = v_n + dt/2·f/m between steps (the paper's v_n is v − dt/2·f/m), and a
  restart file keeps no forces, so the forces are stored to go on bit for bit;
* ``phase-end-<k>.npz`` — the state at each phase end so far (what a scene's ``report`` reads);

and then, atomically, ``RUNDIR/progress.json``: the step, the phase (index in the schedule and
steps done in it), the cycle, the files above, the engine settings and the wall time so far.
``progress.json`` is the commit point: a run killed at any moment leaves it naming a complete
checkpoint. Older checkpoints are deleted once a newer one is committed.

Resuming rebuilds the scene from ``scene.json`` (or from the scene given again, which must match
it), starts LAMMPS from ``particles.data`` as the first part did, replays every phase switch up
to the checkpoint's phase (so the fixes sum their forces in the same order), sets the step, x
and v, runs ``run 0`` (neighbour lists), puts the forces back and continues the schedule.
Frames of ``trajectory.dump`` after the checkpoint's step are cut off and written again, and the
log is appended to. Writing a checkpoint also runs that ``run 0`` (and puts the forces
back), so the uninterrupted run builds its neighbour lists (and shrink-wraps its box) at the same
steps as the resumed one: in serial the resumed run equals the uninterrupted one bit for bit,
trajectory file included. (With a pair style, MagPod's collisions, a run with checkpoints
therefore sums its pair forces in a different order than one without: equal to round-off.)
Under MPI the atoms may be spread differently after resuming, and sums are then equal to
round-off.
"""
from __future__ import annotations

import json
import mmap
from pathlib import Path

import numpy as np

from rackstress.errors import ResumeError, RunDirError
from rackstress.lib.jsonio import jsonable
from rackstress.lib.runfiles import DERIVED
from rackstress.model.scene import PhaseEnd

from rackstress.runs.checkpoint import (PROGRESS, RESTART_DIR, Checkpoint, Checkpointer,  # noqa: F401
                                      default_restart_every)


# ---------------------------------------------------------------------------- reading
def read_progress(rundir: Path) -> dict:
    rundir = Path(rundir)
    path = rundir / PROGRESS
    if not path.exists():
        raise RunDirError(f"{rundir} has no {PROGRESS}: the run wrote no checkpoint to resume "
                          "from (runs write them with --restart-every; the first comes after "
                          "that many steps)")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise RunDirError(f"{path} is not valid JSON: {exc}") from None


def load_checkpoint(rundir: Path, meta: dict | None = None) -> Checkpoint:
    rundir = Path(rundir)
    meta = meta or read_progress(rundir)
    with np.load(rundir / meta["state"]) as z:
        x, v, f = z["x"], z["v"], z["f"]
        moving = z["moving"] if "moving" in z.files else None
    return Checkpoint(int(meta["step"]), int(meta["phase_index"]), int(meta["phase_done"]),
                      int(meta["cycle"]), x, v, f, meta, moving)


def load_phase_ends(rundir: Path, meta: dict) -> list[PhaseEnd]:
    out = []
    for name in meta.get("phase_ends", []):
        with np.load(Path(rundir) / RESTART_DIR / name) as z:
            m = json.loads(str(z["meta"]))
            out.append(PhaseEnd(int(z["step"]), m["phase"], m["vars"], int(z["cycle"]),
                                z["p"].copy()))
    return out


def truncate_dump(path: Path, step: int) -> int:
    """Cut ``trajectory.dump`` before its first frame after ``step`` (or a torn frame); return
    the number of frames kept. A frame at ``step`` itself was complete before the checkpoint was
    committed, so it stays (the resumed run writes from the next frame on)."""
    path = Path(path)
    if not path.exists() or path.stat().st_size == 0:
        return 0
    marker = b"ITEM: TIMESTEP\n"
    with open(path, "r+b") as fh:
        mm = mmap.mmap(fh.fileno(), 0)
        try:
            pos, kept, cut = 0, 0, None
            while True:
                at = mm.find(marker, pos)
                if at < 0:
                    break
                end = mm.find(b"\n", at + len(marker))
                try:
                    s = int(mm[at + len(marker):end]) if end > 0 else None
                except ValueError:
                    s = None
                if s is None or s > step:
                    cut = at
                    break
                kept += 1
                pos = at + len(marker)
        finally:
            mm.close()
        if cut is not None:
            fh.truncate(cut)
    return kept


def remove_derived(rundir: Path) -> None:
    """Remove files derived from the trajectory before it continues (they would mix two lengths;
    ``rackstress stress`` may have been run on the killed run)."""
    import shutil

    for name in DERIVED:
        path = Path(rundir) / name
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        elif path.exists():
            path.unlink()


def rebuild_scene(rundir: Path, spec: str | None = None):
    """The scene of a run directory: from ``spec`` (a name or .toml, checked against
    ``scene.json``) or from the name and parameters recorded in ``scene.json``."""
    from rackstress import scenes
    from rackstress.runs.run import scene_record

    rundir = Path(rundir)
    try:
        rec = json.loads((rundir / "scene.json").read_text())
    except FileNotFoundError:
        raise RunDirError(f"{rundir} is not a run directory (no scene.json)") from None
    params = dict(rec.get("params") or {})
    steps = params.pop("steps", None)
    src = rec.get("source")
    # a scene file's run is rebuilt from its file even when it shares a built-in scene's name
    # (examples/cantilever/scene.toml is named "cantilever", like the planar built-in)
    if spec is None and (src or rec["scene"] not in scenes.BUILDERS):
        if not src or not Path(src).is_file():
            raise ResumeError(f"scene '{rec['scene']}' of {rundir} was read from a scene file, "
                              f"{src or '(unknown)'}, which is gone: give its scene file again, "
                              f"e.g. 'rackstress run SCENE.toml --resume {rundir}'")
        spec = src
    name = spec or rec["scene"]
    if spec is None:
        known = scenes.parameters(name)
        sc = scenes.build(name, **{k: v for k, v in params.items() if k in known})
    else:
        # the file's own [params] as the run had them (its --set overrides included); a
        # duration-given scene gets its steps from the duration, not from a recorded count
        # (a step-given one keeps them); "analysis" is recorded from the file's own key
        # (static), not a --set parameter
        given = {k: v for k, v in params.items()
                 if k not in scenes.RECORDED_ONLY
                 or (k == "steps" and "duration" not in params)}
        sc = scenes.load(spec, given, spacing_scale=float(params.get("spacing_scale", 1.0)),
                         lattice_shift=params.get("lattice_shift"))
        dt = params.get("dt")
        if dt is not None and dt != sc.dt:
            sc = sc.with_dt(float(dt))
    integrator = params.get("integrator")
    if integrator is not None:         # how the run integrated (an option, not a scene key)
        sc.integrator = integrator
        sc.params["integrator"] = integrator
    if sc.dt != rec["dt"]:
        sc = sc.with_dt(float(rec["dt"]))
    if steps is not None or sc.total_steps != rec["steps"]:
        sc = sc.with_steps(int(rec["steps"]))
    mine = json.loads(json.dumps(scene_record(sc), default=_plain))
    for key in ("scene", "dt", "steps", "phases", "groups"):
        if mine.get(key) != rec.get(key):
            raise ResumeError(f"the scene rebuilt for {rundir} differs from its scene.json in "
                              f"'{key}': cannot resume it")
    return sc


def _plain(x):
    return jsonable(x)


def resume_run(rundir: Path, spec: str | None = None, progress: bool = True, comm=None) -> dict:
    """Continue the interrupted LAMMPS run in ``rundir``; return its summary (as
    :func:`rackstress.runs.run.run`).

    The scene is rebuilt (from ``spec``, or from ``scene.json``: a built-in scene by name and
    parameters, a TOML scene from the file it was read from) and its fingerprint
    (:mod:`rackstress.runs.fingerprint`) must equal the checkpoint's: an edited scene file, other
    parameters or another dt are refused, naming what changed. The run directory is held
    locked while it runs.

    Raises
    ------
    ResumeError
        The checkpoint belongs to another run, or there is none.
    DivergenceError
        After writing the summary, like a run that was never cut.
    """
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.lib.mpi import on_root, world
    from rackstress.runs.fingerprint import compare, fingerprint
    from rackstress.runs.run import check_memory, execute, operators_path
    from rackstress.runs.rundir import check_out, locked

    comm = comm or world()
    rundir = check_out(rundir)     # a missing directory: refused by locked() below

    def prepare():
        if (rundir / "summary.json").exists():
            raise RunDirError(f"{rundir} already holds a finished run (summary.json): "
                              "nothing to resume")
        meta = read_progress(rundir)
        if meta.get("engine") != "lammps":
            raise RunDirError(f"{rundir}: only LAMMPS runs can be resumed")
        for tmp in (rundir / RESTART_DIR).glob(".*.tmp"):     # a checkpoint cut short
            tmp.unlink(missing_ok=True)
        return meta

    with locked(rundir, comm=comm, create=False):
        meta = on_root(prepare, comm)
        scene = rebuild_scene(rundir, spec)
        mode, dump_every = meta["mode"], int(meta["dump_every"])
        # the operators where the interrupted run had them (plugin or callback: the sums'
        # order, hence the bits, differ between the two)
        recorded = meta.get("fingerprint") or {}
        deck = compile_deck(scene, mode, plugin=recorded.get("operators") == "plugin")
        now = fingerprint(scene, engine="lammps", mode=mode, dump_every=dump_every)
        if "operators" in recorded:
            now["operators"] = operators_path(deck)
        compare(meta.get("fingerprint"), now,
                f"the checkpoint in {rundir} (step {meta.get('step')})")
        check_memory(scene, "lammps", comm.Get_size())
        ck = load_checkpoint(rundir, meta)
        if ck.x.shape != (scene.n_particles, 3):
            raise ResumeError(f"{rundir}: checkpoint holds {len(ck.x)} particles, the scene "
                              f"{scene.n_particles}")
        try:       # the trajectory goes on as it was begun: every particle, or the moving ones
            deck.dump_all = json.loads((rundir / "scene.json").read_text()).get("dump") == "all"
        except (OSError, json.JSONDecodeError):
            pass
        on_root(lambda: (truncate_dump(rundir / "trajectory.dump", ck.step),
                         remove_derived(rundir)), comm)
        records = None
        if scene.report is not None:
            records = [PhaseEnd(0, None, {}, 0, scene.original_positions())]
            records += load_phase_ends(rundir, meta)
        return execute(scene, rundir, "lammps", mode, dump_every, progress=progress, comm=comm,
                       restart_every=int(meta["restart_every"]), deck=deck, resume=ck,
                       records=records, wall_before=float(meta.get("wall_s", 0.0)),
                       extra={"resumed_from_step": ck.step},
                       fingerprint=meta.get("fingerprint"))
