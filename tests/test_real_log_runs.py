"""A benchmark on a few real flights of one fleet (issue 48 items 4 and 6): ArduCopter logs of two firmware
families (EKF1 in V3.3-dev builds, NKF1 in the Erle-Brain's V3.4-rc2) and with and without GPS, read by
meaning in a run on one dataset, and the flights that lack a quantity named where the user sees them.

To stay fast, each log is a prefix of a shared fleet log (the first few hundred kB: a DataFlash log cut
mid-message is read up to the cut, as ArduPilot's own logs end)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scart_bench.benchmark.protocol import Splits
from scart_bench.benchmark.transfer import open_meaning, open_transfer, shared_values
from scart_bench.cli.main import main
from scart_bench.dataset import open_dataset
from scart_bench.detectors.base import DetectorError
from scart_bench.detectors.statistical import Statistical
from scart_bench.generator.logs.offline import auto_counts, auto_split_line, auto_splits

FLEET = Path(__file__).parents[1].parent / "shared/data/dataflash/fleet"
#: name in the test -> (fleet log, bytes kept): EKF1 with GPS (two), EKF1 without GPS, NKF1 without GPS
LOGS = {"ekf_gps": ("arducopter_8-10-2014_11.bin", 160_000), "ekf_gps_b": ("arducopter_10-11-2014_105.bin", 160_000),
        "ekf_nogps": ("arducopter_25-9-2014_1.bin", 120_000), "nkf_nogps": ("erlebrain_24.bin", 400_000)}
needs_fleet = pytest.mark.skipif(not all((FLEET / f).exists() for f, _ in LOGS.values()),
                                 reason=f"shared fleet logs not found in {FLEET}")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> dict[str, Path]:
    """A dataset of the four log prefixes: EKF1 with and without GPS to train, EKF1 to validate, and the
    NKF1 (other firmware, no GPS) flight to test; and the raw files."""
    root = tmp_path_factory.mktemp("fleet")
    files = {}
    for name, (log, size) in LOGS.items():
        files[name] = root / f"{name}.bin"
        files[name].write_bytes((FLEET / log).read_bytes()[:size])
    ds = root / "ds"
    for split, names in (("train", ["ekf_gps", "ekf_nogps"]), ("validation", ["ekf_gps_b"]), ("test", ["nkf_nogps"])):
        assert main(["import", *(str(files[n]) for n in names), "--out", str(ds), "--split", split]) == 0
    return {"ds": ds, **files}


@needs_fleet
def test_a_plain_run_over_two_firmware_families_reads_the_flights_by_meaning(fleet, tmp_path, capsys):
    ds = open_dataset(fleet["ds"])
    splits = Splits.from_manifest(ds.manifest)
    # as logged (before --columns auto): the NKF1 flight lacks the EKF1 columns the detector was trained on
    with pytest.raises(DetectorError, match=r"lacks \d+ column\(s\) it was trained on"):
        Statistical().fit([ds.flight(f) for f in splits.train]).score(ds.flight("log-nkf_nogps"))

    out = tmp_path / "run"
    capsys.readouterr()
    assert main(["run", "--dataset", str(fleet["ds"]), "--detectors", "statistical", "--jobs", "1",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "columns by meaning (the training flights log different columns" in err
    metrics = pd.read_csv(out / "metrics.csv").set_index("detector")
    assert metrics.loc["statistical", "status"] == "OK"
    config = json.loads((out / "config.json").read_text())
    assert config["columns"]["by"] == "meaning" and config["identity"]["columns"]["by"] == "meaning"
    quantities = config["columns"]["quantities"]
    # the EKF1 and NKF1 estimates are one quantity; the GPS of the GPS flights is kept
    assert {"velocity.vn", "position.x", "attitude.roll", "gps.north"} <= set(quantities)
    assert not any(c.startswith(("ekf1.", "nkf1.")) for c in quantities)
    # the GPS-less flights are named with the GPS quantities they lack, with their roles
    line = next(x for x in err.splitlines() if "gps.north" in x and "not in" in x)
    assert "log-ekf_nogps (train)" in line and "log-nkf_nogps (test)" in line and "log-ekf_gps " not in line
    assert config["columns"]["lacking"]["gps.north"] == ["log-ekf_nogps", "log-nkf_nogps"]
    assert set(pd.read_csv(out / "columns.csv")["why"]) >= {"no meaning"}
    # a live monitor streams logged columns: refused in one line
    from scart_bench.benchmark.live import monitor_from_run
    from scart_bench.errors import ScartBenchError

    with pytest.raises(ScartBenchError, match="read by meaning"):
        monitor_from_run(out, "statistical")


@needs_fleet
def test_columns_logged_keeps_the_old_reading_and_meaning_can_be_asked_for(fleet):
    ds = open_dataset(fleet["ds"])
    splits = Splits.from_manifest(ds.manifest)
    assert open_meaning(ds, splits, "logged") is None
    lines: list[str] = []
    run = open_meaning(ds, splits, "meaning", note=lines.append)
    assert run is not None and run.why == "--columns meaning" and lines[0].startswith("columns by meaning")
    table = run.reader("log-nkf_nogps")
    assert list(table.columns[:5]) == ["Index", "Timestamp", "Is_Anomaly", "Anomaly_Ids", "Anomaly_Kind"]
    assert len(table) == len(ds.flight("log-nkf_nogps"))  # no resampling in a run on one dataset
    assert np.isnan(table["gps.north"]).all() and np.isfinite(table["velocity.vn"]).any()


@needs_fleet
def test_a_transfer_run_names_the_flight_whose_missing_quantity_it_drops(fleet, tmp_path):
    """Train on the EKF1 flights with GPS, test on a GPS flight and the GPS-less NKF1 flight: every
    position quantity is dropped (not in every flight), and a line says which flight lacks it."""
    train, test = tmp_path / "train", tmp_path / "test"
    flights = fleet["ds"] / "flights"  # the imported flights, imported again (their folders read fast)
    assert main(["import", str(flights / "log-ekf_gps"), "--out", str(train), "--split", "train"]) == 0
    assert main(["import", str(flights / "log-ekf_gps_b"), "--out", str(train), "--split", "validation"]) == 0
    assert main(["import", str(flights / "log-ekf_gps"), str(flights / "log-nkf_nogps"), "--out", str(test),
                 "--split", "test", "--start", "1"]) == 0
    lines: list[str] = []
    run = open_transfer(train, open_dataset(test), note=lines.append)
    assert "gps.north" not in run.plan.columns and "velocity.vn" in run.plan.columns
    gpsless = "log-log-nkf_nogps-1s-end"
    assert run.plan.lacking["gps.north"] == [gpsless]
    named = [x for x in lines if x.startswith("transfer: dropped for every flight") and "gps.north" in x]
    assert len(named) == 1 and f"{gpsless} (test" in named[0], lines
    assert run.plan.to_dict()["lacking"]["position.north"] == [gpsless]


@needs_fleet
def test_site_quantities_enter_as_changes_from_the_flight_start(fleet):
    flight = open_dataset(fleet["ds"]).flight("log-ekf_gps")
    values = shared_values(flight)
    for q in ("mag.x", "mag.y", "mag.z", "baro.pressure", "altitude.amsl"):  # (CURR reads no voltage here)
        v = values[q]
        first = v[np.flatnonzero(np.isfinite(v))[0]]
        assert first == 0.0, q
    assert np.nanmax(np.abs(values["mag.x"])) < 1.0  # Gauss, from the start (the site's field is ~0.5 G)


def test_split_auto_keeps_a_third_for_validation_and_says_what_it_chose():
    assert auto_counts(14) == {"train": 5, "validation": 5, "test": 2, "csv_source": 2}
    assert auto_counts(4) == {"train": 1, "validation": 2, "test": 1, "csv_source": 0}
    assert auto_counts(2) == {"train": 1, "validation": 1, "test": 0, "csv_source": 0}
    assert all(sum(auto_counts(n).values()) == n and auto_counts(n)["train"] >= 1 for n in range(1, 60))
    assert all(auto_counts(n)["validation"] >= max(2, n / 3) for n in range(4, 60))
    ids = [f"log-{i}" for i in range(6)]
    splits = auto_splits(ids, seed=0)
    t = np.arange(0, 60_000_000, 100_000)  # a 60 s log; the last one with a 30 s gap
    tables = [{"imu": pd.DataFrame({"Timestamp": t})} for _ in ids[:-1]]
    tables.append({"imu": pd.DataFrame({"Timestamp": np.concatenate([t[:100], t[400:]])})})
    line = auto_split_line(splits, tables, seed=0)
    assert line.startswith("import: --split auto (seed 0) for 6 log(s): 3 train (")
    assert "2 validation (" in line and "1 test (" in line and "\n" not in line
    minutes = {s: sum(60.0 - 30.0 * (i == 5) for i, x in enumerate(splits) if x == s) / 60 for s in set(splits)}
    assert f"2 validation ({minutes['validation']:.1f} min)" in line


def test_columns_is_a_run_option_and_a_run_file_key(tmp_path):
    from scart_bench.benchmark.config import RunConfig, read_run_file
    from scart_bench.errors import RunError

    run_file = tmp_path / "run.toml"
    run_file.write_text('columns = "meaning"\n')
    cfg = RunConfig(**read_run_file(run_file))
    assert cfg.columns == "meaning" and cfg.to_dict()["columns"] == "meaning"
    assert "columns" not in RunConfig().to_dict()  # auto: a run file as before
    with pytest.raises(RunError, match="--columns 'bogus': expected one of auto, logged, meaning"):
        RunConfig(columns="bogus")
    with pytest.raises(RunError, match="a transfer run"):
        RunConfig(columns="logged", dataset=tmp_path, train_dataset=tmp_path)
    run_file.write_text("columns = 3\n")
    with pytest.raises(RunError, match="columns = 3: expected a string"):
        read_run_file(run_file)
