"""Flight-log importers on the real reference ULogs in ../shared/data/ulog, CSV/Parquet tables and
scart-bench flight folders, including every bad-input error."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scart_bench.dataset import (
    DatasetError,
    DatasetWriter,
    FlightRecord,
    combine,
    label_rows,
    open_dataset,
)
from scart_bench.dataset.compact import float32_safe
from scart_bench.dataset.schema import HOME_LAT, HOME_LON, TOPICS
from scart_bench.generator.logs.importers import (
    TIME_COLUMNS,
    load_flight_file,
    sanitize_field_name,
    sanitize_topic_name,
    ulog_info,
)

ULOG_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ulog"
RFLYMAD = ULOG_DIR / "rflymad_TestCase_1_1000000000.ulg"
PX4_SAMPLE = ULOG_DIR / "px4_sample_log_small.ulg"

needs_ulogs = pytest.mark.skipif(not (RFLYMAD.exists() and PX4_SAMPLE.exists()),
                                 reason=f"reference ULogs not found in {ULOG_DIR}")

# What the reference logs hold (measured from the data, see test_reference_rates):
#   log -> (GPS topic, lat, lon, {topic: nominal rate Hz})
REFERENCE = {
    "rflymad": (RFLYMAD, "vehicle_gps_position", 40.1541, 116.2595,
                # sensor_gps is logged at only ~1 Hz in this log; the 10 Hz GPS stream is
                # vehicle_gps_position. sensor_combined runs at 250 Hz (4 ms median interval)
                # though the logger kept only ~187 messages/s.
                {"sensor_combined": 250.0, "vehicle_gps_position": 10.0, "sensor_gps": 1.0,
                 "vehicle_local_position": 10.0, "vehicle_global_position": 5.0}),
    "px4_sample": (PX4_SAMPLE, "vehicle_gps_position", 63.4171, 10.4082,
                   {"sensor_combined": 204.6, "vehicle_gps_position": 5.0, "vehicle_local_position": 102.3}),
}
NAME_RE = re.compile(r"^[A-Za-z0-9_]+$")


@pytest.fixture(scope="module")
def ulogs() -> dict[str, dict[str, pd.DataFrame]]:
    return {key: load_flight_file(ref[0]) for key, ref in REFERENCE.items()}


def _rates(ts: np.ndarray) -> tuple[float, float]:
    dt = np.diff(np.asarray(ts, dtype=np.int64))
    return 1e6 / float(np.median(dt)), (len(ts) - 1) * 1e6 / float(ts[-1] - ts[0])


# ----------------------------------------------------------------------------------------------
# reference ULogs


@needs_ulogs
@pytest.mark.parametrize("key", list(REFERENCE))
def test_reference_tables(ulogs, key):
    tables = ulogs[key]
    gps_topic = REFERENCE[key][1]
    for topic in ("sensor_combined", gps_topic, "vehicle_local_position", "vehicle_attitude"):
        assert topic in tables, f"{key}: {topic} missing"
    assert min(int(df["Timestamp"].iloc[0]) for df in tables.values()) == 0
    for topic, df in tables.items():
        assert NAME_RE.match(topic), topic
        assert df.columns[0] == "Timestamp"
        assert df["Timestamp"].dtype == np.int64
        assert (np.diff(df["Timestamp"].to_numpy()) > 0).all(), topic
        assert df["Timestamp"].iloc[0] >= 0
        assert "Is_Anomaly" not in df.columns and "timestamp" not in df.columns
        for col in df.columns[1:]:
            assert df[col].dtype == np.float64, (topic, col)
            assert NAME_RE.match(col) and "padding" not in col, (topic, col)
    combined = tables["sensor_combined"]
    assert {"gyro_rad_0", "gyro_rad_1", "gyro_rad_2", "accelerometer_m_s2_0", "accelerometer_m_s2_1",
            "accelerometer_m_s2_2"} <= set(combined.columns)
    # on the ground / in hover the body z specific force is about -g
    assert abs(np.median(combined["accelerometer_m_s2_2"]) + 9.81) < 0.5
    print(f"\n{key}: {len(tables)} topics; first samples: sensor_combined "
          f"{combined['Timestamp'].iloc[0] / 1e6:.3f} s, {gps_topic} {tables[gps_topic]['Timestamp'].iloc[0] / 1e6:.3f} s")


@needs_ulogs
@pytest.mark.parametrize("key", list(REFERENCE))
def test_reference_rates(ulogs, key):
    path, _, _, _, expected = REFERENCE[key]
    info = ulog_info(path)
    for topic, hz in expected.items():
        nominal, mean = _rates(ulogs[key][topic]["Timestamp"].to_numpy())
        print(f"\n{key}: {topic}: nominal {nominal:.2f} Hz (median interval), mean {mean:.2f} Hz, "
              f"{len(ulogs[key][topic])} messages")
        assert nominal == pytest.approx(hz, rel=0.10), (topic, nominal)
        assert info["topics"][topic]["rate_hz"] == pytest.approx(nominal)
        assert info["topics"][topic]["messages"] == len(ulogs[key][topic])
    if key == "rflymad":
        _, mean = _rates(ulogs[key]["sensor_combined"]["Timestamp"].to_numpy())
        assert 150 < mean < 250  # the logger skipped samples: mean rate below the 250 Hz nominal


@needs_ulogs
@pytest.mark.parametrize("key", list(REFERENCE))
def test_reference_lat_lon_degrees(ulogs, key):
    _, gps_topic, lat0, lon0, _ = REFERENCE[key]
    gps = ulogs[key][gps_topic]
    assert gps.attrs["converted"] == {"lat": "degE7 -> deg", "lon": "degE7 -> deg", "alt": "mm -> m",
                                      "alt_ellipsoid": "mm -> m"}
    lat, lon, alt = gps["lat"].to_numpy(), gps["lon"].to_numpy(), gps["alt"].to_numpy()
    assert np.abs(lat - lat0).max() < 1e-3 and np.abs(lon - lon0).max() < 1e-3  # within ~100 m
    np.testing.assert_allclose(np.rint(lat * 1e7) / 1e7, lat, rtol=0, atol=1e-12)  # full degE7 precision
    assert -100 < alt.min() and alt.max() < 1000  # metres AMSL, not millimetres
    print(f"\n{key}: {gps_topic} lat {lat.min():.7f}..{lat.max():.7f} lon {lon.min():.7f}..{lon.max():.7f} "
          f"alt {alt.min():.2f}..{alt.max():.2f} m")
    if "vehicle_global_position" in ulogs[key]:  # float degrees already: left as they are
        fused = ulogs[key]["vehicle_global_position"]
        assert "converted" not in fused.attrs
        assert abs(fused["lat"].median() - np.median(lat)) < 2e-5  # ~2 m


@needs_ulogs
def test_multi_instance_names_and_topic_filter(ulogs):
    tables = ulogs["rflymad"]
    for i in range(1, 6):
        assert f"estimator_global_position_{i}" in tables
        assert tables[f"estimator_global_position_{i}"].attrs["multi_id"] == i
    part = load_flight_file(RFLYMAD, topics=["sensor_gps", "estimator_global_position_2"])
    assert list(part) == ["sensor_gps", "estimator_global_position_2"]
    # time zero is the start of logging, with or without a topic filter
    origin = part["sensor_gps"].attrs["origin_us"]
    assert origin == tables["sensor_gps"].attrs["origin_us"] == 1_184_000  # ULog start_timestamp
    full = tables["sensor_gps"]
    np.testing.assert_array_equal(part["sensor_gps"]["Timestamp"], full["Timestamp"])
    pd.testing.assert_frame_equal(part["sensor_gps"].drop(columns="Timestamp"), full.drop(columns="Timestamp"))
    with pytest.raises(DatasetError, match=r"no_such_topic.*sensor_combined"):
        load_flight_file(RFLYMAD, topics=["no_such_topic"])


@needs_ulogs
def test_ulog_info():
    info = ulog_info(RFLYMAD)
    assert info["hardware"] == "PX4_SITL"
    assert info["start_us"] == 1_184_000 and info["duration_s"] == pytest.approx(36.145)
    assert info["start_utc"].startswith("2024-07-26")
    assert info["topics"]["sensor_combined"]["messages"] == 6759
    sample = ulog_info(PX4_SAMPLE)
    assert sample["hardware"] == "CUBEPILOT_CUBEORANGE" and sample["dropouts"] == 1
    with pytest.raises(DatasetError, match="no such file"):
        ulog_info(PX4_SAMPLE.with_name("nope.ulg"))


@needs_ulogs
def test_ulog_topic_to_csv_and_parquet_round_trip(ulogs, tmp_path):
    gps = ulogs["rflymad"]["vehicle_gps_position"]
    gps.to_csv(tmp_path / "vehicle_gps_position.csv", index=False)
    gps.to_parquet(tmp_path / "vehicle_gps_position.parquet", index=False)
    for name in ("vehicle_gps_position.csv", "vehicle_gps_position.parquet"):
        back = load_flight_file(tmp_path / name)["vehicle_gps_position"]
        shifted = gps.assign(Timestamp=gps["Timestamp"] - gps["Timestamp"].iloc[0])
        pd.testing.assert_frame_equal(back, shifted, check_exact=True)


# ----------------------------------------------------------------------------------------------
# synthetic scart-bench flights: combined tables and flight folders


def _synthetic_topics(seed: int = 0) -> dict[str, pd.DataFrame]:
    rng = np.random.default_rng(seed)
    out = {}
    for name, start in (("global_position_int", 4_000), ("gps_raw_int", 110_000), ("attitude", 8_000)):
        topic = TOPICS[name]
        ts = start + np.arange(int(10 * topic.rate_hz), dtype=np.int64) * int(1e6 / topic.rate_hz)
        df = pd.DataFrame({"Timestamp": ts, "Is_Anomaly": np.zeros(len(ts), dtype=np.int8)})
        for f in topic.field_names:
            df[f] = rng.normal(size=len(ts))
        if "lat" in df:
            df["lat"] = HOME_LAT + rng.normal(scale=1e-4, size=len(ts))
            df["lon"] = HOME_LON + rng.normal(scale=1e-4, size=len(ts))
        out[name] = df
    return out


def _expected(topics: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    """scart-bench's own tables keep their time (already from the flight's start)."""
    return {k: df.drop(columns="Is_Anomaly").reset_index(drop=True) for k, df in topics.items()}


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_combined_table_split(tmp_path, fmt):
    topics = _synthetic_topics()
    table = combine({k: v for k, v in topics.items()}, windows=[(2_000_000, 3_000_000)])["all_sensors"]
    assert {"Index", "Is_Anomaly", "global_position_int.lat"} <= set(table.columns)
    path = tmp_path / f"navigator_all_sensors.{fmt}"
    table.to_csv(path, index=False) if fmt == "csv" else table.to_parquet(path, index=False)
    loaded = load_flight_file(path)
    expected = _expected(topics)
    assert sorted(loaded) == sorted(expected)
    for name, df in expected.items():
        pd.testing.assert_frame_equal(loaded[name], df, check_exact=True)  # lat/lon bit-exact
        assert loaded[name].attrs["empty_rows_dropped"] == len(table) - len(df)


@pytest.mark.parametrize("fmt,layout", [("parquet", "paper"), ("csv", "paper"), ("parquet", "compact")])
def test_flight_folder_round_trip(tmp_path, fmt, layout):
    nav = _synthetic_topics(1)
    windows = [(3_000_000, 5_000_000)]
    for df in nav.values():
        df["Is_Anomaly"] = label_rows(df["Timestamp"].to_numpy(), windows)
    record = FlightRecord("f0001", navigator=nav, simulator=_synthetic_topics(2), manifest={"mode": "csv"},
                          config={}, windows=windows)
    writer = DatasetWriter(tmp_path / "ds", fmt=fmt, layout=layout)
    writer.write(record)
    writer.close()
    flight = tmp_path / "ds" / "flights" / "f0001"
    loaded = load_flight_file(flight)
    for name, df in _expected(nav).items():
        if layout == "compact":  # fields other than latitude/longitude are kept as float32
            df = df.astype({c: np.float32 for c in df.columns if float32_safe(name, c)}).astype(
                {c: np.float64 for c in df.columns if float32_safe(name, c)})
            assert all(not float32_safe(name, c) for c in ("lat", "lon")) and "Timestamp" in df
        pd.testing.assert_frame_equal(loaded[name], df, check_exact=True)  # lat/lon bit-exact
    # the combined table of the same flight splits back into the same topics
    combined_path = flight / "combined" / f"navigator_all_sensors.{fmt}"
    if layout == "compact":
        combined_path = tmp_path / "all_sensors.parquet"
        open_dataset(tmp_path / "ds").flight("f0001", table="all_sensors").to_parquet(combined_path)
    combined = load_flight_file(combined_path)
    for name in nav:
        pd.testing.assert_frame_equal(combined[name], loaded[name], check_exact=True)
    assert list(load_flight_file(flight, topics=["attitude"])) == ["attitude"]
    with pytest.raises(DatasetError, match="pass one flight folder"):
        load_flight_file(tmp_path / "ds")


def test_single_topic_csv_rules(tmp_path):
    path = tmp_path / "My Flight-3.csv"
    path.write_text("Index,time_s,x,Speed (m/s),flag\n"
                    "0,0.5,1.0,2.0,True\n"
                    "1,0.25,3.0,,False\n"
                    "2,0.5,1.0,2.0,True\n"
                    "3,0.75,,,\n")
    tables = load_flight_file(path)
    assert list(tables) == ["my_flight_3"]
    df = tables["my_flight_3"]
    assert list(df.columns) == ["Timestamp", "x", "Speed_m_s", "flag"]
    assert df["Timestamp"].tolist() == [0, 250_000]  # seconds -> us, sorted, rebased
    assert df["x"].tolist() == [3.0, 1.0]  # a repeated 0.5 s row is dropped (a different one is refused)
    assert df.attrs["duplicates_dropped"] == 1 and df.attrs["empty_rows_dropped"] == 1
    assert df.attrs["origin_us"] == 250_000
    assert all(df[c].dtype == np.float64 for c in df.columns[1:])


def test_time_column_names(tmp_path):
    """A name with a unit is taken at its word; generic names infer the unit (a 10 Hz, 2 s log)."""
    per_unit = {"ns": 1000, "us": 1, "ms": 0.001, "s": 1e-6}
    for name in (*TIME_COLUMNS, "Timestamp", "TIME_USEC"):
        unit = TIME_COLUMNS.get(name.lower()) or "us"
        ts = [v * per_unit[unit] for v in range(1_000_000, 3_000_001, 100_000)]
        text = "\n".join(f"{t:.6f},{i}" if unit == "s" else f"{int(t)},{i}" for i, t in enumerate(ts))
        (tmp_path / "a.csv").write_text(f"{name},v\n{text}\n")
        got = load_flight_file(tmp_path / "a.csv")["a"]["Timestamp"].tolist()
        assert got[:3] == [0, 100_000, 200_000] and got[-1] == 2_000_000, name


def test_name_sanitising():
    assert sanitize_field_name("accelerometer_m_s2[0]") == "accelerometer_m_s2_0"
    assert sanitize_field_name("current.lat") == "current_lat"
    assert sanitize_topic_name("My Flight-3") == "my_flight_3"


# ----------------------------------------------------------------------------------------------
# bad inputs


def test_missing_and_unknown_files(tmp_path):
    with pytest.raises(DatasetError, match=r"nope\.ulg: no such file"):
        load_flight_file(tmp_path / "nope.ulg")
    (tmp_path / "log.txt").write_text("timestamp,x\n1,2\n")
    with pytest.raises(DatasetError, match=r"log\.txt: unknown file type '\.txt'.*\.ulg.*\.csv.*\.parquet"):
        load_flight_file(tmp_path / "log.txt")
    (tmp_path / "folder").mkdir()
    with pytest.raises(DatasetError, match="sensors/navigator"):
        load_flight_file(tmp_path / "folder")


@needs_ulogs
def test_bad_ulogs(tmp_path, caplog):
    data = PX4_SAMPLE.read_bytes()
    cases = {
        "garbage.ulg": (np.random.default_rng(0).bytes(4096), "not a readable PX4 ULog"),
        "csv_named.ulg": (b"timestamp,x\n1,2\n", "not a readable PX4 ULog"),
        "zero.ulg": (b"", "not a readable PX4 ULog"),
        "header_only.ulg": (data[:16], "empty log"),
        "cut_in_definitions.ulg": (data[:3000], "corrupt"),
    }
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(DatasetError, match=message) as err:
            load_flight_file(tmp_path / name)
        assert name in str(err.value)
    # corruption in the middle of the data: refused, unless the readable part is asked for
    bad = tmp_path / "corrupt_mid.ulg"
    bad.write_bytes(data[:400_000] + np.random.default_rng(1).bytes(20_000) + data[420_000:])
    with pytest.raises(DatasetError, match="corrupt.*allow_corrupt"):
        load_flight_file(bad)
    part = load_flight_file(bad, allow_corrupt=True)
    assert "sensor_combined" in part and part["sensor_combined"].attrs["file_corruption"]
    # a truncated log (power cut, copied while written): refused, saying how much is readable,
    # unless that is asked for (then a warning says how much was read)
    (tmp_path / "half.ulg").write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match=r"half\.ulg: the ULog is truncated.*bytes.*s of logging.*--allow-corrupt"):
        load_flight_file(tmp_path / "half.ulg")
    with caplog.at_level("WARNING"):
        assert "sensor_combined" in load_flight_file(tmp_path / "half.ulg", allow_corrupt=True)
    assert re.search(r"truncated; using the \d+\.\d s of logging read", caplog.text)
    # definitions but no data messages
    from pyulog import ULog
    ULog(str(PX4_SAMPLE), []).write_ulog(str(tmp_path / "no_data.ulg"))
    with pytest.raises(DatasetError, match="no_data.ulg: the ULog has no logged messages"):
        load_flight_file(tmp_path / "no_data.ulg")


def test_bad_csvs(tmp_path):
    def fails(text: str, *patterns: str, name: str = "bad.csv") -> None:
        path = tmp_path / name
        path.write_text(text)
        with pytest.raises(DatasetError) as err:
            load_flight_file(path)
        message = str(err.value)
        assert name in message
        for p in patterns:
            assert re.search(p, message), (p, message)

    accepted = list(TIME_COLUMNS)
    fails("clock,x\n1,2\n", "no timestamp column", *[re.escape(repr(n)) for n in accepted], "'clock'")
    fails("timestamp,x,y\n1,2,3\n2,3,4\n3,oops,5\n", r"column 'x'.*'oops'.*row 3 \(line 4")
    fails("", "empty")
    fails("timestamp,x\n", "empty")
    fails("timestamp\n1\n2\n", "no data columns")
    fails("timestamp,x\n1.5,2\n", r"'timestamp'.*fewer than two distinct times.*timestamp_us")
    # ambiguous units (1 ms or 1 s apart, over 10 s or 10000 s): refused, naming the column
    fails("time,x\n" + "".join(f"{i * 1000},{i}\n" for i in range(10_001)), r"'time'.*ambiguous \(us or ms\)")
    fails("timestamp,x\n1,2\n,3\n", r"time column 'timestamp'.*row 2")
    fails("timestamp,x,x\n1,2,3\n", r"duplicate column.*'x'")
    fails("Index,Timestamp,Is_Anomaly,gps.lat\n0,1,0,\n", "empty")  # every row empty
    pd.DataFrame({"timestamp": [1, 2], "x": ["1", "b"]}).to_parquet(tmp_path / "bad.parquet")
    with pytest.raises(DatasetError, match=r"bad\.parquet: column 'x'.*'b'.*row 2"):
        load_flight_file(tmp_path / "bad.parquet")
    (tmp_path / "junk.parquet").write_bytes(b"not parquet")
    with pytest.raises(DatasetError, match=r"junk\.parquet: not a readable Parquet"):
        load_flight_file(tmp_path / "junk.parquet")


def test_reference_ulog_copy_with_other_case_extension(tmp_path):
    if not PX4_SAMPLE.exists():
        pytest.skip("reference ULog missing")
    copy = tmp_path / "LOG001.ULG"
    shutil.copy(PX4_SAMPLE, copy)
    assert "vehicle_gps_position" in load_flight_file(copy, topics=["vehicle_gps_position"])
