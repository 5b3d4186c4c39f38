"""``scart-bench run`` (run or resume a benchmark) and ``scart-bench score RUN`` (recompute metrics)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

#: Dataset profiles (kept here so that building the parser imports nothing heavy).
PROFILES = ("quick", "standard", "paper")


def _print_table(path: Path, metrics) -> None:
    from scart_bench.benchmark.runner import paper_table

    print(paper_table(metrics))
    failed = metrics[metrics["status"] != "OK"]
    for _, r in failed.iterrows():
        print(f"{r['detector']}: {r['status']}: {r['message']}", file=sys.stderr)
    print(f"\nrun folder: {path} (metrics.csv, metrics.md, breakdown.csv)", file=sys.stderr)


def cmd_run(args: argparse.Namespace) -> int:
    from scart_bench.benchmark.runner import RunConfig, run_benchmark

    cfg = RunConfig(
        detectors=[args.detectors], profile=args.profile, dataset=args.dataset, out=args.out,
        resume=args.resume, executor=args.executor, scheduler=args.scheduler, jobs=args.jobs,
        timeout=args.timeout, seed=args.seed, plugins=list(args.plugin or []),
    )
    outcome = run_benchmark(cfg)
    _print_table(outcome.path, outcome.metrics)
    return 0


def cmd_score(args: argparse.Namespace) -> int:
    from scart_bench.benchmark.runner import score_run

    metrics = score_run(args.run)
    _print_table(Path(args.run), metrics)
    return 0


def register(sub) -> None:
    r = sub.add_parser("run", help="train and score detectors on a dataset; print and save the tables")
    r.add_argument("--detectors", default="all", metavar="all|NAME,...",
                   help="detectors to run: 'all' (default) or a comma-separated list of names")
    r.add_argument("--profile", choices=PROFILES, default="quick",
                   help="dataset size profile (default quick); sets the default dataset, run folder and timeout")
    r.add_argument("--dataset", type=Path, metavar="DIR",
                   help="an existing dataset folder (default: data/datasets/<profile>-seed<N>, generated when missing)")
    r.add_argument("--out", type=Path, metavar="DIR", help="run folder (default runs/<profile>-seed<N>)")
    r.add_argument("--resume", action="store_true",
                   help="keep jobs that finished OK with the same parameters; run only the others")
    r.add_argument("--executor", choices=("local", "dask"), default="local",
                   help="local worker processes (default) or dask.distributed")
    r.add_argument("--scheduler", metavar="ADDRESS",
                   help="dask scheduler address, e.g. tcp://host:8786 (default: a LocalCluster with --jobs workers)")
    r.add_argument("--jobs", type=int, default=1, metavar="N", help="jobs run in parallel (default 1)")
    r.add_argument("--timeout", type=float, metavar="SECONDS",
                   help="per-job limit; a job past it is killed and reported TIMEOUT "
                        "(default 1800 quick, 7200 standard, 21600 paper)")
    r.add_argument("--seed", type=int, default=0, help="dataset and detector seed (default 0)")
    r.add_argument("--plugin", action="append", metavar="SPEC",
                   help="load a detector from module:Class or path/to/file.py:Class (repeatable)")
    r.set_defaults(func=cmd_run)

    s = sub.add_parser("score", help="recompute every metric of a run folder from its saved scores")
    s.add_argument("run", type=Path, metavar="RUN", help="a run folder (runs/<name>)")
    s.set_defaults(func=cmd_score)
