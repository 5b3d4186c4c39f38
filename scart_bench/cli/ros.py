"""``scart-bench ros``: SCART inside ROS 1, as the paper built it (docs/ros.md).

- ``ros node``: the SCART layer as a ROS node between MAVROS (``--input-ns``) and the mission computer
  (``--output-ns``), with ``--record`` into a dataset;
- ``ros mavros``: a MAVROS stand-in that bridges ``scart-bench sitl`` to MAVROS topic names and types;
- ``ros navigator``: the mission computer that flies the default square from the telemetry it receives,
  with an optional live detector whose alarms it publishes as an anomaly notice.

The engines are in :mod:`scart_bench.generator.ros`; this module parses options and calls the run loops of
:mod:`scart_bench.generator.ros.session` (a program calls them the same way, without the command line), which
join the ROS master and run a node until Ctrl-C, SIGTERM or ``--duration``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from scart_bench.cli.common import UsageError, log, record_folder
from scart_bench.names import check_id


def _positive(value: float | None, option: str) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise UsageError(f"{option} {value}: expected a positive, finite number of seconds")


def cmd_node(args: argparse.Namespace) -> int:
    from scart_bench.generator.mavlink.recording import RecordTarget
    from scart_bench.generator.ros.session import run_node
    from scart_bench.generator.scart.scenario import load_scenarios

    _positive(args.duration, "--duration")
    if args.scenario is not None and not Path(args.scenario).is_file():
        raise UsageError(f"--scenario {args.scenario}: no such file")
    if args.flight_id is not None:
        check_id(args.flight_id, "--flight-id")
    record = RecordTarget(args.record, record_folder) if args.record else None  # a URL: checked up front
    if record is not None and args.flight_id in record.taken:
        raise UsageError(f"--flight-id {args.flight_id}: {record.shown} holds a flight {args.flight_id} already; "
                         "give another id")
    scenarios = load_scenarios(args.scenario) if args.scenario else []
    if scenarios and record is not None and args.split != "test":
        raise UsageError(f"--split {args.split}: an attacked flight (--scenario) is always a test flight")
    extra = {"scenario_file": args.scenario, "input_ns": args.input_ns, "output_ns": args.output_ns}
    done = run_node(scenarios, args.input_ns, args.output_ns, name=args.name, seed=args.seed, record=record,
                    flight_id=args.flight_id, split=args.split, fmt=args.format, extra=extra,
                    duration_s=args.duration, log=log)
    if record is not None:
        print(f"flight {done.flight_id} recorded in {record.shown} ({done.path.name})")
    return 0


def cmd_mavros(args: argparse.Namespace) -> int:
    from scart_bench.generator.mavlink import parse_endpoint
    from scart_bench.generator.ros.session import run_mavros

    _positive(args.duration, "--duration")
    connect = parse_endpoint(args.connect, "--connect")
    run_mavros(connect, ns=args.ns, name=args.name, duration_s=args.duration, log=log)
    return 0


def cmd_navigator(args: argparse.Namespace) -> int:
    _positive(args.timeout, "--timeout")
    if (args.detector is None) != (args.run is None):
        raise UsageError(
            "--detector and --run go together: the detector is the one fitted in that benchmark run"
        )
    monitor = None
    if args.detector:
        from scart_bench.benchmark.live import monitor_from_run
        from scart_bench.generator.ros.topics import MAVROS_TOPICS, topic_fields

        monitor = monitor_from_run(Path(args.run), args.detector, list(args.plugin or []), log=log)
        monitor.add_topics(topic_fields(), {n: t.rate_hz for n, t in MAVROS_TOPICS.items()})
    from scart_bench.generator.ros.session import run_navigator

    if not run_navigator(ns=args.ns, name=args.name, monitor=monitor, notice_topic=args.notice_topic,
                         timeout_s=args.timeout, log=log):
        return 1
    print("navigator: mission flown, landed and disarmed")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "ros",
        help="SCART inside ROS 1: the SCART node, a MAVROS stand-in, the mission computer",
        description="The paper's ROS setting: MAVROS telemetry remapped through the SCART node to the "
        "mission computer (docs/ros.md). Needs ROS 1 (rospy and the sensor/geometry message packages).",
    )
    nodes = p.add_subparsers(dest="node", required=True)

    n = nodes.add_parser("node", help="the SCART layer as a ROS node on the MAVROS telemetry topics")
    n.add_argument(
        "--scenario",
        metavar="FILE",
        help="a scenario file (TOML), point link (default: none, every message passes unchanged)",
    )
    n.add_argument("--seed", type=int, default=0, help="seed of the scenario's random draws (default 0)")
    n.add_argument(
        "--input-ns",
        default="/mavros_raw",
        metavar="NS",
        help="where MAVROS (or the stand-in) publishes the telemetry (default /mavros_raw)",
    )
    n.add_argument(
        "--output-ns",
        default="/mavros",
        metavar="NS",
        help="where the mission computer reads it (default /mavros)",
    )
    n.add_argument("--record", metavar="DIR|URL", help="write the flight (both views, labels) into this dataset: "
                   "a folder or a URL such as s3://bucket/prefix, added to a dataset there")
    n.add_argument(
        "--split",
        choices=("train", "validation", "test"),
        default="test",
        help="split of a flight recorded without a scenario (default test)",
    )
    n.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="format of a new dataset")
    n.add_argument("--flight-id", help="flight id of the recording (default ros-<UTC time>)")
    n.add_argument("--name", default="scart", help="the ROS node name (default scart)")
    n.add_argument(
        "--duration", type=float, metavar="SECONDS", help="stop after this many seconds (default: Ctrl-C)"
    )
    n.set_defaults(func=cmd_node)

    m = nodes.add_parser("mavros", help="a MAVROS stand-in for scart-bench sitl")
    m.add_argument(
        "--connect",
        default="udp:127.0.0.1:14580",
        metavar="udp:HOST:PORT",
        help="the sitl's --listen address (default udp:127.0.0.1:14580)",
    )
    m.add_argument(
        "--ns",
        default="/mavros_raw",
        help="the namespace it publishes under (default /mavros_raw, "
        "the SCART node's input; /mavros without the node)",
    )
    m.add_argument("--name", default="mavros", help="the ROS node name (default mavros)")
    m.add_argument(
        "--duration", type=float, metavar="SECONDS", help="stop after this many seconds (default: Ctrl-C)"
    )
    m.set_defaults(func=cmd_mavros)

    v = nodes.add_parser("navigator", help="the mission computer: flies the default square by setpoints")
    v.add_argument(
        "--ns", default="/mavros", help="the MAVROS namespace it reads and commands (default /mavros)"
    )
    v.add_argument(
        "--detector", metavar="NAME", help="score the telemetry it receives with this detector of --run"
    )
    v.add_argument("--run", metavar="RUN", help="the benchmark run folder the detector comes from")
    v.add_argument(
        "--plugin", action="append", metavar="SPEC", help="load a plugin detector from module:Class"
    )
    v.add_argument(
        "--notice-topic",
        default="/navigator/anomaly",
        help="where the anomaly notices go (std_msgs/String; default /navigator/anomaly)",
    )
    v.add_argument("--name", default="navigator", help="the ROS node name (default navigator)")
    v.add_argument(
        "--timeout", type=float, metavar="SECONDS", help="give up after this many seconds (exit 1)"
    )
    v.set_defaults(func=cmd_navigator)
