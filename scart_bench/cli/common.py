"""What the command modules share: the command line's own error (bad options, one line, exit code 2),
the progress log and the options several commands take.

Library code raises the errors of :mod:`scart_bench.errors`; ``UsageError`` is for the CLI modules.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
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


@contextmanager
def staged_folder(location: str | Path, exclude: tuple[str, ...] = ("cache",), write: bool = True) -> Iterator[Path]:
    """A local folder for ``location``: itself, or for an fsspec URL a local copy of what is there,
    uploaded back afterwards (also after an error or an interrupt, so that ``--resume`` finds what
    was done; ``exclude``: top-level entries kept local, such as a run's flight cache)."""
    from scart_bench.storage import check_writable, fetch_folder, is_url, local_path, push_folder

    if not is_url(location):
        yield local_path(location)
        return
    url = str(location).rstrip("/")
    if write:
        check_writable(url)
    with tempfile.TemporaryDirectory(prefix="scart-stage-") as tmp:
        local = Path(tmp) / (url.rsplit("/", 1)[-1] or "folder")
        if not fetch_folder(url, local) and not write:
            raise UsageError(f"{url}: nothing there; expected a run folder")
        try:
            yield local
        finally:
            if write and local.is_dir():
                push_folder(local, url, exclude)


@contextmanager
def staged_dataset(location: str | Path) -> Iterator[Path]:
    """A local folder for the dataset at ``location`` that a command creates or adds to: itself, or
    for an fsspec URL a local copy of the dataset there (if any), published back with its manifest
    last once the command succeeded (scart_bench.storage); after a failure the URL is untouched."""
    from scart_bench.dataset import is_dataset
    from scart_bench.storage import (
        StorageError,
        check_writable,
        clear,
        fetch_dataset,
        has_manifest,
        has_objects,
        is_url,
        local_path,
        publish_dataset,
    )

    if not is_url(location):
        yield local_path(location)
        return
    url = str(location).rstrip("/")
    check_writable(url)
    with tempfile.TemporaryDirectory(prefix="scart-stage-") as tmp:
        local = Path(tmp) / (url.rsplit("/", 1)[-1] or "dataset")
        if has_manifest(url):
            shutil.copytree(fetch_dataset(url), local)
        elif has_objects(url):
            raise StorageError(f"{url}: holds objects but no manifest (not a complete scart-bench dataset); "
                               "choose a new prefix")
        yield local
        if is_dataset(local):
            clear(url)
            publish_dataset(local, url)


def print_tables(path: Path, metrics, shown: str | None = None) -> None:
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
    print(f"\nrun folder: {shown or path} (metrics.csv, metrics.md, breakdown.csv)", file=sys.stderr)


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
