"""``scart-bench generate`` and ``scart-bench attack``: datasets of normal and attacked flights."""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
from pathlib import Path

from scart_bench.benchmark.errors import UsageError
from scart_bench.generator.profiles import PROFILES


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
    out = Path(args.out)
    existed = out.exists()
    try:
        generate_dataset(args.profile, out, seed=args.seed, fmt=args.format, n_normal=args.flights,
                         overwrite=args.overwrite, with_attacks=not args.normal_only, log=_log,
                         scenarios=args.scenarios, config=profile.flight_config())
    except BaseException:
        if not existed:
            shutil.rmtree(out, ignore_errors=True)  # nothing half-written is left behind
        raise
    print(f"dataset written to {out}")
    return 0


def cmd_attack(args: argparse.Namespace) -> int:
    from scart_bench.generator.offline import attack_file

    out = Path(args.out)
    existed = out.exists()
    try:
        attack_file(args.input, args.scenario, out, fmt=args.format, seed=args.seed, overwrite=args.overwrite,
                    topics=args.topics.split(",") if args.topics else None)
    except BaseException:
        if not existed:
            shutil.rmtree(out, ignore_errors=True)
        raise
    print(f"attacked copy written to {out}")
    return 0


def register(sub) -> None:
    g = sub.add_parser("generate", help="fly normal and attacked flights and write a dataset")
    g.add_argument("--profile", default="quick",
                   help=f"{' | '.join(PROFILES)}: flight counts and attack grid (default quick)")
    g.add_argument("--out", required=True, help="dataset folder (new, empty, or an existing dataset with --overwrite)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--format", choices=("parquet", "csv"), default="parquet")
    g.add_argument("--flights", type=int, default=None, help="number of normal flights (default: the profile's)")
    g.add_argument("--normal-only", action="store_true", help="only normal flights, no attacks")
    g.add_argument("--scenarios", default=None, help="a scenario, grid or sweep file (TOML) for the attacked "
                   "flights, instead of the profile's grid")
    g.add_argument("--gps-accuracy", default=None, help="simulator | real_receiver: the GPS accuracy of the "
                   "flights (default: the profile's; see docs/realism.md)")
    g.add_argument("--overwrite", action="store_true", help="replace an existing dataset in --out")
    g.set_defaults(func=cmd_generate)

    a = sub.add_parser("attack", help="csv mode on your own log: inject a scenario into a recorded flight")
    a.add_argument("--input", required=True, help="a CSV with a timestamp column, a PX4 ULog, a Parquet file "
                   "or a dataset flight folder")
    a.add_argument("--scenario", required=True, help="a scenario file or a grid file (TOML)")
    a.add_argument("--out", required=True, help="output dataset folder")
    a.add_argument("--format", choices=("parquet", "csv"), default="parquet")
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--topics", default=None, help="comma-separated topics to load from the input (default: all)")
    a.add_argument("--overwrite", action="store_true")
    a.set_defaults(func=cmd_attack)
