"""``scart-bench proxy``: the SCART layer live on a MAVLink link, with recording and online detection.

The engine is :mod:`scart_bench.generator.mavlink.proxy`; this module parses the options, loads the
scenario, fits the detector of a benchmark run (runs keep scores, not fitted models: the named
detector is fitted again on the run's training flights with the run's parameters and seed, and
its row threshold is calibrated from the run's saved validation scores with the run's protocol)
and calls :func:`scart_bench.generator.mavlink.proxy.run_proxy`, which runs the proxy until Ctrl-C
(or ``--duration``) and writes the recording (a program calls it the same way, without the command line).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from scart_bench.cli.common import PROXY_FORWARD, PROXY_LISTEN, RESPONSES, UsageError, record_folder
from scart_bench.names import check_id


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _require_mavlink():
    try:
        from scart_bench.generator.mavlink import proxy
    except ImportError as exc:
        raise UsageError(f"the MAVLink proxy needs pymavlink, which is not installed: "
                         f"pip install scart-bench[mavlink] ({exc})") from exc
    return proxy


def cmd_proxy(args: argparse.Namespace) -> int:
    px = _require_mavlink()
    from scart_bench.generator.mavlink.recording import RecordTarget
    from scart_bench.generator.scart.scenario import load_scenarios

    listen = px.parse_endpoint(args.listen, "--listen")
    forward = px.parse_endpoint(args.forward, "--forward")
    if not Path(args.scenario).is_file():
        raise UsageError(f"--scenario {args.scenario}: no such file")
    if (args.detector is None) != (args.run is None):
        raise UsageError("--detector and --run go together: the detector is the one fitted in that benchmark run")
    if args.response is not None and args.detector is None:
        raise UsageError("--response needs --detector and --run: the detector whose alarm the response answers")
    if args.response is not None and args.response.startswith("reject_gps"):
        raise UsageError(f"--response {args.response}: the proxy cannot stop the autopilot fusing GPS over MAVLink; "
                         "use hold, return or land (reject_gps runs in sitl and defend)")
    if args.alarms < 1:
        raise UsageError(f"--alarms {args.alarms}: expected a whole number >= 1")
    if not (math.isfinite(args.checkpoint) and args.checkpoint > 0):
        raise UsageError(f"--checkpoint {args.checkpoint}: expected a positive, finite number of seconds")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise UsageError(f"--duration {args.duration}: expected a positive, finite number of seconds")
    if args.flight_id is not None:
        check_id(args.flight_id, "--flight-id")
    target = RecordTarget(args.record, record_folder) if args.record else None
    scenarios = load_scenarios(args.scenario)
    monitor = None
    if args.detector:
        from scart_bench.benchmark.live import monitor_from_run

        monitor = monitor_from_run(Path(args.run), args.detector, list(args.plugin or []), log=_log)
    defense = None
    if args.response is not None:
        from scart_bench.benchmark.defense import require_link_rate
        from scart_bench.generator.defense import LiveDefense, Response

        rate = require_link_rate(args.detector, monitor.detector, where="the live loop")
        _log(f"proxy: {args.detector} scores {rate:.0f} rows/s row by row; on {args.alarms} alarm row(s) the "
             f"autopilot is sent {args.response}")
        defense = LiveDefense(monitor, Response(args.response, alarms=args.alarms))

    detector = {"name": args.detector, "run": str(args.run)} if monitor is not None else None
    done = px.run_proxy(listen, forward, scenarios, seed=args.seed, record=target, flight_id=args.flight_id,
                        monitor=monitor, defense=defense, duration_s=args.duration, checkpoint_s=args.checkpoint,
                        fmt=args.format, extra={"scenario_file": str(args.scenario)}, detector=detector, log=_log)
    if target is not None:
        print(f"flight {done.flight_id} recorded in {target.shown} ({done.path.name})")
    return 0


def register(sub) -> None:
    p = sub.add_parser("proxy", help="live MAVLink man-in-the-middle: run a scenario on an autopilot link",
                       description="A MAVLink 2 proxy between an autopilot (telemetry in on --listen) and a "
                       "mission computer (--forward): the scenario's topics are decoded, attacked by the SCART "
                       "layer and re-encoded; all other traffic, both ways, passes byte-identical. Needs "
                       "pymavlink (pip install scart-bench[mavlink]).")
    p.add_argument("--listen", default=PROXY_LISTEN, metavar="udp:HOST:PORT",
                   help=f"where the autopilot sends its telemetry (default {PROXY_LISTEN}; loopback unless "
                        "told otherwise)")
    p.add_argument("--forward", default=PROXY_FORWARD, metavar="udp:HOST:PORT",
                   help=f"where the mission computer listens (default {PROXY_FORWARD})")
    p.add_argument("--scenario", required=True, metavar="FILE", help="a scenario file (TOML), points link/command")
    p.add_argument("--seed", type=int, default=0, help="seed of the scenario's random draws (default 0)")
    p.add_argument("--record", metavar="DIR|URL", help="write the flight (both views, labels) into this dataset, "
                   "a folder or a URL such as s3://bucket/prefix: added to an existing dataset, or a new one")
    p.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="format of a new dataset")
    p.add_argument("--flight-id", help="flight id of the recording (default live-<UTC time>)")
    p.add_argument("--checkpoint", type=float, default=5.0, metavar="SECONDS",
                   help="with --record: write the flight seen so far beside the dataset this often (default 5), "
                        "so a killed proxy loses at most that much; the next proxy --record adds it, marked "
                        "incomplete")
    p.add_argument("--detector", metavar="NAME", help="score the navigator-side stream with this detector of --run")
    p.add_argument("--run", metavar="RUN", help="the benchmark run folder the detector comes from")
    p.add_argument("--plugin", action="append", metavar="SPEC",
                   help="load a plugin detector from module:Class or file.py:Class (a run folder's record of "
                        "plugin files is never imported)")
    p.add_argument("--response", choices=RESPONSES,
                   help="defense in the loop: on the detector's anomaly notice send the autopilot this (COMMAND_LONG)")
    p.add_argument("--alarms", type=int, default=1, metavar="N", help="alarm rows before the response (default 1)")
    p.add_argument("--duration", type=float, metavar="SECONDS", help="stop after this many seconds (default: Ctrl-C)")
    p.set_defaults(func=cmd_proxy)
