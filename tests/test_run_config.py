"""Detector parameters from the command line (--param) and whole runs from a file (--config)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from run_fixtures import write_dataset

from scart_bench.benchmark.store import read_npz
from scart_bench.cli.main import main


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("data") / "ds")


def scores(run: Path, detector: str = "statistical") -> dict[str, np.ndarray]:
    return read_npz(run / "jobs" / detector / "scores.npz")


def saved_params(run: Path, detector: str = "statistical") -> dict:
    return json.loads((run / "config.json").read_text())["jobs"][detector]["params"]


@pytest.fixture(scope="module")
def default_run(dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "default"
    assert main(["run", "--detectors", "statistical", "--dataset", str(dataset), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def param_run(dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "param"
    assert main(["run", "--detectors", "statistical", "--dataset", str(dataset), "--out", str(out),
                 "--param", "statistical.window=10", "--param", "statistical.min_exceed=3"]) == 0
    return out


def test_param_changes_the_detector_and_is_recorded(default_run, param_run):
    assert saved_params(param_run)["window"] == 10 and saved_params(param_run)["min_exceed"] == 3
    assert saved_params(default_run)["window"] == 50
    a, b = scores(default_run), scores(param_run)
    assert a.keys() == b.keys()
    assert any(not np.array_equal(a[k], b[k]) for k in a)


def test_config_file_gives_the_same_run_as_the_options(dataset, param_run, tmp_path):
    run_file = tmp_path / "run.toml"
    run_file.write_text(f'detectors = ["statistical"]\ndataset = "{dataset}"\nout = "{tmp_path / "from-file"}"\n'
                        "[params.statistical]\nwindow = 10\nmin_exceed = 3\n")
    assert main(["run", "--config", str(run_file)]) == 0
    a, b = scores(param_run), scores(tmp_path / "from-file")
    assert all(np.array_equal(a[k], b[k]) for k in a)


def test_a_run_folder_config_round_trips(param_run, tmp_path):
    again = tmp_path / "again"
    assert main(["run", "--config", str(param_run / "config.json"), "--out", str(again)]) == 0
    first = json.loads((param_run / "config.json").read_text())["run"]
    second = json.loads((again / "config.json").read_text())["run"]
    assert first == second
    assert saved_params(again) == saved_params(param_run)
    a, b = scores(param_run), scores(again)
    assert all(np.array_equal(a[k], b[k]) for k in a)


def test_command_line_overrides_the_config_file(dataset, tmp_path):
    run_file = tmp_path / "run.toml"
    run_file.write_text(f'detectors = "statistical"\ndataset = "{dataset}"\n[params.statistical]\nwindow = 10\n')
    out = tmp_path / "run"
    assert main(["run", "--config", str(run_file), "--out", str(out), "--param", "statistical.window=20"]) == 0
    assert saved_params(out)["window"] == 20


@pytest.mark.parametrize("param, named", [
    ("statistical.no_such=1", "statistical.no_such"),
    ("statistical.window=abc", "expected an integer"),
    ("statistical.window=1", "window must be at least 2"),
    ("statistical.quantile=true", "statistical.quantile"),
    ("goad.n_trans=64", "'goad' is not a detector of this run"),
    ("window=10", "expected DETECTOR.PARAMETER=VALUE"),
    ("statistical.random_state=3", "--seed"),
])
def test_bad_parameters_exit_2_naming_them(dataset, tmp_path, capsys, param, named):
    out = tmp_path / "run"
    assert main(["run", "--detectors", "statistical", "--dataset", str(dataset), "--out", str(out),
                 "--param", param]) == 2
    err = capsys.readouterr().err
    assert named in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


@pytest.mark.parametrize("text, named", [
    ("detectors = 3", "detectors = 3"),
    ("seed = -1", "--seed -1"),
    ("jobs = 1.5", "jobs = 1.5"),
    ("timeout = nan", "--timeout nan"),
    ("wat = 1", "unknown key(s) 'wat'"),
    ("[protocol.flight_rule]\nkind = \"median\"", "protocol.flight_rule"),
    ("detectors = [", "not valid TOML"),
])
def test_bad_config_files_exit_2_naming_the_key(dataset, tmp_path, capsys, text, named):
    run_file = tmp_path / "run.toml"
    run_file.write_text(text + "\n")
    assert main(["run", "--config", str(run_file), "--dataset", str(dataset), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert named in err and str(run_file) in err, err


def test_model_parameters_of_deepod_adapters_go_into_model_params():
    pytest.importorskip("deepod")
    from scart_bench.benchmark.selection import check_params
    from scart_bench.detectors.deepod_models import GOAD

    assert check_params("goad", GOAD, {"n_trans": 64, "epochs": 2}) == {"model_params": {"n_trans": 64}, "epochs": 2}
    from scart_bench.errors import RunError

    with pytest.raises(RunError, match="goad.n_trans"):
        check_params("goad", GOAD, {"n_trans": "many"})


def test_missing_deepod_is_one_line_saying_how_to_install(dataset, tmp_path, capsys, monkeypatch):
    for mod in [m for m in sys.modules if m == "deepod" or m.startswith("deepod.")
                or m == "scart_bench.detectors.deepod_models"]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setitem(sys.modules, "deepod", None)  # import deepod -> ImportError
    assert main(["run", "--detectors", "goad", "--dataset", str(dataset), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install --no-deps deepod==0.4.1" in err, err
    assert main(["detectors"]) == 0
    listed = capsys.readouterr().out
    assert "goad" in listed and "unavailable" in listed and "deepod==0.4.1" in listed
