"""``scart-bench sitl``: a simulated PX4-like vehicle that any MAVLink tool can fly, with the SCART layer.

The engine is :mod:`scart_bench.generator.sitl.server`; this module parses the options, loads the
scenario and the defense, and calls :func:`scart_bench.generator.sitl.session.run_sitl`, which runs the
vehicle until Ctrl-C (or ``--duration`` of simulated time) and writes the recording (a program calls it
the same way, without the command line).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scart_bench.cli.common import RESPONSES, UsageError, record_folder
from scart_bench.names import check_id

DEFAULT_LISTEN = "udp:127.0.0.1:14580"


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def cmd_sitl(args: argparse.Namespace) -> int:
    from scart_bench.generator.mavlink import parse_endpoint
    from scart_bench.generator.sitl.endpoint import bind_udp

    listen = parse_endpoint(args.listen, "--listen")
    remote = parse_endpoint(args.remote, "--remote") if args.remote else None
    _check_options(args)
    sock = bind_udp(listen)  # before the slow imports: a datagram arriving meanwhile waits in the socket
    try:
        return _run(args, listen, remote, sock)
    finally:
        sock.close()


def _check_options(args: argparse.Namespace) -> None:
    if args.scenario is not None and not Path(args.scenario).is_file():
        raise UsageError(f"--scenario {args.scenario}: no such file")
    if args.duration is not None and args.duration <= 0:
        raise UsageError(f"--duration {args.duration}: expected a positive number of seconds")
    if args.speed <= 0:
        raise UsageError(f"--speed {args.speed}: expected a positive factor (1.0 = real time)")
    if len({args.detector is None, args.run is None, args.response is None}) > 1:
        raise UsageError("--detector, --run and --response go together: the detector fitted in that benchmark run "
                         "and what the flight controller does on its alarm")
    if args.alarms < 1:
        raise UsageError(f"--alarms {args.alarms}: expected a whole number >= 1")
    if args.flight_id is not None:
        check_id(args.flight_id, "--flight-id")
    if args.physics != "jmavsim" and (args.jmavsim or args.sim):
        raise UsageError("--jmavsim and --sim are for --physics jmavsim (the built-in physics needs no simulator)")
    if args.jmavsim and args.sim:
        raise UsageError("--jmavsim starts jMAVSim, --sim flies one already running: give one of them")


def _run(args: argparse.Namespace, listen, remote, sock) -> int:
    try:
        from scart_bench.generator.sitl.server import SitlServer  # noqa: F401 (pymavlink is there: said before anything runs)
    except ImportError as exc:
        raise UsageError(f"the sitl needs pymavlink, which is not installed: pip install scart-bench[mavlink] "
                         f"({exc})") from exc
    from scart_bench.generator.mavlink.recording import RecordTarget
    from scart_bench.generator.scart.scenario import load_scenarios
    from scart_bench.generator.sitl.session import run_sitl

    target = RecordTarget(args.record, record_folder) if args.record else None
    scenarios = load_scenarios(args.scenario) if args.scenario else []
    if scenarios and args.split != "test":
        raise UsageError(f"--split {args.split}: an attacked flight (--scenario) is always a test flight")
    defense = _defense(args) if args.detector else None
    extra = {"scenario_file": args.scenario}
    if defense is not None:
        extra["defense"] = {"detector": args.detector, "run": str(args.run), "threshold": defense.monitor.threshold,
                            "response": args.response, "alarms": args.alarms}
    plant = _jmavsim(args, scenarios) if args.physics == "jmavsim" else None
    if plant is not None:
        extra["physics"] = {"name": "jmavsim", "sim": args.sim or plant.sim.link_address}
    try:
        done = run_sitl(listen, scenarios, sock=sock, seed=args.seed, remote=remote, record=target,
                        flight_id=args.flight_id, split=args.split, fmt=args.format, defense=defense, extra=extra,
                        speed=None if args.lockstep else args.speed, duration_s=args.duration, log=_log,
                        plant=plant)
    finally:
        if plant is not None:
            plant.close()  # ends the jMAVSim it started
    if done.path is not None:
        print(f"flight {done.flight_id} recorded in {target.shown} ({done.path.name})")
    if done.error is not None:  # the simulator of --physics jmavsim ended or went silent during the flight
        from scart_bench.generator.hil.errors import HilError

        raise HilError(done.error)
    return 0


def _jmavsim(args: argparse.Namespace, scenarios: list):
    """The started jMAVSim plant (``--physics jmavsim``): jMAVSim started headless in lockstep from ``--jmavsim``
    (or $SCART_JMAVSIM), or the simulator at ``--sim``; what is missing is a one-line error (exit 2)."""
    from scart_bench.generator.hil.jmavsim import DEFAULT_SPEED
    from scart_bench.generator.hil.link import parse_sim_address
    from scart_bench.generator.sitl.jmavsim_plant import JMAVSIM_POINTS, JmavsimPlant
    from scart_bench.generator.sitl.server import check_scenarios

    if args.sim:
        parse_sim_address(args.sim)
    check_scenarios(scenarios, JMAVSIM_POINTS, "jmavsim")  # before jMAVSim starts
    # jMAVSim's lockstep caps its pace at this multiple of real time: above the sitl's --speed
    speed = max(DEFAULT_SPEED, 2.0 * args.speed)
    plant = JmavsimPlant(args.sim, jar=args.jmavsim, seed=args.seed, speed=speed)
    _log(f"sitl: {'starting jMAVSim' if args.sim is None else 'reaching ' + args.sim} ...")
    return plant.start()


def _defense(args: argparse.Namespace):
    """The run's detector (refitted, its threshold calibrated) watching the navigator's view, with the response;
    refused in one line when it cannot score rows as fast as the link brings them."""
    from scart_bench.benchmark.defense import require_link_rate
    from scart_bench.benchmark.live import monitor_from_run
    from scart_bench.generator.defense import LiveDefense, Response

    monitor = monitor_from_run(Path(args.run), args.detector, list(args.plugin or []), log=_log, command="sitl")
    rate = require_link_rate(args.detector, monitor.detector, where="the live loop")
    _log(f"sitl: {args.detector} scores {rate:.0f} rows/s row by row; on {args.alarms} alarm row(s) the flight "
         f"controller takes {args.response}")
    return LiveDefense(monitor, Response(args.response, alarms=args.alarms))


def register(sub) -> None:
    p = sub.add_parser("sitl", help="a simulated PX4-like vehicle any MAVLink tool can fly (SCART layer on its link)",
                       description="One simulated quadrotor (the generator's physics, sensors, estimator and "
                       "controller) behind a MAVLink 2 endpoint that speaks like PX4: heartbeat and telemetry, "
                       "commands, missions, parameters and offboard setpoints. A --scenario runs on its link "
                       "(telemetry to the client, setpoints to the controller) or on its physics. Needs "
                       "pymavlink. See docs/sitl.md.")
    p.add_argument("--listen", default=DEFAULT_LISTEN, metavar="udp:HOST:PORT",
                   help=f"where the vehicle binds; clients connect here (default {DEFAULT_LISTEN})")
    p.add_argument("--remote", metavar="udp:HOST:PORT",
                   help="also send telemetry here from the start (PX4's -o port, e.g. udp:127.0.0.1:14540 for "
                        "MAVSDK's default udpin://0.0.0.0:14540)")
    p.add_argument("--scenario", metavar="FILE",
                   help="a scenario file (TOML): link, command, sensor, environment or vehicle point")
    p.add_argument("--speed", type=float, default=1.0, help="simulated seconds per wall-clock second (default 1)")
    p.add_argument("--lockstep", action="store_true",
                   help="no wall-clock pacing: run as fast as the simulation can, from the first client message")
    p.add_argument("--seed", type=int, default=0, help="seed of the wind, sensor errors and scenario draws")
    p.add_argument("--duration", type=float, metavar="SECONDS", help="stop after this much simulated time")
    p.add_argument("--record", metavar="DIR|URL", help="write the flight (both views, truth, labels) into this "
                   "dataset: a folder or a URL such as s3://bucket/prefix, added to a dataset there")
    p.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="format of a new dataset")
    p.add_argument("--flight-id", help="flight id of the recording (default sitl-<UTC time>)")
    p.add_argument("--split", choices=("train", "validation", "test"), default="test",
                   help="split of a recorded normal flight (attacked flights are always test)")
    p.add_argument("--detector", metavar="NAME", help="defense in the loop: this detector of --run scores what the "
                   "navigator receives; on its alarm the flight controller takes --response (docs/defense.md)")
    p.add_argument("--run", metavar="RUN", help="the benchmark run folder the detector comes from")
    p.add_argument("--response", choices=RESPONSES, help="what the flight controller does on the anomaly notice")
    p.add_argument("--alarms", type=int, default=1, metavar="N", help="alarm rows before the response (default 1)")
    p.add_argument("--plugin", action="append", metavar="SPEC",
                   help="load a plugin detector from module:Class or file.py:Class")
    p.add_argument("--physics", choices=("builtin", "jmavsim"), default="builtin",
                   help="builtin (default): the generator's physics and sensors; jmavsim: jMAVSim's, through PX4's "
                   "simulator MAVLink API, flown by the same estimator and controller (docs/jmavsim.md)")
    p.add_argument("--jmavsim", metavar="PATH", help="with --physics jmavsim: jmavsim_run.jar or the jMAVSim checkout "
                   "it was built in (default $SCART_JMAVSIM); started headless in lockstep, stopped at exit")
    p.add_argument("--sim", metavar="ADDR", help="with --physics jmavsim: a simulator already running at "
                   "udp:HOST:PORT or tcp:HOST:PORT (udp-listen:/tcp-listen: wait for it) instead of starting jMAVSim")
    p.set_defaults(func=cmd_sitl)
