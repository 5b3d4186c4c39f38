"""Run files and run folders are data: a plugin they name is never imported unless the command line
names it (``--plugin``) or says ``--trust-plugins``."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest
from run_fixtures import plugin, write_dataset

from scart_bench.cli.main import main

ZS = plugin("ZScore")

PLUGIN = textwrap.dedent('''
    import os
    from pathlib import Path

    import numpy as np

    from scart_bench.detectors.base import Detector

    Path(os.environ["SCART_TEST_MARKER"]).write_text("imported")  # module-level code: runs on import


    class Marker(Detector):
        name = "marker_test"

        def __init__(self, columns=None, random_state=0):
            self.columns = columns
            self.random_state = random_state

        def _fit(self, X_list):
            self.mu_ = np.concatenate(X_list).mean(axis=0)

        def _score(self, X):
            return np.abs(X - self.mu_).sum(axis=1)
''')


@pytest.fixture()
def shared_run(tmp_path, monkeypatch):
    """A run folder made with a plugin file, as a lab would share it; the marker is then removed."""
    marker = tmp_path / "marker"
    monkeypatch.setenv("SCART_TEST_MARKER", str(marker))
    spec = f"{tmp_path / 'evil.py'}:Marker"
    (tmp_path / "evil.py").write_text(PLUGIN)
    ds = write_dataset(tmp_path / "ds")
    run = tmp_path / "run"
    assert main(["run", "--detectors", "marker_test,zscore_test", "--plugin", spec, "--plugin", ZS,
                 "--dataset", str(ds), "--out", str(run)]) == 0
    assert marker.exists()  # named on the command line: loaded, as asked
    marker.unlink()
    assert spec in json.loads((run / "config.json").read_text())["run"]["plugins"]
    return run, marker, spec


def test_a_run_folder_never_runs_the_code_it_names(shared_run, tmp_path, capsys):
    run, marker, spec = shared_run
    # rerun from its config.json: refused before anything is imported, naming the plugin and the flag
    assert main(["run", "--config", str(run / "config.json"), "--out", str(tmp_path / "again")]) == 2
    err = capsys.readouterr().err
    assert "evil.py:Marker" in err and "--trust-plugins" in err and "--plugin" in err
    assert not marker.exists() and not (tmp_path / "again").exists()
    # resume into the same folder from its config: refused too
    assert main(["run", "--config", str(run / "config.json"), "--out", str(run), "--resume"]) == 2
    assert not marker.exists()
    # score and report read the saved scores only
    assert main(["score", str(run)]) == 0
    assert main(["report", str(run), "--out", str(tmp_path / "report")]) == 0
    assert not marker.exists()
    # the live proxy's detector from a run: resolved among installed detectors, never from the folder
    # (in a process of its own: this one has the plugin registered by the run above)
    probe = ("import sys\nfrom scart_bench.benchmark.live import monitor_from_run\n"
             "from scart_bench.errors import RunError\n"
             "try:\n    monitor_from_run(sys.argv[1], 'marker_test')\nexcept RunError as exc:\n"
             "    print(exc)\n    sys.exit(2)\n")
    done = subprocess.run([sys.executable, "-c", probe, str(run)], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 2 and "not executed" in done.stdout, done.stdout + done.stderr
    assert not marker.exists()


def test_the_user_can_still_load_it_on_purpose(shared_run, tmp_path):
    run, marker, spec = shared_run
    for extra, name in ((["--plugin", spec, "--plugin", ZS], "named"), (["--trust-plugins"], "trusted")):
        out = tmp_path / name
        assert main(["run", "--config", str(run / "config.json"), "--out", str(out), *extra]) == 0
        status = json.loads((out / "jobs/marker_test/status.json").read_text())
        assert status["status"] == "OK"


def test_score_exits_3_when_a_job_has_no_scores(tmp_path):
    """A run folder with an unfinished job scores the rest and says so by its exit status, as run does."""
    ds = write_dataset(tmp_path / "ds")
    run = tmp_path / "run"
    assert main(["run", "--detectors", "zscore_test", "--plugin", ZS, "--dataset", str(ds), "--out", str(run)]) == 0
    assert main(["score", str(run)]) == 0
    (run / "jobs/zscore_test/status.json").unlink()  # as a killed run leaves it
    assert main(["score", str(run)]) == 3
    assert pd.read_csv(run / "metrics.csv").loc[0, "status"] == "UNFINISHED"
