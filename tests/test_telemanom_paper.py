"""The paper's Telemanom as a shipped run file: per-channel LSTMs judged by their own dynamic
threshold, run from the command line (shrunk by --param so that the test stays fast)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
from run_fixtures import write_dataset

from scart_bench.benchmark.config import read_run_file
from scart_bench.cli.main import main

RUN_FILE = Path(__file__).resolve().parents[1] / "data" / "runs" / "telemanom_paper.toml"


def test_the_run_file_holds_the_published_configuration():
    run = read_run_file(RUN_FILE)
    params = run["params"]["telemanom"]
    assert params["per_channel"] is True and params["residual"] is False
    assert (params["l_s"], params["hidden"], params["epochs"], params["patience"]) == (250, [80, 80], 35, 10)
    assert run["protocol"].alarm_rule == "own"


def test_the_paper_telemanom_runs_from_the_command_line_with_its_own_alarms(tmp_path: Path):
    dataset = write_dataset(tmp_path / "ds")
    out = tmp_path / "run"
    shrink = ["epochs=1", "l_s=20", "hidden=[8, 8]", "max_train_windows=300", "error_batch=20"]
    rc = main(["run", "--config", str(RUN_FILE), "--dataset", str(dataset), "--out", str(out),
               *(x for p in shrink for x in ("--param", f"telemanom.{p}"))])
    assert rc == 0
    metrics = pd.read_csv(out / "metrics.csv").set_index("detector")
    assert metrics.loc["telemanom", "status"] == "OK"
    config = json.loads((out / "config.json").read_text())
    assert config["identity"]["protocol"]["alarm_rule"] == "own"
    assert (out / "jobs" / "telemanom" / "alarms.npz").is_file()  # its own alarms were scored
    saved = json.loads((out / "jobs" / "telemanom" / "params.json").read_text())["params"]
    assert saved["per_channel"] is True and saved["l_s"] == 20
