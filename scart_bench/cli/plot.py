"""``scart-bench plot FLIGHT_DIR``: the figures of one flight (path, sensor trace, detector scores)."""

from __future__ import annotations

import argparse
from pathlib import Path

from scart_bench.cli.common import UsageError


def cmd_plot(args: argparse.Namespace) -> int:
    from scart_bench.reports.figures import flight_figures

    if args.detector and args.run is None:
        raise UsageError("--detector needs --run RUN (the run folder holding its scores)")
    out = args.out if args.out is not None else Path("figures") / Path(args.flight_dir).resolve().name
    for path in flight_figures(args.flight_dir, out, run=args.run, detectors=args.detector, field=args.field):
        print(path)
    return 0


def register(sub) -> None:
    p = sub.add_parser("plot", help="figures of one flight: path, sensor trace and detector scores")
    p.add_argument("flight_dir", type=Path, metavar="FLIGHT_DIR", help="a flight folder, <dataset>/flights/<id>")
    p.add_argument("--run", type=Path, metavar="RUN", help="a run folder whose saved scores to plot")
    p.add_argument("--detector", action="append", metavar="NAME",
                   help="detector of --run to plot (repeatable; default: every detector that scored the flight)")
    p.add_argument("--field", metavar="TOPIC.FIELD",
                   help="field for the sensor trace (default: the attacked field, else the first sensor column)")
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder (default figures/<flight id>)")
    p.set_defaults(func=cmd_plot)
