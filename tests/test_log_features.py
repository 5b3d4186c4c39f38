"""The feature rule on imported logs: DataFlash, tlog and ROS clocks, ids, counters and state flags are
not features, and no generated flight's field is caught by those names (its feature list is unchanged)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from scart_bench.dataset import combine
from scart_bench.dataset.schema import TOPICS, TRUTH_FIELDS
from scart_bench.detectors.base import (
    LOG_CONTROL_STATE_PATTERN,
    LOG_NON_FEATURE_PATTERN,
    feature_columns,
    is_feature_name,
)
from scart_bench.generator.flight_software.commander import CONTROL_TOPICS
from scart_bench.generator.logs.importers import load_flight_file
from scart_bench.generator.telemetry.schedule import SENSOR_TOPICS
from scart_bench.generator.telemetry.uorb import UORB_TOPICS

LOITER = Path(__file__).parents[1].parent / "shared/data/dataflash/arducopter_loiter_rtl.bin"


def _generated_fields() -> set[str]:
    """Every field name a generated flight can hold: link, sensor, command, truth and uORB views."""
    names = {f for t in TOPICS.values() for f in t.field_names}
    names |= {f for _, fields in SENSOR_TOPICS.values() for f in fields}
    names |= {f for fields in CONTROL_TOPICS.values() for f in fields}
    names |= {f for t in UORB_TOPICS.values() for f in t.fields}
    return names | set(TRUTH_FIELDS)


def test_the_log_names_catch_no_generated_field():
    log_rule = re.compile(LOG_NON_FEATURE_PATTERN + "|" + LOG_CONTROL_STATE_PATTERN)
    caught = sorted(f for f in _generated_fields() if log_rule.search(f))
    assert caught == []


@pytest.mark.parametrize("column", [
    "gps.TimeMS", "gps.Week", "gps.GMS", "gps.GWk", "gps.T", "imu.SampleUS", "gps_1.I", "ev.Id", "du32.Id",
    "err.Subsys", "err.ECode", "pm.NLon", "pm.NLoop", "pm.MaxT", "pm.I2CErr", "pm.INSErr", "mode.Mode",
    "mode.ModeNum", "mode.Rsn", "ubx1.Instance", "attitude.time_boot_ms", "timesync.tc1", "timesync.ts1",
    "sys_status.errors_count1", "sys_status.drop_rate_comm", "sys_status.onboard_control_sensors_health",
    "heartbeat.system_status", "heartbeat.custom_mode", "extended_sys_state.landed_state",
    "pose.header_stamp_sec", "pose.header_stamp_nanosec", "fix.header_seq"])
def test_imported_clocks_ids_counters_and_flags_are_not_features(column):
    assert not is_feature_name(column)


@pytest.mark.parametrize("column", [
    "gps.Lat", "gps.Lng", "gps.Alt", "gps.Spd", "gps.GCrs", "gps.VZ", "gps.HDop", "gps.NSats", "imu.AccX",
    "imu.GyrZ", "att.Roll", "att.ErrRP", "baro.Press", "ctun.Alt", "ekf1.PN", "curr.Volt", "mag.MagX",
    "global_position_int.lat", "attitude.roll"])
def test_measurements_stay_features(column):
    assert is_feature_name(column)


@pytest.mark.skipif(not LOITER.exists(), reason=f"{LOITER} not found")
def test_a_dataflash_flight_keeps_its_gps_position_and_drops_its_gps_clock():
    flight = combine(load_flight_file(LOITER, topics=["gps", "imu", "pm", "ev"]), [])["most_frequent"]
    cols, dropped = feature_columns([flight])
    assert {"gps.Lat", "gps.Lng", "imu.AccZ"} <= set(cols)
    assert {"gps.TimeMS", "gps.Week", "ev.Id", "pm.NLon"} <= set(dropped["timestamp, counter, id or reset"])
