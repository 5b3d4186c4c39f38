"""False alarms on a run's held-out normal flights by mission family, by airframe and by duration
quartile, beside their mean length and how many validation flights of each the thresholds were
calibrated on.

    python -m perf.false_alarms_by_family RUN DATASET

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

import pandas as pd

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


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m perf.false_alarms_by_family", description=__doc__.split("\n")[0])
    p.add_argument("run", type=Path, help="a run folder (flight_scores.csv)")
    p.add_argument("dataset", type=Path, help="the generated dataset it scored")
    args = p.parse_args(argv)
    for name, table in by_group(args.run, args.dataset).items():
        pct = table.assign(**{c: (100 * table[c]).round(1) for c in ("flagged_all", "flagged_paper")})
        print(f"{name}:\n{pct.to_string()}\n")


if __name__ == "__main__":
    main()
