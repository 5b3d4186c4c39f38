"""``scart-bench generate``: fly normal and attacked flights and write a dataset."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from scart_bench.cli.common import (
    LAYOUT_HELP,
    LAYOUTS,
    UsageError,
    check_seed,
    remove_stale_temp,
    removed_on_failure,
)
from scart_bench.generator.profiles import PROFILES

#: Most local dask workers (--jobs): each is a process holding a batch of flights.
MAX_JOBS = 1024


def cmd_generate(args: argparse.Namespace) -> int:
    from scart_bench.generator.generate import MAX_BATCH_SIZE, MAX_FLIGHTS, generate_dataset

    if getattr(args, "physics", "builtin") == "jmavsim":
        return _generate_jmavsim(args)
    if getattr(args, "sim", None) or getattr(args, "real_time", False):
        raise UsageError("--sim and --real-time are for --physics jmavsim (the built-in engine has its own physics)")
    profile_file = None
    if getattr(args, "like", None):
        return _generate_like(args)
    if is_profile_file(args.profile):
        from scart_bench.generator.like.profile_file import read_profile

        profile_file = read_profile(args.profile)  # checked before anything is written
        args.profile = profile_file.profile.name
    elif args.profile not in PROFILES:
        raise UsageError(f"--profile {args.profile!r}: expected one of {', '.join(PROFILES)}, or a profile TOML file "
                         "(docs/like.md)")
    if args.flights is not None and not 1 <= args.flights <= MAX_FLIGHTS:
        raise UsageError(f"--flights {args.flights}: expected 1 to {MAX_FLIGHTS:,} normal flights (the plan holds a "
                         "seed and a split per flight, and ten million flights are terabytes on disk)")
    check_seed(args.seed)
    from scart_bench.generator.params import GPS_ACCURACY

    profile = PROFILES[args.profile] if profile_file is None else profile_file.profile
    if args.gps_accuracy is not None:
        if args.gps_accuracy not in GPS_ACCURACY:
            raise UsageError(f"--gps-accuracy {args.gps_accuracy!r}: expected one of {', '.join(GPS_ACCURACY)}")
        profile = dataclasses.replace(profile, gps_accuracy=args.gps_accuracy)
    if args.sensor_profile is not None:
        from scart_bench.generator.params import SENSOR_PROFILES

        if args.sensor_profile not in SENSOR_PROFILES:
            raise UsageError(f"--sensor-profile {args.sensor_profile!r}: expected one of {', '.join(SENSOR_PROFILES)}")
        profile = dataclasses.replace(profile, sensor_profile=args.sensor_profile)
    if args.timing is not None:
        from scart_bench.generator.telemetry.timing import TIMINGS

        if args.timing not in TIMINGS:
            raise UsageError(f"--timing {args.timing!r}: expected one of {', '.join(TIMINGS)}")
        profile = dataclasses.replace(profile, timing=args.timing)
    if args.batch_size is not None and not 1 <= args.batch_size <= MAX_BATCH_SIZE:
        raise UsageError(f"--batch-size {args.batch_size}: expected 1 to {MAX_BATCH_SIZE:,} flights (a batch is "
                         "simulated in memory at once)")
    if args.scheduler and args.executor != "dask":
        raise UsageError("--scheduler needs --executor dask")
    if not 1 <= args.jobs <= MAX_JOBS:
        raise UsageError(f"--jobs {args.jobs}: expected 1 to {MAX_JOBS} local dask workers")
    remove_stale_temp()  # the staging folders of killed commands (a generate to a URL writes in one)
    config = profile.flight_config() if profile_file is None else _overridden(profile_file.config, args)
    if args.missions:  # every file read and checked before anything is written
        from scart_bench.generator.flight_software.mission_files import read_missions, with_missions

        config = with_missions(config, read_missions(args.missions))
    from scart_bench.progress import Progress
    from scart_bench.storage import is_url, local_path

    out = args.out if is_url(args.out) else local_path(args.out)
    with removed_on_failure(out), Progress("generate", "flights") as progress:  # nothing half-written is left
        generate_dataset(args.profile, out, seed=args.seed, fmt=args.format, n_normal=args.flights,
                         overwrite=args.overwrite, with_attacks=not args.normal_only, log=progress.note,
                         scenarios=args.scenarios, config=config, layout=args.layout,
                         uorb=args.uorb or None, batch_size=args.batch_size, executor=args.executor,
                         scheduler=args.scheduler, jobs=args.jobs, progress=progress)
    print(f"dataset written to {out}")
    return 0


def is_profile_file(value: str) -> bool:
    """``--profile`` names a TOML file rather than a built-in profile."""
    return value not in PROFILES and (value.lower().endswith(".toml") or Path(value).is_file())


def _overridden(config, args: argparse.Namespace):
    """A profile file's FlightConfig with the command line's --gps-accuracy / --sensor-profile / --timing on top."""
    from scart_bench.generator.params import with_gps_accuracy, with_sensor_profile

    if args.gps_accuracy is not None:
        config = with_gps_accuracy(config, args.gps_accuracy)
    if args.sensor_profile is not None:
        config = with_sensor_profile(config, args.sensor_profile)
    if args.timing is not None:
        config = dataclasses.replace(config, timing=args.timing)
    return config


def _generate_like(args: argparse.Namespace) -> int:
    """``generate --like LOG...``: fit a profile to the logs, write it (profile.toml and missions/) and fly
    ``--flights`` flights of it into ``--out`` (docs/like.md)."""
    import shutil
    import tempfile

    from scart_bench.generator.generate import MAX_FLIGHTS, generate_dataset
    from scart_bench.generator.like.profile_file import read_profile
    from scart_bench.generator.like.write import MISSION_DIR, PROFILE_NAME, fit_to_folder
    from scart_bench.generator.logs.importers import LOG_SUFFIXES
    from scart_bench.storage import is_url, local_path

    if args.missions or args.gps_accuracy or args.sensor_profile or args.timing or is_profile_file(args.profile):
        raise UsageError("--like fits the missions, sensors, GPS accuracy and timing to the logs: leave out --missions, "
                         "--gps-accuracy, --sensor-profile, --timing and a profile file (edit the written profile.toml "
                         "and fly it with --profile FILE.toml)")
    if args.profile not in PROFILES:
        raise UsageError(f"--profile {args.profile!r}: expected one of {', '.join(PROFILES)} (the base of the fitted profile)")
    if is_url(args.out):
        raise UsageError("--like writes a local folder (the profile and missions beside the dataset): give a path")
    n = 60 if args.flights is None else args.flights
    if not 1 <= n <= MAX_FLIGHTS:
        raise UsageError(f"--flights {n}: expected 1 to {MAX_FLIGHTS:,} normal flights")
    check_seed(args.seed)
    for log in args.like:
        p = Path(log)
        if not p.exists():
            raise UsageError(f"--like {log}: no such file or folder (expected a flight log: {', '.join(LOG_SUFFIXES)}, "
                             ".csv, .parquet or a scart-bench flight folder)")
    out = local_path(args.out)
    if out.exists() and any(out.iterdir()) and not args.overwrite:
        raise UsageError(f"--out {out}: exists and is not empty (use a new folder, or --overwrite)")
    remove_stale_temp()
    from scart_bench.progress import Progress

    with tempfile.TemporaryDirectory(prefix="scart-like-") as tmp, removed_on_failure(out):
        path = fit_to_folder(list(args.like), tmp, base=args.profile, say=lambda line: print(line, flush=True))
        fitted = read_profile(path)  # the dataset is flown from the file as written
        with Progress("generate", "flights") as progress:
            generate_dataset(fitted.profile.name, out, seed=args.seed, fmt=args.format, n_normal=n,
                             overwrite=args.overwrite, with_attacks=not args.normal_only, log=progress.note,
                             scenarios=args.scenarios, config=fitted.config, layout=args.layout,
                             uorb=args.uorb or None, batch_size=args.batch_size, executor=args.executor,
                             scheduler=args.scheduler, jobs=args.jobs, progress=progress)
        shutil.copy2(path, out / PROFILE_NAME)
        shutil.copytree(Path(tmp) / MISSION_DIR, out / MISSION_DIR, dirs_exist_ok=True)
    print(f"profile written to {out / PROFILE_NAME} (missions in {out / MISSION_DIR}); "
          f"fly it again with: scart-bench generate --profile {out / PROFILE_NAME} --out DIR")
    print(f"dataset written to {out}")
    return 0


def _generate_jmavsim(args: argparse.Namespace) -> int:
    """``generate --physics jmavsim``: the flights flown in jMAVSim through the simulator bridge (docs/jmavsim.md)."""
    from scart_bench.generator.hil.dataset import attack_configs, generate_jmavsim
    from scart_bench.storage import local_path

    if args.executor != "local" or args.uorb or args.layout:
        raise UsageError("--physics jmavsim flies one jMAVSim flight at a time: --executor dask, --uorb "
                         "and --layout are for the built-in engine")
    # jMAVSim flies the square (or --missions) with its own sensors and timing: a profile's mission mix, sensors,
    # GPS accuracy and timing would otherwise be dropped without a word
    given = [flag for flag, on in (("--profile", args.profile != "quick"),  # a profile TOML too
                                   ("--like", bool(getattr(args, "like", None))),
                                   ("--gps-accuracy", args.gps_accuracy is not None),
                                   ("--sensor-profile", args.sensor_profile is not None),
                                   ("--timing", args.timing is not None)) if on]
    if given:
        raise UsageError(f"--physics jmavsim flies the square or --missions FILE... with jMAVSim's sensors and clock: "
                         f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for the built-in engine")
    check_seed(args.seed)
    mission = None
    if args.missions:  # every file read and checked before anything is flown or written
        from scart_bench.generator.engine.simulate import FlightConfig
        from scart_bench.generator.flight_software.mission_files import read_missions, with_missions

        mission = with_missions(FlightConfig(), read_missions(args.missions)).mission
    n = 8 if args.flights is None else args.flights
    if not 1 <= n <= 1000:
        raise UsageError(f"--flights {n}: expected 1 to 1000 jMAVSim flights")
    configs = [] if args.normal_only else attack_configs(args.scenarios, n)
    csv_configs = [] if args.normal_only else attack_configs(args.scenarios, n, link_only=True)
    out = local_path(args.out)
    with removed_on_failure(out):
        generate_jmavsim(out, args.jmavsim, seed=args.seed, n_normal=n, configs=configs, fmt=args.format,
                         overwrite=args.overwrite, log=lambda msg: print(msg, flush=True), csv_configs=csv_configs,
                         sim=args.sim, lockstep=not args.real_time, mission=mission)
    print(f"dataset written to {out}")
    return 0


def register(sub) -> None:
    g = sub.add_parser("generate", help="fly normal and attacked flights and write a dataset")
    g.add_argument("--profile", default="quick",
                   help=f"{' | '.join(PROFILES)}: flight counts and attack grid (default quick); or a profile TOML file "
                   "(FILE.toml, e.g. the profile.toml --like wrote: its base profile, sensors, mission, missions; docs/like.md)")
    g.add_argument("--like", nargs="+", default=None, metavar="LOG",
                   help="fit the flights to these logs (every format import reads): missions recovered from each log, "
                   "take-off and landing, wind, sensor noise, GPS accuracy; writes --out/profile.toml and "
                   "--out/missions/ beside the dataset of --flights flights (default 60; docs/like.md)")
    g.add_argument("--out", required=True, help="dataset folder (new, empty, or an existing dataset with --overwrite), or an fsspec URL "
                   "such as s3://bucket/datasets/quick (uploaded with the manifest last; docs/scaling.md)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--format", choices=("parquet", "csv"), default="parquet")
    g.add_argument("--layout", choices=LAYOUTS, default=None, help=LAYOUT_HELP)
    g.add_argument("--flights", type=int, default=None, help="number of normal flights (default: the profile's)")
    g.add_argument("--normal-only", action="store_true", help="only normal flights, no attacks")
    g.add_argument("--scenarios", default=None, help="a scenario, grid or sweep file (TOML) for the attacked "
                   "flights, instead of the profile's grid")
    g.add_argument("--gps-accuracy", default=None, help="simulator | real_receiver: the GPS accuracy of the "
                   "flights (default: the profile's; see docs/realism.md)")
    g.add_argument("--sensor-profile", default=None, help="gazebo | rflymad: magnetometer and barometer noise "
                   "(gazebo: PX4 Gazebo SITL and hardware; rflymad: RflySim SIL, 3x quieter; default: the "
                   "profile's; see docs/realism.md)")
    g.add_argument("--timing", default=None, help="ideal | realistic: message timing of the written flights "
                   "(realistic: jitter, drops, late messages, GPS after its fix; default: the profile's)")
    g.add_argument("--uorb", action="store_true", help="also write each flight's uORB view (sensors/uorb/: PX4 "
                   "topic names, fields and units, to score real ULogs; see docs/own_logs.md)")
    g.add_argument("--executor", choices=("local", "dask"), default="local",
                   help="local (default) or dask: every batch of flights is a shard flown and written by a dask "
                   "worker, the manifest is committed here; same bytes as local (docs/scaling.md)")
    g.add_argument("--scheduler", default=None, help="with --executor dask: a running scheduler's address "
                   "(tcp://host:8786); default a local cluster of --jobs workers")
    g.add_argument("--jobs", type=int, default=2, help="with --executor dask and no --scheduler: local workers (default 2)")
    g.add_argument("--batch-size", type=int, default=None, help="flights flown together, and one dask shard "
                   "(default: the profile's, 256); the flights depend on it, so compare datasets made with the same")
    g.add_argument("--missions", nargs="+", default=None, metavar="FILE",
                   help="fly these mission files instead of the square: QGroundControl .plan or MAVLink WPL "
                   "('QGC WPL 110' .waypoints/.txt); the flight with seed s flies file s mod N (docs/missions.md)")
    g.add_argument("--overwrite", action="store_true", help="replace an existing dataset in --out")
    g.add_argument("--physics", choices=("builtin", "jmavsim"), default="builtin",
                   help="builtin (default): the generator's engine; jmavsim: the flight software flies jMAVSim "
                   "through PX4's simulator MAVLink API, headless and in lockstep (--flights normal flights and as many "
                   "attacked flights per mode; docs/jmavsim.md)")
    g.add_argument("--jmavsim", default=None, metavar="PATH", help="with --physics jmavsim: jmavsim_run.jar or "
                   "the jMAVSim checkout it was built in (default $SCART_JMAVSIM)")
    g.add_argument("--sim", default=None, metavar="ADDR", help="with --physics jmavsim: fly against a simulator "
                   "already running at udp:HOST:PORT or tcp:HOST:PORT (udp-listen:/tcp-listen: wait for it) instead of "
                   "starting jMAVSim: jMAVSim, or Gazebo classic / AirSim in PX4 mode elsewhere (docs/jmavsim.md)")
    g.add_argument("--real-time", action="store_true", help="with --physics jmavsim: the started jMAVSim flies in "
                   "real time instead of lockstep (a flight that falls 50 ms behind its clock ends with an error)")
    g.set_defaults(func=cmd_generate)
