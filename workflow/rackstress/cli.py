"""The ``rackstress`` command line: run a scene, write its LAMMPS deck, list scenes."""
from __future__ import annotations

import functools
import json
import os
import re
import sys
import time
from pathlib import Path

import click

from rackstress.lib.progress import phase
from rackstress.errors import (EXIT_BUG, EXIT_DIVERGED, EXIT_INPUT, EXIT_RENDER,  # noqa: F401
                               EXIT_STORAGE, DivergenceError, RackstressError, StorageError,
                               os_error_message)


class Choice(click.Choice):
    """``click.Choice`` whose refusal names the closest choice ("did you mean 'lammps'?")."""

    def convert(self, value, param, ctx):
        try:
            return super().convert(value, param, ctx)
        except click.BadParameter as err:
            from rackstress.lib.suggest import did_you_mean

            hint = did_you_mean(value, self.choices)
            if hint:
                err.message = f"{err.message} ({hint})"
            raise


def _load_scene(scene: str, steps, dt, sets, integrator: str | None = None):
    from rackstress import scenes

    overrides = scenes.parse_overrides(sets)
    sc = scenes.load(scene, overrides)
    if integrator is not None:
        sc.integrator = integrator
        if integrator != "euler":       # recorded where it changes the scene (Eq. 5 is the default)
            sc.params["integrator"] = integrator
            sc.validate()               # what the other integrator does not model
    if dt is not None:
        if not dt > 0:
            raise RackstressError(f"--dt must be positive, got {dt}")
        sc = sc.with_dt(float(dt))   # a scene given by duration keeps its physical time
    if steps is not None:
        sc = sc.with_steps(int(steps))
    return sc


def _fail(err: Exception, code: int):
    click.echo(f"rackstress: error: {err}", err=True)
    sys.exit(code)


def _out_path(ctx, param, value):
    """``--out`` as a Path, refusing an empty one (it would write into the working directory)."""
    if value is None:
        return None
    if not str(value).strip():
        raise click.BadParameter("is empty: give a run directory (e.g. --out runs/mine)")
    return Path(value)


def _fail_any(err: BaseException, out=None):
    """Exit with the documented status of ``err`` (errors.py) after one paragraph.

    Errors rackstress raises reach every rank alike; anything else may have reached one rank
    only while the others wait for it, so under MPI it ends all of them (MPI_Abort)."""
    from rackstress.lib.mpi import abort, settle, world

    if isinstance(err, DivergenceError):
        msg, code = f"{err} (run directory: {out})", EXIT_DIVERGED
    elif isinstance(err, RackstressError):
        msg, code = str(err), err.exit_code
    elif isinstance(err, OSError):
        msg, code = os_error_message(err, "write"), EXIT_STORAGE
    elif isinstance(err, MemoryError):
        msg, code = _memory_message(err), EXIT_INPUT
        if "mpi4py.MPI" not in sys.modules:     # one process: MPI not started, nor started
            click.echo(f"rackstress: error: {msg}", err=True)   # now (its library may not
            sys.exit(code)                                     # load without memory)
    else:
        comm = world()
        if comm.Get_size() > 1:       # a bug on one rank: the others must not wait forever
            import traceback

            traceback.print_exception(err)
            sys.stderr.write(f"rackstress: error on rank {comm.Get_rank()}: ending all ranks\n")
            abort(comm, EXIT_BUG)
        raise err
    comm = world()
    # errors rackstress raises reach every rank alike: one message, from rank 0
    if comm.Get_rank() == 0 or not isinstance(err, RackstressError):
        click.echo(f"rackstress: error: {msg}", err=True)
    if comm.Get_size() > 1 and not isinstance(err, RackstressError):
        abort(comm, code)
    settle(comm)      # rank 0 has released the run directory before any rank exits
    sys.exit(code)


def _memory_message(err: MemoryError) -> str:
    """One paragraph for a MemoryError met anywhere (exit 2, errors.py): what was asked for,
    what the process may have, what to do."""
    from rackstress.lib.resources import available_memory

    asked = str(err).split(" for an array")[0].strip()
    have = available_memory()
    have = f"{have / 2**30:.1f} GiB" if have >= 2**30 else f"{have / 2**20:.0f} MiB"
    return (f"the machine ran out of memory ({asked or 'an allocation failed'}; about "
            f"{have} available to this process now): make the "
            "scene smaller (a larger spacing, fewer steps or frames), run one command at a "
            "time, or use a machine (or a job) with more memory")


#: Options of ``run`` that ``--resume`` cannot honour: the run goes on as it was started.
RESUME_FIXED = ("engine", "mode", "steps", "dt", "sets", "dump_every", "overwrite",
                "restart_every", "allow_unstable", "integrator", "dump_all")


@click.group()
@click.version_option(package_name="rackstress")
def main():
    """Particle-system stress visualization with rack particles, backed by LAMMPS."""


@main.command()
@click.argument("scene", required=False)
@click.option("--engine", type=Choice(["lammps", "reference"]), default="lammps",
              show_default=True, help="lammps (the backend) or reference (exact NumPy engine).")
@click.option("--mode", type=Choice(["exact", "fast"]), default="exact", show_default=True,
              help="LAMMPS realization: exact (matches the reference to round-off) or fast "
                   "(bind as harmonic bonds; only for scenes it takes out of the callback).")
@click.option("--steps", type=click.IntRange(min=0), help="Iterations to run (default: the scene's).")
@click.option("--dt", type=float, help="Time step t of Eq. 5 (default: the scene's).")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a scene parameter; repeatable (see 'rackstress scenes').")
@click.option("--out", type=click.Path(file_okay=False), callback=_out_path,
              help="Run directory (default: runs/SCENE-TIMESTAMP).")
@click.option("--dump-every", type=click.IntRange(min=1), help="Steps between trajectory frames.")
@click.option("--dump-all", is_flag=True,
              help="Every particle in every frame of the trajectory (with --dump-text a plain "
                   "LAMMPS dump for other tools); default: a scene with a resting sediment dumps "
                   "the particles that moved, the others being where particles.data puts them.")
@click.option("--dump-text", is_flag=True,
              help="Keep trajectory.dump as plain text once the run has finished (default: "
                   "trajectory.dump.gz, a gzip member a frame, which rackstress, OVITO and "
                   "MDAnalysis read).")
@click.option("--overwrite", is_flag=True, help="Replace a finished run in --out.")
@click.option("--progress/--no-progress", default=True, show_default=True)
@click.option("--render/--no-render", "do_render", default=True, show_default=True,
              help="Render the default stress pictures and plots into OUT/figures/ at the end.")
@click.option("--restart-every", type=click.IntRange(min=0), default=None,
              help="LAMMPS: write a checkpoint (restart file + exact state) every N steps "
                   "(default: ~10 a run, >= 100 steps apart; 0: none).")
@click.option("--resume", "resume_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Continue the interrupted run in this run directory from its last "
                   "checkpoint (SCENE only needed for .toml scenes).")
@click.option("--allow-unstable", is_flag=True,
              help="Run even if --dt exceeds the predicted stability limit of Eq. 5.")
@click.option("--integrator", type=Choice(["euler", "verlet"]), default="euler",
              show_default=True, help="euler: Eq. 5, the paper's; verlet: the second-order mode "
              "(leapfrog with trapezoidal damping).")
@click.option("--refine", is_flag=True,
              help="A static part: solve it again at spacing/sqrt(2) into OUT/refine and give "
                   "the governing stress's error bar (Richardson; docs/stress.md). With "
                   "--resume OUT on a finished run: only the refinement.")
@click.option("--refine-ratio", type=click.FloatRange(min=1.2, max=3.0), default=None,
              help="With --refine: the spacing divided by this instead of sqrt(2); 2 halves "
                   "it (8x the particles, not 2.8x), which reads the governing stress of "
                   "parts with walls a few spacings thick closer to FEA (docs/stress.md "
                   "\"The error bar\").")
@click.option("--offsets", "n_offsets", type=click.IntRange(min=2, max=16), default=None,
              help="A static part: fill it again on N-1 lattices moved within a spacing into "
                   "OUT/offsets/K and give how far the governing stress moves with where the "
                   "lattice falls (docs/stress.md \"Lattice offsets\"). With --resume OUT on "
                   "a finished run: only the offsets.")
def run(scene, engine, mode, steps, dt, sets, out, dump_every, overwrite, progress, do_render,
        restart_every=None, resume_dir=None, allow_unstable=False, integrator="euler",
        dump_all=False, dump_text=False, refine=False, refine_ratio=None, n_offsets=None):
    """Run SCENE (a built-in name or a .toml file) and write a run directory.

    Exit status (errors.py): 0 done, 2 bad input or a run directory in use or holding another
    run, 3 diverged (frames and summary kept), 4 the run is done but its pictures could not be
    rendered, 5 the disk refused a write (full, read-only, no permission), 6 a static analysis
    did not settle (its state and summary kept); with --refine, 2 or 6 for the refined run
    leave the first run whole.
    """
    import gc

    # no collection while the run's modules load (numpy, mpi4py, LAMMPS, the scene: a tenth
    # less CPU before the first step); from the first step on, as usual, over the new objects
    gc.disable()
    from rackstress.lib.mpi import rank, world
    from rackstress.runs import run as run_mod
    from rackstress.runs.rundir import check_out, locked

    ctx = click.get_current_context()
    try:
        _refine_ratio_needs_refine(refine, refine_ratio)
        if resume_dir is not None:
            given = [n for n in RESUME_FIXED
                     if ctx.get_parameter_source(n) != click.core.ParameterSource.DEFAULT]
            if out is not None and Path(out).resolve() != Path(resume_dir).resolve():
                given.append("out")
            if given:
                opts = ", ".join("--" + ("set" if n == "sets" else n.replace("_", "-"))
                                 for n in given)
                raise RackstressError(
                    f"--resume continues the run in {resume_dir} exactly as it was started, "
                    f"so {opts} cannot be given with it (the checkpoint fixes them); to change "
                    "them start a new run, e.g. with --overwrite")
            out = check_out(resume_dir)
            if (refine or n_offsets) and (Path(out) / "summary.json").is_file():
                rec = json.loads((Path(out) / "scene.json").read_text())
                if refine:
                    _refine(out, scene, sets, rec.get("engine", engine),
                            rec.get("mode", mode), progress, do_render, refine_ratio)
                if n_offsets:
                    _offsets(out, scene, sets, rec.get("engine", engine),
                             rec.get("mode", mode), progress, do_render, n_offsets)
                return
        elif scene is None:
            raise click.UsageError("Missing argument 'SCENE' (or give --resume RUNDIR).")
        elif out is not None:
            check_out(out)
        if resume_dir is not None:
            gc.enable()
            from rackstress.runs.resume import resume_run

            with locked(out, create=False) as held:
                with phase(f"resuming the run in {out}", progress and rank() == 0,
                           ticker=False):
                    summary = resume_run(resume_dir, scene, progress=progress and rank() == 0)
                _finish(summary, out, do_render, progress, dump_text)
            _may_exit_now()
            return
        shown = progress and rank() == 0
        for option, given in (("--refine", refine), ("--offsets", n_offsets)):
            if given and not (scene.endswith(".toml") or Path(scene).is_file()):
                raise RackstressError(f"scene '{scene}' is a built-in scene: {option} fills "
                                      "the parts of a scene file (.toml) again at a spacing")
        with phase(f"building the scene {scene}", shown):
            sc = _load_scene(scene, steps, dt, sets, integrator)
        if refine or n_offsets:
            from rackstress.stress.refine import check_refinable

            check_refinable(sc, "--refine" if refine else "--offsets")
        if rank() == 0:
            said, warned = run_mod.sizing_lines(sc)
            for line in said:
                click.echo(line)
            for line in warned:
                click.echo(f"rackstress: warning: {sc.name}: {line}", err=True)
        if rank() == 0:
            from rackstress.stress.warming import warm_in_background

            warm_in_background()        # a first run compiles the measures' loop meanwhile
        if out is None:
            out = Path("runs") / f"{sc.name}-{time.strftime('%Y%m%d-%H%M%S')}"
        keep_checkpoints = restart_every is not None   # asked for: kept after the run
        if restart_every is None and engine == "lammps":
            from rackstress.runs.checkpoint import default_restart_every

            restart_every = default_restart_every(sc.total_steps)
        # bad input is refused before the run directory is touched
        with phase(f"preparing the run ({sc.n_particles:,} particles on {engine})", shown):
            planned = run_mod.plan(sc, engine, mode, dump_every, allow_unstable=allow_unstable)
        planned["deck"].dump_all = bool(dump_all)
        if planned["engine"] == "lammps":      # a path LAMMPS cannot take: before any write
            from rackstress.engines.lammps.runner import check_paths

            check_paths(out)
        head_start = None
        ranks = world().Get_size()
        if (rank() == 0 and engine == "lammps" and planned["deck"].plugin
                and sc.analysis != "static" and _idle_core(ranks)):
            # post-processing's imports and measures while LAMMPS runs the plugin, from its
            # first steps if it is short (run.execute); not beside a simulation that runs
            # Python each step (the reference engine, the callback path), nor where no core
            # is idle (_idle_core)
            every = planned["dump_every"]
            frames = sc.total_steps // every + 1 + (1 if sc.total_steps % every else 0)
            out_ = out
            if ranks == 1 and _own_streams():
                # in a process of its own, forked now: its imports meanwhile (render/prepare.py)
                from rackstress.render.prepare import Ahead

                def guards():       # the guard rails, checked beside this process
                    from rackstress.engines.guards import check_run

                    return sc.name, check_run(sc, out_, echo=False, engine=engine)

                ahead = Ahead(out_, frames, not dump_text,
                              lambda found: _post_in_child(out_, do_render, progress,
                                                           dump_text, found), guards)
                _AHEAD.append(ahead)

                def head_start():
                    ahead.follow()
                    return ahead.ended          # once LAMMPS has closed the dump
            else:
                from rackstress.render.prepare import prepare_in_background, stop_prepared

                def head_start():       # rank 0's thread (LAMMPS runs the plugin without the GIL)
                    prepare_in_background(out_, frames, compress=not dump_text)
                    return stop_prepared        # once the last step is done
        gc.freeze()
        gc.enable()
        # the lock is held from before anything is written until the pictures are done
        with locked(out) as held:   # noqa: F841
            doing = ("solving for the static equilibrium (Newton's method)"
                     if sc.analysis == "static" else f"running {sc.total_steps:,} steps")
            with phase(f"{doing} into {out}", shown, ticker=False):
                summary = run_mod.run(sc, out, engine=engine, mode=mode,
                                      dump_every=dump_every, progress=shown,
                                      overwrite=overwrite, restart_every=restart_every or None,
                                      allow_unstable=allow_unstable, planned=planned,
                                      keep_checkpoints=keep_checkpoints, head_start=head_start,
                                      guards=not _AHEAD)
            _finish(summary, out, do_render, progress, dump_text)
        if refine and summary.get("settled") is not False:
            _refine(out, scene, sets, engine, mode, progress, do_render, refine_ratio)
        if n_offsets and summary.get("settled") is not False:
            _offsets(out, scene, sets, engine, mode, progress, do_render, n_offsets)
        if summary.get("settled") is False:
            from rackstress.errors import EXIT_UNSETTLED

            if rank() == 0:
                click.echo(f"rackstress: error: {summary['scene']}: the static analysis did not "
                           f"settle: the largest unbalanced force is {summary['residual']:.3g} of "
                           f"the applied load after {summary['iterations']} iterations (settled "
                           f"means at most {summary['tolerance']:g}); the state written to {out} "
                           "is not an equilibrium" + _unbalanced_hint(summary)
                           + _rounding_hint(summary), err=True)
            sys.exit(EXIT_UNSETTLED)
        _may_exit_now()
    except Exception as err:  # noqa: BLE001 - each kind has its exit status (_fail_any)
        _quit_ahead()
        _fail_any(err, out)
    finally:
        gc.enable()
        _quit_ahead()


def _refine_ratio_needs_refine(refine: bool, ratio: float | None) -> None:
    """``--refine-ratio`` sets the refinement's spacing: without ``--refine`` it is refused
    (exit 2), not ignored (``run`` and ``bench parts``)."""
    if ratio is not None and not refine:
        raise click.UsageError("--refine-ratio sets the refinement's spacing: give it with "
                               "--refine")


def _scene_again(out: Path, scene, sets, option: str) -> tuple:
    """(the scene file, its ``--set`` values) a finished run in ``out`` was made from, to fill
    it again (``--refine``, ``--offsets``): the ``--set`` given now, else those it recorded."""
    from rackstress import scenes

    rec = json.loads((Path(out) / "scene.json").read_text())
    spec = scene or rec.get("source")
    if not spec:
        raise RackstressError(f"{out}: its scene file is not recorded; give it: rackstress run "
                              f"SCENE.toml --resume {out} {option}")
    overrides = scenes.parse_overrides(sets) if sets else {
        k: v for k, v in (rec.get("params") or {}).items() if k not in scenes.RECORDED_ONLY}
    return spec, overrides


def _refine(out: Path, scene, sets, engine: str, mode: str, progress: bool,
            do_render: bool, ratio: float | None = None) -> None:
    """``--refine``: the finished run in ``out`` again at spacing/``ratio`` (√2 unless
    ``--refine-ratio``) into ``out/refine``, its error bar into ``out/summary.json`` and the
    report (:mod:`rackstress.stress.refine`)."""
    from rackstress.lib.mpi import rank
    from rackstress.stress.governing import REFINE_RATIO, describe
    from rackstress.stress.refine import refine

    if rank() != 0:
        return
    spec, overrides = _scene_again(out, scene, sets, "--refine")
    from rackstress.runs.rundir import locked

    with locked(out, create=False):
        ratio = REFINE_RATIO if ratio is None else float(ratio)
        said = "sqrt(2)" if ratio == REFINE_RATIO else f"{ratio:g}"
        with phase(f"refining: the scene again at spacing/{said} into {Path(out) / 'refine'}",
                   progress, ticker=False):
            err = refine(out, spec, overrides, engine=engine, mode=mode, progress=progress,
                         echo=click.echo, ratio=ratio)
        summary = json.loads((Path(out) / "summary.json").read_text())
        st = summary.get("stress") or {}
        for line in describe(st.get("governing"), None, err):
            click.echo(line)
        if do_render:
            _write_report(out)


def _offsets(out: Path, scene, sets, engine: str, mode: str, progress: bool,
             do_render: bool, n: int) -> None:
    """``--offsets N``: the finished run in ``out`` again on N − 1 moved lattices into
    ``out/offsets/K``, the governing stress's spread into ``out/summary.json`` and the report
    (:mod:`rackstress.stress.offsets`)."""
    from rackstress.lib.mpi import rank
    from rackstress.runs.rundir import locked
    from rackstress.stress.offsets import offsets, offsets_sentence

    if rank() != 0:
        return
    spec, overrides = _scene_again(out, scene, sets, f"--offsets {n}")
    with locked(out, create=False):
        with phase(f"offsets: the scene again on {n - 1} moved lattice(s) into "
                   f"{Path(out) / 'offsets'}", progress, ticker=False):
            off = offsets(out, spec, n, overrides, engine=engine, mode=mode,
                          progress=progress, echo=click.echo)
        click.echo("  " + offsets_sentence(off))
        if do_render:
            _write_report(out)


def _own_streams() -> bool:
    """Whether this process writes its output to file descriptors (a terminal, a file, a
    pipe), which a forked process shares, and not into a stream of Python objects (click's
    test runner, pytest's capsys), which it would fill in its own memory only."""
    try:
        sys.stdout.fileno()
        sys.stderr.fileno()
        return True
    except (AttributeError, OSError, ValueError):
        return False


#: the post-processing process of this ``rackstress run`` (render/prepare.py's Ahead), if any
_AHEAD: list = []


def _quit_ahead() -> None:
    """End :data:`_AHEAD`'s process if it is still there (the run failed before it was told
    to post-process)."""
    while _AHEAD:
        _AHEAD.pop().quit()


def _post_in_child(out: Path, do_render: bool, progress: bool, dump_text: bool,
                   found: tuple) -> int:
    """What :data:`_AHEAD`'s process does once told: the guard rails it checked (``found``)
    into ``summary.json`` (:func:`_add_guards`), then :func:`_post_and_render`, as this process
    would do it; its exit status."""
    from rackstress.stress.rundata import kept_open

    try:
        _add_guards(out, *found)
        with kept_open():
            _post_and_render(out, do_render, progress, dump_text)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1
    return 0


def _add_guards(out: Path, name: str, found: list) -> None:
    """The guard rails' warnings of a run that ended well, checked beside it (``rackstress
    run``'s head start: :func:`rackstress.runs.run.execute` with ``guards=False``), into its
    ``summary.json`` and on stderr, as :func:`rackstress.engines.guards.check_run` says them."""
    from rackstress.engines.guards import say
    from rackstress.lib.jsonio import write_json

    say(name, found)
    path = Path(out) / "summary.json"
    summary = json.loads(path.read_text())
    summary["warnings"] = list(found) + list(summary.get("warnings") or [])
    write_json(path, summary)


#: set once a ``rackstress run`` on one process has written and closed everything: the
#: process may then end without the interpreter's teardown (:func:`entry`)
_EXIT_NOW: list = []


def _may_exit_now() -> None:
    from rackstress.lib.mpi import world

    if world().Get_size() == 1:     # under MPI every rank ends as usual (MPI_Finalize)
        _EXIT_NOW.append(True)


def entry():
    """The ``rackstress`` command (``[project.scripts]``): :data:`main`, and after a
    ``rackstress run`` on one process that has written and closed every file, ``os._exit(0)``
    once the output is flushed: the interpreter's teardown (a full collection over LAMMPS',
    numba's, VTK's and matplotlib's objects, their modules' finalizers) took 0.3-1 s of
    README's first command's wall time, and nothing needs it. Anything else ends as usual."""
    try:
        main()
    except MemoryError as exc:    # anywhere: a message and exit 2, never a traceback
        _fail_any(exc)
    except SystemExit as exc:
        if _EXIT_NOW and exc.code in (0, None):
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)
        raise


def _idle_core(ranks: int = 1) -> bool:
    """Whether post-processing may start beside the simulation (``rackstress run``'s head
    start, render/prepare.py): not under ``RACKSTRESS_HEAD_START=0``, only where the machine
    has a core beyond the simulation's ``ranks``, and only where the 1-minute load average
    leaves a core idle (below the number of cores; ``RACKSTRESS_HEAD_START=always`` skips
    this last check). On a machine whose cores are all busy the head start takes CPU from
    the simulation and gets nothing done (magpod-small at load 5: its simulation 1.97-2.10 s
    beside it against 1.52-1.57 s without, no frame measured meanwhile; bench e2e)."""
    how = os.environ.get("RACKSTRESS_HEAD_START", "1").strip().lower()
    if how in ("0", "no", "off"):
        return False
    cores = os.cpu_count() or 1
    if ranks >= cores:
        return False
    if how == "always":
        return True
    try:
        return os.getloadavg()[0] < cores
    except OSError:
        return True


def _finish(summary: dict, out: Path, do_render: bool, progress: bool = True,
            dump_text: bool = False) -> None:
    """Report a finished run, post-process it and render its pictures (rank 0, the run
    directory still held); unless ``dump_text``, ``trajectory.dump`` becomes
    ``trajectory.dump.gz`` (compressed meanwhile, in a thread; docs/output.md)."""
    from rackstress.lib.mpi import rank

    if rank() != 0:
        return
    from rackstress.render.prepare import stop_prepared
    from rackstress.runs.checkpoint import discard_finished

    stop_prepared()             # joined before post-processing forks (prepare.py)
    discard_finished(out)       # a kill-only checkpoint of a finished run: never resumed
    static = summary.get("analysis") == "static"
    units = {}
    if static:
        try:
            units = json.loads((Path(out) / "scene.json").read_text()).get("units") or {}
        except (OSError, ValueError):
            units = {}
        how = ("settled in" if summary.get("settled") else
               "NOT SETTLED (not an equilibrium: do not use its numbers) after")
        click.echo(f"{summary['scene']}: static, {how} {summary['iterations']} "
                   f"iterations (residual {summary['residual']:.2g} of the applied load) on "
                   f"{summary['engine']} in {summary['wall_s']:.2f} s -> {out}")
    else:
        click.echo(f"{summary['scene']}: {summary['steps']} steps on {summary['engine']} "
                   f"({summary['mode']}) in {summary['wall_s']:.2f} s -> {out}")
    for name, g in summary["groups"].items():
        md = g["max_deformation"]
        if static:          # a held part's deformation is its displacement (runs/run.py)
            at = g.get("max_deformation_at")
            click.echo(f"  {name:12s} n={g['n']:6d}  largest displacement="
                       + (f"{md:.4g} {units.get('length', '')}".rstrip() if md is not None
                          else "-")
                       + (f" (particle {g['max_deformation_particle']} at "
                          f"({', '.join(f'{x:.4g}' for x in at)}))" if at else ""))
            continue
        click.echo(f"  {name:12s} n={g['n']:6d}  max_deformation="
                   + (f"{md:.4g}" if md is not None else "-"))
    if static:
        _say_reactions(summary, units)
    while _AHEAD:               # post-processing in the process that prepared it
        ahead = _AHEAD.pop()
        code = ahead.go()
        if code is not None:
            if code:
                sys.exit(code)
            return
        _forget(out)            # it died: this process does it all
        _add_guards(out, *ahead.guards())
    from rackstress.stress.rundata import kept_open

    with kept_open():           # particles.data read and the dump indexed once
        _post_and_render(out, do_render, progress, dump_text)


def _physical(out: Path) -> bool:
    """Whether the run in ``out`` is a MagPod in physical units (``magpod-physical-small``,
    ``magpod-physical``) that ran to its end."""
    try:
        rec = json.loads((Path(out) / "scene.json").read_text())
        status = json.loads((Path(out) / "summary.json").read_text()).get("status")
    except (OSError, ValueError):
        return False
    return bool((rec.get("params") or {}).get("physical")) and status == "ok"


def _legs(out: Path, progress: bool, pictures: bool = True) -> None:
    """The legs' quasi-static von Mises in MPa per frame (:mod:`rackstress.stress.legs`):
    ``legs_von_mises.f32`` and ``legs_physical.json`` beside the dump, the time plot and the
    peak picture in ``legs/`` (unless ``pictures`` is False: ``--no-render``)."""
    from rackstress.render.legs import PEAK_PICTURE, TIME_PLOT, peak_picture, time_plot
    from rackstress.stress.legs import run_legs

    t0 = time.perf_counter()
    try:
        with phase("the legs' stress in MPa (quasi-static per frame)", progress, ticker=False):
            res, path = run_legs(out)
        t_stress = time.perf_counter() - t0
        if pictures:
            time_plot(res, Path(out) / "legs" / TIME_PLOT)
            peak_picture(res, Path(out) / "legs" / PEAK_PICTURE)
        rec = json.loads(path.read_text())      # the pictures' time beside the stress's
        rec["timings"]["pictures_s"] = time.perf_counter() - t0 - t_stress
        rec["timings"]["legs_command_s"] = t_stress
        path.write_text(json.dumps(rec, indent=1))
    except Exception as err:  # noqa: BLE001 - the run itself is complete and kept
        click.echo(f"rackstress: error: the run finished, but its legs' physical stress "
                   f"failed: {err}", err=True)
        sys.exit(EXIT_STORAGE if isinstance(err, (StorageError, OSError)) else EXIT_RENDER)
    pk, fig = res.peak, res.figures
    click.echo(f"  legs in physical units ({fig['unit_length_mm']:g} mm a paper unit, "
               f"{fig['material']}, a leg {fig['leg_mass_g']:.0f} g, a gait cycle "
               f"{fig['cycle_s']:.2f} s): peak von Mises {pk['von_mises_mpa']:.3g} MPa on the "
               f"{pk['leg']} (particle {pk['particle']}) at iteration {pk['step']} "
               f"(t = {pk['time_s']:.2f} s); {len(res.steps)} frames in {t_stress:.2f} s "
               f"-> {path}" + (f", {Path(out) / 'legs'}" if pictures else ""))


def _say_reactions(summary: dict, units: dict) -> None:
    """A static run's support reactions, one line each, and their sum against the load (a
    component below the settle tolerance × the load is what the solve leaves: 0)."""
    import math

    reactions, applied = summary.get("reactions"), summary.get("applied_load")
    if not reactions or not applied:
        return
    tol = float(summary.get("tolerance") or 1e-6) if summary.get("settled") else 0.0

    def vec(v, of):
        small = tol * math.sqrt(sum(x * x for x in of))
        return "(" + ", ".join("0" if abs(x) < small else f"{x:.4g}" for x in v) + ")"

    fu, lu = units.get("force", ""), units.get("length", "")
    for r in reactions:
        click.echo(f"  reaction of {r['support']} on {r['group']}: force "
                   f"{vec(r['force'], applied['force'])} {fu}, moment "
                   f"{vec(r['moment'], applied['moment'])} {fu}·{lu}")
    total = [sum(r["force"][k] for r in reactions) for k in range(3)]
    click.echo(f"  reactions' sum {vec(total, applied['force'])} {fu} against the applied load "
               f"{vec(applied['force'], applied['force'])} {fu}")


def _forget(out: Path) -> None:
    """What a post-processing process that died may have left half-written in ``out``: its
    pictures', VTK files' and compressed trajectory's temporary files (the VTK and plot processes it
    forked died with it: PR_SET_PDEATHSIG)."""
    import shutil

    for p in [p for pattern in (".render.tmp*", ".vtk.tmp*", ".*.gz.tmp*")
              for p in Path(out).glob(pattern)]:
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)


def _post_and_render(out: Path, do_render: bool, progress: bool, dump_text: bool) -> None:
    """Post-process the run in ``out`` and render its pictures (:func:`_finish`)."""
    from rackstress.stress.post import cancel_files, wait_files

    squeeze = None
    if not dump_text and (Path(out) / "trajectory.dump").is_file():
        from rackstress.engines.dumpio import CompressJob

        squeeze = CompressJob(Path(out) / "trajectory.dump")   # read meanwhile; renamed at the end
    try:
        info = _post_run(out, progress, background=do_render)
        if do_render:
            from rackstress.render.pictures import render_default

            t0 = time.perf_counter()
            try:
                with phase("rendering the pictures and report.html (the VTK files are written "
                           "meanwhile)", progress, ticker=False):
                    rep = render_default(out, progress=progress)
            except Exception as err:  # noqa: BLE001 - the run itself is complete and kept
                try:
                    wait_files(out)                   # the VTK files are still worth having
                except Exception:  # noqa: BLE001, S110 - the render's error is the one to tell
                    pass
                click.echo(f"rackstress: error: the run finished, but rendering its pictures "
                           f"failed: {err} (retry with 'rackstress render {out}')", err=True)
                sys.exit(EXIT_STORAGE if isinstance(err, StorageError) else EXIT_RENDER)
            click.echo(f"  pictures: {rep.outdir} ({len(rep.files)} files, "
                       f"{time.perf_counter() - t0:.1f} s)")
        if _physical(out):      # after the pictures: their modules loaded, the VTK meanwhile
            _legs(out, progress, pictures=do_render)
        wait_files(out)
        if info and info.get("governing"):        # the headline (docs/stress.md)
            from rackstress.stress.post import describe_governing

            for line in describe_governing(info):
                click.echo(line)
        if do_render and getattr(rep, "report", None):   # last: a headless machine's browser
            click.echo(f"  report: {rep.report}")         # says nothing
    except Exception as err:  # noqa: BLE001 - the run itself is complete and kept
        click.echo(f"rackstress: error: the run finished, but writing its VTK files failed: "
                   f"{err} (retry with 'rackstress stress {out}')", err=True)
        sys.exit(EXIT_STORAGE if isinstance(err, StorageError) else EXIT_RENDER)
    finally:
        cancel_files(out)
        if squeeze is not None:   # the run has finished, whatever its derived files did
            _compressed(squeeze, failed=sys.exc_info()[0] is not None)


def _compressed(job, failed: bool) -> None:
    """Put the finished run's ``trajectory.dump.gz`` in place (``job``: a
    :class:`~rackstress.engines.dumpio.CompressJob`). If that fails (a full disk) the text is
    kept, and the command ends with exit 5 unless an error (``failed``) already ends it."""
    try:
        job.finish()
    except StorageError as err:
        click.echo(f"rackstress: {'note' if failed else 'error'}: the run finished, but its "
                   f"trajectory could not be compressed: {err} (trajectory.dump is kept as "
                   "text)", err=True)
        if not failed:
            sys.exit(EXIT_STORAGE)


@main.command()
@click.argument("scene")
@click.option("--out", type=click.Path(file_okay=False), callback=_out_path, required=True)
@click.option("--mode", type=Choice(["exact", "fast"]), default="exact", show_default=True)
@click.option("--steps", type=click.IntRange(min=0))
@click.option("--dt", type=float)
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE")
@click.option("--dump-every", type=click.IntRange(min=1), default=None)
def deck(scene, out, mode, steps, dt, sets, dump_every):
    """Write the LAMMPS data file and input deck of SCENE into OUT, without running."""
    from rackstress.engines.lammps.deck import write_deck
    from rackstress.runs.run import default_dump_every

    try:
        from rackstress.runs.rundir import own

        sc = _load_scene(scene, steps, dt, sets)
        own(out, ["particles.data", "in.lammps"], "the deck")   # never over the user's files
        d = write_deck(sc, out, mode, dump_every or default_dump_every(sc))
    except Exception as err:  # noqa: BLE001 - each kind has its exit status (_fail_any)
        _fail_any(err, out)
    click.echo(f"wrote {out / 'particles.data'} and {out / 'in.lammps'} "
               f"({sc.n_particles} atoms, {len(d.python_ops)} operator(s) in Python)")


@main.command("scenes")
@click.argument("files", nargs=-1)
@click.option("--json", "as_json", is_flag=True,
              help="Print one JSON object instead of the table: name → particles, shows, "
                   "parameters.")
def list_scenes(files, as_json):
    """List the built-in scenes (or the given .toml scenes): a table of each scene's name, its
    number of particles, what it shows and its parameters with their defaults (what --set
    takes)."""
    from rackstress.errors import SceneError

    try:
        rows = [_scene_row(f) for f in files] if files else [
            _scene_row(name) for name in _builtin_names()]
    except SceneError as err:
        _fail(err, EXIT_INPUT)
    if as_json:
        click.echo(json.dumps({r["name"]: {k: v for k, v in r.items() if k != "name"}
                               for r in rows}, indent=2))
        return
    click.echo(scenes_table(rows))


#: What a built-in scene shows, where its builder's first docstring line does not say it.
SHOWS = {"magpod": "MagPod (Eqs. 27–33): the paper's walking robot, four gait cycles on "
                   "sediment, its footprints and the stress in its legs and feet"}


def _builtin_names():
    from rackstress import scenes

    return list(scenes.BUILDERS)


def _scene_row(spec: str) -> dict:
    """Name, particles, what it shows (a builder's docstring, a file's first comment) and
    parameters of a built-in scene or a .toml file."""
    from rackstress import scenes

    if spec in scenes.BUILDERS:
        doc = (scenes.BUILDERS[spec].__doc__ or "").strip()
        shows = SHOWS.get(spec) or re.sub(r"``([^`]*)``", r"'\1'",
                                          " ".join(doc.split("\n\n")[0].split()))
        params = scenes.parameters(spec)
        sc = scenes.build(spec)
    else:
        from rackstress.scenes.toml import scene_parameters

        params = scene_parameters(spec)
        comments = []
        for line in Path(spec).read_text(encoding="utf-8", errors="replace").splitlines():
            if not line.startswith("#"):
                break
            comments.append(line.lstrip("#").strip())
        shows = " ".join(" ".join(comments).split(". ")[:1]).strip() or "(no leading comment)"
        sc = scenes.load(spec, {})
    return {"name": spec, "particles": int(sc.n_particles), "shows": shows,
            "parameters": params}


#: the widest scene name ``rackstress scenes`` keeps in its first column
NAME_W = 32


def scenes_table(rows: list, width: int = 100) -> str:
    """The table ``rackstress scenes`` prints: a row per scene (name, particles, what it shows)
    and its parameters with their defaults, wrapped beneath it."""
    import textwrap

    # a name longer than NAME_W (a scene file's path) takes a line of its own: the columns
    # keep their room (a 78-character path left the descriptions 10 characters a line)
    name_w = min(NAME_W, max(len("SCENE"), *(len(r["name"]) for r in rows)))
    head = f"{'SCENE':<{name_w}}  {'PARTICLES':>9}  WHAT IT SHOWS"
    indent = " " * (name_w + 13)
    out = [head, "-" * min(width, max(len(head), 60))]
    for r in rows:
        shows = textwrap.wrap(r["shows"], width - len(indent)) or [""]
        name = r["name"]
        if len(name) > name_w:
            out.append(name)
            name = ""
        out.append(f"{name:<{name_w}}  {r['particles']:>9,}  {shows[0]}")
        out += [indent + line for line in shows[1:]]
        params = ", ".join(f"{k}={v!r}" if isinstance(v, str) else f"{k}={v}"
                           for k, v in r["parameters"].items())
        out += textwrap.wrap("parameters: " + (params or "none"), width,
                             initial_indent=indent, subsequent_indent=indent + "  ")
    out.append("")
    out.append("Change a parameter with --set NAME=VALUE (e.g. rackstress run plane-rack "
               "--set plane_bind=50);")
    out.append("docs/scenes.md describes scene files.")
    return "\n".join(out)


def _post_run(out, progress, background: bool = False):
    """After a run: the stress measures once, their peaks into summary.json, the VTK series
    (``background``: written by a forked process while the pictures are painted)."""
    from rackstress.stress.post import TooLargeError, describe, postprocess

    try:
        with phase("computing the stress measures and the VTK series", progress, ticker=False):
            info = postprocess(out, vtk=True, dump=False, progress=progress,
                               background=background, vtk_measures="default")
    except TooLargeError as err:
        click.echo(f"  note: no stress peaks or VTK files: {err}")
        return
    except OSError as err:     # a full disk (StorageError): the run itself is complete and kept
        msg = str(err) if isinstance(err, StorageError) else os_error_message(err, "write")
        click.echo(f"rackstress: error: the run finished, but its stress files could not be "
                   f"written: {msg} (then retry with 'rackstress stress {out}')", err=True)
        sys.exit(EXIT_STORAGE)
    except Exception as err:  # noqa: BLE001 - the run itself is complete and kept
        click.echo(f"rackstress: error: the run finished, but post-processing its stress "
                   f"failed: {err} (retry with 'rackstress stress {out}')", err=True)
        sys.exit(EXIT_RENDER)
    for line in describe(info, governing=False):
        click.echo(line)
    return info


def _post_job(rundir, render: bool = True):
    """A batch job's post-processing: the stress peaks into its summary.json (no VTK: run
    'rackstress stress BATCHDIR/JOB' for the files), and unless ``render`` is False its
    default pictures, report.html and 3D view, as 'rackstress run' leaves them."""
    from mpi4py import MPI

    from rackstress.runs.rundir import locked
    from rackstress.stress.post import postprocess

    # its files recorded in the job's manifest; by this process alone (a job's root, while the
    # other groups' roots run other jobs: no collective over the world)
    with locked(rundir, create=False, comm=MPI.COMM_SELF):
        postprocess(rundir, vtk=False, dump=False)
        if render:
            from rackstress.render.pictures import render_default

            render_default(rundir)


def _csv(text):
    return [t.strip() for t in text.split(",") if t.strip()] if text else None


@main.command()
@click.argument("rundir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--frames", metavar="N,N,...",
              help="Iterations to picture (nearest dumped frame is used); default: the paper's "
                   "1320,2600,4720,17480 if the run reaches them, else 4 spread over the run, "
                   "and the iteration of the peak.")
@click.option("--measure", type=Choice(["paper", "accumulated", "strain", "d2min",
                                        "virial", "von_mises", "contact_pressure"]),
              help="Default: von_mises for a scene with a material, else paper. "
                   "paper: distance from desired position (Sec. 5.2); accumulated: its time "
                   "integral; strain: von Mises shear strain; d2min: non-affine D2min; "
                   "virial: LAMMPS per-atom stress (if the dump has it); von_mises: von Mises "
                   "stress from the bindings' forces, in the scene's stress unit (MPa); "
                   "contact_pressure: parts in contact ([[contact]]), each particle's contact "
                   "force over its cell's face.")
@click.option("--views", default="right,front,left", show_default=True,
              help="Comma-separated: right, front, left, back, top, iso.")
@click.option("--groups", metavar="PART,...",
              help="Parts to show, e.g. body,leftleg (coloured whatever their kind); or parts to "
                   "hide from the default set with a leading '-', e.g. -sediment.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (default: RUNDIR/figures for the default measure, "
                   "RUNDIR/figures/MEASURE otherwise). Files of other names there are kept.")
@click.option("--movie", is_flag=True, help="Also write movie.mp4 of every frame.")
@click.option("--movie-view", help="The view of the movie (default: the first of --views).")
@click.option("--vmax", type=float,
              help="Top of the colour scale (default: the peak, so it is never clipped).")
@click.option("--cmap", default="paper", show_default=True,
              help="paper (grey to red, Section 5.2) or a matplotlib colour map (viridis, ...).")
@click.option("--allow-truncated", is_flag=True,
              help="Render the complete frames of a dump that ends mid-frame.")
@click.option("--progress/--no-progress", default=True, show_default=True,
              help="A progress bar on a terminal.")
@click.option("--allow-unsettled", is_flag=True,
              help="A static run that did not settle: show its headline stress and factor of "
                   "safety in report.html anyway (struck out by default: the state is not an "
                   "equilibrium); the red NOT SETTLED banner stays.")
def render(rundir, frames, measure, views, groups, out, movie, movie_view, vmax, cmap,
           allow_truncated, progress, allow_unsettled=False):
    """Render the stress pictures, sheet, plots (and movie) of RUNDIR; refresh RUNDIR/report.html.

    A static run gets the part's surface instead (figures/sheet.png: four views of the
    deformed surface coloured by the stress; figures/particles.png: the particles): no frames,
    no movie, no plots over time.

    Exit status: 0 done, 2 bad input.
    """
    from rackstress.render.pictures import record_render
    from rackstress.render.pictures import render as render_run
    from rackstress.runs.rundir import locked

    t0 = time.perf_counter()
    try:
        its = None
        if frames:
            try:
                its = [int(f) for f in frames.split(",") if f.strip()]
            except ValueError:
                raise RackstressError(f"--frames expects comma-separated integers, got '{frames}'")
        # one writer per run directory: not while a run (or another render) holds it
        with locked(rundir, create=False):
            from rackstress.runs.rundir import remove_temporaries

            remove_temporaries(rundir)       # of a render or run killed midway
            with phase(f"rendering the pictures of {rundir}", progress, ticker=False):
                rep = render_run(rundir, frames=its, measure=measure,
                                 views=_csv(views) or [], movie=movie, movie_view=movie_view,
                                 vmax=vmax, cmap=cmap, groups=_csv(groups), out=out,
                                 allow_truncated=allow_truncated, progress=progress)
            record_render(rundir, rep, time.perf_counter() - t0)
            report = _write_report(rundir, allow_unsettled)
    except Exception as err:  # noqa: BLE001 - each kind has its exit status (_fail_any)
        _fail_any(err)
    for note in rep.notes:
        click.echo(f"note: {note}")
    pk = rep.peak
    if pk is not None and "iteration" not in pk:        # a static run's headline
        from rackstress.stress.headline import headline_text

        click.echo(f"colour scale 0..{rep.vmax:.4g}; " + headline_text(pk))
    else:
        click.echo("frames: " + ", ".join(f"{s}" for _, _, s in rep.frames)
                   + f"; colour scale 0..{rep.vmax:.4g}"
                   + (f"; peak {pk['value']:.4g} at iteration {pk['iteration']}, particle "
                      f"{pk['particle']} ({pk['group']})" if pk else ""))
    for name in rep.files:
        click.echo(f"  wrote {rep.outdir / name}")
    if report is not None:
        click.echo(f"  wrote {report}")
    click.echo(f"rendered in {time.perf_counter() - t0:.1f} s")


def _write_report(rundir, allow_unsettled: bool | None = None):
    """RUNDIR/report.html when RUNDIR is a run directory with a summary; else None."""
    from rackstress.render.report import write_report

    if not (Path(rundir) / "summary.json").is_file():
        return None
    return write_report(rundir, allow_unsettled=allow_unsettled)


@main.command()
@click.argument("inputs", nargs=-1, required=True,
                type=click.Path(exists=True, path_type=Path))
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (default: the run directory; for DATA DUMP the dump's folder).")
@click.option("--vtk/--no-vtk", default=True, show_default=True,
              help="Write vtk/run.pvd and one .vtp per frame (ParaView, pyvista; OVITO: "
                   "--vtk-format ovito).")
@click.option("--vtk-format", type=click.Choice(["paraview", "ovito"]), default="paraview",
              show_default=True, help="paraview: compressed (ParaView, pyvista); ovito: "
                                      "uncompressed inline arrays, which OVITO 3.17 also reads.")
@click.option("--dump/--no-dump", "write_dump", default=True, show_default=True,
              help="Write stress.dump: a LAMMPS dump with the measures as named columns.")
@click.option("--parts", type=Choice(["mol", "type"]),
              help="DATA DUMP: parts by molecule or by atom type (default: mol when the data "
                   "file has several molecules).")
@click.option("--atom-style", help="DATA DUMP: atom style of the data file's Atoms section, if "
                                   "it does not say (atomic, bond, molecular, full, sphere, ...).")
@click.option("--dt", type=float, default=1.0, show_default=True,
              help="DATA DUMP: time per iteration (for the accumulated measure).")
@click.option("--allow-truncated", is_flag=True,
              help="Use the complete frames of a dump that ends mid-frame.")
@click.option("--progress/--no-progress", default=True, show_default=True)
def stress(inputs, out, vtk, write_dump, parts, atom_style, dt, allow_truncated, progress,
           vtk_format="paraview"):
    """Compute every stress measure of a run once and write them for ParaView and OVITO.

    INPUTS is a run directory (RUNDIR), or a plain LAMMPS data file and dump (DATA DUMP) that
    rackstress did not write. Writes the peaks (into RUNDIR/summary.json and stress.json), the
    VTK time series vtk/run.pvd and the LAMMPS dump stress.dump.

    Exit status: 0 done, 2 bad input.
    """
    from rackstress.stress.post import describe, postprocess

    t0 = time.perf_counter()
    try:
        if len(inputs) == 1:
            if not inputs[0].is_dir():
                raise RackstressError(f"{inputs[0]}: give a run directory, or a data file and a "
                                      "dump (rackstress stress DATA DUMP --out DIR)")
            from rackstress.runs.rundir import locked

            with locked(inputs[0], create=False), \
                    phase("computing the stress measures", progress, ticker=False):
                info = postprocess(inputs[0], vtk=vtk, dump=write_dump, progress=progress,
                                   out=out, vtk_format=vtk_format,
                                   allow_truncated=allow_truncated)
            where = out or inputs[0]
        elif len(inputs) == 2:
            from rackstress.stress.foreign import load_plain

            if not dt > 0:
                raise RackstressError(f"--dt must be positive, got {dt}")
            where = out or inputs[1].resolve().parent
            run = load_plain(inputs[0], inputs[1], parts=parts, atom_style=atom_style, dt=dt,
                             outdir=where, allow_truncated=allow_truncated)
            info = postprocess(None, run=run, vtk=vtk, dump=write_dump, progress=progress,
                               out=where, vtk_format=vtk_format)
        else:
            raise RackstressError("give one run directory, or a data file and a dump")
    except Exception as err:  # noqa: BLE001 - each kind has its exit status (_fail_any)
        _fail_any(err)
    for line in describe(info):
        click.echo(line)
    click.echo(f"wrote {Path(where) / 'stress.json'} ({time.perf_counter() - t0:.1f} s)")


@main.command()
@click.argument("sweep", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", type=click.Path(file_okay=False), callback=_out_path,
              help="Batch directory (default: batches/SWEEP-STEM); rerun to finish it.")
@click.option("--ranks-per-job", type=click.IntRange(min=1), default=1, show_default=True,
              help="MPI ranks per job: mpiexec -n K runs K/J jobs at a time.")
@click.option("--retry-failed", is_flag=True, help="Also rerun jobs recorded as failed.")
@click.option("--manager", type=Choice(["thread", "rank"]), default="thread",
              show_default=True, help="Job hand-out: a thread on rank 0 (which also runs jobs) "
                                      "or rank 0 alone.")
@click.option("--report", "report_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Instead of running: tabulate and plot a finished (or partial) batch.")
@click.option("--figure", help="With --report: a summary figure as a dotted path "
                               "(default: groups.FIRSTGROUP.max_deformation).")
@click.option("--against", help="With --report: the swept parameter on the x axis "
                                "(default: the first swept one).")
@click.option("--render/--no-render", "do_render", default=True, show_default=True,
              help="Render each finished job's pictures, report.html and 3D view.")
def batch(sweep, out, ranks_per_job, retry_failed, manager, report_dir, figure, against,
          do_render):
    """Run every job of a SWEEP file (TOML), over MPI ranks when under mpiexec.

    Jobs that diverge or fail are recorded and the rest go on; a killed batch run again on the
    same --out finishes only what was not finished. Exit status: 0 all jobs finished (whatever
    their status), 2 bad input (also a --figure no summary has), 5 the disk refused a write.
    """
    from rackstress.runs import batch as batch_mod
    from rackstress.lib.mpi import rank, threads

    threads("multiple")     # before MPI starts: the manager thread serves the other ranks
    try:
        if report_dir is not None:
            batch_mod.report(report_dir, figure, against, log=click.echo)
            click.echo(f"page: {_batch_page(report_dir)}")
            return
        if sweep is None:
            raise click.UsageError("give a SWEEP file, or --report BATCHDIR")
        if out is not None:
            from rackstress.runs.rundir import check_out

            check_out(out)
        index = batch_mod.run_batch(sweep, out, ranks_per_job, retry_failed, manager,
                                    log=lambda m: click.echo(m) if rank() == 0 else None,
                                    post=functools.partial(_post_job, render=do_render))
        page = _batch_page(out or Path("batches") / Path(sweep).stem) if rank() == 0 else None
    except click.UsageError:
        raise
    except Exception as err:  # noqa: BLE001 - each kind has its exit status (_fail_any)
        _fail_any(err, out)
    if rank() == 0:
        p = index["passes"][-1]
        click.echo(f"batch {'complete' if index['complete'] else 'incomplete'}: "
                   + ", ".join(f"{v} {k}" for k, v in sorted(index["counts"].items()))
                   + f"; this pass ran {p['jobs_run']} job(s) in {p['wall_s']:.2f} s")
        click.echo(f"page: {page}")


def _batch_page(batchdir):
    """BATCHDIR/report.html: the sweep table, the peak against each swept parameter, links to
    the jobs' reports."""
    from rackstress.render.batch_report import write_batch_report

    return write_batch_report(batchdir)


def _unbalanced_hint(summary: dict) -> str:
    """Where a static run that did not settle left its largest unbalanced force, and when
    most of the largest lie in walls one particle thick, why and what to do
    (engines.static.unbalanced_at)."""
    u = summary.get("unbalanced_at") or {}
    if "particle" not in u:
        return ""
    pos = ", ".join(f"{x:.4g}" for x in u["position"])
    out = (f". The largest stays at particle {u['particle']} of '{u['group']}' at ({pos}) as "
           "drawn")
    if u["in_thin_walls"] * 2 >= u["worst"]:
        a = u.get("spacing")
        finer = f" (spacing ≤ {a / 2:g})" if a else ""
        out += (f"; {u['in_thin_walls']} of the {u['worst']} largest lie in or beside walls one "
                "particle thick, which have no stiffness across themselves but what their "
                "stretching gives (they buckle under compression), so Newton's method cannot "
                "settle them: a finer spacing" + finer + " puts two particles across those "
                "walls (summary.json: warnings)")
    return out


def _rounding_hint(summary: dict) -> str:
    """For a static run stopped near the rounding of its own forces (engines.static.
    rounding_floor): why no number of iterations would settle it, and what would."""
    floor = summary.get("rounding_floor")
    if floor is None or floor < 0.1 * summary.get("tolerance", 1e-6):
        return ""
    return (f". The rounding of its positions in double precision alone can leave up to about "
            f"{floor:.2g} of the applied load unbalanced (its stiffness × the size of its "
            "coordinates × 2.2e-16): the load deforms the part too little for the tolerance to be "
            "reachable, and the state is an equilibrium only as far as that rounding resolves it. "
            "A larger load settles it")


def _fea_inputs(rundir: Path) -> str | None:
    """What ``rackstress fea`` cannot read in a run directory, in a sentence (else None):
    ``scene.json`` missing or not JSON, ``boundary.npz`` not a readable NumPy archive (a copy cut
    short, a file overwritten)."""
    import json
    import zipfile

    import numpy as np

    scene = rundir / "scene.json"
    try:
        json.loads(scene.read_text())
    except FileNotFoundError:
        return (f"{scene} is missing: the run directory is incomplete (was it copied in part?); "
                "run the scene again")
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return f"{scene} cannot be read ({exc}): the run directory is damaged; run the scene again"
    bnd = rundir / "boundary.npz"
    if bnd.exists():
        try:
            with np.load(bnd) as z:
                for k in z.files:
                    z[k]
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            return (f"{bnd} cannot be read ({exc or type(exc).__name__}): remove it to take the "
                    "supports and loads from the scene, or run the scene again")
    return None


@main.command("inspect")
@click.argument("file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--scale", type=float, help="Multiply the file's coordinates (1000: metres to "
              "mm, 25.4: inches to mm); the same as a scene's scale.")
@click.option("--budget", type=click.IntRange(min=1), default=None,
              help="Particles the suggested spacing may make (default 20,000).")
@click.option("--json", "as_json", is_flag=True, help="Everything as JSON, for scripts.")
@click.option("--all", "all_faces", is_flag=True, help="Every flat face, not the largest only.")
@click.option("--png", type=click.Path(dir_okay=False, path_type=Path),
              help="Also a picture of the part with the names written on it.")
@click.option("--bodies", type=click.Choice(["one", "united"]), default="one",
              show_default=True, help="united: the union of the file's bodies, as a scene "
              "with bodies = \"united\" fills it and names its holes and faces.")
def inspect_cmd(file, scale, budget, as_json, all_faces, png, bodies):
    """A part's holes (H1, H2, ...), flat faces (F1, F2, ...), size, bodies, volume,
    watertightness, thinnest walls and the spacing a scene without one gets.

    The names are what a scene file holds and loads by: where = { hole = "H1" },
    where = { face = "F3" }. Exit 2 for a file it cannot read.
    """
    from rackstress.scenes import features as ft
    from rackstress.scenes import inspect as insp

    try:
        info = insp.inspect_part(file, scale=scale, budget=budget or ft.BUDGET, bodies=bodies)
        if png is not None:
            insp.picture(file, png, scale=scale, bodies=bodies)
            info["picture"] = str(png)
    except RackstressError as err:
        _fail(err, err.exit_code)
    except OSError as err:
        _fail(RackstressError(os_error_message(err, "write")), EXIT_STORAGE)
    if as_json:
        click.echo(json.dumps(info, indent=1))
        return
    click.echo(insp.text(info, all_faces=all_faces))
    if png is not None:
        click.echo(f"picture: {png}")


@main.command("fea")
@click.argument("rundir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--E", "E", type=float, help="Young's modulus (default: the part's material in "
              "summary.json, else 1: ranks do not depend on it).")
@click.option("--nu", type=float, help="Poisson's ratio (default: the material's, else 0.3).")
@click.option("--size", type=float, help="Largest FE edge (default: 1.5 particle spacings, "
              "graded finer at re-entrant edges); a larger size needs less memory.")
@click.option("--group", help="The part to solve (default: the one with a material, else the "
              "largest with supports or loads).")
@click.option("--measure", help="The particle measure compared (default: von_mises if the run "
              "has it, else strain).")
@click.option("--allow-unsettled", is_flag=True, help="Compare a static run that did not "
              "settle (refused otherwise: its state is not an equilibrium).")
@click.option("--allow-dynamic", is_flag=True, help="Compare a dynamic run's last frame with "
              "the static FE solution (refused otherwise: a moving state is not one).")
@click.option("--no-converge", is_flag=True, help="Solve at one FE size only (default: also "
              "at a coarser one, to say how much the FE's own governing stress moves).")
@click.option("--no-local", is_flag=True, help="Do not refine the FE's governing stress "
              "locally (default, on a mesh part: a submodel about it graded fine, docs/fea.md).")
def fea(rundir, E, nu, size, group, measure, allow_unsettled, allow_dynamic, no_converge,
        no_local):
    """Check a run's part against linear-elastic FEA of the same part (the 'fem' extra).

    Writes fea.json, fea.npz, vtk/fea.vtp, vtk/fea_mesh.vtu, figures/fea.png and the report's
    "Finite-element check" (docs/fea.md). Exit 2 for a run it cannot read or solve, a static
    run that did not settle, a dynamic run (unless allowed) and an FE model that would not fit
    in memory (the message says how much it needs and which --size fits).
    """
    try:
        from rackstress.validity import solid
    except ImportError as exc:
        _fail(RackstressError(f"rackstress fea needs the 'fem' extra (scikit-fem, gmsh): "
                              f"pip install 'rackstress[fem]' ({exc})"), 2)
    if not (Path(rundir) / "summary.json").is_file():
        _fail(RackstressError(f"{rundir}: no summary.json; is this a finished run directory "
                              "(made by 'rackstress run')?"), 2)
    damaged = _fea_inputs(Path(rundir))
    if damaged:
        _fail(RackstressError(f"rackstress fea {rundir}: {damaged}"), 2)
    try:                        # fea's files, recorded as the run's (runs/rundir.py)
        from rackstress.runs.rundir import own

        own(rundir, ["fea.json", "fea.npz", "vtk", "figures", "report.html", "view3d.html"],
            "the FE check")
    except RackstressError as exc:
        _fail(exc, exc.exit_code)
    try:
        data = solid.check_run(rundir, E=E, nu=nu, size=size, group=group, measure=measure,
                               echo=click.echo, allow_unsettled=allow_unsettled,
                               allow_dynamic=allow_dynamic, converge=not no_converge,
                               local=not no_local)
    except (ValueError, RackstressError) as exc:
        _fail(RackstressError(f"rackstress fea {rundir}: {exc}"), getattr(exc, "exit_code", 2))
    except MemoryError:
        _fail(RackstressError(f"rackstress fea {rundir}: out of memory; try a coarser FE mesh "
                              "(--size, e.g. twice the run's spacing)"), 2)
    _write_report(rundir)
    ag, gv, unit = data["agreement"], data["governing"], data.get("stress_unit", "")
    click.echo(f"fea: {data['group']} ({data['particles']:,} particles, {data['mesh']}, "
               f"{data['fe']['tetrahedra']:,} tetrahedra): compares {data['compared']}")
    if data["fe_quality"]["poor"]:
        click.echo(f"fea: POOR FE MESH: {data['fe_quality']['why']}")
    click.echo(f"fea: Spearman {ag['spearman']:.3f}, top-5 % overlap {ag['top5_overlap']:.2f} "
               f"({data['measure']})")
    for b in data["bands"]:
        if b["n"]:
            click.echo(f"fea:   {b['band']:>5} spacings from a singular point: {b['n']:,} "
                       "particles, " + ", ".join(
                           f"{k} {b[v]:.3f}" for k, v in (("Spearman", "spearman"),
                                                           ("peak ratio", "peak_ratio"),
                                                           ("median error", "median_error"))
                           if b[v] is not None))
    if gv.get("value") is not None:
        moved = "" if gv.get("moved") is None else \
            f"; it moved {100 * gv['moved']:.1f} % from FE size {gv['coarser']['size']:.3g}"
        click.echo(f"fea: FE's governing stress {gv['value']:.4g} {unit} at "
                   f"{[round(x, 2) for x in gv['position']]} (zone {data['zone']['length']:.3g} from "
                   f"{data['zone'].get('source', 'the FE surface')})"
                   + moved)
        lc = gv.get("local")
        if lc:
            from rackstress.render.report import local_refinement

            click.echo("fea: " + local_refinement(lc, unit, length_digits=3))
        elif gv.get("local_note"):
            click.echo(f"fea: {gv['local_note']}")
        if gv.get("ratio") is not None:
            click.echo(f"fea: the particles there: {gv['particle_value']:.4g} {unit} (particle "
                       f"{gv['particle']}, ratio {gv['ratio']:.3f}); their own governing "
                       f"stress {gv['particles_governing']:.4g} (ratio "
                       f"{gv['particles_governing_ratio']:.3f})")
    click.echo(f"fea: wrote {rundir}/fea.json ({data['wall_s']:.0f} s)")


@main.group()
def bench():
    """Benchmarks of stability, work-precision and speed (outputs in docs/benchmarks/)."""


#: every benchmark's ``--out``
_bench_out = click.option("--out", type=click.Path(file_okay=False, path_type=Path),
                          help="Output directory (default: docs/benchmarks/ of the repository).")


def _bench_report(data, mod):
    from rackstress.bench import md_table

    click.echo(md_table(mod.HEADER, mod.table_rows(data)))
    for f in data["files"]:
        click.echo(f"wrote {f}")
    click.echo(f"({data['wall_s']:.0f} s)")


@bench.command("stability")
@_bench_out
@click.option("--quick", is_flag=True, help="A few cases only.")
@click.option("--magpod", is_flag=True, help="Also the 17,480-iteration MagPod run on LAMMPS.")
@click.option("--magpod-steps", type=click.IntRange(min=1), default=17480, show_default=True)
@click.option("--only", multiple=True, help="Only cases whose label contains this (repeatable).")
def bench_stability(out, quick, magpod, magpod_steps, only):
    """Largest stable t by bisection (reference engine) beside the predicted limit."""
    from rackstress.bench import stability as mod

    data = mod.run_bench(out, quick=quick, magpod=magpod, magpod_steps=magpod_steps,
                         only=only or None, echo=click.echo)
    _bench_report(data, mod)
    if data.get("magpod"):
        mp = data["magpod"]
        click.echo(f"magpod: {mp['status']} over {mp['steps']} iterations at t = 0.01 "
                   f"(predicted t_max {mp['t_pred']:.4g})")


@bench.command("accuracy")
@_bench_out
@click.option("--quick", is_flag=True, help="Shorter physical times (under 5 minutes).")
@click.option("--scene", "scene_names", multiple=True,
              type=Choice(["plane-bound", "plane-rack", "magpod-small"]),
              help="Only these scenes (repeatable; default: all three).")
def bench_accuracy(out, quick, scene_names):
    """Work-precision: errors against a converged reference vs wall time."""
    from rackstress.bench import accuracy as mod

    data = mod.run_bench(out, quick=quick, scenes_=scene_names or None, echo=click.echo)
    _bench_report(data, mod)


@bench.command("e2e")
@_bench_out
@click.option("--scene", "scene_names", multiple=True,
              type=click.Choice(["magpod-small", "magpod", "sediment-large"]),
              help="Scenes (default: all three).")
@click.option("--repeat", type=click.IntRange(min=1), default=1, show_default=True,
              help="Cold and warm runs of each scene, interleaved.")
@click.option("--long-steps", type=click.IntRange(min=1), default=1200, show_default=True,
              help="Iterations of magpod and sediment-large (magpod-small runs its own 4800).")
@click.option("--append", is_flag=True,
              help="Add these runs to those of OUT/e2e.json (e.g. magpod-small repeated, "
                   "the long scenes once).")
def bench_e2e(out, scene_names, repeat, long_steps, append):
    """README's first command end to end, warm and cold: phases, run directory by file, the
    trajectory's cost per frame -> docs/benchmarks/e2e.{json,md}."""
    from rackstress import bench as b
    from rackstress.bench import e2e

    names = scene_names or e2e.SCENES
    d = b.out_dir(out)
    machine = b.machine()
    data = e2e.run(d, names, repeat,
                   steps={n: long_steps for n in ("magpod", "sediment-large")}, log=click.echo)
    if append and (d / "e2e.json").is_file():
        old = json.loads((d / "e2e.json").read_text())
        data["runs"] = old.get("runs", []) + data["runs"]
        data["dumps"] = data["dumps"] or old.get("dumps", [])
        machine = old.get("machine") or machine
    data["machine"] = machine
    b.write_json(d / "e2e.json", data)
    (d / "e2e.md").write_text(e2e.markdown(data, machine))
    click.echo(f"wrote {d / 'e2e.md'}")


@bench.command("perf")
@_bench_out
@click.option("--steps", type=click.IntRange(min=1), default=1200, show_default=True)
@click.option("--quick", is_flag=True, help="300 iterations.")
@click.option("--profile-steps", type=click.IntRange(min=0), default=100, show_default=True,
              help="Iterations of the extra chunk profiled by LAMMPS (0: none).")
@click.option("--scene", "scene_name", default="magpod", show_default=True,
              type=Choice(["magpod", "magpod-small"]))
@click.option("--no-mpi", is_flag=True, help="Skip the mpiexec -n 2 configurations.")
@click.option("--only", multiple=True,
              help="Measure only the rows of this scene (e.g. sediment-large:sediment_nx=4400; "
                   "repeatable); the other rows of perf.json in --out stay.")
def bench_perf(out, steps, quick, profile_steps, scene_name, no_mpi, only):
    """Wall time per 1200 MagPod iterations: reference, LAMMPS modes, serial and 2 ranks."""
    from rackstress.bench import perf as mod

    configs = [c for c in mod.CONFIGS if not (no_mpi and c[2] > 1)]
    data = mod.run_bench(out, steps=steps, quick=quick, profile_steps=profile_steps,
                         scene_name=scene_name, configs=configs, echo=click.echo, only=only)
    _bench_report(data, mod)
    from rackstress.bench import md_table

    click.echo(md_table(*mod.breakdown_rows(data)))


@bench.command("scaling")
@_bench_out
@click.option("--quick", is_flag=True, help="A 40 x 20 x 20 block and 60 MagPod steps.")
@click.option("--remodel", is_flag=True, help="Recompute the model from scaling.json, no runs.")
@click.option("--large", is_flag=True,
              help="Also the 4,007,689-particle bed (sediment-large:sediment_nx=4400; ~2 GB).")
@click.option("--scene", "only", multiple=True,
              help="Measure only this scene (block, magpod, sediment-large, "
                   "sediment-large:sediment_nx=4400); the others' rows in scaling.json stay.")
def bench_scaling(out, quick, remodel, large, only):
    """The compiled plugin on 1 and 2 ranks (standalone decks in plain lmp), modelled to 1,024
    ranks from the measured ghosts, communication and reductions (docs/benchmarks/scaling.md)."""
    from rackstress.bench import scaling as mod

    data = (mod.from_json(out) if remodel
            else mod.run_bench(out, quick=quick, echo=click.echo, large=large, only=only))
    _bench_report(data, mod)


@bench.command("inside")
@_bench_out
@click.option("--quick", is_flag=True, help="3,000 and 17,600 particles only.")
def bench_inside(out, quick):
    """Binding a mesh part inside its shape: 17,600 / 100,000 / 1,000,000 particles."""
    from rackstress.bench import inside as mod

    data = mod.run_bench(out, quick=quick, echo=click.echo)
    _bench_report(data, mod)


@bench.command("hertz")
@_bench_out
@click.option("--quick", is_flag=True, help="The coarsest spacing only.")
def bench_hertz(out, quick):
    """Hertz's sphere on a flat (``[[indenter]]``): contact radius and peak pressure against
    Hertz's, static and on LAMMPS, at three spacings -> docs/benchmarks/hertz.{json,md}."""
    from rackstress.bench import hertz as mod

    data = mod.run_bench(out, quick=quick, echo=click.echo)
    _bench_report(data, mod)


@bench.command("governing")
@_bench_out
@click.option("--quick", is_flag=True, help="Every part at two spacings (h and h/sqrt(2), "
              "--refine's pair) and one FE size: no three-spacing order.")
def bench_governing(out, quick):
    """The governing stress, singular peak and --refine error bar against converged FEA."""
    from rackstress.bench import governing as mod

    data = mod.run_bench(out, quick=quick, echo=click.echo)
    _bench_report(data, mod)


@bench.command("validity3d")
@_bench_out
@click.option("--quick", is_flag=True, help="Spacing 1 only.")
def bench_validity3d(out, quick):
    """The bracket STL's particle von Mises stress against tetrahedral FEA (the 'fem' extra)."""
    from rackstress.bench import validity3d as mod

    data = mod.run_bench(out, quick=quick, echo=click.echo)
    _bench_report(data, mod)


@bench.command("walls")
@_bench_out
@click.option("--quick", is_flag=True, help="Two depths only.")
def bench_walls(out, quick):
    """A cantilever whose faces fall between the lattice's layers: tip, curvature and the
    face stress read against beam theory -> docs/benchmarks/walls.{json,md}."""
    from rackstress.bench import walls as mod

    data = mod.run_bench(out, quick=quick, echo=click.echo)
    _bench_report(data, mod)


@bench.command("stress")
@_bench_out
@click.option("--quick", is_flag=True, help="One small bar per case (for tests).")
def bench_stress(out, quick):
    """Stress from particles (virial, completed, Hooke) against tension and bending."""
    from rackstress.bench import stress as mod

    data = mod.run_bench(out, quick=quick, echo=click.echo)
    _bench_report(data, mod)


@bench.command("validity")
@_bench_out
@click.option("--quick", is_flag=True, help="Small bodies and coarse meshes (seconds).")
@click.option("--planar", is_flag=True,
              help="Only the planar cases as aluminium scenes in MPa (~2 min); rewrites their "
                   "section of validity.md.")
@click.option("--concentrations", is_flag=True,
              help="Only the stress concentrations (plate with a hole, fillet, notch, C-frame, "
                   "round shoulder): the governing stress against converged FEA and Peterson "
                   "at three spacings (validity-concentrations.md).")
@click.option("--case", "cases", multiple=True, help="With --concentrations: this case only "
              "(repeatable): plate-hole, fillet, notch, cframe, round-shoulder.")
@click.option("--spacings", help="With --concentrations: these spacings [mm], comma-separated "
              "(default: each case's three).")
def bench_validity(out, quick, planar, concentrations, cases, spacings):
    """Stress measures of three body models against linear-elastic FEA (three cases)."""
    if concentrations or cases or spacings:
        from rackstress.bench import concentrations as conc

        conc.run_bench(out, cases=list(cases) or None,
                       spacings=[float(x) for x in spacings.split(",")] if spacings else None,
                       echo=click.echo)
        return
    if planar:
        from rackstress.bench import planar as mod

        _bench_report(mod.run_bench(out, quick=quick, echo=click.echo), mod)
        return
    from rackstress.bench import validity as mod

    data = mod.run_bench(out, quick=quick, echo=click.echo)
    _bench_report(data, mod)
    # the material solid in physical units: the cantilever at spacings 2, 1, 0.5 mm
    from rackstress.bench import cantilever

    cantilever.run_bench(out, quick=quick, echo=click.echo)


@bench.command("parts")
@_bench_out
@click.option("--fea/--no-fea", default=True, show_default=True,
              help="Check each settled part by FEA (rackstress fea); --no-fea for speed.")
@click.option("--only", multiple=True, help="Only parts whose name contains this (repeatable).")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override every part's scene, e.g. --set budget=5000 (repeatable).")
@click.option("--timeout", type=click.FloatRange(min=1), default=900.0, show_default=True,
              help="Seconds a part's run (and its FE check) may take before it is stopped "
                   "(with --refine the run may take three times as long).")
@click.option("--refine", is_flag=True,
              help="Run each part with --refine (again at spacing/sqrt(2)) and give the refined "
                   "governing stress and its error bar against the FE check.")
@click.option("--refine-ratio", type=click.FloatRange(min=1.2, max=3.0), default=None,
              help="With --refine: each part's spacing divided by this (rackstress run "
                   "--refine-ratio), not sqrt(2).")
def bench_parts(out, fea, only, sets, timeout, refine, refine_ratio):
    """Every real part of examples/parts/ through the static path: particles, spacing, Newton
    steps, residual, solve time, peak and the FE agreement (docs/benchmarks/parts.md)."""
    from rackstress import scenes
    from rackstress.bench import parts as mod

    _refine_ratio_needs_refine(refine, refine_ratio)
    data = mod.run_bench(out, fea=fea, only=only or None,
                         sets=scenes.parse_overrides(sets), echo=click.echo, timeout=timeout,
                         refine=refine, refine_ratio=refine_ratio)
    _bench_report(data, mod)


@bench.command("offsets")
@_bench_out
@click.option("--offsets", "n", type=click.IntRange(min=2, max=16), default=6,
              show_default=True, help="Lattices per part, the scene's own included.")
@click.option("--only", multiple=True, help="Only parts whose name contains this (repeatable).")
def bench_offsets(out, n, only):
    """Every real part of examples/parts/ on N lattices moved within a spacing (rackstress run
    --offsets), against bench parts' converged FE readings (docs/benchmarks/offsets.md)."""
    from rackstress.bench import offsets as mod

    data = mod.run_bench(out, n=n, only=only or None, echo=click.echo)
    _bench_report(data, mod)


@bench.command("cantilever")
@_bench_out
@click.option("--quick", is_flag=True, help="Spacings 2 and 1 only, no 100,000-particle run.")
def bench_cantilever(out, quick):
    """The aluminium cantilever against beam theory (spacings 2, 1, 0.5 mm), the lattice's
    calibration (E_eff, ν), what ν = 1/4 costs, and 100,000 particles to equilibrium beside
    scikit-fem (docs/benchmarks/cantilever.md)."""
    from rackstress.bench import cantilever

    data = cantilever.run_bench(out, quick=quick, echo=click.echo)
    click.echo(cantilever.report(data))


@bench.command("dynamics")
@_bench_out
@click.option("--quick", is_flag=True, help="Spacing 2 mm only; the drop at 3 mm, the pin "
                                            "joint at 2 mm.")
def bench_dynamics(out, quick):
    """Time stepping in physical units against analytical answers: the cantilever's free
    vibration (f1–f3 against Timoshenko and Euler–Bernoulli) and a bar striking a wall (the
    stress wave ρ·c·v and its arrival) and two bars in contact, at spacings 2, 1.25 and 1 mm;
    then the drop test (examples/dynamics/drop.toml, ~20,000 particles) and the pin joint
    (examples/assembly/pin-joint.toml, static) as ``rackstress run`` runs them, on one core,
    under ``mpiexec -n 2`` and in plain ``lmp`` (docs/benchmarks/dynamics.md)."""
    from rackstress.bench import dynamics

    dynamics.run_bench(out, spacings=(2.0,) if quick else dynamics.SPACINGS, echo=click.echo,
                       quick=quick)


@bench.command("lattice")
@_bench_out
@click.option("--quick", is_flag=True, help="Spacings 2 and 1 only.")
def bench_lattice(out, quick):
    """The lattice's calibration proven: E_eff and ν_eff (uniaxial tension), bulk modulus
    (hydrostatic box) and shear modulus on the axes and at 45° (isotropy) at ν = 0, 0.2, 0.3,
    0.33, 0.45 and three spacings (docs/benchmarks/lattice.md)."""
    from rackstress.bench import lattice

    data = lattice.run_bench(out, quick=quick, echo=click.echo)
    click.echo(lattice.report(data))


@bench.command("nafems")
@_bench_out
@click.option("--quick", is_flag=True, help="The two coarser spacings only.")
def bench_nafems(out, quick):
    """NAFEMS LE1 (elliptic membrane) and LE10 (thick plate under pressure), a hole's K_t
    (Kirsch) and a laterally constrained block at ν = 0.3 and 0.45, three spacings each
    (LE10 with the lattice a mesh part gets by default: four; docs/benchmarks/nafems.md)."""
    from rackstress.bench import nafems

    data = nafems.run_bench(out, quick=quick, echo=click.echo)
    click.echo(nafems.report(data))


@bench.command("static")
@_bench_out
@click.option("--quick", is_flag=True, help="The cantilever at 2 and 1 mm only.")
@click.option("--scene", "scenes", multiple=True, type=click.Path(exists=True),
              help="A static scene file to add (repeatable), e.g. a part of your own.")
def bench_static(out, quick, scenes):
    """The static solve's CPU, wall, Newton steps, residual and peak memory on the cantilever
    up to ~100,000 particles and on the SO-ARM100's parts, by the direct factorization and by
    AMG-CG alone (docs/benchmarks/static.md)."""
    from rackstress.bench import static

    data = static.run_bench(out, quick=quick, scenes=scenes, echo=click.echo)
    click.echo(static.report(data))


@bench.command("magpod-physical")
@_bench_out
@click.option("--repeats", type=click.IntRange(min=1), default=2, show_default=True,
              help="Runs of each scene, alternately (the fastest of each is compared).")
@click.option("--phase-steps", type=click.IntRange(min=1), default=1200, show_default=True,
              help="Iterations a gait phase (the scene's 1200; fewer only for a quick look).")
def bench_magpod_physical(out, repeats, phase_steps):
    """MagPod in physical units: one gait cycle of magpod-physical-small (its legs' von Mises
    in MPa, quasi-static per frame) against magpod-small's, and the paper's four cycles of
    magpod-physical against magpod's, as cost ratios; the mapping, the
    legs' lowest natural frequency against the gait's, a bar against F/A
    (docs/benchmarks/magpod-physical.md, docs/magpod/physical.md)."""
    from rackstress.bench import magpod_physical

    data = magpod_physical.run_bench(out, repeats=repeats, phase_steps=phase_steps,
                                     echo=click.echo)
    click.echo(magpod_physical.markdown(data))


if __name__ == "__main__":  # pragma: no cover
    entry()


# ---------------------------------------------------------------------------- help that teaches
#: Every command's one-line purpose (the command list shows it whole) and two or three
#: examples (its --help ends with them). A command added without an entry fails
#: tests/test_help.py.
TEACH = {
    "": ("Stress pictures of particle bodies held by rack particles, on LAMMPS.", [
        "rackstress scenes",
        "rackstress run plane-rack --out runs/plane-rack",
        "rackstress render runs/plane-rack --measure strain",
    ]),
    "run": ("Run a scene and write its run directory, peaks and pictures.", [
        "rackstress run plane-rack --out runs/plane-rack",
        "rackstress run examples/cframe/static.toml --refine --offsets 4 --out runs/cframe",
        "mpiexec -n 2 rackstress run magpod-small --set cycles=2 --out runs/ms",
        "rackstress run --resume runs/ms",
    ]),
    "deck": ("Write a scene's LAMMPS data file and input deck, without running.", [
        "rackstress deck plane-rack --out decks/plane-rack",
        "rackstress deck plane-rack --mode fast --steps 2000 --out decks/pr-fast",
        "(cd decks/pr-fast && lmp -in in.lammps)",
    ]),
    "scenes": ("List the scenes: particles, what each shows, parameters.", [
        "rackstress scenes",
        "rackstress scenes scenes/two-blobs.toml examples/bracket/scene.toml",
    ]),
    "render": ("Render a run's stress pictures, plots and report.html again.", [
        "rackstress render runs/plane-rack",
        "rackstress render runs/ms --measure strain --frames 1320,2600 --views front",
        "rackstress render runs/ms --movie --movie-view left --vmax 3",
    ]),
    "stress": ("Compute the stress measures for ParaView and OVITO (VTK, dump).", [
        "rackstress stress runs/plane-rack",
        "rackstress stress runs/plane-rack --no-dump --out exports/pr",
        "rackstress stress data.lmp dump.lammpstrj --parts type --dt 0.01 --out exports/md",
    ]),
    "batch": ("Run a sweep of jobs (TOML), over MPI ranks under mpiexec.", [
        "rackstress batch sweeps/plane-rack-6.toml --out batches/pr6",
        "mpiexec -n 2 rackstress batch sweeps/magpod-small-gait.toml --out batches/gait",
        "rackstress batch --report batches/pr6 --figure groups.plane.max_deformation",
    ]),
    "bench": ("Benchmarks: stability, work-precision, speed, validity.", [
        "rackstress bench stability --quick --out /tmp/bench",
        "rackstress bench perf --quick --no-mpi --out /tmp/bench",
    ]),
    "bench stability": ("Largest stable time step by bisection against the prediction.", [
        "rackstress bench stability --quick --out /tmp/bench",
        "rackstress bench stability --only plane --out /tmp/bench",
    ]),
    "bench accuracy": ("Work-precision: error against wall time per engine and mode.", [
        "rackstress bench accuracy --quick --out /tmp/bench",
        "rackstress bench accuracy --scene plane-rack --out /tmp/bench",
    ]),
    "bench perf": ("Wall time per 1200 MagPod iterations, serial and 2 ranks.", [
        "rackstress bench perf --quick --out /tmp/bench",
        "rackstress bench perf --steps 2400 --no-mpi --out /tmp/bench",
    ]),
    "bench validity": ("Stress measures of three bodies against linear-elastic FEA.", [
        "rackstress bench validity --quick --out /tmp/bench",
        "rackstress bench validity --out docs/benchmarks",
        "rackstress bench validity --planar --out docs/benchmarks",
        "rackstress bench validity --concentrations --case plate-hole --spacings 0.8,0.6",
    ]),
    # commands that may not exist in every build (applied when the command exists)
    "inspect": ("Name a part's holes and faces; its walls and a spacing.", [
        "rackstress inspect examples/bracket/bracket.stl",
        "rackstress inspect arm.stl --scale 1000 --png arm-names.png",
        "rackstress inspect part.step --json > part.json",
    ]),
    "fea": ("Check a run's part against linear-elastic FEA of the same part.", [
        "rackstress fea runs/bracket",
        "rackstress fea runs/bracket --E 70e3 --nu 0.33 --size 0.5",
        "rackstress fea runs/ms --group rightleg --measure strain",
    ]),
    "bench cantilever": ("The aluminium cantilever against beam theory, to equilibrium.", [
        "rackstress bench cantilever --quick --out /tmp/bench",
        "rackstress bench cantilever --out docs/benchmarks",
    ]),
    "bench dynamics": ("Vibration and a stress wave in physical units, against theory.", [
        "rackstress bench dynamics --quick --out /tmp/bench",
        "rackstress bench dynamics --out docs/benchmarks",
    ]),
    "bench magpod-physical": ("MagPod's legs in MPa: cost against magpod-small, checks.", [
        "rackstress bench magpod-physical --repeats 1 --phase-steps 300 --out /tmp/bench",
        "rackstress bench magpod-physical --out docs/benchmarks",
    ]),
    "bench static": ("The static solve's time and memory, direct against AMG-CG.", [
        "rackstress bench static --quick --out /tmp/bench",
        "rackstress bench static --scene my-part.toml --out docs/benchmarks",
    ]),
    "bench inside": ("Binding a mesh part inside its shape, up to 10^6 particles.", [
        "rackstress bench inside --quick --out /tmp/bench",
        "rackstress bench inside --out docs/benchmarks",
    ]),
    "bench hertz": ("Hertz's sphere on a flat: contact radius and pressure vs theory.", [
        "rackstress bench hertz",
        "rackstress bench hertz --quick --out /tmp/hertz"]),
    "bench governing": ("The governing stress and --refine's error bar against FEA.", [
        "rackstress bench governing --quick --out /tmp/bench",
        "rackstress bench governing --out docs/benchmarks",
    ]),
    "bench validity3d": ("The bracket STL's von Mises stress [MPa] against tetrahedral FEA.", [
        "rackstress bench validity3d --quick --out /tmp/bench",
        "rackstress bench validity3d --out docs/benchmarks",
    ]),
    "bench offsets": ("Real parts on lattices moved within a spacing, against FE.", [
        "rackstress bench offsets --only hip --offsets 2 --out /tmp/bench",
        "rackstress bench offsets --out docs/benchmarks",
    ]),
    "bench walls": ("A wall between the lattice's layers in bending, against beam theory.", [
        "rackstress bench walls --quick --out /tmp/bench",
        "rackstress bench walls --out docs/benchmarks",
    ]),
    "bench e2e": ("README's first command end to end, cold and warm, by phase.", [
        "rackstress bench e2e --scene magpod-small --out /tmp/bench",
        "rackstress bench e2e --repeat 2 --long-steps 600 --out /tmp/bench",
    ]),
    "bench scaling": ("The compiled plugin on 1 and 2 ranks, modelled to 1,024.", [
        "rackstress bench scaling --quick --out /tmp/bench",
        "rackstress bench scaling --large --out docs/benchmarks",
        "rackstress bench scaling --scene magpod --out docs/benchmarks",
    ]),
    "bench parts": ("Every real part of examples/parts/ through the static path.", [
        "rackstress bench parts --only so100 --set budget=5000 --no-fea --out /tmp/bench",
        "rackstress bench parts --refine --out docs/benchmarks",
        "rackstress bench parts --refine --set poisson=material "
        "--out docs/benchmarks/parts-material",
        "rackstress bench parts --refine --refine-ratio 2 --out docs/benchmarks/parts-half",
    ]),
    "bench lattice": ("E, ν, bulk and shear moduli with the volumetric term.", [
        "rackstress bench lattice --quick --out /tmp/bench",
        "rackstress bench lattice --out docs/benchmarks",
    ]),
    "bench nafems": ("NAFEMS LE1 and LE10, Kirsch and a constrained block.", [
        "rackstress bench nafems --quick --out /tmp/bench",
        "rackstress bench nafems --out docs/benchmarks",
    ]),
    "bench stress": ("Stress from particles against tension and bending.", [
        "rackstress bench stress --quick --out /tmp/bench",
        "rackstress bench stress --out docs/benchmarks",
    ]),
}


def _teach(cmd, path: str = "") -> None:
    """Give ``cmd`` and its subcommands their purpose and examples from :data:`TEACH`."""
    if path in TEACH:
        purpose, examples = TEACH[path]
        cmd.short_help = purpose
        # \b keeps click from rewrapping the examples into one paragraph
        cmd.epilog = "Examples:\n\n\b\n" + "\n".join(f"  {e}" for e in examples)
    for name, sub in getattr(cmd, "commands", {}).items():
        _teach(sub, f"{path} {name}".strip())


_teach(main)
