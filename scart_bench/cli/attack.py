"""``scart-bench attack``: csv mode, labelled attacked copies of your own log or of a dataset's normal flights."""

from __future__ import annotations

import argparse

from scart_bench.cli.common import (
    LAYOUT_HELP,
    LAYOUTS,
    UsageError,
    check_seed,
    removed_on_failure,
    staged_dataset,
    topic_list,
)


def cmd_attack(args: argparse.Namespace) -> int:
    from scart_bench.generator.logs.offline import attack_dataset, attack_file

    check_seed(args.seed)
    if args.dataset is not None:
        if args.input or args.out or args.topics or args.overwrite:
            raise UsageError("--dataset adds copies to that dataset: --input, --out, --topics and --overwrite "
                             "belong to the single-log form")
        sources = tuple(s.strip() for s in args.sources.split(",") if s.strip())
        from scart_bench.progress import Progress

        with staged_dataset(args.dataset) as dataset, Progress("attack", "flights") as progress:  # URL: a local copy
            ids = attack_dataset(dataset, args.scenario, sources=sources, seed=args.seed, say=progress.note,
                                 progress=progress)
        print(f"{len(ids)} attacked cop{'y' if len(ids) == 1 else 'ies'} added to {args.dataset}")
        return 0
    if not args.input or not args.out:
        raise UsageError("give --input LOG --out DIR (one log), or --dataset DATASET (its test flights)")
    with staged_dataset(args.out, overwrite=args.overwrite) as out:  # at a URL: written in a local copy, uploaded once done
        with removed_on_failure(out):
            attack_file(args.input, args.scenario, out, fmt=args.format, seed=args.seed, overwrite=args.overwrite,
                        topics=topic_list(args.topics), allow_corrupt=args.allow_corrupt, layout=args.layout)
    print(f"attacked copy written to {out}")
    return 0


def register(sub) -> None:
    a = sub.add_parser("attack", help="csv mode: attacked copies of your own log, or of a dataset's test flights")
    a.add_argument("--input", help="a CSV with a timestamp column, a PX4 ULog, a Parquet file or a dataset "
                   "flight folder (with --out)")
    a.add_argument("--scenario", required=True, help="a scenario file or a grid file (TOML); on logs, times count "
                   "logged time (gaps left out) and data/scenarios/logs/quick.toml triggers on the flight's own phases")
    a.add_argument("--out", help="output dataset folder or fsspec URL (with --input)")
    a.add_argument("--dataset", metavar="DATASET", help="add labelled attacked copies of this "
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
