"""What the command modules share: the command line's own error (bad options, one line, exit code 2),
the progress log and the options several commands take.

Library code raises the errors of :mod:`scart_bench.errors`; ``UsageError`` is for the CLI modules.
"""

from __future__ import annotations

import shutil
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from scart_bench.errors import ScartBenchError
from scart_bench.storage import (  # noqa: F401 (the commands import them from here too)
    STAGE_PREFIX,
    owned_tempdir,
    remove_stale_temp,
    stage_name,
    staged_dataset,
)


class UsageError(ScartBenchError):
    """Bad command-line input (unknown name, missing file, conflicting options)."""


#: scart_bench.dataset.LAYOUTS, spelled out here so that the command line starts without pandas
LAYOUTS = ("compact", "paper")
#: the library's choices and defaults the parser shows, spelled out here as LAYOUTS is, so that building the
#: parser (and ``--help``) imports no numpy, pandas or torch; tests/test_house.py checks them against the library
#: (scart_bench.benchmark.protocol's PHASE_RULES and DEFAULT_PHASE_MARGIN_S, scart_bench.generator.defense's
#: RESPONSES, scart_bench.generator.mavlink's DEFAULT_LISTEN and DEFAULT_FORWARD)
PHASE_RULES = ("burn-in", "ends", "cruise")
DEFAULT_PHASE_MARGIN_S = 3.0
RESPONSES = ("hold", "return", "land", "reject_gps", "reject_gps_then_return")
PROXY_LISTEN, PROXY_FORWARD = "udp:127.0.0.1:14540", "udp:127.0.0.1:14541"
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


class Staged:
    """A local folder standing for ``location``; :meth:`sync` uploads what changed in it since the last
    sync when ``location`` is a URL (a run uploads each finished job so that a kill loses none)."""

    def __init__(self, path: Path, url: str | None = None, exclude: tuple[str, ...] = ()):
        self.path, self.url, self.exclude = path, url, exclude
        self._pushed: dict | None = None

    def fetched(self) -> None:
        """Record the local copy as what the URL holds (only changes are uploaded afterwards)."""
        from scart_bench.storage import snapshot

        self._pushed = snapshot(self.path, self.exclude) if self.path.is_dir() else {}

    def sync(self) -> None:
        """Make the URL hold the local folder's files (no-op for a local folder). A job's
        ``status.json`` goes up last: a job counts as done once it is there, so its scores and the
        run's ``checksums.json`` must be there first."""
        from scart_bench.storage import push_folder

        if self.url is not None and self.path.is_dir():
            self._pushed = push_folder(self.path, self.url, self.exclude, since=self._pushed,
                                       last=("status.json",))


@contextmanager
def stage_folder(location: str | Path, exclude: tuple[str, ...] = ("cache",), write: bool = True) -> Iterator[Staged]:
    """:func:`staged_folder`, yielding a :class:`Staged` (its ``sync`` uploads before the end)."""
    from scart_bench.storage import check_writable, fetch_folder, is_url, local_path

    if not is_url(location):
        remove_stale_temp()
        yield Staged(local_path(location))
        return
    url = str(location).rstrip("/")
    if write:
        check_writable(url)
    with owned_tempdir(STAGE_PREFIX) as tmp:
        local = tmp / stage_name(url, "folder")
        if not fetch_folder(url, local) and not write:
            raise UsageError(f"{url}: nothing there; expected a run folder")
        staged = Staged(local, url, exclude)
        staged.fetched()
        try:
            yield staged
        finally:
            if write and local.is_dir():
                staged.sync()


@contextmanager
def staged_folder(location: str | Path, exclude: tuple[str, ...] = ("cache",), write: bool = True) -> Iterator[Path]:
    """A local folder for ``location``: itself, or for an fsspec URL a local copy of what is there,
    uploaded back afterwards (also after an error or an interrupt, so that ``--resume`` finds what
    was done; ``exclude``: top-level entries kept local, such as a run's flight cache). The copy is
    made in a staging folder owned by this process; those of killed processes are removed here."""
    with stage_folder(location, exclude, write) as staged:
        yield staged.path


@contextmanager
def removed_on_failure(out: Path | str) -> Iterator[None]:
    """Remove ``out`` when the block fails and ``out`` did not exist before it (a URL is left to its
    staging): nothing half-written looks like a new dataset."""
    from scart_bench.storage import is_url

    existed = is_url(out) or Path(out).exists()
    try:
        yield
    except BaseException:
        if not existed:
            shutil.rmtree(out, ignore_errors=True)
        raise


#: The terminal table's columns (``run``, ``score``): the paper's three, the false alarms beside the stated
#: alpha and ROC-AUC (then the job's status), so that a row fits a 120-column terminal; ``--wide`` prints every
#: column of metrics.md.
TERMINAL_COLUMNS = (("TP Simulation", "tp_simulation", "pct_ci"), ("TP CSV", "tp_csv", "pct_ci"),
                    ("TN No Attack", "tn_no_attack", "pct_ci"), ("False alarms", "far_no_attack", "pct_ci"),
                    ("ROC-AUC", "roc_auc", "f3"))


def aligned(markdown: str) -> str:
    """A Markdown table with its cells padded to their column's width (still Markdown, readable in a terminal)."""
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in markdown.splitlines()]
    widths = [max(len(r[i]) for r in rows if r[i].strip("-")) for i in range(len(rows[0]))]
    out = []
    for r in rows:
        if all(not c.strip("-") for c in r):  # the separator line
            out.append("|" + "|".join("-" * (w + 2) for w in widths) + "|")
        else:
            out.append("| " + " | ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) + " |")
    return "\n".join(out)


def terminal_table(metrics, wide: bool = False) -> str:
    """The table ``run`` and ``score`` print: :data:`TERMINAL_COLUMNS`, aligned; ``wide``: the paper's
    table of metrics.md with every column, as written there."""
    from scart_bench.benchmark.results import paper_table
    from scart_bench.benchmark.tables import markdown_table

    if wide:
        return paper_table(metrics)
    return aligned(markdown_table(metrics, TERMINAL_COLUMNS))


def print_tables(path: Path, metrics, shown: str | None = None, label: str = "run folder",
                 wide: bool = False) -> None:
    """The terminal table (``wide``: every column) and the operating-point lines of a run (stdout); failed
    jobs and the folder (stderr, ``shown`` as ``label``: an evaluation made after the run names its own folder)."""
    from scart_bench.benchmark.results import trained_where, transfer_summary
    from scart_bench.benchmark.store import RunStore
    from scart_bench.benchmark.tables import rate_summary

    config = RunStore(path).read_config()
    train = (config.get("train_dataset") or {}).get("path")
    if train:  # a transfer run: where each number comes from, above the table
        print(f"{trained_where(config).replace('`', '')} (thresholds); TP and TN on {config['dataset'].get('path')}")
    print(terminal_table(metrics, wide))
    no_effect = (config.get("dataset") or {}).get("no_effect") or []
    print("\n".join(line for line in rate_summary(metrics, no_effect) if line.startswith("- ")))
    if train:
        print("\n".join(line for line in transfer_summary(config, metrics) if line.startswith(("- ", "|"))))
    failed = metrics[metrics["status"] != "OK"]
    for _, r in failed.iterrows():
        print(f"{r['detector']}: {r['status']}: {r['message']}", file=sys.stderr)
    print(f"\n{label}: {shown or path} (metrics.csv, metrics.md with every column, breakdown.csv)", file=sys.stderr)


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
