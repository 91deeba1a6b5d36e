"""report.html's 3D view (``view3d.html``): offline, the peak frame, the peak marked, a frame slider.

A plane-rack run on the reference engine (60 steps, a frame every 3) is rendered as
``rackstress run`` does; the page is read back with ``html.parser`` and its inlined scene
(vtk.js's zipped state) decoded. Expected values come from the run's own files read
independently (the dump's frames, summary.json's peak) and from Section 5.2's colouring (the
peak particle is full red when the scale's top is the peak).
"""
from __future__ import annotations

import base64
import io
import json
import re
import zipfile
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from conftest import dump_text, trajectory
from click.testing import CliRunner

from rackstress.cli import main


class Page(HTMLParser):
    """Tags with their attributes, and the text of every <script>."""

    def __init__(self):
        super().__init__()
        self.tags, self.scripts, self._in = [], [], None

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        if tag == "script":
            self._in = dict(attrs)
            self.scripts.append([dict(attrs), ""])

    def handle_endtag(self, tag):
        if tag == "script":
            self._in = None

    def handle_data(self, data):
        if self._in is not None:
            self.scripts[-1][1] += data


def parse(path: Path) -> Page:
    p = Page()
    p.feed(path.read_text(encoding="utf-8"))
    return p


def dump_frames(path: Path) -> dict:
    """{iteration: positions (n×3) in atom-id order} of a LAMMPS dump, read by hand."""
    lines = dump_text(path).splitlines()
    out, k = {}, 0
    while k < len(lines):
        step, n = int(lines[k + 1]), int(lines[k + 3])
        rows = np.array([[float(x) for x in r.split()] for r in lines[k + 9:k + 9 + n]])
        rows = rows[np.argsort(rows[:, 0])]
        out[step] = rows[:, 3:6]
        k += 9 + n
    return out


def no_network(page: Page, text: str) -> None:
    for tag, attrs in page.tags:
        for key in ("src", "href"):
            v = attrs.get(key) or ""
            assert not re.match(r"^(https?:)?//", v), (tag, key, v)
    assert "cdn." not in text.lower()


@pytest.fixture(scope="module")
def rundir(tmp_path_factory):
    out = tmp_path_factory.mktemp("view") / "pr"
    res = CliRunner().invoke(main, ["run", "plane-rack", "--engine", "reference", "--steps", "60",
                                    "--dump-every", "3", "--out", str(out), "--no-progress"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return out


def test_report_embeds_the_view_offline(rundir):
    report = parse(rundir / "report.html")
    text = (rundir / "report.html").read_text()
    no_network(report, text)
    frames = [a for t, a in report.tags if t == "iframe"]
    assert [f["src"] for f in frames] == ["view3d.html"]
    what = next(a for t, a in report.tags if a.get("id") == "view3d-what")
    assert int(what["data-shown"]) == 400            # the 20 × 20 plane; the racks are hidden
    assert int(what["data-context-total"]) == 0      # no sediment
    assert 1 < int(what["data-frames"]) <= 21       # 21 frames dumped (0, 3, …, 60)
    view = rundir / "view3d.html"
    assert int(what["data-bytes"]) == view.stat().st_size
    assert view.stat().st_size < 2_000_000
    # the 3D section comes right after the peaks and before the still pictures
    ids = [a.get("id") for _, a in report.tags if a.get("id")]
    assert ids.index("peaks") < ids.index("view3d") < ids.index("pictures")


def test_view_holds_the_peak_frame_and_marks_the_peak(rundir):
    summary = json.loads((rundir / "summary.json").read_text())
    peak = summary["stress"]["peak"]
    dumped = dump_frames(trajectory(rundir))
    page = parse(rundir / "view3d.html")
    text = (rundir / "view3d.html").read_text()
    no_network(page, text)
    # every script is inline: the vtk.js viewer, the scene, the slider
    assert all(not a.get("src") for a, _ in page.scripts)
    assert any(a.get("id") == "rs-frame" and a.get("type") == "range" for _, a in page.tags)
    b64 = re.search(r'base64Str = "([A-Za-z0-9+/=]+)"', text).group(1)
    state = json.loads(zipfile.ZipFile(io.BytesIO(base64.b64decode(b64))).read("index.json"))

    def instances(node):
        yield node
        for d in node.get("dependencies", []):
            yield from instances(d)

    nodes = list(instances(state["scene"]))
    glyphs = [n for n in nodes if n["type"] == "vtkGlyph3DMapper"]
    assert len(glyphs) == 1                          # the plane (racks hidden, no context)
    pts = glyphs[0]["dependencies"][0]["properties"]["points"]
    raw = base64.b64decode(state["hashes"][pts["hash"]]["content"])
    q = np.frombuffer(raw, dtype=np.float32).reshape(-1, 3)
    np.testing.assert_allclose(q, dumped[peak["iteration"]][:400], atol=1e-5)
    # the peak marker sits on the peak particle (summary.json's position)
    actors = [n for n in nodes if n["type"].endswith("Actor")]
    np.testing.assert_allclose(actors[-1]["properties"]["position"], peak["position"], atol=1e-9)

    info = json.loads(next(s for a, s in page.scripts if a.get("id") == "rs-frames"))
    its = [f["iteration"] for f in info["frames"]]
    assert its == sorted(its) and its[0] == 0 and its[-1] == 60
    k = info["peak_frame"]
    assert its[k] == peak["iteration"] and info["frames"][k]["peak"]
    for f in info["frames"]:
        pos = np.frombuffer(base64.b64decode(f["pos"]), dtype=np.float32).reshape(-1, 3)
        np.testing.assert_allclose(pos, dumped[f["iteration"]][:400], atol=1e-5)
        np.testing.assert_allclose(f["marker"], dumped[f["iteration"]][peak["particle"] - 1],
                                   atol=1e-9)
    # Section 5.2's colouring: the peak particle at the peak frame is the top of the scale, red
    rgb = np.frombuffer(base64.b64decode(info["frames"][k]["rgb"]), dtype=np.uint8).reshape(-1, 3)
    assert tuple(rgb[peak["particle"] - 1]) == (255, 0, 0)
    assert rgb.shape == (400, 3)


def test_large_context_keeps_the_particles_nearest_the_parts():
    """MagPod's 30,000 sediment particles: the view keeps MAX_CONTEXT, the nearest to the
    coloured parts' box. On a line of points x = 0 … 24,999 and a box over x ∈ [0, 10] the
    nearest 20,000 are x < 20,000."""
    from rackstress.render.view3d import MAX_CONTEXT, _context_subset

    q = np.column_stack([np.arange(25000.0), np.zeros(25000), np.zeros(25000)])
    keep = _context_subset(q, np.array([0.0, 0, 0]), np.array([10.0, 0, 0]))
    assert MAX_CONTEXT == 20000
    np.testing.assert_array_equal(keep, np.arange(20000))
    small = q[:500]
    np.testing.assert_array_equal(_context_subset(small, np.zeros(3), np.zeros(3)),
                                  np.arange(500))


@pytest.mark.parametrize("n, per_frame, peak", [(101, 100_000, 37), (101, 10, 100), (5, 10, 0),
                                                (1, 10, 0)])
def test_slider_frames_fit_the_budget_and_hold_the_peak(n, per_frame, peak):
    from types import SimpleNamespace

    from rackstress.render.view3d import FRAME_BUDGET, MAX_FRAMES, _frames

    run = SimpleNamespace(steps=np.arange(n) * 10)
    ks = _frames(run, peak, per_frame)
    cap = min(MAX_FRAMES, n, max(1, FRAME_BUDGET // per_frame))
    assert peak in ks and ks == sorted(set(ks))
    assert len(ks) == cap
    assert ks[-1] == n - 1 or cap == 1


def test_camera_looks_from_the_peak_side_raised_30_degrees():
    from rackstress.render.view3d import _view_direction

    d = _view_direction(np.zeros(3), np.array([3.0, -2.0, 4.0]))
    assert np.linalg.norm(d) == pytest.approx(1.0)
    assert d[1] == pytest.approx(0.5)                                # sin 30°
    np.testing.assert_allclose(d[[0, 2]] / np.linalg.norm(d[[0, 2]]), [0.6, 0.8])
    # a peak straight above the centre, or none: the iso side
    for peak in (np.array([0.0, 5.0, 0.0]), None):
        d = _view_direction(np.zeros(3), peak)
        np.testing.assert_allclose(d, [np.cos(np.pi / 6) / np.sqrt(2), 0.5,
                                       np.cos(np.pi / 6) / np.sqrt(2)])


def test_report_without_a_trajectory_says_why_there_is_no_view(rundir, tmp_path):
    """A run directory whose dump is gone still gets its report, with one line in place of the
    view (the rest of the page as before)."""
    import shutil

    from rackstress.render.report import write_report

    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("summary.json", "scene.json", "particles.data"):
        shutil.copy(rundir / name, bare / name)
    write_report(bare)
    page = parse(bare / "report.html")
    ids = {a.get("id") for _, a in page.tags}
    assert "view3d-missing" in ids and "peaks" in ids and "view3d-frame" not in ids
    assert not (bare / "view3d.html").exists()
    assert "trajectory.dump" in (bare / "report.html").read_text()
