"""The results store: one folder per run, every file written atomically (temp file + os.replace).

```
<run>/config.json              full config: identity (dataset fingerprint, seed, protocol),
                               detectors, plugins, executor, versions, git commit, dataset.json
<run>/flights.csv              the dataset's manifest rows with a ``role`` column (train /
                               validation / test_normal / test_attacked / no_effect / csv_source)
<run>/truth.parquet            flight_id, Timestamp, Is_Anomaly for every scored flight
<run>/arming.csv               flight_id, armed_us, armed_by: when each scored flight was armed
                               (the burn-in's start; benchmark.protocol.arming_time_us)
<run>/phases.csv               flight_id, liftoff_us, climb_end_us, descent_start_us, touchdown_us,
                               phases_by: each scored flight's phase bounds (the "ends" counting rule;
                               benchmark.protocol.flight_phase_bounds); written by runs since protocol
                               v3, and by `score --phases` for older runs whose dataset is at hand
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
<run>/evaluations/<name>/      the tables (metrics.csv, metrics.md, breakdown.csv, flight_scores.csv,
                               calibration.csv) and evaluation.json of the saved scores at another
                               operating point (``scart-bench score RUN --alpha A``; no job run);
                               never read back by the run, ``score`` or ``--resume``
<run>/cache/flights/           the run's flight cache (benchmark.flight_cache): every flight read
                               once, shared by the jobs; removed when every job of the invocation
                               finished OK, kept (and reused) while one is left to --resume
<run>/.lock                    held (flock) by the run writing the folder; a second writer is refused
<run>/checksums.json           sha256 of every file the scores are computed from (truth.parquet,
                               arming.csv, flights.csv and each job's status.json, scores.npz and
                               alarms.npz), recorded when the run writes them
```
A job is complete exactly when its status.json says OK: status.json is removed when a job
starts and written after its scores and params.

Every file the metrics are computed from is checked against checksums.json when it is read (and all
of them by ``score``, ``report`` and a rerun into the folder, :meth:`RunStore.verify`): a flipped
byte in the labels or the scores is refused (:class:`ChecksumError`, one line naming the file)
instead of scored. A checksum is recorded before its file is written, and a job's files only count
once its status.json exists, so a run killed between the two leaves nothing that reads as damaged.
Run folders made before checksums (no checksums.json) are read as before. The tables made from
these files (metrics.csv, flight_scores.csv, ...) are not covered: ``scart-bench score`` remakes them.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import re
import tempfile
import threading
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.benchmark.protocol import PHASE_COLUMNS
from scart_bench.dataset.locks import FolderLock
from scart_bench.errors import ScartBenchError
from scart_bench.jsonfile import JsonFileError, loads_bounded, read_json
from scart_bench.names import check_id, inside

STATUSES = ("OK", "ERROR", "TIMEOUT")
#: Run-level tables made from the jobs' saved scores (removed when a new invocation starts).
SUMMARY_FILES = ("results.csv", "metrics.csv", "metrics.md", "breakdown.csv", "flight_scores.csv")


#: The run folder's record of checksums (:meth:`RunStore.verify`).
CHECKSUMS_FILE = "checksums.json"
CHECKSUMS_FORMAT = "scart-bench-checksums/1"
#: Run-level files the scores are computed from (each job's are in :data:`JOB_CHECKED_FILES`).
RUN_CHECKED_FILES = ("truth.parquet", "arming.csv", "phases.csv", "flights.csv")
JOB_CHECKED_FILES = ("status.json", "scores.npz", "alarms.npz")
_SHA256 = re.compile(r"[0-9a-f]{64}")
_record_lock = threading.Lock()


class RunStoreError(ScartBenchError):
    """A run folder is missing, foreign or incompatible with the requested run."""


class ChecksumError(RunStoreError):
    """A file of a run folder differs from the checksum the run recorded when it wrote it (or the
    record itself is damaged)."""


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


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


def read_npz(path: Path, data: bytes | None = None) -> dict[str, np.ndarray]:
    """The arrays of a scores file (RunStoreError naming the file when it is not a valid .npz of arrays);
    ``data``: its bytes, already read."""
    try:
        with np.load(io.BytesIO(data) if data is not None else path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise
    except Exception as exc:  # a damaged zip raises zlib, zipfile, EOF, NotImplemented (method) and numpy errors
        # numpy's message for a pickled entry suggests allow_pickle=True: never, scores are plain arrays
        raise RunStoreError(f"{path}: not a valid scores file (a .npz of numeric arrays): "
                            f"{type(exc).__name__}") from None


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_int(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def check_config(config: dict, path: Path) -> dict:
    """``config`` (a run folder's config.json) when every field the project reads has its type;
    RunStoreError naming the file, the field and what was expected otherwise."""
    from scart_bench.benchmark.protocol import Protocol

    def bad(name: str, value: object, expected: str) -> RunStoreError:
        return RunStoreError(f"{path}: {name} = {_shown(value)}: expected {expected} "
                             "(damaged or not written by scart-bench)")

    identity = config.get("identity")
    if not isinstance(identity, dict):
        raise bad("identity", identity, "an object (the run's dataset fingerprint, seed and protocol)")
    protocol = identity.get("protocol")
    if not isinstance(protocol, dict):
        raise bad("identity.protocol", protocol, "an object (threshold rules, burn-in, end transient)")
    try:
        Protocol.from_dict(protocol)
    except (ScartBenchError, KeyError, TypeError, ValueError, AttributeError) as exc:
        what = f"no {exc}" if isinstance(exc, KeyError) else str(exc)
        raise RunStoreError(f"{path}: identity.protocol: {what}; expected the threshold rules scart-bench "
                            "writes (damaged or not written by scart-bench)") from None
    fields: dict[str, tuple] = {
        "format": (str,), "name": (str,), "profile": (str,), "created": (str,), "updated": (str,),
        "detectors": (list,), "jobs": (dict,), "executor": (dict,), "dataset": (dict,), "protocol": (dict,),
        "run": (dict,), "plugins": (list,), "train_dataset": (dict,), "transfer": (dict,), "versions": (dict,),
        "git": (dict,), "checksums": (str,),
    }
    names = {str: "a string", list: "a list", dict: "an object"}
    nullable = ("format", "name", "profile", "created", "updated", "train_dataset", "transfer", "git", "checksums")
    for key, types in fields.items():
        if key in config and not isinstance(config[key], types) and not (config[key] is None and key in nullable):
            raise bad(key, config[key], names[types[0]])
    for key in ("seed", "random_state"):
        if config.get(key) is not None and not _is_int(config[key]):
            raise bad(key, config[key], "an integer")
    if identity.get("seed") is not None and not _is_int(identity["seed"]):
        raise bad("identity.seed", identity["seed"], "an integer")
    for key in ("detectors", "plugins"):
        if not all(isinstance(x, str) for x in config.get(key) or []):
            raise bad(key, config[key], "a list of strings")
    for name, job in (config.get("jobs") or {}).items():
        if not isinstance(job, dict):
            raise bad(f"jobs.{name}", job, "an object (source, class, params)")
    jobs = (config.get("executor") or {}).get("jobs")
    if jobs is not None and not (_is_int(jobs) and jobs >= 1):
        raise bad("executor.jobs", jobs, "a whole number >= 1")
    if config.get("timeout_s") is not None and not (_is_number(config["timeout_s"]) and config["timeout_s"] > 0):
        raise bad("timeout_s", config["timeout_s"], "a positive number of seconds")
    for side in ("dataset", "train_dataset"):
        part = config.get(side) or {}
        for key, kind in (("path", str), ("fingerprint", str), ("flights", dict), ("info", dict),
                          ("no_effect", list)):
            if key in part and not isinstance(part[key], kind):
                raise bad(f"{side}.{key}", part[key], names[kind])
        for role, n in (part.get("flights") or {}).items():
            if not (_is_int(n) and n >= 0):
                raise bad(f"{side}.flights.{role}", n, "a count of flights >= 0")
    columns = (config.get("transfer") or {}).get("columns")
    if columns is not None and not (isinstance(columns, list) and all(isinstance(c, str) for c in columns)):
        raise bad("transfer.columns", columns, "a list of column names")
    return config


#: status.json fields and their types (None allowed for every field but status)
_STATUS_TEXT = ("detector", "message", "finished")
_STATUS_SECONDS = ("fit_seconds", "score_seconds", "wall_seconds", "max_rss_mb")
_STATUS_COUNTS = ("rows_scored", "n_train_flights", "n_scored_flights", "threads")


def check_status(status: object, path: Path) -> dict:
    """A job's status.json when its fields have their types; RunStoreError naming the file and field."""
    def bad(name: str, value: object, expected: str) -> RunStoreError:
        return RunStoreError(f"{path}: {name} = {_shown(value)}: expected {expected} "
                             "(damaged or not written by scart-bench)")

    if not isinstance(status, dict):
        raise RunStoreError(f"{path}: the top level is {type(status).__name__}; expected a JSON object "
                            "(damaged or not written by scart-bench)")
    if status.get("status") not in STATUSES:
        raise bad("status", status.get("status"), f"one of {', '.join(STATUSES)}")
    for key in _STATUS_TEXT:
        if status.get(key) is not None and not isinstance(status[key], str):
            raise bad(key, status[key], "a string")
    for key in _STATUS_SECONDS:
        if status.get(key) is not None and not (_is_number(status[key]) and status[key] >= 0):
            raise bad(key, status[key], "a number >= 0 (or null)")
    for key in _STATUS_COUNTS:
        if status.get(key) is not None and not (_is_int(status[key]) and status[key] >= 0):
            raise bad(key, status[key], "a whole number >= 0 (or null)")
    return status


class RunStore:
    """Paths and reads/writes of one run folder."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    # -- paths --------------------------------------------------------------------------------
    @property
    def config_path(self) -> Path:
        return self.path / "config.json"

    @property
    def checksums_path(self) -> Path:
        return self.path / CHECKSUMS_FILE

    def job_dir(self, detector: str) -> Path:
        return inside(self.path / "jobs", check_id(detector, "detector name"))

    def exists(self) -> bool:
        return self.config_path.exists()

    # -- checksums ----------------------------------------------------------------------------
    def has_checksums(self) -> bool:
        """Whether the run records checksums (run folders made before them do not)."""
        return self.checksums_path.exists()

    def _checksums(self) -> dict | None:
        """The recorded checksums (path in the run folder -> sha256 as written), None for a run folder
        made before checksums. ChecksumError when the record is damaged, or missing although
        config.json says the run keeps one."""
        if not self.checksums_path.exists():
            try:
                says = read_json(self.config_path).get("checksums")  # type: ignore[union-attr]
            except (JsonFileError, AttributeError):
                says = None  # read_config names a damaged config.json
            if says:
                raise ChecksumError(f"{self.checksums_path}: missing, though {self.config_path} says the run "
                                    "records checksums; the folder is incomplete or was edited (run it again into "
                                    "a new --out)")
            return None
        try:
            record = read_json(self.checksums_path)
        except JsonFileError as exc:
            raise ChecksumError(str(exc)) from None
        files = record.get("files")  # type: ignore[union-attr]
        if record.get("format") != CHECKSUMS_FORMAT or not isinstance(files, dict):  # type: ignore[union-attr]
            raise ChecksumError(f"{self.checksums_path}: not a scart-bench checksum record; expected "
                                f"format {CHECKSUMS_FORMAT!r} and \"files\": an object of sha256 digests")
        return files

    def _check(self, rel: str, digest: str, files: dict | None) -> None:
        """ChecksumError naming ``rel`` when ``digest`` (sha256 of its bytes) is not what the run recorded."""
        if files is None:
            return
        path = self.path / rel
        if rel not in files:
            raise ChecksumError(f"{path}: no checksum recorded for it in {self.checksums_path}, although the run "
                                "records one for every file it writes; the file was added or the record edited "
                                "(run it again into a new --out)")
        expected = files[rel]
        if not isinstance(expected, str) or not _SHA256.fullmatch(expected):
            raise ChecksumError(f"{path}: its checksum in {self.checksums_path} is {_shown(expected)}; expected a "
                                "sha256 hex digest (the record is damaged or was edited)")
        if digest != expected:
            raise ChecksumError(f"{path}: changed since the run wrote it (sha256 {digest[:16]}..., the run recorded "
                                f"{expected[:16]}...); the file is damaged or was edited: remove it and rerun the "
                                "run with --resume to write it again, or run it again into a new --out")

    def _read_checked(self, rel: str) -> bytes:
        """The bytes of ``rel`` (a path in the run folder), refused when they differ from its checksum."""
        data = (self.path / rel).read_bytes()
        self._check(rel, sha256_hex(data), self._checksums())
        return data

    def _record(self, entries: dict[str, str | None]) -> None:
        """Record sha256 digests (None: forget the entry) of paths in the run folder, before their files
        are written; nothing in a run folder made before checksums."""
        with _record_lock:
            files = self._checksums()
            if files is None:
                return
            files = {**files, **entries}
            atomic_write_json(self.checksums_path, {"format": CHECKSUMS_FORMAT, "algorithm": "sha256",
                                                    "files": {k: v for k, v in files.items() if v is not None}})

    def _write_checked(self, rel: str, data: bytes) -> None:
        self._record({rel: sha256_hex(data)})
        atomic_write_bytes(self.path / rel, data)

    def checked_files(self) -> list[str]:
        """The files of the run the scores are computed from, as paths in the folder: the run-level
        files that exist and the files of every job with a status.json."""
        out = [rel for rel in RUN_CHECKED_FILES if (self.path / rel).is_file()]
        for name in self.job_names():
            d = self.job_dir(name)
            if (d / "status.json").is_file():
                out += [f"jobs/{name}/{f}" for f in JOB_CHECKED_FILES if (d / f).is_file()]
        return out

    def verify(self) -> None:
        """Compare every file the scores are computed from with the checksum recorded when the run
        wrote it (``score``, ``report`` and a rerun into the folder do, before anything else):
        ChecksumError naming the first that differs, or whose checksum is missing, null or empty.
        A run folder made before checksums passes unchecked. Then every job's status.json is read
        (:meth:`read_status`), so a damaged one is named here in every command."""
        files = self._checksums()
        if files is not None:
            for rel in self.checked_files():
                with open(self.path / rel, "rb") as fh:
                    digest = hashlib.file_digest(fh, "sha256").hexdigest()
                self._check(rel, digest, files)
        for name in self.job_names():
            self.read_status(name)

    def seal(self, rel: str) -> None:
        """Record the checksum of ``rel`` as it is now: for a file changed on purpose (a test's
        damaged scores, a repaired table); a run folder without checksums is left as it is."""
        self._record({rel: sha256_hex((self.path / rel).read_bytes())})

    # -- config -------------------------------------------------------------------------------
    def read_config(self) -> dict:
        """config.json, bounded (:func:`scart_bench.jsonfile.read_json`) and checked field by field
        (:func:`check_config`): a damaged or hostile file is one error naming it."""
        if not self.config_path.exists():
            raise RunStoreError(f"{self.path}: not a scart-bench run folder (no config.json)")
        try:
            config = read_json(self.config_path)
        except JsonFileError as exc:
            raise RunStoreError(str(exc)) from None
        return check_config(config, self.config_path)  # type: ignore[arg-type]

    def lock(self) -> FolderLock:
        """Hold the run folder for this process (LockHeld when another process holds it)."""
        return FolderLock(self.path / ".lock", f"{self.path}").acquire()

    def mark_stale(self) -> None:
        """Remove the run-level result tables before jobs start; they are written again at the end, so an
        interrupted run leaves no metrics that look like its own (``scart-bench score RUN`` remakes them)."""
        for name in SUMMARY_FILES:
            (self.path / name).unlink(missing_ok=True)

    def write_config(self, config: dict) -> None:
        """config.json; a new run folder starts its checksum record here (and config.json says so,
        so that a removed record is noticed)."""
        if not self.config_path.exists() and not self.checksums_path.exists():
            atomic_write_json(self.checksums_path, {"format": CHECKSUMS_FORMAT, "algorithm": "sha256", "files": {}})
        if self.has_checksums():
            config = {**config, "checksums": CHECKSUMS_FILE}
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
        self._write_checked("flights.csv", flights.to_csv(index=False).encode("utf-8"))

    def _read_csv(self, rel: str, **kwargs) -> pd.DataFrame:
        data = self._read_checked(rel)
        try:
            return pd.read_csv(io.BytesIO(data), **kwargs)
        except (ValueError, pd.errors.ParserError, UnicodeDecodeError) as exc:
            raise RunStoreError(f"{self.path / rel}: not a table scart-bench wrote ({type(exc).__name__}: "
                                f"{str(exc).splitlines()[0] if str(exc) else ''})") from None

    def read_flights(self) -> pd.DataFrame:
        """flights.csv, with ``armed_us`` / ``armed_by`` from arming.csv when the run has it."""
        df = self._read_csv("flights.csv", dtype={"flight_id": str, "scenario_id": "string"}, keep_default_na=True)
        if "flight_id" not in df.columns:
            raise RunStoreError(f"{self.path / 'flights.csv'}: no flight_id column; not a table scart-bench wrote")
        for col in ("attack_start_us", "attack_end_us"):
            if col in df.columns:
                try:
                    df[col] = df[col].astype("Int64")
                except (TypeError, ValueError) as exc:
                    raise RunStoreError(f"{self.path / 'flights.csv'}: column {col}: {exc}; expected whole "
                                        "microseconds") from None
        arming = self.read_arming()
        if arming is not None:
            df = df.drop(columns=[c for c in ("armed_us", "armed_by") if c in df.columns]).merge(
                arming, on="flight_id", how="left")
        phases = self.read_phases()
        if phases is not None:
            df = df.drop(columns=[c for c in PHASE_COLUMNS if c in df.columns]).merge(
                phases, on="flight_id", how="left")
        return df

    def has_phases(self) -> bool:
        return (self.path / "phases.csv").is_file()

    def write_phases(self, bounds: dict[str, dict]) -> None:
        """phases.csv: flight id -> its phase bounds (:data:`~scart_bench.benchmark.protocol.PHASE_COLUMNS`)."""
        df = pd.DataFrame([{"flight_id": f, **{c: b.get(c, pd.NA) for c in PHASE_COLUMNS}} for f, b in bounds.items()],
                          columns=["flight_id", *PHASE_COLUMNS])
        for c in PHASE_COLUMNS[:-1]:
            df[c] = df[c].astype("Int64")
        self._write_checked("phases.csv", df.to_csv(index=False).encode("utf-8"))

    def read_phases(self) -> pd.DataFrame | None:
        if not self.has_phases():
            return None
        df = self._read_csv("phases.csv", dtype={"flight_id": str, "phases_by": str,
                                                 **dict.fromkeys(PHASE_COLUMNS[:-1], "Int64")})
        missing = [c for c in ("flight_id", *PHASE_COLUMNS) if c not in df.columns]
        if missing:
            raise RunStoreError(f"{self.path / 'phases.csv'}: columns {', '.join(missing)} missing; expected "
                                f"flight_id, {', '.join(PHASE_COLUMNS)}")
        return df

    def has_arming(self) -> bool:
        return (self.path / "arming.csv").exists()

    def write_arming(self, arming: dict[str, tuple[int, str]]) -> None:
        """arming.csv: flight id -> (armed_us, the column that said so)."""
        df = pd.DataFrame([(f, int(t), str(by)) for f, (t, by) in arming.items()],
                          columns=["flight_id", "armed_us", "armed_by"])
        self._write_checked("arming.csv", df.to_csv(index=False).encode("utf-8"))

    def read_arming(self) -> pd.DataFrame | None:
        if not (self.path / "arming.csv").is_file():
            return None
        df = self._read_csv("arming.csv", dtype={"flight_id": str, "armed_us": "Int64", "armed_by": str})
        if "flight_id" not in df.columns or "armed_us" not in df.columns:
            raise RunStoreError(f"{self.path / 'arming.csv'}: expected columns flight_id, armed_us, armed_by")
        return df

    def has_truth(self) -> bool:
        """truth.parquet is there (and, in a run that records checksums, so is its checksum: a run killed
        between the two writes it again)."""
        if not (self.path / "truth.parquet").exists():
            return False
        files = self._checksums()
        return files is None or "truth.parquet" in files

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
        self._write_checked("truth.parquet", buf.getvalue())

    def read_truth(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Labels per flight: (timestamps, Is_Anomaly), checked against the run's checksum and for shape
        (each flight one block of increasing timestamps, labels 0 or 1)."""
        path = self.path / "truth.parquet"
        if not path.is_file():
            raise RunStoreError(f"{path}: missing; the run's labels are gone (run it again into a new --out)")
        data = self._read_checked("truth.parquet")
        try:
            df = pd.read_parquet(io.BytesIO(data))
            col = df["flight_id"]
            ts = df["Timestamp"].to_numpy(np.int64)
            lab = df["Is_Anomaly"].to_numpy()
        except Exception as exc:  # pyarrow raises its own types for a damaged file
            what = " ".join(str(exc).split())  # pyarrow's messages span lines; an error here is one line
            raise RunStoreError(f"{path}: cannot be read ({type(exc).__name__}: {what[:300]})") from None
        if isinstance(col.dtype, pd.CategoricalDtype):  # as written: compare codes, not 12 M strings
            fid, names = col.cat.codes.to_numpy(), np.asarray(col.cat.categories.astype(str))
        else:
            fid = col.astype(str).to_numpy()
            names = None
        if fid.size == 0:
            return {}
        if not np.isin(lab, (0, 1)).all():
            raise RunStoreError(f"{path}: Is_Anomaly holds values other than 0 and 1; damaged or not written "
                                "by scart-bench")
        lab = lab.astype(np.int8)
        cut = np.flatnonzero(fid[1:] != fid[:-1]) + 1
        starts, ends = np.r_[0, cut], np.r_[cut, fid.size]
        out = {str(fid[s] if names is None else names[fid[s]]): (ts[s:e], lab[s:e]) for s, e in zip(starts, ends)}
        if len(out) != starts.size:
            raise RunStoreError(f"{path}: a flight's rows are not in one block; damaged or not written by scart-bench")
        step = np.diff(ts)
        step[cut - 1] = 1  # a new flight may start anywhere
        if (step <= 0).any():
            row = int(np.flatnonzero(step <= 0)[0]) + 1
            raise RunStoreError(f"{path}: Timestamp not increasing at row {row}; damaged or not written by "
                                "scart-bench")
        return out

    # -- jobs ---------------------------------------------------------------------------------
    def job_names(self) -> list[str]:
        root = self.path / "jobs"
        return sorted(p.name for p in root.iterdir() if p.is_dir()) if root.exists() else []

    def read_status(self, detector: str) -> dict | None:
        """A job's status.json (None when the job has none: not finished), checked against its
        checksum, bounded and checked field by field."""
        p = self.job_dir(detector) / "status.json"
        if not p.exists():
            return None
        data = self._read_checked(f"jobs/{detector}/status.json")
        return check_status(loads_bounded(data, str(p)), p)

    def read_params(self, detector: str) -> dict | None:
        p = self.job_dir(detector) / "params.json"
        return read_json(p) if p.exists() else None  # type: ignore[return-value]

    def read_scores(self, detector: str) -> dict[str, np.ndarray]:
        path = self.job_dir(detector) / "scores.npz"
        return read_npz(path, self._read_checked(f"jobs/{detector}/scores.npz"))

    def read_alarms(self, detector: str) -> dict[str, np.ndarray] | None:
        """The detector's own row alarms (alarm rule "own"), None when the job saved none."""
        path = self.job_dir(detector) / "alarms.npz"
        if not path.is_file():
            return None
        arrays = read_npz(path, self._read_checked(f"jobs/{detector}/alarms.npz"))
        return {k: v.astype(bool) for k, v in arrays.items()}

    def start_job(self, detector: str) -> None:
        """Mark a job as not complete: remove its status.json before anything else is written."""
        d = self.job_dir(detector)
        d.mkdir(parents=True, exist_ok=True)
        (d / "status.json").unlink(missing_ok=True)

    def finish_job(self, detector: str, status: dict, params: dict, scores: dict[str, np.ndarray] | None,
                   log: str = "", alarms: dict[str, np.ndarray] | None = None) -> None:
        """Write a finished job: scores (OK only), params, log, their checksums, then status.json last."""
        if status.get("status") not in STATUSES:
            raise ValueError(f"job status {status.get('status')!r}: expected one of {STATUSES}")
        d = self.job_dir(detector)
        d.mkdir(parents=True, exist_ok=True)
        rel = f"jobs/{detector}"
        record: dict[str, str | None] = {}
        if scores is not None:
            data = npz_bytes(scores)
            record[f"{rel}/scores.npz"] = sha256_hex(data)
            atomic_write_bytes(d / "scores.npz", data)
        else:
            record[f"{rel}/scores.npz"] = None
            (d / "scores.npz").unlink(missing_ok=True)
        if scores is not None and alarms is not None:
            data = npz_bytes({k: np.asarray(v, dtype=np.int8) for k, v in alarms.items()})
            record[f"{rel}/alarms.npz"] = sha256_hex(data)
            atomic_write_bytes(d / "alarms.npz", data)
        else:
            record[f"{rel}/alarms.npz"] = None
            (d / "alarms.npz").unlink(missing_ok=True)
        atomic_write_json(d / "params.json", params)
        atomic_write_text(d / "log.txt", log)
        text = (to_json(status) + "\n").encode("utf-8")
        record[f"{rel}/status.json"] = sha256_hex(text)
        self._record(record)  # before status.json: a job is complete (and checked) once that is there
        atomic_write_bytes(d / "status.json", text)

    # -- tables -------------------------------------------------------------------------------
    def write_table(self, name: str, df: pd.DataFrame) -> None:
        atomic_write_csv(self.path / name, df)

    def write_text(self, name: str, text: str) -> None:
        atomic_write_text(self.path / name, text)


#: The protocol keys that change a job's output (the own alarms it returns); the rest (alpha, the
#: threshold rules, burn-in, end transient, counting rule) only change how saved scores are counted,
#: so they are not part of what makes two runs (or two jobs) the same.
JOB_PROTOCOL_KEYS = ("alarm_rule",)


def comparable(value: dict) -> dict:
    """An identity (or a job key holding one under ``identity``) with its protocol reduced to
    :data:`JOB_PROTOCOL_KEYS`: what ``--resume`` compares. The operating point is chosen after the run
    (``scart-bench score RUN --alpha``, ``run --resume --alpha``) and never reruns a job."""
    if not isinstance(value, dict):
        return value
    if isinstance(value.get("identity"), dict):
        return {**value, "identity": comparable(value["identity"])}
    proto = value.get("protocol")
    if isinstance(proto, dict):
        return {**value, "protocol": {"alarm_rule": proto.get("alarm_rule", "calibrated")}}
    return value


def diff_identity(old: dict, new: dict) -> list[str]:
    """Human-readable differences between two config identities (empty when they match), the
    operating point left out (:func:`comparable`)."""
    old, new = comparable(old), comparable(new)
    out = []
    for key in sorted(set(old) | set(new)):
        if json_safe(old.get(key)) != json_safe(new.get(key)):
            a, b = old.get(key), new.get(key)
            if isinstance(a, dict) or isinstance(b, dict):
                out.append(f"{key} differs")
            else:
                out.append(f"{key}: {a!r} -> {b!r}")
    return out
