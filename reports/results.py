"""Reading finished benchmark runs for reports: config, metrics and score tables, never detector code.

A run folder (see :mod:`benchmark.store`) is usable by a report when it has ``config.json`` and
``metrics.csv`` (written by ``scart-bench run`` or ``scart-bench score``). Text columns (detector
names, statuses, messages) are read as text, so a detector called ``NA`` or ``nan`` stays a name.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from scart_bench.benchmark.store import RunStore, RunStoreError
from scart_bench.errors import ReportError

#: Columns of the run tables that hold text, not numbers.
TEXT_COLUMNS = ("detector", "status", "message", "flight_id", "role", "mode", "dimension", "value", "outcome",
                "cluster", "armed_by")


def read_table(path: Path) -> pd.DataFrame:
    """A CSV table of a run with text columns kept as text and every other column numeric or bool
    (ReportError naming the file when it is not a table)."""
    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (ValueError, UnicodeDecodeError) as exc:  # pandas' ParserError and EmptyDataError are ValueErrors
        first = str(exc).splitlines()[0] if str(exc) else ""
        raise ReportError(f"{path}: not a table scart-bench wrote ({type(exc).__name__}: {first}); "
                          f"rerun `scart-bench score {path.parent}`") from None

    def convert(col: str) -> pd.Series:
        if col in TEXT_COLUMNS:
            return df[col]
        low = df[col].str.lower()
        if len(df) and low.isin(["true", "false"]).all():
            return low == "true"
        return pd.to_numeric(df[col].replace("", None), errors="coerce")

    # one constructor: a frame rebuilt column by column (metrics.csv has ~150) is fragmented
    return pd.DataFrame({col: convert(col) for col in df.columns}, index=df.index)


@dataclass
class RunResults:
    """One run folder as a report sees it."""

    path: Path
    label: str
    config: dict
    metrics: pd.DataFrame  # metrics.csv, one row per detector, in run order

    @property
    def store(self) -> RunStore:
        return RunStore(self.path)

    @property
    def config_path(self) -> Path:
        return self.path / "config.json"

    def table(self, name: str) -> pd.DataFrame:
        """Another table of the run (``flight_scores.csv``, ``breakdown.csv``, ``flights.csv``)."""
        path = self.path / name
        if not path.is_file():
            raise ReportError(f"{path}: no such file in the run folder; rerun `scart-bench score {self.path}`")
        if name == "flights.csv":
            return self.store.read_flights()
        return read_table(path)


def load_run(path: str | Path, label: str | None = None) -> RunResults:
    """Read a run folder's config and metrics (ReportError naming the path when it is not a finished run)."""
    path = Path(path)
    if not path.is_dir():
        raise ReportError(f"{path}: no such run folder")
    store = RunStore(path)
    try:
        config = store.read_config()
    except RunStoreError as exc:
        raise ReportError(str(exc)) from exc
    if not (path / "metrics.csv").is_file():
        raise ReportError(f"{path}: no metrics.csv; the run has not been scored "
                         f"(run `scart-bench score {path}` first)")
    store.verify()  # the labels and scores behind the tables are the ones the run wrote (ChecksumError)
    metrics = read_table(path / "metrics.csv")
    for col in ("detector", "status"):
        if col not in metrics.columns:
            raise ReportError(f"{path / 'metrics.csv'}: missing column {col!r}; not a scart-bench metrics table")
    return RunResults(path, label or str(config.get("name") or path.name), config, metrics)


def load_runs(paths: list[str | Path]) -> list[RunResults]:
    """Load several runs, giving each a distinct label (``name``, ``name #2``, ...)."""
    if not paths:
        raise ReportError("expected at least one run folder")
    runs = [load_run(p) for p in paths]
    seen: dict[str, int] = {}
    for run in runs:
        seen[run.label] = seen.get(run.label, 0) + 1
        if seen[run.label] > 1:
            run.label = f"{run.label} #{seen[run.label]}"
    return runs
