"""What a benchmark run is asked to do: :class:`RunConfig`, from the command line or a ``--config`` file.

A run file (TOML) holds the whole run; every key is optional and the command line's options win
over it::

    detectors = ["statistical", "goad"]     # or "all"
    profile = "quick"                        # or: dataset = "path/to/dataset"
    train_dataset = "path/to/generated"      # optional: train and calibrate there, test on dataset
                                             #   (scart_bench.benchmark.transfer)
    out = "runs/my-run"
    seed = 0
    jobs = 2
    timeout = 1800                           # seconds per job
    score_shards = 1                         # >1: fit once, score the flights in this many parallel jobs
    executor = "local"                       # or "dask" (with scheduler = "tcp://host:8786")
    plugins = ["my_detector.py:MyDetector"]
    features = ["vehicle_gps_position.*"]    # optional: the feature columns (glob patterns), or
    exclude = ["battery_status.*"]           #   columns to leave out of the default feature rule
    columns = "auto"                         # or "logged" / "meaning": how flights that log different
                                             #   columns are read (scart_bench.benchmark.transfer.open_meaning)

    [params.goad]                            # constructor parameters per detector
    n_trans = 64
    epochs = 5

    [protocol]                               # the operating point (see scart_bench.benchmark.protocol)
    alpha = 0.05                             # target per-flight false-alarm rate (conformal threshold)
    burn_in_s = 8.0                          # after arming: rows neither calibrate nor alarm
    end_transient_s = 2.0                    # an alarm this soon after the attack's end is "at the end"
    alarm_rule = "calibrated"                # or "own": the detector's own alarm rule where it has one
    phases = "burn-in"                       # rows counted at the ends: burn-in, ends or cruise
    phase_margin_s = 3.0                     # the margin of ends / cruise after take-off and before touchdown
    hourly_rate = 1.0                        # too few validation flights for alpha: false alarms per flight-hour
    [protocol.flight_rule]                   # or the rules in full (kind conformal / max / quantile)
    kind = "conformal"

A finished run's ``config.json`` holds the same data under ``"run"``; ``--config RUN/config.json``
reruns it (the file is read as data: nothing in it is imported or executed; the plugins it names are
loaded only when the command line names them with ``--plugin`` or passes ``--trust-plugins``).
"""

from __future__ import annotations

import fnmatch
import json
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from scart_bench.benchmark.protocol import Protocol, ProtocolError, ThresholdRule
from scart_bench.benchmark.transfer import COLUMN_MODES
from scart_bench.errors import RunError
from scart_bench.generator.profiles import PROFILES
from scart_bench.storage import is_url

#: The keys a run file may hold.
#: values of ``--calibrate-on`` (run file: ``calibrate_on``)
CALIBRATE_ON = ("train_dataset", "dataset")
#: values of ``--device``
DEVICES = ("auto", "cpu", "cuda")
RUN_KEYS = ("detectors", "profile", "dataset", "train_dataset", "calibrate_on", "out", "seed", "jobs", "timeout", "executor", "scheduler",
            "plugins", "params", "protocol", "resume", "features", "exclude", "device", "score_shards", "columns")


@dataclass
class RunConfig:
    """What ``scart-bench run`` was asked to do (the CLI's options, as plain values)."""

    detectors: list[str] = field(default_factory=lambda: ["all"])
    profile: str = "quick"
    #: a dataset folder, or an fsspec URL (str) of one (scart_bench.storage)
    dataset: Path | str | None = None
    #: train and calibrate on this dataset, test on ``dataset`` (a transfer run: benchmark.transfer)
    train_dataset: Path | None = None
    #: a transfer run's calibration flights: the train dataset's validation flights ("train_dataset"), or the
    #: test dataset's normal flights of split validation ("dataset": a few of your own flights, never tested)
    calibrate_on: str = "train_dataset"
    out: Path | str | None = None
    resume: bool = False
    executor: str = "local"
    scheduler: str | None = None
    jobs: int = 1
    timeout: float | None = None
    #: score each detector's flights in this many parallel jobs after one fit (benchmark.sharding);
    #: same scores and metrics as 1, so it is not part of the run's identity
    score_shards: int = 1
    seed: int = 0
    plugins: list[str] = field(default_factory=list)
    params: dict[str, dict] = field(default_factory=dict)
    #: feature selection for every detector (glob patterns on ``topic.field``;
    #: scart_bench.detectors.base.feature_columns)
    features: list[str] | None = None
    exclude: list[str] | None = None
    #: how a run on one dataset reads its flights: auto (by meaning when they log different columns
    #: and no --features/--exclude names logged columns), logged or meaning (benchmark.transfer.open_meaning)
    columns: str = "auto"
    #: torch device of the detectors that take one: auto (cuda when available, as the detectors'
    #: own default), cpu or cuda
    device: str = "auto"
    protocol: Protocol = field(default_factory=Protocol)
    data_root: Path = Path("data/datasets")
    runs_root: Path = Path("runs")
    progress: bool = True

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise RunError(f"--profile {self.profile!r}: expected one of {', '.join(PROFILES)}")
        if self.executor not in ("local", "dask"):
            raise RunError(f"--executor {self.executor!r}: expected local or dask")
        if self.scheduler and self.executor != "dask":
            raise RunError("--scheduler needs --executor dask")
        if isinstance(self.jobs, bool) or not isinstance(self.jobs, int) or self.jobs < 1:
            raise RunError(f"--jobs {self.jobs!r}: expected a positive number of parallel jobs")
        if isinstance(self.score_shards, bool) or not isinstance(self.score_shards, int) or self.score_shards < 1:
            raise RunError(f"--score-shards {self.score_shards!r}: expected a positive number of scoring shards")
        if self.timeout is not None:
            try:
                t = float(self.timeout)
            except (TypeError, ValueError):
                t = float("nan")
            if not (math.isfinite(t) and t > 0):
                raise RunError(f"--timeout {self.timeout!r}: expected a positive, finite number of seconds")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**32:
            raise RunError(f"--seed {self.seed!r}: expected an integer in 0..{2**32 - 1}")
        if self.device not in DEVICES:
            raise RunError(f"--device {self.device!r}: expected one of {', '.join(DEVICES)}")
        if not self.detectors:
            raise RunError("--detectors: expected 'all' or a comma-separated list of names")
        if self.columns not in COLUMN_MODES:
            raise RunError(f"--columns {self.columns!r}: expected one of {', '.join(COLUMN_MODES)}")
        if self.train_dataset is not None and self.columns == "logged":
            raise RunError("--columns logged: a transfer run (--train-dataset) always reads its flights by meaning")
        if self.calibrate_on not in CALIBRATE_ON:
            raise RunError(f"--calibrate-on {self.calibrate_on!r}: expected one of "
                           f"{', '.join(c.replace('_', '-') for c in CALIBRATE_ON)}")
        if self.calibrate_on != "train_dataset" and self.train_dataset is None:
            raise RunError("--calibrate-on dataset: a transfer run's option (it needs --train-dataset)")
        if self.train_dataset is not None and self.dataset is None:
            raise RunError(f"--train-dataset {self.train_dataset}: a transfer run tests on --dataset DIR; none given")

    @property
    def timeout_s(self) -> float:
        return float(self.timeout) if self.timeout is not None else PROFILES[self.profile].job_timeout_s

    @property
    def out_path(self) -> Path:
        return Path(self.out) if self.out is not None else self.runs_root / f"{self.profile}-seed{self.seed}"

    def to_dict(self) -> dict:
        """The run as plain data, in the run file's schema (what ``--config`` reads back)."""
        out: dict = {"detectors": list(self.detectors), "profile": self.profile, "seed": int(self.seed),
                     "jobs": int(self.jobs), "executor": self.executor, "timeout": self.timeout_s,
                     "score_shards": int(self.score_shards),
                     "plugins": list(self.plugins), "params": {k: dict(v) for k, v in self.params.items()},
                     "protocol": self.protocol.rules()}
        if self.dataset is not None:
            out["dataset"] = str(self.dataset)
        if self.train_dataset is not None:
            out["train_dataset"] = str(self.train_dataset)
        if self.calibrate_on != "train_dataset":
            out["calibrate_on"] = self.calibrate_on
        if self.scheduler:
            out["scheduler"] = self.scheduler
        if self.features:
            out["features"] = list(self.features)
        if self.exclude:
            out["exclude"] = list(self.exclude)
        if self.columns != "auto":
            out["columns"] = self.columns
        out["device"] = self.device
        return out


def read_run_file(path: str | Path) -> dict:
    """The run settings in a run file (TOML) or a run folder's ``config.json`` (its ``"run"`` entry)."""
    p = Path(path)
    if p.is_dir():
        p = p / "config.json"
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise RunError(f"--config {p}: cannot read it ({exc.strerror or exc})") from exc
    if p.suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise RunError(f"--config {p}: not valid JSON ({exc})") from exc
        if not isinstance(data, dict) or not isinstance(data.get("run"), dict):
            raise RunError(f"--config {p}: a run folder's config.json with a \"run\" entry was expected")
        data = data["run"]
        if isinstance(data.get("protocol"), dict):
            # a run folder made before protocol v2 had no burn-in and no end transient: rerun it as it was
            data = {**data, "protocol": {"burn_in_s": 0.0, "end_transient_s": 0.0, **data["protocol"]}}
    else:
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise RunError(f"--config {p}: not valid TOML ({exc})") from exc
    unknown = [k for k in data if k not in RUN_KEYS]
    if unknown:
        raise RunError(f"--config {p}: unknown key(s) {', '.join(map(repr, unknown))}; expected: "
                       f"{', '.join(RUN_KEYS)}")
    return _checked(p, data)


def _checked(p: Path, data: dict) -> dict:
    """Types of a run file's values, named by key when wrong."""
    def bad(key: str, expected: str) -> RunError:
        return RunError(f"--config {p}: {key} = {data[key]!r}: expected {expected}")

    out = dict(data)
    if "detectors" in data:
        d = data["detectors"]
        if isinstance(d, str):
            out["detectors"] = [d]
        elif isinstance(d, list) and all(isinstance(x, str) for x in d) and d:
            out["detectors"] = list(d)
        else:
            raise bad("detectors", '"all" or a list of detector names')
    for key in ("profile", "executor", "scheduler", "dataset", "train_dataset", "calibrate_on", "out", "device",
                "columns"):
        if key in data and not isinstance(data[key], str):
            raise bad(key, "a string")
    for key in ("dataset", "train_dataset", "out"):
        if key in data:  # an fsspec URL (s3://...) stays a string: Path would fold its "//"
            out[key] = data[key] if is_url(data[key]) else Path(data[key])
    for key in ("seed", "jobs", "score_shards"):
        if key in data and (isinstance(data[key], bool) or not isinstance(data[key], int)):
            raise bad(key, "an integer")
    if "timeout" in data and (isinstance(data["timeout"], bool) or not isinstance(data["timeout"], int | float)):
        raise bad("timeout", "a number of seconds")
    if "resume" in data and not isinstance(data["resume"], bool):
        raise bad("resume", "true or false")
    if "plugins" in data and not (isinstance(data["plugins"], list)
                                  and all(isinstance(x, str) for x in data["plugins"])):
        raise bad("plugins", "a list of module:Class or file.py:Class strings")
    for key in ("features", "exclude"):
        if key in data and not (isinstance(data[key], list) and all(isinstance(x, str) for x in data[key])):
            raise bad(key, "a list of glob patterns on topic.field, e.g. [\"vehicle_gps_position.*\"]")
    if "params" in data:
        params = data["params"]
        if not isinstance(params, dict) or not all(isinstance(v, dict) for v in params.values()):
            raise bad("params", "tables [params.DETECTOR] of parameter = value")
    if "protocol" in data:
        out["protocol"] = protocol_from(p, data["protocol"])
    return out


def protocol_from(p: Path, data: object) -> Protocol:
    """A Protocol from a run file's ``[protocol]`` table (missing keys keep their defaults)."""
    keys = ("flight_rule", "row_rule", "alpha", "burn_in_s", "end_transient_s", "alarm_rule", "phases",
            "phase_margin_s", "hourly_rate", "hourly_window_s")
    if not isinstance(data, dict):
        raise RunError(f"--config {p}: protocol: expected a table with {', '.join(keys)}")
    unknown = [k for k in data if k not in keys]
    if unknown:
        raise RunError(f"--config {p}: protocol: unknown key(s) {unknown}; expected {', '.join(keys)}")
    rules = {}
    for key in ("flight_rule", "row_rule"):
        value = data.get(key, {})
        if not isinstance(value, dict):
            raise RunError(f"--config {p}: protocol.{key}: expected a table (kind, margin, q, alpha)")
        if "alpha" in data and "alpha" not in value:
            value = {**value, "alpha": data["alpha"]}
        try:
            rules[key] = ThresholdRule(**value)
        except TypeError as exc:
            raise RunError(f"--config {p}: protocol.{key}: {exc}; expected keys kind, margin, q, alpha") from exc
        except ProtocolError as exc:
            raise RunError(f"--config {p}: protocol.{key}: {exc}") from exc
    extra = {}
    for key in ("burn_in_s", "end_transient_s", "phase_margin_s", "hourly_rate", "hourly_window_s"):
        if key in data:
            v = data[key]
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise RunError(f"--config {p}: protocol.{key} = {v!r}: expected a number of seconds >= 0")
            extra[key] = float(v)
    for key in ("alarm_rule", "phases"):
        if key in data:
            extra[key] = data[key]
    try:
        return Protocol(rules["flight_rule"], rules["row_rule"], **extra)
    except ProtocolError as exc:
        raise RunError(f"--config {p}: protocol: {exc}") from exc


def merge_params(base: dict[str, dict], extra: dict[str, dict]) -> dict[str, dict]:
    """Per-detector parameters of ``base`` updated by ``extra`` (the command line's ``--param``)."""
    out = {k: dict(v) for k, v in base.items()}
    for name, values in extra.items():
        out.setdefault(name, {}).update(values)
    return out


def check_against_flights(cfg: RunConfig, chosen: list, splits, flights: pd.DataFrame,
                          read: Callable[[str], pd.DataFrame]) -> None:
    """Refuse, before any job runs, what would only fail inside every job or score nothing: a
    detector window (a parameter in its class's ``window_params``) not shorter than the run's
    shortest flight, a burn-in at least as long as every validation or every test flight, and
    ``--features`` / ``--exclude`` that leave no column of the first training flight.

    ``flights``: the run's flights (flight_id with the manifest's ``rows`` and ``duration_s`` where
    known); ``read``: a flight by id (the table the jobs read). RunError naming the option and the
    accepted range."""
    from scart_bench.dataset.schema import sensor_columns
    from scart_bench.detectors.base import is_feature_name

    def column(name: str, ids) -> pd.Series:
        if name not in flights.columns:
            return pd.Series(dtype=float)
        known = flights[flights["flight_id"].astype(str).isin(set(ids))]
        values = pd.to_numeric(known[name], errors="coerce")
        return values[values.notna() & (values > 0)]

    used = (*splits.train, *splits.scored)
    rows = column("rows", used)
    for choice in chosen:
        for param in getattr(choice.cls, "window_params", ()):
            value = choice.params.get(param)  # as given (a default window on short flights pads, as before)
            if not isinstance(value, int) or isinstance(value, bool) or not len(rows):
                continue
            shortest = int(rows.min())
            if value >= shortest:
                raise RunError(f"--param {choice.name}.{param}={value}: expected a window of fewer rows than the "
                               f"run's shortest flight ({shortest} rows)")
    burn_in = float(cfg.protocol.burn_in_s)
    for role, ids in (("validation", splits.validation), ("test", splits.test_normal + splits.test_attacked)):
        durations = column("duration_s", ids)
        if burn_in > 0 and len(durations) == len(ids) and len(ids) and burn_in >= float(durations.max()):
            raise RunError(f"--burn-in {burn_in:g}: expected fewer seconds than the longest {role} flight "
                           f"({float(durations.max()):g} s); no row of any {role} flight would count")
    if not (cfg.features or cfg.exclude) or not splits.train:
        return
    first = splits.train[0]
    columns = sensor_columns(read(first).columns)
    keep = ([c for c in columns if any(fnmatch.fnmatchcase(c, p) for p in cfg.features)] if cfg.features
            else [c for c in columns if is_feature_name(c)])
    shown = ", ".join(columns[:8]) + (", ..." if len(columns) > 8 else "")
    if cfg.features and not keep:
        raise RunError(f"--features {','.join(cfg.features)}: matches no column of the dataset's flights "
                       f"({first} has {shown or 'none'}); expected glob patterns on topic.field")
    if cfg.exclude and not [c for c in keep if not any(fnmatch.fnmatchcase(c, p) for p in cfg.exclude)]:
        raise RunError(f"--exclude {','.join(cfg.exclude)}: leaves no feature column of the dataset's flights "
                       f"({first} has {shown or 'none'}); expected patterns that keep at least one")

