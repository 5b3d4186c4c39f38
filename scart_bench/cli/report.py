"""``scart-bench report RUN... --out DIR``: the leaderboard (Markdown, CSV, HTML) and figures over runs."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

from scart_bench.cli.common import UsageError, aligned, staged_folder


def cmd_report(args: argparse.Namespace) -> int:
    from scart_bench.reports.report import write_report
    from scart_bench.storage import is_url, local_path

    seen: dict[object, str] = {}
    for run in args.runs:
        key = run.rstrip("/") if is_url(run) else local_path(run).resolve()
        if key in seen:
            raise UsageError(f"{run}: given twice (as {seen[key]} too); each run counts once in a leaderboard")
        seen[key] = run
    with contextlib.ExitStack() as stack:  # runs and the report at URLs: local copies, the report uploaded
        runs = [stack.enter_context(staged_folder(r, write=False)) for r in args.runs]
        out = stack.enter_context(staged_folder(args.out))
        files = write_report(runs, out, figures=not args.no_figures, defense=args.defense)
        def shown(p) -> str:  # the URL's name for a file of the uploaded report
            return str(p).replace(str(out), str(args.out).rstrip("/"), 1) if is_url(args.out) else str(p)

        for note in files.notes:
            print(f"note: {note}", file=sys.stderr)
        print(files.terminal(wide=True) if args.wide else aligned(files.terminal()) + "\n")
        print(f"{shown(files.markdown)}\n{shown(files.csv)}\n{shown(files.html)}")
        if files.figures:
            print(f"{len(files.figures)} figure(s) in {shown(files.figures[0].parent)}", file=sys.stderr)
    return 0


def register(sub) -> None:
    r = sub.add_parser("report", help="leaderboard (Markdown, CSV, self-contained HTML) and figures over runs")
    r.add_argument("runs", nargs="+", metavar="RUN", help="run folders (runs/<name>) with metrics.csv, or their "
                   "fsspec URLs")
    r.add_argument("--out", required=True, metavar="DIR|URL", help="folder for the report files, or an fsspec URL "
                   "(written locally, then uploaded)")
    r.add_argument("--no-figures", action="store_true", help="only the tables, no figures")
    r.add_argument("--wide", action="store_true", help="print every column of the leaderboard (leaderboard.md's), "
                   "not the terminal's seven")
    r.add_argument("--defense", action="append", default=[], type=Path, metavar="DIR",
                   help="a folder scart-bench defend wrote: its defense table and example flight in the report "
                        "(one in a run folder, RUN/defense.csv or RUN/defense/, is found by itself)")
    r.set_defaults(func=cmd_report)
