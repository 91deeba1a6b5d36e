"""The documentation's figures cannot fall behind their benchmarks (tests/figures.py):

* every figure marked in README.md and docs/ agrees with its benchmark's JSON;
* no hand-written page (every page of README.md and docs/ but those a benchmark command writes)
  quotes a figure without a ``fig`` mark (measured) or a ``given`` mark (not measured);
* every page a benchmark command writes equals, byte for byte, what the command writes from
  the JSON beside it (so a page edited by hand, or a JSON regenerated without its page, fails);
* no README, docs/, workflow/ or tests/ text cites a ticket number or a work round as the
  reason for a number: the target and why, in the project's own words.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from figures import REPO, marks, named_tests, unmarked

PAGES = sorted([REPO / "README.md", *(REPO / "docs").rglob("*.md")])


def _rel(p: Path) -> str:
    return str(p.relative_to(REPO))


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_every_marked_figure_agrees_with_its_json(page):
    bad = [f"{_rel(page)}:{r['line']}: quotes {r['figure']}, {r['file']} gives {r['value']!r} "
           f"({r['expr']})" for r in marks(page) if not r["ok"]]
    assert not bad, "\n".join(bad)




def _planar_in(text: str, data: dict) -> str:
    """validity.md as ``bench validity`` leaves it: its report, with ``--planar``'s section put
    in by :func:`rackstress.bench.planar.write_section`."""
    import tempfile

    from rackstress.bench import planar

    with tempfile.TemporaryDirectory() as d:
        md = Path(d) / "validity.md"
        md.write_text(text)
        planar.write_section(md, planar.section(data))
        return md.read_text()


#: page under docs/benchmarks: (module of rackstress.bench, or a script ``scripts/x.py``; its
#: function from the JSON to the page; the JSON, under docs/benchmarks)
GENERATED = {"accuracy.md": ("accuracy", "markdown", "accuracy.json"),
             "cantilever.md": ("cantilever", "report", "cantilever.json"),
             "dynamics.md": ("dynamics", "report", "dynamics.json"),
             "e2e.md": ("e2e", "markdown", "e2e.json"),
             "governing.md": ("governing", "markdown", "governing.json"),
             "hertz.md": ("hertz", "markdown", "hertz.json"),
             "inside.md": ("inside", "markdown", "inside.json"),
             "lattice.md": ("lattice", "report", "lattice.json"),
             "magpod-physical.md": ("magpod_physical", "markdown", "magpod-physical.json"),
             "mesh-fill.md": ("scripts/bench_mesh_fill.py", "markdown", "mesh-fill.json"),
             "nafems.md": ("nafems", "report", "nafems.json"),
             "parts.md": ("parts", "markdown", "parts.json"),
             "parts-100k/parts.md": ("parts", "markdown", "parts-100k/parts.json"),
             "parts-nofea/parts.md": ("parts", "markdown", "parts-nofea/parts.json"),
             "parts-material/parts.md": ("parts", "markdown", "parts-material/parts.json"),
             "parts-half/parts.md": ("parts", "markdown", "parts-half/parts.json"),
             "perf.md": ("perf", "markdown", "perf.json"),
             "phase-error.md": ("scripts/phase_error.py", "markdown", "phase-error.json"),
             "scaling.md": ("scaling", "markdown", "scaling.json"),
             "stability.md": ("stability", "markdown", "stability.json"),
             "static.md": ("static", "report", "static.json"),
             "static-report.md": ("scripts/bench_static_report.py", "markdown",
                                  "static-report.json"),
             "validity-concentrations.md": ("concentrations", "markdown",
                                            "validity-concentrations.json"),
             "stress.md": ("stress", "report", "stress.json"),
             "validity.md": ("validity", "report", "validity.json"),
             "validity3d.md": ("validity3d", "markdown", "validity3d.json"),
             "walls.md": ("walls", "report", "walls.json"),
             "offsets.md": ("offsets", "markdown", "offsets.json")}


#: the pages no command writes
WRITTEN = [_rel(p) for p in PAGES
           if str(p.relative_to(REPO / "docs" / "benchmarks")
                  if p.is_relative_to(REPO / "docs" / "benchmarks") else p) not in GENERATED]


@pytest.mark.parametrize("page", WRITTEN)
def test_a_written_page_quotes_no_figure_without_its_mark(page):
    found = unmarked(REPO / page)
    assert not found, "\n".join(f"{page}:{k}: {fig} has no fig, checked or given mark "
                                "(tests/figures.py)" for k, fig in found)
    missing = [f"{page}:{k}: names {name}, which does not exist"
               for k, name, ok in named_tests(REPO / page) if not ok]
    assert not missing, "\n".join(missing)


def _renderer(mod: str, fn: str):
    """``rackstress.bench.MOD``'s ``fn``, or, for a script (``scripts/x.py``), the script's."""
    import importlib
    import importlib.util

    if mod.endswith(".py"):
        spec = importlib.util.spec_from_file_location(Path(mod).stem, REPO / mod)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return getattr(module, fn)
    return getattr(importlib.import_module(f"rackstress.bench.{mod}"), fn)


@pytest.mark.parametrize("page", sorted(GENERATED))
def test_a_benchmark_page_is_what_its_command_writes_from_its_json(page):
    mod, fn, src = GENERATED[page]
    bench = REPO / "docs" / "benchmarks"
    data = json.loads((bench / src).read_text())
    render = _renderer(mod, fn)
    text = render(data, data.get("machine", {})) if mod == "e2e" else render(data)
    if page == "validity.md":
        text = _planar_in(text, json.loads((bench / "validity_planar.json").read_text()))
    command = mod if mod.endswith(".py") else f"rackstress bench {mod}"
    assert (bench / page).read_text() == text, (
        f"docs/benchmarks/{page} is not what `{command}` writes from {src}: "
        "regenerate the page with its command, never edit it by hand")


#: a ticket or a work round given as the reason for something
CITED = re.compile(r"\b(?:issues?|rounds?)\s+(?:#\s*)?\d+"
                   r"|\b(?:previous|last|this|earlier|next)\s+rounds?\b"
                   r"|\brounds?\s+(?:one|two|three|four|five|six|seven|eight|nine|ten)\b", re.I)


def test_no_text_cites_a_ticket_or_a_round():
    """A reader of the repository has no tracker: a number's reason is said, not cited."""
    found = []
    for root, pattern in ((REPO, "README.md"), (REPO / "docs", "**/*.md"),
                          (REPO / "workflow", "**/*.py"), (REPO / "tests", "**/*.py"),
                          (REPO / "examples", "**/*"), (REPO / "scripts", "**/*.py")):
        for f in sorted(root.glob(pattern)):
            if not f.is_file() or f.suffix not in (".md", ".py", ".toml", ".txt") \
                    or f.name == Path(__file__).name:
                continue
            for k, line in enumerate(f.read_text(errors="replace").splitlines(), 1):
                if CITED.search(line):
                    found.append(f"{_rel(f)}:{k}: {line.strip()[:100]}")
    names = [_rel(f) for f in (REPO / "tests").glob("*.py") if CITED.search(f.stem.replace("_", " "))
             or re.search(r"round\d", f.stem)]
    assert not found and not names, "\n".join(found + names)
