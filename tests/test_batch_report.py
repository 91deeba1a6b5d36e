"""Batches you can look at: every finished job gets its pictures, report.html and 3D view
(unless ``--no-render``), and the batch its own report.html — the sweep table, the peak against
each swept parameter, links to the jobs' reports. Real batches of small plane-rack jobs
(reference engine, 150 steps), serial and under ``mpiexec -n 2``; pages read with html.parser.
Expected values: each job's own summary.json (an independent file: the table must repeat it),
and the physics of the pulled plane (Eqs. 24–26: a stiffer plane binding deforms less)."""
from __future__ import annotations

import json
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest
from conftest import HANG_S

BIN = Path(sys.executable).parent
RACKSTRESS, MPIEXEC = str(BIN / "rackstress"), str(BIN / "mpiexec")
SWEEP = """scene = "plane-rack"
engine = "reference"
steps = 150

[grid]
plane_bind = [50.0, 200.0]

[[job]]
name = "diverge"
plane_bind = 1e5
allow_unstable = true
"""
PNG = b"\x89PNG\r\n\x1a\n"


class Tags(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))


def tags(path: Path) -> list:
    p = Tags()
    p.feed(path.read_text(encoding="utf-8"))
    return p.tags


def run_batch(tmp_path: Path, *extra, mpi: int | None = None) -> Path:
    sw = tmp_path / "sweep.toml"
    sw.write_text(SWEEP)
    out = tmp_path / "b"
    cmd = ([MPIEXEC, "-n", str(mpi)] if mpi else []) + [RACKSTRESS, "batch", str(sw), "--out",
                                                         str(out), *extra]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    assert f"page: {out / 'report.html'}" in r.stdout
    return out


def check_batch_page(out: Path, rendered: bool) -> None:
    index = json.loads((out / "batch.json").read_text())
    assert index["counts"] == {"ok": 2, "diverged": 1}
    t = tags(out / "report.html")
    rows = {a["data-job"]: a for tag, a in t if tag == "tr" and "data-job" in a}
    assert set(rows) == {j["name"] for j in index["jobs"]}
    peaks = {}
    for j in index["jobs"]:
        row = rows[j["name"]]
        assert row["data-status"] == j["status"]
        if j["status"] != "ok":
            assert "data-peak" not in row
            continue
        s = json.loads((out / j["dir"] / "summary.json").read_text())
        assert float(row["data-peak"]) == s["stress"]["peak"]["value"]
        peaks[j["params"]["plane_bind"]] = s["stress"]["peak"]["value"]
    # the pulled corner deforms less on a plane bound four times as stiffly
    assert peaks[200.0] < peaks[50.0]
    links = [a["href"] for tag, a in t if tag == "a" and a.get("href", "").endswith("report.html")]
    oks = [j["dir"] for j in index["jobs"] if j["status"] == "ok"]
    if rendered:
        assert sorted(links) == sorted(f"{d}/report.html" for d in oks)
        for d in oks:
            job = out / d
            assert (job / "figures" / "sheet.png").read_bytes()[:8] == PNG
            assert (job / "view3d.html").is_file()
            jt = tags(job / "report.html")
            assert [a["src"] for tag, a in jt if tag == "iframe"] == ["view3d.html"]
    else:
        assert links == []
        for d in oks:
            assert not (out / d / "report.html").exists()
            assert not (out / d / "figures").exists()
    # the peak against the one swept parameter: a picture that exists
    imgs = [a for tag, a in t if tag == "img"]
    assert [a["data-against"] for a in imgs] == ["plane_bind"]
    assert (out / imgs[0]["src"]).read_bytes()[:8] == PNG
    assert not any(a.get("src", "").startswith(("http:", "https:", "//")) for _, a in t)


@pytest.mark.slow
def test_batch_renders_each_job_and_writes_its_own_report(tmp_path):
    out = run_batch(tmp_path)
    check_batch_page(out, rendered=True)
    # --report refreshes the page (and still prints the table)
    r = subprocess.run([RACKSTRESS, "batch", "--report", str(out), "--figure",
                        "stress.peak.value"], capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0, r.stderr
    assert f"page: {out / 'report.html'}" in r.stdout
    check_batch_page(out, rendered=True)


def test_batch_no_render(tmp_path):
    check_batch_page(run_batch(tmp_path, "--no-render"), rendered=False)


@pytest.mark.slow
@pytest.mark.mpi
def test_batch_renders_under_mpiexec(tmp_path):
    """Two groups of one rank: each job's root renders its own job."""
    out = run_batch(tmp_path, mpi=2)
    check_batch_page(out, rendered=True)
    assert {j["group"] for j in json.loads((out / "batch.json").read_text())["jobs"]} == {0, 1}
