"""Each detector scored with its own published decision rule, the closest replica of the SCART paper's
protocol we can state (issue 46, experiment b).

    python -m perf.own_rules RUN [RUN ...] [--detectors ...] [--csv FILE]

From a run folder's saved scores, with the detector refitted once where its rule needs the fitted model
(the fit is deterministic; the refit's scores on a validation flight are compared with the saved ones):

- **statistical**: its vote (a row alarms when ``min_exceed`` of its thresholds are exceeded at once:
  a saved score above 1.0);
- **telemanom**: Hundman et al.'s nonparametric dynamic threshold with pruning (``Telemanom.alarms``,
  refitted and run on every scored flight);
- **deepsvdd, rdp, rca, goad, neutral**: DeepOD's default decision rule, a window is anomalous above
  the ``1 - contamination`` quantile of the training windows' scores (``contamination`` 0.1; the
  fitted model's ``threshold_``), applied to the saved row scores.

Rows outside the counting rule (``--phases``, default the run's) never alarm, as under the common
threshold. Per run and detector: TP in the window and flagged anywhere per mode, false alarms on the
held-out normal flights (per flight), beside the run's calibrated threshold at its alpha.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from perf.fresh_false_alarms import _spec, one_thread
from perf.phase_rules import scored_flights
from scart_bench.benchmark.jobs import run_job
from scart_bench.benchmark.protocol import Protocol, counted_masks
from scart_bench.benchmark.store import RunStore

DEEPOD = ("deepsvdd", "rdp", "rca", "goad", "neutral")
RULES = {"statistical": "its vote (score > 1)", "telemanom": "nonparametric dynamic threshold",
         **dict.fromkeys(DEEPOD, "DeepOD default: training-window quantile at contamination 0.1")}


def own_alarms(store: RunStore, det: str, flights: pd.DataFrame, scores: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """flight id -> the detector's own row alarms on every scored flight."""
    ids = list(flights.index)
    if det == "statistical":
        return {f: scores[f] > 1.0 for f in ids}
    config = store.read_config()
    dataset = str(config["dataset"]["path"])
    train = list(store.read_flights().query("role == 'train'")["flight_id"].astype(str))
    fit = run_job(_spec(store, det, dataset, train, [], "fit"))
    if fit.status != "OK":
        raise RuntimeError(f"{det}: refit failed: {fit.message}")
    check = [f for f in ids if flights.at[f, "role"] == "validation"][:1]
    again = run_job(_spec(store, det, dataset, train, check, "score", fit.model))
    diff = float(np.max(np.abs(again.scores[check[0]] - scores[check[0]])))
    print(f"  {det}: refit in {fit.fit_seconds:.1f} s; its scores on {check[0]} vs saved: max |diff| {diff:.3g}",
          flush=True)
    if det == "telemanom":
        spec = _spec(store, det, dataset, train, [f for f in ids if flights.at[f, "role"] != "validation"],
                     "score", fit.model)
        from dataclasses import replace

        res = run_job(replace(spec, own_alarms=True))
        if res.status != "OK":
            raise RuntimeError(f"telemanom: own alarms failed: {res.message}")
        return res.alarms
    import pickle

    threshold = float(pickle.loads(fit.model).model_.threshold_)
    print(f"  {det}: DeepOD threshold_ {threshold:.4g}", flush=True)
    return {f: scores[f] > threshold for f in ids}


def evaluate(run: Path, detectors: list[str], phases: str | None) -> pd.DataFrame:
    store = RunStore(run)
    config = store.read_config()
    protocol = Protocol.from_dict(config["identity"]["protocol"])
    if phases:
        import dataclasses

        protocol = dataclasses.replace(protocol, phases=phases)
    flights = scored_flights(store)
    truth = store.read_truth()
    counted = counted_masks(protocol, flights, {f: truth[f][0] for f in flights.index})
    metrics = pd.read_csv(run / "metrics.csv").set_index("detector")
    rows = []
    for det in detectors:
        if det not in store.job_names() or (store.read_status(det) or {}).get("status") != "OK":
            continue
        print(f"{run.name}: {det}", flush=True)
        scores = {f: np.asarray(s, dtype=np.float64) for f, s in store.read_scores(det).items()}
        alarms = own_alarms(store, det, flights, scores)
        row = {"run": run.name, "detector": det, "rule": RULES[det], "counting": protocol.phases}
        normal = [f for f in flights.index if flights.at[f, "role"] == "test_normal"]
        row["false_alarms"] = 100.0 * np.mean([(alarms[f] & counted[f]).any() for f in normal])
        for mode in ("simulation", "csv"):
            att = [f for f in flights.index if flights.at[f, "role"] == "test_attacked" and flights.at[f, "mode"] == mode]
            row[f"tp_{mode}"] = 100.0 * np.mean([(alarms[f] & counted[f] & (truth[f][1] == 1)).any() for f in att])
            row[f"flagged_{mode}"] = 100.0 * np.mean([(alarms[f] & counted[f]).any() for f in att])
            row[f"calibrated_tp_{mode}"] = 100.0 * float(metrics.at[det, f"tp_{mode}"])
        row["calibrated_false_alarms"] = 100.0 * float(metrics.at[det, "far_no_attack"])
        rows.append(row)
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.own_rules", description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--detectors", default=",".join(RULES))
    p.add_argument("--phases", choices=("burn-in", "ends", "cruise"), help="counting rule (default: the run's)")
    p.add_argument("--csv", type=Path)
    args = p.parse_args(argv)
    one_thread()
    table = pd.concat([evaluate(r, args.detectors.split(","), args.phases) for r in args.runs], ignore_index=True)
    if args.csv:
        table.to_csv(args.csv, index=False)
    print("\n| Detector | Own rule | TP sim / TP csv in window | Flagged anywhere sim / csv | False alarms | "
          "Calibrated (alpha): TP sim / TP csv / false alarms |")
    print("|---|---|---|---|---|---|")
    for det, g in table.groupby("detector", sort=False):
        m = g.mean(numeric_only=True)
        print(f"| {det} | {g['rule'].iloc[0]} | {m.tp_simulation:.1f} / {m.tp_csv:.1f} | "
              f"{m.flagged_simulation:.1f} / {m.flagged_csv:.1f} | {m.false_alarms:.1f} | "
              f"{m.calibrated_tp_simulation:.1f} / {m.calibrated_tp_csv:.1f} / {m.calibrated_false_alarms:.1f} |")
    print(f"(mean over {table['run'].nunique()} run(s))")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
