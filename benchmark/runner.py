"""The benchmark run: resolve detectors, prepare the dataset and run folder, run one isolated job
per detector, then score every finished job from its saved scores.

The parts live in their own modules, imported in one direction (runner -> the rest):
:mod:`~scart_bench.benchmark.config` (what was asked), :mod:`~scart_bench.benchmark.selection`
(which detectors, with which parameters), :mod:`~scart_bench.benchmark.jobs` (the job body, run in
a worker process by :mod:`~scart_bench.benchmark.executors`), :mod:`~scart_bench.benchmark.results`
(metrics and tables from the saved scores), :mod:`~scart_bench.benchmark.store` (the run folder).

Jobs are deterministic: each detector gets ``random_state`` = the run seed and a fixed number of
threads, so the local and the dask executor give the same scores.

A run folder belongs to one identity: dataset (manifest fingerprint), seed and threshold rules.
Running into an existing folder with another identity is refused (RunError, nothing touched).
With the same identity, the requested detectors' jobs are run again (with ``--resume``: only
those without an OK status, or whose class/parameters changed); jobs of other detectors already
in the folder are kept, so a folder can collect detectors over several invocations.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.config import RunConfig, check_against_flights
from scart_bench.benchmark.flight_cache import (
    CacheInvalid,
    DatasetReader,
    FlightCache,
    build_cache,
    cache_key,
    cache_path,
    remove_cache,
)
from scart_bench.benchmark.jobs import JobResult, JobSpec
from scart_bench.benchmark.protocol import ROLES, Splits, arming_time_us, assign_roles, flight_phase_bounds
from scart_bench.benchmark.results import paper_table, score_run, write_results
from scart_bench.benchmark.selection import DetectorChoice, load_plugins, resolve_detectors, with_params
from scart_bench.benchmark.sharding import ShardedScoring
from scart_bench.benchmark.store import RunStore, comparable, diff_identity, json_safe
from scart_bench.benchmark.transfer import (
    MeaningRun,
    TransferRun,
    open_meaning,
    open_transfer,
    plan_fingerprint,
)
from scart_bench.errors import RunError
from scart_bench.storage import fetch_dataset, is_url

__all__ = ["RunConfig", "RunOutcome", "paper_table", "prepare_dataset", "run_benchmark", "score_run"]

RUN_FORMAT = "scart-bench-run/1"
_VERSION_PACKAGES = ("scart-bench", "numpy", "pandas", "scipy", "scikit-learn", "pyarrow", "torch", "deepod",
                     "dask", "distributed", "tqdm")


def prepare_dataset(cfg: RunConfig) -> Path:
    """The dataset folder: ``--dataset``, or the profile's dataset (generated when missing)."""
    from scart_bench.dataset import is_dataset, open_dataset

    if cfg.dataset is not None:
        if is_url(cfg.dataset):  # read here from a local copy (downloaded once per manifest)
            return fetch_dataset(str(cfg.dataset))
        return Path(cfg.dataset)
    path = cfg.data_root / f"{cfg.profile}-seed{cfg.seed}"
    try:
        from scart_bench.generator.engine.flight_batch import FLIGHT_DEFAULTS
        from scart_bench.generator.generate import generate_dataset
    except ImportError as exc:
        if is_dataset(path):
            return path
        raise RunError(f"cannot generate the {cfg.profile} dataset: the generator is not available ({exc}); "
                         "pass --dataset DIR with an existing dataset") from exc
    if is_dataset(path):
        made_with = open_dataset(path).flight_defaults
        if made_with == FLIGHT_DEFAULTS:
            return path
        # the profile's own dataset is a cache of this version's generator: one made with older defaults
        # would give last version's numbers under this version's name
        print(f"the {cfg.profile} dataset in {path} was made with generator defaults {made_with}, this "
              f"version makes {FLIGHT_DEFAULTS}: generating it again", file=sys.stderr)
        return Path(generate_dataset(cfg.profile, path, cfg.seed, overwrite=True))
    print(f"generating the {cfg.profile} dataset (seed {cfg.seed}) in {path}", file=sys.stderr)
    return Path(generate_dataset(cfg.profile, path, cfg.seed))


def dataset_fingerprint(manifest: pd.DataFrame, root: str | Path | None = None) -> str:
    """sha256 of the manifest's CSV text and, with ``root``, of the flight tables under
    ``root/flights``: same manifest and tables, same fingerprint.

    A table counts by its path, size and last 4 KiB (a Parquet file's footer holds its schema and
    column statistics, a CSV's end its last rows): reading every byte of a large dataset would cost
    minutes, and a copy of the dataset keeps its fingerprint (no timestamps are used).
    """
    h = hashlib.sha256(manifest[sorted(manifest.columns)].to_csv(index=False).encode("utf-8"))
    if root is not None:
        flights = Path(root) / "flights"
        for f in sorted(flights.rglob("*")) if flights.is_dir() else []:
            if not f.is_file():
                continue
            size = f.stat().st_size
            with f.open("rb") as fh:
                fh.seek(max(0, size - 4096))
                tail = fh.read()
            h.update(f"\0{f.relative_to(flights).as_posix()}\0{size}\0".encode())
            h.update(tail)
    return h.hexdigest()


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


def _truth(ds, flight_ids) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], dict[str, tuple[int, str]],
                                    dict[str, dict]]:
    """Labels (timestamps, Is_Anomaly), arming time and phase bounds of every scored flight, each read once."""
    out, arming, phases = {}, {}, {}
    for fid in flight_ids:
        f = ds.flight(fid)
        out[fid] = (f["Timestamp"].to_numpy(np.int64), f["Is_Anomaly"].to_numpy(np.int8))
        arming[fid] = arming_time_us(f)
        phases[fid] = flight_phase_bounds(f)
    return out, arming, phases


def _flight_cache(store: RunStore, read, key: dict, flight_ids: list[str], note,
                  workers: int = 1) -> FlightCache | None:
    """The run's flight cache holding ``flight_ids``: the one in the run folder when its key matches
    (kept by an unfinished run), else built now, reading each flight once. None (the jobs read
    the dataset, as before) when a table cannot be cached exactly or the build fails."""
    folder = cache_path(store.path)
    try:
        cache = FlightCache(folder, key)
        if cache.has(flight_ids):
            note(f"flight cache: reusing {folder}")
            return cache
    except CacheInvalid:
        pass
    t0 = time.perf_counter()
    try:
        cache = build_cache(folder, key, flight_ids, read, workers=workers)
    except Exception as exc:  # an optimisation only: the jobs read the dataset as before
        note(f"flight cache off ({type(exc).__name__}: {exc}); every job reads the dataset")
        return None
    note(f"flight cache: {len(cache.index)} flights read once in {time.perf_counter() - t0:.1f} s ({folder})")
    return cache


def _previous_config(store: RunStore, seed: int) -> dict | None:
    """The config of an existing run folder (None for a new one); refuses another seed early,
    before a dataset is generated for nothing."""
    store.check_usable()
    old = store.read_config() if store.exists() else None
    if old is not None:
        store.verify()  # the files a rerun keeps (labels, finished jobs) are the ones the run wrote
    if old is not None and old.get("identity", {}).get("seed") != seed:
        raise RunError(f"{store.path}: this run folder was made with a different config (seed: "
                         f"{old.get('identity', {}).get('seed')!r} -> {seed!r}); nothing was changed. "
                         "Choose a new --out, or rerun with the same settings")
    return old


def _check_identity(store: RunStore, old: dict | None, identity: dict) -> None:
    diffs = diff_identity(old.get("identity", {}), identity) if old is not None else []
    if diffs:
        raise RunError(f"{store.path}: this run folder was made with a different config "
                         f"({'; '.join(diffs)}); nothing was changed. Choose a new --out, or rerun "
                         "with the same dataset, seed and protocol")


def _run_config(cfg: RunConfig, old: dict | None, store: RunStore, ds, splits: Splits, identity: dict,
                chosen: list[DetectorChoice], plugins: dict[str, DetectorChoice], settings: dict,
                transfer: TransferRun | None = None, meaning: MeaningRun | None = None) -> dict:
    """config.json: identity, dataset, detectors (accumulated over invocations), environment."""
    previous = list(old.get("detectors", [])) if old else []
    if meaning is not None:  # a run on one dataset read by meaning: its quantities and why
        plan = meaning.plan.to_dict()
        dropped = plan["dropped"].get("dataset", {})
        by_meaning = {"columns": {"by": "meaning", "why": meaning.why, "quantities": plan["columns"],
                                  "lacking": plan["lacking"],
                                  "dropped": {c: why for c, why in dropped.items() if why != "no meaning"},
                                  "no_meaning": sum(why == "no meaning" for why in dropped.values())}}
    extra = {} if transfer is None else {
        "train_dataset": {"path": str(transfer.train.path.resolve()), "info": transfer.train.info,
                          "fingerprint": identity["train_dataset_fingerprint"],
                          "flights": {"train": len(splits.train), "validation": len(splits.validation)
                                      if transfer.calibrate_on == "train_dataset" else 0}},
        "transfer": {**transfer.plan.to_dict(), "calibrate_on": transfer.calibrate_on,
                     "calibration_flights": len(splits.validation), "dropped": {
            side: {c: why for c, why in cols.items() if why != "no meaning"}
            for side, cols in transfer.plan.dropped.items()},
            "no_meaning": {side: sum(why == "no meaning" for why in cols.values())
                           for side, cols in transfer.plan.dropped.items()}}}
    return {
        "format": RUN_FORMAT,
        "identity": identity,
        "name": store.path.name,
        "profile": cfg.profile,
        "seed": int(cfg.seed),
        "random_state": int(cfg.seed),
        "dataset": {"path": str(ds.path.resolve()), "info": ds.info, "fingerprint": identity["dataset_fingerprint"],
                    "flights": {r: len(getattr(splits, r)) for r in ROLES}, "no_effect": list(splits.no_effect)},
        **extra,
        **(by_meaning if meaning is not None else {}),
        "detectors": list(dict.fromkeys([*previous, *(c.name for c in chosen)])),
        "jobs": {**(old.get("jobs", {}) if old else {}), **settings},
        "plugins": [c.source for c in plugins.values()],
        "executor": {"kind": cfg.executor, "scheduler": cfg.scheduler, "jobs": int(cfg.jobs)},
        "timeout_s": cfg.timeout_s,
        "protocol": cfg.protocol.to_dict(),
        "run": cfg.to_dict(),
        "versions": package_versions(),
        "git": git_commit(),
        "created": old.get("created", _now()) if old else _now(),
        "updated": _now(),
    }


def _finished(store: RunStore, name: str, key: dict) -> bool:
    """True when a job finished OK with the same job key and its scores are on disk."""
    status, params = store.read_status(name), store.read_params(name)
    return bool(status and status.get("status") == "OK" and params
                and json_safe(comparable(params.get("key"))) == json_safe(comparable(key))
                and (store.job_dir(name) / "scores.npz").exists())


def _status(spec: JobSpec, res: JobResult) -> dict:
    return {"detector": spec.detector, "status": res.status, "message": res.message,
            "fit_seconds": res.fit_seconds, "score_seconds": res.score_seconds, "rows_scored": res.rows_scored,
            "n_train_flights": len(spec.train), "n_scored_flights": len(spec.scored),
            "max_rss_mb": res.max_rss_mb, "wall_seconds": res.wall_seconds, "threads": spec.threads,
            "finished": _now()}


def run_benchmark(cfg: RunConfig, on_job_done: Callable[[str], None] | None = None) -> RunOutcome:
    """Run (or resume) a benchmark run and score it. ``on_job_done(detector)`` is called after each
    finished job is saved (a run folder at a URL uploads it then, so a kill loses no finished job).

    Bad input (unknown detector, missing dataset, foreign run folder, unreachable scheduler)
    raises RunError (a ValueError) before anything in the run folder is touched.
    """
    from scart_bench.benchmark.executors import JobProgress, make_executor
    from scart_bench.dataset import open_dataset

    store = RunStore(cfg.out_path)
    old = _previous_config(store, cfg.seed)
    plugins = load_plugins(cfg.plugins, probe_timeout_s=cfg.timeout_s)
    chosen = with_params(resolve_detectors(cfg.detectors, plugins), cfg.params, cfg.device)
    ds = open_dataset(prepare_dataset(cfg))
    transfer = None
    if cfg.train_dataset is not None:  # train here, test there: flights read by meaning (benchmark.transfer)
        train_dataset = fetch_dataset(cfg.train_dataset) if is_url(cfg.train_dataset) else cfg.train_dataset
        transfer = open_transfer(train_dataset, ds, note=lambda m: print(m, file=sys.stderr),
                                 calibrate_on=cfg.calibrate_on)
        splits = transfer.splits
    else:
        splits = Splits.from_manifest(ds.manifest)
        ds.check_flights(dict.fromkeys(splits.train + splits.scored))  # a damaged table stops the run here
    meaning = None  # flights that log different columns are read by meaning (benchmark.transfer.open_meaning)
    if transfer is None and not (cfg.columns == "auto" and (cfg.features or cfg.exclude)):
        meaning = open_meaning(ds, splits, cfg.columns, note=lambda m: print(m, file=sys.stderr))
    reader = transfer.reader if transfer is not None else meaning.reader if meaning is not None else ds.flight
    check_against_flights(cfg, chosen, splits, ds.manifest if transfer is None else transfer.flights,
                          reader)  # windows, burn-in, --features
    identity = {"format": RUN_FORMAT, "dataset_fingerprint": dataset_fingerprint(ds.manifest, ds.path),
                "seed": int(cfg.seed), "protocol": cfg.protocol.rules()}
    if transfer is not None:  # absent otherwise: runs on one dataset keep their identity
        identity["train_dataset_fingerprint"] = dataset_fingerprint(transfer.train.manifest, transfer.train.path)
        identity["transfer"] = {"columns": list(transfer.plan.columns), "interval_us": transfer.plan.interval_us}
        if transfer.calibrate_on != "train_dataset":  # absent otherwise: earlier transfer runs keep their identity
            identity["transfer"]["calibrate_on"] = transfer.calibrate_on
    if meaning is not None:  # absent otherwise: runs on flights read as logged keep their identity
        identity["columns"] = {"by": "meaning", "columns": list(meaning.plan.columns)}
    if cfg.features or cfg.exclude:  # absent otherwise: runs made before these options stay comparable
        identity["features"] = {"include": list(cfg.features or []), "exclude": list(cfg.exclude or [])}
    _check_identity(store, old, identity)
    settings = {c.name: {"source": c.source, "class": f"{c.cls.__module__}:{c.cls.__qualname__}",
                         "params": c.params_of(cfg.seed)} for c in chosen}
    keys = {name: {"identity": identity, **s} for name, s in settings.items()}
    executor = make_executor(cfg.executor, scheduler=cfg.scheduler, jobs=int(cfg.jobs))
    try:
        # dask workers read a dataset at a URL from the URL themselves (no shared disk needed)
        job_dataset = str(cfg.dataset) if cfg.executor == "dask" and is_url(cfg.dataset) else str(ds.path.resolve())
        executor.check_dataset(job_dataset)
        if transfer is not None:
            executor.check_dataset(str(transfer.train.path.resolve()))
    except BaseException:
        executor.close()
        raise
    try:  # from here on the run folder is written
        store.path.mkdir(parents=True, exist_ok=True)
        lock = store.lock()  # a second writer to this folder is refused here, before it writes anything
        store.mark_stale()  # old tables must not read as this run's results if it is interrupted
        config = _run_config(cfg, old, store, ds, splits, identity, chosen, plugins, settings, transfer, meaning)
        if is_url(cfg.dataset):  # where the dataset lives (its "path" is this machine's copy)
            config["dataset"]["url"] = str(cfg.dataset)
        store.write_config(config)
        if transfer is None:
            store.write_flights(ds.manifest.assign(role=assign_roles(ds.manifest))[
                ["flight_id", "role", *(c for c in ds.manifest.columns if c != "flight_id")]])
            if meaning is not None:
                store.write_table("columns.csv", meaning.dropped_table())
        else:
            store.write_flights(transfer.flights)
            store.write_table("columns.csv", transfer.dropped_table())
        skipped = [c.name for c in chosen if cfg.resume and _finished(store, c.name, keys[c.name])]
        progress = JobProgress(len(chosen) - len(skipped), enabled=cfg.progress)
        if skipped:
            progress.note(f"resume: {len(skipped)} finished job(s) kept: {', '.join(skipped)}")
        by_meaning = transfer is not None or meaning is not None
        key = cache_key(plan_fingerprint(identity) if by_meaning else identity["dataset_fingerprint"])
        readers = min(int(cfg.jobs), os.cpu_count() or 1) if cfg.executor == "local" else 1
        read = (transfer.reader if transfer is not None else meaning.reader if meaning is not None
                else DatasetReader(ds.path))
        cache = (_flight_cache(store, read, key, [*splits.train, *splits.scored], progress.note, readers)
                 if len(skipped) < len(chosen) else None)
        if not store.has_truth() or not store.has_arming() or not store.has_phases():
            # labels, arming and phases from the flights as logged (a table by meaning has the same rows,
            # but not the topics the phase detector reads); a transfer run's test flights are resampled
            source = transfer.reader if transfer is not None else ds if meaning is not None else cache or ds
            truth, arming, phases = _truth(source, splits.scored)
            store.write_truth(truth)
            store.write_arming(arming)
            store.write_phases(phases)
        threads = max(1, (os.cpu_count() or 1) // int(cfg.jobs))
        specs = [JobSpec(c.name, c.source, c.overrides(cfg.seed), tuple(p.source for p in plugins.values()),
                         job_dataset, splits.train, splits.scored, threads,
                         tuple(cfg.features) if cfg.features else None, tuple(cfg.exclude) if cfg.exclude else None,
                         str(cache.folder.resolve()) if cache else None, key if cache else None,
                         cfg.protocol.alarm_rule == "own",
                         transfer.job_args() if transfer else meaning.job_args(job_dataset) if meaning else None)
                 for c in chosen if c.name not in skipped]
        # costliest first (a scheduling hint only: tables keep the detectors' order)
        cost = {c.name: float(getattr(c.cls, "relative_cost", 10.0)) for c in chosen}
        specs.sort(key=lambda spec: -cost[spec.detector])
        for spec in specs:
            store.start_job(spec.detector)
        statuses: list[str] = []

        def on_done(spec: JobSpec, res: JobResult) -> None:
            """Save a finished job (a sharded one once all its shards are merged)."""
            params = {"detector": spec.detector, **settings[spec.detector], "key": keys[spec.detector]}
            store.finish_job(spec.detector, _status(spec, res), json_safe(params),
                             res.scores if res.status == "OK" else None, res.log,
                             res.alarms if res.status == "OK" else None)
            statuses.append(res.status)
            progress.done(spec.detector, res)
            if on_job_done is not None:
                on_job_done(spec.detector)

        rows = ({str(f): int(r) for f, r in zip(ds.manifest["flight_id"], ds.manifest["rows"]) if pd.notna(r)}
                if transfer is None and "rows" in ds.manifest else {})
        sharded = ShardedScoring(cfg.score_shards, rows, on_done, progress.note)
        try:
            executor.run([sharded.plan(spec) for spec in specs], cfg.timeout_s, sharded,
                         on_progress=progress.job if cfg.progress else None)
            if cache is not None and len(statuses) == len(specs) and all(s == "OK" for s in statuses):
                remove_cache(cache.folder)  # nothing left to resume; a failed job keeps it for --resume
                with contextlib.suppress(OSError):
                    cache.folder.parent.rmdir()
        finally:
            progress.close()
            write_results(store)
    finally:
        executor.close()
        if "lock" in locals():
            lock.release()
    return RunOutcome(store.path, score_run(store.path), [s.detector for s in specs], skipped)
