"""Parts from meshes: particle counts against volumes, and the time to turn a mesh into ~100,000
particles (read + checks + fill), on this machine. Prints a table and saves it to
docs/benchmarks/mesh-fill.md, its figures to docs/benchmarks/mesh-fill.json (the page is
:func:`markdown` of them).

    python scripts/bench_mesh_fill.py [--repeat 3]

The meshes are built here by CSG (manifold3d) with volumes known by hand: an L-shape (union of
a 40×10×20 and a 10×40×20 box, 14,000), a 30×2×20 plate with a 48-gon hole of circumradius 5,
and the example bracket (examples/bracket/make_bracket.py). Each is filled cubic and hcp; the
expected count is volume/spacing³ (cubic) or √2·volume/spacing³ (hcp). Times are the best of
three, each from a fresh read of the file (the per-file cache is cleared).
"""
from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples" / "bracket"))


def solids(tmp: Path) -> dict:
    import trimesh
    from manifold3d import Manifold

    import make_bracket

    def save(solid, name):
        m = solid.to_mesh()
        path = tmp / name
        trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts)).export(path)
        return path

    n = 48
    hole = Manifold.cylinder(4.0, 5.0, 5.0, n).rotate((-90.0, 0.0, 0.0)).translate((15.0, -1.0, 10.0))
    plate_v = 2.0 * (600.0 - n / 2 * 25.0 * math.sin(2 * math.pi / n))
    return {
        "L-shape": (save(Manifold.cube((40.0, 10.0, 20.0)) + Manifold.cube((10.0, 40.0, 20.0)),
                         "L.stl"), 14000.0),
        "plate with hole": (save(Manifold.cube((30.0, 2.0, 20.0)) - hole, "plate.stl"), plate_v),
        "bracket": (REPO / "examples" / "bracket" / "bracket.stl", make_bracket.expected_volume()),
    }


def timed(fn, repeat=3):
    from rackstress.scenes import mesh

    best, out = math.inf, None
    for _ in range(repeat):
        mesh._checked.cache_clear()
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def measure(repeat: int = 3) -> dict:
    """Every row the page prints, as written to mesh-fill.json."""
    import os
    import platform

    from rackstress.model.particles import fill
    from rackstress.scenes.mesh import read_surface

    load = list(os.getloadavg())
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for name, (path, volume) in solids(Path(d)).items():
            for spacing in (1.0, 0.5, 0.25):
                for packing in ("cubic", "hcp"):
                    t_read, surf = timed(lambda: read_surface(path), repeat)
                    t_all, o = timed(lambda: fill(read_surface(path), spacing, packing), repeat)
                    expected = volume / spacing ** 3 * (1 if packing == "cubic" else math.sqrt(2))
                    rows.append({"part": name, "spacing": spacing, "packing": packing,
                                 "volume": volume, "particles": len(o), "expected": expected,
                                 "deviation": len(o) / expected - 1, "read_s": t_read,
                                 "read_fill_s": t_all})
    return {"benchmark": "mesh-fill", "repeat": repeat, "target_s": 3.0,
            "machine": {"cores": os.cpu_count(), "python": platform.python_version(),
                        "platform": platform.platform(), "load_avg_at_start": load},
            "rows": rows}


def markdown(data: dict) -> str:
    """The page, from :func:`measure`'s data (mesh-fill.json)."""
    rows = data["rows"]
    lines = ["| part | spacing | packing | volume | particles | expected | deviation | read + checks (s) | read + checks + fill (s) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['part']} | {r['spacing']:g} | {r['packing']} | {r['volume']:.2f} | "
                     f"{r['particles']:,} | {r['expected']:,.0f} | {100 * r['deviation']:+.2f} % "
                     f"| {r['read_s']:.3f} | {r['read_fill_s']:.3f} |")
    near = min((r for r in rows if r["particles"] >= 100_000), key=lambda r: r["particles"])
    m = data["machine"]
    head = (f"Measured with `python scripts/bench_mesh_fill.py` (best of {data['repeat']}, this "
            f"{m['cores']}-core machine shared with other work, load average "
            f"{m['load_avg_at_start'][0]:.1f} at the start; the figures are in "
            f"`mesh-fill.json`). ~100,000 particles from a mesh: {near['particles']:,} particles "
            f"({near['part']}, spacing {near['spacing']:g}, {near['packing']}) in "
            f"{near['read_fill_s']:.2f} s, reading and checking the STL included (target ≤ "
            f"{data['target_s']:g} s: {'met' if near['read_fill_s'] <= data['target_s'] else '**not met**'}).")
    return "# Parts from meshes: counts and times\n\n" + head + "\n\n" + "\n".join(lines) + "\n"


def main() -> None:
    import argparse
    import json

    ap = argparse.ArgumentParser(description="Parts from meshes: particle counts against "
                                 "volumes, and the time to fill ~100,000 particles; writes "
                                 "docs/benchmarks/mesh-fill.md and .json.")
    ap.add_argument("--repeat", type=int, default=3, help="timings: the best of this many")
    args = ap.parse_args()
    data = measure(args.repeat)
    text = markdown(data)
    print(text)
    out = REPO / "docs" / "benchmarks" / "mesh-fill.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(data, indent=1) + "\n")
    out.write_text(text)
    print(f"saved {out} and {out.with_suffix('.json').name}")


if __name__ == "__main__":
    main()
