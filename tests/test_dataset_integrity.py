"""Datasets that know their contents: a flipped byte, swapped attack windows and a broken
dataset.json are caught and named, before a run uses them."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
from run_fixtures import plugin, write_dataset

from scart_bench.cli.main import main
from scart_bench.dataset import DatasetError, open_dataset

ZS = plugin("ZScore")


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """The run fixtures' dataset, written once for the module (the tests below damage their copies)."""
    return write_dataset(tmp_path_factory.mktemp("pristine") / "ds")


@pytest.fixture()
def fresh(pristine, tmp_path):
    """A copy of it at ``tmp_path / "ds"``, byte for byte what ``write_dataset`` writes there."""
    return Path(shutil.copytree(pristine, tmp_path / "ds"))


def _flip(path, offset: int = 2000) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


def test_every_flight_records_its_checksum(fresh):
    ds = open_dataset(fresh)
    assert ds.manifest["checksum"].str.match(r"^b2:[0-9a-f]{32}$").all()
    ds.flight("normal-000")  # reads and verifies


def test_one_flipped_byte_is_caught_with_the_flights_name(fresh, tmp_path):
    root = fresh
    _flip(root / "flights" / "normal-005" / "navigator.parquet")
    ds = open_dataset(root)
    ds.flight("normal-000")
    with pytest.raises(DatasetError, match="normal-005.*changed since it was written"):
        ds.flight("normal-005")
    with pytest.raises(DatasetError, match="normal-005"):
        ds.check_flights(["normal-000", "normal-005"])


def test_resume_refuses_a_dataset_whose_contents_changed(fresh, tmp_path, capsys):
    root = fresh
    run = tmp_path / "run"
    args = ["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(root), "--out", str(run)]
    assert main(args) == 0
    before = (run / "metrics.csv").read_bytes()
    _flip(root / "flights" / "sim-000" / "navigator.parquet")
    capsys.readouterr()
    assert main([*args, "--resume"]) == 2
    assert "sim-000" in capsys.readouterr().err
    assert (run / "metrics.csv").read_bytes() == before  # nothing of the run was touched


def test_swapped_attack_windows_are_refused(fresh, tmp_path):
    root = fresh
    m = pd.read_parquet(root / "manifest.parquet")
    i = m.index[m["flight_id"] == "sim-001"][0]
    m.loc[i, ["attack_start_us", "attack_end_us"]] = m.loc[i, ["attack_end_us", "attack_start_us"]].to_numpy()
    m.to_parquet(root / "manifest.parquet", index=False)
    with pytest.raises(DatasetError, match="sim-001.*attack_end_us .* <= attack_start_us"):
        open_dataset(root)


def test_a_broken_dataset_json_is_named(fresh, tmp_path):
    root = fresh
    (root / "dataset.json").write_text("{not json")
    with pytest.raises(DatasetError, match=r"dataset\.json: not valid JSON"):
        open_dataset(root)


def test_import_says_how_many_cells_are_not_finite(tmp_path, capsys):
    """A log with NaN and inf cells imports (detectors treat them as missing) with one warning line
    that counts them per column."""
    import numpy as np

    t = np.arange(200) * 20_000
    df = pd.DataFrame({"timestamp": t, "attitude.roll": np.sin(t / 1e6), "attitude.pitch": 0.01 * np.cos(t / 1e6),
                       "gps.alt": 488.0 + np.zeros(200)})
    df.loc[[3, 4, 5], "attitude.roll"] = np.nan
    df.loc[7, "gps.alt"] = np.inf
    log = tmp_path / "flight.csv"
    df.to_csv(log, index=False)
    assert main(["import", str(log), "--out", str(tmp_path / "mine")]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "NaN/inf" in line]
    assert len(lines) == 1 and "4 NaN/inf cell(s) in 2 column(s)" in lines[0]
    assert "attitude.roll 3" in lines[0] and "gps.alt 1" in lines[0]


def test_a_killed_overwrite_is_cleaned_up_by_the_next_command(fresh, tmp_path):
    """A generate --overwrite killed mid-write leaves its hidden partial folder; killed between its two
    renames, the old dataset sits aside. The next command on that folder removes the first and puts
    the second back."""
    from scart_bench.dataset import check_output_dir

    root = fresh
    partial = tmp_path / ".ds.partial"
    partial.mkdir()
    (partial / "half.parquet").write_bytes(b"x" * 1000)
    assert len(open_dataset(root)) == 16 and not partial.exists()
    old = tmp_path / ".ds.old"
    root.rename(old)  # killed after moving the old dataset aside
    partial.mkdir()
    check_output_dir(root, overwrite=True)
    assert is_complete(root) and not old.exists() and not partial.exists()


def is_complete(path) -> bool:
    return (path / "manifest.parquet").exists() and len(open_dataset(path)) == 16


def test_appending_to_a_dataset_from_before_checksums_records_every_flights(fresh, tmp_path):
    """Only a dataset without a checksum column is "older"; appending to one gives it the column, so
    the flights already there get theirs too (an empty checksum is refused by the reader)."""
    from scart_bench.dataset import append_flights, flight_record

    root = fresh
    m = pd.read_parquet(root / "manifest.parquet").drop(columns="checksum")
    m.to_parquet(root / "manifest.parquet", index=False)
    ds = open_dataset(root)
    topics = {t: ds.topic("normal-000", t) for t in ds.topics("normal-000")}
    append_flights(root, [flight_record("extra-1", topics, topics, {"mode": "normal", "split": "test"}, {})])
    again = open_dataset(root)
    assert again.manifest["checksum"].str.match(r"^b2:[0-9a-f]{32}$").all() and len(again) == 17
    again.check_flights(list(again.manifest["flight_id"]))
