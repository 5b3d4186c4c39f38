"""``scart-bench score RUN``: recompute every metric of a run folder from its saved scores."""

from __future__ import annotations

import argparse

from scart_bench.cli.common import UsageError, name_failed, print_tables, staged_folder


def cmd_score(args: argparse.Namespace) -> int:
    from scart_bench.benchmark.runner import score_run
    from scart_bench.benchmark.store import RunStore

    if args.jobs is not None and args.jobs < 1:
        raise UsageError(f"scart-bench score --jobs {args.jobs}: expected a whole number >= 1")
    with staged_folder(args.run) as run:  # a run folder at a URL: scored in a local copy, uploaded back
        RunStore(run).read_config()  # a damaged config.json is named before anything else
        RunStore(run).verify()  # labels and scores as the run wrote them, or refused (one line naming the file)
        metrics = score_run(run, processes=args.jobs)
        print_tables(run, metrics, shown=str(args.run))
    # as `run` does: tables that look complete must not hide a job without scores
    return name_failed("score", metrics[metrics["status"] != "OK"], "have no usable scores",
                       "their rows show the status (rerun the run with --resume to finish them)")


def register(sub) -> None:
    s = sub.add_parser("score", help="recompute every metric of a run folder from its saved scores")
    s.add_argument("run", metavar="RUN", help="a run folder (runs/<name>) or its fsspec URL")
    s.add_argument("--jobs", type=int, metavar="N",
                   help="detectors scored at a time, each in its own process (default: the run's --jobs); "
                        "the tables are the same for any N")
    s.set_defaults(func=cmd_score)
