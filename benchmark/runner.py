"""The benchmark run: resolve detectors, prepare the dataset and run folder, run one isolated job
per detector, then score every finished job from its saved scores.

One job = one detector fitted on the train normal flights and scoring every validation and test
flight (:func:`run_job`, executed in its own process by :mod:`benchmark.executors`). Jobs are
deterministic: each detector gets ``random_state`` = the run seed and a fixed number of threads,
so the local and the dask executor give the same scores. The run folder layout is documented in
:mod:`benchmark.store`; metrics in :mod:`benchmark.scoring`; splits and thresholds in
:mod:`benchmark.protocol`.

A run folder belongs to one identity: dataset (manifest fingerprint), seed and threshold rules.
Running into an existing folder with another identity is refused (UsageError, nothing touched).
With the same identity, the requested detectors' jobs are run again (with ``--resume``: only
those without an OK status, or whose class/parameters changed); jobs of other detectors already
in the folder are kept, so a folder can collect detectors over several invocations.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import platform
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.errors import UsageError
from scart_bench.benchmark.protocol import ROLES, Protocol, Splits, assign_roles
from scart_bench.benchmark.scoring import (
    DEFAULT_METRICS,
    EXTRA_COLUMNS,
    PAPER_COLUMNS,
    ScoreError,
    breakdown,
    build_evaluation,
    compute_metrics,
    markdown_table,
)
from scart_bench.benchmark.store import RunStore, diff_identity, json_safe

PROFILES = ("quick", "standard", "paper")
#: Default per-job timeout (seconds) per profile.
DEFAULT_TIMEOUT_S = {"quick": 1800.0, "standard": 7200.0, "paper": 6 * 3600.0}
RUN_FORMAT = "scart-bench-run/1"
_VERSION_PACKAGES = ("scart-bench", "numpy", "pandas", "scipy", "scikit-learn", "pyarrow", "torch", "deepod",
                     "dask", "distributed", "tqdm")


# -- configuration ----------------------------------------------------------------------------

@dataclass
class RunConfig:
    """What ``scart-bench run`` was asked to do (the CLI's options, as plain values)."""

    detectors: list[str] = field(default_factory=lambda: ["all"])
    profile: str = "quick"
    dataset: Path | None = None
    out: Path | None = None
    resume: bool = False
    executor: str = "local"
    scheduler: str | None = None
    jobs: int = 1
    timeout: float | None = None
    seed: int = 0
    plugins: list[str] = field(default_factory=list)
    protocol: Protocol = field(default_factory=Protocol)
    data_root: Path = Path("data/datasets")
    runs_root: Path = Path("runs")
    progress: bool = True

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise UsageError(f"--profile {self.profile!r}: expected one of {', '.join(PROFILES)}")
        if self.executor not in ("local", "dask"):
            raise UsageError(f"--executor {self.executor!r}: expected local or dask")
        if self.scheduler and self.executor != "dask":
            raise UsageError("--scheduler needs --executor dask")
        if int(self.jobs) < 1:
            raise UsageError(f"--jobs {self.jobs}: expected a positive number of parallel jobs")
        if self.timeout is not None and float(self.timeout) <= 0:
            raise UsageError(f"--timeout {self.timeout}: expected a positive number of seconds")
        if not self.detectors:
            raise UsageError("--detectors: expected 'all' or a comma-separated list of names")

    @property
    def timeout_s(self) -> float:
        return float(self.timeout) if self.timeout is not None else DEFAULT_TIMEOUT_S[self.profile]

    @property
    def out_path(self) -> Path:
        return Path(self.out) if self.out is not None else self.runs_root / f"{self.profile}-seed{self.seed}"


@dataclass(frozen=True)
class DetectorChoice:
    """A detector of the run: its name, class and how a worker loads the class."""

    name: str
    cls: type
    source: str

    def overrides(self, seed: int) -> dict:
        """Constructor arguments set by the run (the seed, where the detector takes one)."""
        accepted = inspect.signature(self.cls.__init__).parameters
        return {"random_state": int(seed)} if "random_state" in accepted else {}

    def params(self, seed: int) -> dict:
        return json_safe(self.cls(**self.overrides(seed)).get_params(deep=False))


@dataclass(frozen=True)
class JobSpec:
    """Everything a worker process needs to run one job (picklable, plain data)."""

    detector: str
    source: str
    overrides: dict
    plugins: tuple[str, ...]
    dataset: str
    train: tuple[str, ...]
    scored: tuple[str, ...]
    threads: int = 1


@dataclass
class JobResult:
    """What a job returns: status, timings, per-row scores (OK only) and the worker's log."""

    status: str
    message: str = ""
    fit_seconds: float = float("nan")
    score_seconds: float = float("nan")
    rows_scored: int = 0
    scores: dict[str, np.ndarray] | None = None
    max_rss_mb: float = float("nan")
    wall_seconds: float = float("nan")
    log: str = ""


# -- the job body (runs in a worker process) --------------------------------------------------

def _load_class(spec: JobSpec) -> type:
    from scart_bench.detectors import registry

    loaded = {}
    for p in spec.plugins:
        info = registry.load_plugin(p)
        loaded[info.name] = info.cls
    if spec.detector in loaded:
        return loaded[spec.detector]
    return registry.load_plugin(spec.source).cls


def _max_rss_mb() -> float:
    """Peak resident memory of this process (MiB).

    Linux's VmHWM starts afresh when a job process execs; ``ru_maxrss`` is kept across fork and
    exec, so a job launched by a big process would report the launcher's peak.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    except ImportError:  # pragma: no cover - not on POSIX
        return float("nan")


def run_job(spec: JobSpec) -> JobResult:
    """Fit one detector on the train flights and score every validation/test flight.

    Never raises for a detector failure: an exception becomes ERROR with its message (the
    traceback goes to the log), a NaN/inf score or a wrong number of scores becomes ERROR.
    """
    from scart_bench.generator.dataset import open_dataset

    fit_s = score_s = float("nan")
    try:
        det = _load_class(spec)(**spec.overrides)
        ds = open_dataset(spec.dataset)
        train = [ds.flight(fid) for fid in spec.train]
        t0 = time.perf_counter()
        det.fit(train)
        fit_s = time.perf_counter() - t0
        del train
        scores: dict[str, np.ndarray] = {}
        score_s, rows = 0.0, 0
        for fid in spec.scored:
            flight = ds.flight(fid)
            t0 = time.perf_counter()
            s = det.score(flight)
            score_s += time.perf_counter() - t0
            s = np.asarray(s, dtype=np.float64).reshape(-1)
            if s.shape[0] != len(flight):
                return JobResult("ERROR", f"returned {s.shape[0]} scores for the {len(flight)} rows of flight {fid}",
                                 fit_s, score_s, rows, max_rss_mb=_max_rss_mb())
            bad = np.flatnonzero(~np.isfinite(s))
            if bad.size:
                return JobResult("ERROR", f"returned {bad.size} NaN/inf score(s) on flight {fid} "
                                 f"(first at row {bad[0]})", fit_s, score_s, rows, max_rss_mb=_max_rss_mb())
            scores[fid] = s
            rows += s.shape[0]
        return JobResult("OK", "", fit_s, score_s, rows, scores, max_rss_mb=_max_rss_mb())
    except Exception as exc:  # a detector failure is a status row, never a crash of the run
        traceback.print_exc()
        return JobResult("ERROR", f"{type(exc).__name__}: {exc}".strip(), fit_s, score_s,
                         max_rss_mb=_max_rss_mb())


# -- preparing a run --------------------------------------------------------------------------

def _absolute_plugin(spec: str) -> str:
    target, sep, cls = spec.rpartition(":")
    if sep and target.endswith(".py"):
        return f"{Path(target).resolve()}:{cls}"
    return spec


def load_plugins(specs: list[str]) -> dict[str, DetectorChoice]:
    """Load ``--plugin`` specs (file paths made absolute so workers anywhere can load them)."""
    from scart_bench.detectors import registry

    out = {}
    for spec in specs:
        absolute = _absolute_plugin(spec)
        info = registry.load_plugin(absolute)
        out[info.name] = DetectorChoice(info.name, info.cls, absolute)
    return out


def _parse_names(names: list[str]) -> list[str]:
    out: list[str] = []
    for item in names:
        for n in str(item).split(","):
            n = n.strip()
            if n and n not in out:
                out.append(n)
    if not out:
        raise UsageError("--detectors: expected 'all' or a comma-separated list of names")
    return out


def resolve_detectors(names: list[str], plugins: dict[str, DetectorChoice]) -> list[DetectorChoice]:
    """The detectors to run, in order; ``["all"]`` means every known detector."""
    from scart_bench.detectors import registry

    names = _parse_names(names)

    def choice(info) -> DetectorChoice:
        if info.name in plugins:
            return plugins[info.name]
        if info.name in registry.BUILTINS:
            return DetectorChoice(info.name, info.cls, registry.BUILTINS[info.name])
        return DetectorChoice(info.name, info.cls, f"{info.cls.__module__}:{info.cls.__qualname__}")

    if names == ["all"]:
        return [choice(info) for info in registry.available().values()]
    if "all" in names:
        raise UsageError("--detectors: 'all' cannot be combined with names")
    chosen = []
    for name in names:
        if name in plugins:
            chosen.append(plugins[name])
        elif name in registry.BUILTINS:
            cls = type(registry.make(name))
            chosen.append(DetectorChoice(name, cls, registry.BUILTINS[name]))
        else:
            try:
                known = registry.available()
            except ValueError:
                known = {}
            if name not in known:
                listed = ", ".join(dict.fromkeys([*registry.BUILTINS, *plugins, *known]))
                raise UsageError(f"--detectors: unknown detector {name!r}; expected one of: {listed} "
                                 "(or load one with --plugin module:Class)")
            chosen.append(choice(known[name]))
    for c in chosen:
        if not c.name or "/" in c.name or "\\" in c.name or c.name.startswith("."):
            raise UsageError(f"detector name {c.name!r} cannot name a job folder")
    return chosen


def prepare_dataset(cfg: RunConfig) -> Path:
    """The dataset folder: ``--dataset``, or the profile's dataset (generated when missing)."""
    from scart_bench.generator.dataset import is_dataset

    if cfg.dataset is not None:
        return Path(cfg.dataset)
    path = cfg.data_root / f"{cfg.profile}-seed{cfg.seed}"
    if is_dataset(path):
        return path
    try:
        from scart_bench.generator.generate import generate_dataset
    except ImportError as exc:
        raise UsageError(f"cannot generate the {cfg.profile} dataset: the generator is not available ({exc}); "
                         "pass --dataset DIR with an existing dataset") from exc
    print(f"generating the {cfg.profile} dataset (seed {cfg.seed}) in {path}", file=sys.stderr)
    return Path(generate_dataset(cfg.profile, path, cfg.seed))


def dataset_fingerprint(manifest: pd.DataFrame) -> str:
    """sha256 of the manifest's CSV text: same manifest, same fingerprint."""
    text = manifest[sorted(manifest.columns)].to_csv(index=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def package_versions() -> dict[str, str | None]:
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in _VERSION_PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def git_commit() -> dict | None:
    """HEAD commit of the source tree and whether it has uncommitted changes (None without git)."""
    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": head, "dirty": bool(dirty)}


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


@dataclass
class RunOutcome:
    """The finished (or resumed) run: its folder, metrics and what ran."""

    path: Path
    metrics: pd.DataFrame
    ran: list[str]
    skipped: list[str]


def _truth(ds, flight_ids) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    out = {}
    for fid in flight_ids:
        f = ds.flight(fid)
        out[fid] = (f["Timestamp"].to_numpy(np.int64), f["Is_Anomaly"].to_numpy(np.int8))
    return out


def _previous_config(store: RunStore, seed: int) -> dict | None:
    """The config of an existing run folder (None for a new one); refuses another seed early,
    before a dataset is generated for nothing."""
    store.check_usable()
    old = store.read_config() if store.exists() else None
    if old is not None and old.get("identity", {}).get("seed") != seed:
        raise UsageError(f"{store.path}: this run folder was made with a different config (seed: "
                         f"{old.get('identity', {}).get('seed')!r} -> {seed!r}); nothing was changed. "
                         "Choose a new --out, or rerun with the same settings")
    return old


def _check_identity(store: RunStore, old: dict | None, identity: dict) -> None:
    diffs = diff_identity(old.get("identity", {}), identity) if old is not None else []
    if diffs:
        raise UsageError(f"{store.path}: this run folder was made with a different config "
                         f"({'; '.join(diffs)}); nothing was changed. Choose a new --out, or rerun "
                         "with the same dataset, seed and protocol")


def _run_config(cfg: RunConfig, old: dict | None, store: RunStore, ds, splits: Splits, identity: dict,
                chosen: list[DetectorChoice], plugins: dict[str, DetectorChoice], settings: dict) -> dict:
    """config.json: identity, dataset, detectors (accumulated over invocations), environment."""
    previous = list(old.get("detectors", [])) if old else []
    return {
        "format": RUN_FORMAT,
        "identity": identity,
        "name": store.path.name,
        "profile": cfg.profile,
        "seed": int(cfg.seed),
        "random_state": int(cfg.seed),
        "dataset": {"path": str(ds.path.resolve()), "info": ds.info, "fingerprint": identity["dataset_fingerprint"],
                    "flights": {r: len(getattr(splits, r)) for r in ROLES}},
        "detectors": list(dict.fromkeys([*previous, *(c.name for c in chosen)])),
        "jobs": {**(old.get("jobs", {}) if old else {}), **settings},
        "plugins": [c.source for c in plugins.values()],
        "executor": {"kind": cfg.executor, "scheduler": cfg.scheduler, "jobs": int(cfg.jobs)},
        "timeout_s": cfg.timeout_s,
        "protocol": cfg.protocol.to_dict(),
        "versions": package_versions(),
        "git": git_commit(),
        "created": old.get("created", _now()) if old else _now(),
        "updated": _now(),
    }


def _finished(store: RunStore, name: str, key: dict) -> bool:
    """True when a job finished OK with the same job key and its scores are on disk."""
    status, params = store.read_status(name), store.read_params(name)
    return bool(status and status.get("status") == "OK" and params and params.get("key") == json_safe(key)
                and (store.job_dir(name) / "scores.npz").exists())


def _status(spec: JobSpec, res: JobResult) -> dict:
    return {"detector": spec.detector, "status": res.status, "message": res.message,
            "fit_seconds": res.fit_seconds, "score_seconds": res.score_seconds, "rows_scored": res.rows_scored,
            "n_train_flights": len(spec.train), "n_scored_flights": len(spec.scored),
            "max_rss_mb": res.max_rss_mb, "wall_seconds": res.wall_seconds, "threads": spec.threads,
            "finished": _now()}


def run_benchmark(cfg: RunConfig) -> RunOutcome:
    """Run (or resume) a benchmark run and score it.

    Bad input (unknown detector, missing dataset, foreign run folder, unreachable scheduler)
    raises UsageError/ValueError before anything in the run folder is touched.
    """
    from scart_bench.benchmark.executors import Progress, make_executor
    from scart_bench.generator.dataset import open_dataset

    store = RunStore(cfg.out_path)
    old = _previous_config(store, cfg.seed)
    plugins = load_plugins(cfg.plugins)
    chosen = resolve_detectors(cfg.detectors, plugins)
    ds = open_dataset(prepare_dataset(cfg))
    splits = Splits.from_manifest(ds.manifest)
    identity = {"format": RUN_FORMAT, "dataset_fingerprint": dataset_fingerprint(ds.manifest),
                "seed": int(cfg.seed), "protocol": cfg.protocol.rules()}
    _check_identity(store, old, identity)
    settings = {c.name: {"source": c.source, "class": f"{c.cls.__module__}:{c.cls.__qualname__}",
                         "params": c.params(cfg.seed)} for c in chosen}
    keys = {name: {"identity": identity, **s} for name, s in settings.items()}
    executor = make_executor(cfg.executor, scheduler=cfg.scheduler, jobs=int(cfg.jobs))
    try:  # from here on the run folder is written
        store.path.mkdir(parents=True, exist_ok=True)
        store.write_config(_run_config(cfg, old, store, ds, splits, identity, chosen, plugins, settings))
        store.write_flights(ds.manifest.assign(role=assign_roles(ds.manifest))[
            ["flight_id", "role", *(c for c in ds.manifest.columns if c != "flight_id")]])
        if not store.has_truth():
            store.write_truth(_truth(ds, splits.scored))

        skipped = [c.name for c in chosen if cfg.resume and _finished(store, c.name, keys[c.name])]
        threads = max(1, (os.cpu_count() or 1) // int(cfg.jobs))
        specs = [JobSpec(c.name, c.source, c.overrides(cfg.seed), tuple(p.source for p in plugins.values()),
                         str(ds.path.resolve()), splits.train, splits.scored, threads)
                 for c in chosen if c.name not in skipped]
        for spec in specs:
            store.start_job(spec.detector)
        progress = Progress(len(specs), enabled=cfg.progress)
        if skipped:
            progress.note(f"resume: {len(skipped)} finished job(s) kept: {', '.join(skipped)}")

        def on_done(spec: JobSpec, res: JobResult) -> None:
            params = {"detector": spec.detector, **settings[spec.detector], "key": keys[spec.detector]}
            store.finish_job(spec.detector, _status(spec, res), json_safe(params),
                             res.scores if res.status == "OK" else None, res.log)
            progress.done(spec.detector, res)

        try:
            executor.run(specs, cfg.timeout_s, on_done)
        finally:
            progress.close()
            write_results(store)
    finally:
        executor.close()
    return RunOutcome(store.path, score_run(store.path), [s.detector for s in specs], skipped)


# -- scoring a run from its saved files -------------------------------------------------------

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


def score_run(path: str | Path, write: bool = True) -> pd.DataFrame:
    """Recompute every metric of a run from its saved scores (no detector runs).

    Writes results.csv, metrics.csv, metrics.md, breakdown.csv and flight_scores.csv (when
    ``write``) and returns the metrics table, one row per detector.
    """
    store = RunStore(path)
    config = store.read_config()
    protocol = Protocol.from_dict(config["identity"]["protocol"])
    flights = store.read_flights()
    truth = store.read_truth()
    results = write_results(store) if write else pd.DataFrame(
        [_result_row(store, config, n) for n in _job_order(store, config)], columns=list(_RESULT_COLUMNS))
    metric_rows, breakdowns, flight_scores = [], [], []
    for _, res in results.iterrows():
        row = {"detector": res["detector"], "status": res["status"], "message": res["message"]}
        if res["status"] == "OK":
            try:
                scores = store.read_scores(res["detector"])
                ev = build_evaluation(res["detector"], flights, truth, scores, protocol,
                                      fit_seconds=res["fit_s"], score_seconds=res["score_s"],
                                      rows_scored=int(res["rows"]))
            except (ScoreError, OSError, ValueError) as exc:
                row.update(status="ERROR", message=f"saved scores unusable: {exc}")
            else:
                row.update(compute_metrics(ev))
                breakdowns.append(breakdown(ev))
                fs = ev.flights[["flight_id", "role", "mode", "score", "flagged"]].copy()
                fs.insert(0, "detector", res["detector"])
                flight_scores.append(fs)
        row.update(fit_s=res["fit_s"], score_s=res["score_s"], rows=res["rows"])
        metric_rows.append(row)
    columns = ["detector", "status", "message", *(c for m in DEFAULT_METRICS for c in m.columns),
               "flight_threshold", "row_threshold", "fit_s", "score_s", "rows"]
    metrics = pd.DataFrame(metric_rows, columns=columns)
    if write:
        store.write_table("metrics.csv", metrics)
        store.write_text("metrics.md", metrics_markdown(config, metrics))
        bd = pd.concat(breakdowns, ignore_index=True) if breakdowns else breakdown_columns()
        store.write_table("breakdown.csv", bd)
        fs = pd.concat(flight_scores, ignore_index=True) if flight_scores else pd.DataFrame(
            columns=["detector", "flight_id", "role", "mode", "score", "flagged"])
        store.write_table("flight_scores.csv", fs)
    return metrics


def breakdown_columns() -> pd.DataFrame:
    return pd.DataFrame(columns=["detector", "dimension", "value", "mode", "n", "detected", "tp_rate"])


def metrics_markdown(config: dict, metrics: pd.DataFrame) -> str:
    """metrics.md: the paper's table, the extra metrics, failures and the protocol used."""
    ds = config.get("dataset", {})
    proto = config.get("protocol", {})
    lines = [f"# Run {config.get('name', '')}", "",
             f"Dataset `{ds.get('path')}` (fingerprint {str(ds.get('fingerprint', ''))[:12]}), "
             f"flights per role: {json.dumps(ds.get('flights', {}))}; seed {config.get('seed')}.", "",
             "## The paper's table", "", markdown_table(metrics, PAPER_COLUMNS), "",
             "## Further metrics", "", markdown_table(metrics, EXTRA_COLUMNS, status=False), ""]
    failed = metrics[metrics["status"] != "OK"] if "status" in metrics else metrics.iloc[:0]
    if len(failed):
        lines += ["## Failed jobs", ""]
        lines += [f"- **{r['detector']}**: {r['status']}: {r['message']}" for _, r in failed.iterrows()]
        lines.append("")
    lines += ["## Protocol", "",
              f"- flight score: {proto.get('flight_score')}",
              f"- flight threshold: {proto.get('flight_threshold')}",
              f"- row threshold: {proto.get('row_threshold')}",
              f"- decision: {proto.get('decision')}",
              "- TP rate: attacked test flights of the mode that are flagged; TN rate: held-out normal "
              "test flights not flagged; delay: first row alarm inside the attack window.", ""]
    return "\n".join(lines)


def paper_table(metrics: pd.DataFrame) -> str:
    """The paper's table as printed at the end of a run."""
    return markdown_table(metrics, PAPER_COLUMNS)
