"""The stated false-alarm rate checked on fresh flights: a run's detectors fitted once, scoring normal
flights of another seed at the run's own thresholds (protocol v3, issue 46).

    python -m perf.fresh_false_alarms RUN [--flights 180] [--seed 1000] [--fresh DATASET] [--alpha 0.05]

For each OK detector of the run: fitted once on the run's train flights with its saved parameters
(the fit is deterministic, so it is the run's model: its scores on the first validation flights are
compared with the saved ones and the largest difference printed), then scoring ``--flights`` normal
flights generated with the run's profile and another seed (``--fresh``: an existing dataset, else
one is generated beside the run as ``<run>-fresh-seed<S>``; every normal flight in it is scored,
whatever its split). Under each counting rule of :mod:`perf.phase_rules`, the thresholds are the
ones the run's validation scores give, and the measured per-flight false-alarm rate on the fresh
flights is printed with its exact (Clopper-Pearson) 95 % interval and whether it contains or lies
below alpha. Prints timing; writes the table as CSV with ``--csv``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import binomtest

from perf.phase_rules import default_rules, row_alarms
from scart_bench.benchmark.jobs import JobSpec, run_job
from scart_bench.benchmark.protocol import arming_time_us, flight_phase_bounds
from scart_bench.benchmark.results import ensure_phases
from scart_bench.benchmark.store import RunStore
from scart_bench.dataset import open_dataset

#: validation flights re-scored to show the refit is the run's model
CHECKED = 3


def one_thread() -> None:
    """One passive torch/OpenMP thread, as a benchmark job has (before torch is first imported, at the
    first fit): torch's default spinning threads made a refit several times slower on a loaded machine,
    and a refit with other thread counts can differ from the run's scores in the last digits."""
    for var, value in (("OMP_NUM_THREADS", "1"), ("MKL_NUM_THREADS", "1"), ("OMP_WAIT_POLICY", "PASSIVE")):
        os.environ.setdefault(var, value)


def fresh_dataset(run_config: dict, out: Path, seed: int, flights: int) -> Path:
    """``flights`` normal flights of the run's profile and another seed (generated once, then reused)."""
    from scart_bench.generator.generate import generate_dataset

    if not (out / "manifest.parquet").exists():
        generate_dataset(run_config.get("profile") or "standard", out, seed=seed, n_normal=flights,
                         with_attacks=False, jobs=min(2, os.cpu_count() or 1))
    return out


def _spec(store: RunStore, det: str, dataset: str, train: list[str], scored: list[str], stage: str,
          model: bytes | None = None) -> JobSpec:
    params = store.read_params(det)
    return JobSpec(det, params["key"]["source"], dict(params["params"]), (), dataset, tuple(train), tuple(scored),
                   1, stage=stage, model=model)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.fresh_false_alarms", description=__doc__.split("\n")[0])
    p.add_argument("run", type=Path)
    p.add_argument("--flights", type=int, default=180)
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--fresh", type=Path, help="a dataset of normal flights (default: generated beside the run)")
    p.add_argument("--alpha", type=float, help="target rate (default: the run's)")
    p.add_argument("--detectors", help="comma-separated (default: every OK job)")
    p.add_argument("--csv", type=Path)
    args = p.parse_args(argv)
    one_thread()
    store = RunStore(args.run)
    config = store.read_config()
    ensure_phases(store, config)
    alpha = args.alpha or float(config["identity"]["protocol"]["flight_rule"]["alpha"])
    t0 = time.perf_counter()
    fresh_path = args.fresh or args.run.parent / f"{args.run.name}-fresh-seed{args.seed}"
    fresh = open_dataset(fresh_dataset(config, fresh_path, args.seed, args.flights))
    fresh_ids = list(fresh.manifest.loc[fresh.manifest["mode"] == "normal", "flight_id"].astype(str))
    print(f"fresh flights: {len(fresh_ids)} normal flights of seed {args.seed} in {fresh_path} "
          f"({time.perf_counter() - t0:.0f} s)")
    flights = store.read_flights()
    flights["flight_id"] = flights["flight_id"].astype(str)
    train = list(flights.loc[flights["role"] == "train", "flight_id"])
    kept = flights[flights["role"].isin(("validation", "test_normal", "test_attacked"))]
    val = list(kept.loc[kept["role"] == "validation", "flight_id"])
    # the fresh flights join the run's flights as held-out normal flights of their own
    rows, truth = [], dict(store.read_truth())
    for fid in fresh_ids:
        f = fresh.flight(fid)
        armed, by = arming_time_us(f)
        key = f"fresh:{fid}"
        truth[key] = (f["Timestamp"].to_numpy(np.int64), f["Is_Anomaly"].to_numpy(np.int8))
        rows.append({"flight_id": key, "role": "fresh", "mode": "normal", "armed_us": armed, "armed_by": by,
                     **flight_phase_bounds(f)})
    table = pd.concat([kept, pd.DataFrame(rows)], ignore_index=True).set_index("flight_id", drop=False)
    dataset = str(Path(config["dataset"]["path"]))
    wanted = args.detectors.split(",") if args.detectors else None
    out = []
    for det in store.job_names():
        if (store.read_status(det) or {}).get("status") != "OK" or (wanted and det not in wanted):
            continue
        t1 = time.perf_counter()
        fit = run_job(_spec(store, det, dataset, train, [], "fit"))
        if fit.status != "OK":
            print(f"{det}: fit failed: {fit.message}")
            continue
        check = run_job(_spec(store, det, dataset, train, val[:CHECKED], "score", fit.model))
        saved = store.read_scores(det)
        diff = max(float(np.max(np.abs(check.scores[f] - saved[f]))) for f in val[:CHECKED])
        scored = run_job(_spec(store, det, str(fresh.path), train, fresh_ids, "score", fit.model))
        if scored.status != "OK":
            print(f"{det}: scoring the fresh flights failed: {scored.message}")
            continue
        scores = {f: np.asarray(s, dtype=np.float64) for f, s in saved.items()}
        scores.update({f"fresh:{f}": np.asarray(s, dtype=np.float64) for f, s in scored.scores.items()})
        for rule in default_rules(alpha):
            alarms, _ = row_alarms(rule, table, truth, scores, alpha)
            k = sum(bool(alarms[f"fresh:{f}"].any()) for f in fresh_ids)
            ci = binomtest(k, len(fresh_ids)).proportion_ci(method="exact")
            out.append({"detector": det, "rule": rule.name, "alpha": alpha, "fresh_flights": len(fresh_ids),
                        "flagged": k, "rate": 100.0 * k / len(fresh_ids), "lo": 100.0 * ci.low,
                        "hi": 100.0 * ci.high, "holds": bool(ci.low <= alpha),
                        "refit_max_abs_diff": diff, "seconds": time.perf_counter() - t1})
        print(f"{det}: fitted {fit.fit_seconds:.1f} s, {len(fresh_ids)} fresh flights scored in "
              f"{scored.score_seconds:.1f} s; refit vs saved scores on {CHECKED} validation flights: "
              f"max |diff| {diff:.3g}", flush=True)
    res = pd.DataFrame(out)
    if args.csv:
        res.to_csv(args.csv, index=False)
    print(f"\nalpha {alpha:g}; {len(fresh_ids)} fresh normal flights (seed {args.seed}); thresholds from the run's "
          f"{len(val)} validation flights; rate % [exact 95 % interval]; holds: the interval contains alpha or lies "
          "below it")
    print("| Detector | " + " | ".join(dict.fromkeys(res["rule"])) + " |")
    print("|---|" + "---|" * res["rule"].nunique())
    for det, g in res.groupby("detector", sort=False):
        print(f"| {det} | " + " | ".join(f"{r.rate:.1f} [{r.lo:.1f}-{r.hi:.1f}]{'' if r.holds else ' (above)'}"
                                         for r in g.itertuples()) + " |")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    print(json.dumps({"holds_everywhere": {r: bool(g["holds"].all()) for r, g in res.groupby("rule")}}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
