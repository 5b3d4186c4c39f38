"""A SITL flight in the dataset layout: both views of the link, the ground truth, labels from the layer.

The navigator view is what went past the layer: the telemetry the client (and the mission
executor) received, and the setpoints the controller got; the simulator view is what the flight
controller produced (telemetry before the layer, the commander's setpoints) plus the ``truth``
topic (true state, 50 Hz). With scenarios the flight is an attacked flight of mode
``simulation`` (closed loop); without, a normal flight. It is written with
:func:`scart_bench.generator.mavlink.recording.save_recording`, like the proxy's.
"""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pandas as pd

from scart_bench.dataset import FlightRecord, insert_labels
from scart_bench.generator.modes import scenario_manifest
from scart_bench.generator.telemetry.schedule import field_names

SOURCE = "scart-bench-sitl"


def _table(topic: str, ts: list[int], vals: list[np.ndarray], windows) -> pd.DataFrame:
    names = list(field_names(topic))
    t = np.asarray(ts, dtype=np.int64)
    df = pd.DataFrame(np.vstack(vals) if len(vals) else np.zeros((0, len(names))), columns=names)
    df.insert(0, "Timestamp", t)
    return insert_labels(df, t, windows)


def sitl_parts(server, extra_config: dict, split: str = "test") -> dict:
    """What a recording holds besides the tables: manifest, config, labelled windows, events, end (JSON-able)."""
    end_us = server.plant.t_us + 1
    windows = server.layer.labelled_windows(0, end_us) if server.layer is not None else []
    if server.scenarios:
        manifest = scenario_manifest(server.scenarios, "simulation", server.seed, source=SOURCE)
        manifest["split"] = split
    else:
        manifest = {"mode": "normal", "scenario_id": "", "action": "", "target": "", "injection_point": "",
                    "params": "{}", "seed": server.seed, "split": split, "source_flight": SOURCE}
    manifest["duration_s"] = end_us / 1e6
    config = {
        **extra_config, "seed": server.seed, "mode": manifest["mode"], "source": SOURCE,
        "listen": f"udp:{server.listen[0]}:{server.listen[1]}",
        "scenarios": [s.to_dict() for s in server.scenarios], "stats": dict(server.stats.__dict__),
        "params": dict(server.params.values), "wind_mean_ned": server.plant.wind.mean[0].tolist(),
        "mission": [item.__dict__ for item in server.commander.mission],
        "recorded_at": datetime.fromtimestamp(server.started_wall, UTC).isoformat(timespec="seconds"),
    }
    events = server.layer.event_log(0, end_us) if server.layer is not None else []
    if getattr(server, "defense", None) is not None:
        events = sorted(events + server.defense.event_log(end_us), key=lambda e: e["timestamp_us"])
    return {"manifest": manifest, "config": config, "windows": [list(w) for w in windows], "events": events,
            "end_us": end_us}


def build_record(flight_id: str, views: dict, parts: dict) -> FlightRecord:
    """A FlightRecord from ``views`` (view -> topic -> (timestamps, rows)) and :func:`sitl_parts`."""
    windows = [tuple(w) for w in parts["windows"]]
    nav = {t: _table(t, *views["navigator"][t], windows) for t in views.get("navigator", {})}
    sim = {t: _table(t, *views["simulator"][t], windows if t != "truth" else ()) for t in views.get("simulator", {})}
    return FlightRecord(flight_id=flight_id, navigator=nav, simulator=sim, manifest=dict(parts["manifest"]),
                        config=dict(parts["config"]), windows=windows, events=list(parts["events"]))


def sitl_record(server, flight_id: str, extra_config: dict, split: str = "test") -> FlightRecord:
    """The flight a :class:`scart_bench.generator.sitl.server.SitlServer` has flown so far (``record=True``)."""
    return build_record(flight_id, server.views, sitl_parts(server, extra_config, split))
