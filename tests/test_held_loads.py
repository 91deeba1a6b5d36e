"""A load on particles a support holds goes straight into the support (the engines zero a
held direction's force): a load wholly on held particles is refused (exit 2), one partly on
them warns with the share (scenes/physical.py). Real processes."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

RS = str(Path(sys.executable).parent / "rackstress")

# a steel bar 10 × 3 × 3 mm at spacing 1: 10 layers of 3 × 3 particles at x = 0.5 … 9.5; the
# support holds the layers x = 0.5 and 1.5 (18 particles)
SCENE = """name = "held"
units = "mm-N-s"
analysis = "static"

[params]
x0 = 9.5
x1 = 11

[[group]]
name = "bar"
fill = { box = { min = [0, 0, 0], max = [10, 3, 3] } }
spacing = 1.0
material = "steel"

[[support]]
on = "bar"
where = { box = { min = [-1, -1, -1], max = [1.8, 4, 4] } }

[[load]]
on = "bar"
where = { box = { min = ["$x0", -1, -1], max = ["$x1", 4, 4] } }
force = [0, -10, 0]
"""


def run(tmp_path: Path, out: str, *sets):
    scene = tmp_path / "held.toml"
    scene.write_text(SCENE)
    args = [a for s in sets for a in ("--set", s)]
    return subprocess.run([RS, "run", scene, *args, "--engine", "reference", "--out",
                           tmp_path / out, "--no-render", "--no-progress"],
                          capture_output=True, text=True, timeout=900)


def test_a_load_on_held_particles_is_refused_or_its_share_named(tmp_path):
    # wholly inside the support: it would settle in 0 iterations at 0 MPa, silently
    r = run(tmp_path, "all", "x0=-1", "x1=1.2")
    assert r.returncode == 2, r.stderr
    assert "[[load]] #1 (on 'bar')" in r.stderr and "[[support]] #1" in r.stderr
    assert "every one of its 9 particle(s) is held" in r.stderr
    assert not (tmp_path / "all").exists()
    # over the whole bar: 18 of its 90 particles held, so 18/90 = 20 % of the 10 N
    r = run(tmp_path, "part", "x0=-1", "x1=11")
    assert r.returncode == 0, r.stderr
    assert "18 of its 90 particles are held by [[support]] #1: 20% of its force" in r.stderr
    assert "(2 of 10 in the scene's force unit)" in r.stderr
    s = json.loads((tmp_path / "part" / "summary.json").read_text())
    (w,) = [w for w in s["warnings"] if w["kind"] == "load_on_support"]
    assert w["share"] == 0.2 and w["groups"] == ["bar"]


def test_a_load_through_a_pinned_hole_is_named_with_its_share(tmp_path):
    """A pinned hole's ring is one rigid body turning about its axis: a load on the ring
    reaches the part only through its moment about the axis. 100 N in −y over the whole ring
    of H1 has almost none (its particles' levers about the bore's axis nearly cancel; the
    lattice's ring is not exactly round): nearly all of it goes into the pin, which the run
    now says, naming the support and the share (was: silent, the check ignored pins)."""
    import re

    sys.path.insert(0, str(Path(__file__).parent))
    from test_named_supports import bar_scene

    toml = bar_scene(tmp_path, "pinned")
    text = toml.read_text()
    loaded = text.replace("where = { box = { min = [48.9, -1, -1], max = [51.1, 11, 7] } }",
                          'where = { hole = "H1" }')
    assert loaded != text
    toml.write_text(loaded)
    r = subprocess.run([RS, "run", toml, "--engine", "reference", "--out", tmp_path / "r",
                        "--no-render", "--no-progress"], capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stderr
    said = re.search(r"\[\[load\]\] #1 \(on 'bar'\): (\d+) of its (\d+) particles are held by "
                     r"\[\[support\]\] #1: (\d+)% of its force", r.stderr)
    assert said and said.group(1) == said.group(2), r.stderr
    assert int(said.group(3)) >= 90
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    (w,) = [w for w in s["warnings"] if w["kind"] == "load_on_support"]
    assert w["share"] >= 0.9
