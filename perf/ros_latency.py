"""The latency the SCART ROS node adds per message: through the node minus a direct ROS hop.

    python -m perf.ros_latency [--messages 2000] [--rate 200]

A roscore of its own on a free port; ``scart-bench ros node`` in a process of its own. This process
publishes ``sensor_msgs/NavSatFix`` on the node's input (``/p_in/global_position/global``) and
subscribes both to that topic (a direct hop: publisher -> subscriber) and to the node's output
(publisher -> node -> subscriber). For each message the added latency is the arrival time through the
node minus the arrival time of the same message directly (both measured in this process, on the same
clock). Two cases: no scenario (the message object is published as received) and a GPS bias that is
active from the first message (values out, the layer, an altered copy published: the worst case).
Printed: p50 and p99 of the added latency, and the node's own handling time (its closing line).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BIAS = """
[scenario]
id = "gps-bias-always"
[[scenario.actions]]
action = "bias"
target = ["position"]
offset = 5.0
"""


def _case(ros1, rospy, scenario: Path | None, n: int, rate: float, tag: str) -> tuple[np.ndarray, str]:
    from sensor_msgs.msg import NavSatFix

    ns_in, ns_out = f"/p_in_{tag}", f"/p_out_{tag}"
    args = [
        sys.executable,
        "-m",
        "scart_bench",
        "ros",
        "node",
        "--input-ns",
        ns_in,
        "--output-ns",
        ns_out,
        "--name",
        f"scart_{tag}",
    ]
    if scenario is not None:
        args += ["--scenario", str(scenario)]
    log = tempfile.TemporaryFile(mode="w+")
    node = subprocess.Popen(
        args, cwd=ROOT, stderr=log, stdout=log, env={**os.environ, "PYTHONPATH": str(ROOT)}
    )
    direct, through = {}, {}
    lock = threading.Lock()

    def on(store):
        def cb(msg):
            t = time.perf_counter_ns()
            with lock:
                store[msg.header.stamp.to_nsec()] = t

        return cb

    topic = ros1.MAVROS_TOPICS["global_position_global"].ros_name
    pub = rospy.Publisher(ros1.join(ns_in, topic), NavSatFix, queue_size=1000)
    subs = [
        rospy.Subscriber(ros1.join(ns_in, topic), NavSatFix, on(direct), tcp_nodelay=True),
        rospy.Subscriber(ros1.join(ns_out, topic), NavSatFix, on(through), tcp_nodelay=True),
    ]
    end = time.monotonic() + 60
    while pub.get_num_connections() < 2 or subs[1].get_num_connections() < 1:
        if time.monotonic() > end:
            raise SystemExit("the node did not connect within 60 s")
        time.sleep(0.05)
    time.sleep(0.5)
    period = 1.0 / rate
    t_next = time.perf_counter()
    for k in range(n + 50):  # the first 50 warm up
        msg = NavSatFix(latitude=47.397742, longitude=8.545594, altitude=498.0)
        msg.header.stamp = rospy.Time(1000, 0) + rospy.Duration(0, (k + 1) * 1_000_000)
        pub.publish(msg)
        t_next += period
        time.sleep(max(0.0, t_next - time.perf_counter()))
    time.sleep(1.0)
    node.send_signal(signal.SIGINT)
    node.wait(timeout=30)
    log.seek(0)
    closing = [line for line in log.read().splitlines() if "stopped after" in line]
    for s in subs:
        s.unregister()
    pub.unregister()
    keys = sorted(set(direct) & set(through))[50:]
    lost = n + 50 - len(set(direct) & set(through))
    if lost:
        print(f"  {lost} messages did not arrive both ways")
    return np.array([(through[k] - direct[k]) / 1e6 for k in keys]), (closing[0] if closing else "")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--messages", type=int, default=2000)
    p.add_argument("--rate", type=float, default=200.0, help="messages per second (default 200)")
    args = p.parse_args(argv)
    from scart_bench.generator.ros import require_rospy, ros1

    rospy = require_rospy()
    with tempfile.TemporaryDirectory() as tmp, ros1.RosCore():
        bias = Path(tmp) / "bias.toml"
        bias.write_text(BIAS)
        rospy.init_node("ros_latency", anonymous=True, disable_signals=True)
        for name, scenario in (
            ("no scenario (passed as received)", None),
            ("GPS bias active (altered copy)", bias),
        ):
            added, closing = _case(
                ros1, rospy, scenario, args.messages, args.rate, "a" if scenario is None else "b"
            )
            print(
                f"{name}: {len(added)} messages at {args.rate:.0f}/s; added latency p50 "
                f"{np.quantile(added, 0.5):.3f} ms, p99 {np.quantile(added, 0.99):.3f} ms"
            )
            print(f"  node: {closing.partition('stopped after')[2].strip()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
