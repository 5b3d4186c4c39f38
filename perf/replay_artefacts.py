"""Can the paper's csv >> simulation pattern come from how its csv flights were made? (issue 46, experiment c)

    python -m perf.replay_artefacts RUN [--flights 64] [--detectors ...] [--phases ends] [--csv FILE]

The run's csv-mode attacked flights (a seeded sample of ``--flights``) are given one candidate replay
artefact at a time and scored by the run's detectors, each refitted once (the fit is deterministic:
the refit's scores on a validation flight are compared with the saved ones), at the run's thresholds
(recalibrated on its saved validation scores under the counting rule). The artefacts:

- ``splice``: inside the attack window every field is taken from the recording 1 s later (a splice
  of a shifted segment: a jump in every field where the window opens and closes);
- ``held``: inside the attack window every second row repeats the row before it (a segment
  re-gridded from half the rate, duplicated timestamps' values);
- ``rounded``: every value of the whole flight rounded to 3 decimals (a CSV export's precision);
- ``resampled``: the whole flight linearly interpolated half a row later (re-gridded onto another clock).

Printed per detector: TP csv (in window) and the share flagged before onset, untouched and with each
artefact; beside the run's TP simulation.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd

from perf.fresh_false_alarms import _spec, one_thread
from perf.phase_rules import Rule, row_alarms
from scart_bench.benchmark.jobs import run_job
from scart_bench.benchmark.protocol import Protocol, arming_time_us, flight_phase_bounds
from scart_bench.benchmark.results import ensure_phases
from scart_bench.benchmark.store import RunStore
from scart_bench.dataset import open_dataset

ARTEFACTS = ("splice", "held", "rounded", "resampled")
#: label and bookkeeping columns, never changed
KEEP = ("Index", "Timestamp", "Is_Anomaly", "Anomaly_Ids", "Anomaly_Kind")


def _values(flight: pd.DataFrame) -> list[str]:
    return [c for c in flight.columns if c not in KEEP and pd.api.types.is_numeric_dtype(flight[c])]


def with_artefact(flight: pd.DataFrame, artefact: str) -> pd.DataFrame:
    """The flight (a flat table) with one replay artefact; labels and timestamps unchanged."""
    out = flight.copy()
    cols = _values(flight)
    win = np.flatnonzero(flight["Is_Anomaly"].to_numpy() == 1)
    n = len(flight)
    if artefact in ("splice", "held") and win.size:
        a, b = int(win[0]), int(win[-1]) + 1
        if artefact == "splice":
            dt = np.median(np.diff(flight["Timestamp"].to_numpy(np.int64)))
            k = max(1, int(round(1e6 / dt)))
            src = np.minimum(np.arange(a, b) + k, n - 1)
            out.loc[out.index[a:b], cols] = flight[cols].to_numpy()[src]
        else:
            rows = np.arange(a + 1, b, 2)
            out.loc[out.index[rows], cols] = flight[cols].to_numpy()[rows - 1]
    elif artefact == "rounded":
        out[cols] = flight[cols].round(3)
    elif artefact == "resampled":
        v = flight[cols].to_numpy(np.float64)
        mid = np.vstack([(v[:-1] + v[1:]) / 2, v[-1:]])
        out[cols] = mid
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.replay_artefacts", description=__doc__.split("\n")[0])
    p.add_argument("run", type=Path)
    p.add_argument("--flights", type=int, default=64)
    p.add_argument("--detectors")
    p.add_argument("--phases", choices=("burn-in", "ends", "cruise"))
    p.add_argument("--csv", type=Path)
    args = p.parse_args(argv)
    one_thread()
    store = RunStore(args.run)
    config = store.read_config()
    protocol = Protocol.from_dict(config["identity"]["protocol"])
    if args.phases:
        protocol = dataclasses.replace(protocol, phases=args.phases)
    ensure_phases(store, config)
    alpha = protocol.alpha or 0.05
    ds = open_dataset(config["dataset"]["path"])
    flights = store.read_flights()
    flights["flight_id"] = flights["flight_id"].astype(str)
    kept = flights[flights["role"].isin(("validation", "test_normal", "test_attacked"))]
    csv_ids = list(kept.loc[(kept["role"] == "test_attacked") & (kept["mode"] == "csv"), "flight_id"])
    rng = np.random.default_rng(int(config.get("seed", 0)))
    chosen = sorted(rng.choice(csv_ids, size=min(args.flights, len(csv_ids)), replace=False).tolist())
    train = list(flights.loc[flights["role"] == "train", "flight_id"])
    val = list(kept.loc[kept["role"] == "validation", "flight_id"])
    truth = dict(store.read_truth())
    import pickle

    tables = {f"{c}+{what}": with_artefact(ds.flight(c), what) for c in chosen for what in ARTEFACTS}
    rows = []
    for new, f in tables.items():
        src, _, what = new.rpartition("+")
        truth[new] = (f["Timestamp"].to_numpy(np.int64), truth[src][1])
        armed, _ = arming_time_us(f)
        rows.append({"flight_id": new, "role": "artefact", "mode": what, "armed_us": armed, **flight_phase_bounds(f)})
    table = pd.concat([kept, pd.DataFrame(rows)], ignore_index=True).set_index("flight_id", drop=False)
    wanted = args.detectors.split(",") if args.detectors else None
    out = []
    for det in store.job_names():
        if (store.read_status(det) or {}).get("status") != "OK" or (wanted and det not in wanted):
            continue
        fit = run_job(_spec(store, det, str(ds.path), train, [], "fit"))
        if fit.status != "OK":
            print(f"{det}: refit failed: {fit.message}")
            continue
        model = pickle.loads(fit.model)
        saved = store.read_scores(det)
        diff = float(np.max(np.abs(np.asarray(model.score(ds.flight(val[0])), dtype=np.float64) - saved[val[0]])))
        scores = {f: np.asarray(s, dtype=np.float64) for f, s in saved.items()}
        scores.update({f: np.asarray(model.score(t), dtype=np.float64) for f, t in tables.items()})
        alarms, _ = row_alarms(Rule("run", protocol), table, truth, scores, alpha)
        row = {"detector": det, "refit_max_abs_diff": diff, "flights": len(chosen)}
        for what in ("untouched", *ARTEFACTS):
            ids = chosen if what == "untouched" else [f"{c}+{what}" for c in chosen]
            lab = [truth[f][1] == 1 for f in ids]
            first = [np.flatnonzero(x)[0] if x.any() else len(x) for x in lab]
            row[f"tp_{what}"] = 100.0 * np.mean([(alarms[f] & lab[i]).any() for i, f in enumerate(ids)])
            row[f"fa_before_{what}"] = 100.0 * np.mean([alarms[f][:first[i]].any() for i, f in enumerate(ids)])
        sim = kept.loc[(kept["role"] == "test_attacked") & (kept["mode"] == "simulation"), "flight_id"]
        row["tp_simulation"] = 100.0 * np.mean([(alarms[f] & (truth[f][1] == 1)).any() for f in sim])
        out.append(row)
        print(f"{det}: refit max |diff| {diff:.3g}; " + ", ".join(
            f"{w} {row[f'tp_{w}']:.1f}" for w in ("untouched", *ARTEFACTS)), flush=True)
    res = pd.DataFrame(out)
    if args.csv:
        res.to_csv(args.csv, index=False)
    print(f"\n{len(chosen)} csv-mode flights of {args.run.name}, counting rule {protocol.phases}, alpha {alpha:g}; "
          "TP csv in window % (flagged before onset %)")
    print("| Detector | TP simulation | untouched | " + " | ".join(ARTEFACTS) + " |")
    print("|---|---|---|" + "---|" * len(ARTEFACTS))
    for r in res.itertuples():
        print(f"| {r.detector} | {r.tp_simulation:.1f} | " + " | ".join(
            f"{getattr(r, 'tp_' + w):.1f} ({getattr(r, 'fa_before_' + w):.1f})" for w in ("untouched", *ARTEFACTS))
            + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
