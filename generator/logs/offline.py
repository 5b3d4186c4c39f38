"""Your own flights: import logs as normal flights of a dataset, and attack flights in csv mode.

- :func:`import_logs`: PX4 ULogs, CSVs, Parquet files or flight folders become normal flights of a
  dataset (new or existing), ids from the log names, added atomically.
- :func:`attack_dataset`: labelled attacked copies of a dataset's normal flights (split ``test``
  or ``csv_source``) added to the same dataset, ids ``csv-<source flight>-<scenario id>``.
- :func:`attack_file`: the single-log form, one log into a new dataset of attacked copies.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset import (
    DatasetError,
    DatasetWriter,
    LockHeld,
    append_flights,
    check_layout,
    check_output_dir,
    dataset_lock,
    flight_record,
    is_dataset,
    open_dataset,
    replacing,
)
from scart_bench.dataset.write import SourceView
from scart_bench.generator.logs.copies import copy_record
from scart_bench.generator.logs.importers import flight_view_tables, load_flight_file
from scart_bench.generator.logs.logged_time import (
    LoggedClock,
    gap_line,
    gap_record,
    log_triggers,
    logging_gaps,
)
from scart_bench.generator.logs.orientation import listen_view, recorded_view
from scart_bench.generator.logs.phases import LANDED, PHASE_TOPIC, phase_progress, phase_topic
from scart_bench.generator.modes import csv_mode, csv_record, with_labels
from scart_bench.generator.scart.grid import load_configurations
from scart_bench.generator.scart.meanings import input_fields
from scart_bench.generator.scart.spec import ScenarioError
from scart_bench.progress import Progress, quiet

logger = logging.getLogger(__name__)

#: Splits a log can be imported into; ``csv_source``: normal flights kept as csv-mode attack sources
#: (neither trained on nor scored).
IMPORT_SPLITS = ("train", "validation", "test", "csv_source")
#: ``--split auto``: validation gets this share of the logs, and at least AUTO_MIN_VALIDATION: validation
#: flights set every threshold, and on a few logs the false alarms per flight-hour are calibrated on their
#: time, so they get as much as leaves train and test a share; test and csv_source get these shares
#: (test at least one), train the rest.
AUTO_VALIDATION_SHARE = 1 / 3
AUTO_MIN_VALIDATION = 2
AUTO_SHARES = {"test": 0.15, "csv_source": 0.15}


def _config_id(job) -> str:
    return "+".join(s.id for s in job)


def _available(tables) -> dict[str, tuple[str, ...]]:
    return input_fields([tables], ("Is_Anomaly",))  # with the constants of a listen view (orientation.py)


def _validate(jobs, tables, where: str) -> None:
    available = _available(tables)
    for job in jobs:
        for sc in job:
            sc.validate_topics(available, where=f"{sc.source} (on {where})")


def with_phases(tables: dict[str, pd.DataFrame], clock: LoggedClock | None = None) -> dict[str, pd.DataFrame]:
    """The topics the layer listens to on a recording: its own and, when it has no mission computer's
    setpoint (a log, not a generated flight), the ``flight_phase`` topic derived from it
    (generator.logs.phases: the phase and mission item that ``flight_phase`` and ``mission_phase``
    conditions read, and the progress through the phases that ``after_phase`` reads, in logged
    time when ``clock`` is given). The derived topic is on rows of the log's altitude, so the
    replay's message times are the log's own; it is never written (:func:`without_phases`)."""
    tables = listen_view(tables)  # attitude from a quaternion, constant fields marked (orientation.py)
    if "setpoint" in tables or PHASE_TOPIC in tables:
        return tables
    topic = phase_topic(tables)
    if topic is None:
        return tables
    logged = None if clock is None else clock.to_logged(topic["Timestamp"].to_numpy(np.int64))
    return {**tables, PHASE_TOPIC: phase_progress(topic, logged)}


def takeoff_us(listen: dict[str, pd.DataFrame]) -> int | None:
    """The first row off the ground (µs) by the derived phases, or None (no phases, never airborne)."""
    topic = listen.get(PHASE_TOPIC)
    if topic is None or "phase" not in topic.columns:
        return None
    air = np.flatnonzero(topic["phase"].to_numpy(np.float64) != LANDED)
    return int(topic["Timestamp"].iloc[air[0]]) if len(air) else None


def copy_seed(seed: int, job) -> int:
    """The seed of one attacked copy: derived from ``--seed`` and the configuration id, so random
    onsets and noise differ between the copies of one log as they do between generated flights
    (one seed for all would give every level of an action the same onset)."""
    return int.from_bytes(hashlib.sha256(f"{int(seed)}:{_config_id(job)}".encode()).digest()[:4], "little")


def replay_on_log(listen: dict[str, pd.DataFrame], jobs: list, seed: int, clock: LoggedClock,
                  leave_passed: bool = False) -> list[tuple[tuple, list[str]]]:
    """csv mode on a recording in logged time: each configuration's time triggers taken to the
    logged clock (generator.logs.logged_time.log_triggers: a trigger in a gap moves to the next
    logged row, one past the end of the log moves earlier), the replay on that clock (durations
    count logged seconds; each copy's seed from :func:`copy_seed`), and the results back on the log's own
    time. Returns per configuration
    (result without the derived phase topic, notes on moved triggers). ``leave_passed`` (csv_mode's): the
    topics passed unchanged map to None (generator.logs.copies holds them as the source's tables) where
    their labels read the same on the log's time (LoggedClock.back)."""
    if not jobs:
        return []
    moved = [log_triggers(job, clock, takeoff_us(listen)) for job in jobs]
    replay = clock.tables(listen)
    results = csv_mode([replay] * len(jobs), [m[0] for m in moved], [copy_seed(seed, job) for job in jobs],
                       leave_passed=leave_passed)
    return [(without_phases(clock.back(r, replay)), m[1]) for r, m in zip(results, moved)]


def time_record(clock: LoggedClock, notes: list[str]) -> dict:
    """What a copy records of its log's time (config.json ``logged_time``): the gaps and the moved triggers."""
    return {"logging_gaps": gap_record(clock.gaps_), "trigger_notes": list(notes),
            "rule": "durations and random spans count logged time (gaps excluded); see docs/own_logs.md"}


def without_phases(result: tuple) -> tuple:
    """A csv-mode result without the derived phase topic (a copy holds the recording's topics only)."""
    nav, windows, events = result
    return recorded_view({t: df for t, df in nav.items() if t != PHASE_TOPIC}), windows, events


#: Why a configuration gave no copy of a flight, from the error that refused it (short, for the summary).
_REASONS = (
    (re.compile(r"'([^']+)' \(a quantity\) matches no topic"), "{} not in the log"),
    (re.compile(r"unknown topic '([^']+)'"), "topic {} not in the log"),
    (re.compile(r"unknown field '([^']+)'"), "field {} not in the log"),
    (re.compile(r"topic '([^']+)' is not in this input"), "topic {} not in the log"),
    (re.compile(r"reads the flight's phases"), "no flight phases (no altitude in the log)"),
)


def refusal_reason(message: str) -> str:
    """A short reason for a configuration that does not apply to a flight, from its error message."""
    for pattern, text in _REASONS:
        m = pattern.search(message)
        if m:
            return text.format(*m.groups())
    return message.rsplit(": ", 1)[-1][:80]


def applicable(jobs: list, tables: dict[str, pd.DataFrame], where: str) -> tuple[list, Counter]:
    """The configurations whose topics this recording has, and the reasons of the others (counted)."""
    available = _available(tables)
    keep, reasons = [], Counter()
    for job in jobs:
        try:
            for sc in job:
                sc.validate_topics(available, where=f"{sc.source} (on {where})")
        except ScenarioError as exc:
            reasons[refusal_reason(str(exc))] += 1
            continue
        keep.append(job)
    return keep, reasons


def summary_line(reasons: Counter, total: int) -> str:
    """One line: how many configuration x flight pairs gave no copy, grouped by reason."""
    n = sum(reasons.values())
    if not n:
        return f"attack: all {total} configuration x flight pair(s) applied"
    why = "; ".join(f"{k} {r}" for r, k in sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0])))
    return f"attack: {n} of {total} configuration x flight pair(s) gave no copy: {why}"


def prune_orphans(dataset: str | Path) -> list[str]:
    """Remove what a killed ``attack`` or ``import`` left in a dataset: flight folders the manifest
    does not list (the manifest is replaced last, so a killed append leaves its copies unlisted) and
    a half-written manifest. Only while no other process writes the dataset (its lock is free).
    Returns the names removed."""
    import shutil

    path = Path(dataset)
    flights = path / "flights"
    if not is_dataset(path) or not flights.is_dir():
        return []
    try:
        lock = dataset_lock(path).acquire()
    except (LockHeld, OSError):
        return []  # another writer is at work: its folders are not orphans
    try:
        listed = set(open_dataset(path).manifest["flight_id"].astype(str))
        gone = []
        for entry in sorted(flights.iterdir()):
            if entry.name not in listed and entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
                gone.append(entry.name)
        for tmp in path.glob(".manifest.tmp.*"):
            tmp.unlink(missing_ok=True)
            gone.append(tmp.name)
        return gone
    finally:
        lock.release()


def _say_pruned(gone: list[str], say: Callable[[str], None]) -> None:
    if gone:
        say(f"removed {len(gone)} flight folder(s) that an interrupted attack or import left unlisted in the "
            f"manifest ({', '.join(gone[:3])}{' ...' if len(gone) > 3 else ''})")


# ----------------------------------------------------------------------------------------------
# import


def _refuse_physical(jobs, scenario_path) -> None:
    """A recording cannot be flown again: refuse configurations that only change the physics."""
    physical = [j for j in jobs if all(sc.physical for sc in j)]
    if len(physical) == len(jobs):
        points = sorted({sc.injection_point for j in physical for sc in j})
        raise DatasetError(f"{scenario_path}: {'/'.join(points)} scenarios change the physics, which a recorded "
                           "flight cannot replay; use them in simulation mode (scart-bench generate --scenarios)")


def closed_loop(jobs) -> list:
    """The configurations with an action that needs the closed loop (a forged command, a tampered mission)."""
    from scart_bench.generator.scart.link_actions import CLOSED_LOOP_ACTIONS

    return [j for j in jobs if any(n in CLOSED_LOOP_ACTIONS for sc in j for n, _ in sc.actions)]


def _refuse_closed_loop(jobs, scenario_path) -> list:
    """A recording has no flight controller to obey a forged command and no navigator to fly a tampered
    mission: configurations with those actions get no copy (a warning names them); when no other
    configuration is left, a clear error."""
    from scart_bench.generator.scart.link_actions import CLOSED_LOOP_ACTIONS

    closed = closed_loop(jobs)
    if not closed:
        return jobs
    names = sorted({n for j in closed for sc in j for n, _ in sc.actions if n in CLOSED_LOOP_ACTIONS})
    why = (f"{', '.join(names)} act(s) on the flight controller or the navigator, which a recorded flight cannot "
           "replay; use them in simulation mode (scart-bench generate --scenarios)")
    if len(closed) == len(jobs):
        raise DatasetError(f"{scenario_path}: {why}; replay, flood and link_loss apply to recordings")
    logger.warning("%s: no copy of %s: %s", scenario_path, ", ".join(_config_id(j) for j in closed), why)
    return [j for j in jobs if j not in closed]


def _start_conditions(job) -> str:
    """The start conditions of a configuration, for a message (``id: condition key=value``)."""
    parts = []
    for sc in job:
        for name, p in sc.start:
            args = " ".join(f"{k}={v}" for k, v in p.items() if v is not None)
            parts.append(f"{sc.id}: {name} {args}".strip())
    return "; ".join(parts) or "none"


def log_name(path: Path) -> str:
    """A log's name for flight ids: the file name without its extensions, in ``[a-z0-9_-]``."""
    name = path.name if path.is_dir() else re.sub(r"(\.(ulg|bin|tlog|bag|mcap|db3|csv|parquet|pq|gz|bz2|xz|zip|zst))+$", "",
                                                   path.name, flags=re.IGNORECASE)
    return re.sub(r"[^a-z0-9_-]+", "_", name.lower()).strip("_") or "log"


def _seconds(v: float | None) -> str:
    return "end" if v is None else f"{v:g}s".replace(".", "p")


def import_ids(paths: list[Path], start_s: float | None = None, end_s: float | None = None) -> list[str]:
    """Flight ids of imported logs: ``log-<name>``, plus ``-<start>s-<end>s`` (or ``-end``) when trimmed.

    Stable (the same log and window always give the same id). Two logs of the same name are told
    apart by their folder's name; if that is the same too, DatasetError.
    """
    window = "" if start_s is None and end_s is None else f"-{_seconds(start_s or 0.0)}-{_seconds(end_s)}"
    plain = [f"log-{log_name(p)}{window}" for p in paths]
    ids = [f"log-{log_name(p.resolve().parent)}-{log_name(p)}{window}" if plain.count(plain[i]) > 1 else plain[i]
           for i, p in enumerate(paths)]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise DatasetError(f"logs give the same flight id {dup[0]!r}; rename one of them")
    return ids


def auto_counts(n: int) -> dict[str, int]:
    """How many of ``n`` logs ``--split auto`` puts in each split: a third (at least 2) validation,
    15 % test (at least 1), 15 % csv_source, the rest train. Too few logs for all: csv_source gives
    way first, then test down to 1, validation down to 1, test, validation (train keeps one)."""
    import math

    if n <= 0:
        return dict.fromkeys(IMPORT_SPLITS, 0)
    val = max(AUTO_MIN_VALIDATION, math.ceil(n * AUTO_VALIDATION_SHARE))
    test = max(1, int(n * AUTO_SHARES["test"] + 1e-9))
    csv = int(n * AUTO_SHARES["csv_source"] + 1e-9)
    while n > 0 and val + test + csv + 1 > n:
        if csv:
            csv -= 1
        elif test > 1:
            test -= 1
        elif val > 1:
            val -= 1
        elif test:
            test -= 1
        else:
            val -= 1
    return {"train": max(n - val - test - csv, 0), "validation": val, "test": test, "csv_source": csv}


def auto_splits(ids: list[str], seed: int) -> list[str]:
    """``--split auto``: train / validation / test / csv_source by a seeded shuffle of the ids, in the
    numbers of :func:`auto_counts`.

    Deterministic for a seed and a set of ids (not their order). From 2 logs on, train and
    validation each get one; from 3, test too; from 4, validation gets 2.
    """
    n = len(ids)
    key = lambda fid: hashlib.sha256(f"{seed}:{fid}".encode()).hexdigest()  # noqa: E731
    order = sorted(range(n), key=lambda i: key(ids[i]))
    counts = auto_counts(n)
    n_train, n_val, n_test = counts["train"], counts["validation"], counts["test"]
    out = [""] * n
    for rank, i in enumerate(order):
        out[i] = ("train" if rank < n_train else "validation" if rank < n_train + n_val
                  else "test" if rank < n_train + n_val + n_test else "csv_source")
    return out


def auto_split_line(splits: list[str], loaded: list[dict[str, pd.DataFrame]], seed: int) -> str:
    """One line on what ``--split auto`` chose: flights and logged minutes (gaps not counted) per split."""
    from scart_bench.generator.logs.logged_time import log_times

    minutes = dict.fromkeys(IMPORT_SPLITS, 0.0)
    for sp, tables in zip(splits, loaded):
        t = log_times(tables)
        if len(t) > 1:
            span = float(t[-1] - t[0]) - sum(b - a for a, b in logging_gaps(tables))
            minutes[sp] += span / 60e6
    parts = [f"{splits.count(sp)} {sp} ({minutes[sp]:.1f} min)" for sp in IMPORT_SPLITS if splits.count(sp)]
    return (f"import: --split auto (seed {seed}) for {len(splits)} log(s): {', '.join(parts)} of logged flight; "
            f"validation holds a third of the logs (at least {AUTO_MIN_VALIDATION}): its time calibrates the "
            "thresholds")


def non_finite_cells(tables: dict[str, pd.DataFrame]) -> dict[str, int]:
    """NaN or +/-inf cells per ``topic.field`` column of a log's numeric fields (only those with any)."""
    out: dict[str, int] = {}
    for topic, df in tables.items():
        for col in df.columns:
            if col in ("Timestamp", "Index", "Is_Anomaly"):
                continue
            v = df[col]
            if not pd.api.types.is_numeric_dtype(v):
                continue
            n = int((~np.isfinite(v.to_numpy(np.float64, na_value=np.nan))).sum())
            if n:
                out[f"{topic}.{col}"] = n
    return out


def import_logs(paths: list[str | Path], out: str | Path, split: str = "train", topics: list[str] | None = None,
                start_s: float | None = None, end_s: float | None = None, seed: int = 0, fmt: str = "parquet",
                allow_corrupt: bool = False, say: Callable[[str], None] | None = None,
                layout: str | None = None, progress: Progress | None = None) -> list[str]:
    """Add logs to dataset ``out`` (created if missing) as normal flights; returns their ids.

    Each log (trimmed to ``[start_s, end_s)`` if given) becomes one flight whose navigator and
    simulator views are the log's topic tables. Every log is read and checked before anything is
    written; the flights are then appended atomically (the manifest is replaced last).
    ``progress`` counts the logs ``read`` and ``written``.
    """
    if split not in (*IMPORT_SPLITS, "auto"):
        raise DatasetError(f"--split {split!r}: expected one of {', '.join(IMPORT_SPLITS)} or auto")
    if not paths:
        raise DatasetError("no log given to import")
    paths = [Path(p) for p in paths]
    ids = import_ids(paths, start_s, end_s)
    out = Path(out)
    say = say or (lambda msg: None)
    if is_dataset(out):
        _say_pruned(prune_orphans(out), lambda m: say(f"import: {m}"))
        taken = set(open_dataset(out).manifest["flight_id"].astype(str))
        clash = [i for i in ids if i in taken]
        if clash:
            raise DatasetError(f"{out}: flight {clash[0]!r} is already in the dataset (imported before?); "
                               "flight ids come from the log names and --start/--end")
    splits = auto_splits(ids, seed) if split == "auto" else [split] * len(ids)
    loaded = []
    progress = progress or quiet()
    progress.expect("read", len(paths))
    progress.expect("written", len(paths))
    for p in paths:  # read everything first: a bad log fails before anything is written
        tables = load_flight_file(p, topics, allow_corrupt=allow_corrupt, start_s=start_s, end_s=end_s)
        loaded.append(tables)
        progress.add("read")
        gaps = logging_gaps(tables)
        if gaps:
            say(f"import: {p}: {gap_line(gaps)}; attack windows count logged time")
        counts = non_finite_cells(tables)
        if counts:
            shown = ", ".join(f"{c} {n}" for c, n in list(counts.items())[:8]) + (" ..." if len(counts) > 8 else "")
            say(f"import: warning: {p}: {sum(counts.values())} NaN/inf cell(s) in {len(counts)} column(s) ({shown}); "
                "detectors treat them as missing values")
    if split == "auto":
        say(auto_split_line(splits, loaded, seed))

    def records() -> Iterator:
        for p, fid, sp, tables in zip(paths, ids, splits, loaded):
            say(f"import: {p} -> {fid} ({sp})")
            config = {"mode": "import", "input": str(p), "topics": topics, "window_s": [start_s, end_s],
                      "input_origin_us": {t: df.attrs.get("origin_us") for t, df in tables.items()},
                      "logging_gaps": gap_record(logging_gaps(tables))}
            yield flight_record(fid, with_labels(tables), with_labels(tables),
                                {"mode": "normal", "split": sp, "seed": seed, "source_flight": str(p)},
                                json.loads(json.dumps(config, default=str)))
            progress.add("written")  # the writer has taken the flight

    append_flights(out, records(), fmt=fmt, info={"profile": "own-logs", "seed": seed}, layout=layout)
    return ids


# ----------------------------------------------------------------------------------------------
# attack


def attack_dataset(dataset: str | Path, scenario_path: str | Path, sources: tuple[str, ...] = ("test",),
                   seed: int = 0, say: Callable[[str], None] | None = None,
                   progress: Progress | None = None, full_copies: bool = False) -> list[str]:
    """Add labelled attacked copies of the dataset's normal flights of split ``sources`` to it.

    Every configuration of the scenario (or grid) file that applies to a source flight is replayed on
    it; ids ``csv-<source flight>-<configuration id>``. A configuration applies when the flight has
    its topics (quantities resolve by meaning: generator.scart.meanings) and its attack starts; the
    others give no copy, and one line through ``say`` counts them by reason (a quantity the log
    lacks, a trigger that never held, an action that needs the closed loop). When no configuration
    applies to any flight, the first refusal is raised in full before anything is written; when
    none starts, DatasetError. Returns the ids added. ``progress`` counts the source flights
    ``read`` and the copies ``replayed`` (written, or found never to start). A copy stores what the
    attack changed and reads its untouched fields from its source flight's file (generator.logs.copies);
    ``full_copies``: every copy written whole, as before (perf/attack_speed.py compares the two).
    """
    say = say or (lambda msg: None)
    _say_pruned(prune_orphans(dataset), lambda m: say(f"attack: {m}"))
    ds = open_dataset(dataset)
    bad = [s for s in sources if s not in ("test", "csv_source", "validation", "train")]
    if bad:
        raise DatasetError(f"--sources {bad[0]!r}: expected test and/or csv_source")
    m = ds.manifest
    rows = m[(m["mode"].astype(str) == "normal") & m["split"].astype(str).isin(sources)]
    if rows.empty:
        raise DatasetError(f"{ds.path}: no normal flight with split {' or '.join(sources)} to attack; import logs with "
                           f"--split {sources[0]} (or --split auto)")
    jobs = load_configurations(Path(scenario_path), check_topics=False)
    _refuse_physical(jobs, scenario_path)
    n_closed = len(closed_loop(jobs))
    jobs = _refuse_closed_loop(jobs, scenario_path)
    reasons: Counter = Counter()
    if n_closed:
        reasons["act in the closed loop (simulation mode only)"] = n_closed * len(rows)
    progress = progress or quiet()
    progress.expect("read", len(rows))
    flights, views = [], {}
    for fid in rows["flight_id"].astype(str):
        view = None if full_copies else _source_view(ds, fid)
        stored = None if view is None else view.tables()
        tables = load_flight_file(ds.flight_dir(fid)) if stored is None else flight_view_tables(ds.flight_dir(fid), stored)
        if view is not None:
            views[fid] = view
        clock = LoggedClock().fit(tables)
        listen = with_phases(tables, clock)
        fit, why = applicable(jobs, listen, f"flight {fid}")
        reasons.update(why)
        flights.append((fid, tables, listen, fit, clock))
        progress.add("read")
    progress.expect("replayed", sum(len(f[3]) for f in flights))
    if not any(f[3] for f in flights):
        _validate(jobs, flights[0][2], f"flight {flights[0][0]}")  # the first refusal, in full
    added: list[str] = []

    def records() -> Iterator:
        for fid, tables, listen, fit, clock in flights:
            if not clock.identity:
                say(f"attack: {fid}: {gap_line(clock.gaps_)}; durations count logged time")
            moved_any = []
            for job, (result, notes) in zip(fit, replay_on_log(listen, fit, seed, clock, leave_passed=not full_copies)):
                progress.add("replayed")
                moved_any.extend(notes)
                cid = f"csv-{fid}-{_config_id(job)}"
                if not result[1]:
                    reasons["trigger never held (no attack window)"] += 1
                    logger.info("%s: the attack %s never started on flight %s (its start conditions never "
                                "held); no copy added", scenario_path, _config_id(job), fid)
                    continue
                say(f"attack: {fid} x {_config_id(job)} -> {cid}")
                added.append(cid)
                config = {"input": f"{ds.path}/flights/{fid}", "source_flight": fid,
                          "logged_time": time_record(clock, notes)}
                if full_copies:
                    yield csv_record(cid, tables, result, job, copy_seed(seed, job), fid, config)
                else:
                    yield copy_record(cid, tables, result, job, copy_seed(seed, job), fid, config, replayed=listen)
            if moved_any:
                say(f"attack: {fid}: {len(moved_any)} trigger(s) moved on the log's time, e.g. {moved_any[0]} "
                    "(each copy's raw/config.json lists its own)")

    append_flights(ds.path, records(), share_sources=not full_copies, source_views=views)
    say(summary_line(reasons, (len(jobs) + n_closed) * len(flights)))
    if not added:
        raise DatasetError(f"{scenario_path}: the attack never started on any source flight; nothing was added "
                           f"(start conditions: {_start_conditions(jobs[0])})")
    return added


def _source_view(ds, fid: str) -> SourceView | None:
    """A compact source flight's navigator view, read once for both the replay (its tables) and the
    writer's comparison of each copy with it; None where it is not one (the flight is then read as
    before, and a damaged one reported as before)."""
    if not ds.is_compact(fid):
        return None
    try:
        return SourceView(ds.flight_dir(fid) / "navigator.parquet", fid)
    except DatasetError:
        return None


def attack_file(input_path: str | Path, scenario_path: str | Path, out: str | Path, fmt: str = "parquet",
                seed: int = 0, overwrite: bool = False, topics: list[str] | None = None,
                allow_corrupt: bool = False, layout: str | None = None) -> Path:
    """Replay ``input_path`` (CSV, ULog, Parquet or a dataset flight folder) through the scenario(s).

    A scenario file's scenarios are applied together to one attacked copy; a grid or sweep file
    gives one attacked copy per configuration that applies to the log (a warning counts the others by
    reason; none applying is an error naming the first refusal). Everything is validated before
    anything is written.
    """
    input_path, out = Path(input_path), Path(out)
    check_layout(fmt, layout)
    check_output_dir(out, overwrite=overwrite)
    jobs = load_configurations(Path(scenario_path), check_topics=False)
    _refuse_physical(jobs, scenario_path)
    jobs = _refuse_closed_loop(jobs, scenario_path)
    tables = load_flight_file(input_path, topics=topics, allow_corrupt=allow_corrupt)
    clock = LoggedClock().fit(tables)
    listen = with_phases(tables, clock)
    fit, why = applicable(jobs, listen, str(input_path))
    if not fit:
        _validate(jobs, listen, str(input_path))  # the first refusal, in full
    if why:
        logger.warning("%s on %s: %s", scenario_path, input_path, summary_line(why, len(jobs)).partition(": ")[2])
    jobs = fit
    replayed = replay_on_log(listen, jobs, seed, clock)
    results = [r for r, _ in replayed]
    notes = {_config_id(job): n for job, (_, n) in zip(jobs, replayed)}
    for n in [n for _, ns in replayed for n in ns][:5]:
        logger.warning("%s on %s: %s", scenario_path, input_path, n)
    started = [(job, result) for job, result in zip(jobs, results) if result[1]]
    for job, result in zip(jobs, results):
        if started and not result[1]:
            logger.warning("%s: the attack %r never started on %s (its start conditions never held); no copy",
                           scenario_path, _config_id(job), input_path)
    if not started:
        raise DatasetError(f"{scenario_path}: the attack never started on {input_path}: its start conditions "
                           f"({_start_conditions(jobs[0])}) never held within the log; nothing was written")
    jobs, results = [j for j, _ in started], [r for _, r in started]
    origins = {t: df.attrs.get("origin_us") for t, df in tables.items()}
    # built beside ``out`` and moved into place when complete: --overwrite never loses the old
    # dataset to a failure (a full disk) half-way
    with replacing(out) as partial:
        writer = DatasetWriter(partial, fmt=fmt, layout=layout,
                               info={"mode": "csv", "input": str(input_path), "scenario_file": str(scenario_path)})
        for job, result in zip(jobs, results):
            config = json.loads(json.dumps({"input": str(input_path), "input_origin_us": origins,
                                            "logged_time": time_record(clock, notes[_config_id(job)])}, default=str))
            writer.write(csv_record("csv-" + _config_id(job), tables, result, job, copy_seed(seed, job), str(input_path),
                                    config))
        writer.close()
    return out
