"""The analysis scripts behind docs/missions.md and docs/realism.md: the split test of a run's held-out false
alarms (perf.false_alarms_by_family) and the mix-beside-the-square table (perf.mission_mix_table)."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from perf.false_alarms_by_family import split_test
from perf.mission_mix_table import table


def _run(path, shift: float, seed: int, flagged_right: bool = True):
    """A run folder with two detectors' flight scores: 60 validation and 60 held-out normal flights, the held-out
    ones ``shift`` standard deviations higher, flagged by the conformal threshold of the validation scores."""
    rng = np.random.default_rng(seed)
    path.mkdir()
    (path / "config.json").write_text(json.dumps({"protocol": {"flight_rule": {"kind": "conformal", "alpha": 0.05}}}))
    rows = []
    for det in ("a", "b"):
        val, held = rng.normal(size=60), rng.normal(size=60) + shift
        threshold = np.sort(val)[math.ceil(61 * 0.95) - 1]
        rows += [(det, f"v{i}", "validation", "normal", x, x > threshold) for i, x in enumerate(val)]
        rows += [(det, f"h{i}", "test_normal", "normal", x, (x > threshold) == flagged_right) for i, x in enumerate(held)]
    pd.DataFrame(rows, columns=["detector", "flight_id", "role", "mode", "score", "flagged"]).to_csv(
        path / "flight_scores.csv", index=False)
    return path


def test_the_split_test_tells_a_shifted_held_out_split_from_a_lucky_one(tmp_path):
    shifted = split_test(_run(tmp_path / "shifted", 1.5, 0), permutations=400)
    assert shifted["observed"] > 0.3 and shifted["p"] < 0.01  # no random re-split flags that many
    assert abs(shifted["mean"] - shifted["expected"]) < 0.1  # re-splits mix the two halves
    alike = split_test(_run(tmp_path / "alike", 0.0, 1), permutations=400)
    assert alike["observed"] < 0.15 and alike["p"] > 0.05
    assert alike["expected"] == pytest.approx(1 - 58 / 61)
    # flags that the conformal threshold does not give (another rule): refused, not tested
    with pytest.raises(SystemExit, match="does not apply"):
        split_test(_run(tmp_path / "other_rule", 0.0, 2, flagged_right=False), permutations=10)


def test_the_mix_table_puts_each_detector_s_seeds_side_by_side(tmp_path):
    def runs(side: str, tp: list[float]):
        out = []
        for seed, v in enumerate(tp):
            d = tmp_path / f"{side}-{seed}"
            d.mkdir()
            pd.DataFrame({"detector": ["deepsvdd", "pca"], "status": ["OK", "ERROR"], "tp_simulation": [v, 0.9],
                          "tp_csv": [v / 2, 0.9], "tn_no_attack": [0.95, 0.9], "roc_auc": [0.8, 0.5]}).to_csv(
                d / "metrics.csv", index=False)
            out.append(d)
        return out

    page = table(runs("mix", [0.40, 0.50]), runs("square", [0.70, 0.70, 0.70]))
    row = next(line for line in page.splitlines() if line.startswith("| deepsvdd |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1:4] == ["45.0 (40.0-50.0)", "70.0 (70.0-70.0)", "-25.0"]  # TP simulation: mix, square, difference
    assert cells[4:7] == ["22.5 (20.0-25.0)", "35.0 (35.0-35.0)", "-12.5"]
    assert "| pca |" not in page  # a detector that failed on both sides has no row
    assert "Mean over 2 mix and 3 square runs" in page
    with pytest.raises(SystemExit, match="no metrics.csv"):
        table([tmp_path / "nowhere"], runs("sq2", [0.5]))
