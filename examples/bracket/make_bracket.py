"""Write ``bracket.stl``: a shelf L-bracket, the concept design of this example.

A wall leg (x 0..3, y 0..30, z 0..16) with two bolt holes of radius 2 through it along x, at
(y, z) = (6, 8) and (16, 8), and an arm (x 0..30, y 27..30, z 0..16) along the top. Built by
constructive solid geometry with manifold3d (a maintained CSG library, so the mesh is closed and
free of self-intersections by construction) and written as binary STL with trimesh.

Its volume by hand: leg 3·30·16 = 1440, arm 27·3·16 = 1296, minus two holes, each a regular
32-gon prism of circumradius 2 and length 3: 2 · 3 · (32/2 · 2² · sin(2π/32)) = 74.91; in all
2661.09. The script checks the mesh against that number.

    pip install manifold3d      # (in the '[examples]' and '[test]' extras)
    python examples/bracket/make_bracket.py            # writes examples/bracket/bracket.stl
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

#: Dimensions (scene units: think millimetres) and the hole's polygon.
LEG = (3.0, 30.0, 16.0)
ARM = (30.0, 3.0, 16.0)
HOLES = ((6.0, 8.0), (16.0, 8.0))     # (y, z) of each hole's axis (along x)
HOLE_RADIUS = 2.0
SEGMENTS = 32


def expected_volume() -> float:
    """The bracket's volume by hand (module docstring)."""
    hole = SEGMENTS / 2 * HOLE_RADIUS ** 2 * math.sin(2 * math.pi / SEGMENTS)
    arm_beyond_leg = (ARM[0] - LEG[0]) * ARM[1] * ARM[2]
    return LEG[0] * LEG[1] * LEG[2] + arm_beyond_leg - len(HOLES) * LEG[0] * hole


def bracket():
    """The bracket as a manifold3d solid."""
    from manifold3d import Manifold

    leg = Manifold.cube(LEG)
    arm = Manifold.cube(ARM).translate((0.0, LEG[1] - ARM[1], 0.0))
    solid = leg + arm
    for y, z in HOLES:
        # a cylinder along z, turned to run along x, longer than the leg is thick
        hole = Manifold.cylinder(LEG[0] + 2.0, HOLE_RADIUS, HOLE_RADIUS, SEGMENTS)
        hole = hole.rotate((0.0, 90.0, 0.0)).translate((-1.0, y, z))
        solid = solid - hole
    return solid


def write(path: Path) -> float:
    """Write the STL; return its volume (checked against :func:`expected_volume`)."""
    import trimesh

    mesh = bracket().to_mesh()
    tm = trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts))
    assert tm.is_watertight and tm.is_winding_consistent
    volume = float(tm.volume)
    if not math.isclose(volume, expected_volume(), rel_tol=1e-9):
        raise SystemExit(f"bracket volume {volume} differs from the hand value "
                         f"{expected_volume()}")
    tm.export(path)
    return volume


if __name__ == "__main__":
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("bracket.stl")
    v = write(out)
    print(f"wrote {out}: volume {v:.4f} (by hand {expected_volume():.4f})")
