"""What a dataset is made of: its formats, layouts, views and manifest columns, and one flight's record.

A :class:`FlightRecord` is everything written for one flight (both views' topic tables, the
anomaly windows, the events and the manifest row); :func:`flight_record` builds it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.errors import ScartBenchError

FORMATS = ("parquet", "csv")


#: "compact": one Parquet file per view per flight (the default for Parquet); "paper": the paper's
#: per-topic and combined files (CSV, or Parquet on request)
LAYOUTS = ("compact", "paper")


VIEWS = ("navigator", "simulator")


#: Views with per-topic tables (``sensors/<view>/``); ``uorb`` only for flights generated with it.
TOPIC_VIEWS = (*VIEWS, "uorb")


TABLES = ("most_frequent", "all_sensors")


MANIFEST_COLUMNS = (
    "flight_id", "mode", "scenario_id", "action", "target", "injection_point", "params", "seed",
    "split", "rows", "duration_s", "attack_start_us", "attack_end_us", "source_flight", "kind",
    "effect_rows", "effect_fields", "no_effect", "detectability",
    "impact_max_dev_m", "impact_final_dev_m", "impact_mission_completed", "impact_landing_dist_m",
    "impact_crashed", "checksum",
)


#: Simulator-view topics that are the vehicle's true state, not link messages (kept out of the
#: combined tables): the flight's own and, for a simulation-mode attacked flight, its twin's.
TRUTH_TOPICS = ("truth", "twin_truth")


class DatasetError(ScartBenchError):
    """A dataset folder or file is missing, incomplete or malformed."""


@dataclass
class FlightRecord:
    """One flight as produced by the generator or the attack layer, before it is written.

    ``navigator`` and ``simulator`` map topic name -> table (``Timestamp``, ``Is_Anomaly``,
    fields). ``windows`` are the attack windows ``[start_us, end_us)`` in which an action was
    active; ``events`` is the attack event log (one dict per event). ``uorb``: the flight's uORB
    view (generator.telemetry.uorb; topic -> table like the other views), written as a third view when given.
    An attacked copy's table may be a :class:`scart_bench.dataset.labels.SourceTopic` (its source
    recording's table with the copy's labels, not built; the writers take it as that table).
    """

    flight_id: str
    navigator: dict[str, pd.DataFrame]
    simulator: dict[str, pd.DataFrame]
    manifest: dict
    config: dict
    windows: list[tuple] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)
    uorb: dict[str, pd.DataFrame] | None = None


#: Manifest values of a flight that does not set them (a normal flight, no attack).
MANIFEST_DEFAULTS = {
    "mode": "normal", "scenario_id": "", "action": "", "target": "", "injection_point": "", "params": "{}",
    "seed": 0, "split": "test", "source_flight": "", "kind": "",
}


def flight_record(flight_id: str, navigator: dict[str, pd.DataFrame], simulator: dict[str, pd.DataFrame],
                  manifest: dict, config: dict, windows: Iterable[tuple] = (), events: Iterable[dict] = (),
                  end_us: int | None = None) -> FlightRecord:
    """The one way a flight record is built (generator, attack layer, import, proxy recording).

    ``manifest`` holds what differs from :data:`MANIFEST_DEFAULTS` (mode, split, seed, the
    attack fields...); ``duration_s`` is ``end_us`` / 1e6, where ``end_us`` (the end of the
    flight, exclusive) defaults to one microsecond after the last timestamp of any table.
    """
    if end_us is None:
        last = [int(df["Timestamp"].iloc[-1]) for view in (navigator, simulator) for df in view.values() if len(df)]
        end_us = max(last) + 1 if last else 0
    row = {**MANIFEST_DEFAULTS, **manifest, "duration_s": int(end_us) / 1e6}
    return FlightRecord(flight_id=str(flight_id), navigator=navigator, simulator=simulator, manifest=row,
                        config=config, windows=list(windows), events=list(events))


def is_dataset(path: Path) -> bool:
    path = Path(path)
    return (path / "manifest.parquet").exists() or (path / "manifest.csv").exists()


def check_layout(fmt: str, layout: str | None) -> str:
    """The layout to write: ``layout``, or compact for Parquet and the paper's for CSV."""
    if layout is None:
        return "compact" if fmt == "parquet" else "paper"
    if layout not in LAYOUTS:
        raise DatasetError(f"layout {layout!r}: expected one of {', '.join(LAYOUTS)}")
    if layout == "compact" and fmt != "parquet":
        raise DatasetError("layout 'compact' is Parquet only; use --layout paper for CSV files")
    return layout


def json_default(obj):
    """``json.dumps(default=...)`` for numpy values and paths; TypeError for anything else."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
