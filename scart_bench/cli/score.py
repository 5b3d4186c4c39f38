"""``scart-bench score RUN``: recompute every metric of a run folder from its saved scores; with
``--alpha`` / ``--burn-in``, evaluate the saved scores at another operating point instead (into
``RUN/evaluations/<name>/``, no job run, the run's own tables untouched)."""

from __future__ import annotations

import argparse

from scart_bench.cli.common import UsageError, name_failed, print_tables, staged_folder
from scart_bench.cli.run import add_phase_options


def _operating_point(run, args: argparse.Namespace):
    """The run's protocol with ``--alpha`` and ``--burn-in`` applied (RunError naming a refused value)."""
    from scart_bench.benchmark.protocol import Protocol
    from scart_bench.benchmark.store import RunStore
    from scart_bench.cli.run import protocol_options

    run_protocol = Protocol.from_dict(RunStore(run).read_config()["identity"]["protocol"])
    if args.alpha is not None and run_protocol.alarm_rule == "own":
        raise UsageError(f"scart-bench score --alpha {args.alpha:g}: {args.run} uses each detector's own alarm "
                         "rule (--threshold own), which states no alpha; expected a run with calibrated thresholds")
    return protocol_options(run_protocol, args)


def cmd_score(args: argparse.Namespace) -> int:
    from scart_bench.benchmark.results import evaluate_run, evaluation_name, score_run
    from scart_bench.benchmark.store import RunStore

    if args.jobs is not None and args.jobs < 1:
        raise UsageError(f"scart-bench score --jobs {args.jobs}: expected a whole number >= 1")
    with staged_folder(args.run) as run:  # a run folder at a URL: scored in a local copy, uploaded back
        RunStore(run).read_config()  # a damaged config.json is named before anything else
        RunStore(run).verify()  # labels and scores as the run wrote them, or refused (one line naming the file)
        if all(getattr(args, k) is None for k in ("alpha", "burn_in", "phases", "phase_margin", "hourly_rate")):
            metrics = score_run(run, processes=args.jobs)
            print_tables(run, metrics, shown=str(args.run), wide=args.wide)
        else:
            protocol = _operating_point(run, args)
            parts = [] if args.hourly_rate is None else [f"hourly-{args.hourly_rate:g}"]
            moved = any(getattr(args, k) is not None for k in ("alpha", "burn_in", "phases", "phase_margin"))
            name = "-".join([evaluation_name(args.alpha, args.burn_in, protocol.phases if (
                args.phases is not None or args.phase_margin is not None) else None, args.phase_margin)] * moved
                + parts)
            _, metrics = evaluate_run(run, protocol, name, processes=args.jobs)
            print_tables(run, metrics, shown=f"{str(args.run).rstrip('/')}/evaluations/{name}",
                         label="evaluation folder", wide=args.wide)
    # as `run` does: tables that look complete must not hide a job without scores
    return name_failed("score", metrics[metrics["status"] != "OK"], "have no usable scores",
                       "their rows show the status (rerun the run with --resume to finish them)")


def register(sub) -> None:
    s = sub.add_parser("score", help="recompute every metric of a run folder from its saved scores, or evaluate "
                                     "them at another operating point (--alpha, --burn-in)")
    s.add_argument("run", metavar="RUN", help="a run folder (runs/<name>) or its fsspec URL")
    s.add_argument("--wide", action="store_true", help="print every column of the paper's table (metrics.md's), "
                   "not the terminal's seven")
    s.add_argument("--jobs", type=int, metavar="N",
                   help="detectors scored at a time, each in its own process (default: the run's --jobs); "
                        "the tables are the same for any N")
    s.add_argument("--alpha", type=float, metavar="RATE",
                   help="evaluate the saved scores at this target per-flight false-alarm rate: thresholds "
                        "recalibrated on the saved validation scores, tables written into "
                        "RUN/evaluations/alpha-RATE/ (no job is run; the run's own tables stay as they are)")
    s.add_argument("--burn-in", type=float, metavar="SECONDS", dest="burn_in",
                   help="with or without --alpha: evaluate with this burn-in after arming instead of the run's "
                        "(folder RUN/evaluations/[alpha-RATE-]burnin-SECONDS/)")
    add_phase_options(s)
    s.set_defaults(func=cmd_score)
