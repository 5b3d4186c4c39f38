"""``scart-bench report RUN... --out DIR`` (leaderboard + figures) and ``scart-bench plot FLIGHT_DIR``
(the figures of one flight)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scart_bench.benchmark.errors import UsageError


def cmd_report(args: argparse.Namespace) -> int:
    from scart_bench.reports.report import write_report

    seen: dict[Path, Path] = {}
    for run in args.runs:
        key = Path(run).resolve()
        if key in seen:
            raise UsageError(f"{run}: given twice (as {seen[key]} too); each run counts once in a leaderboard")
        seen[key] = Path(run)
    files = write_report(args.runs, args.out, figures=not args.no_figures)
    for note in files.notes:
        print(f"note: {note}", file=sys.stderr)
    print(f"{files.markdown}\n{files.csv}\n{files.html}")
    if files.figures:
        print(f"{len(files.figures)} figure(s) in {files.figures[0].parent}", file=sys.stderr)
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from scart_bench.reports.figures import flight_figures

    if args.detector and args.run is None:
        raise UsageError("--detector needs --run RUN (the run folder holding its scores)")
    out = args.out if args.out is not None else Path("figures") / Path(args.flight_dir).resolve().name
    for path in flight_figures(args.flight_dir, out, run=args.run, detectors=args.detector, field=args.field):
        print(path)
    return 0


def register(sub) -> None:
    r = sub.add_parser("report", help="leaderboard (Markdown, CSV, self-contained HTML) and figures over runs")
    r.add_argument("runs", nargs="+", type=Path, metavar="RUN", help="run folders (runs/<name>) with metrics.csv")
    r.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for the report files")
    r.add_argument("--no-figures", action="store_true", help="only the tables, no figures")
    r.set_defaults(func=cmd_report)

    p = sub.add_parser("plot", help="figures of one flight: path, sensor trace and detector scores")
    p.add_argument("flight_dir", type=Path, metavar="FLIGHT_DIR", help="a flight folder, <dataset>/flights/<id>")
    p.add_argument("--run", type=Path, metavar="RUN", help="a run folder whose saved scores to plot")
    p.add_argument("--detector", action="append", metavar="NAME",
                   help="detector of --run to plot (repeatable; default: every detector that scored the flight)")
    p.add_argument("--field", metavar="TOPIC.FIELD",
                   help="field for the sensor trace (default: the attacked field, else the first sensor column)")
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder (default figures/<flight id>)")
    p.set_defaults(func=cmd_plot)
