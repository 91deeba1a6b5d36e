"""``rackstress bench offsets``: every real part of ``examples/parts/`` at its default spacing on
N lattices moved within a spacing, against the FE check's converged reading.

Each part is run as a user runs it, ``rackstress run SCENE --offsets N`` (docs/stress.md
"Lattice offsets"): its scene's own lattice, then N − 1 lattices moved by R₃'s fractions of
the spacing, each governing stress read at the first run's zone and singular points. The FE
reference is the one ``rackstress bench parts --refine`` converged for the same part
(``docs/benchmarks/parts.json``'s ``fe_reference_mpa``: the FE check's local refinement about
its own governing point, or its governing stress; ``fe_converged`` says whether it moved less
than 5 % between its two meshes). One row a part: the first lattice's reading and every
other's over the FE's, their median's and range's, whether the range holds the FE's value,
and whether the first run's own band (``summary.json``'s ``stress.error``, what a default run
says) holds every lattice's reading. What it measures: how much of a default run's distance
from the FE is where its lattice happened to fall, and whether the band it prints says so.

Writes ``docs/benchmarks/offsets.json`` and ``offsets.md``.
"""
from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from rackstress.bench import fmt, machine, md_table, out_dir, repository_file, write_json
from rackstress.bench.parts import TIMEOUT_S, _error_of, _rackstress, _timed, part_names
from rackstress.stress.refine import finished_summary

#: lattices per part, the scene's own included
N = 6
#: within this of the FE's reading: the governing stress's target at the default spacing
TARGET = 0.10


def reference() -> dict:
    """``{part: row}`` of ``bench parts``' last page (docs/benchmarks/parts.json)."""
    data = json.loads(repository_file("docs", "benchmarks", "parts.json").read_text())
    return {r["part"]: r for r in data["rows"]}


def case(name: str, work: Path, ref: dict, n: int = N, echo=print,
         timeout: float = TIMEOUT_S) -> dict:
    """One part: ``rackstress run SCENE --offsets n`` into ``work/name``; its row."""
    scene = repository_file("examples", "parts", name, "scene.toml")
    out = work / name
    t0 = time.perf_counter()
    code, err, usage = _timed([*_rackstress(), "run", str(scene), "--offsets", str(n),
                               "--out", str(out), "--no-render", "--no-progress"],
                              timeout * n)
    row = {"part": name, "wall_s": time.perf_counter() - t0,
           "cpu_s": usage.ru_utime + usage.ru_stime, "exit": code}
    r = ref.get(name) or {}
    fe = r.get("fe_reference_mpa")
    row.update(fe_mpa=fe, fe_converged=r.get("fe_converged"), spacing=r.get("spacing"))
    if code != 0:
        row["status"] = "stopped" if code is None else f"exit {code}: {_error_of(err)}"
        echo(f"bench offsets: {name}: {row['status']}")
        return row
    st = json.loads((out / "summary.json").read_text())["stress"]
    off, band = st["offsets"], st.get("error") or {}
    values = [x["value"] for x in off["rows"]]
    row.update(status="ok", values=values, offsets=[x["offset"] for x in off["rows"]],
               states=["refused" if "refused" in x else "read" if x["value"] is not None
                       else "unread" if x["settled"] else "unsettled" for x in off["rows"]],
               particles=[x["particles"] for x in off["rows"]], unsettled=off["unsettled"],
               median=off["median"], low=off["low"], high=off["high"], spread=off["spread"],
               band_low=band.get("low"), band_high=band.get("high"))
    # what a user would have read on each lattice alone: its own governing stress (its own
    # singular points and zone) and the band its run printed
    own = []
    for x in off["rows"]:
        s = (finished_summary(out / x["dir"]) if x["settled"] and "refused" not in x
             else None)
        g = ((s or {}).get("stress") or {}).get("governing")
        e = ((s or {}).get("stress") or {}).get("error") or {}
        own.append(None if g is None else {"value": g["value"], "low": e.get("low"),
                                           "high": e.get("high"), "read": g.get("read")})
    row["own"] = own
    got = [v for v in values if v is not None]
    row["band_holds_all"] = bool(band.get("low") is not None
                                 and band["low"] <= min(got) and max(got) <= band["high"])
    if fe:
        ratios = [v / fe if v is not None else None for v in values]
        row.update(ratios=ratios, first_over_fe=ratios[0], median_over_fe=off["median"] / fe,
                   low_over_fe=off["low"] / fe, high_over_fe=off["high"] / fe,
                   range_holds_fe=bool(off["low"] <= fe <= off["high"]),
                   within=sum(abs(x - 1) < TARGET for x in ratios if x is not None),
                   read=sum(x is not None for x in ratios),
                   own_bands=sum(o is not None and o["low"] is not None for o in own),
                   own_bands_hold_fe=sum(o is not None and o["low"] is not None
                                         and o["low"] <= fe <= o["high"] for o in own))
    echo(f"bench offsets: {name}: {' '.join(fmt(v, 4) for v in got)} MPa, FE {fmt(fe, 4)} "
         f"({row['wall_s']:.0f} s)")
    return row


def run_bench(out=None, n: int = N, only=None, echo=print, timeout: float = TIMEOUT_S) -> dict:
    """Every part (module doc); returns the data written to ``offsets.json``."""
    t0 = time.perf_counter()
    start = machine()
    out = out_dir(out)
    ref = reference()
    with tempfile.TemporaryDirectory(prefix="rs-offsets-") as tmp:
        rows = [case(name, Path(tmp), ref, n=n, echo=echo, timeout=timeout)
                for name in part_names(only)]
    try:
        load_end = os.getloadavg()
    except OSError:  # pragma: no cover
        load_end = None
    conv = [r for r in rows if r.get("fe_converged") and r.get("ratios")]
    data = {"machine": {**start, "load_avg_at_end": load_end}, "n": int(n),
            "only": list(only or []), "rows": rows, "target": TARGET,
            "converged": len(conv),
            "first_within": sum(abs(r["first_over_fe"] - 1) < TARGET for r in conv),
            "median_within": sum(abs(r["median_over_fe"] - 1) < TARGET for r in conv),
            "readings_within": sum(r["within"] for r in conv),
            "readings": sum(r["read"] for r in conv),
            "range_holds_fe": sum(r["range_holds_fe"] for r in conv),
            "own_bands": sum(r["own_bands"] for r in conv),
            "own_bands_hold_fe": sum(r["own_bands_hold_fe"] for r in conv),
            "band_holds_all": sum(bool(r.get("band_holds_all")) for r in rows
                                  if r.get("status") == "ok"),
            "ok": sum(r.get("status") == "ok" for r in rows),
            "largest_spread": max((r["spread"] for r in rows if r.get("status") == "ok"),
                                  default=None),
            "median_spread": (float(np.median([r["spread"] for r in rows
                                               if r.get("status") == "ok"]))
                              if any(r.get("status") == "ok" for r in rows) else None)}
    data["files"] = [str(out / "offsets.json"), str(out / "offsets.md")]
    data["wall_s"] = time.perf_counter() - t0
    write_json(out / "offsets.json", data)
    (out / "offsets.md").write_text(markdown(data))
    return data


HEADER = ["part", "spacing [mm]", "FE [MPa]", "FE converged", "first / FE",
          "each lattice / FE", "median / FE", "spread", "range holds FE", "own bands hold FE",
          "first band holds all"]


def table_rows(data) -> list:
    rows = []
    for r in data["rows"]:
        if r.get("status") != "ok":
            rows.append([r["part"], fmt(r.get("spacing")), fmt(r.get("fe_mpa"), 4), "—",
                         "—", r.get("status", "—"), "—", "—", "—", "—", "—"])
            continue
        states = r.get("states") or ["unsettled"] * len(r.get("ratios") or [])
        each = " ".join(fmt(x, 3) if x is not None else st
                        for x, st in zip(r.get("ratios") or [], states))
        rows.append([r["part"], fmt(r.get("spacing")), fmt(r.get("fe_mpa"), 4),
                     {True: "yes", False: "no"}.get(r.get("fe_converged"), "—"),
                     fmt(r.get("first_over_fe"), 3), each, fmt(r.get("median_over_fe"), 3),
                     f"±{100 * r['spread']:.1f} %",
                     {True: "yes", False: "**no**"}.get(r.get("range_holds_fe"), "—"),
                     (f"{r['own_bands_hold_fe']} of {r['own_bands']}" if "own_bands" in r
                      else "—"),
                     "yes" if r.get("band_holds_all") else "**no**"])
    return rows


def markdown(data) -> str:
    m = data["machine"]
    load = m.get("load_avg_at_start")
    lines = [
        "# The governing stress on lattices moved within a spacing", "",
        f"Written by `rackstress bench offsets` (module docstring of `bench/offsets.py`): each "
        f"part of `examples/parts/` at its default spacing, run as `rackstress run SCENE "
        f"--offsets {data['n']}` — its scene's own lattice, then {data['n'] - 1} lattices moved "
        "by R₃'s fractions of the spacing, each read at the first run's zone and singular "
        "points and, where that reads more, at the first run's governing point "
        "(docs/stress.md \"Lattice offsets\") — against the FE check's converged "
        "reading of `rackstress bench parts --refine` ([parts.md](parts.md), "
        "`fe_reference_mpa`). *first / FE*: the scene's own lattice, what a default run "
        "reads; *each lattice / FE*: every lattice's, the first first (*unsettled*: it did not "
        "settle; *refused*: the part check refused the moved lattice; *unread*: every particle "
        "lies within the zone); *spread*: the largest "
        "departure from the median; *range holds FE*: the FE's value lies within the lattices' "
        "range; *own bands hold FE*: on how many lattices the band that lattice's run prints "
        "alone (its own governing stress, singular points and zone) holds the FE's value; "
        "*first band holds all*: the first run's own error band (`summary.json`'s "
        "`stress.error`) holds every lattice's reading.", "",
        md_table(HEADER, table_rows(data)), "",
        f"Of the {data['converged']} parts whose FE reading converged, the scene's own lattice "
        f"reads within {100 * data['target']:.0f} % of it on {data['first_within']}; of all "
        f"their lattices' readings, {data['readings_within']} of {data['readings']} are "
        f"within {100 * data['target']:.0f} %; the median of a part's lattices on "
        f"{data['median_within']}; the lattices' range holds the FE's value on "
        f"{data['range_holds_fe']}. Run on one lattice alone (its own singular points and "
        f"zone), the band a run prints holds the FE's value on {data['own_bands_hold_fe']} of "
        f"those {data['own_bands']} runs. Where the lattice falls moves a part's governing "
        "stress by "
        f"up to ±{100 * data['largest_spread']:.1f} % (median part ±"
        f"{100 * data['median_spread']:.1f} %); the first run's own band holds every "
        f"lattice's reading on {data['band_holds_all']} of {data['ok']} parts.", "",
        f"Machine: {m.get('cores', '?')} cores, load average {fmt(load[0]) if load else '?'} "
        f"at the start, {fmt((m.get('load_avg_at_end') or [None])[0])} at the end; "
        f"{data['wall_s']:.0f} s wall.", ""]
    return "\n".join(lines)
