"""csv mode's replay calls the layer only where a call can matter (generator.scart.replay): the same
bytes as the call at every message time (the per-message path), under realistic timing, where every
flight has its own message schedule (issue 51 item 1)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from scart_bench.generator.scart.scenario import load_scenarios

#: A grid whose configurations exercise what the replay skips or keeps: random draws while idle
#: (noise), history lookback (duplicate), lost messages (intermittent), a time, a random and an
#: altitude (history-only) trigger, each ended by a duration.
GRID = """
[grid]
id = "csvb"
injection_point = "link"

[grid.axes]
action = ["add_white_noise", "duplicate", "intermittent"]
target = ["position"]
level = [2]
duration_s = [6.0]
trigger = ["time", "random", "altitude"]

[targets.position]
fields = ["global_position_int.lat", "global_position_int.lon", "local_position_ned.x", "local_position_ned.y"]
magnitudes = [2.0, 5.0, 10.0, 25.0]
[actions.add_white_noise]
param = "std"
[actions.duplicate]
param = "k"
levels = [5, 15, 50, 150]
[actions.intermittent]
param = "off_fraction"
levels = [0.2, 0.5, 0.8, 1.0]
extra = { period_s = 0.5 }

[triggers.time]
start = [{ condition = "time_window", start_s = 12.0 }]
[triggers.random]
start = [{ condition = "random_start", low_s = 8.0, high_s = 20.0 }]
[triggers.altitude]
start = [{ condition = "altitude_above", height = 3.0 }]
"""


def _hashes(folder: Path) -> dict[str, str]:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_csv_mode_dataset_is_byte_identical_to_the_per_message_replay(tmp_path, monkeypatch):
    from scart_bench.dataset import open_dataset
    from scart_bench.generator.generate import generate_dataset

    grid = tmp_path / "grid.toml"
    grid.write_text(GRID)
    out = {}
    for name in ("per-message", "replay"):
        if name == "per-message":  # read by csv_mode, in the csv-mode process too (spawned: the environment)
            monkeypatch.setenv("SCART_BENCH_CSV_REPLAY", "per-message")
        else:
            monkeypatch.delenv("SCART_BENCH_CSV_REPLAY", raising=False)
        out[name] = Path(generate_dataset("quick", tmp_path / name, seed=5, n_normal=3, scenarios=grid))
    ds = open_dataset(out["replay"])
    csv = ds.manifest[ds.manifest["mode"].astype(str) == "csv"]
    assert len(csv) == 9 and csv["attack_start_us"].notna().sum() >= 7  # the attacks did start
    a, b = _hashes(out["per-message"]), _hashes(out["replay"])
    assert sorted(a) == sorted(b)
    assert [k for k in a if a[k] != b[k]] == []


@pytest.fixture(scope="module")
def own_schedules():
    """Two generated flights' link topics, each on its own message schedule (realistic timing)."""
    from scart_bench.generator.attacks import strip_labels
    from scart_bench.generator.engine.simulate import simulate
    from scart_bench.generator.telemetry.tables import normal_record

    batch = simulate([21, 22])
    return [{t: df for t, df in strip_labels(normal_record(batch, i, f"n{i}", "csv_source", {}).navigator).items()
             if t != "truth"} for i in range(2)]


def _csv_results(monkeypatch, per_message: bool, flights, scenarios, seeds):
    from scart_bench.generator.modes import csv_mode

    if per_message:
        monkeypatch.setenv("SCART_BENCH_CSV_REPLAY", "per-message")
    else:
        monkeypatch.delenv("SCART_BENCH_CSV_REPLAY", raising=False)
    return csv_mode(flights, scenarios, seeds)


@pytest.mark.parametrize("files", [
    ["chain_jam_then_drift.toml"],  # a physical scenario's timing and a condition on another scenario
    ["link_replay.toml", "link_flood.toml", "link_loss.toml", "gps_spoof.toml"],
])
def test_csv_mode_on_flights_of_their_own_schedules_matches_the_per_message_replay(files, own_schedules,
                                                                                    monkeypatch):
    flights = own_schedules
    assert not np.array_equal(flights[0]["attitude"]["Timestamp"].to_numpy()[:50],
                              flights[1]["attitude"]["Timestamp"].to_numpy()[:50])  # realistic timing
    scenarios = [load_scenarios(f"data/scenarios/{f}") for f in files]
    scenarios = [scenarios[i % len(scenarios)] for i in range(max(2, len(scenarios)))]
    sources = [flights[i % 2] for i in range(len(scenarios))]
    seeds = [7 + i for i in range(len(scenarios))]
    old = _csv_results(monkeypatch, True, sources, scenarios, seeds)
    new = _csv_results(monkeypatch, False, sources, scenarios, seeds)
    assert any(w for _, w, _ in new)
    for (nav_a, win_a, ev_a), (nav_b, win_b, ev_b) in zip(old, new):
        assert win_a == win_b and ev_a == ev_b
        assert list(nav_a) == list(nav_b)
        for t in nav_a:
            assert nav_a[t].equals(nav_b[t]), t
            assert nav_a[t].dtypes.tolist() == nav_b[t].dtypes.tolist()
