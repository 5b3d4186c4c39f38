"""``scart-bench generate``, ``import`` and ``attack``: datasets of normal and attacked flights."""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
from pathlib import Path

from scart_bench.benchmark.errors import UsageError
from scart_bench.generator.profiles import PROFILES

#: generator.dataset.LAYOUTS, spelled out here so that the command line starts without pandas
LAYOUTS = ("compact", "paper")
LAYOUT_HELP = ("compact (one Parquet file per view per flight; the default for Parquet) | paper (the paper's "
               "per-topic and combined files; the default for CSV)")


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def check_seed(seed: int) -> int:
    """``--seed``: numpy's seed sequences take any non-negative integer, but 32 bits are what every
    consumer (torch included) accepts; refuse the rest up front, naming the option."""
    if not 0 <= seed < 2**32:
        raise UsageError(f"--seed {seed}: expected an integer in 0..{2**32 - 1}")
    return seed


def cmd_generate(args: argparse.Namespace) -> int:
    from scart_bench.generator.generate import generate_dataset

    if args.profile not in PROFILES:
        raise UsageError(f"--profile {args.profile!r}: expected one of {', '.join(PROFILES)}")
    if args.flights is not None and args.flights < 1:
        raise UsageError(f"--flights must be at least 1, got {args.flights}")
    check_seed(args.seed)
    from scart_bench.generator.params import GPS_ACCURACY

    profile = PROFILES[args.profile]
    if args.gps_accuracy is not None:
        if args.gps_accuracy not in GPS_ACCURACY:
            raise UsageError(f"--gps-accuracy {args.gps_accuracy!r}: expected one of {', '.join(GPS_ACCURACY)}")
        profile = dataclasses.replace(profile, gps_accuracy=args.gps_accuracy)
    if args.timing is not None:
        from scart_bench.generator.timing import TIMINGS

        if args.timing not in TIMINGS:
            raise UsageError(f"--timing {args.timing!r}: expected one of {', '.join(TIMINGS)}")
        profile = dataclasses.replace(profile, timing=args.timing)
    out = Path(args.out)
    existed = out.exists()
    try:
        generate_dataset(args.profile, out, seed=args.seed, fmt=args.format, n_normal=args.flights,
                         overwrite=args.overwrite, with_attacks=not args.normal_only, log=_log,
                         scenarios=args.scenarios, config=profile.flight_config(), layout=args.layout,
                         uorb=args.uorb or None)
    except BaseException:
        if not existed:
            shutil.rmtree(out, ignore_errors=True)  # nothing half-written is left behind
        raise
    print(f"dataset written to {out}")
    return 0


def _topics(text: str | None) -> list[str] | None:
    return [t.strip() for t in text.split(",") if t.strip()] if text else None


def cmd_attack(args: argparse.Namespace) -> int:
    from scart_bench.generator.offline import attack_dataset, attack_file

    if args.dataset is not None:
        if args.input or args.out or args.topics or args.overwrite:
            raise UsageError("--dataset adds copies to that dataset: --input, --out, --topics and --overwrite "
                             "belong to the single-log form")
        sources = tuple(s.strip() for s in args.sources.split(",") if s.strip())
        ids = attack_dataset(args.dataset, args.scenario, sources=sources, seed=args.seed, say=_log)
        print(f"{len(ids)} attacked cop{'y' if len(ids) == 1 else 'ies'} added to {args.dataset}")
        return 0
    if not args.input or not args.out:
        raise UsageError("give --input LOG --out DIR (one log), or --dataset DATASET (its test flights)")
    out = Path(args.out)
    existed = out.exists()
    try:
        attack_file(args.input, args.scenario, out, fmt=args.format, seed=args.seed, overwrite=args.overwrite,
                    topics=_topics(args.topics), allow_corrupt=args.allow_corrupt, layout=args.layout)
    except BaseException:
        if not existed:
            shutil.rmtree(out, ignore_errors=True)
        raise
    print(f"attacked copy written to {out}")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from scart_bench.generator.offline import import_logs

    if (args.start is not None and args.start < 0) or (args.end is not None and args.end <= (args.start or 0.0)):
        raise UsageError(f"--start {args.start} / --end {args.end}: expected 0 <= start < end (seconds)")
    ids = import_logs(args.logs, args.out, split=args.split, topics=_topics(args.topics), start_s=args.start,
                      end_s=args.end, seed=args.seed, fmt=args.format, allow_corrupt=args.allow_corrupt, say=_log,
                      layout=args.layout)
    print(f"{len(ids)} flight{'' if len(ids) == 1 else 's'} added to {args.out}: {', '.join(ids)}")
    return 0


def register(sub) -> None:
    g = sub.add_parser("generate", help="fly normal and attacked flights and write a dataset")
    g.add_argument("--profile", default="quick",
                   help=f"{' | '.join(PROFILES)}: flight counts and attack grid (default quick)")
    g.add_argument("--out", required=True, help="dataset folder (new, empty, or an existing dataset with --overwrite)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--format", choices=("parquet", "csv"), default="parquet")
    g.add_argument("--layout", choices=LAYOUTS, default=None, help=LAYOUT_HELP)
    g.add_argument("--flights", type=int, default=None, help="number of normal flights (default: the profile's)")
    g.add_argument("--normal-only", action="store_true", help="only normal flights, no attacks")
    g.add_argument("--scenarios", default=None, help="a scenario, grid or sweep file (TOML) for the attacked "
                   "flights, instead of the profile's grid")
    g.add_argument("--gps-accuracy", default=None, help="simulator | real_receiver: the GPS accuracy of the "
                   "flights (default: the profile's; see docs/realism.md)")
    g.add_argument("--timing", default=None, help="ideal | realistic: message timing of the written flights "
                   "(realistic: jitter, drops, late messages, GPS after its fix; default: the profile's)")
    g.add_argument("--uorb", action="store_true", help="also write each flight's uORB view (sensors/uorb/: PX4 "
                   "topic names, fields and units, to score real ULogs; see docs/own_logs.md)")
    g.add_argument("--overwrite", action="store_true", help="replace an existing dataset in --out")
    g.set_defaults(func=cmd_generate)

    i = sub.add_parser("import", help="add your own logs (ULog, CSV, Parquet, flight folders) to a dataset as "
                       "normal flights")
    i.add_argument("logs", nargs="+", metavar="LOG", help="log files or flight folders; flight ids come from "
                   "their names (log-<name>, plus -<start>s-<end>s when trimmed)")
    i.add_argument("--out", required=True, metavar="DATASET", help="dataset folder: created, or added to atomically")
    i.add_argument("--split", default="train", choices=("train", "validation", "test", "csv_source", "auto"),
                   help="split of the imported flights (auto: train/validation/test/csv_source by --seed)")
    i.add_argument("--topics", default=None, help="comma-separated topics to keep (default: all)")
    i.add_argument("--start", type=float, default=None, metavar="S", help="keep from S seconds after the start "
                   "of logging (becomes the flight's time zero)")
    i.add_argument("--end", type=float, default=None, metavar="S", help="keep up to S seconds after the start "
                   "of logging (e.g. before an injected fault or a crash)")
    i.add_argument("--seed", type=int, default=0, help="seed of --split auto (default 0)")
    i.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="format of a new dataset")
    i.add_argument("--layout", choices=LAYOUTS, default=None, help=LAYOUT_HELP + "; of a new dataset")
    i.add_argument("--allow-corrupt", action="store_true", help="use the readable part of a corrupt or "
                   "truncated ULog (with a warning saying how much was read)")
    i.set_defaults(func=cmd_import)

    a = sub.add_parser("attack", help="csv mode: attacked copies of your own log, or of a dataset's test flights")
    a.add_argument("--input", help="a CSV with a timestamp column, a PX4 ULog, a Parquet file or a dataset "
                   "flight folder (with --out)")
    a.add_argument("--scenario", required=True, help="a scenario file or a grid file (TOML)")
    a.add_argument("--out", help="output dataset folder (with --input)")
    a.add_argument("--dataset", type=Path, metavar="DATASET", help="add labelled attacked copies of this "
                   "dataset's normal flights to it (ids csv-<source>-<scenario>)")
    a.add_argument("--sources", default="test", metavar="test|csv_source",
                   help="with --dataset: the splits whose normal flights are attacked (default test; "
                   "comma-separated for several)")
    a.add_argument("--format", choices=("parquet", "csv"), default="parquet")
    a.add_argument("--layout", choices=LAYOUTS, default=None, help=LAYOUT_HELP + " (with --out)")
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--topics", default=None, help="comma-separated topics to load from the input (default: all)")
    a.add_argument("--allow-corrupt", action="store_true", help="use the readable part of a corrupt or "
                   "truncated ULog")
    a.add_argument("--overwrite", action="store_true")
    a.set_defaults(func=cmd_attack)
