"""A proxied flight in the dataset layout: both views, labels from the layer, the event log.

The navigator view is what the proxy forwarded to the mission computer (attacked), the
simulator view what it received from the autopilot (ground truth of the link; a live link has
no ``truth`` topic). The flight is an attacked flight of mode ``simulation`` (closed loop: the
mission computer reacts to what it is fed), split ``test``.

:func:`save_recording` writes it into a new dataset, or appends it to an existing one (for
example one made with ``scart-bench generate --normal-only``, which holds the normal train and
validation flights a benchmark run needs); the manifest is replaced atomically, so the dataset
is complete before and after.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.generator.dataset import (
    DatasetError,
    FlightRecord,
    append_flights,
    flight_record,
    insert_labels,
    is_dataset,
    open_dataset,
)
from scart_bench.generator.modes import scenario_manifest
from scart_bench.generator.topics import TOPICS

LIVE_SOURCE = "mavlink-proxy"


def _table(topic: str, ts: list[int], vals: list[np.ndarray], windows) -> pd.DataFrame:
    t = np.asarray(ts, dtype=np.int64)
    df = pd.DataFrame(np.vstack(vals) if vals else np.zeros((0, len(TOPICS[topic].fields))),
                      columns=list(TOPICS[topic].field_names))
    df.insert(0, "Timestamp", t)
    return insert_labels(df, t, windows)


def proxy_record(proxy, flight_id: str, extra_config: dict) -> FlightRecord:
    """The flight a :class:`scart_bench.generator.mavlink.proxy.MavlinkProxy` has seen so far."""
    end_us = proxy.end_us
    windows = proxy.layer.labelled_windows(0, end_us)
    nav = {t: _table(t, *proxy.views.forwarded[t], windows) for t in TOPICS if t in proxy.views.forwarded}
    sim = {t: _table(t, *proxy.views.received[t], windows) for t in TOPICS if t in proxy.views.received}
    manifest = scenario_manifest(proxy.scenarios, "simulation", proxy.seed, source=LIVE_SOURCE)
    config = {
        **extra_config, "seed": proxy.seed, "mode": "simulation", "source": LIVE_SOURCE,
        "listen": f"udp:{proxy.listen[0]}:{proxy.listen[1]}",
        "forward": f"udp:{proxy.forward[0]}:{proxy.forward[1]}",
        "scenarios": [s.to_dict() for s in proxy.scenarios], "stats": proxy.stats.to_dict(),
        "first_autopilot_time_us": proxy.first_time_us,
        "recorded_at": datetime.fromtimestamp(proxy.started_wall, UTC).isoformat(timespec="seconds"),
    }
    return flight_record(flight_id, nav, sim, manifest, config, windows, proxy.layer.event_log(0, end_us),
                         end_us=end_us)


def new_flight_id(path: str | Path | None = None, prefix: str = "live") -> str:
    """A flight id from the current time, unique in the dataset at ``path`` (if any)."""
    base = f"{prefix}-{datetime.now(UTC).strftime('%Y%m%dT%H%M%S')}"
    taken: set[str] = set()
    if path is not None and is_dataset(Path(path)):
        taken = set(open_dataset(path).manifest["flight_id"].astype(str))
    fid, k = base, 1
    while fid in taken:
        k += 1
        fid = f"{base}-{k}"
    return fid


def save_recording(record: FlightRecord, out: str | Path, fmt: str = "parquet") -> Path:
    """Write the flight into dataset ``out``: appended when ``out`` is a dataset, else a new one."""
    out = Path(out)
    if record.navigator == {}:
        raise DatasetError(f"{out}: nothing was recorded (no telemetry of a known topic passed the proxy)")
    return append_flights(out, [record], fmt=fmt, info={"profile": "live", "source": LIVE_SOURCE})
