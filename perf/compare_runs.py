"""Whether two run folders scored identically: every detector's saved scores compared byte for byte,
and metrics.csv without its timing columns.

    python -m perf.compare_runs RUN_A RUN_B

For checking that a speed change left the scores alone (e.g. a run before and after it on the same
dataset and seed). Exit 0 when every common detector is byte-identical, 1 otherwise.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.metrics import TIMING_COLUMNS
from scart_bench.benchmark.store import RunStore


def _quality(run: Path) -> pd.DataFrame:
    m = pd.read_csv(run / "metrics.csv")
    return m.drop(columns=[c for c in (*TIMING_COLUMNS, "rows") if c in m.columns]).set_index("detector")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.compare_runs", description=__doc__.split("\n")[0])
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    args = p.parse_args(argv)
    a, b = RunStore(args.a), RunStore(args.b)
    same_all = True
    for det in sorted(set(a.job_names()) | set(b.job_names())):
        if det not in a.job_names() or det not in b.job_names():
            print(f"{det:14s} only in {args.a if det in a.job_names() else args.b}")
            continue
        sa, sb = a.read_scores(det), b.read_scores(det)
        same = sa.keys() == sb.keys() and all(sa[k].tobytes() == sb[k].tobytes() for k in sa)
        rel = max((float(np.max(np.abs(sa[k] - sb[k]) / np.maximum(np.abs(sa[k]), 1e-300), initial=0.0))
                   for k in sa if k in sb and sa[k].shape == sb[k].shape), default=float("nan"))
        same_all &= same
        print(f"{det:14s} byte-identical {same!s:5s}  max relative difference {rel:.2e}")
    qa, qb = _quality(args.a), _quality(args.b)
    common = qa.index.intersection(qb.index)
    try:
        pd.testing.assert_frame_equal(qa.loc[common], qb.loc[common])
        print("metrics.csv without timings: identical")
    except AssertionError as exc:
        same_all = False
        print(f"metrics.csv without timings: differ ({str(exc).splitlines()[0]})")
    return 0 if same_all else 1


if __name__ == "__main__":
    sys.exit(main())
