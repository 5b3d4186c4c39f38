"""``scart-bench run``: run or resume a benchmark, print and save its tables."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from scart_bench.cli.common import (
    DEFAULT_PHASE_MARGIN_S,
    PHASE_RULES,
    name_failed,
    print_tables,
    remove_stale_temp,
    stage_folder,
)
from scart_bench.generator.profiles import PROFILES

if TYPE_CHECKING:
    from scart_bench.benchmark.config import RunConfig


def _patterns(values: list[str] | None) -> list[str] | None:
    out = [p.strip() for v in (values or []) for p in v.split(",") if p.strip()]
    return out or None


#: run option -> the RunConfig field it sets (the run file uses the field names)
_OPTIONS = {"detectors": "detectors", "profile": "profile", "dataset": "dataset", "train_dataset": "train_dataset",
            "calibrate_on": "calibrate_on", "out": "out",
            "resume": "resume", "executor": "executor", "scheduler": "scheduler", "jobs": "jobs",
            "score_shards": "score_shards",
            "timeout": "timeout", "seed": "seed", "features": "features",
            "exclude": "exclude", "device": "device", "columns": "columns"}


def run_config(args: argparse.Namespace):
    """The RunConfig of ``scart-bench run``: the ``--config`` file, overridden by the options given."""
    import dataclasses

    from scart_bench.benchmark.config import RunConfig, merge_params, read_run_file
    from scart_bench.benchmark.selection import parse_params
    from scart_bench.errors import RunError

    cfg = RunConfig()
    if args.config:
        try:
            cfg = RunConfig(**read_run_file(args.config))
        except RunError as exc:
            msg = str(exc)
            raise RunError(msg if msg.startswith("--config") else f"--config {args.config}: {msg}") from None
    given: dict = {}
    for option, key in _OPTIONS.items():
        value = getattr(args, option)
        if value is None or value is False:
            continue
        if option in ("features", "exclude"):
            value = _patterns(value)
        if option in ("dataset", "train_dataset", "out"):  # a folder, or an fsspec URL kept as text
            from scart_bench.storage import is_url, local_path

            value = value if is_url(value) else local_path(value)
        if option == "calibrate_on":
            value = value.replace("-", "_")
        given[key] = [value] if option == "detectors" else value
    given["params"] = merge_params(cfg.params, parse_params(args.param or []))
    given["protocol"] = protocol_options(cfg.protocol, args)
    given["plugins"] = _trusted_plugins(cfg.plugins, list(args.plugin or []), args)
    return dataclasses.replace(cfg, **given)


def _trusted_plugins(from_file: list[str], from_command_line: list[str], args: argparse.Namespace) -> list[str]:
    """The plugins to load: those named on the command line, plus a run file's only with
    ``--trust-plugins``. A run file (or a shared run folder's config.json) is data: importing a
    plugin it names would run that file's code, so it is refused, naming the plugin and the flag."""
    from scart_bench.benchmark.selection import absolute_plugin
    from scart_bench.errors import RunError

    named = {absolute_plugin(p) for p in from_command_line}
    untrusted = [p for p in from_file if absolute_plugin(p) not in named]
    if untrusted and not getattr(args, "trust_plugins", False):
        raise RunError(f"--config {args.config}: it names the plugin {untrusted[0]!r}, whose code would run when "
                       "it is imported; a run file is read as data only. Load it with --plugin "
                       f"{untrusted[0]} (or pass --trust-plugins to load every plugin the file names)")
    return list(dict.fromkeys([*from_command_line, *untrusted]))


def add_phase_options(parser) -> None:
    """``--phases`` and ``--phase-margin`` (run and score)."""

    parser.add_argument("--phases", choices=PHASE_RULES,
                        help="which rows calibrate and alarm at the flight's ends: burn-in (protocol v2: from "
                             "--burn-in s after arming), ends (airborne rows from --phase-margin s after take-off "
                             "to --phase-margin s before touchdown, read from the flight) or cruise (from the end "
                             "of the climb to the final descent); docs/protocol.md")
    parser.add_argument("--phase-margin", type=float, metavar="SECONDS", dest="phase_margin",
                        help=f"margin of --phases ends/cruise at both ends (default {DEFAULT_PHASE_MARGIN_S:g} s)")
    parser.add_argument("--hourly-rate", type=float, metavar="PER_HOUR", dest="hourly_rate",
                        help="with too few validation flights for --alpha: at most this many false alarms per "
                             "flight-hour, calibrated on 60 s windows of the validation flights (default 1; 0: "
                             "the largest validation score)")


def protocol_options(protocol, args: argparse.Namespace):
    """The run's protocol with ``--alpha``, ``--burn-in`` and ``--threshold`` applied."""
    import dataclasses

    from scart_bench.benchmark.protocol import ProtocolError
    from scart_bench.errors import RunError

    option = None
    try:
        if getattr(args, "alpha", None) is not None:
            option = f"--alpha {args.alpha:g}"
            protocol = dataclasses.replace(
                protocol, flight_rule=dataclasses.replace(protocol.flight_rule, kind="conformal", alpha=args.alpha),
                row_rule=dataclasses.replace(protocol.row_rule, kind="conformal", alpha=args.alpha))
        if getattr(args, "burn_in", None) is not None:
            option = f"--burn-in {args.burn_in:g}"
            protocol = dataclasses.replace(protocol, burn_in_s=args.burn_in)
        if getattr(args, "phases", None) is not None:
            option = f"--phases {args.phases}"
            protocol = dataclasses.replace(protocol, phases=args.phases)
        if getattr(args, "phase_margin", None) is not None:
            option = f"--phase-margin {args.phase_margin:g}"
            protocol = dataclasses.replace(protocol, phase_margin_s=args.phase_margin)
        if getattr(args, "hourly_rate", None) is not None:
            option = f"--hourly-rate {args.hourly_rate:g}"
            protocol = dataclasses.replace(protocol, hourly_rate=args.hourly_rate)
        if getattr(args, "threshold", None) is not None:
            option = f"--threshold {args.threshold}"
            protocol = dataclasses.replace(protocol, alarm_rule=args.threshold)
    except ProtocolError as exc:  # the option whose value was refused, with the protocol's reason
        raise RunError(f"{option}: {exc}") from None
    return protocol


def resume_datasets(cfg: RunConfig, folder: Path, shown: str | None = None) -> RunConfig:
    """``--resume`` without ``--dataset``: the run's own datasets, read from ``folder``'s config.json
    (``dataset.url`` or ``dataset.path``, and the train dataset of a transfer run), so that nothing is
    generated for a run made on another dataset. RunError up front when a saved dataset is gone; ``cfg``
    unchanged for a new folder or one made on this profile's own dataset (generated when missing).
    ``shown``: the run folder's name in messages (its URL; ``folder`` is then a local copy)."""
    import dataclasses

    from scart_bench.errors import RunError
    from scart_bench.jsonfile import read_json
    from scart_bench.storage import is_url, local_path

    path = folder / "config.json"
    where = f"{shown.rstrip('/')}/config.json" if shown else str(path)
    if not cfg.resume or cfg.dataset is not None or not path.is_file():
        return cfg
    config = read_json(path)

    def saved(key: str) -> tuple[str, str] | None:
        """(the dataset's URL or folder, the field it came from), None when the run has no such entry."""
        entry, run = config.get(key), config.get("run")
        if entry is None:
            return None
        if not isinstance(entry, dict):
            raise RunError(f"{where}: field {key!r} is {type(entry).__name__}; expected an object with the "
                           "dataset's path")
        given = run.get(key) if isinstance(run, dict) else None
        for value, field in ((entry.get("url"), f"{key}.url"), (given if is_url(given) else None, f"run.{key}"),
                             (entry.get("path"), f"{key}.path")):
            if value is None:
                continue
            if not isinstance(value, str) or not value or "\0" in value:
                raise RunError(f"{where}: field {field!r} is {value!r}; expected the dataset's folder or URL")
            return value, field
        return None

    def usable(found: tuple[str, str], option: str):
        from scart_bench.dataset import is_dataset

        value, field = found
        if is_url(value):
            return value
        try:
            if is_dataset(local_path(value)):
                return local_path(value)
        except OSError:  # a name too long for this file system, say: not there
            pass
        raise RunError(f"{where}: --resume without {option}: this run was made on the dataset {value!r} (field "
                       f"{field!r}), which is not there any more; pass {option} DIR|URL with that dataset")

    dataset, train = saved("dataset"), saved("train_dataset")
    if dataset is None:
        return cfg
    own = (cfg.data_root / f"{cfg.profile}-seed{cfg.seed}").resolve()
    if train is None and not is_url(dataset[0]) and local_path(dataset[0]).resolve() == own:
        return cfg  # the profile's own dataset: regenerated as before when it is missing
    changes = {"dataset": usable(dataset, "--dataset")}
    if train is not None and cfg.train_dataset is None:
        changes["train_dataset"] = usable(train, "--train-dataset")
    print(f"resume: the run's dataset {str(changes['dataset'])!r} (from {where})", file=sys.stderr)
    return dataclasses.replace(cfg, **changes)


def cmd_run(args: argparse.Namespace) -> int:
    import dataclasses

    from scart_bench.benchmark.runner import run_benchmark
    from scart_bench.errors import ScartBenchError
    from scart_bench.storage import is_url

    cfg = run_config(args)
    if is_url(cfg.out):  # a run folder at a URL: worked on in a local copy, each finished job uploaded
        with stage_folder(cfg.out) as staged:
            def upload(detector: str) -> None:
                try:
                    staged.sync()
                except (ScartBenchError, OSError) as exc:  # kept locally, uploaded at the end
                    print(f"note: job {detector} not uploaded yet ({exc}); retried at the end", file=sys.stderr)

            local_cfg = resume_datasets(dataclasses.replace(cfg, out=staged.path), staged.path, str(cfg.out))
            outcome = run_benchmark(local_cfg, on_job_done=upload)
            print_tables(outcome.path, outcome.metrics, shown=str(cfg.out), wide=args.wide)
    else:
        remove_stale_temp()
        outcome = run_benchmark(resume_datasets(cfg, cfg.out_path))
        print_tables(outcome.path, outcome.metrics, wide=args.wide)
    failed = outcome.metrics[outcome.metrics["status"].isin(("ERROR", "TIMEOUT"))]
    return name_failed("run", failed, "did not finish OK",
                       "everything else is written (rerun with --resume to run only those again)")


def register(sub) -> None:
    r = sub.add_parser("run", help="train and score detectors on a dataset; print and save the tables")
    r.add_argument("--wide", action="store_true", help="print every column of the paper's table (metrics.md's), "
                   "not the terminal's seven")
    r.add_argument("--config", type=Path, metavar="FILE",
                   help="a run file (TOML: detectors, params, profile or dataset, seed, protocol, ...) or a run "
                        "folder's config.json; the options below override it")
    r.add_argument("--detectors", metavar="all|zoo|NAME,...",
                   help="detectors to run: 'all' (default: the paper's eight and any plugins), 'zoo' (the zoo's "
                        "built-ins: `scart-bench detectors`) or a comma-separated list of names and tags")
    r.add_argument("--param", action="append", metavar="DETECTOR.KEY=VALUE",
                   help="a detector parameter, e.g. goad.n_trans=64 or telemanom.epochs=5 (repeatable); "
                        "VALUE is a TOML literal (64, 0.5, true, [32, 32], \"cpu\")")
    r.add_argument("--profile", choices=PROFILES,
                   help="dataset size profile (default quick); sets the default dataset, run folder and timeout")
    r.add_argument("--dataset", metavar="DIR|URL",
                   help="an existing dataset folder or fsspec URL (s3://bucket/prefix: read from a local copy, and by "
                        "dask workers from the URL) (default: data/datasets/<profile>-seed<N>, generated when missing)")
    r.add_argument("--train-dataset", metavar="DIR|URL", dest="train_dataset",
                   help="train and calibrate on this dataset's train and validation flights, test on --dataset "
                        "(every normal flight of it and its attacked flights), the columns matched by meaning "
                        "(docs/own_logs.md, 'Train on simulation, test on your flights')")
    r.add_argument("--calibrate-on", choices=("train-dataset", "dataset"), dest="calibrate_on",
                   help="a transfer run's calibration flights: train-dataset (default: its validation flights) or "
                        "dataset (--dataset's normal flights of split validation: a few of your own flights set the "
                        "thresholds and are not tested; docs/sim_to_real.md)")
    r.add_argument("--out", metavar="DIR|URL", help="run folder (default runs/<profile>-seed<N>), or an fsspec URL "
                   "(worked on in a local copy; each finished job is uploaded as it finishes, the rest at the end, "
                   "also after a failure, so --resume works even after a kill)")
    r.add_argument("--resume", action="store_true",
                   help="keep jobs that finished OK with the same parameters; run only the others (without "
                        "--dataset: the dataset the run folder's config.json names)")
    r.add_argument("--executor", choices=("local", "dask"),
                   help="local worker processes (default) or dask.distributed")
    r.add_argument("--scheduler", metavar="ADDRESS",
                   help="dask scheduler address, e.g. tcp://host:8786 (default: a LocalCluster with --jobs workers)")
    r.add_argument("--jobs", type=int, metavar="N", help="jobs run in parallel (default 1)")
    r.add_argument("--score-shards", type=int, metavar="N", dest="score_shards",
                   help="fit each detector once, then score its flights in N parallel jobs (slices of about equal "
                        "rows) on the executor and merge them: same scores and metrics as 1 (default 1); for "
                        "large datasets, where scoring is the long pole (docs/scaling.md)")
    r.add_argument("--timeout", type=float, metavar="SECONDS",
                   help="per-job limit; a job past it is killed and reported TIMEOUT "
                        "(default 1800 quick, 7200 standard, 21600 paper)")
    r.add_argument("--seed", type=int, help="dataset and detector seed (default 0)")
    r.add_argument("--plugin", action="append", metavar="SPEC",
                   help="load a detector from module:Class or path/to/file.py:Class (repeatable)")
    r.add_argument("--features", action="append", metavar="GLOB,...",
                   help="use only these columns as features, e.g. 'vehicle_gps_position.*' (repeatable; default: "
                        "the feature rule: every topic.field column in all training flights that is not a "
                        "timestamp, counter, id, reset counter or control/state flag (armed, mode, mission item) and "
                        "not constant)")
    r.add_argument("--exclude", action="append", metavar="GLOB,...",
                   help="drop these columns from the features, e.g. 'battery_status.*' (repeatable)")
    r.add_argument("--columns", choices=("auto", "logged", "meaning"),
                   help="how a run on one dataset reads its flights: logged (each flight's own topic.field "
                        "columns), meaning (the quantities of the scenarios' meaning table, shared by firmware "
                        "builds that log different fields) or auto (default: by meaning when the flights log "
                        "different columns and no --features/--exclude is given); docs/own_logs.md")
    r.add_argument("--device", choices=("auto", "cpu", "cuda"),
                   help="torch device of the detectors that take one (deepsvdd, rdp, rca, goad, neutral, "
                        "telemanom): auto (default: cuda when available, else cpu), cpu or cuda")
    r.add_argument("--trust-plugins", action="store_true", dest="trust_plugins",
                   help="also load the plugins a --config file names (by default only --plugin options are "
                        "imported: a run file is data)")
    r.add_argument("--alpha", type=float, metavar="RATE",
                   help="target per-flight false-alarm rate of every detector's threshold (default 0.05): the "
                        "conformal order statistic of the validation flights' scores")
    r.add_argument("--burn-in", type=float, metavar="SECONDS", dest="burn_in",
                   help="seconds after arming in which rows neither calibrate nor alarm (default 8)")
    add_phase_options(r)
    r.add_argument("--threshold", choices=("calibrated", "own"),
                   help="calibrated (default): score > the calibrated threshold; own: each detector's own alarm "
                        "rule where it has one (Telemanom's dynamic threshold, Statistical's vote)")
    r.set_defaults(func=cmd_run)
