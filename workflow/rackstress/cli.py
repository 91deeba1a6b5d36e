"""The ``rackstress`` command line: run a scene, write its LAMMPS deck, list scenes."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from rackstress.errors import (EXIT_BUG, EXIT_DIVERGED, EXIT_INPUT, EXIT_RENDER,  # noqa: F401
                               EXIT_STORAGE, DivergenceError, RackstressError, os_error_message)


def _load_scene(scene: str, steps, dt, sets, integrator: str | None = None):
    from rackstress import scenes

    overrides = scenes.parse_overrides(sets)
    sc = scenes.load(scene, overrides)
    if integrator is not None:
        sc.integrator = integrator
        if integrator != "euler":       # recorded where it changes the scene (Eq. 5 is the default)
            sc.params["integrator"] = integrator
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
    from rackstress.lib.mpi import abort, world

    if isinstance(err, DivergenceError):
        msg, code = f"{err} (run directory: {out})", EXIT_DIVERGED
    elif isinstance(err, RackstressError):
        msg, code = str(err), err.exit_code
    elif isinstance(err, OSError):
        msg, code = os_error_message(err, "write"), EXIT_STORAGE
    elif isinstance(err, MemoryError):
        msg, code = ("the machine ran out of memory; make the scene smaller or run it on a "
                     "larger machine"), EXIT_INPUT
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
    sys.exit(code)


#: Options of ``run`` that ``--resume`` cannot honour: the run goes on as it was started.
RESUME_FIXED = ("engine", "mode", "steps", "dt", "sets", "dump_every", "overwrite",
                "restart_every", "allow_unstable", "integrator")


@click.group()
@click.version_option(package_name="rackstress")
def main():
    """Particle-system stress visualization with rack particles, backed by LAMMPS."""


@main.command()
@click.argument("scene", required=False)
@click.option("--engine", type=click.Choice(["lammps", "reference"]), default="lammps",
              show_default=True, help="lammps (the backend) or reference (exact NumPy engine).")
@click.option("--mode", type=click.Choice(["exact", "fast"]), default="exact", show_default=True,
              help="LAMMPS realization: exact (matches the reference to round-off) or fast "
                   "(bind as harmonic bonds; only for scenes it takes out of the callback).")
@click.option("--steps", type=click.IntRange(min=0), help="Iterations to run (default: the scene's).")
@click.option("--dt", type=float, help="Time step t of Eq. 5 (default: the scene's).")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a scene parameter; repeatable (see 'rackstress scenes').")
@click.option("--out", type=click.Path(file_okay=False), callback=_out_path,
              help="Run directory (default: runs/SCENE-TIMESTAMP).")
@click.option("--dump-every", type=click.IntRange(min=1), help="Steps between trajectory frames.")
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
@click.option("--integrator", type=click.Choice(["euler", "verlet"]), default="euler",
              show_default=True, help="euler: Eq. 5, the paper's; verlet: the second-order mode "
              "(leapfrog with trapezoidal damping).")
def run(scene, engine, mode, steps, dt, sets, out, dump_every, overwrite, progress, do_render,
        restart_every=None, resume_dir=None, allow_unstable=False, integrator="euler"):
    """Run SCENE (a built-in name or a .toml file) and write a run directory.

    Exit status (errors.py): 0 done, 2 bad input or a run directory in use or holding another
    run, 3 diverged (frames and summary kept), 4 the run is done but its pictures could not be
    rendered, 5 the disk refused a write (full, read-only, no permission).
    """
    from rackstress.lib.mpi import rank
    from rackstress.runs import run as run_mod
    from rackstress.runs.rundir import check_out, locked

    ctx = click.get_current_context()
    try:
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
        elif scene is None:
            raise click.UsageError("Missing argument 'SCENE' (or give --resume RUNDIR).")
        elif out is not None:
            check_out(out)
        if resume_dir is not None:
            from rackstress.runs.resume import resume_run

            with locked(out, create=False) as held:
                summary = resume_run(resume_dir, scene, progress=progress and rank() == 0)
                _finish(summary, out, do_render, progress)
            return
        sc = _load_scene(scene, steps, dt, sets, integrator)
        if out is None:
            out = Path("runs") / f"{sc.name}-{time.strftime('%Y%m%d-%H%M%S')}"
        if restart_every is None and engine == "lammps":
            from rackstress.runs.checkpoint import default_restart_every

            restart_every = default_restart_every(sc.total_steps)
        # bad input is refused before the run directory is touched
        planned = run_mod.plan(sc, engine, mode, dump_every, allow_unstable=allow_unstable)
        # the lock is held from before anything is written until the pictures are done
        with locked(out) as held:   # noqa: F841
            summary = run_mod.run(sc, out, engine=engine, mode=mode, dump_every=dump_every,
                                  progress=progress and rank() == 0, overwrite=overwrite,
                                  restart_every=restart_every or None,
                                  allow_unstable=allow_unstable, planned=planned)
            _finish(summary, out, do_render, progress)
    except Exception as err:  # noqa: BLE001 - each kind has its exit status (_fail_any)
        _fail_any(err, out)


def _finish(summary: dict, out: Path, do_render: bool, progress: bool = True) -> None:
    """Report a finished run, post-process it and render its pictures (rank 0, the run
    directory still held)."""
    from rackstress.lib.mpi import rank

    if rank() != 0:
        return
    click.echo(f"{summary['scene']}: {summary['steps']} steps on {summary['engine']} "
               f"({summary['mode']}) in {summary['wall_s']:.2f} s -> {out}")
    for name, g in summary["groups"].items():
        md = g["max_deformation"]
        click.echo(f"  {name:12s} n={g['n']:6d}  max_deformation="
                   + (f"{md:.4g}" if md is not None else "-"))
    _post_run(out, progress)
    if do_render:
        from rackstress.render.pictures import render_default

        t0 = time.perf_counter()
        try:
            rep = render_default(out, progress=progress)
        except Exception as err:  # noqa: BLE001 - the run itself is complete and kept
            click.echo(f"rackstress: error: the run finished, but rendering its pictures "
                       f"failed: {err} (retry with 'rackstress render {out}')", err=True)
            sys.exit(EXIT_RENDER)
        click.echo(f"  pictures: {rep.outdir} ({len(rep.files)} files, "
                   f"{time.perf_counter() - t0:.1f} s)")


@main.command()
@click.argument("scene")
@click.option("--out", type=click.Path(file_okay=False), callback=_out_path, required=True)
@click.option("--mode", type=click.Choice(["exact", "fast"]), default="exact", show_default=True)
@click.option("--steps", type=click.IntRange(min=0))
@click.option("--dt", type=float)
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE")
@click.option("--dump-every", type=click.IntRange(min=1), default=None)
def deck(scene, out, mode, steps, dt, sets, dump_every):
    """Write the LAMMPS data file and input deck of SCENE into OUT, without running."""
    from rackstress.engines.lammps.deck import write_deck
    from rackstress.runs.run import default_dump_every

    try:
        sc = _load_scene(scene, steps, dt, sets)
        d = write_deck(sc, out, mode, dump_every or default_dump_every(sc))
    except Exception as err:  # noqa: BLE001 - each kind has its exit status (_fail_any)
        _fail_any(err, out)
    click.echo(f"wrote {out / 'particles.data'} and {out / 'in.lammps'} "
               f"({sc.n_particles} atoms, {len(d.python_ops)} operator(s) in Python)")


@main.command("scenes")
@click.argument("files", nargs=-1)
def list_scenes(files):
    """List the built-in scenes and their parameters (or those of the given .toml scenes)."""
    from rackstress import scenes
    from rackstress.errors import SceneError

    if files:
        from rackstress.scenes.toml import scene_parameters

        for f in files:
            try:
                click.echo(f"{f}\n  " + json.dumps(scene_parameters(f)))
            except SceneError as err:
                _fail(err, EXIT_INPUT)
        return
    for name in scenes.BUILDERS:
        params = scenes.parameters(name)
        click.echo(f"{name}")
        click.echo("  " + json.dumps(params))


def _post_run(out, progress):
    """After a run: the stress measures once, their peaks into summary.json, the VTK series."""
    from rackstress.stress.post import TooLargeError, describe, postprocess

    try:
        info = postprocess(out, vtk=True, dump=False, progress=progress)
    except TooLargeError as err:
        click.echo(f"  note: no stress peaks or VTK files: {err}")
        return
    except Exception as err:  # noqa: BLE001 - the run itself is complete and kept
        click.echo(f"rackstress: error: the run finished, but post-processing its stress "
                   f"failed: {err} (retry with 'rackstress stress {out}')", err=True)
        sys.exit(EXIT_RENDER)
    for line in describe(info):
        click.echo(line)


def _post_job(rundir):
    """A batch job's post-processing: the stress peaks into its summary.json (no VTK: run
    'rackstress stress BATCHDIR/JOB' for the files)."""
    from rackstress.stress.post import postprocess

    postprocess(rundir, vtk=False, dump=False)


def _csv(text):
    return [t.strip() for t in text.split(",") if t.strip()] if text else None


@main.command()
@click.argument("rundir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--frames", metavar="N,N,...",
              help="Iterations to picture (nearest dumped frame is used); default: the paper's "
                   "1320,2600,4720,17480 if the run reaches them, else 4 spread over the run, "
                   "and the iteration of the peak.")
@click.option("--measure", type=click.Choice(["paper", "accumulated", "strain", "d2min",
                                              "virial", "von_mises"]),
              help="Default: von_mises for a scene with a material, else paper. "
                   "paper: distance from desired position (Sec. 5.2); accumulated: its time "
                   "integral; strain: von Mises shear strain; d2min: non-affine D2min; "
                   "virial: LAMMPS per-atom stress (if the dump has it); von_mises: von Mises "
                   "stress from the bindings' forces, in the scene's stress unit (MPa).")
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
def render(rundir, frames, measure, views, groups, out, movie, movie_view, vmax, cmap,
           allow_truncated, progress):
    """Render the stress pictures, sheet, plots (and movie) of RUNDIR; refresh RUNDIR/report.html.

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
            rep = render_run(rundir, frames=its, measure=measure, views=_csv(views) or [],
                             movie=movie, movie_view=movie_view, vmax=vmax, cmap=cmap,
                             groups=_csv(groups), out=out, allow_truncated=allow_truncated,
                             progress=progress)
            record_render(rundir, rep, time.perf_counter() - t0)
            report = _write_report(rundir)
    except Exception as err:  # noqa: BLE001 - each kind has its exit status (_fail_any)
        _fail_any(err)
    for note in rep.notes:
        click.echo(f"note: {note}")
    pk = rep.peak
    click.echo("frames: " + ", ".join(f"{s}" for _, _, s in rep.frames)
               + f"; colour scale 0..{rep.vmax:.4g}"
               + (f"; peak {pk['value']:.4g} at iteration {pk['iteration']}, particle "
                  f"{pk['particle']} ({pk['group']})" if pk else ""))
    for name in rep.files:
        click.echo(f"  wrote {rep.outdir / name}")
    if report is not None:
        click.echo(f"  wrote {report}")
    click.echo(f"rendered in {time.perf_counter() - t0:.1f} s")


def _write_report(rundir):
    """RUNDIR/report.html when RUNDIR is a run directory with a summary; else None."""
    from rackstress.render.report import write_report

    if not (Path(rundir) / "summary.json").is_file():
        return None
    return write_report(rundir)


@main.command()
@click.argument("inputs", nargs=-1, required=True,
                type=click.Path(exists=True, path_type=Path))
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (default: the run directory; for DATA DUMP the dump's folder).")
@click.option("--vtk/--no-vtk", default=True, show_default=True,
              help="Write vtk/run.pvd and one .vtp per frame (ParaView, OVITO, pyvista).")
@click.option("--dump/--no-dump", "write_dump", default=True, show_default=True,
              help="Write stress.dump: a LAMMPS dump with the measures as named columns.")
@click.option("--parts", type=click.Choice(["mol", "type"]),
              help="DATA DUMP: parts by molecule or by atom type (default: mol when the data "
                   "file has several molecules).")
@click.option("--atom-style", help="DATA DUMP: atom style of the data file's Atoms section, if "
                                   "it does not say (atomic, bond, molecular, full, sphere, ...).")
@click.option("--dt", type=float, default=1.0, show_default=True,
              help="DATA DUMP: time per iteration (for the accumulated measure).")
@click.option("--allow-truncated", is_flag=True,
              help="Use the complete frames of a dump that ends mid-frame.")
@click.option("--progress/--no-progress", default=True, show_default=True)
def stress(inputs, out, vtk, write_dump, parts, atom_style, dt, allow_truncated, progress):
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

            with locked(inputs[0], create=False):      # not while a run or render holds it
                info = postprocess(inputs[0], vtk=vtk, dump=write_dump, progress=progress,
                                   out=out)
            where = out or inputs[0]
        elif len(inputs) == 2:
            from rackstress.stress.foreign import load_plain

            if not dt > 0:
                raise RackstressError(f"--dt must be positive, got {dt}")
            where = out or inputs[1].resolve().parent
            run = load_plain(inputs[0], inputs[1], parts=parts, atom_style=atom_style, dt=dt,
                             outdir=where, allow_truncated=allow_truncated)
            info = postprocess(None, run=run, vtk=vtk, dump=write_dump, progress=progress,
                               out=where)
        else:
            raise RackstressError("give one run directory, or a data file and a dump")
    except RackstressError as err:
        _fail(err, EXIT_INPUT)
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
@click.option("--manager", type=click.Choice(["thread", "rank"]), default="thread",
              show_default=True, help="Job hand-out: a thread on rank 0 (which also runs jobs) "
                                      "or rank 0 alone.")
@click.option("--report", "report_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Instead of running: tabulate and plot a finished (or partial) batch.")
@click.option("--figure", help="With --report: a summary figure as a dotted path "
                               "(default: groups.FIRSTGROUP.max_deformation).")
@click.option("--against", help="With --report: the swept parameter on the x axis "
                                "(default: the first swept one).")
def batch(sweep, out, ranks_per_job, retry_failed, manager, report_dir, figure, against):
    """Run every job of a SWEEP file (TOML), over MPI ranks when under mpiexec.

    Jobs that diverge or fail are recorded and the rest go on; a killed batch run again on the
    same --out finishes only what was not finished. Exit status: 0 all jobs finished (whatever
    their status), 2 bad input (also a --figure no summary has), 5 the disk refused a write.
    """
    from rackstress.runs import batch as batch_mod
    from rackstress.lib.mpi import rank

    try:
        if report_dir is not None:
            batch_mod.report(report_dir, figure, against, log=click.echo)
            return
        if sweep is None:
            raise click.UsageError("give a SWEEP file, or --report BATCHDIR")
        if out is not None:
            from rackstress.runs.rundir import check_out

            check_out(out)
        index = batch_mod.run_batch(sweep, out, ranks_per_job, retry_failed, manager,
                                    log=lambda m: click.echo(m) if rank() == 0 else None,
                                    post=_post_job)
    except click.UsageError:
        raise
    except Exception as err:  # noqa: BLE001 - each kind has its exit status (_fail_any)
        _fail_any(err, out)
    if rank() == 0:
        p = index["passes"][-1]
        click.echo(f"batch {'complete' if index['complete'] else 'incomplete'}: "
                   + ", ".join(f"{v} {k}" for k, v in sorted(index["counts"].items()))
                   + f"; this pass ran {p['jobs_run']} job(s) in {p['wall_s']:.2f} s")


@main.group()
def bench():
    """Benchmarks of stability, work-precision and speed (outputs in docs/benchmarks/)."""


def _bench_report(data, mod):
    from rackstress.bench import md_table

    click.echo(md_table(mod.HEADER, mod.table_rows(data)))
    for f in data["files"]:
        click.echo(f"wrote {f}")
    click.echo(f"({data['wall_s']:.0f} s)")


@bench.command("stability")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Output directory (default: docs/benchmarks/ of the repository).")
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
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Output directory (default: docs/benchmarks/ of the repository).")
@click.option("--quick", is_flag=True, help="Shorter physical times (under 5 minutes).")
@click.option("--scene", "scene_names", multiple=True,
              type=click.Choice(["plane-bound", "plane-rack", "magpod-small"]),
              help="Only these scenes (repeatable; default: all three).")
def bench_accuracy(out, quick, scene_names):
    """Work-precision: errors against a converged reference vs wall time."""
    from rackstress.bench import accuracy as mod

    data = mod.run_bench(out, quick=quick, scenes_=scene_names or None, echo=click.echo)
    _bench_report(data, mod)


@bench.command("perf")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Output directory (default: docs/benchmarks/ of the repository).")
@click.option("--steps", type=click.IntRange(min=1), default=1200, show_default=True)
@click.option("--quick", is_flag=True, help="300 iterations.")
@click.option("--profile-steps", type=click.IntRange(min=0), default=100, show_default=True,
              help="Iterations of the extra chunk profiled by LAMMPS (0: none).")
@click.option("--scene", "scene_name", default="magpod", show_default=True,
              type=click.Choice(["magpod", "magpod-small"]))
@click.option("--no-mpi", is_flag=True, help="Skip the mpiexec -n 2 configurations.")
def bench_perf(out, steps, quick, profile_steps, scene_name, no_mpi):
    """Wall time per 1200 MagPod iterations: reference, LAMMPS modes, serial and 2 ranks."""
    from rackstress.bench import perf as mod

    configs = [c for c in mod.CONFIGS if not (no_mpi and c[2] > 1)]
    data = mod.run_bench(out, steps=steps, quick=quick, profile_steps=profile_steps,
                         scene_name=scene_name, configs=configs, echo=click.echo)
    _bench_report(data, mod)
    from rackstress.bench import md_table

    click.echo(md_table(*mod.breakdown_rows(data)))


@bench.command("stress")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Output directory (default: docs/benchmarks/ of the repository).")
@click.option("--quick", is_flag=True, help="One small bar per case (for tests).")
def bench_stress(out, quick):
    """Stress from particles (virial, completed, Hooke) against tension and bending."""
    from rackstress.bench import stress as mod

    data = mod.run_bench(out, quick=quick, echo=click.echo)
    _bench_report(data, mod)


@bench.command("validity")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Output directory (default: docs/benchmarks/ of the repository).")
@click.option("--quick", is_flag=True, help="Small bodies and coarse meshes (seconds).")
def bench_validity(out, quick):
    """Stress measures of three body models against linear-elastic FEA (three cases)."""
    from rackstress.bench import validity as mod

    data = mod.run_bench(out, quick=quick, echo=click.echo)
    _bench_report(data, mod)


if __name__ == "__main__":  # pragma: no cover
    main()
