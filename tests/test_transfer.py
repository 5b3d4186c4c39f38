"""Train here, test there: a transfer run trained on generated flights and tested on imported PX4 logs
with attacked copies, from the command line (benchmark.transfer)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from run_fixtures import plugin, write_dataset

from scart_bench.benchmark.transfer import column_meanings, resample, shared_table
from scart_bench.cli.main import main

SHARED = Path(__file__).parents[1].parent / "shared/data/ulog"
ULOGS = sorted(SHARED.glob("*.ulg"))
SCENARIOS = Path(__file__).parents[1] / "data" / "scenarios"
TOPICS = ("vehicle_gps_position,vehicle_local_position,vehicle_attitude,sensor_combined,vehicle_air_data,"
          "vehicle_magnetometer,battery_status,actuator_armed,vehicle_status")
ZS = plugin("ZScore")
needs_ulogs = pytest.mark.skipif(len(ULOGS) < 4, reason=f"shared PX4 logs not found in {SHARED}")


@pytest.fixture(scope="module")
def datasets(tmp_path_factory) -> tuple[Path, Path]:
    """(generated, real): 3 generated normal flights (train, validation, test); the 4 shared ULogs
    imported with --split auto and attacked with the 50 m GPS jump (by meaning) wherever it applies."""
    root = tmp_path_factory.mktemp("transfer")
    gen, real = root / "gen", root / "real"
    assert main(["generate", "--profile", "quick", "--flights", "3", "--normal-only", "--out", str(gen)]) == 0
    assert main(["import", *map(str, ULOGS), "--out", str(real), "--split", "auto", "--topics", TOPICS]) == 0
    assert main(["attack", "--dataset", str(real), "--scenario", str(SCENARIOS / "sensor_gps_jump.toml"),
                 "--sources", "train,validation,test,csv_source"]) == 0
    return gen, real


@needs_ulogs
def test_a_transfer_run_trains_on_generated_flights_and_tests_on_real_logs(datasets, tmp_path, capsys):
    gen, real = datasets
    out = tmp_path / "run"
    capsys.readouterr()
    assert main(["run", "--train-dataset", str(gen), "--dataset", str(real), "--detectors", "statistical,tsbitmaps",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr()
    # the table says where each number comes from
    assert f"Trained and calibrated on {gen}" in printed.out and f"TP and TN on {real}" in printed.out
    assert f"False alarms, normal flights ({real.name})" in printed.out and f"Threshold from ({gen.name})" in printed.out
    assert "quantities shared by meaning" in printed.err
    config = json.loads((out / "config.json").read_text())
    assert config["train_dataset"]["path"] == str(gen.resolve()) and config["dataset"]["path"] == str(real.resolve())
    assert config["identity"]["train_dataset_fingerprint"] and "transfer" in config["identity"]
    shared = config["transfer"]["columns"]
    # PX4 quaternions become Euler angles; lat/lon become metres from the first fix
    assert {"attitude.roll", "imu.zacc", "gps.north", "gps.east"} <= set(shared)
    assert not any(c.endswith((".lat", ".lon")) for c in shared)
    assert "attitude.q" not in shared  # the quaternion's parts are not a quantity of their own
    flights = pd.read_csv(out / "flights.csv")
    by_role = flights.groupby("role")["dataset"].agg(set).to_dict()
    assert by_role["train"] == {str(gen)} and by_role["validation"] == {str(gen)}
    assert by_role["test_normal"] == {str(real)} and by_role["test_attacked"] == {str(real)}
    assert (flights["role"] == "test_normal").sum() == 4  # every real normal flight, whatever its split
    metrics = pd.read_csv(out / "metrics.csv").set_index("detector")
    assert (metrics["n_no_attack"] == 4).all() and (metrics["n_csv"] >= 1).all()
    md = (out / "metrics.md").read_text()
    assert "## Train here, test there" in md and f"`{gen}`" in md
    dropped = pd.read_csv(out / "columns.csv")
    assert set(dropped["dataset"]) == {"train", "test"}
    assert "vehicle_attitude.q_0" not in set(dropped["column"])  # used (as Euler angles), not dropped
    # the report shows the false-alarm rate on the real normal flights and the TP on their attacked copies
    assert main(["report", str(out), "--out", str(tmp_path / "report"), "--no-figures"]) == 0
    board = (tmp_path / "report" / "leaderboard.md").read_text()
    assert "Train here, test there" in board and f"False alarms, normal flights ({real.name})" in board
    # a live monitor (proxy/ros/defend --run) cannot stream columns by meaning: refused in one line
    from scart_bench.benchmark.live import monitor_from_run
    from scart_bench.errors import ScartBenchError

    with pytest.raises(ScartBenchError, match="a transfer run"):
        monitor_from_run(out, "statistical")

    # resume: same identity, nothing rerun; another train dataset is another identity (refused, nothing written)
    assert main(["run", "--train-dataset", str(gen), "--dataset", str(real), "--detectors", "statistical",
                 "--out", str(out), "--resume"]) == 0
    before = (out / "config.json").read_text()
    assert main(["run", "--dataset", str(real), "--train-dataset", str(real), "--detectors", "statistical",
                 "--out", str(out)]) == 2
    assert (out / "config.json").read_text() == before


@needs_ulogs
def test_transfer_runs_are_deterministic(datasets, tmp_path):
    gen, real = datasets
    scores = []
    for name in ("a", "b"):
        assert main(["run", "--train-dataset", str(gen), "--dataset", str(real), "--detectors", "statistical",
                     "--out", str(tmp_path / name)]) == 0
        with np.load(tmp_path / name / "jobs" / "statistical" / "scores.npz") as z:
            scores.append({k: z[k] for k in z.files})
    assert scores[0].keys() == scores[1].keys()
    assert all(np.array_equal(scores[0][k], scores[1][k]) for k in scores[0])


@needs_ulogs
def test_bad_transfer_input_is_one_line_and_writes_nothing(datasets, tmp_path, capsys):
    gen, real = datasets
    out = tmp_path / "run"
    cases = [
        (["--train-dataset", str(tmp_path / "missing"), "--dataset", str(real)], "missing: not a dataset"),
        (["--train-dataset", str(gen)], "--train-dataset"),  # no --dataset to test on
    ]
    for args, needle in cases:
        capsys.readouterr()
        assert main(["run", *args, "--detectors", "statistical", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and needle in err, err
        assert not out.exists()
    # a real dataset sharing no quantity with the train dataset: refused naming both
    bare = tmp_path / "bare.csv"
    pd.DataFrame({"timestamp_us": np.arange(0, 20_000_000, 20_000), "rpm": 1.0}).to_csv(bare, index=False)
    assert main(["import", str(bare), "--out", str(tmp_path / "bare"), "--split", "test"]) == 0
    capsys.readouterr()
    assert main(["run", "--train-dataset", str(gen), "--dataset", str(tmp_path / "bare"), "--detectors",
                 "statistical", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no quantity is in every flight of both" in err, err
    assert not out.exists()


def test_columns_map_by_meaning_and_units():
    ts = np.arange(0, 2_000_000, 4_000, dtype=np.int64)
    n = ts.size
    px4 = pd.DataFrame({"Index": np.arange(n), "Timestamp": ts, "Is_Anomaly": np.zeros(n, np.int8),
                        "vehicle_local_position.vx": 1.0, "vehicle_air_data.baro_pressure_pa": 101325.0 - ts / 1e5,
                        "vehicle_attitude.q_0": np.cos(0.25), "vehicle_attitude.q_1": 0.0,
                        "vehicle_attitude.q_2": 0.0, "vehicle_attitude.q_3": np.sin(0.25),
                        "vehicle_gps_position.lat": 40.0 + np.arange(n) * 1e-7, "vehicle_gps_position.lon": 116.0,
                        "actuator_armed.armed": 1, "cpuload.load": 0.3})
    assert column_meanings(px4.columns)["velocity.vn"] == "vehicle_local_position.vx"
    t = shared_table(px4)
    assert "cpuload.load" not in t.columns and "actuator_armed.armed" in t.columns
    assert np.allclose(t["attitude.yaw"], 0.5) and np.allclose(t["attitude.roll"], 0.0)
    assert t["baro.pressure"].iloc[0] == 0.0 and np.isclose(t["baro.pressure"].iloc[-1], -ts[-1] / 1e7)  # hPa
    assert np.isclose(t["gps.north"].iloc[-1], (n - 1) * 1e-7 * 111_034, rtol=2e-3)  # metres north, 40 deg N
    ardupilot = pd.DataFrame({"Timestamp": ts, "Is_Anomaly": np.zeros(n, np.int8), "att.Yaw": 90.0,
                              "mag.MagX": 200.0, "mag.MagY": 0.0, "mag.MagZ": 400.0 + 0.1 * np.arange(n)})
    t = shared_table(ardupilot)
    # deg -> rad; mG -> G, and the field (the site's) as its change since the flight's start
    assert np.allclose(t["attitude.yaw"], np.pi / 2) and np.allclose(t["mag.z"], 1e-4 * np.arange(n))
    # resampling keeps an attacked row's label
    lab = np.zeros(n, np.int8)
    lab[101] = 1
    r = resample(px4.assign(Is_Anomaly=lab), 20_000)
    assert len(r) == 100 and r["Is_Anomaly"].sum() == 1 and r["Timestamp"].iloc[1] == 20_000

@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory) -> Path:
    """The benchmark tests' small dataset (normal-000 ... normal-009 and six attacked flights)."""
    return write_dataset(tmp_path_factory.mktemp("small") / "ds")


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# -- flights are keyed by (dataset, flight id) -----------------------------------------------------

def test_a_transfer_run_between_two_generated_datasets_with_the_same_ids_runs(small_dataset, tmp_path, capsys):
    other = write_dataset(tmp_path / "other", seed=1)  # normal-000 ... in both, different flights
    out = tmp_path / "run"
    assert main(["run", "--train-dataset", str(small_dataset), "--dataset", str(other), "--detectors", "zscore_test",
                 "--plugin", ZS, "--out", str(out)]) == 0
    flights = pd.read_csv(out / "flights.csv")
    train = flights[flights["role"].isin(["train", "validation"])]
    assert set(train["dataset"]) == {str(small_dataset)} and train["flight_id"].str.startswith("train+").all()
    assert set(train["dataset_flight_id"]) == {f"normal-{i:03d}" for i in range(7)}
    test = flights[flights["role"].str.startswith("test")]
    assert "normal-007" in set(test["flight_id"]) and set(test["dataset"]) == {str(other)}
    # normal-004: a validation flight of the train dataset and a held-out normal flight of the test dataset
    scores = np.load(out / "jobs/zscore_test/scores.npz")
    assert {"train+normal-004", "normal-004"} <= set(scores.files)
    truth = pd.read_parquet(out / "truth.parquet")
    assert {"train+normal-004", "normal-004"} <= set(truth["flight_id"].astype(str))
    assert main(["score", str(out)]) == 0


@pytest.mark.parametrize("copy", [False, True])
def test_the_same_dataset_in_both_roles_is_still_refused(small_dataset, tmp_path, capsys, copy):
    test = small_dataset
    if copy:
        test = tmp_path / "copy"
        shutil.copytree(small_dataset, test)
    assert main(["run", "--train-dataset", str(small_dataset), "--dataset", str(test), "--detectors", "zscore_test",
                 "--plugin", ZS, "--out", str(tmp_path / "run")]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "the same flight in both" in line and "normal-000" in line


@needs_ulogs
def test_calibrating_on_a_few_of_your_own_flights_sets_the_thresholds_and_leaves_them_untested(datasets, tmp_path,
                                                                                              capsys):
    """``--calibrate-on dataset``: fitted on the generated flights, thresholds from the real dataset's normal
    flights of split validation, which are then not among the tested normal flights."""
    gen, real = datasets
    # the fixture attacked a validation flight too: a calibration flight's copy would be tested on rows the
    # thresholds saw, which the protocol refuses in one line (as on one dataset)
    capsys.readouterr()
    assert main(["run", "--train-dataset", str(gen), "--dataset", str(real), "--detectors", "statistical",
                 "--calibrate-on", "dataset", "--out", str(tmp_path / "refused")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "a validation flight" in err and not (tmp_path / "refused").exists()
    own = tmp_path / "own_logs"  # the real logs without that copy
    shutil.copytree(real, own)
    m = pd.read_parquet(own / "manifest.parquet")
    for fid in m.loc[m["mode"] != "normal", "flight_id"]:
        shutil.rmtree(own / "flights" / fid)
    m[m["mode"] == "normal"].to_parquet(own / "manifest.parquet", index=False)
    runs = {}
    for name, extra in (("gen", []), ("own", ["--calibrate-on", "dataset"])):
        capsys.readouterr()
        assert main(["run", "--train-dataset", str(gen), "--dataset", str(own), "--detectors", "statistical",
                     "--out", str(tmp_path / name), *extra]) == 0
        runs[name] = (capsys.readouterr(), pd.read_csv(tmp_path / name / "flights.csv"),
                      pd.read_csv(tmp_path / name / "metrics.csv").set_index("detector"))
    printed, flights, metrics = runs["own"]
    own_val = set(m.loc[(m["mode"] == "normal") & (m["split"] == "validation"), "flight_id"])
    assert len(own_val) == 2
    roles = flights.groupby("role")["flight_id"].agg(set).to_dict()
    assert roles["validation"] == own_val and set(flights.loc[flights["role"] == "train", "dataset"]) == {str(gen)}
    assert not own_val & roles["test_normal"] and len(roles["test_normal"]) == 2
    assert metrics.loc["statistical", "n_no_attack"] == 2 and runs["gen"][2].loc["statistical", "n_no_attack"] == 4
    assert "calibrated on 2 normal flights of" in printed.out
    assert f"Threshold from ({own.name})" in (tmp_path / "own" / "metrics.md").read_text()
    # the real flights set it: not the generated flights' threshold
    assert metrics.loc["statistical", "flight_threshold"] != runs["gen"][2].loc["statistical", "flight_threshold"]
    config = json.loads((tmp_path / "own" / "config.json").read_text())
    assert config["identity"]["transfer"]["calibrate_on"] == "dataset" and config["run"]["calibrate_on"] == "dataset"
    # another calibration is another run: refused on the first run's folder, nothing written
    before = (tmp_path / "gen" / "config.json").read_text()
    assert main(["run", "--train-dataset", str(gen), "--dataset", str(own), "--detectors", "statistical",
                 "--out", str(tmp_path / "gen"), "--calibrate-on", "dataset"]) == 2
    assert (tmp_path / "gen" / "config.json").read_text() == before
    # refused in one line: without a transfer run, and on a dataset with no normal flight of split validation
    m.loc[m["split"] == "validation", "split"] = "test"
    m.to_parquet(own / "manifest.parquet", index=False)
    for args, needle in ((["--dataset", str(own)], "needs --train-dataset"),
                         (["--train-dataset", str(gen), "--dataset", str(own)], "no normal flight of split validation")):
        capsys.readouterr()
        assert main(["run", *args, "--calibrate-on", "dataset", "--detectors", "statistical",
                     "--out", str(tmp_path / "bad")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and needle in err, err
        assert not (tmp_path / "bad").exists()
