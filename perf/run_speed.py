"""End-to-end wall time and peak memory of a benchmark run, per phase.

    python -m perf.run_speed --profile quick [--detectors all] [--jobs N] [--executor dask]

Phases: preparing the profile's dataset (generated unless it exists; pass ``--dataset`` to skip)
and the run itself (jobs + scoring) into a fresh run folder. Peak memory is the maximum resident
set size from ``resource.getrusage``: of this process (generation and scoring happen here) and of
the largest waited-for child (a job's worker process). Per-job timings come from results.csv.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from datetime import datetime
from pathlib import Path

import pandas as pd

from scart_bench.benchmark.runner import RunConfig, prepare_dataset
from scart_bench.cli.main import main as cli_main
from scart_bench.cli.run import PROFILES


def _peak_mib(who: int) -> float:
    return resource.getrusage(who).ru_maxrss / 1024.0  # ru_maxrss is in KiB on Linux


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.run_speed", description=__doc__.split("\n")[0])
    p.add_argument("--profile", choices=PROFILES, default="quick")
    p.add_argument("--detectors", default="all")
    p.add_argument("--dataset", type=Path, help="an existing dataset (skips the generation phase)")
    p.add_argument("--out", type=Path, help="run folder (default: a new runs/perf/<profile>-seed<N>-<time>)")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--executor", choices=("local", "dask"), default="local")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--timeout", type=float)
    p.add_argument("--plugin", action="append", default=[])
    args = p.parse_args(argv)

    t0 = time.perf_counter()
    dataset = args.dataset or prepare_dataset(RunConfig(profile=args.profile, seed=args.seed))
    t_data = time.perf_counter() - t0
    out = args.out or Path("runs/perf") / f"{args.profile}-seed{args.seed}-{datetime.now():%Y%m%d-%H%M%S}"
    run_args = ["run", "--detectors", args.detectors, "--profile", args.profile, "--dataset", str(dataset),
                "--out", str(out), "--jobs", str(args.jobs), "--executor", args.executor, "--seed", str(args.seed)]
    if args.timeout is not None:
        run_args += ["--timeout", str(args.timeout)]
    for spec in args.plugin:
        run_args += ["--plugin", spec]
    t1 = time.perf_counter()
    rc = cli_main(run_args)
    t_run = time.perf_counter() - t1

    print(f"\nprofile {args.profile}, seed {args.seed}, {args.jobs} job(s), executor {args.executor}: exit {rc}")
    print(f"  dataset   {t_data:9.1f} s  ({dataset})")
    print(f"  run       {t_run:9.1f} s  ({out})")
    print(f"  total     {t_data + t_run:9.1f} s")
    print(f"  peak RSS  {_peak_mib(resource.RUSAGE_SELF):9.0f} MiB this process, "
          f"{_peak_mib(resource.RUSAGE_CHILDREN):.0f} MiB largest child")
    results = out / "results.csv"
    if results.exists():
        cols = ["detector", "status", "fit_s", "score_s", "rows", "latency_us_per_row", "max_rss_mb", "wall_s"]
        with pd.option_context("display.width", 160, "display.float_format", "{:.2f}".format):
            print(pd.read_csv(results)[cols].to_string(index=False))
    return rc


if __name__ == "__main__":
    sys.exit(main())
