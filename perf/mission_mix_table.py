"""The effect of mission diversity on every detector: one profile's runs on its mission mix beside the
same profile's runs on the square, same seeds, code and protocol (issue 47 acceptance 5).

    python -m perf.mission_mix_table --mix runs/zoo/standard-seed{0,1,2} \\
        --square runs/standard-square-seed{0,1,2} [--detectors paper]

Reads each run's ``metrics.csv`` and prints a Markdown table: per detector, TP in simulation mode, TP in
csv mode, TN on the held-out normal flights and ROC-AUC, each the mean over the runs with the lowest
and highest run in brackets, on the mix and on the square, and the mix minus the square. The runs of a
side are the seeds of one setting; a detector missing from a run (or not OK) is left out of that side.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from scart_bench.detectors.registry import PAPER

#: (metrics.csv column, header, as a percentage)
COLUMNS = (("tp_simulation", "TP sim", True), ("tp_csv", "TP csv", True), ("tn_no_attack", "TN", True),
           ("roc_auc", "ROC-AUC", False))


def side(runs: list[Path]) -> pd.DataFrame:
    """Every OK detector row of the runs' metrics.csv, with the run's name."""
    frames = []
    for run in runs:
        if not (run / "metrics.csv").is_file():
            raise SystemExit(f"{run}: no metrics.csv (not a run folder, or its run has not finished)")
        m = pd.read_csv(run / "metrics.csv")
        ok = m.loc[m["status"] == "OK", ["detector", *(c for c, _, _ in COLUMNS)]].copy()
        ok["run"] = run.name
        frames.append(ok)
    return pd.concat(frames, ignore_index=True)


def _cell(values: pd.Series, pct: bool) -> str:
    k, fmt = (100.0, "{:.1f}") if pct else (1.0, "{:.3f}")
    v = values * k
    return f"{fmt.format(v.mean())} ({fmt.format(v.min())}-{fmt.format(v.max())})"


def table(mix: list[Path], square: list[Path], detectors: list[str] | None = None) -> str:
    """The Markdown table (see the module docstring)."""
    a, b = side(mix), side(square)
    names = [d for d in (detectors or sorted(set(a["detector"]) & set(b["detector"])))
             if d in set(a["detector"]) and d in set(b["detector"])]
    head = ["Detector"] + [f"{h} {s}" for _, h, _ in COLUMNS for s in ("mix", "square", "mix - square")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for d in names:
        x, y = a[a["detector"] == d], b[b["detector"] == d]
        cells = [d]
        for col, _, pct in COLUMNS:
            k = 100.0 if pct else 1.0
            diff = (x[col].mean() - y[col].mean()) * k
            cells += [_cell(x[col], pct), _cell(y[col], pct), f"{diff:+.1f}" if pct else f"{diff:+.3f}"]
        lines.append("| " + " | ".join(cells) + " |")
    n_mix, n_square = a["run"].nunique(), b["run"].nunique()
    lines.append("")
    lines.append(f"Mean over {n_mix} mix and {n_square} square runs (lowest-highest run).")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m perf.mission_mix_table", description=__doc__.split("\n")[0])
    p.add_argument("--mix", type=Path, nargs="+", required=True, help="run folders on the mission mix")
    p.add_argument("--square", type=Path, nargs="+", required=True, help="run folders on the square")
    p.add_argument("--detectors", default=None,
                   help="'paper' (the paper's eight) or names, comma-separated (default: those in both sides)")
    args = p.parse_args(argv)
    dets = None
    if args.detectors:
        dets = list(PAPER) if args.detectors == "paper" else [d.strip() for d in args.detectors.split(",") if d.strip()]
    print(table(args.mix, args.square, dets))


if __name__ == "__main__":
    main()
