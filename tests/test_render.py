"""Rendering off-screen: pictures, sheet, movie and plots of a real (short) plane-rack LAMMPS run;
the CLI; nothing half-written on failure; MagPod's stress where Section 5.2 says it is."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib import image as mpimg

from rackstress import scenes
from rackstress.cli import main
from rackstress.render.pictures import HEADER_H, VIEWS, render, stress_rgba
from rackstress.runs.run import run as run_scene
from rackstress.stress import DesiredPositionDistance, TruncatedDumpError, load_run

STEPS, EVERY = 200, 10


@pytest.fixture(scope="module")
def plane_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("plane_rack")
    sc = scenes.load("plane-rack").with_steps(STEPS)
    run_scene(sc, out, engine="lammps", dump_every=EVERY, progress=False)
    return out


@pytest.fixture(scope="module")
def rendered(plane_run):
    rep = render(plane_run, frames=[100, 200], views=["right", "left", "top"], movie=True)
    return plane_run, rep


def _red(img, skip_bar=True, margin=60):
    """Reddish pixels (shaded red spheres included), not counting the strip above the model
    (title, colour bar, legend); ``margin`` 25 counts the pink of a value well below the top."""
    img = np.asarray(img)[..., :3]
    if img.dtype != np.uint8:
        img = np.round(img * 255).astype(np.uint8)
    r, g, b = (img[..., k].astype(int) for k in range(3))
    red = (r - g > margin) & (r - b > margin)
    if skip_bar:
        red[:HEADER_H] = False
    return red


def test_colouring_is_the_papers():
    rgba = stress_rgba(np.array([0.0, 0.5, 1.0, 3.0, np.nan]), vmax=1.0)
    assert tuple(rgba[0]) == (153, 153, 153, 38)          # grey, translucent
    assert tuple(rgba[2]) == (255, 0, 0, 255)              # red, opaque
    assert tuple(rgba[3]) == (255, 0, 0, 255)              # clipped at the scale's top
    assert rgba[1, 0] > rgba[0, 0] and rgba[1, 1] < rgba[0, 1] and rgba[0, 3] < rgba[1, 3] < 255
    assert tuple(rgba[4]) == tuple(rgba[0])                # undefined → as zero


@pytest.mark.slow
def test_pictures_exist_and_show_the_pulled_corner_red(rendered):
    rundir, rep = rendered
    fig = rundir / "figures"
    for view in ("right", "left", "top"):
        for step in (100, 200):
            assert (fig / f"{view}_{step:06d}.png").is_file()
    run = load_run(rundir)
    paper = DesiredPositionDistance(run).run().results.per_particle
    k = int(np.flatnonzero(run.steps == 200)[0])
    corner_hot = paper[k, :400][run.o[:400, 0] + run.o[:400, 2] < 3].mean()
    assert corner_hot > 3 * np.nanmean(paper[k, :400])     # the measure itself: corner stressed
    halves = {}
    # the colour scale tops at the run's peak (iteration ~40), so at 200 the corner is pink
    for view in ("right", "left"):
        img = mpimg.imread(fig / f"{view}_000200.png")
        assert img.std() > 0.05                            # not a uniform image
        red = _red(img, margin=25)
        assert red.sum() > 50, view
        cols = np.nonzero(red)[1]
        halves[view] = cols.mean() / img.shape[1]
    # the pulled corner is at x ≈ 0: seen from +z (right) it is on the left of the picture,
    # seen from −z (left) on the right
    assert halves["right"] < 0.5 < halves["left"]
    top = mpimg.imread(fig / "top_000200.png")
    assert _red(top, margin=25).sum() > 50
    assert rep.vmax > 0 and rep.timings["pictures_s"] > 0


def test_sheet_plots_manifest(rendered):
    rundir, rep = rendered
    fig = rundir / "figures"
    sheet = mpimg.imread(fig / "sheet.png")
    assert sheet.shape[0] > 300 and sheet.shape[1] > 300 and _red(sheet, False).sum() > 50
    for name in ("stress_over_time.png", "com_path.png"):
        assert (fig / name).stat().st_size > 10_000
    assert not (fig / "footprints.png").exists()
    assert any("no sediment" in n for n in rep.notes)
    manifest = json.loads((fig / "render.json").read_text())
    assert manifest["measure"] == "paper" and manifest["views"] == ["right", "left", "top"]
    assert [f["iteration"] for f in manifest["frames"]] == [100, 200]
    assert "length units" in manifest["label"]
    assert not list(rundir.glob(".figures*"))


def test_movie_is_a_readable_mp4_of_every_frame(rendered):
    import imageio_ffmpeg

    rundir, rep = rendered
    mp4 = rundir / "figures" / "movie.mp4"
    assert mp4.stat().st_size > 1000
    reader = imageio_ffmpeg.read_frames(str(mp4))
    meta = next(reader)
    frames = [np.frombuffer(f, np.uint8) for f in reader]
    assert len(frames) == STEPS // EVERY + 1 == rep.timings["movie_frames"]
    w, h = meta["size"]
    last = frames[-1].reshape(h, w, 3)
    assert last.std() > 5 and _red(last).sum() > 20


def test_nearest_frame_is_used_and_said(plane_run, tmp_path):
    rundir = tmp_path / "r"
    shutil.copytree(plane_run, rundir, ignore=shutil.ignore_patterns("figures"))
    res = CliRunner().invoke(main, ["render", str(rundir), "--frames", "33,5000",
                                    "--views", "front", "--measure", "strain"])
    assert res.exit_code == 0, res.output
    assert "iteration 33 is not in the dump; using the nearest frame, iteration 30" in res.output
    assert "iteration 5000" in res.output and "wrote" in res.output and "rendered in" in res.output
    # another measure goes into its own folder: the paper measure's figures stay
    assert (rundir / "figures" / "strain" / "front_000030.png").is_file()
    assert (rundir / "figures" / "strain" / "front_000200.png").is_file()
    manifest = json.loads((rundir / "figures" / "strain" / "render.json").read_text())
    assert manifest["label"] == "von Mises shear strain [dimensionless]"


def test_failed_render_leaves_nothing_and_keeps_old_figures(plane_run, tmp_path):
    rundir = tmp_path / "r"
    shutil.copytree(plane_run, rundir, ignore=shutil.ignore_patterns("figures"))
    (rundir / "figures").mkdir()
    (rundir / "figures" / "old.png").write_bytes(b"old")
    dump = rundir / "trajectory.dump"
    data = dump.read_bytes()
    dump.write_bytes(data[: len(data) - 2000])           # cut the last frame
    hidden = sorted(p.name for p in rundir.iterdir() if p.name.startswith("."))  # the run's own
    res = CliRunner().invoke(main, ["render", str(rundir)])
    assert res.exit_code == 2
    assert "ends mid-frame at step 200 (frame 20)" in res.output and str(dump) in res.output
    assert (rundir / "figures" / "old.png").read_bytes() == b"old"
    assert sorted(p.name for p in rundir.iterdir() if p.name.startswith(".")) == hidden
    with pytest.raises(TruncatedDumpError):
        render(rundir)
    # on request, the complete frames render (beside the old figures: renders add, never delete)
    rep = render(rundir, allow_truncated=True, views=["right"], frames=[190], plots=False)
    assert any("mid-frame" in n for n in rep.notes)
    assert (rundir / "figures" / "right_000190.png").is_file()
    assert (rundir / "figures" / "old.png").read_bytes() == b"old"
    res = CliRunner().invoke(main, ["render", str(rundir), "--allow-truncated", "--measure",
                                    "virial"])
    assert res.exit_code == 2 and "did not record per-atom virial stress" in res.output


def test_views_are_defined_relative_to_walking_direction():
    # MagPod walks towards +x with y up: its right side is +z
    assert VIEWS["right"][0] == (0.0, 0.0, 1.0) and VIEWS["left"][0] == (0.0, 0.0, -1.0)
    assert VIEWS["front"][0] == (1.0, 0.0, 0.0)


# ----------------------------------------------------------------------------- MagPod
@pytest.fixture(scope="module")
def magpod_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("magpod_small")
    sc = scenes.load("magpod-small").with_steps(600)
    run_scene(sc, out, engine="lammps", dump_every=50, progress=False)
    return out, sc


def _section_52_zone(run, sc, step):
    """Where Section 5.2 puts the stress at ``step``: the active attraction regions (the body
    regions of this phase and the one before, and each leg's region R), with their neighbours
    one spacing away, and the feet (the legs' foot plates, in contact or swinging)."""
    from scipy.spatial import cKDTree

    phases = run.scene["phases"]
    total = sum(p["steps"] for p in phases)
    s, i = (step - 1) % total, 0
    while s >= phases[i]["steps"]:
        s -= phases[i]["steps"]
        i += 1
    o, parts = run.o, run.parts
    seed = np.zeros(run.n_atoms, bool)
    body = parts["body"].index
    regions = sc.groups["body"].meta["regions"]
    for v in (phases[i]["vars"], phases[i - 1]["vars"]):
        for key in (f"breg{v['r']}", f"breg{v['l']}"):
            seed[body[np.asarray(regions[key]) != 0]] = True
    for leg, key in (("rightleg", "rreg"), ("leftleg", "lreg")):
        seed[parts[leg].index[np.asarray(sc.groups[leg].meta["regions"][key]) != 0]] = True
    spacing = float(sc.params.get("spacing", 2.0))
    zone = np.zeros(run.n_atoms, bool)
    for name in ("body", "rightleg", "leftleg"):
        idx = parts[name].index
        near = cKDTree(o[idx[seed[idx]]]).query(o[idx])[0] <= spacing * (1 + 1e-9)
        zone[idx] = near
        if name != "body":                                   # the foot: its foot_ny layers
            layers = int(sc.params.get("foot_ny", 1))
            zone[idx] |= o[idx, 1] <= o[idx, 1].min() + spacing * (layers - 1) + 1e-9
    return zone


def test_magpod_pictures_and_stress_where_section_5_2_says(magpod_run):
    rundir, sc = magpod_run
    rep = render(rundir, frames=[600], views=["right", "front"])
    fig = rundir / "figures"
    for name in ("right_000600.png", "front_000600.png", "sheet.png", "stress_over_time.png",
                 "com_path.png", "footprints.png"):
        assert (fig / name).is_file(), name
    img = mpimg.imread(fig / "right_000600.png")
    # the scale tops at the run's peak (the right leg at iteration 50): at 600 the active
    # regions are pink to red
    assert img.std() > 0.05 and _red(img, margin=25).sum() > 200
    run = load_run(rundir)
    assert [p.name for p in run.displayed()] == ["body", "rightleg", "leftleg"]
    paper = DesiredPositionDistance(run).run().results.per_particle[-1]
    shown = np.concatenate([p.index for p in run.displayed()])
    top = shown[paper[shown] >= np.quantile(paper[shown], 0.9)]
    zone = _section_52_zone(run, sc, int(run.steps[-1]))
    base = zone[shown].mean()                    # what a random choice would give
    frac = zone[top].mean()
    print(f"top decile in the zone: {frac:.2f}, random: {base:.2f}")
    assert frac >= 0.7 and frac >= 2.5 * base, (frac, base)
    assert rep.vmax > 0


# ----------------------------------------------------------------------------- steering
def test_groups_legend_out_movie_view_cmap_and_no_overlap(plane_run, tmp_path):
    rundir = tmp_path / "r"
    shutil.copytree(plane_run, rundir, ignore=shutil.ignore_patterns("figures"))
    render(rundir, views=["right"], frames=[200], plots=False)
    before = sorted(p.name for p in (rundir / "figures").iterdir())
    # another view into the same folder adds, deletes nothing
    render(rundir, views=["top"], frames=[200], plots=False)
    after = sorted(p.name for p in (rundir / "figures").iterdir())
    assert set(before) <= set(after) and "top_000200.png" in after
    # --out, --groups (a rack shown, coloured), --cmap, a movie of the second view
    out = tmp_path / "mine"
    res = CliRunner().invoke(main, ["render", str(rundir), "--out", str(out), "--groups",
                                    "plane,planerack", "--views", "right,top", "--frames", "200",
                                    "--cmap", "viridis", "--movie", "--movie-view", "top"])
    assert res.exit_code == 0, res.output
    # not a terminal: no progress bar, one line of record
    assert "%|" not in res.output and "\r" not in res.output
    assert sum(ln.startswith("rendered in ") for ln in res.output.splitlines()) == 1
    manifest = json.loads((out / "render.json").read_text())
    assert manifest["parts"] == {"coloured": ["plane", "planerack"], "context": [],
                                 "hidden": []}
    assert manifest["movie_view"] == "top" and manifest["cmap"] == "viridis"
    assert (out / "movie.mp4").stat().st_size > 1000
    assert sorted(p.name for p in (rundir / "figures").iterdir()) == after   # untouched
    img = np.asarray(mpimg.imread(out / "right_000200.png"))[..., :3]
    # viridis: the top of the scale is yellow, the bottom purple; no grey→red in the bar
    bar = img[35:45, int(0.56 * img.shape[1]):int(0.95 * img.shape[1])]
    assert bar[:, -1].mean(axis=0)[2] < 0.3 and bar[:, 0].mean(axis=0)[2] > 0.25
    # the strip above the model holds title, legend and colour bar; the model stays below it:
    # the same strip on every picture, and nothing of the model in it
    other = np.asarray(mpimg.imread(out / "top_000200.png"))[..., :3]
    np.testing.assert_array_equal(img[:HEADER_H], other[:HEADER_H])
    # hiding: the default set minus the plane leaves nothing to colour -> a clear error
    res = CliRunner().invoke(main, ["render", str(rundir), "--groups", "-plane"])
    assert res.exit_code == 2 and "no part to colour" in res.output
    res = CliRunner().invoke(main, ["render", str(rundir), "--groups", "wing"])
    assert res.exit_code == 2 and "no part(s) wing" in res.output and "plane" in res.output
    res = CliRunner().invoke(main, ["render", str(rundir), "--cmap", "nope"])
    assert res.exit_code == 2 and "unknown colour map 'nope'" in res.output


def test_a_part_that_flew_away_is_framed_out_with_a_warning(tmp_path):
    from test_stress import BLOCK, write_run

    d = tmp_path / "run"
    far = BLOCK + [40.0, 0.0, 0.0]
    frames = [(0, np.concatenate([BLOCK, far])),
              (10, np.concatenate([BLOCK, far + [5000.0, 0.0, 0.0]]))]
    write_run(d, [("stay", "part", BLOCK), ("gone", "part", far)], frames)
    rep = render(d, views=["right"], frames=[10], plots=False)
    assert any("part gone flew away" in n for n in rep.notes), rep.notes
    img = np.asarray(mpimg.imread(d / "figures" / "right_000010.png"))[HEADER_H:-40, :, :3]
    drawn = np.argwhere(img.min(axis=2) < 0.9)          # (the iteration line is below)
    # the remaining block fills the picture instead of shrinking to a dot
    assert np.ptp(drawn[:, 1]) > 0.3 * img.shape[1]


def test_default_frames_are_the_papers_for_magpod_only():
    """Fig. 12's iterations (1320, 2600, 4720, 17480) for a MagPod run that reaches them; any
    other run of that length gets four spread over it, its last iteration included."""
    from types import SimpleNamespace

    from rackstress.render.pictures import default_iterations

    other = SimpleNamespace(steps=np.array([0, 10000, 20000]), scene={"scene": "plane-rack"})
    assert default_iterations(other) == [5000, 10000, 15000, 20000]
    assert default_iterations(other, 37) == [37, 5000, 10000, 15000, 20000]
    magpod = SimpleNamespace(steps=np.array([0, 19200]), scene={"scene": "magpod"})
    assert default_iterations(magpod) == [1320, 2600, 4720, 17480]


@pytest.mark.parametrize("x, y", [(390, 150), (10, 150), (200, 2), (390, 296)])
def test_the_peak_label_stays_inside_the_panel(x, y):
    """The ring's label is drawn right of the ring, or left of it at the right edge, and never
    cut at an edge of the 400 × 300 panel (black text pixels 2+ px from every edge)."""
    from rackstress.render.pictures import annotate

    img = np.full((300, 400, 3), 255, np.uint8)
    out = annotate(img, 100, "right", [], ring=(x, y, 12), ring_text="peak 2.81 (particle 1)")
    # the label's black pixels (the ring is black too: mask the ring's box out)
    black = (out < 60).all(axis=2)
    black[max(y - 16, 0):y + 16, max(x - 16, 0):x + 16] = False
    black[-32:, :] = False                     # the iteration line at the bottom
    rows, cols = np.nonzero(black)
    assert cols.size > 50                      # the label is there
    assert cols.min() >= 2 and cols.max() <= 397 and rows.min() >= 2
    if x > 200:
        assert cols.max() < x                  # moved to the ring's left
    else:
        assert cols.min() > x                  # right of the ring
