"""Figures quoted in the documentation, checked against the JSON their benchmark wrote.

A page quotes a measured figure with a mark right after it, an HTML comment (invisible on the
site, plain in the Markdown)::

    magpod on the plugin, one rank: 0.102<!-- fig perf.json row(d.rows, scene="magpod",
    kernels="plugin", ranks=1, particles="active only").ms_per_it --> ms an iteration

``fig FILE EXPR``: FILE is the benchmark's JSON, relative to the page (as a Markdown link is);
EXPR is an expression over its data ``d``: ``d.key`` or ``d["key with spaces"]``, ``[n]``,
arithmetic (``+ - * /``, numbers), a list comprehension (``[r.a / r.b for s in d.x for r in
s.rows]``), and ``row(list, key=value, …)`` (the first dict of ``list``
whose keys have those values), ``col(list, key)`` (every dict's value of ``key``), ``min``,
``max``, ``abs``, ``len``, ``sum``. The figure is the
number just before the mark (``0.102``, ``33,689``, ``1.5e-3``, ``**1.89**``); it agrees when the
expression's value rounds to it at the figure's own precision (its decimals, or its significant
digits in ``e`` notation). ``tests/test_figures.py`` checks every mark of README.md and docs/, and
that no hand-written page quotes a figure without one.

A number that is not measured — a setting of a scene (a spacing, a load), a target, a material's
datum, a hand calculation or an analytical answer — says so instead, with its reason, its mark
right after the number as a ``fig`` mark is::

    pulled by 50<!-- given: the scene's load --> N at the far hole

A figure a test compares with a command's own output (a tutorial's printed peak, say) names
that test instead: ``<!-- checked: tests/test_readme.py::test_name -->``; the test must exist.

``given: WHY``: the reason is required. A measured figure with no benchmark JSON behind it has
no mark at all and fails: link the page its command writes, or make a command write it.

    .venv/bin/python tests/figures.py docs/benchmarks/index.md     # each mark: quoted, value
"""
from __future__ import annotations

import ast
import json
import math
import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: a number, bold or not, then its mark
MARK = re.compile(r"(?P<fig>[-+−]?\d[\d,]*(?:\.\d+)?(?:[eE][-+]?\d+)?)(?P<bold>\**)"
                  r"<!--\s*fig\s+(?P<file>\S+)\s+(?P<expr>.*?)\s*-->", re.S)

#: what counts as a figure on a hand-written page: a number followed by a unit of time, memory,
#: stress, length, force, frequency or speed, a ratio (``×``) or a percentage. Each carries a
#: ``fig`` or a ``given`` mark; pages a benchmark command writes are checked whole instead
#: (test_figures.py).
MEASURED = re.compile(r"(?<![\w.])\d[\d,]*(?:\.\d+)?(?:[eE][-+]?\d+)?\**\s?"
                      r"(?:ms|µs|s|MB|GB|GiB|MiB|×|%|GPa|MPa|kPa|Pa|mm|µm|m/s|mm/s|Hz|kHz|kN|N)"
                      r"(?![\w/])")
#: a figure a named test compares with a command's output (module doc)
CHECKED_BY = re.compile(r"[-+−]?\d[\d,]*(?:\.\d+)?(?:[eE][-+]?\d+)?\**"
                        r"<!--\s*checked:\s*(?P<file>tests/\S+?\.py)::(?P<test>\w+)\s*-->")
#: a number that is not measured, and why (module doc)
GIVEN = re.compile(r"[-+−]?\d[\d,]*(?:\.\d+)?(?:[eE][-+]?\d+)?\**<!--\s*given:\s*\S.*?-->")


def _row(seq, **match):
    for r in seq:
        if isinstance(r, dict) and all(r.get(k) == v for k, v in match.items()):
            return r
    raise KeyError(f"no row with {match}")


_OPS = {ast.Add: lambda a, b: a + b, ast.Sub: lambda a, b: a - b,
        ast.Mult: lambda a, b: a * b, ast.Div: lambda a, b: a / b}
def _col(seq, key):
    return [r[key] for r in seq if isinstance(r, dict) and r.get(key) is not None]


_CMP = {ast.Eq: lambda a, b: a == b, ast.NotEq: lambda a, b: a != b,
        ast.Lt: lambda a, b: a < b, ast.Gt: lambda a, b: a > b}
_FUNCS = {"row": _row, "col": _col, "min": min, "max": max, "abs": abs, "len": len, "sum": sum}


def evaluate(expr: str, data):
    """``expr`` (module doc) over ``data`` (the JSON, as ``d``)."""
    def ev(n, env):
        if isinstance(n, ast.Expression):
            return ev(n.body, env)
        if isinstance(n, ast.Constant) and isinstance(n.value, (int, float, str)):
            return n.value
        if isinstance(n, ast.Name) and n.id in env:
            return env[n.id]
        if isinstance(n, ast.Attribute):
            return ev(n.value, env)[n.attr]
        if isinstance(n, ast.Subscript):
            return ev(n.value, env)[ev(n.slice, env)]
        if isinstance(n, ast.UnaryOp) and isinstance(n.op, ast.USub):
            return -ev(n.operand, env)
        if isinstance(n, ast.BinOp) and type(n.op) in _OPS:
            return _OPS[type(n.op)](ev(n.left, env), ev(n.right, env))
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id in _FUNCS:
            return _FUNCS[n.func.id](*[ev(a, env) for a in n.args],
                                     **{k.arg: ev(k.value, env) for k in n.keywords})
        if isinstance(n, (ast.List, ast.Tuple)):
            return [ev(e, env) for e in n.elts]
        if isinstance(n, ast.ListComp):       # [expr for x in list for y in x.rows if …]
            out = []

            def walk(k, local):
                if k == len(n.generators):
                    out.append(ev(n.elt, local))
                    return
                g = n.generators[k]
                if not isinstance(g.target, ast.Name):
                    raise ValueError("a comprehension's variable must be a plain name")
                for item in ev(g.iter, local):
                    inner = {**local, g.target.id: item}
                    if all(ev(c, inner) for c in g.ifs):
                        walk(k + 1, inner)
            walk(0, env)
            return out
        if isinstance(n, ast.Compare) and len(n.ops) == 1 and type(n.ops[0]) in _CMP:
            return _CMP[type(n.ops[0])](ev(n.left, env), ev(n.comparators[0], env))
        raise ValueError(f"not allowed in a figure's expression: {ast.dump(n)[:60]}")

    return ev(ast.parse(expr.replace("\n", " "), mode="eval"), {"d": data})


def agrees(quoted: str, value) -> bool:
    """Whether ``value`` rounds to the ``quoted`` figure at the figure's own precision."""
    text = quoted.replace(",", "").replace("−", "-")
    q = float(text)
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        return False
    if "e" in text.lower():
        mant = text.lower().split("e")[0].lstrip("+-")
        digits = len(mant.replace(".", "").lstrip("0")) or 1
        return q == float(f"{value:.{digits - 1}e}")
    decimals = len(text.split(".")[1]) if "." in text else 0
    return abs(value - q) <= 0.5 * 10.0 ** -decimals * (1 + 1e-9)


def _outside_code(text: str) -> str:
    """``text`` with its fenced code blocks blanked (their lines kept, empty): an example of a
    mark shown as code is no mark."""
    lines, fenced = text.split("\n"), False
    for k, line in enumerate(lines):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            lines[k] = ""
        elif fenced:
            lines[k] = ""
    return "\n".join(lines)


def marks(page: Path) -> list[dict]:
    """Every mark of a page: the figure, the file, the expression, the value, agreement."""
    out = []
    text = _outside_code(page.read_text())
    for m in MARK.finditer(text):
        line = text.count("\n", 0, m.start()) + 1
        rec = {"line": line, "figure": m["fig"], "file": m["file"], "expr": m["expr"]}
        src = (page.parent / m["file"]).resolve()
        try:
            rec["value"] = evaluate(m["expr"], json.loads(src.read_text()))
            rec["ok"] = agrees(m["fig"], rec["value"])
        except (OSError, ValueError, KeyError, IndexError, TypeError, SyntaxError,
                ZeroDivisionError) as exc:
            rec["value"], rec["ok"] = f"{type(exc).__name__}: {exc}", False
        out.append(rec)
    return out


def unmarked(page: Path) -> list[tuple[int, str]]:
    """Measured figures (:data:`MEASURED`) of a page that carry no mark, outside code blocks
    (commands and program output, which their own tests check)."""
    found, fenced = [], False
    for k, line in enumerate(page.read_text().splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            continue
        bare = CHECKED_BY.sub("", GIVEN.sub("", MARK.sub("", line)))
        bare = re.sub(r"<!--.*?-->", "", bare)
        bare = re.sub(r"`[^`]*`", "", bare)          # inline code: options, file names
        for m in MEASURED.finditer(bare):
            found.append((k, m.group(0)))
    return found


def named_tests(page: Path) -> list[tuple[int, str, bool]]:
    """Each ``checked:`` mark of a page: its line, the test, whether that test exists."""
    out = []
    text = _outside_code(page.read_text())
    for m in CHECKED_BY.finditer(text):
        src = REPO / m["file"]
        ok = src.is_file() and re.search(rf"^def {m['test']}\(", src.read_text(), re.M) is not None
        out.append((text.count("\n", 0, m.start()) + 1, f"{m['file']}::{m['test']}", ok))
    return out


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        for r in marks(Path(arg)):
            print(f"{arg}:{r['line']}: {r['figure']} {'==' if r['ok'] else '!='} "
                  f"{r['value']!r}  ({r['file']}: {r['expr']})")
        for k, name, ok in named_tests(Path(arg)):
            if not ok:
                print(f"{arg}:{k}: names {name}, which does not exist")
        for k, fig in unmarked(Path(arg)):
            print(f"{arg}:{k}: {fig} has no mark")
