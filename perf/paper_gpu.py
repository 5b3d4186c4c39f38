"""The paper profile end to end on one GPU machine, phase by phase (issue 51's ten-minute target).

    python -m perf.paper_gpu [--profile paper] [--seed 0] [--gen-jobs N] [--jobs 8] [--device cuda]
                             [--score-shards 1] [--out DIR] [--target-s 600]

Phases, each timed on the wall clock and in the CPU seconds of this process and its children:

1. generation: ``scart-bench generate --executor dask --jobs <gen-jobs>`` (default: every core), so
   that normal, simulation-mode and csv-mode batches are flown on all the machine's cores at once
   (the local executor runs csv mode in one process, the paper profile's long pole);
2. the run: ``scart-bench run --detectors all --device cuda --jobs <jobs>``, every torch detector on
   the GPU with batched scoring (``score_batch_size``), the CPU detectors beside them.

It prints the machine (cores, GPU, torch and CUDA versions), the phases, every job's fit and score
seconds and peak memory from the run's ``results.csv``, the total against ``--target-s`` and the
run's headline table, so that one call on a lent machine gives every figure docs/scaling.md needs.
``--profile quick --device cpu`` checks the script on any machine in a few minutes. Without a CUDA
device and with ``--device cuda`` it stops before generating anything (exit 2).
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from perf.generate_speed import cpu_seconds
from scart_bench.cli.main import main as cli_main
from scart_bench.cli.run import PROFILES


def machine_line(device: str) -> str:
    """Cores, GPU and library versions, for the figures' header."""
    import torch

    gpu = "no CUDA device"
    if torch.cuda.is_available():
        props = torch.cuda.get_device_properties(0)
        gpu = f"{props.name} ({props.total_memory / 2**30:.0f} GiB), {torch.cuda.device_count()} device(s)"
    return (f"{os.cpu_count()} cores, {gpu}; Python {platform.python_version()}, torch {torch.__version__}"
            f" (CUDA {torch.version.cuda}); detectors on {device}")


def timed(label: str, argv: list[str], phases: list[tuple[str, float, float, int]]) -> int:
    """Run one scart-bench command, record its wall and CPU seconds under ``label``."""
    print(f"== {label}: scart-bench {' '.join(argv)}", flush=True)
    w0, c0 = time.perf_counter(), cpu_seconds()
    rc = cli_main(argv)
    phases.append((label, time.perf_counter() - w0, cpu_seconds() - c0, rc))
    return rc


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.paper_gpu", description=__doc__.split("\n")[0])
    p.add_argument("--profile", choices=PROFILES, default="paper")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gen-jobs", type=int, default=os.cpu_count() or 1, help="dask workers of the generation")
    p.add_argument("--jobs", type=int, default=8, help="detector jobs at a time")
    p.add_argument("--device", choices=("cuda", "cpu", "auto"), default="cuda")
    p.add_argument("--score-shards", type=int, default=1)
    p.add_argument("--out", type=Path, help="folder for the dataset and the run (default: a temp folder, removed)")
    p.add_argument("--target-s", type=float, default=600.0, help="the wall time aimed at (default 10 min)")
    args = p.parse_args(argv)

    if args.device == "cuda":
        import torch

        if not torch.cuda.is_available():
            print("perf.paper_gpu: --device cuda, but torch sees no CUDA device on this machine "
                  "(pass --device cpu to check the script here)", file=sys.stderr)
            return 2
    print(machine_line(args.device), flush=True)
    root = args.out or Path(tempfile.mkdtemp(prefix="scart-paper-gpu-"))
    dataset, run = root / f"{args.profile}-seed{args.seed}", root / "run"
    phases: list[tuple[str, float, float, int]] = []
    try:
        rc = timed("generate", ["generate", "--profile", args.profile, "--seed", str(args.seed), "--out",
                                str(dataset), "--executor", "dask", "--jobs", str(args.gen_jobs), "--overwrite"],
                   phases)
        if rc == 0:
            rc = timed("run", ["run", "--profile", args.profile, "--dataset", str(dataset), "--detectors", "all",
                               "--device", args.device, "--jobs", str(args.jobs), "--score-shards",
                               str(args.score_shards), "--seed", str(args.seed), "--out", str(run)], phases)
        report(phases, run, args)
    finally:
        if args.out is None:
            shutil.rmtree(root, ignore_errors=True)
    return rc


def report(phases: list[tuple[str, float, float, int]], run: Path, args: argparse.Namespace) -> None:
    """The phases, the jobs and the total against the target."""
    print(f"\n{args.profile} profile, seed {args.seed}: generation on {args.gen_jobs} dask workers, "
          f"{args.jobs} detector jobs on {args.device}")
    print(f"{'phase':<10} {'wall s':>9} {'CPU s':>9}  exit")
    for label, wall, cpu, rc in phases:
        print(f"{label:<10} {wall:9.1f} {cpu:9.1f}  {rc}")
    total = sum(w for _, w, _, _ in phases)
    verdict = "within" if total <= args.target_s else "over"
    print(f"{'total':<10} {total:9.1f} {sum(c for _, _, c, _ in phases):9.1f}  "
          f"({verdict} the {args.target_s:.0f} s target)")
    results = run / "results.csv"
    if results.exists():
        cols = ["detector", "status", "fit_s", "score_s", "rows", "latency_us_per_row", "max_rss_mb", "wall_s"]
        table = pd.read_csv(results)
        with pd.option_context("display.width", 160, "display.float_format", "{:.2f}".format):
            print(table[[c for c in cols if c in table.columns]].to_string(index=False))
    metrics = run / "metrics.csv"
    if metrics.exists():
        table = pd.read_csv(metrics)
        cols = [c for c in ("detector", "tp_simulation", "tp_csv", "tn_no_attack", "roc_auc") if c in table.columns]
        with pd.option_context("display.width", 160, "display.float_format", "{:.3f}".format):
            print(table[cols].to_string(index=False))


if __name__ == "__main__":
    sys.exit(main())
