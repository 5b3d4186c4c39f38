"""csv mode under realistic timing at the cost of ideal timing (issue 51 acceptance 1), with the same bytes:
a scenario group skips the updates before its next change point (AttackLayer.plan_ticks) and csv mode
runs in two processes, each a run of whole batches."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from scart_bench.generator.engine.simulate import FlightConfig
from scart_bench.generator.flight_software.navigator import MissionParams

SHORT = FlightConfig(mission=MissionParams(max_duration_s=40.0))


@pytest.fixture(scope="module")
def recordings():
    """Two generated flights' link topics, each on its own message schedule (realistic timing)."""
    from scart_bench.generator.attacks import strip_labels
    from scart_bench.generator.engine.simulate import simulate
    from scart_bench.generator.telemetry.tables import normal_record

    batch = simulate([31, 32], SHORT)
    return [{t: df for t, df in strip_labels(normal_record(batch, i, f"n{i}", "csv_source", {}).navigator).items()
             if t != "truth"} for i in range(2)]


def _paper_configs():
    """Paper-grid configurations of every trigger (time, waypoint, altitude, random), single attacks of
    every action and chained and concurrent combinations (conditions on another scenario's state), at
    10 s: what the quiet spans must get right."""
    from scart_bench.generator.attacks import grid_path
    from scart_bench.generator.scart.grid import load_configurations

    configs = load_configurations(grid_path("paper.toml"))
    triggers, targets = ("time", "waypoint", "altitude", "random"), ("altitude", "attitude", "imu")
    picked, seen = [], set()
    for c in configs:
        first = c[0].id.split("-")  # paper-<action>-<target>-L<level>-d<duration>-<trigger>
        if first[3:5] != ["L2", "d10"]:
            continue
        # singles: each action once, the triggers in turn; combinations: concurrent and chained per trigger
        key = (first[1], "single") if len(c) == 1 else (first[5], c[1].id.rsplit("-", 1)[-1])
        if key in seen or (len(c) == 1 and (first[5], first[2]) != (triggers[len(seen) % 4], targets[len(seen) % 3])):
            continue
        seen.add(key)
        picked.append(c)
    return picked


def _replay(monkeypatch, per_message: bool, flights, scenarios, seeds, count: list | None = None):
    from scart_bench.generator.modes import csv_mode
    from scart_bench.generator.scart import layer

    if per_message:
        monkeypatch.setenv("SCART_BENCH_CSV_REPLAY", "per-message")
    else:
        monkeypatch.delenv("SCART_BENCH_CSV_REPLAY", raising=False)
    if count is not None:  # full group updates (the condition evaluations the quiet spans leave out)
        real = layer._Group._update_vanilla

        def counted(self, ctx, t_us):
            count.append(1)
            return real(self, ctx, t_us)

        monkeypatch.setattr(layer._Group, "_update_vanilla", counted)
    try:
        return csv_mode(flights, scenarios, seeds)
    finally:
        monkeypatch.undo()


def test_paper_configurations_replay_the_same_as_every_message_on_realistic_schedules(recordings, monkeypatch):
    configs = _paper_configs()
    assert len(configs) >= 12 and any(len(c) > 1 for c in configs)
    flights = [recordings[i % 2] for i in range(len(configs))]
    seeds = [100 + i for i in range(len(configs))]
    old = _replay(monkeypatch, True, flights, configs, seeds)
    fewer: list = []
    new = _replay(monkeypatch, False, flights, configs, seeds, fewer)
    assert sum(bool(w) for _, w, _ in new) >= len(configs) // 2  # the attacks did start
    for (nav_a, win_a, ev_a), (nav_b, win_b, ev_b) in zip(old, new):
        assert win_a == win_b and ev_a == ev_b
        assert list(nav_a) == list(nav_b)
        for t in nav_a:
            assert nav_a[t].equals(nav_b[t]), t
    # the spans leave out most condition evaluations: the replay without them (every call updated)
    from scart_bench.generator.scart.layer import AttackLayer

    every: list = []
    monkeypatch.setattr(AttackLayer, "plan_ticks", lambda self, ticks, arrivals: None)
    plain = _replay(monkeypatch, False, flights, configs, seeds, every)
    assert [w for _, w, _ in plain] == [w for _, w, _ in new]
    assert len(fewer) < 0.5 * len(every), (len(fewer), len(every))


def test_csv_mode_in_two_processes_writes_the_dataset_of_one(tmp_path, monkeypatch):
    """Three csv batches split over two processes (batches 0-1 and 2): every file and the manifest's
    row order as csv mode in this process, one batch after the other."""
    from scart_bench.dataset import open_dataset
    from scart_bench.generator import attacks
    from scart_bench.generator.generate import generate_dataset

    grid = tmp_path / "grid.toml"
    grid.write_text(GRID)
    started: list = []
    real = attacks._CsvProcess.start.__func__

    def start(cls, *a, **k):
        started.append(k.get("batches", a[7] if len(a) > 7 else None))
        return real(cls, *a, **k)

    monkeypatch.setattr(attacks._CsvProcess, "start", classmethod(start))
    two = generate_dataset("quick", tmp_path / "two", seed=4, n_normal=3, config=SHORT, scenarios=grid,
                           batch_size=2)
    assert started == [range(0, 2), range(2, 3)]
    monkeypatch.setattr(attacks._CsvProcess, "start", classmethod(lambda cls, *a, **k: None))
    one = generate_dataset("quick", tmp_path / "one", seed=4, n_normal=3, config=SHORT, scenarios=grid,
                           batch_size=2)
    assert _digest(two) == _digest(one)
    manifest = open_dataset(two).manifest
    assert (manifest["mode"].astype(str) == "csv").sum() == 6
    assert manifest["flight_id"].tolist() == open_dataset(one).manifest["flight_id"].tolist()


GRID = """
[grid]
id = "two"
injection_point = "link"

[grid.axes]
action = ["add_white_noise", "bias"]
target = ["position"]
level = [2]
duration_s = [5.0]
trigger = ["time", "random", "altitude"]

[targets.position]
fields = ["global_position_int.lat", "global_position_int.lon", "local_position_ned.x", "local_position_ned.y"]
magnitudes = [2.0, 5.0, 10.0, 25.0]
[actions.add_white_noise]
param = "std"
[actions.bias]
param = "offset"

[triggers.time]
start = [{ condition = "time_window", start_s = 8.0 }]
[triggers.random]
start = [{ condition = "random_start", low_s = 5.0, high_s = 15.0 }]
[triggers.altitude]
start = [{ condition = "altitude_above", height = 3.0 }]
"""


def _digest(folder: Path) -> dict[str, str]:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(folder).rglob("*")) if p.is_file()}


def test_quiet_spans_end_at_a_message_the_conditions_read():
    """An altitude trigger reads the History: its group is updated at every altitude message, so a span
    never reaches past the next one (the replay's arrivals)."""
    from scart_bench.generator.scart.layer import AttackLayer
    from scart_bench.generator.scart.scenario import load_scenarios

    sc = load_scenarios("data/scenarios/gps_spoof.toml")
    layer = AttackLayer([sc], [1], physics=False)
    g = layer.groups[0]
    assert g._start_topics  # mission_phase reads the mission computer's setpoint
    topic = sorted(g._start_topics)[0]
    ticks = np.arange(0, 10_000_000, 10_000, dtype=np.int64)
    layer.plan_ticks(ticks, {topic: ticks[::7]})
    g.update(int(ticks[0]))
    assert g._quiet_until <= int(ticks[7])
