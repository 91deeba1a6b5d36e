"""The ``rackstress`` command line: run a scene, write its LAMMPS deck, list scenes."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from .errors import DivergenceError, RackstressError

#: Exit codes: bad input, diverged run, pictures failed after a good run.
EXIT_INPUT, EXIT_DIVERGED, EXIT_RENDER = 2, 3, 4


def _load_scene(scene: str, steps, dt, sets):
    from . import scenes

    overrides = scenes.parse_overrides(sets)
    sc = scenes.load(scene, overrides)
    if dt is not None:
        if not dt > 0:
            raise RackstressError(f"--dt must be positive, got {dt}")
        sc.dt = float(dt)
        sc.params["dt"] = float(dt)
        sc.validate()
    if steps is not None:
        sc = sc.with_steps(int(steps))
    return sc


def _fail(err: Exception, code: int):
    click.echo(f"rackstress: error: {err}", err=True)
    sys.exit(code)


@click.group()
@click.version_option(package_name="rackstress")
def main():
    """Particle-system stress visualization with rack particles, backed by LAMMPS."""


@main.command()
@click.argument("scene")
@click.option("--engine", type=click.Choice(["lammps", "reference"]), default="lammps",
              show_default=True, help="lammps (the backend) or reference (exact NumPy engine).")
@click.option("--mode", type=click.Choice(["exact", "fast"]), default="exact", show_default=True,
              help="LAMMPS realization: exact (matches the reference to round-off) or fast.")
@click.option("--steps", type=click.IntRange(min=0), help="Iterations to run (default: the scene's).")
@click.option("--dt", type=float, help="Time step t of Eq. 5 (default: the scene's).")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a scene parameter; repeatable (see 'rackstress scenes').")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path),
              help="Run directory (default: runs/SCENE-TIMESTAMP).")
@click.option("--dump-every", type=click.IntRange(min=1), help="Steps between trajectory frames.")
@click.option("--overwrite", is_flag=True, help="Replace a finished run in --out.")
@click.option("--progress/--no-progress", default=True, show_default=True)
@click.option("--render/--no-render", "do_render", default=True, show_default=True,
              help="Render the default stress pictures and plots into OUT/figures/ at the end.")
def run(scene, engine, mode, steps, dt, sets, out, dump_every, overwrite, progress, do_render):
    """Run SCENE (a built-in name or a .toml file) and write a run directory.

    Exit status: 0 done, 2 bad input, 3 diverged (frames and summary kept), 4 the run is done
    but its pictures could not be rendered.
    """
    from . import run as run_mod
    from .mpi import rank

    try:
        sc = _load_scene(scene, steps, dt, sets)
        if out is None:
            out = Path("runs") / f"{sc.name}-{time.strftime('%Y%m%d-%H%M%S')}"
        summary = run_mod.run(sc, out, engine=engine, mode=mode, dump_every=dump_every,
                              progress=progress and rank() == 0, overwrite=overwrite)
    except DivergenceError as err:
        _fail(f"{err} (run directory: {out})", EXIT_DIVERGED)
    except RackstressError as err:
        _fail(err, EXIT_INPUT)
    if rank() == 0:
        click.echo(f"{summary['scene']}: {summary['steps']} steps on {summary['engine']} "
                   f"({summary['mode']}) in {summary['wall_s']:.2f} s -> {out}")
        for name, g in summary["groups"].items():
            click.echo(f"  {name:12s} n={g['n']:6d}  max_deformation={g['max_deformation']:.4g}")
        if do_render:
            from .render import render_default

            t0 = time.perf_counter()
            try:
                rep = render_default(out)
            except Exception as err:  # noqa: BLE001 - the run itself is complete and kept
                click.echo(f"rackstress: error: the run finished, but rendering its pictures "
                           f"failed: {err} (retry with 'rackstress render {out}')", err=True)
                sys.exit(EXIT_RENDER)
            click.echo(f"  pictures: {rep.outdir} ({len(rep.files)} files, "
                       f"{time.perf_counter() - t0:.1f} s)")


@main.command()
@click.argument("scene")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True)
@click.option("--mode", type=click.Choice(["exact", "fast"]), default="exact", show_default=True)
@click.option("--steps", type=click.IntRange(min=0))
@click.option("--dt", type=float)
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE")
@click.option("--dump-every", type=click.IntRange(min=1), default=None)
def deck(scene, out, mode, steps, dt, sets, dump_every):
    """Write the LAMMPS data file and input deck of SCENE into OUT, without running."""
    from .deck import write_deck
    from .run import default_dump_every

    try:
        sc = _load_scene(scene, steps, dt, sets)
        d = write_deck(sc, out, mode, dump_every or default_dump_every(sc))
    except RackstressError as err:
        _fail(err, EXIT_INPUT)
    click.echo(f"wrote {out / 'particles.data'} and {out / 'in.lammps'} "
               f"({sc.n_particles} atoms, {len(d.python_ops)} operator(s) in Python)")


@main.command("scenes")
def list_scenes():
    """List the built-in scenes and their parameters."""
    from . import scenes

    for name in scenes.BUILDERS:
        params = scenes.parameters(name)
        click.echo(f"{name}")
        click.echo("  " + json.dumps(params))


@main.command()
@click.argument("rundir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--frames", metavar="N,N,...",
              help="Iterations to picture (nearest dumped frame is used); default: the paper's "
                   "1320,2600,4720,17480 if the run reaches them, else 4 spread over the run.")
@click.option("--measure", type=click.Choice(["paper", "accumulated", "strain", "d2min",
                                              "virial"]),
              default="paper", show_default=True,
              help="paper: distance from desired position (Sec. 5.2); accumulated: its time "
                   "integral; strain: von Mises shear strain; d2min: non-affine D2min; "
                   "virial: LAMMPS per-atom stress (if the dump has it).")
@click.option("--views", default="right,front,left", show_default=True,
              help="Comma-separated: right, front, left, back, top, iso.")
@click.option("--movie", is_flag=True, help="Also write figures/movie.mp4 (first view).")
@click.option("--vmax", type=float, help="Top of the colour scale (default: 99th percentile).")
@click.option("--allow-truncated", is_flag=True,
              help="Render the complete frames of a dump that ends mid-frame.")
def render(rundir, frames, measure, views, movie, vmax, allow_truncated):
    """Render the stress pictures, sheet, plots (and movie) of RUNDIR into RUNDIR/figures/."""
    from .render import render as render_run

    t0 = time.perf_counter()
    try:
        its = None
        if frames:
            try:
                its = [int(f) for f in frames.split(",") if f.strip()]
            except ValueError:
                raise RackstressError(f"--frames expects comma-separated integers, got '{frames}'")
        rep = render_run(rundir, frames=its, measure=measure,
                         views=[v.strip() for v in views.split(",") if v.strip()], movie=movie,
                         vmax=vmax, allow_truncated=allow_truncated)
    except RackstressError as err:
        _fail(err, EXIT_INPUT)
    for note in rep.notes:
        click.echo(f"note: {note}")
    click.echo("frames: " + ", ".join(f"{s}" for _, _, s in rep.frames)
               + f"; colour scale 0..{rep.vmax:.4g}")
    for name in rep.files:
        click.echo(f"  wrote {rep.outdir / name}")
    click.echo(f"rendered in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":  # pragma: no cover
    main()
