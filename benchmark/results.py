"""A run's results from its saved files: results.csv (one row per job), the metrics, the breakdown and
the Markdown tables. Nothing here runs a detector, so a run can be re-scored at any time."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from scart_bench.benchmark.evaluation import (
    CALIBRATION_COLUMNS,
    PHASE_CALIBRATION_COLUMNS,
    ScoreError,
    build_evaluation,
    calibration_table,
)
from scart_bench.benchmark.metrics import (
    DEFAULT_METRICS,
    HOURLY_METRIC_COLUMNS,
    NEAR_ARMING_S,
    NEAR_ENDS_S,
    OC_ALPHAS,
    OC_COLUMNS,
    PHASE_METRIC_COLUMNS,
    compute_metrics,
    operating_characteristic,
)
from scart_bench.benchmark.protocol import Protocol
from scart_bench.benchmark.store import RunStore, RunStoreError, atomic_write_json
from scart_bench.benchmark.tables import (
    BREAKDOWN_COLUMNS,
    DETECTION_RULE,
    EXTRA_COLUMNS,
    INTERVAL_METHOD,
    PAPER_COLUMNS,
    breakdown,
    markdown_table,
    rate_summary,
)

_RESULT_COLUMNS = ("detector", "status", "message", "fit_s", "score_s", "rows", "latency_us_per_row",
                   "n_train_flights", "n_scored_flights", "max_rss_mb", "wall_s", "source", "finished")


def _job_order(store: RunStore, config: dict) -> list[str]:
    return list(dict.fromkeys([*config.get("detectors", []), *store.job_names()]))


def _result_row(store: RunStore, config: dict, name: str) -> dict:
    st = store.read_status(name) or {}
    rows = st.get("rows_scored") or 0
    score_s = st.get("score_seconds", float("nan"))
    score_s = float("nan") if score_s is None else float(score_s)
    return {
        "detector": name,
        "status": st.get("status", "UNFINISHED"),
        "message": st.get("message", "" if st else "the job did not finish; rerun with --resume"),
        "fit_s": st.get("fit_seconds"),
        "score_s": score_s,
        "rows": rows,
        "latency_us_per_row": score_s / rows * 1e6 if rows else float("nan"),
        "n_train_flights": st.get("n_train_flights"),
        "n_scored_flights": st.get("n_scored_flights"),
        "max_rss_mb": st.get("max_rss_mb"),
        "wall_s": st.get("wall_seconds"),
        "source": config.get("jobs", {}).get(name, {}).get("source"),
        "finished": st.get("finished"),
    }


def write_results(store: RunStore) -> pd.DataFrame:
    """results.csv: one row per job of the run (UNFINISHED for a job without status)."""
    config = store.read_config()
    df = pd.DataFrame([_result_row(store, config, n) for n in _job_order(store, config)],
                      columns=list(_RESULT_COLUMNS))
    store.write_table("results.csv", df)
    return df


class _RunScores:
    """What every detector's metrics need from a run folder, read once per process. ``protocol``
    (rules as plain data, :meth:`Protocol.rules`): another operating point than the run's own."""

    def __init__(self, path: str | Path, protocol: dict | None = None):
        self.store = RunStore(path)
        self.protocol = Protocol.from_dict(protocol if protocol is not None
                                           else self.store.read_config()["identity"]["protocol"])
        self.flights = self.store.read_flights()
        self.truth = self.store.read_truth()

    def detector(self, res: dict) -> tuple[dict, pd.DataFrame | None, pd.DataFrame | None, pd.DataFrame | None]:
        """One detector's metrics row, breakdown, flight scores and calibration table from its saved
        scores."""
        row = {"detector": res["detector"], "status": res["status"], "message": res["message"]}
        bd = fs = cal = None
        if res["status"] == "OK":
            try:
                scores = self.store.read_scores(res["detector"])
                alarms = self.store.read_alarms(res["detector"]) if self.protocol.alarm_rule == "own" else None
                ev = build_evaluation(res["detector"], self.flights, self.truth, scores, self.protocol,
                                      fit_seconds=res["fit_s"], score_seconds=res["score_s"],
                                      rows_scored=int(res["rows"]), alarms=alarms)
            except (ScoreError, OSError, ValueError) as exc:
                row.update(status="ERROR", message=f"saved scores unusable: {exc}")
            else:
                row.update(compute_metrics(ev))
                bd = breakdown(ev)
                fs = ev.flights[list(FLIGHT_SCORE_COLUMNS)].copy()
                fs.insert(0, "detector", res["detector"])
                cal = calibration_table(ev)
                cal.insert(0, "detector", res["detector"])
        row.update(fit_s=res["fit_s"], score_s=res["score_s"], rows=res["rows"])
        return row, bd, fs, cal


_WORKER_RUN: _RunScores | None = None


def _worker_start(path: str, protocol: dict | None = None) -> None:
    global _WORKER_RUN
    _WORKER_RUN = _RunScores(path, protocol)


def _worker_detector(res: dict) -> tuple[dict, pd.DataFrame | None, pd.DataFrame | None, pd.DataFrame | None]:
    assert _WORKER_RUN is not None
    return _WORKER_RUN.detector(res)


def _default_processes(config: dict) -> int:
    """The run's own parallelism: its local executor's job count, at most the machine's cores."""
    executor = config.get("executor", {})
    jobs = int(executor.get("jobs", 1) or 1) if executor.get("kind", "local") == "local" else 1
    return max(1, min(jobs, os.cpu_count() or 1))


def _score_detectors(store: RunStore, todo: list[dict], processes: int,
                     protocol: dict | None = None) -> list[tuple]:
    """Every job's (metrics row, breakdown, flight scores, calibration) from its saved scores, at the
    run's operating point or at ``protocol``'s, ``processes`` detectors at a time."""
    n_ok = sum(r["status"] == "OK" for r in todo)
    if processes > 1 and n_ok > 1:
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=min(processes, n_ok), mp_context=ctx, initializer=_worker_start,
                                 initargs=(str(store.path), protocol)) as pool:
            return list(pool.map(_worker_detector, todo))
    run = _RunScores(store.path, protocol)
    return [run.detector(r) for r in todo]


def _write_tables(store: RunStore, config: dict, done: list[tuple], prefix: str = "",
                  evaluation: dict | None = None) -> pd.DataFrame:
    """The metrics table of ``done`` (:func:`_score_detectors`), written as metrics.csv, metrics.md,
    breakdown.csv, flight_scores.csv and calibration.csv under ``prefix`` in the run folder."""
    breakdowns = [bd for _, bd, _, _ in done if bd is not None]
    flight_scores = [fs for _, _, fs, _ in done if fs is not None]
    calibrations = [cal for _, _, _, cal in done if cal is not None]
    metrics = _metrics_of(done)
    store.write_table(f"{prefix}metrics.csv", metrics)
    store.write_text(f"{prefix}metrics.md", metrics_markdown(config, metrics, evaluation))
    bd = pd.concat(breakdowns, ignore_index=True) if breakdowns else breakdown_columns()
    store.write_table(f"{prefix}breakdown.csv", bd)
    fs = pd.concat(flight_scores, ignore_index=True) if flight_scores else pd.DataFrame(
        columns=["detector", *FLIGHT_SCORE_COLUMNS])
    store.write_table(f"{prefix}flight_scores.csv", fs)
    cal = pd.concat(calibrations, ignore_index=True) if calibrations else pd.DataFrame(
        columns=["detector", *(c for c in CALIBRATION_COLUMNS if c not in PHASE_CALIBRATION_COLUMNS)])
    store.write_table(f"{prefix}calibration.csv", cal)
    return metrics


def _metrics_of(done: list[tuple]) -> pd.DataFrame:
    """The metrics table (one row per job, metrics.csv's columns) of :func:`_score_detectors`'s result."""
    columns = ["detector", "status", "message", *(c for m in DEFAULT_METRICS for c in m.columns),
               "flight_threshold", "row_threshold", "fit_s", "score_s", "rows"]
    table = pd.DataFrame([row for row, _, _, _ in done], columns=columns)
    # a run without phase bounds (made before protocol v3) keeps metrics.csv's columns as they were
    # columns that only some runs fill (phase bounds since v3, the small-data operating point) are left
    # out when no detector has them, so older runs' metrics.csv keep their columns
    for group, key in ((PHASE_METRIC_COLUMNS, "val_max_near_ends"), (HOURLY_METRIC_COLUMNS, "hourly_rate")):
        if table[key].isna().all():
            table = table.drop(columns=list(group))
    return table


def score_run(path: str | Path, write: bool = True, processes: int | None = None) -> pd.DataFrame:
    """Recompute every metric of a run from its saved scores (no detector runs).

    Writes results.csv, metrics.csv, metrics.md, breakdown.csv and flight_scores.csv (when
    ``write``) and returns the metrics table, one row per detector. ``processes`` (default: the
    run's job count) computes that many detectors' metrics at a time in spawned processes; the
    tables are the same whatever the count.
    """
    store = RunStore(path)
    config = store.read_config()
    results = write_results(store) if write else pd.DataFrame(
        [_result_row(store, config, n) for n in _job_order(store, config)], columns=list(_RESULT_COLUMNS))
    processes = _default_processes(config) if processes is None else max(1, int(processes))
    done = _score_detectors(store, results.to_dict("records"), processes)
    return _write_tables(store, config, done) if write else _metrics_of(done)


def operating_characteristics(path: str | Path, detectors: list[str] | None = None,
                              alphas: tuple[float, ...] = OC_ALPHAS) -> pd.DataFrame:
    """Each OK detector's flight-level operating characteristic (:func:`benchmark.metrics.operating_characteristic`)
    from the run's saved scores, at the run's burn-in and with calibrated thresholds (a run with
    ``--threshold own`` too: the characteristic is its scores'); ``detectors``: only these. No job is run.
    ScoreError / RunStoreError naming the file when a detector's saved scores are unusable."""
    store = RunStore(path)
    config = store.read_config()
    protocol = dataclasses.replace(Protocol.from_dict(config["identity"]["protocol"]), alarm_rule="calibrated")
    run = _RunScores(store.path, protocol.rules())
    frames = []
    for name in _job_order(store, config):
        status = store.read_status(name) or {}
        if status.get("status") != "OK" or (detectors is not None and name not in detectors):
            continue
        ev = build_evaluation(name, run.flights, run.truth, store.read_scores(name), protocol)
        frames.append(operating_characteristic(ev, alphas))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=list(OC_COLUMNS))


#: The folder of a run holding the evaluations made after it (``scart-bench score RUN --alpha``).
EVALUATIONS_DIR = "evaluations"
EVALUATION_FORMAT = "scart-bench-evaluation/1"


def evaluation_name(alpha: float | None = None, burn_in_s: float | None = None, phases: str | None = None,
                    phase_margin_s: float | None = None) -> str:
    """The folder name of an evaluation at another operating point: ``alpha-0.01``,
    ``alpha-0.01-burnin-12``, ``burnin-12``, ``phases-ends``, ``alpha-0.01-phases-ends-margin-5``."""
    parts = ([f"alpha-{alpha:g}"] if alpha is not None else []) + (
        [f"burnin-{burn_in_s:g}"] if burn_in_s is not None else []) + (
        [f"phases-{phases}"] if phases is not None else []) + (
        [f"margin-{phase_margin_s:g}"] if phase_margin_s is not None else [])
    if not parts:
        raise ValueError("an evaluation needs an alpha, a burn-in or a counting rule")
    return "-".join(parts)


def ensure_phases(store: RunStore, config: dict) -> None:
    """Give a run made before protocol v3 its phase bounds (phases.csv), read from its dataset's
    flights; RunStoreError when the dataset is not at hand (or the run is a transfer run, whose
    flights are read by meaning)."""
    from scart_bench.benchmark.protocol import flight_phase_bounds
    from scart_bench.dataset import DatasetError, open_dataset

    if store.has_phases():
        return
    if config.get("train_dataset"):
        raise RunStoreError(f"{store.path}: a transfer run made before protocol v3 has no phase bounds; "
                            "run it again to count by phases")
    path = (config.get("dataset") or {}).get("path")
    try:
        ds = open_dataset(path)
    except (DatasetError, OSError, TypeError) as exc:
        raise RunStoreError(f"{store.path}: made before protocol v3, it has no phases.csv, and its dataset "
                            f"{path} cannot be read to find them ({exc})") from None
    ids = list(store.read_truth())
    store.write_phases({fid: flight_phase_bounds(ds.flight(fid)) for fid in ids})


def evaluate_run(path: str | Path, protocol: Protocol, name: str,
                 processes: int | None = None) -> tuple[Path, pd.DataFrame]:
    """The run's saved scores evaluated at another operating point, without running a job.

    The thresholds are recalibrated on the saved validation flights' scores under ``protocol``
    (another alpha or burn-in; the scores do not depend on either), and the tables are written into
    ``<run>/evaluations/<name>/`` (metrics.csv, metrics.md, breakdown.csv, flight_scores.csv,
    calibration.csv and evaluation.json, which records both protocols and the sha256 of the scores
    it was made from). The saved scores and the run's own tables are left as they are. Returns the
    evaluation's folder and its metrics table.
    """
    store = RunStore(path)
    config = store.read_config()
    if protocol.phases != "burn-in":
        ensure_phases(store, config)
    results = pd.DataFrame([_result_row(store, config, n) for n in _job_order(store, config)],
                           columns=list(_RESULT_COLUMNS))
    processes = _default_processes(config) if processes is None else max(1, int(processes))
    done = _score_detectors(store, results.to_dict("records"), processes, protocol.rules())
    folder = store.path / EVALUATIONS_DIR / name
    folder.mkdir(parents=True, exist_ok=True)
    run_protocol = Protocol.from_dict(config["identity"]["protocol"])
    scores = {}
    for det in results.loc[results["status"] == "OK", "detector"].astype(str):
        with open(store.job_dir(det) / "scores.npz", "rb") as fh:
            scores[det] = hashlib.file_digest(fh, "sha256").hexdigest()
    record = {"format": EVALUATION_FORMAT, "name": name, "run": config.get("name"),
              "alpha": protocol.alpha, "burn_in_s": protocol.burn_in_s,
              "protocol": protocol.rules(), "run_protocol": run_protocol.rules(),
              "scores_sha256": scores, "created": datetime.now(UTC).isoformat(timespec="seconds")}
    ev_config = {**config, "protocol": protocol.to_dict()}
    metrics = _write_tables(store, ev_config, done, f"{EVALUATIONS_DIR}/{name}/",
                            {**record, "run_alpha": run_protocol.alpha, "run_burn_in_s": run_protocol.burn_in_s})
    atomic_write_json(folder / "evaluation.json", record)
    return folder, metrics


#: Columns of flight_scores.csv after ``detector``.
FLIGHT_SCORE_COLUMNS = ("flight_id", "role", "mode", "score", "flagged", "outcome", "delay_s", "late_delay_s",
                        "alarm_before_onset", "cluster")


def breakdown_columns() -> pd.DataFrame:
    return pd.DataFrame(columns=BREAKDOWN_COLUMNS)


def _evaluation_lines(evaluation: dict | None) -> list[str]:
    """metrics.md's note on an evaluation made after the run (:func:`evaluate_run`)."""
    if not evaluation:
        return []

    def rate(a) -> str:
        return "its own alarm rules" if a is None else f"alpha {a:g}"

    def counting(rules: dict | None, burn_in) -> str:
        if rules and rules.get("phases", "burn-in") != "burn-in":
            return Protocol.from_dict(rules).counting()
        return f"burn-in {burn_in:g} s"

    return [f"Evaluation `{evaluation['name']}`, made after the run from its saved scores (no job was run): "
            f"thresholds recalibrated on the saved validation scores at {rate(evaluation['alpha'])}, "
            f"{counting(evaluation.get('protocol'), evaluation['burn_in_s'])} (the run: "
            f"{rate(evaluation.get('run_alpha'))}, "
            f"{counting(evaluation.get('run_protocol'), evaluation.get('run_burn_in_s', 0.0))}). "
            "The run's own tables are in the run folder.", ""]


def calibrated_on_test(config: dict) -> bool:
    """Whether a transfer run took its thresholds from the tested dataset (``--calibrate-on dataset``)."""
    return (config.get("transfer") or {}).get("calibrate_on", "train_dataset") == "dataset"


def trained_where(config: dict) -> str:
    """Where a transfer run's detectors were fitted and its thresholds calibrated, in words ("" for a
    run on one dataset): the train dataset for both, or its train flights and the tested dataset's
    normal flights of split validation (``--calibrate-on dataset``)."""
    train = (config.get("train_dataset") or {}).get("path")
    if not train:
        return ""
    if calibrated_on_test(config):
        return (f"Trained on `{train}`, calibrated on {config['transfer'].get('calibration_flights', 0)} normal flights of "
                f"`{(config.get('dataset') or {}).get('path')}` (split validation, not tested)")
    return f"Trained and calibrated on `{train}`"


def metrics_markdown(config: dict, metrics: pd.DataFrame, evaluation: dict | None = None) -> str:
    """metrics.md: the paper's table, the extra metrics, failures and the protocol used
    (``evaluation``: the record of an evaluation made after the run, said under the title)."""
    ds = config.get("dataset", {})
    proto = config.get("protocol", {})
    train = config.get("train_dataset") or {}
    lines = [f"# Run {config.get('name', '')}", "", *_evaluation_lines(evaluation),
             *([f"{trained_where(config)} (fingerprint {str(train.get('fingerprint'))[:12]}); tested on:", ""]
               if train else []),
             f"Dataset `{ds.get('path')}` (fingerprint {str(ds.get('fingerprint', ''))[:12]}), "
             f"flights per role: {json.dumps(ds.get('flights', {}))}; seed {config.get('seed')}.", "",
             "## The paper's table", "", markdown_table(metrics, PAPER_COLUMNS), "",
             "## Further metrics", "", markdown_table(metrics, EXTRA_COLUMNS, status=False), "",
             *rate_summary(metrics, ds.get("no_effect", [])), *transfer_summary(config, metrics)]
    failed = metrics[metrics["status"] != "OK"] if "status" in metrics else metrics.iloc[:0]
    if len(failed):
        lines += ["## Failed jobs", ""]
        lines += [f"- **{r['detector']}**: {r['status']}: {r['message']}" for _, r in failed.iterrows()]
        lines.append("")
    lines += ["## Protocol", "",
              f"- flight score: {proto.get('flight_score')}",
              f"- flight threshold: {proto.get('flight_threshold')}",
              f"- row threshold: {proto.get('row_threshold')}",
              f"- burn-in: {proto.get('burn_in', 'none')}",
              *([f"- counted rows: {proto['counted_rows']}"] if "counted_rows" in proto else []),
              f"- alarms: {proto.get('alarms', 'score > the calibrated threshold')}",
              f"- end transient: {proto.get('end_transient', 'none')}",
              f"- decision: {proto.get('decision')}",
              f"- {DETECTION_RULE}",
              f"- {INTERVAL_METHOD}", ""]
    ok = metrics[metrics["status"] == "OK"] if "status" in metrics else metrics.iloc[:0]
    if len(ok) and "threshold_after_arming_s" in ok.columns:
        near = ok[pd.to_numeric(ok["threshold_after_arming_s"], errors="coerce") < NEAR_ARMING_S]
        lines += ["## Where the thresholds come from", "",
                  f"- {len(near)} of {len(ok)} detectors' thresholds are set by a row within {NEAR_ARMING_S:g} s "
                  "after arming" + (f" ({', '.join(near['detector'].astype(str))})" if len(near) else "") + "; "
                  "per detector and validation flight, calibration.csv says when each maximum occurred.",
                  *(f"- **{r['detector']}**: threshold set {float(r['threshold_after_arming_s']):.1f} s after arming; "
                    f"{int(r['val_raw_max_in_burn_in'])} of {int(r['n_validation'])} validation maxima fell "
                    + ("in the burn-in" if proto.get("phases", "burn-in") == "burn-in" else "outside the counted rows")
                    + " and were left out" for _, r in ok.iterrows()
                    if not pd.isna(r.get("threshold_after_arming_s"))), ""]
    if len(ok) and "val_max_near_ends" in ok.columns:
        lift = pd.to_numeric(ok["threshold_after_liftoff_s"], errors="coerce").abs()
        down = pd.to_numeric(ok["threshold_before_touchdown_s"], errors="coerce").abs()
        near = ok[(lift < NEAR_ENDS_S) | (down < NEAR_ENDS_S)]
        lines += [f"- {len(near)} of {len(ok)} detectors' thresholds are set by a row within {NEAR_ENDS_S:g} s of "
                  "take-off or touchdown" + (f" ({', '.join(near['detector'].astype(str))})" if len(near) else "")
                  + "; validation maxima within it: " + ", ".join(
                      f"{r['detector']} {int(r['val_max_near_ends'])}" for _, r in ok.iterrows()
                      if not pd.isna(r.get("val_max_near_ends"))), ""]
    return "\n".join(lines)


def transfer_summary(config: dict, metrics: pd.DataFrame) -> list[str]:
    """Markdown lines of a transfer run (``--train-dataset``): which dataset each number comes from and,
    per detector, the false-alarm rate on the test dataset's normal flights and the TP on its attacked
    flights (empty for a run on one dataset)."""
    train = config.get("train_dataset")
    if not train:
        return []
    test = config.get("dataset", {}) or {}
    flights = test.get("flights", {}) or {}
    shared = (config.get("transfer") or {}).get("columns", [])
    g, r = train.get("path", ""), test.get("path", "")
    here = calibrated_on_test(config)
    calibration = (f"- trained on `{g}`: {train.get('flights', {}).get('train', 0)} train flights fit the detectors; "
                   f"{(config.get('transfer') or {}).get('calibration_flights', 0)} normal flights of `{r}` (split "
                   "validation) set the thresholds and are not tested;" if here else
                   f"- trained and calibrated on `{g}`: {train.get('flights', {}).get('train', 0)} train flights fit "
                   f"the detectors, {train.get('flights', {}).get('validation', 0)} validation flights set the "
                   "thresholds;")
    lines = ["## Train here, test there", "", calibration,
             f"- tested on `{r}`: TN and false alarms on its {flights.get('test_normal', 0)} normal flights, TP on "
             f"its {flights.get('test_attacked', 0)} attacked flights;",
             f"- {len(shared)} quantities matched by meaning: {', '.join(shared)} (columns.csv: what was dropped).", ""]
    ok = metrics[metrics["status"] == "OK"] if "status" in metrics else metrics.iloc[:0]
    modes = [m for m in ("csv", "simulation") if len(ok) and (pd.to_numeric(ok[f"n_{m}"], errors="coerce") > 0).any()]
    cols = [(f"Threshold from ({Path(r if here else g).name})", "flight_threshold", "f3"),
            (f"False alarms, normal flights ({Path(r).name})", "far_no_attack", "pct_ci"),
            *((f"TP {m} (in window, {Path(r).name})", f"tp_{m}", "pct_ci") for m in modes)]
    lines += [markdown_table(metrics, cols), ""]
    return lines


def paper_table(metrics: pd.DataFrame) -> str:
    """The paper's table as printed at the end of a run."""
    return markdown_table(metrics, PAPER_COLUMNS)
