"""``scart-bench import``: your own logs (ULog, DataFlash .bin, tlog, ROS bags, CSV, Parquet, flight folders) as normal
flights of a dataset."""

from __future__ import annotations

import argparse
import math

from scart_bench.cli.common import LAYOUT_HELP, LAYOUTS, UsageError, check_seed, staged_dataset, topic_list


def cmd_import(args: argparse.Namespace) -> int:
    from scart_bench.generator.logs.offline import import_logs

    for name, value in (("--start", args.start), ("--end", args.end)):
        if value is not None and not math.isfinite(value):
            raise UsageError(f"{name} {value}: expected a finite number of seconds")
    if (args.start is not None and args.start < 0) or (args.end is not None and args.end <= (args.start or 0.0)):
        raise UsageError(f"--start {args.start} / --end {args.end}: expected 0 <= start < end (seconds)")
    check_seed(args.seed)
    from scart_bench.progress import Progress

    with staged_dataset(args.out) as out, Progress("import", "logs") as progress:  # at a URL: a local copy, uploaded
        ids = import_logs(args.logs, out, split=args.split, topics=topic_list(args.topics), start_s=args.start,
                          end_s=args.end, seed=args.seed, fmt=args.format, allow_corrupt=args.allow_corrupt,
                          say=progress.note, layout=args.layout, progress=progress)
    print(f"{len(ids)} flight{'' if len(ids) == 1 else 's'} added to {args.out}: {', '.join(ids)}")
    return 0


def register(sub) -> None:
    i = sub.add_parser("import", help="add your own logs (ULog, DataFlash .bin, tlog, ROS bag, CSV, Parquet, flight folders) to a dataset as "
                       "normal flights")
    i.add_argument("logs", nargs="+", metavar="LOG", help="log files or flight folders; flight ids come from "
                   "their names (log-<name>, plus -<start>s-<end>s when trimmed)")
    i.add_argument("--out", required=True, metavar="DATASET", help="dataset folder: created, or added to atomically; or an fsspec URL (s3://...)")
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
                   "truncated log (with a warning saying how much was read)")
    i.set_defaults(func=cmd_import)
