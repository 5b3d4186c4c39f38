"""``scart-bench report RUN... --out DIR``: the leaderboard (Markdown, CSV, HTML) and figures over runs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scart_bench.cli.common import UsageError


def cmd_report(args: argparse.Namespace) -> int:
    from scart_bench.reports.report import write_report

    seen: dict[Path, Path] = {}
    for run in args.runs:
        key = Path(run).resolve()
        if key in seen:
            raise UsageError(f"{run}: given twice (as {seen[key]} too); each run counts once in a leaderboard")
        seen[key] = Path(run)
    files = write_report(args.runs, args.out, figures=not args.no_figures, defense=args.defense)
    for note in files.notes:
        print(f"note: {note}", file=sys.stderr)
    print(f"{files.markdown}\n{files.csv}\n{files.html}")
    if files.figures:
        print(f"{len(files.figures)} figure(s) in {files.figures[0].parent}", file=sys.stderr)
    return 0


def register(sub) -> None:
    r = sub.add_parser("report", help="leaderboard (Markdown, CSV, self-contained HTML) and figures over runs")
    r.add_argument("runs", nargs="+", type=Path, metavar="RUN", help="run folders (runs/<name>) with metrics.csv")
    r.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for the report files")
    r.add_argument("--no-figures", action="store_true", help="only the tables, no figures")
    r.add_argument("--defense", action="append", default=[], type=Path, metavar="DIR",
                   help="a folder scart-bench defend wrote: its defense table and example flight in the report "
                        "(one in a run folder, RUN/defense.csv or RUN/defense/, is found by itself)")
    r.set_defaults(func=cmd_report)
