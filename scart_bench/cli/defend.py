"""``scart-bench defend``: fly a grid's attacked flights and as many normal flights with a run's detector and a
response in the loop, each beside its undefended twin, and write the defense table (benchmark.defense)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from scart_bench.cli.common import RESPONSES, UsageError, log


def cmd_defend(args: argparse.Namespace) -> int:
    import numpy as np

    from scart_bench.benchmark.defense import (
        BLOCK_ROWS,
        defend,
        from_run,
        require_link_rate,
        write_defense,
    )
    from scart_bench.generator.attacks import attack_seeds, grid_path
    from scart_bench.generator.defense import Response
    from scart_bench.generator.profiles import get_profile
    from scart_bench.generator.scart.grid import load_configurations

    if args.alarms < 1:
        raise UsageError(f"--alarms {args.alarms}: expected a whole number >= 1")
    if args.grid is not None and args.profile is not None:
        raise UsageError("--grid and --profile: give one (the profile's grid is its scenario grid)")
    profile = get_profile(args.profile or "quick")
    grid = args.grid or grid_path(profile.scenario_grid)
    configs = load_configurations(grid)
    if args.flights is not None:
        if args.flights < 1:
            raise UsageError(f"--flights {args.flights}: expected a whole number >= 1")
        configs = configs[: args.flights]
    responses = [Response(r, alarms=args.alarms) for r in args.response]
    detectors = [from_run(args.run, name, plugins=args.plugin, log=log) for name in args.detector]
    for det in detectors:  # before any flight is flown: a detector slower than the link is refused
        rate = require_link_rate(det.name, det.detector, block_rows=BLOCK_ROWS)
        log(f"defend: {det.name} scores {rate:.0f} rows/s in blocks of {BLOCK_ROWS} rows")
    seeds = attack_seeds(args.seed, len(configs))
    normal = [
        int(s) for s in np.random.SeedSequence(int(args.seed), spawn_key=(32,)).generate_state(len(configs))
    ]
    log(
        f"defend: {len(configs)} attacked and {len(normal)} normal flights x {len(detectors)} detector(s) x "
        f"{len(responses)} response(s), grid {grid}"
    )
    t0 = time.perf_counter()
    run = defend(
        detectors,
        responses,
        configs,
        seeds,
        normal,
        flight_config=profile.flight_config(),
        batch_size=args.batch_size,
        say=log,
    )
    wall = time.perf_counter() - t0
    times = ", ".join(f"{k} {v:.1f}" for k, v in run.wall_s.items())
    flown = run.wall_s.get("undefended_s", 0.0)
    if flown > 0:
        extra = run.wall_s.get("scoring_s", 0.0) + run.wall_s.get("defended_s", 0.0)
        per = extra / max(len(detectors) * len(responses), 1)
        times += (f"; one detector x response's defended grid (its undefended flights, their scoring and the alarmed "
                  f"flights flown again) in {(flown + per) / flown:.2f}x the undefended grid's time")
    out = Path(args.out)
    text = write_defense(run, out, f"Run {args.run}, grid {grid}; wall {wall:.1f} s ({times}).")
    print(text)
    log(
        f"defend: wrote {out / 'defense.csv'}, {out / 'defense.md'}, {out / 'defense_flights.csv'} in {wall:.1f} s"
    )
    return 0


def register(sub) -> None:
    s = sub.add_parser(
        "defend", help="fly a grid with a run's detector and a response in the loop: the defense table"
    )
    s.add_argument("--run", required=True, type=Path, metavar="RUN_FOLDER", help="a finished benchmark run")
    s.add_argument(
        "--detector",
        required=True,
        action="append",
        metavar="NAME",
        help="a detector of the run (repeat for several)",
    )
    s.add_argument(
        "--response",
        required=True,
        action="append",
        choices=RESPONSES,
        help="what the flight controller does on the alarm (repeat for several)",
    )
    s.add_argument(
        "--alarms", type=int, default=1, metavar="N", help="alarm rows before the response (default 1)"
    )
    s.add_argument("--grid", type=Path, metavar="FILE", help="scenario grid of the attacked flights")
    s.add_argument("--profile", help="take the profile's grid and flight config (default quick)")
    s.add_argument(
        "--flights", type=int, metavar="N", help="the grid's first N configurations (and N normal flights)"
    )
    s.add_argument("--seed", type=int, default=0, help="seed of the flights (default 0)")
    s.add_argument(
        "--batch-size", type=int, default=64, metavar="N", help="flights flown at once (default 64)"
    )
    s.add_argument("--plugin", action="append", default=[], metavar="SPEC", help="load a detector plugin")
    s.add_argument("--out", required=True, type=Path, metavar="DIR", help="where the defense table goes")
    s.set_defaults(func=cmd_defend)
