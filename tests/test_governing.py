"""The governing stress: singular points found from the geometry, the headline read away from
them, and the error bar. Expected values from geometry (where an L's re-entrant edge is, which
particles border a support), hand calculation (Richardson on a sequence with a known limit)
and the continuum's behaviour at a sharp re-entrant edge (its peak grows as the spacing
shrinks; the stress a fixed distance away does not)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rackstress.model import singular as S
from rackstress.model.regions import Box, Cylinder, Difference, Union
from rackstress.stress.governing import (error_bar, governing, observed_order, richardson,
                                         zone)

# an L of two 2 × 10 arms, 2 deep: its one re-entrant edge is the line x = y = 2
L_SHAPE = Union([Box([0, 0, 0], [10, 2, 2]), Box([0, 0, 0], [2, 10, 2])])


def _filleted(r: float):
    """The L with its inner corner rounded by a fillet of radius r (a corner block minus a
    cylinder, CSG)."""
    corner = Difference([Box([2, 2, 0], [2 + r, 2 + r, 2]),
                         Cylinder([2 + r, 2 + r, -1], [2 + r, 2 + r, 3], r)])
    return Union([L_SHAPE, corner])


def test_sharp_L_has_its_reentrant_edge_and_nothing_else():
    s = S.find(np.zeros((0, 3)), 0.5, L_SHAPE)
    assert len(s) and set(s.kinds()) == {"re-entrant edge"}
    # every point on the line x = y = 2, from z = 0 to 2 (geometry), 90° turning
    np.testing.assert_allclose(s.points[:, :2], 2.0, atol=1e-9)
    assert s.points[:, 2].min() == pytest.approx(0.0) and s.points[:, 2].max() == pytest.approx(2)
    np.testing.assert_allclose(s.angle, 90.0, atol=1e-6)


def test_the_same_L_as_a_mesh_file_gives_the_same_edge():
    import trimesh

    a = trimesh.creation.box([10, 2, 2])
    a.apply_translation([5, 1, 1])
    b = trimesh.creation.box([2, 10, 2])
    b.apply_translation([1, 5, 1])
    m = trimesh.boolean.union([a, b], engine="manifold")
    seg, turn, _ = S.sharp_edges(m.vertices, m.faces, 0.5)
    mid = seg.mean(axis=1)
    np.testing.assert_allclose(mid[:, :2], 2.0, atol=1e-9)
    assert turn == pytest.approx(np.full(len(turn), 90.0))


def test_a_fillet_of_a_spacing_and_more_is_not_singular_a_smaller_one_is():
    # a fillet of radius r turns WINDOW·a/r radians within the window: singular below
    # r = 0.5 a / 20° = 1.43 a (hand calculation)
    assert len(S.find(np.zeros((0, 3)), 1.0, _filleted(2.0))) == 0
    assert len(S.find(np.zeros((0, 3)), 1.0, _filleted(3.0))) == 0
    small = S.find(np.zeros((0, 3)), 1.0, _filleted(0.5))
    # its facets (the CSG cylinder's 72 segments: 5° each) each turn less than 20°, the
    # window as a whole more: a fillet this spacing does not resolve, not a sharp edge
    assert len(small) and set(small.kinds()) == {"unresolved fillet"}
    # the sharp L's edge turns 90° at one edge of its surface: a re-entrant edge
    assert set(S.find(np.zeros((0, 3)), 1.0, L_SHAPE).kinds()) == {"re-entrant edge"}
    # the fillet of radius 0.5 at (2.5, 2.5): its edges lie on that arc
    r = np.hypot(small.points[:, 0] - 2.5, small.points[:, 1] - 2.5)
    np.testing.assert_allclose(r, 0.5, rtol=0.02)
    # the same fillet at a spacing 4 × finer is resolved
    assert len(S.find(np.zeros((0, 3)), 0.25, _filleted(0.5))) == 0


def test_support_boundary_is_the_held_layer_next_to_free_particles():
    o = np.array([[x, y, z] for z in range(3) for y in range(3) for x in range(5)], float)
    fixed = np.zeros((len(o), 3), bool)
    fixed[o[:, 0] <= 1] = True                      # two layers held: x = 0 and x = 1
    k = S.support_boundary(o, fixed, 1.0)
    # the x = 1 layer borders x = 2 (free); x = 0 is 2 spacings from any free particle
    assert sorted(k.tolist()) == sorted(np.flatnonzero(o[:, 0] == 1).tolist())
    roller = np.zeros((len(o), 3), bool)
    roller[o[:, 0] == 0, 0] = True                  # a roller (x only) is a mirror, not a clamp
    assert len(S.support_boundary(o, roller, 1.0)) == 0


def test_point_and_line_loads_are_singular_a_face_patch_is_not():
    o = np.array([[x, y, z] for z in range(6) for y in range(6) for x in range(6)], float)
    F = np.zeros((len(o), 3))
    F[(o[:, 0] == 5) & (o[:, 1] == 2) & (o[:, 2] == 2)] = [0, 0, -1]     # one particle
    assert len(S.point_loads(o, F, 1.0)) == 1
    F[:] = 0
    F[(o[:, 0] == 5) & (o[:, 2] == 5)] = [0, 0, -1]                     # a line of 6
    assert len(S.point_loads(o, F, 1.0)) == 6
    F[:] = 0
    F[(o[:, 2] == 5) & (o[:, 0] >= 2) & (o[:, 1] >= 2)] = [0, 0, -1]    # a 4 × 4 face patch
    assert len(S.point_loads(o, F, 1.0)) == 0


def test_governing_skips_the_zone_and_the_zone_rule():
    s = S.Singular(np.array([[0.0, 0, 0]]), np.array([0]), np.array([90.0]))
    x = np.array([[0.5, 0, 0], [1.9, 0, 0], [2.0, 0, 0], [5.0, 0, 0]])
    assert governing(np.array([50.0, 40.0, 30.0, 20.0]), x, s, 2.0) == (2, 30.0)
    assert governing(np.array([50.0, 40.0]), x[:2], s, 2.0) == (None, None)
    # two spacings, or 0.4 of the wall when that is more
    assert zone(1.0, 3.0) == pytest.approx(2.0) and zone(0.5, 10.0) == pytest.approx(4.0)


def test_richardson_on_a_sequence_with_a_known_limit():
    # G(h) = 100 − 12·h^p: hand calculation at h = 1, 1/√2, 1/2
    for p in (1.0, 2.0):
        h = [1.0, 1 / math.sqrt(2), 0.5]
        g = [100 - 12 * x ** p for x in h]
        assert richardson(g[0], g[1], math.sqrt(2), p) == pytest.approx(100.0, rel=1e-12)
        assert observed_order(*g) == pytest.approx(p, rel=1e-9)
        e = error_bar(g, h)
        assert e["order"] == pytest.approx(p, rel=1e-9)
        assert e["extrapolated"] == pytest.approx(100.0, rel=1e-12)
        assert e["low"] <= 100.0 <= e["high"]
        # the coarsest value's relative error against the limit: −12/100
        assert e["relative"] == pytest.approx(-0.12, rel=1e-9)
    # two values and the assumed order 1: limit 2·g(h/2) − g(h), band 3 × |g(h/2) − limit|
    e = error_bar([88.0, 94.0], [1.0, 0.5], order=1.0)
    assert e["extrapolated"] == pytest.approx(100.0) and e["estimate"] == pytest.approx(18.0)
    # differences of both signs: no order from them, the lattice's is used
    assert observed_order(90.0, 95.0, 93.0) is None


STEP = """
name = "step"
units = "mm-N-s"
analysis = "static"
[params]
spacing = 1.0
[[group]]
name = "bar"
fill = {{ union = [{{ box = {{ min = [0, 0, 0], max = [6, 10, 10] }} }}, {{ box = {{ min = [6, 2, 2], max = [16, 8, 8] }} }}] }}
spacing = "$spacing"
material = "aluminium"
[[support]]
on = "bar"
where = {{ box = {{ min = [-1, -1, -1], max = [0.6, 11, 11] }} }}
[[load]]
on = "bar"
where = {{ box = {{ min = [15.4, -1, -1], max = [17, 11, 11] }} }}
force = [{F}, 0, 0]
"""


def _step_runs(tmp_path, spacings, F=3600.0):
    """A 10 × 10 head with a 6 × 6 shank (a sharp re-entrant ring where they meet), its back
    face held, pulled by F along the shank: F/A = 100 MPa there. Every spacing divides the
    part's dimensions, so the particle nearest the ring sits at (½, ½) spacing from it."""
    from rackstress.runs.run import run
    from rackstress.scenes import load_toml
    from rackstress.stress.post import postprocess

    path = tmp_path / "step.toml"
    path.write_text(STEP.format(F=F))
    out = []
    for s in spacings:
        d = tmp_path / f"s{s:.4f}"
        sc = load_toml(path, {"spacing": s})
        summary = run(sc, d, engine="reference", progress=False)
        assert summary["settled"]
        out.append((d, postprocess(d, vtk=False)))
    return out


@pytest.mark.slow
def test_headline_stays_put_while_the_singular_peak_grows(tmp_path):
    """At 1, 2/3 and 1/2 mm the peak at the sharp ring grows (σ ~ r^−0.46 in the continuum:
    the nearest particle is half a spacing from it) while the governing stress, read 0.4 of the
    6 mm walls (2.4 mm) away from it at every spacing, stays within 5 %. The peak is read by
    patch recovery (a linear fit over a patch that shrinks with the spacing), which keeps the
    h^−0.46 growth of the singular part but not the per-step rate of the nearest particle's
    raw value; so: it grows at every step, and over the two steps by more than twice the 5 %
    band the headline has to stay in."""
    runs = _step_runs(tmp_path, (1.0, 2.0 / 3.0, 0.5))
    gov = [info["governing"] for _, info in runs]
    sing = [info["singular"] for _, info in runs]
    assert [g["zone"] for g in gov] == pytest.approx([2.4] * 3)
    values = [g["value"] for g in gov]
    assert max(values) / min(values) < 1.05
    # uniform tension in the shank: F/A = 100 MPa by hand (the shank's edges read a little high)
    assert all(95.0 < v < 110.0 for v in values)
    # the singular peak, at the ring, grows with every refinement (its singular part by
    # (1.5)^0.46 and (4/3)^0.46 for a right-angled re-entrant edge, on top of the bounded
    # nominal stress), and by more than the headline may move
    assert all(s["kind"] == "re-entrant edge" for s in sing)
    peaks = [s["value"] for s in sing]
    assert peaks[0] < peaks[1] < peaks[2] and peaks[2] > 1.10 * peaks[0]
    # the headline is never within the zone of a singular point
    for (d, _), g in zip(runs, gov):
        from rackstress.stress.governing import read_singular

        pts = read_singular(d)["bar"][2]
        dist, _ = pts.distance(np.array([g["read_at"]]))     # where its stress is read
        assert dist[0] >= g["zone"] - 1e-9


def test_a_governing_stress_at_the_zones_edge_names_the_edge_it_rises_toward(tmp_path):
    """The step's shank bent by a force across it at its end: the moment, and the stress,
    rise toward the sharp ring where the shank meets the head (x = 6, the square y, z ∈
    [2, 8]), so the largest outside the 2.4 mm zone lies at the zone's edge, and the run says
    so: the ring's point nearest it (on the ring, by geometry), its distance (at least the
    zone, less than half a spacing beyond), how much less the particles a spacing farther out
    read (about the 1/7.5 by which the beam's moment F·(16 − x) falls from x = 8.5 to 9.5),
    what to do, in the terminal and in the report. Pulled along the shank (uniform tension),
    the stress there does not rise: nothing is said."""
    from rackstress.render.report import governing_section
    from rackstress.runs.run import run
    from rackstress.scenes import load_toml
    from rackstress.stress.governing import describe
    from rackstress.stress.post import postprocess

    path = tmp_path / "bent.toml"
    path.write_text(STEP.format(F=3600.0).replace("force = [3600.0, 0, 0]", "force = [0, 300, 0]"))
    assert run(load_toml(path, {"spacing": 1.0}), tmp_path / "bent", engine="reference",
               progress=False)["settled"]
    info = postprocess(tmp_path / "bent", vtk=False)
    g = info["governing"]
    ze = g["zone_edge"]
    assert ze["kind"] == "re-entrant edge"
    x, y, z = ze["position"]
    assert x == pytest.approx(6.0, abs=1e-6)
    assert 2 - 1e-6 <= y <= 8 + 1e-6 and 2 - 1e-6 <= z <= 8 + 1e-6
    assert min(abs(y - 2), abs(y - 8), abs(z - 2), abs(z - 8)) < 1e-6    # on the ring
    dist = float(np.linalg.norm(np.array(g["read_at"]) - ze["position"]))
    assert ze["distance"] == pytest.approx(dist)
    assert g["zone"] - 1e-9 <= ze["distance"] <= g["zone"] + 0.5
    assert ze["beyond"] == pytest.approx(ze["distance"] - g["zone"])
    assert ze["fall"] >= 1 / 7.5 - 0.01
    said = "\n".join(describe(g, info["singular"], info.get("error")))
    assert "at the zone's edge" in said and "model the edge's real fillet" in said
    assert 'id="zone-edge"' in governing_section(info)
    (_, pulled), = _step_runs(tmp_path, (1.0,))
    assert pulled["governing"]["zone_edge"] is None
    assert 'id="zone-edge"' not in governing_section(pulled)


# ----------------------------------------------------------------------------- --refine
#: a dog-bone: two 6 × 10 × 10 heads joined by a 12 mm shank 6 × 6 (sharp re-entrant rings at
#: both shoulders), one head's back face held, the far half of the other pulled by F: F/A =
#: 100 MPa in the shank, far from where the load is applied (a load shared equally by its
#: particles is not uniform where boundary cells are larger than others)
DOGBONE = STEP.replace(
    "{{ box = {{ min = [6, 2, 2], max = [16, 8, 8] }} }}",
    "{{ box = {{ min = [6, 2, 2], max = [18, 8, 8] }} }}, "
    "{{ box = {{ min = [18, 0, 0], max = [24, 10, 10] }} }}").replace(
    "min = [15.4, -1, -1], max = [17, 11, 11]", "min = [21, -1, -1], max = [25, 11, 11]")


@pytest.fixture
def refined(tmp_path_factory):
    """``rackstress run dogbone.toml --refine`` as a user runs it (a real process), killed
    once the refinement has started, then ``rackstress run --resume RUN --refine``: the
    dog-bone at 1 mm, then at 1/√2 mm into RUN/refine. Returns the run directory, the
    resume's process, its summary and the summary the killed run left."""
    import json
    import os
    import signal
    import subprocess

    from conftest import RACKSTRESS
    from test_faults import QUIET, rs, wait_for

    tmp = tmp_path_factory.mktemp("refine")
    scene = tmp / "dogbone.toml"
    scene.write_text(DOGBONE.format(F=3600.0))
    out = tmp / "run"
    proc = subprocess.Popen([RACKSTRESS, "run", str(scene), "--refine", "--engine",
                             "reference", "--out", str(out), *QUIET],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    try:
        assert wait_for(lambda: (out / "refine" / "scene.json").exists(), 120, proc)
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    first = proc.stdout.read().decode()           # what the first run said before the kill
    killed = json.loads((out / "summary.json").read_text())
    fine_done = (out / "refine" / "summary.json").exists()
    p = rs("run", "--resume", out, "--refine", *QUIET, timeout=300)    # the run's engine
    assert p.returncode == 0, p.stderr
    return out, p, json.loads((out / "summary.json").read_text()), (killed, fine_done, first)


@pytest.mark.slow
def test_refine_killed_resumed_error_bar_covers_converged_fea(refined):
    """One refinement, killed and resumed (one test: the two runs are the suite's dearest):
    killed while refining, the first run is whole (settled, its governing stress, the single
    run's estimate) and the refined one unfinished; resumed, both runs kept, the error bar
    from the first run's governing stress, Richardson by hand, the report's headline,
    singular peak and table; and the band covers the converged value: FEA of the same part,
    P2 graded toward the re-entrant ring (validity/graded.py), the refined run's supports and
    loads, read at the same zone."""
    import json

    from rackstress.stress.governing import read_singular
    from rackstress.validity.graded import governing_fe, reference

    out, p, summary, (killed, fine_done, first) = refined
    assert killed["settled"] and killed["stress"]["governing"]["value"] > 0
    assert killed["stress"]["error"].get("extrapolated") is None      # the default estimate
    assert not fine_done
    assert summary["stress"]["error"]["values"][0] == killed["stress"]["governing"]["value"]
    # the first run's own band is kept beside the refined bar
    assert summary["stress"]["error"]["first_run"]["low"] == killed["stress"]["error"]["low"]
    assert summary["stress"]["error"]["first_run"]["high"] == killed["stress"]["error"]["high"]
    st = summary["stress"]
    gov, err = st["governing"], st["error"]
    fine = json.loads((out / "refine" / "summary.json").read_text())
    assert fine["settled"] and fine["params"]["spacing_scale"] == pytest.approx(1 / math.sqrt(2))
    assert err["values"][0] == gov["value"] and err["spacings"] == pytest.approx(
        [1.0, 1 / math.sqrt(2)])
    assert err["zone"] == gov["zone"] == pytest.approx(2.4)        # the coarse run's zone
    # Richardson by hand from the two values and the stated order
    g1, g2 = err["values"]
    r = math.sqrt(2) ** err["order"]
    assert err["extrapolated"] == pytest.approx(g2 + (g2 - g1) / (r - 1))
    assert err["low"] <= err["extrapolated"] <= err["high"]
    # what the refinement reports: the finer run's value, the centre of Roache's band
    assert err["value"] == g2 and err["low"] <= g2 <= err["high"]
    assert "governing von Mises stress" in p.stdout and "error bar:" in p.stdout
    assert "singular peak" in first and "re-entrant edge" in first       # the first run's lines
    # the report: the governing stress as the headline, the singular peak beside it, the table
    from rackstress.render.report import write_report

    html = write_report(out, view=False).read_text()
    assert 'id="headline" data-kind="governing"' in html and 'id="singular"' in html
    assert f'data-value="{gov["value"]!r}"' in html
    table = html.split('id="error-bar"')[1].split("</table>")[0]
    assert all(f"{v:.4g}" in table for v in err["values"])
    assert f"{err['extrapolated']:.4g}" in table
    assert f"{g2:.4g}" in table.split('id="refined"')[1].split("</tr>")[0]
    err = summary["stress"]["error"]
    sing = read_singular(out)["bar"][2]
    ref = reference(out / "refine", h_far=2.0, h_near=0.5, singular=sing)   # 0.2 % off h/1.3
    fe = governing_fe(ref, err["zone"])
    assert err["low"] <= fe["value"] <= err["high"]
    assert abs(fe["value"] / 100.0 - 1) < 0.1     # F/A = 100 MPa in the shank, by hand
    assert 6 + 2.4 <= fe["position"][0] <= 18 - 2.4        # the shank, away from the rings


def test_refine_refuses_what_it_cannot_refine(tmp_path):
    from test_faults import QUIET, rs

    p = rs("run", "plane-rack", "--refine", "--out", tmp_path / "a", *QUIET)
    assert p.returncode == 2 and "built-in scene" in p.stderr
    assert not (tmp_path / "a").exists()
    dyn = tmp_path / "dyn.toml"
    dyn.write_text(STEP.format(F=3600.0).replace('analysis = "static"',
                                                 'analysis = "dynamic"\nsteps = 10'))
    p = rs("run", dyn, "--refine", "--out", tmp_path / "b", *QUIET)
    assert p.returncode == 2 and "not a static analysis" in p.stderr
    assert not (tmp_path / "b").exists()


BAR = """
name = "bar"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "bar"
{source}
material = "steel"
[[support]]
on = "bar"
where = {{ cylinder = {{ start = [{x}, {y}, -1], end = [{x}, {y}, 5], radius = {r} }} }}
[[load]]
on = "bar"
where = {{ box = {{ min = [19.4, -1, -1], max = [21, 5, 5] }} }}
force = [0, -10, 0]
"""


def test_refine_of_a_lattice_part_keeps_the_first_run(tmp_path):
    import json

    from test_faults import QUIET, rs

    scene = tmp_path / "bar.toml"
    scene.write_text(BAR.format(source="lattice = { shape = [20, 4, 4], spacing = 1.0, "
                                       "origin = [0.5, 0.5, 0.5] }", x=1, y=1, r=2.5))
    p = rs("run", scene, "--refine", "--engine", "reference", "--out", tmp_path / "r", *QUIET)
    assert p.returncode == 2 and "cannot be refined" in p.stderr
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["settled"] and summary["stress"]["governing"]["value"] > 0


def test_refine_ratio_two_halves_the_spacing_and_extrapolates_at_that_ratio(tmp_path):
    """``--refine --refine-ratio 2``: the bar filled at 1 mm (20 × 4 × 4 = 320 particles) is
    refined at 0.5 mm (40 × 8 × 8 = 2,560, by hand), and the error bar's Richardson
    extrapolation is the finer value plus its change over 2¹ − 1 (order 1), by hand from the
    two values it gives; a ratio outside 1.2 … 3, or one without --refine, is refused (exit
    2, nothing written)."""
    import json

    from test_faults import QUIET, rs

    scene = tmp_path / "bar.toml"
    scene.write_text(BAR.format(source='fill = { box = { min = [0, 0, 0], max = [20, 4, 4] } }'
                                       "\nspacing = 1.0", x=1, y=1, r=2.5))
    p = rs("run", scene, "--refine", "--refine-ratio", "2", "--engine", "reference", "--out",
           tmp_path / "r", *QUIET, timeout=300)
    assert p.returncode == 0, p.stderr
    assert "at spacing / 2 (2,560 particles)" in p.stdout
    err = json.loads((tmp_path / "r" / "summary.json").read_text())["stress"]["error"]
    assert err["spacings"] == [1.0, 0.5] and err["ratio"] == 2.0
    assert err["particles"] == [320, 2560]
    coarse, fine = err["values"]
    assert err["extrapolated"] == pytest.approx(fine + (fine - coarse))
    for args in (("--refine", "--refine-ratio", "5"), ("--refine-ratio", "2")):  # no --refine
        p = rs("run", scene, *args, "--out", tmp_path / "x", *QUIET)
        assert p.returncode == 2 and "--refine-ratio" in p.stderr, p.stderr
        assert "Traceback" not in p.stderr and not (tmp_path / "x").exists()


def test_refined_run_that_does_not_settle_keeps_the_first_run(tmp_path):
    """Held on a cylinder of radius 0.7 about (1.161, 0.939): at 1 mm it holds two lines of
    particles (x = 1.5, y = 0.5 and 1.5: a clamp), at 1/√2 mm one (a hinge: a mechanism)."""
    import json

    from test_faults import QUIET, rs

    scene = tmp_path / "bar.toml"
    scene.write_text(BAR.format(source='fill = { box = { min = [0, 0, 0], max = [20, 4, 4] } }'
                                       "\nspacing = 1.0", x=1.161, y=0.939, r=0.7))
    p = rs("run", scene, "--refine", "--engine", "reference", "--out", tmp_path / "r", *QUIET,
           timeout=300)
    assert p.returncode in (2, 6), p.stderr        # 6: did not settle (2: refused as a mechanism)
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["settled"] and summary["stress"]["governing"]["value"] > 0
    assert summary["stress"]["error"].get("extrapolated") is None
    # bench parts' row of such a run: the refinement's own error, not a refined value (its
    # summary's error is the first run's band alone, without the two values)
    from rackstress.bench.parts import _error_of, _refined

    row = _refined(summary["stress"], p, short=lambda x: x)
    assert row == {"refine_error": _error_of(p.stderr)}
    assert ("did not settle" if p.returncode == 6 else "cannot hold") in row["refine_error"]


def test_band_inverts_the_measured_relative_error():
    from rackstress.stress.governing import band

    # a reading 42 % low of 100 (58) and one 42 % high (142): both bands reach 100 (by hand:
    # |g / c − 1| ≤ e  ⇔  g / (1 + e) ≤ c ≤ g / (1 − e))
    lo, hi = band(58.0, 0.42)
    assert hi == pytest.approx(100.0) and lo == pytest.approx(58.0 / 1.42)
    lo, hi = band(142.0, 0.42)
    assert lo == pytest.approx(100.0)
    assert band(10.0, 1.0)[1] == math.inf


#: an L of two 4 × 3 arms, 11 and 10 long, its inner corner rounded by a fillet of radius 3
#: (three spacings: resolved, not singular), the long arm's end held, the short arm's end
#: pushed along the long arm (bending through the fillet)
FILLETED_L = """
name = "fl"
units = "mm-N-s"
analysis = "static"
[[group]]
name = "L"
fill = { union = [ { box = { min = [0, 0, 0], max = [4, 11, 3] } },
                   { box = { min = [0, 0, 0], max = [10, 4, 3] } },
                   { difference = [ { box = { min = [4, 4, 0], max = [7, 7, 3] } },
                                    { cylinder = { start = [7, 7, -1], end = [7, 7, 4], radius = 3 } } ] } ] }
spacing = 1.0
material = "aluminium"
[[support]]
on = "L"
where = { box = { min = [-1, 10.4, -1], max = [5, 12, 4] } }
[[load]]
on = "L"
where = { box = { min = [9.4, -1, -1], max = [11, 5, 4] } }
force = [0, 150, 0]
"""


def test_a_fillets_peak_is_named_and_bounds_the_error_bar(tmp_path):
    """The governing record names the fillet's largest value (the concave curved face away
    from the singular points) and a single run's band reaches its value over 1 − CURVED_ERROR:
    the lattice under-reads such a peak (docs/stress.md)."""
    from rackstress.runs.run import run
    from rackstress.scenes import load_toml
    from rackstress.stress.governing import CURVED_ERROR, curved_bound
    from rackstress.stress.post import postprocess

    path = tmp_path / "fl.toml"
    path.write_text(FILLETED_L)
    d = tmp_path / "run"
    assert run(load_toml(path), d, engine="reference", progress=False)["settled"]
    info = postprocess(d, vtk=False)
    gov, err = info["governing"], info["error"]
    c = gov["curved_face"]
    assert c is not None
    # at the fillet: the read point within two spacings of the arc of radius 3 about (7, 7)
    # from (4, 7) to (7, 4)
    t = np.linspace(math.pi, 1.5 * math.pi, 91)
    arc = np.column_stack([7 + 3 * np.cos(t), 7 + 3 * np.sin(t)])
    assert np.hypot(*(arc - np.array(c["read_at"][:2])).T).min() <= 2.0 + 1e-9
    assert curved_bound(gov) == pytest.approx(c["value"] / (1 - CURVED_ERROR))
    assert err["high"] >= c["value"] / (1 - CURVED_ERROR) - 1e-9
    assert err["low"] <= gov["value"] <= err["high"]


def test_refine_says_what_the_refined_run_reads_at_a_fillet_the_first_run_took_for_sharp(
        tmp_path):
    """The filleted C frame (fillets of radius 2 mm at x 10…12, y 10…12 and 18…20) run at
    1.6 mm, where a fillet below 1.43 spacings (2.29 mm) is a sharp edge, and refined to
    1.13 mm, where it is one (1.62 mm): the error bar reads both at the first run's singular
    points, so the fillets stay out of it; the refined run on its own reads at a fillet, more
    than 10 % higher, and --refine says so (summary.json and its lines)."""
    import json
    from pathlib import Path

    from test_faults import QUIET, rs

    d = tmp_path / "r"
    scene = Path(__file__).resolve().parents[1] / "examples" / "cframe" / "filleted.toml"
    out = rs("run", scene, "--set", "spacing=1.6", "--refine", "--out", d, *QUIET, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    err = json.loads((d / "summary.json").read_text())["stress"]["error"]
    own = err["fine_own"]
    assert own["why"] == "singular points"
    assert own["value"] > 1.1 * err["values"][-1]
    x, y, _ = own["position"]
    # within a spacing of either fillet's arc (centres (12, 12) and (12, 18), radius 2)
    assert min(abs(math.hypot(x - 12, y - cy) - 2.0) for cy in (12, 18)) <= 1.6
    assert "the refined run alone reads" in out.stdout


def test_a_fillet_the_spacing_does_not_resolve_is_not_called_a_property_of_the_spacing():
    """The singular peak at an unresolved fillet is bounded in the part: the run's line does
    not call it 'not a property of the part', and its advice is to refine, not to round an
    edge that is round; at a sharp edge it still is."""
    from rackstress.stress.governing import ADVICE, describe

    def line(kind):
        sing = {"value": 90.0, "units": "MPa", "kind": kind, "particle": 7,
                "position": [1.0, 2.0, 3.0], "near": None, "advice": ADVICE[kind]}
        return describe(None, sing, None)[0]

    fillet, sharp = line("unresolved fillet"), line("re-entrant edge")
    assert "at an unresolved fillet" in fillet and "not a property of the part" not in fillet
    assert "bounded" in fillet and "Round the edge" not in ADVICE["unresolved fillet"]
    assert "not a property of the part" in sharp


def test_another_lattice_reads_the_first_runs_governing_point_by_beam_theory(tmp_path):
    """``with_first_point`` (``--refine``, ``--offsets``): another lattice's governing stress is
    its own rule reading, or its stress field at the first run's governing point where that is
    the larger. The 20 × 4 × 4 mm cantilever at 1 mm (a real run), 10 N at its tip (x = 19.5):
    at the top face mid-span (10, 4, 2) beam theory gives σ = M c / I = 10 · 9.5 · 2 / (4 · 4³
    / 12) = 8.906 MPa (hand calculation); the field read there is within the lattice's own
    band for a 4 mm member at 1 mm (``DEFAULT_ERROR_SLOPE`` · s / t, docs/stress.md). A rule
    reading above it is kept as it is; none at all (every particle within the zone) gives the
    field's reading, said as read at the first point."""
    from test_faults import QUIET, rs

    from rackstress.stress.governing import DEFAULT_ERROR_SLOPE, FIRST_POINT, with_first_point
    from rackstress.stress.post import compute_fields
    from rackstress.stress.rundata import load_run

    scene = tmp_path / "bar.toml"
    scene.write_text(BAR.format(source='fill = { box = { min = [0, 0, 0], max = [20, 4, 4] } }'
                                       "\nspacing = 1.0", x=1, y=1, r=2.5))
    p = rs("run", scene, "--engine", "reference", "--out", tmp_path / "r", *QUIET)
    assert p.returncode == 0, p.stderr
    run = load_run(tmp_path / "r")
    fields = compute_fields(run)
    first = {"group": "bar", "read_at": [10.0, 4.0, 2.0], "value": 1.0, "safety": 250.0,
             "units": "MPa", "length_units": "mm", "zone": 2.0}
    beam = 10.0 * 9.5 * 2.0 / (4.0 * 4.0 ** 3 / 12.0)
    got = with_first_point(run, fields, None, first)
    assert got["read"] == FIRST_POINT and got["rule_value"] is None
    assert got["read_at"] == [10.0, 4.0, 2.0]
    assert abs(got["value"] / beam - 1.0) <= DEFAULT_ERROR_SLOPE * 1.0 / 4.0
    assert got["safety"] == pytest.approx(250.0 / got["value"])      # the yield, 250 MPa
    # the nearest particle is named: a top-layer particle at mid-span
    assert abs(got["position"][0] - 10.0) <= 0.5 and got["position"][1] == pytest.approx(3.5)
    # read where it is asked: M falls linearly toward the tip, so does the reading
    at = [with_first_point(run, fields, None, dict(first, read_at=[x, 4.0, 2.0]))["value"]
          for x in (8.0, 12.0)]
    assert at[0] > got["value"] > at[1]
    assert abs((at[0] - at[1]) / (10.0 * 4.0 * 2.0 / (4.0 * 4.0 ** 3 / 12.0)) - 1.0) \
        <= DEFAULT_ERROR_SLOPE * 1.0 / 4.0
    low = {"value": 0.5 * beam, "frame": len(fields.steps) - 1, "group": "bar"}
    assert with_first_point(run, fields, low, first)["value"] == got["value"]
    assert with_first_point(run, fields, low, first)["rule_value"] == 0.5 * beam
    high = dict(low, value=2.0 * beam)
    assert with_first_point(run, fields, high, first) is high
