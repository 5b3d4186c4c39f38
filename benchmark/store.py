"""The results store: one folder per run, every file written atomically (temp file + os.replace).

```
<run>/config.json              full config: identity (dataset fingerprint, seed, protocol),
                               detectors, plugins, executor, versions, git commit, dataset.json
<run>/flights.csv              the dataset's manifest rows with a ``role`` column (train /
                               validation / test_normal / test_attacked / no_effect / csv_source)
<run>/truth.parquet            flight_id, Timestamp, Is_Anomaly for every scored flight
<run>/arming.csv               flight_id, armed_us, armed_by: when each scored flight was armed
                               (the burn-in's start; benchmark.protocol.arming_time_us)
<run>/jobs/<detector>/params.json   detector name, class, source spec, params, job key
<run>/jobs/<detector>/scores.npz    one float64 array of per-row scores per flight_id
                                    (validation + test flights; written only for OK jobs)
<run>/jobs/<detector>/alarms.npz    the detector's own row alarms per flight_id (alarm rule "own" only)
<run>/jobs/<detector>/log.txt       the worker's stdout/stderr (traceback on error)
<run>/jobs/<detector>/status.json   written last: status OK / ERROR / TIMEOUT, message, timings
<run>/results.csv              one row per job: status, message, timings, rows
<run>/metrics.csv              one row per detector: the paper's table and every extra metric
<run>/metrics.md               the same as Markdown tables
<run>/breakdown.csv            TP rate (in window, Wilson interval), late and flagged counts per
                               action / target / injection point / kind / detectability bin (and mode)
<run>/flight_scores.csv        detector, flight_id, role, mode, score, flagged (anywhere), outcome
                               (detected / at_end / late / missed), delay_s, late_delay_s,
                               alarm_before_onset, cluster
<run>/calibration.csv          per detector and validation flight: its score, when its maximum
                               occurred (after arming, with and without the burn-in) and whether
                               it sets the threshold
<run>/cache/flights/           the run's flight cache (benchmark.flight_cache): every flight read
                               once, shared by the jobs; removed when every job of the invocation
                               finished OK, kept (and reused) while one is left to --resume
<run>/.lock                    held (flock) by the run writing the folder; a second writer is refused
```
A job is complete exactly when its status.json says OK: status.json is removed when a job
starts and written after its scores and params.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset.locks import FolderLock
from scart_bench.errors import ScartBenchError
from scart_bench.names import check_id, inside

STATUSES = ("OK", "ERROR", "TIMEOUT")
#: Run-level tables made from the jobs' saved scores (removed when a new invocation starts).
SUMMARY_FILES = ("results.csv", "metrics.csv", "metrics.md", "breakdown.csv", "flight_scores.csv")


class RunStoreError(ScartBenchError):
    """A run folder is missing, foreign or incompatible with the requested run."""


def _json_default(obj):
    """numpy values and paths as JSON (scart_bench.dataset's rule); anything else as its repr."""
    from scart_bench.dataset import json_default

    try:
        return json_default(obj)
    except TypeError:
        return repr(obj)


def _nan_to_none(obj):
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_nan_to_none(v) for v in obj]
    return obj


def to_json(obj) -> str:
    """Stable, standard JSON text (sorted keys; numpy values and paths converted; NaN -> null)."""
    return json.dumps(_nan_to_none(json.loads(json.dumps(obj, default=_json_default))), indent=2,
                      sort_keys=True, allow_nan=False)


def json_safe(obj):
    """``obj`` after a JSON round trip (what a later read of the file returns)."""
    return json.loads(to_json(obj))


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temp file in the same folder and os.replace."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: Path, obj) -> None:
    atomic_write_text(path, to_json(obj) + "\n")


def atomic_write_csv(path: Path, df: pd.DataFrame) -> None:
    atomic_write_text(path, df.to_csv(index=False))


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """A compressed .npz (readable by numpy.load) with one entry per key, any key string.

    Deflate level 1: at paper scale (12 M float64 scores) 1.1 s and 40.7 MB per detector against
    4.7 s and 39.8 MB at the default level 6, in the run's main process while jobs wait to start."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for key, arr in arrays.items():
            with zf.open(f"{key}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asarray(arr), allow_pickle=False)
    return buf.getvalue()


def read_npz(path: Path) -> dict[str, np.ndarray]:
    """The arrays of a scores file (RunStoreError naming the file when it is not a valid .npz of arrays)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        # numpy's message for a pickled entry suggests allow_pickle=True: never, scores are plain arrays
        raise RunStoreError(f"{path}: not a valid scores file (a .npz of numeric arrays): "
                            f"{type(exc).__name__}") from None


class RunStore:
    """Paths and reads/writes of one run folder."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    # -- paths --------------------------------------------------------------------------------
    @property
    def config_path(self) -> Path:
        return self.path / "config.json"

    def job_dir(self, detector: str) -> Path:
        return inside(self.path / "jobs", check_id(detector, "detector name"))

    def exists(self) -> bool:
        return self.config_path.exists()

    # -- config -------------------------------------------------------------------------------
    def read_config(self) -> dict:
        if not self.config_path.exists():
            raise RunStoreError(f"{self.path}: not a scart-bench run folder (no config.json)")
        try:
            config = json.loads(self.config_path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise RunStoreError(f"{self.config_path}: not valid JSON ({exc})") from None
        if not isinstance(config, dict):
            raise RunStoreError(f"{self.config_path}: expected a JSON object, got {type(config).__name__}")
        return config

    def lock(self) -> FolderLock:
        """Hold the run folder for this process (LockHeld when another process holds it)."""
        return FolderLock(self.path / ".lock", f"{self.path}").acquire()

    def mark_stale(self) -> None:
        """Remove the run-level result tables before jobs start; they are written again at the end, so an
        interrupted run leaves no metrics that look like its own (``scart-bench score RUN`` remakes them)."""
        for name in SUMMARY_FILES:
            (self.path / name).unlink(missing_ok=True)

    def write_config(self, config: dict) -> None:
        atomic_write_json(self.config_path, config)

    def check_usable(self) -> None:
        """Refuse a path that exists but is not a folder, or a non-empty folder that is not a run."""
        if not self.path.exists():
            return
        if not self.path.is_dir():
            raise RunStoreError(f"{self.path}: exists and is not a folder; expected a run folder")
        if any(p.name != ".lock" for p in self.path.iterdir()) and not self.exists():
            raise RunStoreError(f"{self.path}: exists, is not empty and has no config.json; "
                                "expected a scart-bench run folder or a new path for --out")

    # -- flights and labels -------------------------------------------------------------------
    def write_flights(self, flights: pd.DataFrame) -> None:
        atomic_write_csv(self.path / "flights.csv", flights)

    def read_flights(self) -> pd.DataFrame:
        """flights.csv, with ``armed_us`` / ``armed_by`` from arming.csv when the run has it."""
        df = pd.read_csv(self.path / "flights.csv", dtype={"flight_id": str, "scenario_id": "string"},
                         keep_default_na=True)
        for col in ("attack_start_us", "attack_end_us"):
            if col in df.columns:
                df[col] = df[col].astype("Int64")
        arming = self.read_arming()
        if arming is not None:
            df = df.drop(columns=[c for c in ("armed_us", "armed_by") if c in df.columns]).merge(
                arming, on="flight_id", how="left")
        return df

    def has_arming(self) -> bool:
        return (self.path / "arming.csv").exists()

    def write_arming(self, arming: dict[str, tuple[int, str]]) -> None:
        """arming.csv: flight id -> (armed_us, the column that said so)."""
        atomic_write_csv(self.path / "arming.csv", pd.DataFrame(
            [(f, int(t), str(by)) for f, (t, by) in arming.items()], columns=["flight_id", "armed_us", "armed_by"]))

    def read_arming(self) -> pd.DataFrame | None:
        path = self.path / "arming.csv"
        if not path.is_file():
            return None
        return pd.read_csv(path, dtype={"flight_id": str, "armed_us": "Int64", "armed_by": str})

    def has_truth(self) -> bool:
        return (self.path / "truth.parquet").exists()

    def write_truth(self, truth: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
        ids = list(truth)
        lengths = [len(truth[f][0]) for f in ids]
        # the ids as codes: a repeated string array of 12 M rows (the paper run) took 6.5 GB
        codes = np.repeat(np.arange(len(ids), dtype=np.int64), lengths)
        df = pd.DataFrame({
            "flight_id": pd.Categorical.from_codes(codes, categories=ids),
            "Timestamp": np.concatenate([np.asarray(truth[f][0], dtype=np.int64) for f in ids]) if ids else [],
            "Is_Anomaly": np.concatenate([np.asarray(truth[f][1], dtype=np.int8) for f in ids]) if ids else [],
        })
        buf = io.BytesIO()
        df.to_parquet(buf, index=False)
        atomic_write_bytes(self.path / "truth.parquet", buf.getvalue())

    def read_truth(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        path = self.path / "truth.parquet"
        if not path.is_file():
            raise RunStoreError(f"{path}: missing; the run's labels are gone (run it again into a new --out)")
        try:
            df = pd.read_parquet(path)
        except Exception as exc:  # pyarrow raises its own types for a damaged file
            raise RunStoreError(f"{path}: cannot be read ({type(exc).__name__}: {exc})") from None
        col = df["flight_id"]
        if isinstance(col.dtype, pd.CategoricalDtype):  # as written: compare codes, not 12 M strings
            fid, names = col.cat.codes.to_numpy(), np.asarray(col.cat.categories.astype(str))
        else:
            fid = col.astype(str).to_numpy()
            names = None
        ts = df["Timestamp"].to_numpy(np.int64)
        lab = df["Is_Anomaly"].to_numpy(np.int8)
        if fid.size == 0:
            return {}
        cut = np.flatnonzero(fid[1:] != fid[:-1]) + 1
        starts, ends = np.r_[0, cut], np.r_[cut, fid.size]
        return {str(fid[s] if names is None else names[fid[s]]): (ts[s:e], lab[s:e]) for s, e in zip(starts, ends)}

    # -- jobs ---------------------------------------------------------------------------------
    def job_names(self) -> list[str]:
        root = self.path / "jobs"
        return sorted(p.name for p in root.iterdir() if p.is_dir()) if root.exists() else []

    def read_status(self, detector: str) -> dict | None:
        p = self.job_dir(detector) / "status.json"
        return json.loads(p.read_text()) if p.exists() else None

    def read_params(self, detector: str) -> dict | None:
        p = self.job_dir(detector) / "params.json"
        return json.loads(p.read_text()) if p.exists() else None

    def read_scores(self, detector: str) -> dict[str, np.ndarray]:
        return read_npz(self.job_dir(detector) / "scores.npz")

    def read_alarms(self, detector: str) -> dict[str, np.ndarray] | None:
        """The detector's own row alarms (alarm rule "own"), None when the job saved none."""
        path = self.job_dir(detector) / "alarms.npz"
        return {k: v.astype(bool) for k, v in read_npz(path).items()} if path.is_file() else None

    def start_job(self, detector: str) -> None:
        """Mark a job as not complete: remove its status.json before anything else is written."""
        d = self.job_dir(detector)
        d.mkdir(parents=True, exist_ok=True)
        (d / "status.json").unlink(missing_ok=True)

    def finish_job(self, detector: str, status: dict, params: dict, scores: dict[str, np.ndarray] | None,
                   log: str = "", alarms: dict[str, np.ndarray] | None = None) -> None:
        """Write a finished job: scores (OK only), params, log, then status.json last."""
        if status.get("status") not in STATUSES:
            raise ValueError(f"job status {status.get('status')!r}: expected one of {STATUSES}")
        d = self.job_dir(detector)
        d.mkdir(parents=True, exist_ok=True)
        if scores is not None:
            atomic_write_bytes(d / "scores.npz", npz_bytes(scores))
        else:
            (d / "scores.npz").unlink(missing_ok=True)
        if scores is not None and alarms is not None:
            atomic_write_bytes(d / "alarms.npz", npz_bytes({k: np.asarray(v, dtype=np.int8) for k, v in alarms.items()}))
        else:
            (d / "alarms.npz").unlink(missing_ok=True)
        atomic_write_json(d / "params.json", params)
        atomic_write_text(d / "log.txt", log)
        atomic_write_json(d / "status.json", status)

    # -- tables -------------------------------------------------------------------------------
    def write_table(self, name: str, df: pd.DataFrame) -> None:
        atomic_write_csv(self.path / name, df)

    def write_text(self, name: str, text: str) -> None:
        atomic_write_text(self.path / name, text)


def diff_identity(old: dict, new: dict) -> list[str]:
    """Human-readable differences between two config identities (empty when they match)."""
    out = []
    for key in sorted(set(old) | set(new)):
        if json_safe(old.get(key)) != json_safe(new.get(key)):
            a, b = old.get(key), new.get(key)
            if isinstance(a, dict) or isinstance(b, dict):
                out.append(f"{key} differs")
            else:
                out.append(f"{key}: {a!r} -> {b!r}")
    return out
