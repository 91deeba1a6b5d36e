"""Running a scene: the run directory, the engine loop, the watchdog, and ``summary.json``.

A run directory holds ``scene.json`` (how the scene was built), ``particles.data`` (particles, types,
molecules), ``trajectory.dump`` (frames every ``dump_every`` steps) and, once the run has ended
either way, ``summary.json``. A run stopped by the watchdog keeps its frames and records
``status: "diverged"`` with the step, particle and group.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from rackstress.lib import rigid
from rackstress.model import topology
from rackstress.errors import DivergenceError, RunDirError
from rackstress.lib.jsonio import write_json
from rackstress.lib.progress import progress_bar
from rackstress.model.scene import PhaseEnd, Scene

ENGINES = ("lammps", "reference")


def default_dump_every(scene: Scene) -> int:
    """About 100 frames a run, never fewer than every step."""
    return max(1, scene.total_steps // 100)


def prepare_rundir(out: Path, overwrite: bool = False) -> Path:
    """Create ``out``; refuse to reuse a directory holding a finished run unless ``overwrite``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise RunDirError(f"run directory {out} exists and is not a directory")
    if (out / "summary.json").exists() and not overwrite:
        raise RunDirError(f"run directory {out} already holds a finished run (summary.json); "
                          "choose another --out or pass --overwrite to replace it")
    out.mkdir(parents=True, exist_ok=True)
    for stale in ("summary.json", "trajectory.dump"):
        if (out / stale).exists():
            (out / stale).unlink()
    return out


def scene_record(scene: Scene) -> dict:
    """What post-processing needs to know of a scene: its groups as atom types and id ranges."""
    types, mols = topology.group_types(scene), topology.group_mols(scene)
    return {"scene": scene.name, "params": scene.params, "dt": scene.dt,
            "steps": scene.total_steps,
            "phases": [{"name": p.name, "steps": p.steps, "vars": dict(p.vars)}
                       for p in scene.phases],
            "cycles": scene.cycles,
            "groups": [{"name": name, "kind": g.kind, "host": g.host, "n": g.n,
                        "type": types[name], "mol": mols[name],
                        "first_id": scene.offset(name) + 1}
                       for name, g in scene.groups.items()]}


def group_figures(scene: Scene, p_start: np.ndarray, p_end: np.ndarray) -> dict:
    """Per group: n, centre of mass at start and end, and max_deformation (docs/model.md, "Desired position")."""
    out = {}
    for name, g in scene.groups.items():
        sl = scene.slice(name)
        end = p_end[sl]
        ok = bool(np.isfinite(end).all())
        out[name] = {
            "n": g.n,
            "kind": g.kind,
            "com_start": p_start[sl].mean(axis=0).tolist(),
            "com_end": end.mean(axis=0).tolist() if ok else None,
            "max_deformation": rigid.max_deformation(g.o, end) if ok else None,
        }
    return out


def summarize(scene: Scene, engine: str, mode: str, p_end: np.ndarray, steps_done: int,
              wall_s: float, status: str, error: DivergenceError | None = None,
              extra: dict | None = None) -> dict:
    s = {
        "scene": scene.name,
        "engine": engine,
        "mode": mode,
        "status": status,
        "n_particles": scene.n_particles,
        "steps": int(steps_done),
        "steps_requested": scene.total_steps,
        "dt": scene.dt,
        "wall_s": wall_s,
        "params": scene.params,
        "groups": group_figures(scene, scene.original_positions(), p_end),
    }
    if error is not None:
        s["error"] = {"message": str(error), "step": error.step, "group": error.group,
                      "particle": error.local, "index": error.index}
    if extra:
        s.update(extra)
    return s


def run_reference(scene: Scene, out: Path, dump_every: int, progress: bool, on_phase_end=None):
    """Step a scene with the reference engine, writing frames; returns (p_end, steps_done)."""
    from rackstress.engines.dumpio import DumpWriter
    from rackstress.engines.reference import Reference

    ref = Reference(scene)
    types = topology.per_particle(scene, topology.group_types(scene))
    mols = topology.per_particle(scene, topology.group_mols(scene))
    with DumpWriter(out / "trajectory.dump", types, mols) as dump, \
            progress_bar(scene.total_steps, progress, scene.name) as bar:
        dump.write(0, ref.p)
        try:
            for _, phase, cycle in scene.schedule():
                for _ in range(phase.steps):
                    ref.step(phase.vars)
                    if ref.step_count % dump_every == 0:
                        dump.write(ref.step_count, ref.p)
                    bar.update(1)
                if on_phase_end is not None:
                    on_phase_end(PhaseEnd(ref.step_count, phase.name, dict(phase.vars), cycle,
                                          ref.p.copy()))
        except DivergenceError as err:
            err.p_end, err.steps_done = ref.p, ref.step_count
            raise
    return ref.p, ref.step_count


def run(scene: Scene, out: Path, engine: str = "lammps", mode: str = "exact",
        dump_every: int | None = None, progress: bool = True, overwrite: bool = False,
        comm=None, restart_every: int | None = None, allow_unstable: bool = False) -> dict:
    """Run ``scene`` on ``engine`` into the run directory ``out``; return the summary.

    Raises :class:`DivergenceError` after writing the summary when the watchdog stops the run.
    ``comm`` (batch runs): the mpi4py communicator whose ranks run this one job (default
    COMM_WORLD). ``restart_every``: write a checkpoint (LAMMPS restart + exact state, see
    :mod:`rackstress.runs.resume`) every so many steps; None: none.
    """
    # refuse a dt beyond the predicted stability limit of Eq. 5 (rackstress.model.stability) before
    # anything is written, unless allow_unstable
    from rackstress.model.stability import check_dt

    check_dt(scene, allow=allow_unstable)
    if engine not in ENGINES:
        raise RunDirError(f"unknown engine '{engine}'; choose one of {', '.join(ENGINES)}")
    dump_every = dump_every or default_dump_every(scene)
    if dump_every < 1:
        raise RunDirError(f"--dump-every must be >= 1, got {dump_every}")
    from rackstress.engines.lammps.deck import compile_deck

    deck = compile_deck(scene, mode if engine == "lammps" else "exact")

    def start():
        prepare_rundir(out, overwrite)
        write_json(out / "scene.json", scene_record(scene))
        (out / "particles.data").write_text(deck.data_text())
        if engine == "lammps":
            (out / "in.lammps").write_text(deck.input_text(dump_every))

    out = Path(out)
    on_root(start, comm)
    t0 = time.perf_counter()
    extra = {"dump_every": dump_every}
    records = [PhaseEnd(0, None, {}, 0, scene.original_positions())]
    on_phase_end = records.append if scene.report is not None else None

    def report():
        if scene.report is not None and _is_root(comm):
            extra["report"] = scene.report(scene, records)
        if _is_root(comm):   # guard rails: pass-through, force on racks (engines/guards.py)
            from rackstress.engines.guards import check_run

            extra["warnings"] = check_run(scene, out)
    try:
        if engine == "reference":
            mode = "exact"
            if not _is_root(comm):
                raise RunDirError("the reference engine runs on one rank; run it without mpiexec")
            p_end, steps = run_reference(scene, out, dump_every, progress, on_phase_end)
        else:
            p_end, steps, more = run_lammps(scene, out, mode, dump_every, progress, deck,
                                            on_phase_end, comm=comm, restart_every=restart_every)
            extra.update(more)
    except DivergenceError as err:
        wall = time.perf_counter() - t0
        report()
        p_end = getattr(err, "p_end", None)
        if p_end is None:
            p_end = np.full((scene.n_particles, 3), np.nan)
        summary = summarize(scene, engine, mode, p_end, getattr(err, "steps_done", err.step),
                            wall, "diverged", err, extra)
        if _is_root(comm):
            write_json(out / "summary.json", summary)
        raise
    wall = time.perf_counter() - t0
    report()
    summary = summarize(scene, engine, mode, p_end, steps, wall, "ok", extra=extra)
    if _is_root(comm):
        write_json(out / "summary.json", summary)
    return summary


def _is_root(comm=None) -> bool:
    from rackstress.lib.mpi import world

    return (comm or world()).Get_rank() == 0


def on_root(fn, comm=None):
    """Run ``fn`` on rank 0 of ``comm`` (default: world) only; every rank then raises what it
    raised, or goes on together."""
    from rackstress.lib.mpi import world

    comm = comm or world()
    err = None
    if comm.Get_rank() == 0:
        try:
            fn()
        except Exception as exc:  # noqa: BLE001 - re-raised on every rank below
            err = exc
    if comm.Get_size() > 1:
        err = comm.bcast(err, root=0)
    if err is not None:
        raise err

def run_lammps(scene, out: Path, mode: str, dump_every: int, progress: bool, deck=None,
               on_phase_end=None, comm=None, restart_every: int | None = None, resume=None):
    """Run ``scene`` on LAMMPS into ``out``; return (final positions, steps done, extra summary).

    ``comm``: the ranks running it (default COMM_WORLD). ``restart_every``: checkpoint interval
    in steps (None: no checkpoints). ``resume``: a :class:`rackstress.runs.resume.Checkpoint` to
    continue from (the run directory ``out`` already holds the first part).
    """
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    deck = deck or compile_deck(scene, mode)
    runner = LammpsRun(deck, out, comm=comm, dump_every=dump_every, append=resume is not None)
    ckpt = None
    if restart_every:
        from rackstress.runs.checkpoint import Checkpointer

        ckpt = Checkpointer(out, runner.comm, restart_every, mode=mode, dump_every=dump_every,
                            resumed=resume)
        on_phase_end = ckpt.wrap_phase_end(on_phase_end)
    try:
        done = resume.step if resume is not None else 0
        with progress_bar(scene.total_steps, progress, f"{scene.name} (lammps)") as bar:
            bar.update(done)
            try:
                runner.run_schedule(bar, on_phase_end=on_phase_end, checkpoint=ckpt,
                                    resume=resume)
            except DivergenceError as err:
                err.p_end = runner.gather_positions()
                err.steps_done = runner.step
                raise
        p = runner.gather_positions()
        extra = {"ranks": runner.comm.Get_size(), "lammps_version": runner.lmp.version(),
                 "python_operators": [f"{r.target} <- {r.op.kind}" for r in deck.python_ops],
                 "masses": deck.masses}
        return p, runner.step, extra
    finally:
        runner.close()
