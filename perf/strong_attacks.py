"""Do strong attacks alone give the paper's 100 %? (issue 46, experiment a)

    python -m perf.strong_attacks RUN [RUN ...] [--evaluation NAME] [--min-sd 10]

From each run folder's flight outcomes (flight_scores.csv, or ``evaluations/NAME/flight_scores.csv``)
and its flights' detectability (how far the attack moves the attacked field, in standard deviations
of that field on validation flights), the TP in the attack window of the attacked flights whose attack
moves its field by ``--min-sd`` or more: per detector and mode, and per detector and attack family.
Prints Markdown (pooled over the runs, with the number of flights).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd


def outcomes(run: Path, evaluation: str | None) -> pd.DataFrame:
    folder = run / "evaluations" / evaluation if evaluation else run
    fs = pd.read_csv(folder / "flight_scores.csv", dtype={"flight_id": str})
    fl = pd.read_csv(run / "flights.csv", dtype={"flight_id": str})[["flight_id", "action", "detectability"]]
    out = fs[fs["role"] == "test_attacked"].merge(fl, on="flight_id", how="left")
    out["detected"] = out["outcome"] == "detected"
    out["run"] = run.name
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.strong_attacks", description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--evaluation", help="an evaluation folder's name (default: the run's own tables)")
    p.add_argument("--min-sd", type=float, default=10.0)
    args = p.parse_args(argv)
    df = pd.concat([outcomes(r, args.evaluation) for r in args.runs], ignore_index=True)
    strong = df[pd.to_numeric(df["detectability"], errors="coerce") >= args.min_sd]
    n = strong.groupby("detector").size().iloc[0] if len(strong) else 0
    print(f"{len(args.runs)} run(s); attacked flights moving their field by >= {args.min_sd:g} sd: {n} of "
          f"{df.groupby('detector').size().iloc[0]} (pooled over the runs)\n")
    print("| Detector | TP simulation | TP csv | TP all |")
    print("|---|---|---|---|")
    for det, g in strong.groupby("detector", sort=False):
        cells = [f"{100 * g[g['mode'] == m]['detected'].mean():.1f} (n={int((g['mode'] == m).sum())})"
                 for m in ("simulation", "csv")]
        print(f"| {det} | {cells[0]} | {cells[1]} | {100 * g['detected'].mean():.1f} |")
    fam = strong.pivot_table(index="detector", columns="action", values="detected", aggfunc="mean", sort=False)
    counts = strong[strong["detector"] == strong["detector"].iloc[0]].groupby("action").size() if len(strong) else {}
    print("\nTP (%) by attack family, strong attacks only (n flights per family in the header):\n")
    print("| Detector | " + " | ".join(f"{a} (n={counts[a]})" for a in fam.columns) + " |")
    print("|---|" + "---|" * len(fam.columns))
    for det, r in fam.iterrows():
        print(f"| {det} | " + " | ".join(f"{100 * v:.0f}" for v in r) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
