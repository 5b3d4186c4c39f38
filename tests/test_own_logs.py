"""Your own flights: real PX4 logs and CSVs made from them -> dataset -> attacks -> benchmark run."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scart_bench.benchmark.store import RunStore
from scart_bench.cli.main import main
from scart_bench.dataset import DatasetError, append_flights, combine, flight_record, open_dataset
from scart_bench.detectors.base import NON_FEATURE_FIELDS, Detector, DetectorError, feature_columns
from scart_bench.detectors.statistical import Statistical
from scart_bench.generator.logs.importers import load_flight_file
from scart_bench.generator.logs.offline import auto_splits, import_ids, import_logs

# CI clones the repository with shared/ beside it
SHARED = Path(__file__).parents[1].parent / "shared/data/ulog"
RFLYMAD = SHARED / "rflymad_TestCase_1_1000000000.ulg"
PX4_SAMPLE = SHARED / "px4_sample_log_small.ulg"
SCENARIOS = Path(__file__).parents[1] / "data" / "scenarios"
needs_ulogs = pytest.mark.skipif(not (RFLYMAD.exists() and PX4_SAMPLE.exists()),
                                 reason=f"shared PX4 logs not found in {SHARED} (clone shared/ beside the repo)")
TOPICS = ("vehicle_gps_position,sensor_gps,vehicle_global_position,vehicle_local_position,vehicle_attitude,"
          "sensor_combined,vehicle_air_data,vehicle_magnetometer,battery_status,mission_result")


def csv_from_log(log: Path, out: Path, unit: str = "ns", topics: str = TOPICS) -> Path:
    """A wide CSV (``timestamp`` in ``unit`` since boot, ``topic.field`` columns) made from a log."""
    tables = load_flight_file(log, topics=[t for t in topics.split(",") if t])
    wide = combine(tables, [])["all_sensors"].drop(columns=["Index", "Is_Anomaly", "Anomaly_Ids", "Anomaly_Kind"])
    origin = next(iter(tables.values())).attrs["origin_us"]
    factor = {"ns": 1000, "us": 1, "ms": 1e-3, "s": 1e-6}[unit]
    ts = (wide.pop("Timestamp") + origin) * factor
    wide.insert(0, "timestamp", ts if unit in ("ms", "s") else ts.astype(np.int64))
    wide.to_csv(out, index=False)
    return out


@pytest.fixture(scope="module")
def rflymad_csv(tmp_path_factory) -> Path:
    """The RflyMAD log's main topics as one CSV (nanosecond timestamps), made once."""
    return csv_from_log(RFLYMAD, tmp_path_factory.mktemp("csv") / "rflymad.csv", topics=TOPICS)


def _detected_inside_window(run: Path, ds_path: Path, detector: str, flight_id: str) -> bool:
    metrics = pd.read_csv(run / "metrics.csv").set_index("detector")
    scores = RunStore(run).read_scores(detector)[flight_id]
    ds = open_dataset(ds_path)
    row = ds.manifest.set_index("flight_id").loc[flight_id]
    ts = ds.flight(flight_id, columns=["Timestamp"])["Timestamp"].to_numpy()
    inside = (ts >= row["attack_start_us"]) & (ts < row["attack_end_us"])
    return bool((scores[inside] > metrics.loc[detector, "row_threshold"]).any())


@needs_ulogs
def test_own_logs_to_a_leaderboard_row_per_detector(tmp_path, capsys):
    """Acceptance: import the two shared ULogs (trimmed windows) and CSVs made from them, attack the
    test flights with a shipped example unchanged, run statistical and deepsvdd on the dataset."""
    ds = tmp_path / "ds"
    csv = csv_from_log(RFLYMAD, tmp_path / "rflymad_export.csv")
    px4_csv = csv_from_log(PX4_SAMPLE, tmp_path / "px4_sample_export.csv", unit="us",
                           topics="vehicle_gps_position,vehicle_local_position,sensor_combined")
    steps = [
        [str(RFLYMAD), "--split", "train"],
        [str(RFLYMAD), "--split", "train", "--start", "2"],
        [str(csv), "--split", "train", "--start", "1"],
        [str(RFLYMAD), "--split", "validation", "--start", "4"],
        [str(csv), "--split", "validation", "--start", "3"],
        [str(RFLYMAD), "--split", "test", "--start", "1"],
        [str(PX4_SAMPLE), str(px4_csv), "--split", "csv_source"],  # other topics: sources only
    ]
    for args in steps:
        topics = TOPICS if "px4" not in args[0] else "vehicle_gps_position,vehicle_local_position,sensor_combined"
        assert main(["import", *args, "--out", str(ds), "--topics", topics]) == 0, capsys.readouterr().err
    assert "import: read 2/2, written 2/2 logs in " in capsys.readouterr().err  # the last import: two logs
    manifest = open_dataset(ds).manifest
    assert manifest["flight_id"].is_unique and len(manifest) == 8
    assert set(manifest["split"]) == {"train", "validation", "test", "csv_source"}
    # the CSV's nanoseconds were recognised: same duration as the log (time zero: its first row)
    durations = manifest.set_index("flight_id")["duration_s"]
    assert abs(durations["log-rflymad_export-1s-end"] - durations["log-rflymad_testcase_1_1000000000-1s-end"]) < 1.5

    assert main(["attack", "--dataset", str(ds), "--scenario", str(SCENARIOS / "sensor_gps_jump.toml")]) == 0
    assert "attack: read 1/1, replayed 1/1 flights in " in capsys.readouterr().err  # one test flight, one copy
    attacked = "csv-log-rflymad_testcase_1_1000000000-1s-end-sensor-gps-jump"
    row = open_dataset(ds).manifest.set_index("flight_id").loc[attacked]
    assert row["mode"] == "csv" and row["split"] == "test"
    assert row["attack_end_us"] - row["attack_start_us"] == pytest.approx(10e6, abs=0.2e6)

    run = tmp_path / "run"
    assert main(["run", "--dataset", str(ds), "--detectors", "statistical,deepsvdd", "--out", str(run)]) == 0
    table = capsys.readouterr().out
    assert re.search(r"\| statistical +\|.*\| OK +\|", table) and re.search(r"\| deepsvdd +\|.*\| OK +\|", table)
    assert any(_detected_inside_window(run, ds, d, attacked) for d in ("statistical", "deepsvdd"))


#: the 2,048-configuration grids take minutes in csv mode: tests/test_log_grids.py checks which of theirs apply
BIG_GRIDS = ("paper", "paper_single")


@needs_ulogs
@pytest.mark.parametrize("path", [p for p in sorted(SCENARIOS.glob("*.toml")) if p.stem not in BIG_GRIDS],
                         ids=lambda p: p.stem)
def test_every_example_applies_to_a_ulog_and_its_csv_or_is_refused_naming_the_topic(tmp_path, capsys, path,
                                                                                       rflymad_csv):
    for log in (RFLYMAD, rflymad_csv):
        out = tmp_path / f"out-{log.suffix[1:]}"
        code = main(["attack", "--input", str(log), "--scenario", str(path), "--out", str(out),
                     *(["--topics", TOPICS] if log.suffix == ".ulg" else [])])
        err = capsys.readouterr().err
        if code == 0:
            assert open_dataset(out).manifest["mode"].eq("csv").all()
        else:
            assert code == 2 and not out.exists()
            assert re.search(r"(unknown topic|quantity\) matches no topic|is not in this input) .*'[a-z_.]+'|"
                             r"'[a-z_.]+' \(a quantity\) matches no topic|(change the physics|the flight controller or the "
                             r"navigator), which a recorded flight cannot replay|never started .*: its start conditions \(.+\) never held", err), err
    # gps_spoof and sensor_gps_drift start after mission item 1, which the RflyMAD log (no mission items)
    # reaches by its phases (generator/logs/phases.py)
    if path.stem in ("sensor_gps_jump", "gps_spoof", "sensor_gps_drift", "quick", "standard"):
        assert code == 0, f"{path.name} should apply unchanged to a PX4 log"


@needs_ulogs
def test_a_condition_on_a_topic_the_input_lacks_is_exit_2_naming_it(tmp_path, capsys):
    only_gps = csv_from_log(RFLYMAD, tmp_path / "gps_only.csv", topics="vehicle_gps_position")
    out = tmp_path / "out"
    assert main(["attack", "--input", str(only_gps), "--scenario", str(SCENARIOS / "sensor_gps_jump.toml"),
                 "--out", str(out)]) == 2
    assert "'altitude' (a quantity) matches no topic" in capsys.readouterr().err and not out.exists()


@needs_ulogs
def test_time_zero_is_the_start_of_logging_with_or_without_topics():
    full = load_flight_file(RFLYMAD)
    part = load_flight_file(RFLYMAD, topics=["vehicle_gps_position"])
    for t in ("vehicle_gps_position",):
        pd.testing.assert_series_equal(full[t]["Timestamp"], part[t]["Timestamp"])
    assert full["vehicle_gps_position"].attrs["origin_us"] == 1_184_000
    assert part["vehicle_gps_position"]["Timestamp"].iloc[0] == 5_796_000 - 1_184_000


@needs_ulogs
def test_time_units_give_the_same_duration_and_ambiguity_is_refused(tmp_path):
    paths = [csv_from_log(RFLYMAD, tmp_path / f"log_{unit}.csv", unit=unit, topics="vehicle_gps_position")
             for unit in ("ns", "us", "ms", "s")]
    import_logs(paths, tmp_path / "ds")
    durations = open_dataset(tmp_path / "ds").manifest.set_index("flight_id")["duration_s"]
    assert durations.max() - durations.min() < 1e-5, durations
    assert 31.0 < durations["log-log_us"] < 31.6  # 5.8 s .. 37.3 s of the log: GPS messages at 10 Hz
    (tmp_path / "amb.csv").write_text("timestamp,x\n" + "".join(f"{i * 1000},{i}\n" for i in range(20_000)))
    with pytest.raises(DatasetError, match=r"amb\.csv: time column 'timestamp'.*ambiguous"):
        load_flight_file(tmp_path / "amb.csv")


def test_ros_export_columns_make_one_topic_named_after_the_file(tmp_path):
    t = np.arange(50) * 20_000_000 + 1_600_000_000_000_000_000  # ROS %time: ns since the epoch
    pd.DataFrame({"%time": t, "field.header.seq": np.arange(50), "field.x": np.arange(50) * 0.1,
                  "field.y": 1.0}).to_csv(tmp_path / "mavros_local_position.csv", index=False)
    tables = load_flight_file(tmp_path / "mavros_local_position.csv")
    assert list(tables) == ["mavros_local_position"]
    df = tables["mavros_local_position"]
    assert list(df.columns) == ["Timestamp", "header_seq", "x", "y"] and df["Timestamp"].iloc[-1] == 49 * 20_000


@needs_ulogs
def test_rflymad_features_exclude_clocks_ids_counters_and_score_without_error():
    """+inf limit fields, late-starting topics and reset counters: every detector input is finite."""
    tables = load_flight_file(RFLYMAD)
    flight = combine(tables, [])["most_frequent"]
    cols, dropped = feature_columns([flight])
    names = [c.partition(".")[2] for c in cols]
    for bad in ("timestamp_sample", "time_utc_usec", "device_id", "delta_q_reset_0", "quat_reset_counter",
                "xy_reset_counter", "timestamp_time_relative"):
        assert bad not in names
        assert any(c.endswith("." + bad) for group in dropped.values() for c in group), bad
    assert "vehicle_local_position.vxy_max" in dropped["constant or missing"]  # +inf everywhere: missing
    assert not any(NON_FEATURE_FIELDS.search(n) for n in names)
    assert "vehicle_gps_position.lat" in cols and "sensor_combined.accelerometer_m_s2_2" in cols
    det = Statistical().fit([flight])
    s = det.score(flight)
    assert np.isfinite(s).all() and s.shape == (len(flight),)
    # NaN-aware statistics: lat's scale is the GPS's own spread (metres), not 0-filled leading rows
    j = det.columns_.index("vehicle_gps_position.lat")
    assert det.scale_[j] < 1e-4


class _Exploding(Detector):
    name = "exploding"

    def __init__(self, columns=None):
        self.columns = columns

    def _fit(self, X_list):
        pass

    def _score(self, X):
        return np.where(np.abs(X).max(axis=1) > 50, np.inf, 0.0)


def test_a_non_finite_score_names_the_column_and_row():
    t = np.arange(100) * 20_000
    train = pd.DataFrame({"Timestamp": t, "a.x": np.sin(t / 1e5), "a.y": np.cos(t / 1e5)})
    test = train.copy()
    test.loc[60, "a.y"] = 1e6
    det = _Exploding().fit([train])
    with pytest.raises(DetectorError, match=r"non-finite score inf at row 60: column 'a\.y'"):
        det.score(test)


def test_import_ids_are_stable_and_unique_and_auto_split_is_deterministic(tmp_path):
    a, b = Path("x/flight.ulg"), Path("y/flight.csv")
    assert import_ids([a]) == ["log-flight"]
    assert import_ids([a, b]) == ["log-x-flight", "log-y-flight"]
    assert import_ids([a], 2.5, 30) == ["log-flight-2p5s-30s"]
    ids = [f"log-{i}" for i in range(10)]
    s = auto_splits(ids, seed=3)
    assert s == auto_splits(list(reversed(ids)), seed=3)[::-1]  # by id, not order
    assert {"train", "validation", "test", "csv_source"} == set(s) and s.count("train") == 4
    assert s.count("validation") == 4  # a third (at least 2): the thresholds' flights
    assert auto_splits(ids, seed=4) != s


def test_a_failing_import_or_append_leaves_the_dataset_as_it_was(tmp_path):
    def log(name: str) -> Path:
        path = tmp_path / name
        pd.DataFrame({"timestamp_us": np.arange(100) * 20_000, "v": np.arange(100.0)}).to_csv(path, index=False)
        return path

    bad = tmp_path / "bad.csv"
    bad.write_text("timestamp_us,v\n0,1\n20000,oops\n")
    ds = tmp_path / "ds"
    import_logs([log("good.csv")], ds)
    before = open_dataset(ds).manifest.copy()
    with pytest.raises(DatasetError, match=r"bad\.csv: column 'v'"):
        import_logs([log("other.csv"), bad], ds, split="test")
    with pytest.raises(DatasetError, match="already in the dataset"):
        import_logs([tmp_path / "good.csv"], ds)

    def records():  # the second record fails while the first is already written
        tables = load_flight_file(tmp_path / "other.csv")
        yield flight_record("new-1", tables, tables, {"split": "test"}, {})
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        append_flights(ds, records())
    pd.testing.assert_frame_equal(open_dataset(ds).manifest, before)
    assert sorted(p.name for p in (ds / "flights").iterdir()) == ["log-good"]
    import_logs([tmp_path / "other.csv"], ds, split="test")  # and a good append goes through
    assert list(open_dataset(ds).manifest["flight_id"]) == ["log-good", "log-other"]
