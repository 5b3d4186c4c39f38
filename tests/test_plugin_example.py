"""The example plugin package (examples/custom_detector), installed with pip as a user would.

``make test`` installs it into its own folder and puts that on PYTHONPATH, so that ``make run``'s
table (the same venv, no PYTHONPATH) lists only the built-ins and the plugins a user installed.
"""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import pandas as pd
import pytest
from run_fixtures import write_dataset

from scart_bench.cli.main import main

INSTALLED = any(ep.name == "zscore" for ep in entry_points(group="scart_bench.detectors"))
pytestmark = pytest.mark.skipif(
    not INSTALLED, reason="example plugin not installed: pip install examples/custom_detector (make test does, into .venv/example-plugin on PYTHONPATH)")


def test_installed_plugin_is_listed_with_its_package():
    out = subprocess.run([sys.executable, "-m", "scart_bench.cli", "detectors"], capture_output=True, text=True,
                         check=True).stdout
    line = next(line for line in out.splitlines() if line.startswith("zscore"))
    assert "scart-bench-example-detector" in line


def test_installed_plugin_runs_in_a_benchmark_run(tmp_path: Path, capsys):
    dataset = write_dataset(tmp_path / "ds")
    run = tmp_path / "run"
    assert main(["run", "--detectors", "zscore", "--dataset", str(dataset), "--out", str(run)]) == 0
    metrics = pd.read_csv(run / "metrics.csv")
    row = metrics.set_index("detector").loc["zscore"]
    assert row["status"] == "OK"
    assert 0.0 <= row["roc_auc"] <= 1.0
    assert "zscore" in capsys.readouterr().out
