"""``BATCHDIR/report.html``: one page to look at a batch (``rackstress batch``).

The sweep table (every job: its swept parameters, status, the overall peak of the stress
measure with its part, iteration and particle, wall time, a link to the job's own
``report.html``), the peak plotted against each swept parameter (``report-peak-vs-NAME.png``,
one line per combination of the other parameters, diverged, not settled or failed jobs dotted; drawn by
:func:`rackstress.runs.batch.report`), the jobs' errors and the batch's passes. The numbers are
those of each job's ``summary.json`` (``stress.peak``). Self-contained as a folder (relative
links), no script; written atomically.
"""
from __future__ import annotations

import html
import json
import os
import time
from pathlib import Path

REPORT = "report.html"
#: The figure the batch report plots: the overall peak of a job (summary.json).
PEAK = "stress.peak.value"
CSS = """
body{font-family:DejaVu Sans,Helvetica,Arial,sans-serif;margin:1.5em auto;max-width:1200px;
color:#222;padding:0 1em}h1{font-size:1.6em}h2{font-size:1.25em;border-bottom:1px solid #ccc;
margin-top:1.6em}table{border-collapse:collapse;font-size:.92em}td,th{border:1px solid #ccc;
padding:.25em .6em;text-align:left}th{background:#f0f0f0}td.num{text-align:right;
font-variant-numeric:tabular-nums}img{max-width:100%;border:1px solid #ddd}
.note{color:#666;font-size:.9em}.ok{color:#060}.bad{color:#b00}
"""


def _e(x) -> str:
    return html.escape(str(x), quote=True)


def _num(v) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def write_batch_report(batchdir) -> Path:
    """Write ``BATCHDIR/report.html`` from ``batch.json`` and the jobs' directories.

    Parameters
    ----------
    batchdir : path
        A batch directory (``rackstress batch SWEEP --out BATCHDIR``), finished or not.

    Returns
    -------
    Path
        The page.

    Example
    -------
    >>> write_batch_report("batches/plane-rack-6")          # doctest: +SKIP
    PosixPath('batches/plane-rack-6/report.html')
    """
    from rackstress.runs.batch import INDEX, report

    batchdir = Path(batchdir)
    index = json.loads((batchdir / INDEX).read_text())
    jobs = index["jobs"]
    swept = list(index.get("swept") or [])
    summaries = {}
    for j in jobs:
        try:
            summaries[j["name"]] = json.loads((batchdir / j["dir"] / "summary.json").read_text())
        except (OSError, json.JSONDecodeError):
            summaries[j["name"]] = {}
    has_peak = any(((s.get("stress") or {}).get("peak") or {}).get("value") is not None
                   for s in summaries.values())
    plots, rows, notes = [], {}, []
    for name in swept:
        try:
            rec = report(batchdir, PEAK if has_peak else None, name, log=lambda *_: None)
        except Exception as exc:  # noqa: BLE001 - the table is still worth having
            notes.append(f"no plot against {name}: {exc}")
            continue
        safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in name)
        dest = batchdir / f"report-peak-vs-{safe}.png"
        os.replace(rec["plot"], dest)
        plots.append((name, dest.name, rec["figure"]))
        rows = {r["name"]: r for r in rec["rows"]}

    out = []
    w = out.append
    title = index.get("name") or batchdir.name
    w("<!DOCTYPE html>")
    w('<html lang="en"><head><meta charset="utf-8">')
    w(f"<title>rackstress batch: {_e(title)}</title><style>{CSS}</style></head><body>")
    w(f"<h1>{_e(title)}: batch report</h1>")
    counts = ", ".join(f"{v} {k}" for k, v in sorted((index.get("counts") or {}).items()))
    w(f'<p id="summary">Scene <b>{_e(index.get("scene"))}</b>, {len(jobs)} jobs ({_e(counts)})'
      f"{'' if index.get('complete') else ' — <b>not complete</b>: run the same command again'}"
      f"; swept: {_e(', '.join(swept) or 'nothing')}. Sweep file: "
      f'<a href="sweep.toml">sweep.toml</a>; index: <a href="{INDEX}">{INDEX}</a>.</p>')
    w(f'<p class="note">{_e(batchdir.resolve())} — written '
      f"{_e(time.strftime('%Y-%m-%d %H:%M:%S'))}</p>")

    w('<h2 id="jobs">The sweep</h2>')
    w('<table id="sweep"><thead><tr><th>job</th>'
      + "".join(f"<th>{_e(k)}</th>" for k in swept)
      + "<th>status</th><th>peak</th><th>units</th><th>part</th><th>iteration</th>"
      "<th>particle</th><th>wall [s]</th><th>report</th></tr></thead><tbody>")
    for j in jobs:
        s = summaries[j["name"]]
        pk = (s.get("stress") or {}).get("peak") or {} if j["status"] == "ok" else {}
        eff = rows.get(j["name"]) or {}
        params = [eff.get(k, j["params"].get(k)) for k in swept]
        rel = f"{j['dir']}/{REPORT}"
        link = (f'<a href="{_e(rel)}">report</a>' if (batchdir / rel).is_file() else "–")
        cls = "ok" if j["status"] == "ok" else "bad"
        value = pk.get("value")
        w(f'<tr data-job="{_e(j["name"])}" data-status="{_e(j["status"])}"'
          + (f' data-peak="{value!r}"' if value is not None else "") + ">"
          f'<td><a href="{_e(j["dir"])}/">{_e(j["name"])}</a></td>'
          + "".join(f"<td class=num>{_e(_num(v))}</td>" for v in params)
          + f'<td class="{cls}">{_e(j["status"])}</td><td class=num>{_e(_num(value))}</td>'
          f"<td>{_e(pk.get('units', ''))}</td><td>{_e(pk.get('group', ''))}</td>"
          f"<td class=num>{_e(_num(pk.get('iteration')))}</td>"
          f"<td class=num>{_e(_num(pk.get('particle')))}</td>"
          f"<td class=num>{_e(_num(j.get('wall_s')))}</td><td>{link}</td></tr>")
    w("</tbody></table>")
    w('<p class="note">peak: the largest value of the stress measure over each run and its '
      "coloured parts (<code>summary.json</code> → <code>stress.peak</code>, the same number "
      "as the job's report and pictures); a job with no report was run with "
      "<code>--no-render</code> (<code>rackstress render BATCHDIR/JOB</code> makes one).</p>")

    w('<h2 id="plots">The peak against each swept parameter</h2>')
    for name, fname, figure in plots:
        w(f'<figure><img src="{_e(fname)}" alt="{_e(figure)} against {_e(name)}" '
          f'data-against="{_e(name)}"><figcaption>{_e(figure)} against {_e(name)} (dotted: '
          "diverged, not settled or failed jobs)</figcaption></figure>")
    for note in notes:
        w(f'<p class="note">{_e(note)}</p>')

    errs = [j for j in jobs if j.get("error")]
    if errs:
        w('<h2 id="errors">Jobs that did not finish well</h2><ul>')
        for j in errs:
            w(f"<li><b>{_e(j['name'])}</b> ({_e(j['status'])}): {_e(j['error'])}</li>")
        w("</ul>")
    w('<h2 id="passes">Passes</h2><table id="passes-table"><thead><tr><th>started</th>'
      "<th>ended</th><th>ranks</th><th>ranks per job</th><th>jobs run</th><th>wall [s]</th>"
      "</tr></thead><tbody>")
    for p in index.get("passes") or []:
        w(f"<tr><td>{_e(p.get('started'))}</td><td>{_e(p.get('ended') or '–')}</td>"
          f"<td class=num>{_e(p.get('ranks'))}</td><td class=num>{_e(p.get('ranks_per_job'))}</td>"
          f"<td class=num>{_e(p.get('jobs_run'))}</td>"
          f"<td class=num>{_e(_num(p.get('wall_s')))}</td></tr>")
    w("</tbody></table></body></html>")
    path = batchdir / REPORT
    tmp = batchdir / f".{REPORT}.tmp{os.getpid()}"
    tmp.write_text("\n".join(out) + "\n", encoding="utf-8")
    os.replace(tmp, path)
    return path
