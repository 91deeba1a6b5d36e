"""``rackstress run --offsets N``: the same scene on N lattices moved within a spacing, and how
far the governing stress moves with where the lattice falls.

A part is filled on a cubic lattice centred in its bounding box (docs/scenes.md). Where that
lattice's layers fall inside a wall decides how many particles stand across it and how far the
outer ones lie from its faces, so at one spacing the governing stress depends on a choice the
part knows nothing about. After a run at its lattice (``RUN``), :func:`offsets` fills the
scene again N − 1 times, every filled part's lattice moved by :func:`lattice_offsets`'s
fractions of its spacing (the same spacing: nothing else changes), into ``RUN/offsets/K``
(each a run directory of its own, locked, resumable, overwritten only by this step), reads each
governing stress **at the first run's zone and singular points** (the same quantity at every
offset, as ``--refine`` reads its finer run: its field at the first run's governing point
where that is the larger, :func:`rackstress.stress.governing.with_first_point`), and writes
into ``RUN/summary.json["stress"]["offsets"]`` the readings, their median and range and the
largest departure from the median: a measured spread of the reading at this spacing, not an
assumed one. ``RUN`` is complete before the first offset starts; an offset that does not
settle, or whose moved lattice the part check refuses (a load on a wall it fills one particle
thick), is kept, named and left out of the spread.

Example
-------
>>> offsets("runs/bracket", "examples/bracket/static.toml", 4)["spread"]   # doctest: +SKIP
0.071
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rackstress.errors import RackstressError, SceneError
from rackstress.stress.governing import record, with_first_point
from rackstress.stress.refine import finished_summary, first_run

#: the offsets' run directories inside the run: ``RUN/offsets/1`` …
OFFSETS_DIR = "offsets"
#: the most lattices ``--offsets`` fills (the first run's included)
MOST = 16
#: φ₃, the root of x⁴ = x + 1 above 1: Roberts' R₃ sequence k·(1/φ₃, 1/φ₃², 1/φ₃³) mod 1
#: spreads any number of points evenly over the unit cube, each new one far from the others
PHI3 = 1.2207440846057596


class OffsetsError(RackstressError):
    """The offsets cannot be read (no governing stress, a first run that did not settle):
    exit 2."""


def lattice_offsets(n: int) -> np.ndarray:
    """n × 3 fractions of a spacing by which the lattice is moved: k·(1/φ₃, 1/φ₃², 1/φ₃³)
    mod 1 for k = 0 … n − 1 (the first is the scene's own lattice).

    >>> lattice_offsets(3).round(4).tolist()
    [[0.0, 0.0, 0.0], [0.8192, 0.671, 0.5497], [0.6383, 0.3421, 0.0994]]
    """
    k = np.arange(int(n), dtype=float)[:, None]
    return np.mod(k * PHI3 ** -np.arange(1.0, 4.0)[None, :], 1.0)


def spread(values) -> dict:
    """The readings' median, range and largest departure from the median (a fraction of it).

    >>> s = spread([9.0, 10.0, 12.0])
    >>> s["median"], s["low"], s["high"], round(s["spread"], 12)
    (10.0, 9.0, 12.0, 0.2)
    """
    v = np.asarray([x for x in values if x is not None], float)
    med = float(np.median(v))
    return {"median": med, "low": float(v.min()), "high": float(v.max()),
            "spread": float(np.abs(v / med - 1.0).max()) if med > 0 else float("inf")}


def offsets(rundir, spec: str, n: int, overrides: dict | None = None, engine: str = "lammps",
            mode: str = "exact", progress: bool = False, echo=print) -> dict:
    """Run ``spec`` on ``n`` − 1 moved lattices into ``RUNDIR/offsets/K`` and write the spread.

    Parameters
    ----------
    rundir : path
        A finished, settled run of ``spec`` with a governing stress.
    spec : str
        The scene file the run was made from; ``overrides`` its ``--set`` values.
    n : int
        Lattices in all, the first run's included (2 … :data:`MOST`).

    Returns
    -------
    dict
        What is written into ``summary.json["stress"]["offsets"]``.

    Raises
    ------
    OffsetsError
        The run has no governing stress or did not settle.
    """
    from rackstress.lib.jsonio import write_json
    from rackstress.runs.run import run as run_scene
    from rackstress.scenes import load
    from rackstress.stress.post import compute_fields, postprocess
    from rackstress.stress.rundata import load_run

    rundir = Path(rundir)
    summary, gov, sing, scale, z = first_run(
        rundir, OffsetsError, "move the lattice of", "so there is no reading to compare at "
        "other lattice offsets", "to read at other lattice offsets")
    shifts = lattice_offsets(n)
    rows = [{"offset": [0.0, 0.0, 0.0], "dir": ".", "settled": True, "value": gov["value"],
             "position": gov.get("position"), "particles": int(summary.get("n_particles", 0))}]
    for k in range(1, int(n)):
        shift = [float(x) for x in shifts[k]]
        d = rundir / OFFSETS_DIR / str(k)
        row = {"offset": shift, "dir": f"{OFFSETS_DIR}/{k}", "settled": False, "value": None,
               "position": None, "particles": 0}
        try:
            sc = load(spec, overrides, spacing_scale=scale, lattice_shift=shift)
            done = finished_summary(d)
            if not (done is not None and done.get("n_particles") == sc.n_particles
                    and (done.get("params") or {}).get("lattice_shift") == shift):
                echo(f"offsets: {sc.name} on its lattice moved by ({shift[0]:.3f}, "
                     f"{shift[1]:.3f}, {shift[2]:.3f}) spacings ({sc.n_particles:,} particles) "
                     f"into {d} ({k} of {int(n) - 1})")
                d.parent.mkdir(exist_ok=True)
                run_scene(sc, d, engine=engine, mode=mode, progress=progress, overwrite=True)
                done = finished_summary(d)
                if done.get("settled") is not False:
                    postprocess(d, vtk=False, dump=False)
        except SceneError as exc:
            # the moved lattice itself is refused (a load on a wall it fills one particle
            # thick, a region it leaves empty): a property of that lattice, said and kept
            row["refused"] = str(exc)
            echo(f"offsets: the lattice moved by ({shift[0]:.3f}, {shift[1]:.3f}, "
                 f"{shift[2]:.3f}) is refused, left out of the spread: {exc}")
            rows.append(row)
            continue
        row.update(settled=done.get("settled") is not False,
                   particles=int(done.get("n_particles", 0)))
        if row["settled"]:
            run = load_run(d)
            fields = compute_fields(run)
            rec = record(run, fields, zone_override=z, singular=sing)
            g = with_first_point(run, fields, (rec.get("parts") or {}).get(gov["group"], {})
                                 .get("governing"), gov)
            if g is not None:
                row.update(value=float(g["value"]), position=g.get("position"),
                           read=g.get("read"))
            else:
                row["unread"] = (f"every particle of '{gov['group']}' lies within the zone "
                                 f"({z:.3g}) of a singular point")
        else:
            echo(f"offsets: {d} did not settle (residual {done.get('residual'):.3g} of the "
                 "load): left out of the spread")
        rows.append(row)
    read = [r["value"] for r in rows if r["value"] is not None]
    out = {"n": int(n), "group": gov["group"], "units": gov.get("units"), "zone": z,
           "spacing": gov.get("spacing"), "dir": OFFSETS_DIR, "rows": rows,
           "values": read, "unsettled": sum(not r["settled"] and "refused" not in r
                                            for r in rows),
           "refused": sum("refused" in r for r in rows), **spread(read)}
    summary = finished_summary(rundir)    # as it is now (post-processing may have added to it)
    band = (summary.get("stress") or {}).get("error") or {}
    if band.get("low") is not None and band.get("high") is not None and read:
        # does the error band the run prints (--refine's, else the single run's) hold every
        # lattice's reading? where it does not, it is narrower than the lattice's own scatter
        out["band"] = [band["low"], band["high"]]
        out["band_holds"] = bool(band["low"] <= out["low"] and out["high"] <= band["high"])
    summary.setdefault("stress", {})["offsets"] = out
    write_json(rundir / "summary.json", summary)
    return out


def offsets_sentence(off: dict, digits: int = 4) -> str:
    """One line for the terminal and the report.

    >>> offsets_sentence({"n": 3, "values": [9.0, 10.0, 12.0], "median": 10.0, "low": 9.0,
    ...                   "high": 12.0, "spread": 0.2, "units": "MPa", "unsettled": 0})
    'at 3 lattice offsets within a spacing the governing stress reads 9 … 12 MPa (median 10): \
where the lattice falls moves it by up to 20 % (docs/stress.md "Lattice offsets")'
    """
    u = off.get("units") or ""
    f = (lambda x: f"{x:.{digits}g}")
    s = (f"at {off['n']} lattice offsets within a spacing the governing stress reads "
         f"{f(off['low'])} … {f(off['high'])} {u} (median {f(off['median'])}): where the "
         f"lattice falls moves it by up to {100 * off['spread']:.0f} % (docs/stress.md "
         "\"Lattice offsets\")")
    if off.get("unsettled"):
        s += f"; {off['unsettled']} offset(s) did not settle and are left out"
    if off.get("refused"):
        s += (f"; {off['refused']} moved lattice(s) could not hold the part (the part check "
              "refused them) and are left out")
    if off.get("band_holds") is True:
        s += "; the error band holds every one"
    elif off.get("band_holds") is False:
        s += (f"; the error band, {f(off['band'][0])} … {f(off['band'][1])} {u}, does not hold "
              "them all: it is narrower than where the lattice falls moves the reading")
    return s
