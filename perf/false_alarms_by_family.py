"""False alarms on a run's held-out normal flights by mission family, by airframe and by duration
quartile, beside their mean length and how many validation flights of each the thresholds were
calibrated on.

    python -m perf.false_alarms_by_family RUN DATASET [--permutations 2000]

``--permutations N`` adds the split test: is the held-out flights' false-alarm rate (pooled over the
run's detectors) within what a random split of the same normal flights into validation and held-out
gives? The validation and held-out flights of the run are pooled and re-split N times at random (as
many validation flights as the run had), the conformal threshold of each detector recalibrated on each
draw; printed: the observed rate, the draws' mean and standard deviation, and the share of draws at or
above the observed rate (a one-sided p-value). The draws keep the detectors' correlation (the same
flights set every detector's threshold), which a binomial interval per detector does not.

A generated dataset with the mission mix draws each flight's family and airframe independently of its
split; a family that is rare among the validation flights and scores high is under-covered by a
per-flight threshold (docs/missions.md, "False alarms by family"). Reads ``flight_scores.csv`` of the
run, each flight's ``raw/config.json`` (its ``flight.family`` and ``flight.airframe``) and the
manifest's ``duration_s``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.protocol import conformal_rank
from scart_bench.dataset import open_dataset
from scart_bench.detectors.registry import PAPER


def flight_info(dataset: Path, flight_id: str) -> dict:
    """The generated flight's ``family`` and ``airframe`` ("?" for a flight without them)."""
    flight = json.loads((dataset / "flights" / flight_id / "raw" / "config.json").read_text()).get("flight", {})
    return {"family": flight.get("family", "?"), "airframe": flight.get("airframe", "?")}


def by_group(run: Path, dataset: Path) -> dict[str, pd.DataFrame]:
    """Per family and per airframe: held-out normal flights, the share flagged over every detector of
    the run and over the paper's eight, and the validation flights of that group."""
    scores = pd.read_csv(run / "flight_scores.csv")
    normal = scores[scores["role"] == "test_normal"].copy()
    manifest = open_dataset(dataset).manifest
    val = manifest.loc[(manifest["mode"].astype(str) == "normal") & (manifest["split"].astype(str) == "validation"),
                       "flight_id"].astype(str)
    info = {f: flight_info(dataset, f) for f in set(normal["flight_id"].astype(str)) | set(val)}
    paper = set(PAPER)
    duration = manifest.set_index(manifest["flight_id"].astype(str))["duration_s"].astype(float)
    normal["minutes"] = duration.reindex(normal["flight_id"].astype(str)).to_numpy() / 60.0
    # held-out flights by duration quartile: a per-flight rate grows with the flight's length
    quartiles = pd.qcut(normal.drop_duplicates("flight_id")["minutes"], 4, duplicates="drop").cat.categories
    normal["duration"] = pd.cut(normal["minutes"], quartiles, include_lowest=True).astype(str)
    out = {}
    for key in ("family", "airframe", "duration"):
        if key != "duration":
            normal[key] = [info[f][key] for f in normal["flight_id"].astype(str)]
        table = normal.groupby(key).agg(held_out=("flight_id", "nunique"), minutes=("minutes", "mean"),
                                        flagged_all=("flagged", "mean"))
        table["flagged_paper"] = normal[normal["detector"].isin(paper)].groupby(key)["flagged"].mean()
        if key == "duration":
            out[key] = table.round({"minutes": 2})
            continue
        table["validation"] = pd.Series([info[f][key] for f in val]).value_counts()
        out[key] = table.fillna({"validation": 0}).astype({"validation": int}).round({"minutes": 2})
    out["all"] = pd.DataFrame({"flagged_all": [normal["flagged"].mean()],
                               "flagged_paper": [normal.loc[normal["detector"].isin(paper), "flagged"].mean()]})
    return out


def split_test(run: Path, permutations: int = 2000, seed: int = 0) -> dict[str, float]:
    """The held-out normal flights' false-alarm rate pooled over the run's detectors against random
    re-splits of the run's validation and held-out normal flights (see the module docstring)."""
    cfg = json.loads((run / "config.json").read_text())["protocol"]["flight_rule"]
    if cfg["kind"] != "conformal":
        raise SystemExit(f"{run}: flight threshold rule {cfg['kind']!r}; the split test needs the conformal rule")
    scores = pd.read_csv(run / "flight_scores.csv")
    normal = scores[scores["role"].isin(("validation", "test_normal"))]
    table = normal.pivot(index="flight_id", columns="detector", values="score")
    role = normal.drop_duplicates("flight_id").set_index("flight_id")["role"].reindex(table.index)
    values, is_val = table.to_numpy(dtype=float), (role == "validation").to_numpy()
    n_val = int(is_val.sum())
    k = min(conformal_rank(n_val, float(cfg["alpha"])), n_val)

    def rate(val: np.ndarray) -> float:
        threshold = np.sort(values[val], axis=0)[k - 1]
        return float((values[~val] > threshold).mean())

    observed = rate(is_val)
    flagged = float(normal.loc[normal["role"] == "test_normal", "flagged"].mean())
    if not np.isclose(observed, flagged):
        raise SystemExit(f"{run}: recomputed held-out rate {observed:.4f} differs from flight_scores.csv's "
                         f"{flagged:.4f} (an hourly operating point or another rule): the split test does not apply")
    rng = np.random.default_rng(seed)
    draws = np.empty(permutations)
    for i in range(permutations):
        val = np.zeros(len(values), dtype=bool)
        val[rng.choice(len(values), n_val, replace=False)] = True
        draws[i] = rate(val)
    return {"validation": n_val, "held_out": int(len(values) - n_val), "detectors": int(values.shape[1]),
            "observed": observed, "mean": float(draws.mean()), "sd": float(draws.std()),
            "p": float((draws >= observed).mean()), "expected": 1.0 - k / (n_val + 1)}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m perf.false_alarms_by_family", description=__doc__.split("\n")[0])
    p.add_argument("run", type=Path, help="a run folder (flight_scores.csv)")
    p.add_argument("dataset", type=Path, help="the generated dataset it scored")
    p.add_argument("--permutations", type=int, default=0, metavar="N",
                   help="also test the split: N random re-splits of the validation and held-out flights")
    args = p.parse_args(argv)
    for name, table in by_group(args.run, args.dataset).items():
        pct = table.assign(**{c: (100 * table[c]).round(1) for c in ("flagged_all", "flagged_paper")})
        print(f"{name}:\n{pct.to_string()}\n")
    if args.permutations:
        t = split_test(args.run, args.permutations)
        print(f"split test ({t['validation']} validation, {t['held_out']} held-out flights, {t['detectors']} "
              f"detectors, {args.permutations} re-splits): held-out false alarms {100 * t['observed']:.1f} %, "
              f"re-splits {100 * t['mean']:.1f} +- {100 * t['sd']:.1f} % (conformal expectation "
              f"{100 * t['expected']:.2f} %), p = {t['p']:.3f}")


if __name__ == "__main__":
    main()
