"""Parts from meshes: particle counts against volumes, and the time to turn a mesh into ~100,000
particles (read + checks + fill), on this machine. Prints a table and saves it to
docs/benchmarks/mesh-fill.md.

    python scripts/bench_mesh_fill.py

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


def main() -> None:
    from rackstress.model.particles import fill
    from rackstress.scenes.mesh import read_surface

    rows = []
    with tempfile.TemporaryDirectory() as d:
        for name, (path, volume) in solids(Path(d)).items():
            for spacing in (1.0, 0.5, 0.25):
                for packing in ("cubic", "hcp"):
                    t_read, surf = timed(lambda: read_surface(path))
                    t_all, o = timed(lambda: fill(read_surface(path), spacing, packing))
                    expected = volume / spacing ** 3 * (1 if packing == "cubic" else math.sqrt(2))
                    rows.append((name, spacing, packing, volume, len(o), expected,
                                 len(o) / expected - 1, t_read, t_all))
    lines = ["| part | spacing | packing | volume | particles | expected | deviation | read + checks (s) | read + checks + fill (s) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r[0]} | {r[1]:g} | {r[2]} | {r[3]:.2f} | {r[4]:,} | {r[5]:,.0f} | "
                     f"{100 * r[6]:+.2f} % | {r[7]:.3f} | {r[8]:.3f} |")
    near = min((r for r in rows if r[4] >= 100_000), key=lambda r: r[4])
    head = (f"Measured with `python scripts/bench_mesh_fill.py` (best of 3, this 2-core machine "
            f"shared with other work). ~100,000 particles from a mesh: {near[4]:,} particles "
            f"({near[0]}, spacing {near[1]:g}, {near[2]}) in {near[8]:.2f} s, reading and "
            "checking the STL included (target ≤ 3 s).")
    text = "# Parts from meshes: counts and times\n\n" + head + "\n\n" + "\n".join(lines) + "\n"
    print(text)
    out = REPO / "docs" / "benchmarks" / "mesh-fill.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(f"saved {out}")


if __name__ == "__main__":
    main()
