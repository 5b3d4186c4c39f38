"""leaderboard.html: one self-contained page (inline CSS, figures as base64 PNG data URIs, no
JavaScript, no network; a Content-Security-Policy forbids scripts and remote loads).

Every string that comes from a run (detector names, plugin specs, config values, messages, file
names) goes through :func:`html.escape`, so a detector called ``<script>...`` is shown as text.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

import pandas as pd

from scart_bench.benchmark.store import to_json
from scart_bench.reports.leaderboard import (
    HEADLINE_DOC,
    RULES_DOC,
    config_link,
    display_table,
    failures,
    transfer_lines,
)
from scart_bench.reports.results import RunResults

CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 2em auto; max-width: 1400px;
       color: #222; padding: 0 1em; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; margin-top: 2em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; font-size: 0.9em; margin: 0.5em 0; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: right; white-space: nowrap; }
th { background: #f3f3f3; } td.name, th.name { text-align: left; white-space: normal; }
tbody tr:nth-child(even) { background: #fafafa; }
td.missing { color: #999; font-style: italic; } td.failed { color: #b00; font-weight: bold; }
p.doc { max-width: 60em; color: #444; } pre { background: #f7f7f7; padding: 0.6em; overflow-x: auto;
font-size: 0.8em; max-height: 30em; } figure { display: inline-block; margin: 0.5em; vertical-align: top; }
div.scroll { overflow-x: auto; } img { max-width: 100%; height: auto; border: 1px solid #eee; } figcaption { font-size: 0.85em; color: #444; }
"""
CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"


def esc(text: object) -> str:
    """HTML-escaped text (quotes too, so it is safe in attributes)."""
    return html.escape(str(text), quote=True)


def data_uri(png: Path) -> str:
    """A PNG file as a data: URI."""
    return "data:image/png;base64," + base64.b64encode(Path(png).read_bytes()).decode("ascii")


def _cell_class(text: str, run_column: bool) -> str:
    if not run_column:
        return ""
    if text == "missing":
        return ' class="missing"'
    return ' class="failed"' if text in ("ERROR", "TIMEOUT", "UNFINISHED") else ""


def leaderboard_table(board: pd.DataFrame, runs: list[RunResults]) -> str:
    head, body = display_table(board, runs)
    at = head.index("Detector")
    first_run = head.index("n runs") + 1
    run_cols = set(range(first_run, first_run + len(runs)))
    out = ['<div class="scroll"><table class="leaderboard"><thead><tr>']
    name = ' class="name"'
    out += [f"<th{name if i == at else ''}>{esc(h)}</th>" for i, h in enumerate(head)]
    out.append("</tr></thead><tbody>")
    for cells in body:
        out.append(f'<tr class="detector" data-detector="{esc(cells[at])}">')
        for i, c in enumerate(cells):
            cls = ' class="name"' if i == at else _cell_class(c, i in run_cols)
            out.append(f"<td{cls}>{esc(c)}</td>")
        out.append("</tr>")
    out.append("</tbody></table></div>")
    return "".join(out)


def runs_table(runs: list[RunResults], out: Path | None) -> str:
    rows = ['<div class="scroll"><table class="runs"><thead><tr><th class="name">Run</th><th class="name">Folder</th><th>Profile</th>'
            '<th>Seed</th><th class="name">Dataset</th><th>Detectors</th><th class="name">Plugins</th>'
            '<th>Git commit</th><th>Updated</th><th class="name">Config</th></tr></thead><tbody>']
    for r in runs:
        c = r.config
        ds = c.get("dataset") or {}
        git = c.get("git") or {}
        commit = f"{str(git.get('commit', ''))[:10]}{' (dirty)' if git.get('dirty') else ''}"
        plugins = ", ".join(map(str, c.get("plugins") or [])) or "none"
        rows.append(
            f'<tr class="run"><td class="name">{esc(r.label)}</td><td class="name">{esc(r.path.resolve())}</td>'
            f"<td>{esc(c.get('profile', ''))}</td><td>{esc(c.get('seed', ''))}</td>"
            f'<td class="name">{esc(ds.get("path", ""))} ({esc(str(ds.get("fingerprint", ""))[:12])})</td>'
            f"<td>{len(r.metrics)}</td><td class=\"name\">{esc(plugins)}</td><td>{esc(commit)}</td>"
            f"<td>{esc(c.get('updated', ''))}</td>"
            f'<td class="name"><a href="{esc(config_link(r, out))}">config.json</a></td></tr>')
    rows.append("</tbody></table></div>")
    for r in runs:
        rows.append(f"<details><summary>config.json of {esc(r.label)} (embedded)</summary>"
                    f"<pre>{esc(to_json(r.config))}</pre></details>")
    return "".join(rows)


def _transfer_html(runs: list[RunResults]) -> list[str]:
    """The transfer runs' section (leaderboard.transfer_lines): bullets and their table."""
    lines = transfer_lines(runs)
    if not lines:
        return []
    parts, rows = [], []
    for line in [*lines, ""]:
        if line.startswith("|"):
            if not line.startswith("|---"):
                rows.append([c.strip() for c in line.strip("|").split(" | ")])
            continue
        if rows:
            head, *body = rows
            parts.append('<div class="scroll"><table><thead><tr>' + "".join(f"<th>{esc(h)}</th>" for h in head)
                         + "</tr></thead><tbody>" + "".join("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r)
                                                           + "</tr>" for r in body) + "</tbody></table></div>")
            rows = []
        if line.startswith("## "):
            parts.append(f"<h2>{esc(line[3:])}</h2>")
        elif line.startswith("- "):
            parts.append(f"<p class=\"doc\">{esc(line[2:])}</p>")
    return parts


def page(board: pd.DataFrame, runs: list[RunResults], figures: list[tuple[str, Path]], out: Path | None,
         notes: list[str] = (), sections: str = "") -> str:
    """The whole leaderboard page; ``sections``: more HTML after the runs (e.g. the defense table)."""
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             f'<meta http-equiv="Content-Security-Policy" content="{esc(CSP)}">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             '<link rel="icon" href="data:,">', "<title>scart-bench leaderboard</title>",
             f"<style>{CSS}</style></head><body>", "<h1>scart-bench leaderboard</h1>",
             f'<p class="doc">{esc(HEADLINE_DOC)}</p>', f'<p class="doc">{esc(RULES_DOC)}</p>',
             leaderboard_table(board, runs),
             f"<h2>Runs ({len(runs)})</h2>", runs_table(runs, out)]
    parts += _transfer_html(runs)
    if sections:
        parts.append(sections)
    fails = failures(runs)
    if fails:
        parts.append("<h2>Failed or unfinished jobs</h2><ul>")
        parts += [f"<li>{esc(run)}: <b>{esc(det)}</b> {esc(status)}: {esc(msg)}</li>"
                  for run, det, status, msg in fails]
        parts.append("</ul>")
    if notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f"<li>{esc(n)}</li>" for n in notes) + "</ul>")
    if figures:
        parts.append("<h2>Figures</h2>")
        parts += [f'<figure><img src="{data_uri(p)}" alt="{esc(cap)}"><figcaption>{esc(cap)}</figcaption></figure>'
                  for cap, p in figures]
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"
