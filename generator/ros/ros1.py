"""The ROS 1 transport: the SCART node, the MAVROS stand-in and the navigator node (the only rospy code).

Everything that is not ROS lives beside it: the topics (:mod:`~scart_bench.generator.ros.topics`),
the layer on one message (:mod:`~scart_bench.generator.ros.layer`) and the mission
(:mod:`~scart_bench.generator.ros.mission`). A ROS 2 transport replaces this module only: message
classes by type name, field paths, subscriptions and publishers, the spin loop.

Namespaces: the SCART node reads the flight controller's telemetry under ``input_ns`` (where MAVROS, or
the stand-in, publishes it) and publishes it under ``output_ns`` (where the mission computer reads
it, ``/mavros`` as without SCART). The mission computer's setpoints and commands travel the other way,
from ``output_ns`` to ``input_ns``, unchanged, so the mission computer needs no remap at all.
"""

from __future__ import annotations

import copy
import importlib
import math
import sys
import threading
import time
from collections.abc import Callable
from operator import attrgetter

import numpy as np

from scart_bench.generator.ros import RosError, require_rospy
from scart_bench.generator.ros.layer import RosLayer, StampClock
from scart_bench.generator.ros.mission import SquareMission
from scart_bench.generator.ros.topics import (
    COMMAND,
    MAVROS_TOPICS,
    SETPOINT_POSITION,
    SETPOINT_VELOCITY,
    STATE,
    RosTopic,
)

rospy = require_rospy()


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def msg_class(type_name: str):
    """The ROS 1 message class of ``package/Name``."""
    pkg, _, name = type_name.partition("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), name)
    except (ImportError, AttributeError) as exc:
        raise RosError(
            f"message type {type_name!r} is not installed ({exc}); install python3-{pkg.replace('_', '-')}"
        ) from exc


def join(ns: str, name: str) -> str:
    """``ns/name`` as a global name (``/`` is the root namespace)."""
    return "/" + "/".join(p for p in (ns.strip("/"), name.strip("/")) if p)


def stamp_us(msg) -> int | None:
    """The header stamp of ``msg`` in microseconds (None when the message has no header)."""
    header = getattr(msg, "header", None)
    if header is None:
        return None
    return header.stamp.secs * 1_000_000 + header.stamp.nsecs // 1000


class Codec:
    """A topic's field values out of a message and back into a copy of it."""

    def __init__(self, topic: RosTopic):
        self.topic = topic
        self.cls = msg_class(topic.msg_type)
        self.getters = [attrgetter(p) for p in topic.paths]
        self.parents = [
            (attrgetter(p.rpartition(".")[0]) if "." in p else None, p.rpartition(".")[2])
            for p in topic.paths
        ]

    def values(self, msg) -> np.ndarray:
        return np.array([float(g(msg)) for g in self.getters], dtype=np.float64)

    def altered(self, msg, new: np.ndarray, before: np.ndarray):
        """A copy of ``msg`` whose fields that differ between ``before`` and ``new`` carry ``new``; every other
        field (header, covariances, status) as received."""
        out = copy.deepcopy(msg)
        for k, (parent, leaf) in enumerate(self.parents):
            if new[k] == before[k] or (math.isnan(new[k]) and math.isnan(before[k])):
                continue
            obj = parent(out) if parent is not None else out
            old = getattr(obj, leaf)
            setattr(obj, leaf, int(round(new[k])) if isinstance(old, int) else float(new[k]))
        return out


# -- the SCART node -------------------------------------------------------------------------------------
class ScartNode:
    """The SCART layer as a ROS 1 node: every MAVROS telemetry topic from ``input_ns`` to ``output_ns``.

    A message of a topic no scenario uses is published as the very object received; one the layer altered
    is a copy with only the changed fields rewritten; one it dropped is not published. Setpoints and
    commands of the mission computer (``output_ns`` -> ``input_ns``) and the stand-in's state
    (``input_ns`` -> ``output_ns``) are relayed unchanged.
    """

    def __init__(
        self,
        layer: RosLayer,
        input_ns: str = "/mavros_raw",
        output_ns: str = "/mavros",
        log: Callable[[str], None] = _log,
    ):
        if join(input_ns, "") == join(output_ns, ""):
            raise RosError(
                f"--input-ns and --output-ns are both {join(input_ns, '')!r}: the node would read what "
                "it publishes; remap the flight controller's telemetry (MAVROS) to another namespace"
            )
        self.layer = layer
        self.input_ns, self.output_ns = input_ns, output_ns
        self.log = log
        self._lock = threading.Lock()
        self._subs, self._pubs = [], {}
        self.codecs = {n: Codec(t) for n, t in layer.topics.items()}
        self.relayed = 0

    def start(self) -> ScartNode:
        for name, t in self.layer.topics.items():
            codec = self.codecs[name]
            if t.direction == "mission":  # the mission computer's progress: listened to, not relayed
                self._subs.append(
                    rospy.Subscriber(
                        join(self.output_ns, t.ros_name),
                        codec.cls,
                        self._on_listen,
                        callback_args=name,
                        tcp_nodelay=True,
                    )
                )
                continue
            self._pubs[name] = rospy.Publisher(join(self.output_ns, t.ros_name), codec.cls, queue_size=100)
            self._subs.append(
                rospy.Subscriber(
                    join(self.input_ns, t.ros_name),
                    codec.cls,
                    self._on_message,
                    callback_args=name,
                    tcp_nodelay=True,
                    queue_size=100,
                )
            )
        for (ros_name, type_name), down in (
            (SETPOINT_POSITION, True),
            (SETPOINT_VELOCITY, True),
            (COMMAND, True),
            (STATE, False),
        ):
            src, dst = (self.output_ns, self.input_ns) if down else (self.input_ns, self.output_ns)
            pub = rospy.Publisher(join(dst, ros_name), msg_class(type_name), queue_size=100)
            self._subs.append(
                rospy.Subscriber(
                    join(src, ros_name),
                    msg_class(type_name),
                    self._relay,
                    callback_args=pub,
                    tcp_nodelay=True,
                )
            )
        return self

    def _relay(self, msg, pub) -> None:
        self.relayed += 1
        pub.publish(msg)

    def _on_listen(self, msg, topic: str) -> None:
        if self.layer.needs_values(topic):
            with self._lock:
                self.layer.on_message(topic, stamp_us(msg), self.codecs[topic].values(msg))

    def _on_message(self, msg, topic: str) -> None:
        if not self.layer.needs_values(topic):
            self._pubs[topic].publish(msg)
            with self._lock:
                self.layer.stats.received += 1
                self.layer.stats.published += 1
            return
        codec = self.codecs[topic]
        with self._lock:
            values = codec.values(msg)
            new, ok = self.layer.on_message(topic, stamp_us(msg), values)
        if not ok:
            return
        self._pubs[topic].publish(msg if new is None else codec.altered(msg, new, values))

    def stop(self) -> None:
        for s in self._subs:
            s.unregister()
        for p in self._pubs.values():
            p.unregister()


# -- the MAVROS stand-in ----------------------------------------------------------------------------------
#: PX4 custom modes (main, sub) -> the name PX4 and MAVROS use
PX4_MODES = {
    (1, 0): "MANUAL",
    (2, 0): "ALTCTL",
    (3, 0): "POSCTL",
    (4, 2): "AUTO.TAKEOFF",
    (4, 3): "AUTO.LOITER",
    (4, 4): "AUTO.MISSION",
    (4, 5): "AUTO.RTL",
    (4, 6): "AUTO.LAND",
    (6, 0): "OFFBOARD",
}
LANDED = {0: "UNDEFINED", 1: "ON_GROUND", 2: "IN_AIR", 3: "TAKEOFF", 4: "LANDING"}


def quaternion_enu(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the ENU/FLU orientation of a body at FRD/NED Euler angles (roll, pitch, yaw), as MAVROS
    converts PX4's attitude: roll stays, pitch and yaw change sign, yaw turns from north to east."""
    r, p, y = roll, -pitch, math.pi / 2 - yaw
    cr, sr, cp, sp, cy, sy = (
        math.cos(r / 2),
        math.sin(r / 2),
        math.cos(p / 2),
        math.sin(p / 2),
        math.cos(y / 2),
        math.sin(y / 2),
    )
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def yaw_ned_of(q) -> float:
    """PX4's yaw (rad from north, clockwise) of an ENU orientation quaternion."""
    yaw_enu = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
    return math.atan2(math.sin(math.pi / 2 - yaw_enu), math.cos(math.pi / 2 - yaw_enu))


class MavrosStandIn:
    """``scart-bench sitl``'s MAVLink as MAVROS topics (names, types, ENU/FLU frames and units), for people
    without MAVROS and for the tests. Takes ``setpoint_position/local`` and ``setpoint_velocity/cmd_vel``
    back to the flight controller, and requests (``command``: arm, disarm, offboard, hold, land, return)
    as MAVLink commands; publishes the flight controller's ``state`` as ``armed=0|1 mode=NAME
    landed=NAME`` (MAVROS's State and services need mavros_msgs, absent here)."""

    def __init__(self, connect: tuple[str, int], ns: str = "/mavros", log: Callable[[str], None] = _log):
        from pymavlink import mavutil

        self.mavutil = mavutil
        self.mav_mod = mavutil.mavlink
        self.ns = ns
        self.log = log
        self.conn = mavutil.mavlink_connection(
            f"udpout:{connect[0]}:{connect[1]}", source_system=255, source_component=191, dialect="common"
        )
        self._send_lock = threading.Lock()
        self.pubs: dict[str, object] = {}
        self.msgs: dict[str, type] = {}
        self.time_boot_ms = 0
        self.armed = False
        self.mode = "UNKNOWN"
        self.landed = "UNDEFINED"
        self._q = (0.0, 0.0, 0.0, 1.0)
        self._rates = (0.0, 0.0, 0.0)
        self._vz_down = 0.0
        self._state_sent = ""
        self.counts: dict[str, int] = {}
        self.setpoints = 0

    def start(self) -> MavrosStandIn:
        for name, t in MAVROS_TOPICS.items():
            if t.direction == "telemetry":
                self.msgs[name] = msg_class(t.msg_type)
                self.pubs[name] = rospy.Publisher(join(self.ns, t.ros_name), self.msgs[name], queue_size=100)
        from std_msgs.msg import String

        self.String = String
        self.pubs["state"] = rospy.Publisher(join(self.ns, STATE[0]), String, queue_size=10, latch=True)
        self._subs = [
            rospy.Subscriber(
                join(self.ns, SETPOINT_POSITION[0]),
                msg_class(SETPOINT_POSITION[1]),
                self._on_position,
                tcp_nodelay=True,
            ),
            rospy.Subscriber(
                join(self.ns, SETPOINT_VELOCITY[0]),
                msg_class(SETPOINT_VELOCITY[1]),
                self._on_velocity,
                tcp_nodelay=True,
            ),
            rospy.Subscriber(join(self.ns, COMMAND[0]), String, self._on_command),
        ]
        self._heartbeat()
        return self

    # -- MAVLink out --------------------------------------------------------------------------------
    def _heartbeat(self) -> None:
        m = self.mav_mod
        with self._send_lock:
            self.conn.mav.heartbeat_send(m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def command(self, what: str) -> bool:
        """Send one request to the flight controller; False for an unknown one."""
        m = self.mav_mod
        table = {
            "arm": (m.MAV_CMD_COMPONENT_ARM_DISARM, 1),
            "disarm": (m.MAV_CMD_COMPONENT_ARM_DISARM, 0),
            "offboard": (m.MAV_CMD_DO_SET_MODE, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0),
            "hold": (m.MAV_CMD_DO_SET_MODE, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3),
            "land": (m.MAV_CMD_NAV_LAND,),
            "return": (m.MAV_CMD_NAV_RETURN_TO_LAUNCH,),
        }
        if what not in table:
            self.log(f"mavros stand-in: unknown command {what!r}; expected one of {', '.join(table)}")
            return False
        cmd, *params = table[what]
        params = [float(p) for p in params] + [0.0] * (7 - len(params))
        with self._send_lock:
            self.conn.mav.command_long_send(1, 1, cmd, 0, *params)
        return True

    def _on_command(self, msg) -> None:
        self.command(msg.data.strip().lower())

    def _on_position(self, msg) -> None:
        p = msg.pose.position
        mask = 0b0000_1001_1111_1000  # position + yaw
        with self._send_lock:
            self.conn.mav.set_position_target_local_ned_send(
                self.time_boot_ms,
                1,
                1,
                self.mav_mod.MAV_FRAME_LOCAL_NED,
                mask,
                p.y,
                p.x,
                -p.z,
                0,
                0,
                0,
                0,
                0,
                0,
                yaw_ned_of(msg.pose.orientation),
                0,
            )
        self.setpoints += 1

    def _on_velocity(self, msg) -> None:
        v = msg.twist.linear
        mask = 0b0000_0101_1100_0111  # velocity + yaw rate
        with self._send_lock:
            self.conn.mav.set_position_target_local_ned_send(
                self.time_boot_ms,
                1,
                1,
                self.mav_mod.MAV_FRAME_LOCAL_NED,
                mask,
                0,
                0,
                0,
                v.y,
                v.x,
                -v.z,
                0,
                0,
                0,
                0,
                -msg.twist.angular.z,
            )
        self.setpoints += 1

    # -- MAVLink in ---------------------------------------------------------------------------------
    def _stamped(self, name: str, t_us: int):
        msg = self.msgs[name]()
        msg.header.stamp = rospy.Time(t_us // 1_000_000, (t_us % 1_000_000) * 1000)
        msg.header.frame_id = "map" if name.startswith(("local_position", "global_position")) else "base_link"
        return msg

    def _publish(self, name: str, msg) -> None:
        self.pubs[name].publish(msg)
        self.counts[name] = self.counts.get(name, 0) + 1

    def handle(self, m) -> None:
        """Publish what one MAVLink message of the flight controller carries."""
        kind = m.get_type()
        if m.get_srcSystem() != 1:
            return
        if hasattr(m, "time_boot_ms"):
            self.time_boot_ms = int(m.time_boot_ms)
        if kind == "HEARTBEAT":
            if m.get_srcComponent() != 1:
                return
            self.armed = bool(m.base_mode & self.mav_mod.MAV_MODE_FLAG_SAFETY_ARMED)
            main, sub = (m.custom_mode >> 16) & 0xFF, (m.custom_mode >> 24) & 0xFF
            self.mode = PX4_MODES.get((main, sub), PX4_MODES.get((main, 0), f"{main}.{sub}"))
            self._state()
        elif kind == "EXTENDED_SYS_STATE":
            self.landed = LANDED.get(m.landed_state, "UNDEFINED")
            self._state()
        elif kind == "ATTITUDE":
            self._q = quaternion_enu(m.roll, m.pitch, m.yaw)
            self._rates = (m.rollspeed, -m.pitchspeed, -m.yawspeed)
        elif kind == "HIGHRES_IMU":
            msg = self._stamped("imu_data", m.time_usec)
            o = msg.orientation
            o.x, o.y, o.z, o.w = self._q
            w = msg.angular_velocity
            w.x, w.y, w.z = m.xgyro, -m.ygyro, -m.zgyro
            a = msg.linear_acceleration
            a.x, a.y, a.z = m.xacc, -m.yacc, -m.zacc
            self._publish("imu_data", msg)
            mag = self._stamped("imu_mag", m.time_usec)
            f = mag.magnetic_field
            f.x, f.y, f.z = m.xmag * 1e-4, -m.ymag * 1e-4, -m.zmag * 1e-4
            self._publish("imu_mag", mag)
        elif kind == "GLOBAL_POSITION_INT":
            t_us = m.time_boot_ms * 1000
            fix = self._stamped("global_position_global", t_us)
            fix.latitude, fix.longitude, fix.altitude = m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0
            self._publish("global_position_global", fix)
            self._vz_down = m.vz / 100.0
            rel = self.msgs["global_position_rel_alt"](data=m.relative_alt / 1000.0)
            self._publish("global_position_rel_alt", rel)
            hdg = self.msgs["global_position_compass_hdg"](
                data=m.hdg / 100.0 if m.hdg != 65535 else float("nan")
            )
            self._publish("global_position_compass_hdg", hdg)
        elif kind == "LOCAL_POSITION_NED":
            t_us = m.time_boot_ms * 1000
            pose = self._stamped("local_position_pose", t_us)
            p, o = pose.pose.position, pose.pose.orientation
            p.x, p.y, p.z = m.y, m.x, -m.z
            o.x, o.y, o.z, o.w = self._q
            self._publish("local_position_pose", pose)
            vel = self._stamped("local_position_velocity_local", t_us)
            v, w = vel.twist.linear, vel.twist.angular
            v.x, v.y, v.z = m.vy, m.vx, -m.vz
            w.x, w.y, w.z = self._rates
            self._publish("local_position_velocity_local", vel)
        elif kind == "GPS_RAW_INT":
            fix = self._stamped("global_position_raw_fix", m.time_usec)
            fix.latitude, fix.longitude, fix.altitude = m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0
            fix.status.status = 0 if m.fix_type >= 2 else -1
            fix.status.service = 1
            self._publish("global_position_raw_fix", fix)
            vel = self._stamped("global_position_raw_gps_vel", m.time_usec)
            speed = m.vel / 100.0 if m.vel != 65535 else 0.0
            cog = math.radians(m.cog / 100.0) if m.cog != 65535 else 0.0
            v = vel.twist.linear
            v.x, v.y, v.z = speed * math.sin(cog), speed * math.cos(cog), -self._vz_down
            self._publish("global_position_raw_gps_vel", vel)
        elif kind == "SCALED_PRESSURE":
            msg = self._stamped("imu_static_pressure", m.time_boot_ms * 1000)
            msg.fluid_pressure = m.press_abs * 100.0
            self._publish("imu_static_pressure", msg)
        elif kind == "BATTERY_STATUS":
            msg = self._stamped("battery", self.time_boot_ms * 1000)
            msg.voltage = m.voltages[0] / 1000.0 if m.voltages[0] != 65535 else float("nan")
            msg.current = -m.current_battery / 100.0 if m.current_battery != -1 else float("nan")
            msg.percentage = m.battery_remaining / 100.0 if m.battery_remaining >= 0 else float("nan")
            msg.present = True
            self._publish("battery", msg)

    def _state(self) -> None:
        text = f"armed={int(self.armed)} mode={self.mode} landed={self.landed}"
        if text != self._state_sent:
            self._state_sent = text
            self.pubs["state"].publish(self.String(data=text))

    def spin(self, stop: threading.Event) -> None:
        """Read the flight controller until ``stop`` (or ROS shutdown); a HEARTBEAT to it every second."""
        last = 0.0
        while not stop.is_set() and not rospy.is_shutdown():
            now = time.monotonic()
            if now - last >= 1.0:
                last = now
                self._heartbeat()
            m = self.conn.recv_match(blocking=True, timeout=0.2)
            if m is not None and m.get_type() != "BAD_DATA":
                self.handle(m)

    def close(self) -> None:
        for s in getattr(self, "_subs", ()):
            s.unregister()
        self.conn.close()


# -- the navigator ------------------------------------------------------------------------------------
def parse_state(text: str) -> dict[str, str]:
    """The stand-in's state line as a dict (``armed``, ``mode``, ``landed``)."""
    return dict(part.partition("=")[::2] for part in text.split())


class NavigatorNode:
    """The paper's mission computer: flies :class:`SquareMission` from the telemetry under ``ns`` (what the SCART
    node publishes), velocity setpoints and requests back to ``ns``; publishes its mission item on
    ``mission/current`` and, with a ``monitor`` (a live detector), an anomaly notice on ``notice_topic``
    (std_msgs/String) at each alarm."""

    def __init__(
        self,
        mission: SquareMission | None = None,
        ns: str = "/mavros",
        monitor=None,
        notice_topic: str = "/navigator/anomaly",
        log: Callable[[str], None] = _log,
    ):
        from geometry_msgs.msg import TwistStamped
        from std_msgs.msg import String, UInt16

        self.mission = mission or SquareMission()
        self.ns = ns
        self.monitor = monitor
        self.log = log
        self.TwistStamped, self.String, self.UInt16 = TwistStamped, String, UInt16
        self.state = {"armed": "0", "mode": "UNKNOWN", "landed": "UNDEFINED"}
        self.done = threading.Event()
        self._lock = threading.Lock()
        self.notices = 0
        self._alarms_seen = 0
        self._clock = StampClock()  # a Float64 without a header takes the last stamped time, as in the node
        self.notice_topic = notice_topic

    def start(self) -> NavigatorNode:
        self.pub_vel = rospy.Publisher(join(self.ns, SETPOINT_VELOCITY[0]), self.TwistStamped, queue_size=10)
        self.pub_cmd = rospy.Publisher(join(self.ns, COMMAND[0]), self.String, queue_size=10)
        self.pub_seq = rospy.Publisher(
            join(self.ns, MAVROS_TOPICS["mission_current"].ros_name), self.UInt16, queue_size=10, latch=True
        )
        self.pub_notice = rospy.Publisher(self.notice_topic, self.String, queue_size=10)
        pose = MAVROS_TOPICS["local_position_pose"]
        self._subs = [
            rospy.Subscriber(
                join(self.ns, pose.ros_name), msg_class(pose.msg_type), self._on_pose, tcp_nodelay=True
            ),
            rospy.Subscriber(join(self.ns, STATE[0]), self.String, self._on_state),
        ]
        if self.monitor is not None:
            self._codecs = {n: Codec(t) for n, t in MAVROS_TOPICS.items() if t.direction == "telemetry"}
            for name, codec in self._codecs.items():
                self._subs.append(
                    rospy.Subscriber(
                        join(self.ns, codec.topic.ros_name), codec.cls, self._on_telemetry, callback_args=name
                    )
                )
        self._seq_sent = -1
        return self

    def _on_state(self, msg) -> None:
        self.state.update(parse_state(msg.data))

    def _on_telemetry(self, msg, topic: str) -> None:
        with self._lock:
            self.monitor.on_message(topic, self._clock.tick(stamp_us(msg)), self._codecs[topic].values(msg))
            for alarm in self.monitor.alarms[self._alarms_seen :]:
                self.notices += 1
                self.pub_notice.publish(
                    self.String(
                        data=f"anomaly: {self.monitor.name} score {alarm.score:.4g} > "
                        f"{self.monitor.threshold:.4g} at t={alarm.t_us / 1e6:.2f} s"
                    )
                )
            self._alarms_seen = len(self.monitor.alarms)

    def _on_pose(self, msg) -> None:
        p = msg.pose.position
        t_us = stamp_us(msg) or 0
        with self._lock:
            sp = self.mission.step(
                t_us / 1e6,
                np.array([p.x, p.y, p.z]),
                self.state.get("armed") == "1",
                self.state.get("mode", ""),
            )
        if sp.request is not None:
            self.pub_cmd.publish(self.String(data=sp.request))
        out = self.TwistStamped()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = "map"
        out.twist.linear.x, out.twist.linear.y, out.twist.linear.z = (float(v) for v in sp.velocity)
        self.pub_vel.publish(out)
        if sp.seq != self._seq_sent:
            self._seq_sent = sp.seq
            self.pub_seq.publish(self.UInt16(data=sp.seq))
        if self.mission.done:
            self.done.set()

    def close(self) -> None:
        for s in getattr(self, "_subs", ()):
            s.unregister()


def init_node(name: str) -> None:
    """Join the ROS master (``ROS_MASTER_URI``) as node ``name``; a one-line RosError when it is not there."""
    import os

    uri = os.environ.get("ROS_MASTER_URI", "http://localhost:11311")
    try:
        import rosgraph

        if not rosgraph.is_master_online(uri):
            raise RosError(
                f"no ROS master at ROS_MASTER_URI={uri}: start one with `roscore` (or `roscore -p PORT` "
                "and ROS_MASTER_URI=http://localhost:PORT)"
            )
    except ImportError:  # pragma: no cover (rosgraph comes with rospy)
        pass
    rospy.init_node(name, anonymous=False, disable_signals=True)


class RosCore:
    """A ``roscore`` of our own on a free port (tests, the perf script): ``with RosCore() as uri: ...``; sets
    ``ROS_MASTER_URI`` for this process and its children while it runs."""

    def __init__(self, port: int | None = None, timeout_s: float = 20.0):
        import shutil

        if shutil.which("roscore") is None:
            raise RosError("roscore is not installed: apt-get install ros-core")
        self.port = port or _free_port()
        self.uri = f"http://localhost:{self.port}"
        self.timeout_s = timeout_s
        self.proc = None

    def __enter__(self) -> str:
        import os
        import subprocess

        import rosgraph

        self._old = os.environ.get("ROS_MASTER_URI")
        os.environ["ROS_MASTER_URI"] = self.uri
        self.proc = subprocess.Popen(
            ["roscore", "-p", str(self.port)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        end = time.monotonic() + self.timeout_s
        while not rosgraph.is_master_online(self.uri):
            if self.proc.poll() is not None or time.monotonic() > end:
                self.__exit__()
                raise RosError(f"roscore -p {self.port} did not start within {self.timeout_s:.0f} s")
            time.sleep(0.2)
        return self.uri

    def __exit__(self, *exc) -> None:
        import os
        import signal as _signal

        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, _signal.SIGINT)  # roscore's own group: it stops rosmaster and rosout
            try:
                self.proc.wait(timeout=10)
            except Exception:  # noqa: BLE001 (a stuck roscore: kill its group)
                os.killpg(self.proc.pid, _signal.SIGKILL)
                self.proc.wait()
        if self._old is None:
            os.environ.pop("ROS_MASTER_URI", None)
        else:
            os.environ["ROS_MASTER_URI"] = self._old


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
