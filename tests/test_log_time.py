"""Time in real logs (issue 48 items 1, 3, 7): attack windows count logged time on the shared
fleet's gapped ArduCopter logs, triggers follow the flight's own phases, and a killed attack leaves
nothing behind.

The replays run on the topics the attacks touch or listen to (the clock is fitted on the whole log,
so its gaps are the log's): the time rules are the point here, not the copies' other columns.
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scart_bench.dataset import open_dataset
from scart_bench.generator.logs.importers import load_flight_file
from scart_bench.generator.logs.logged_time import LoggedClock, log_triggers
from scart_bench.generator.logs.offline import (
    _config_id,
    applicable,
    attack_dataset,
    import_logs,
    replay_on_log,
    with_phases,
)
from scart_bench.generator.logs.phases import PHASE_TOPIC, altitude_source
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.generator.scart.spec import ScenarioError

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
FLEET = SHARED / "dataflash" / "fleet"
RFLYMAD = SHARED / "ulog" / "rflymad_TestCase_1_1000000000.ulg"
QUICK = ROOT / "data" / "scenarios" / "quick.toml"
QUICK_LOGS = ROOT / "data" / "scenarios" / "logs" / "quick.toml"
#: The fleet's logs with logging gaps (ArduCopter logs only while armed), and their longest gap (s).
GAPPED = {"arducopter_09-10-2014_30.bin": 32.9, "arducopter_25-9-2014_1.bin": 323.6,
          "arducopter_27-9-2014_71.bin": 221.6, "arducopter_6-3-2014_7.bin": 58.8,
          "arducopter_7-9-2014_6.bin": 15.4, "arducopter_7-9-2014_7.bin": 176.3,
          "arducopter_8-10-2014_10.bin": 99.3}

pytestmark = pytest.mark.skipif(not FLEET.is_dir() or not RFLYMAD.is_file(), reason="shared logs not present")

#: Two of the quick grid's attacks on attitude (every fleet log has it; some have no position: no
#: GPS) with its own triggers (33 s; random in 23-45 s), two levels each: 8 configurations of 15 s.
SMALL_GRID = textwrap.dedent("""
    [grid]
    id = "t"
    injection_point = "link"
    [grid.axes]
    action = ["bias", "add_white_noise"]
    target = ["attitude"]
    level = [1, 3]
    duration_s = [15.0]
    trigger = ["time", "random"]
    [targets.attitude]
    fields = ["attitude.roll", "attitude.pitch"]
    magnitudes = [0.03, 0.08, 0.2, 0.5]
    [actions.bias]
    param = "offset"
    [actions.add_white_noise]
    param = "std"
    [triggers.time]
    start = [{ condition = "time_window", start_s = 33.0 }]
    [triggers.random]
    start = [{ condition = "random_start", low_s = 23.0, high_s = 45.0 }]
""")


def _used(jobs: list, listen: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    """The topics the configurations act on or listen to (and the derived phases)."""
    available = {t: tuple(c for c in df.columns if c not in ("Timestamp", "Is_Anomaly")) for t, df in listen.items()}
    names = {PHASE_TOPIC, altitude_source(listen)[0]}  # the derived phases are on the altitude's rows
    for job in jobs:
        for sc in job:
            names |= sc.resolved(available, available).used_topics()
    return {t: df for t, df in listen.items() if t in names}


@functools.lru_cache(maxsize=2)
def _load(log: Path, end_s: float | None = None) -> tuple[LoggedClock, dict[str, pd.DataFrame]]:
    tables = load_flight_file(log, allow_corrupt=True, end_s=end_s)
    clock = LoggedClock().fit(tables)
    return clock, with_phases(tables, clock)


def _replay(log: Path, grid: Path, end_s: float | None = None) -> tuple[LoggedClock, list, list]:
    clock, listen = _load(log, end_s)
    fit, _ = applicable(load_configurations(grid, check_topics=False), listen, log.name)
    return clock, fit, replay_on_log(_used(fit, listen), fit, 0, clock)


def _logged_s(gaps: list[tuple[int, int]], start_us: int, end_us: int) -> float:
    """Seconds of ``[start_us, end_us)`` that the log has rows for (its gaps left out)."""
    inside = sum(max(0, min(b, end_us) - max(a, start_us)) for a, b in gaps)
    return (end_us - start_us - inside) / 1e6


@pytest.fixture(scope="module")
def small_grid(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("grid") / "small.toml"
    path.write_text(SMALL_GRID)
    return path


@pytest.mark.parametrize("name", sorted(GAPPED))
def test_attacks_on_gapped_logs_label_15_s_of_logged_flight(name, small_grid):
    clock, fit, results = _replay(FLEET / name, small_grid)
    assert clock.gaps_ and max(b - a for a, b in clock.gaps_) / 1e6 == pytest.approx(GAPPED[name], abs=0.1)
    onsets = []
    for job, ((nav, windows, events), _notes) in zip(fit, results):
        assert len(windows) == 1, _config_id(job)
        s, e = windows[0][:2]
        logged = _logged_s(clock.gaps_, s, e)
        rest = _logged_s(clock.gaps_, s, clock.end_us_)
        # 15 s of logged flight, or the rest of the log
        assert logged == pytest.approx(15.0, abs=0.1) or logged == pytest.approx(rest, abs=0.1), (_config_id(job), logged)
        first = []
        for topic, df in nav.items():  # the labelled rows are exactly the window's
            ts = df["Timestamp"].to_numpy()
            flags = df["Is_Anomaly"].to_numpy().astype(bool)
            assert np.array_equal(flags, (ts >= s) & (ts < e)), (topic, _config_id(job))
            first.extend(ts[flags][:1])
        assert min(first) == s  # the window opens on a logged row
        assert [ev["timestamp_us"] for ev in events if ev["event"] == "start"] == [s]
        if _config_id(job).endswith("random"):
            onsets.append(s)
    assert len(set(onsets)) == len(onsets) == 4  # every random configuration its own onset


def test_trigger_in_a_gap_moves_to_the_next_row_and_the_manifest_agrees(tmp_path, small_grid):
    """27-9-2014_71 logs nothing from 12.9 to 57.9 s: the 33 s trigger starts at 57.9 s, says so,
    and the written copy's manifest window is the span of its labelled rows."""
    log = FLEET / "arducopter_27-9-2014_71.bin"
    said: list[str] = []
    ds = tmp_path / "ds"
    import_logs([log], ds, split="test", allow_corrupt=True, say=said.append,
                topics=["ctun", "ev", "mode", "baro", "att"])
    assert any("2 logging gaps (longest 221.6 s at 60.4-282.0 s" in line for line in said), said
    d = open_dataset(ds)
    gaps = d.config("log-arducopter_27-9-2014_71")["logging_gaps"]
    assert gaps["count"] == 2 and gaps["longest_s"] == pytest.approx(221.6, abs=0.1)
    assert gaps["gaps_s"][0] == pytest.approx([12.9, 57.9], abs=0.05)
    grid = tmp_path / "one.toml"
    grid.write_text(SMALL_GRID.replace('action = ["bias", "add_white_noise"]', 'action = ["bias"]')
                    .replace("level = [1, 3]", "level = [3]"))
    said.clear()
    ids = attack_dataset(ds, grid, sources=("test",), say=said.append)
    assert len(ids) == 2 and any("time_window start_s=33 falls in the logging gap 12.9 s-57.9 s" in s for s in said)
    d = open_dataset(ds)
    m = d.manifest.set_index("flight_id")
    for fid in ids:
        flight = d.flight(fid)
        labelled = flight["Timestamp"].to_numpy()[flight["Is_Anomaly"].to_numpy().astype(bool)]
        after = flight["Timestamp"].to_numpy()[flight["Timestamp"].to_numpy() > labelled[-1]]
        assert m.loc[fid, "attack_start_us"] == labelled[0]
        assert m.loc[fid, "attack_end_us"] == (after[0] if len(after) else labelled[-1] + 1)
        cfg = d.config(fid)["logged_time"]
        assert cfg["logging_gaps"]["count"] == 2 and cfg["trigger_notes"]
    time_copy = next(f for f in ids if f.endswith("time"))
    assert abs(int(m.loc[time_copy, "attack_start_us"]) - gaps["gaps_s"][0][1] * 1e6) < 1000  # the first row after


def test_quick_grid_gives_copies_on_the_rflymad_log_cut_at_18_s():
    """Its triggers (33 s; 23-45 s) lie past the end of an 18 s log: they move to take-off (13.3 s)
    and the attacks cover the rest of the log; at least half of the grid's pairs give a copy."""
    clock, fit, results = _replay(RFLYMAD, QUICK, end_s=18.0)
    copies = [(job, r) for job, (r, notes) in zip(fit, results) if r[1]]
    assert len(copies) >= 66 / 2, len(copies)
    starts = {_config_id(job): r[1][0][0] for job, r in copies}
    assert all(abs(s - 13.3e6) < 0.05e6 for c, s in starts.items() if c.endswith("time"))  # take-off
    random = [s for c, s in starts.items() if c.endswith("random")]
    # spread over the first half of what is left after take-off (13.3-15.7 s), not all on one row
    assert len(set(random)) > len(random) / 2 and all(13.2e6 < s < 15.7e6 for s in random)
    assert all(any("leaves no 15 s of the log" in n for n in notes) for _, notes in results)


def test_phase_relative_grid_on_the_rflymad_log_cut_at_18_s():
    clock, fit, results = _replay(RFLYMAD, QUICK_LOGS, end_s=18.0)
    copies = [r for r, _ in results if r[1]]
    assert len(copies) == len(fit) >= 33 and not any(n for _, n in results)  # nothing to move
    air = 18.0 - 13.3  # off the ground from take-off to the cut
    for job, (r, _) in zip(fit, results):
        s = r[1][0][0] / 1e6
        if _config_id(job).endswith("phase"):  # a fifth of the way through the time off the ground
            assert s == pytest.approx(13.3 + 0.2 * air, abs=0.1)
        else:
            assert 13.3 + 0.1 * air - 0.1 <= s <= 13.3 + 0.5 * air + 0.1


@pytest.mark.parametrize(("after", "expected_s"), [("takeoff + 2 s", 15.3), ("climb", 16.1), ("cruise + 1.5 s", 25.0),
                                                    ("cruise 50 %", 28.25)])
def test_after_phase_reads_the_flights_own_phases(tmp_path, after, expected_s):
    """RflyMAD: take-off 13.3 s, climb 16.1 s, cruise 23.5-33.0 s (tests/test_phases.py)."""
    scenario = tmp_path / "s.toml"
    scenario.write_text(textwrap.dedent(f"""
        [scenario]
        id = "a"
        [[scenario.start]]
        condition = "after_phase"
        after = "{after}"
        [[scenario.end]]
        condition = "duration"
        seconds = 1.0
        [[scenario.actions]]
        action = "bias"
        target = ["vehicle_local_position.x"]
        offset = 5.0
    """))
    clock, fit, results = _replay(RFLYMAD, scenario)
    assert results[0][0][1][0][0] / 1e6 == pytest.approx(expected_s, abs=0.15)


@pytest.mark.parametrize("after", ["landing + 2 s", "takeoff - 2 s", "cruise 130 %", "cruise + 2"])
def test_after_phase_refuses_what_it_cannot_read(tmp_path, after):
    scenario = tmp_path / "s.toml"
    scenario.write_text(f'[scenario]\nid = "a"\n[[scenario.start]]\ncondition = "after_phase"\nafter = "{after}"\n'
                        '[[scenario.actions]]\naction = "bias"\ntarget = ["position"]\noffset = 5.0\n')
    with pytest.raises(ScenarioError, match=r"start\[0\]\.after: .*expected '<anchor> \+ <seconds> s'"):
        load_configurations(scenario, check_topics=False)


def test_a_log_without_gaps_keeps_its_triggers():
    """A generated flight (no gap, its triggers inside it) replays its scenarios unchanged."""
    jobs = load_configurations(QUICK, check_topics=False)
    t = np.arange(0, 120_000_000, 40_000)
    clock = LoggedClock().fit({"a": pd.DataFrame({"Timestamp": t})})
    assert clock.identity and np.array_equal(clock.to_logged(t), t)
    for job in jobs:
        moved, notes = log_triggers(job, clock, takeoff_us=10_000_000)
        assert moved == job and not notes


def test_a_killed_attack_leaves_nothing_the_next_attack_or_a_read_trips_over(tmp_path):
    """attack killed (no cleanup, as SIGKILL) while writing its third copy: the copies written are
    not in the manifest; the next attack removes them, adds every copy, and the dataset reads whole."""
    t = np.arange(0, 80_000_000, 100_000)
    pd.DataFrame({"timestamp": t, "roll": np.sin(t / 1e7), "pitch": np.cos(t / 1e7)}).to_csv(tmp_path / "attitude.csv",
                                                                                           index=False)
    ds = tmp_path / "ds"
    import_logs([tmp_path / "attitude.csv"], ds, split="test")
    killer = textwrap.dedent("""
        import os, sys
        import scart_bench.dataset.write as w
        real, n = w.write_flight, [0]
        def dying(*a, **k):
            n[0] += 1
            if n[0] == 3:
                os._exit(9)
            return real(*a, **k)
        w.write_flight = dying
        from scart_bench.cli.main import main
        sys.exit(main(sys.argv[1:]))
    """)
    grid = tmp_path / "four.toml"
    grid.write_text(SMALL_GRID.replace('action = ["bias", "add_white_noise"]', 'action = ["bias"]'))
    run = subprocess.run([sys.executable, "-c", killer, "attack", "--dataset", str(ds), "--scenario", str(grid)],
                         capture_output=True, text=True, env={**os.environ, "SCART_BENCH_PROGRESS_S": "0"})
    assert run.returncode == 9
    listed = set(open_dataset(ds).manifest["flight_id"])
    orphans = {p.name for p in (ds / "flights").iterdir()} - listed
    assert listed == {"log-attitude"} and len(orphans) == 2  # what the old code left for good
    said: list[str] = []
    ids = attack_dataset(ds, grid, sources=("test",), say=said.append)
    assert len(ids) == 4 and any("removed 2 flight folder(s)" in s for s in said)
    d = open_dataset(ds)
    assert {p.name for p in (ds / "flights").iterdir()} == set(d.manifest["flight_id"]) == {*ids, *listed}
    for fid in d.manifest["flight_id"]:
        d.verify(fid)  # checksums as written
        assert len(d.flight(fid))
    assert json.loads((ds / "flights" / ids[0] / "raw" / "config.json").read_text())["logged_time"]["logging_gaps"][
        "count"] == 0


def test_back_keeps_a_left_out_topic_only_where_its_labels_read_the_same_on_the_logs_time():
    """csv mode leaves a topic it passed unchanged out (None); mapping a copy back to the log's time
    keeps it out where every window holds the same rows on both clocks, and builds it as csv mode
    builds it (labels counted on the logged clock) where it cannot tell (rows out of order)."""
    from scart_bench.generator.modes import passed_table

    ts = np.r_[np.arange(0, 10_000_000, 100_000), np.arange(30_000_000, 40_000_000, 100_000)]  # a 20 s gap
    clock = LoggedClock().fit({"a": pd.DataFrame({"Timestamp": ts, "x": 0.0})})
    assert len(clock.gaps_) == 1
    shuffled = np.r_[ts[1::2], ts[::2]]
    log = {"sorted": pd.DataFrame({"Timestamp": ts, "x": np.arange(len(ts), dtype=float)}),
           "shuffled": pd.DataFrame({"Timestamp": shuffled, "x": np.arange(len(ts), dtype=float)})}
    replayed = clock.tables(log)
    windows = [(8_000_000, 12_000_000, "s1", "attack")]  # 4 s of logged time across the gap
    nav, wins, _ = clock.back(({"sorted": None, "shuffled": None}, windows, []), replayed)
    assert nav["sorted"] is None
    assert wins[0][1] - wins[0][0] > 20e6  # the window spans the gap on the log's time
    flag = passed_table(log["sorted"], wins)["Is_Anomaly"].to_numpy()
    want = passed_table(replayed["sorted"], windows)["Is_Anomaly"].to_numpy()
    assert np.array_equal(flag, want) and flag.sum() == 40  # 2 s before the gap and 2 s after it
    built = nav["shuffled"]
    assert np.array_equal(built["Timestamp"].to_numpy(), shuffled)
    assert np.array_equal(built["Is_Anomaly"].to_numpy(), passed_table(replayed["shuffled"], windows)["Is_Anomaly"])
    with pytest.raises(ValueError, match="replayed tables"):
        clock.back(({"sorted": None}, windows, []))
