"""What the command modules share: the command line's own error (bad options, one line, exit code 2),
the progress log and the options several commands take.

Library code raises the errors of :mod:`scart_bench.errors`; ``UsageError`` is for the CLI modules.
"""

from __future__ import annotations

import sys
from pathlib import Path

from scart_bench.errors import ScartBenchError


class UsageError(ScartBenchError):
    """Bad command-line input (unknown name, missing file, conflicting options)."""


#: scart_bench.dataset.LAYOUTS, spelled out here so that the command line starts without pandas
LAYOUTS = ("compact", "paper")
LAYOUT_HELP = ("compact (one Parquet file per view per flight; the default for Parquet) | paper (the paper's "
               "per-topic and combined files; the default for CSV)")


def log(msg: str) -> None:
    """A progress line on stderr (stdout keeps the command's result)."""
    print(msg, file=sys.stderr, flush=True)


def check_seed(seed: int) -> int:
    """``--seed``: numpy's seed sequences take any non-negative integer, but 32 bits are what every
    consumer (torch included) accepts; refuse the rest up front, naming the option."""
    if not 0 <= seed < 2**32:
        raise UsageError(f"--seed {seed}: expected an integer in 0..{2**32 - 1}")
    return seed


def topic_list(text: str | None) -> list[str] | None:
    """``--topics a,b``: the names, or None for all."""
    return [t.strip() for t in text.split(",") if t.strip()] if text else None


#: Exit status of ``scart-bench run`` when a job ended ERROR or TIMEOUT (the run is written).
EXIT_JOBS_FAILED = 3


def print_tables(path: Path, metrics) -> None:
    """The paper table and the operating-point lines of a run (stdout); failed jobs and the folder (stderr)."""
    from scart_bench.benchmark.results import paper_table, transfer_summary
    from scart_bench.benchmark.scoring import rate_summary
    from scart_bench.benchmark.store import RunStore

    config = RunStore(path).read_config()
    train = (config.get("train_dataset") or {}).get("path")
    if train:  # a transfer run: where each number comes from, above the table
        print(f"Trained and calibrated on {train} (thresholds); TP and TN on {config['dataset'].get('path')}")
    print(paper_table(metrics))
    no_effect = (config.get("dataset") or {}).get("no_effect") or []
    print("\n".join(line for line in rate_summary(metrics, no_effect) if line.startswith("- ")))
    if train:
        print("\n".join(line for line in transfer_summary(config, metrics) if line.startswith(("- ", "|"))))
    failed = metrics[metrics["status"] != "OK"]
    for _, r in failed.iterrows():
        print(f"{r['detector']}: {r['status']}: {r['message']}", file=sys.stderr)
    print(f"\nrun folder: {path} (metrics.csv, metrics.md, breakdown.csv)", file=sys.stderr)


def name_failed(command: str, failed, what: str, hint: str) -> int:
    """One stderr line naming the jobs of ``failed`` (metrics rows) and what happened to them; the
    exit status: :data:`EXIT_JOBS_FAILED` when there are any, else 0."""
    if not len(failed):
        return 0
    names = ", ".join(f"{r['detector']} ({r['status']})" for _, r in failed.iterrows())
    print(f"scart-bench {command}: {len(failed)} job(s) {what}: {names}; {hint}", file=sys.stderr)
    return EXIT_JOBS_FAILED


def record_folder(record: str | Path | None) -> Path | None:
    """``--record``'s folder: new, empty, or an existing dataset to add the flight to (UsageError otherwise)."""
    from scart_bench.dataset import is_dataset

    if not record:
        return None
    record = Path(record)
    if record.exists():
        if not record.is_dir():
            raise UsageError(f"--record {record}: exists and is not a folder")
        if any(record.iterdir()) and not is_dataset(record):
            raise UsageError(f"--record {record}: not empty and not a scart-bench dataset (no manifest); "
                             "give a new folder or an existing dataset to add the flight to")
    return record
