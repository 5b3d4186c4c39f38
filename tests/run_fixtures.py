"""Helpers for the benchmark-run tests: a small synthetic dataset and cheap test detectors.

The detectors are loaded by the runner with ``--plugin tests/run_fixtures.py:ClassName``, in
worker processes, exactly like a user's plugin. Environment variables let a test observe them:
``SCART_TEST_FIT_LOG`` (a file each fit appends its detector name to), ``SCART_TEST_PID_DIR``
(where a hanging detector writes its pid) and ``SCART_TEST_INTERRUPT_MARKER`` (see
:class:`InterruptOnce`).
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.metrics import TIMING_COLUMNS
from scart_bench.dataset import DatasetWriter, FlightRecord
from scart_bench.detectors.base import Detector

HERE = Path(__file__).resolve().parent
FIXTURES = HERE / "run_fixtures.py"

DURATION_S = 20.0
ATTACK_US = (8_000_000, 14_000_000)

#: (flight id, mode, action, target, magnitude) of the attacked flights.
ATTACKS = (
    ("sim-000", "simulation", "bias", "attitude.roll", 0.6),
    ("sim-001", "simulation", "bias", "local_position_ned.z", 3.0),
    ("sim-002", "simulation", "noise", "attitude.roll", 0.002),  # too small to see
    ("csv-000", "csv", "bias", "attitude.roll", 0.6),
    ("csv-001", "csv", "noise", "local_position_ned.z", 2.0),
    ("csv-002", "csv", "bias", "local_position_ned.z", 0.01),  # too small to see
)
SPLITS = ("train",) * 4 + ("validation",) * 3 + ("test",) * 3


def quality(run: Path) -> pd.DataFrame:
    """metrics.csv without the timing columns (those differ between any two runs)."""
    m = pd.read_csv(run / "metrics.csv")
    return m.drop(columns=[c for c in (*TIMING_COLUMNS, "rows") if c in m.columns]).set_index("detector")


def plugin(cls_name: str) -> str:
    """The --plugin spec of a detector class defined here."""
    return f"{FIXTURES}:{cls_name}"


def _topics(rng: np.random.Generator) -> dict[str, pd.DataFrame]:
    t50 = np.arange(0, int(DURATION_S * 1e6), 20_000, dtype=np.int64)
    t25 = np.arange(0, int(DURATION_S * 1e6), 40_000, dtype=np.int64)
    ph = rng.uniform(0, 2 * np.pi, 4)
    s50, s25 = t50 / 1e6, t25 / 1e6
    att = pd.DataFrame({
        "Timestamp": t50, "Is_Anomaly": np.zeros(t50.size, np.int8),
        "roll": 0.05 * np.sin(0.5 * s50 + ph[0]) + rng.normal(0, 0.003, t50.size),
        "pitch": 0.04 * np.sin(0.3 * s50 + ph[1]) + rng.normal(0, 0.003, t50.size),
        "yaw": 0.2 * np.sin(0.1 * s50 + ph[2]) + rng.normal(0, 0.003, t50.size),
    })
    pos = pd.DataFrame({
        "Timestamp": t25, "Is_Anomaly": np.zeros(t25.size, np.int8),
        "x": 10 * np.sin(0.2 * s25 + ph[3]) + rng.normal(0, 0.05, t25.size),
        "y": 10 * np.cos(0.2 * s25 + ph[3]) + rng.normal(0, 0.05, t25.size),
        "z": -10 + 0.5 * np.sin(0.4 * s25) + rng.normal(0, 0.05, t25.size),
    })
    return {"attitude": att, "local_position_ned": pos}


def _manifest(mode: str, split: str, seed: int, **extra) -> dict:
    row = {"mode": mode, "split": split, "seed": seed, "duration_s": DURATION_S, "scenario_id": None,
           "action": None, "target": None, "injection_point": None, "params": "{}", "source_flight": None}
    row.update(extra)
    return row


def _attack(topics: dict[str, pd.DataFrame], action: str, target: str, magnitude: float,
            rng: np.random.Generator) -> dict[str, pd.DataFrame]:
    topic, fieldname = target.split(".")
    out = {k: v.copy() for k, v in topics.items()}
    df = out[topic]
    inside = (df["Timestamp"] >= ATTACK_US[0]) & (df["Timestamp"] < ATTACK_US[1])
    if action == "bias":
        df.loc[inside, fieldname] += magnitude
    else:
        df.loc[inside, fieldname] += rng.normal(0, magnitude, int(inside.sum()))
    for d in out.values():
        d["Is_Anomaly"] = ((d["Timestamp"] >= ATTACK_US[0]) & (d["Timestamp"] < ATTACK_US[1])).astype(np.int8)
    return out


def write_dataset(out: Path, seed: int = 0, fmt: str = "parquet") -> Path:
    """A small labelled dataset: 10 normal flights (4 train, 3 validation, 3 test) and 6 attacked
    flights (3 simulation mode, 3 csv mode; bias or noise on one field from 8 s to 14 s)."""
    rng = np.random.default_rng(seed)
    writer = DatasetWriter(out, fmt=fmt, info={"profile": "test", "seed": seed})
    normals = {}
    for i, split in enumerate(SPLITS):
        fid = f"normal-{i:03d}"
        topics = _topics(rng)
        normals[fid] = topics
        writer.write(FlightRecord(fid, topics, topics, _manifest("normal", split, seed + i), {"seed": seed + i}))
    test_normals = [f for f, s in zip(normals, SPLITS) if s == "test"]
    for k, (fid, mode, action, target, magnitude) in enumerate(ATTACKS):
        clean = _topics(rng) if mode == "simulation" else normals[test_normals[k % len(test_normals)]]
        attacked = _attack(clean, action, target, magnitude, rng)
        params = json.dumps({"magnitude": magnitude})
        extra = {"scenario_id": f"s{k}", "action": action, "target": target, "injection_point": "link",
                 "params": params, "source_flight": test_normals[k % len(test_normals)] if mode == "csv" else None}
        writer.write(FlightRecord(fid, attacked, clean, _manifest(mode, "test", seed + 100 + k, **extra),
                                  {"seed": seed + 100 + k}, windows=[ATTACK_US],
                                  events=[{"timestamp_us": ATTACK_US[0], "event": "start", "scenario_id": f"s{k}",
                                           "detail": action}]))
    writer.close()
    return Path(out)


# -- test detectors ---------------------------------------------------------------------------

def _log_fit(name: str) -> None:
    log = os.environ.get("SCART_TEST_FIT_LOG")
    if log:
        with open(log, "a") as fh:
            fh.write(name + "\n")


class ZScore(Detector):
    """Largest absolute z-score over the columns (standardised on the training flights)."""

    name = "zscore_test"
    description = "test detector: max |z| per row"

    def __init__(self, columns=None, random_state=0):
        self.columns = columns
        self.random_state = random_state

    def _fit(self, X_list):
        _log_fit(self.name)

    def _score(self, X):
        return np.abs(X).max(axis=1)


class Diff(Detector):
    """Largest absolute change from the previous row, in training standard deviations."""

    name = "diff_test"
    description = "test detector: max |x_t - x_{t-1}| per row"

    def __init__(self, columns=None, random_state=0):
        self.columns = columns
        self.random_state = random_state

    def _fit(self, X_list):
        _log_fit(self.name)
        rng = np.random.default_rng(self.random_state)  # used, so the seed matters
        self.jitter_ = rng.uniform(0.999, 1.001)

    def _score(self, X):
        d = np.abs(np.diff(X, axis=0, prepend=X[:1]))
        return d.max(axis=1) * self.jitter_


class Slow(ZScore):
    """ZScore at 0.2 s per scored flight: a job long enough to report its progress."""

    name = "slow_test"

    def _score(self, X):
        time.sleep(0.2)
        return super()._score(X)


class FailFit(ZScore):
    name = "fail_fit_test"

    def _fit(self, X_list):
        raise RuntimeError("boom in fit")


class NaNScore(ZScore):
    name = "nan_score_test"

    def _score(self, X):
        s = np.abs(X).max(axis=1)
        s[len(s) // 2] = np.nan
        return s


class Hang(ZScore):
    """Hangs in fit (the runner must kill it at the timeout)."""

    name = "hang_test"

    def _fit(self, X_list):
        pid_dir = os.environ.get("SCART_TEST_PID_DIR")
        if pid_dir:
            Path(pid_dir, "hang.pid").write_text(str(os.getpid()))
        time.sleep(600)


class InterruptOnce(ZScore):
    """Presses Ctrl-C on the run (SIGINT to the launching process) the first time it is fitted,
    when ``SCART_TEST_INTERRUPT_MARKER`` names a file that does not exist yet; otherwise a z-score."""

    name = "interrupt_test"

    def _fit(self, X_list):
        marker = os.environ.get("SCART_TEST_INTERRUPT_MARKER")
        if marker and not Path(marker).exists():
            Path(marker).write_text("interrupted")
            os.kill(os.getppid(), signal.SIGINT)
            time.sleep(600)
        super()._fit(X_list)


class FailOnce(ZScore):
    """Fails in fit while ``SCART_TEST_FAIL_MARKER`` names a file that does not exist yet (and
    creates it), so a resumed run finishes it; otherwise a z-score."""

    name = "fail_once_test"

    def _fit(self, X_list):
        marker = os.environ.get("SCART_TEST_FAIL_MARKER")
        if marker and not Path(marker).exists():
            Path(marker).write_text("failed once")
            raise RuntimeError("boom once")
        super()._fit(X_list)
