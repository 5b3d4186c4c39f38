"""One benchmark job: a detector fitted on the train normal flights, scoring every validation and test
flight. A job runs in a worker process of its own (:mod:`scart_bench.benchmark.executors`) and takes
and returns plain, picklable data."""

from __future__ import annotations

import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np


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
    features: tuple[str, ...] | None = None
    exclude: tuple[str, ...] | None = None
    #: The run's flight cache (:mod:`~scart_bench.benchmark.flight_cache`) and the key it must have;
    #: None, or a cache this worker cannot read, means the flights are read from the dataset.
    cache: str | None = None
    cache_key: dict | None = None
    #: Also return the detector's own row alarms (``Detector.alarms``) where it has them
    #: (the protocol's alarm rule "own").
    own_alarms: bool = False
    #: A transfer run (benchmark.transfer.TransferRun.job_args): flights read by meaning from two datasets.
    transfer: dict | None = None
    #: "all": fit and score; "fit": fit only and return the fitted detector (``JobResult.model``);
    #: "score": score ``scored`` with the pickled fitted detector ``model`` (a scoring shard)
    stage: str = "all"
    model: bytes | None = None
    #: which scoring shard this is (index, count), for logs and progress lines
    shard: tuple[int, int] | None = None


@dataclass
class JobResult:
    """What a job returns: status, timings, per-row scores (OK only) and the worker's log."""

    status: str
    message: str = ""
    fit_seconds: float = float("nan")
    score_seconds: float = float("nan")
    rows_scored: int = 0
    scores: dict[str, np.ndarray] | None = None
    #: the detector's own row alarms per flight (JobSpec.own_alarms and a detector that has them)
    alarms: dict[str, np.ndarray] | None = None
    max_rss_mb: float = float("nan")
    wall_seconds: float = float("nan")
    log: str = ""
    #: the fitted detector, pickled (a "fit" stage job only)
    model: bytes | None = None


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


def open_flights(spec: JobSpec):
    """Where the job reads its flights: the run's flight cache when it is usable here (same key,
    every flight in it), else the dataset (a line in the job's log says why)."""
    from scart_bench.dataset import open_dataset

    if spec.cache:
        from scart_bench.benchmark.flight_cache import CacheInvalid, FlightCache

        try:
            cache = FlightCache(spec.cache, spec.cache_key)
            if cache.has(spec.train + spec.scored):
                return cache
            print(f"flight cache {spec.cache} lacks some of the job's flights; reading the dataset", file=sys.stderr)
        except CacheInvalid as exc:
            print(f"flight cache not used ({exc}); reading the dataset", file=sys.stderr)
    if spec.transfer:
        from scart_bench.benchmark.transfer import TransferFlights

        t = spec.transfer
        return TransferFlights(t["train_dataset"], spec.dataset, t["train_ids"], t["columns"], t["interval_us"])
    return open_dataset(spec.dataset)


#: ``report(flights_done, flights_total, rows_scored, score_seconds)``, called after each scored flight
Report = "Callable[[int, int, int, float], None]"


def run_job(spec: JobSpec, report=None) -> JobResult:
    """Fit one detector on the train flights and score every validation/test flight.

    Never raises for a detector failure: an exception becomes ERROR with its message (the
    traceback goes to the log), a NaN/inf score or a wrong number of scores becomes ERROR.
    """
    fit_s = score_s = float("nan")
    try:
        if spec.stage == "score":
            import pickle

            _load_class(spec)  # a plugin's module must be importable before its detector is unpickled
            det, fit_s = pickle.loads(spec.model), 0.0
            ds = open_flights(spec)
        else:
            det = _load_class(spec)(**spec.overrides)
            # the run's feature rule is an argument of fit (a plugin's own fit may take no such argument
            # when the run sets no rule)
            rule = {k: list(v) for k, v in (("features", spec.features), ("exclude", spec.exclude)) if v}
            ds = open_flights(spec)
            train = [ds.flight(fid) for fid in spec.train]
            t0 = time.perf_counter()
            det.fit(train, **rule)
            fit_s = time.perf_counter() - t0
            del train
            if spec.stage == "fit":
                import pickle

                return JobResult("OK", "", fit_s, 0.0, 0, max_rss_mb=_max_rss_mb(),
                                 model=pickle.dumps(det, protocol=pickle.HIGHEST_PROTOCOL))
        scores: dict[str, np.ndarray] = {}
        own = bool(spec.own_alarms and getattr(det, "has_alarms", False))
        alarms: dict[str, np.ndarray] | None = {} if own else None
        score_s, rows = 0.0, 0
        for fid in spec.scored:
            flight = ds.flight(fid)
            t0 = time.perf_counter()
            s = det.score(flight)
            score_s += time.perf_counter() - t0
            if alarms is not None:
                a = np.asarray(det.alarms(flight), dtype=bool).reshape(-1)
                if a.shape[0] != len(flight):
                    return JobResult("ERROR", f"returned {a.shape[0]} own alarms for the {len(flight)} rows of "
                                     f"flight {fid}", fit_s, score_s, rows, max_rss_mb=_max_rss_mb())
                alarms[fid] = a
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
            if report is not None:
                report(len(scores), len(spec.scored), rows, score_s)
        return JobResult("OK", "", fit_s, score_s, rows, scores, alarms, max_rss_mb=_max_rss_mb())
    except Exception as exc:  # a detector failure is a status row, never a crash of the run
        traceback.print_exc()
        return JobResult("ERROR", f"{type(exc).__name__}: {exc}".strip(), fit_s, score_s,
                         max_rss_mb=_max_rss_mb())
