"""The two modes of the SCART layer.

- simulation mode: the layer runs inside the closed loop; the navigator reacts to what it is fed.
- csv mode: the layer replays recorded flights message by message in timestamp order and writes an
  attacked copy; nothing reacts, and the simulator view is the input, unchanged.
"""

from __future__ import annotations

import os

import numpy as np
import pandas as pd

from scart_bench.dataset import (
    LABEL_COLUMNS,
    FlightRecord,
    flight_record,
    insert_labels,
    labelled_table,
)
from scart_bench.generator.attack_effect import attack_effect
from scart_bench.generator.engine.simulate import BatchResult, FlightConfig, simulate
from scart_bench.generator.params import STEP_US
from scart_bench.generator.scart.layer import AttackLayer
from scart_bench.generator.scart.meanings import input_fields
from scart_bench.generator.scart.replay import per_message, replay
from scart_bench.generator.scart.scenario import Scenario
from scart_bench.generator.telemetry.tables import flight_views, uorb_stream_tables, with_uorb


def simulation_mode(seeds: list[int], scenarios: list[list[Scenario]], config: FlightConfig | None = None
                    ) -> tuple[BatchResult, AttackLayer]:
    """Fly each seed with its scenarios in the closed loop."""
    layer = AttackLayer(scenarios, seeds, rates=_builtin_rates())
    batch = simulate(seeds, config, layer=layer)
    return batch, layer


def _builtin_rates() -> dict[str, float]:
    from scart_bench.dataset.schema import TOPICS
    from scart_bench.generator.telemetry.schedule import SENSOR_TOPICS

    rates = {t: v.rate_hz for t, v in TOPICS.items()}
    rates.update({t: r for t, (r, _) in SENSOR_TOPICS.items()})
    return rates


def scenario_manifest(scenarios: list[Scenario], mode: str, seed: int, source: str = "") -> dict:
    """Manifest fields describing the attack of one flight."""
    import json

    return {
        "mode": mode, "scenario_id": "+".join(s.id for s in scenarios),
        "kind": "+".join(sorted({s.kind for s in scenarios})),
        "action": "+".join(s.primary_action() for s in scenarios),
        "target": "+".join(s.target_label() for s in scenarios),
        "injection_point": "+".join(s.injection_point for s in scenarios),
        "params": json.dumps([json.loads(s.params_json()) for s in scenarios], sort_keys=True),
        "seed": seed, "split": "test", "source_flight": source,
    }


def simulation_record(batch: BatchResult, layer: AttackLayer, i: int, flight_id: str,
                      scenarios: list[Scenario], config: dict) -> FlightRecord:
    """An attacked simulation-mode flight ready for the dataset writer."""
    end_us = (int(batch.exit_step[i]) + 1) * STEP_US
    windows = layer.labelled_windows(i, end_us)
    nav, sim = flight_views(batch, i, windows)
    cfg = {**config, "seed": batch.seeds[i], "status": batch.status[i], "mode": "simulation",
           "scenarios": [s.to_dict() for s in scenarios], "wind_mean_ned": batch.wind[i].tolist(),
           "waypoints_ned": batch.waypoints[i].tolist()}
    record = flight_record(flight_id, nav, sim, scenario_manifest(scenarios, "simulation", batch.seeds[i]), cfg,
                           windows, layer.event_log(i, end_us), end_us=end_us)
    wanted = getattr(batch, "uorb", False)
    return with_uorb(record, wanted, uorb_stream_tables(batch, i, windows) if wanted else None)


def csv_record(flight_id: str, source: dict[str, pd.DataFrame], result: tuple, scenarios: list[Scenario],
               seed: int, source_name: str, config: dict, stds: dict[str, float] | None = None) -> FlightRecord:
    """An attacked csv-mode flight: ``result`` is one entry of :func:`csv_mode` on ``source``
    (the unattacked topic tables, which become the simulator view). Its manifest row says what the
    attack changed relative to the source (:func:`scart_bench.generator.attack_effect.attack_effect`;
    ``stds``: the validation flights' std per ``topic.field``, for the detectability)."""
    nav, windows, events = result
    cfg = {**config, "mode": "csv", "seed": seed, "scenarios": [s.to_dict() for s in scenarios]}
    manifest = scenario_manifest(scenarios, "csv", seed, source=source_name)
    # compared with the source itself: what acts off the link changes nothing on a recording
    manifest.update(attack_effect(nav, source, windows, stds, "link"))
    record = flight_record(flight_id, nav, with_labels(source, windows), manifest, cfg, windows, events)
    # the flight controller's own topics are the recording's: a replayed link attack never reaches them
    return with_uorb(record, bool(config.get("flight_config", {}).get("uorb", False)))


def _same_schedule(flights: list[dict[str, pd.DataFrame]]) -> bool:
    first = flights[0]
    if all(f is first for f in flights):  # one recording replayed for several copies
        return True
    for f in flights[1:]:
        if set(f) != set(first):
            return False
        for topic, df in f.items():
            a = df["Timestamp"].to_numpy()
            b = first[topic]["Timestamp"].to_numpy()
            k = min(len(a), len(b))
            if not np.array_equal(a[:k], b[:k]):
                return False
    return True


def csv_mode(flights: list[dict[str, pd.DataFrame]], scenarios: list[list[Scenario]], seeds: list[int],
             leave_passed: bool = False) -> list[tuple[dict[str, pd.DataFrame], list[tuple[int, int]], list[dict]]]:
    """Replay recorded flights through the layer.

    ``flights[i]`` maps topic -> table (``Timestamp`` in µs, fields; an ``Is_Anomaly`` column is
    ignored). Returns per flight: the attacked (navigator-view) topic tables with labels, the
    attack windows and the event log. Flights that share one message schedule (as the generator's
    do under ideal timing) are replayed together as one batch; otherwise the copies of one recording
    (the same tables: under realistic timing every recording has its own schedule) are, each
    recording's batch after the other (per flight the same result: a flight's draws and state are its own).

    ``leave_passed``: a topic never handed to the layer (passed unchanged) maps to None instead of
    its table, :func:`passed_table` of the flight's table (an attacked copy of an all-topic log need
    not build a hundred tables it can take from its source, generator.logs.copies).
    """
    if len(flights) > 1 and not _same_schedule(flights):
        if os.environ.get("SCART_BENCH_CSV_REPLAY") == "per-message":  # as before issue 51: one by one
            return [r for f, sc, sd in zip(flights, scenarios, seeds) for r in csv_mode([f], [sc], [sd], leave_passed)]
        groups: dict[tuple, list[int]] = {}
        for i, f in enumerate(flights):
            groups.setdefault(tuple((t, id(df)) for t, df in f.items()), []).append(i)
        out: list = [None] * len(flights)
        for rows in groups.values():
            for i, r in zip(rows, csv_mode([flights[i] for i in rows], [scenarios[i] for i in rows],
                                           [seeds[i] for i in rows], leave_passed)):
                out[i] = r
        return out
    n = len(flights)
    topics = list(flights[0])
    fields = input_fields(flights, LABEL_COLUMNS)  # with what a recording's listen view knows (meanings.Fields)
    lengths = {t: np.array([len(f[t]) for f in flights]) for t in topics}
    times = {t: max((f[t] for f in flights), key=len)["Timestamp"].to_numpy(np.int64) for t in topics}
    rates = {t: (len(times[t]) - 1) / max((times[t][-1] - times[t][0]) / 1e6, 1e-9) if len(times[t]) > 1 else 1.0
             for t in topics}
    layer = AttackLayer(scenarios, seeds, fields=fields, rates=rates, physics=False)
    one_by_one = os.environ.get("SCART_BENCH_CSV_REPLAY") == "per-message"
    # the replay hands the layer only the topics it must see (listened, targeted, or a lat/lon pair while an
    # origin is unknown: a set that only shrinks), so the others' values are never stacked per flight:
    # an all-topic log's hundred untouched topics cost their tables, not (flights x rows x fields) arrays
    seen = set(topics) if one_by_one else layer.must_see(topics)
    own: dict[tuple[str, int], np.ndarray] = {}  # one table replayed for several flights is read once

    def table_values(t: str, i: int) -> np.ndarray:
        key = (t, id(flights[i][t]))
        if key not in own:
            own[key] = flights[i][t][list(fields[t])].to_numpy(np.float64)
        return own[key]

    values = {}
    for t in topics:
        if t not in seen:
            continue
        arr = np.full((n, len(times[t]), len(fields[t])), np.nan)
        for i, f in enumerate(flights):
            arr[i, : len(f[t])] = table_values(t, i)
        values[t] = arr
    out_vals = {t: values[t].copy() for t in values}
    delivered = {t: np.ones((n, len(times[t])), dtype=bool) for t in values}
    # every message in timestamp order, topics at the same time together (generator.scart.replay)
    (per_message if one_by_one else replay)(layer, times, values, out_vals, delivered)
    results = []
    last: dict[int, int] = {}  # a table's last timestamp, read once for the copies that replay it

    def last_us(df: pd.DataFrame) -> int:
        if id(df) not in last:
            last[id(df)] = int(df["Timestamp"].iloc[-1])
        return last[id(df)]

    for i, f in enumerate(flights):
        end_us = max(last_us(f[t]) for t in topics if len(f[t])) + 1
        windows = layer.labelled_windows(i, end_us)
        nav = {}
        for t in topics:
            k = lengths[t][i]
            if t not in values:  # never handed to the layer: passed unchanged
                nav[t] = None if leave_passed else labelled_table(times[t][:k], table_values(t, i), list(fields[t]), windows)
                continue
            keep = delivered[t][i, :k]
            nav[t] = labelled_table(times[t][:k][keep], out_vals[t][i, :k][keep], list(fields[t]), windows)
        results.append((nav, windows, layer.event_log(i, end_us)))
    return results


def passed_table(table: pd.DataFrame, windows=()) -> pd.DataFrame:
    """What :func:`csv_mode` returns for a topic it passed unchanged when it replays ``table`` alone
    (or with copies of itself): its timestamps, the labels of ``windows`` and its fields as float64."""
    fields = [c for c in table.columns if c != "Timestamp" and c not in LABEL_COLUMNS]
    return labelled_table(table["Timestamp"].to_numpy(np.int64), table[fields].to_numpy(np.float64), fields, windows)


def with_labels(topics: dict[str, pd.DataFrame], windows=()) -> dict[str, pd.DataFrame]:
    """Topic tables with the label columns from ``windows`` (as the simulator view)."""
    return {t: insert_labels(df, df["Timestamp"].to_numpy(), windows) for t, df in topics.items()}
