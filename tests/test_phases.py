"""Mission phases derived from real logs (generator/logs/phases.py) on the shared PX4 and ArduPilot logs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scart_bench.generator.logs.importers import load_flight_file
from scart_bench.generator.logs.phases import (
    PHASES,
    TAKEOFF_HEIGHT_M,
    flight_phases,
    mission_progress,
    phase_at,
    phase_topic,
)

SHARED = Path(__file__).parents[1].parent / "shared/data"
RFLYMAD = SHARED / "ulog/rflymad_TestCase_1_1000000000.ulg"
EVENTS = SHARED / "ulog/sample_px4_events.ulg"
GROUND = SHARED / "ulog/sample_logging_tagged_and_default_params.ulg"
LOITER = SHARED / "dataflash/arducopter_loiter_rtl.bin"
CUT = SHARED / "dataflash/arducopter_181.bin"
needs = pytest.mark.skipif(not all(p.exists() for p in (RFLYMAD, EVENTS, GROUND, LOITER, CUT)),
                           reason=f"shared logs not found in {SHARED}")


@pytest.fixture(scope="module")
def logs():
    return {p.name: load_flight_file(p, allow_corrupt=True) for p in (RFLYMAD, EVENTS, GROUND, LOITER, CUT)}


def _runs(ph: pd.DataFrame) -> list[str]:
    names = ph["phase"].to_numpy(object)
    return list(names[np.r_[True, names[1:] != names[:-1]]])


@needs
@pytest.mark.parametrize("name", [RFLYMAD.name, EVENTS.name, LOITER.name])
def test_a_flight_starts_landed_takes_off_where_it_rises_and_ends_landed(logs, name):
    ph = flight_phases(logs[name])
    runs = _runs(ph)
    assert runs[0] == "landed" and runs[1] == "takeoff" and runs[-1] == "landed", runs
    assert set(runs) <= set(PHASES)
    up = ph["phase"].to_numpy(object) == "takeoff"
    first = np.flatnonzero(up)[0]
    h = ph["altitude_m"].to_numpy()
    # before take-off the vehicle sits on the ground; within the take-off it rises
    assert np.abs(h[:first]).max() < 0.5
    t = ph["Timestamp"].to_numpy()
    later = (t > t[first]) & (t < t[first] + 10e6)
    assert h[later].max() > h[first] + 1.0
    # every airborne phase is above the ground at some point, the cruise well above the take-off height
    cruise = ph["phase"].to_numpy(object) == "cruise"
    assert cruise.any() and np.median(h[cruise]) > TAKEOFF_HEIGHT_M


@needs
def test_sources_are_the_logs_own_land_detector_and_modes(logs):
    assert flight_phases(logs[RFLYMAD.name]).attrs == {
        "altitude": "vehicle_local_position.z", "landed": "vehicle_land_detected.landed",
        "mode": "vehicle_status.nav_state"}
    assert flight_phases(logs[LOITER.name]).attrs == {"altitude": "ctun.Alt", "landed": "ev.Id", "mode": "mode.Mode"}
    # PX4's AUTO_TAKEOFF navigation state is the take-off (sample_px4_events: 14.9 s .. 21.3 s, airborne from 16.7 s)
    ph = flight_phases(logs[EVENTS.name])
    t = ph["Timestamp"].to_numpy()
    assert set(ph["phase"][(t > 17e6) & (t < 21e6)]) == {"takeoff"}
    # ArduCopter's LAND mode (24.0 s .. 30.9 s of the loiter log) descends
    ph = flight_phases(logs[LOITER.name])
    t = ph["Timestamp"].to_numpy()
    assert set(ph["phase"][(t > 24.5e6) & (t < 30e6)]) == {"descent"}


@needs
def test_without_a_land_detector_altitude_and_vertical_speed_decide(logs):
    only_z = {"vehicle_local_position": logs[RFLYMAD.name]["vehicle_local_position"]}
    ph = flight_phases(only_z)
    assert ph.attrs["landed"] == "altitude" and ph.attrs["mode"] is None
    runs = _runs(ph)
    assert runs[0] == "landed" and "takeoff" in runs and "cruise" in runs and runs[-1] == "landed", runs
    # the take-off starts within a second of the land detector's own (13.26 s)
    t = ph["Timestamp"].to_numpy()
    start = t[np.flatnonzero(ph["phase"].to_numpy(object) == "takeoff")[0]] / 1e6
    assert 12.3 < start < 14.3


@needs
def test_a_log_on_the_ground_is_landed_throughout_and_a_cut_log_ends_in_the_air(logs):
    assert _runs(flight_phases(logs[GROUND.name])) == ["landed"]
    runs = _runs(flight_phases(logs[CUT.name]))  # the 181 log stops in flight (its last message is cut)
    assert runs[:2] == ["landed", "takeoff"] and runs[-1] != "landed"


@needs
def test_phase_at_labels_any_rows_and_mission_progress_counts_legs(logs):
    tables = logs[RFLYMAD.name]
    ph = flight_phases(tables)
    rows = tables["vehicle_gps_position"]["Timestamp"].to_numpy()
    labels = phase_at(ph, rows)
    assert labels.shape == rows.shape and labels[0] == "landed" and set(labels) <= set(PHASES)
    seq = mission_progress(ph, legs=5)
    cruise = np.flatnonzero(ph["phase"].to_numpy(object) == "cruise")
    assert (seq[: cruise[0]] == 0).all() and seq[cruise[0]] == 1 and seq.max() == 5
    assert (np.diff(seq) >= 0).all()
    topic = phase_topic(tables)
    assert list(topic.columns) == ["Timestamp", "phase", "seq"] and len(topic) == len(ph)


def test_no_altitude_is_a_clear_error():
    t = pd.DataFrame({"Timestamp": np.arange(10) * 100_000, "x": 0.0})
    with pytest.raises(ValueError, match="need an altitude; the log has none of vehicle_local_position.z"):
        flight_phases({"imu": t})
    assert phase_topic({"imu": t}) is None
