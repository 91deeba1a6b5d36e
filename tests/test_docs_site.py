"""The documentation site (mkdocs.yml, docs/) builds with warnings as errors, its API reference
comes from the numpydoc docstrings, and the code examples of its pages run as written."""
from __future__ import annotations

import doctest
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import HANG_S

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
BIN = Path(sys.executable).parent


def test_site_builds_strict(tmp_path):
    """``mkdocs build --strict``: a broken link, a missing page or a docstring the API
    reference cannot read fails the build."""
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    r = subprocess.run([str(BIN / "mkdocs"), "build", "--strict", "--site-dir", str(site)],
                       cwd=REPO, capture_output=True, text=True, timeout=HANG_S, env=env)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "WARNING" not in r.stderr, r.stderr[-3000:]
    for page in ["index.html", "getting-started/index.html", "tutorials/own-part/index.html",
                 "tutorials/sweep/index.html", "tutorials/mpi/index.html",
                 "tutorials/lammps-decks/index.html", "tutorials/results/index.html",
                 "scenes/index.html", "model/index.html", "picture/index.html",
                 "faults/index.html", "benchmarks/index.html", "reference/index.html"]:
        assert (site / page).is_file(), page
    # the API reference is generated from the docstrings: their words, not only the names
    ref = (site / "reference" / "index.html").read_text()
    for text in ["build_view", "write_batch_report", "load_run", "The linear stability limit of Eq. 5",
                 "the peak frame in 3D"]:
        assert text in ref, text
    # no page loads anything from the network at reading time but the theme's own fonts
    # (material's Google Fonts link is switched off: the site reads offline)
    assert "fonts.googleapis" not in (site / "index.html").read_text()
    # the pictures the pages show are in the site
    assert (site / "magpod" / "fig12-sheet.png").is_file()
    assert (site / "benchmarks" / "validity.png").is_file()


PAGES = sorted(p for p in DOCS.rglob("*.md") if p.name != "api.md" and ">>> " in p.read_text())


def test_some_pages_have_examples():
    assert DOCS / "tutorials" / "results.md" in PAGES


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(DOCS)))
def test_page_examples_run_as_written(page, tmp_path, monkeypatch):
    """Every page's ``>>>`` examples (docs/api.md has its own test, tests/test_api_doc.py)."""
    monkeypatch.chdir(tmp_path)
    r = doctest.testfile(str(page), module_relative=False, optionflags=doctest.ELLIPSIS,
                         raise_on_error=False, verbose=False)
    assert r.attempted >= 5
    assert r.failed == 0, f"{r.failed} example(s) of {page} failed (see output)"


def test_every_page_is_in_the_nav_and_readme_points_at_real_pages():
    """The site is complete: every docs/ page is reachable from the nav (a page left out builds
    without a warning but no reader finds it), and every docs/ path README names exists."""
    import re

    nav = (REPO / "mkdocs.yml").read_text().split("\nnav:", 1)[1]
    in_nav = set(re.findall(r":\s*(\S+\.md)\s*$", nav, re.M))
    pages = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md")}
    assert pages - in_nav == set(), f"pages missing from mkdocs.yml's nav: {sorted(pages - in_nav)}"
    assert in_nav - pages == set(), f"nav entries without a page: {sorted(in_nav - pages)}"
    readme = (REPO / "README.md").read_text()
    named = set(re.findall(r"docs/[\w/.-]+\.(?:md|png)", readme))
    assert len(named) >= 15
    for path in named:
        assert (REPO / path).is_file(), f"README names {path}, which does not exist"


def test_what_left_readme_lives_on_the_site():
    """README keeps a pointer; the full texts live on these pages."""
    faults = (DOCS / "faults.md").read_text()
    # the whole fault table: a row per fault, each a test in tests/test_faults.py
    rows = [l for l in faults.splitlines() if l.startswith("| ") and not l.startswith("| fault")]
    assert len(rows) >= 34
    for text in ["One writer per run directory", "Checkpoints know their run", "disk full",
                 "`--steps 1000000000000`", "read-only `--out`"]:
        assert text in faults, text
    gs = (DOCS / "getting-started.md").read_text()
    assert "6 a static\nanalysis did not settle" in gs and "--vtk-format ovito" in gs
    assert "compiled plugin" in (DOCS / "lammps-backend.md").read_text()
    assert "zlib-compressed" in (DOCS / "picture.md").read_text()
    assert "`von_mises` instead" in (DOCS / "picture.md").read_text()
    own = (DOCS / "tutorials" / "own-part.md").read_text()
    readme = (REPO / "README.md").read_text()
    # README's five-minute scene is the tutorial's, word for word
    toml = readme.split("```toml\n")[1].split("```")[0]
    assert toml in own and "rackstress fea runs/my-part" in own
