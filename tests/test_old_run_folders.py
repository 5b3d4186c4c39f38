"""A run folder written before the rooms moved (commit 98aff80, the dataset format still under
generator/ and the command line under benchmark/) still scores: the same tables, byte for byte.

The fixture is a real run of that commit: ``scart-bench generate --profile quick --flights 8
--scenarios data/scenarios/gps_spoof.toml`` and ``scart-bench run --detectors statistical`` on it.
Scoring needs only the run folder (scores, truth, arming times), not the dataset.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from scart_bench.cli.main import main

FIXTURE = Path(__file__).parent / "data" / "run_made_before_the_rooms"


def test_a_run_folder_made_before_the_move_scores_to_the_same_tables(tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(FIXTURE, run)
    (run / "metrics.csv").unlink()
    (run / "breakdown.csv").unlink()
    assert main(["score", str(run)]) == 0
    assert "statistical" in capsys.readouterr().out
    for name in ("metrics.csv", "breakdown.csv"):
        assert (run / name).read_bytes() == (FIXTURE / name).read_bytes(), name
