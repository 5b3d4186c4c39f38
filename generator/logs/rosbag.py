"""ROS bags: ROS 1 ``.bag`` files and ROS 2 bag folders (sqlite3 ``.db3`` or MCAP storage), read with
the ``rosbags`` library (pure Python: no ROS installation needed).

The rules (docs/own_logs.md):

- **Time**: each message's record time in the bag (its receive time); time zero is the start of
  the bag, whichever topics are asked for. The messages' own stamps (``header_stamp_sec`` ...,
  px4_msgs ``timestamp_sample``) stay fields.
- **MAVROS topics** with a meaning are mapped to the project's link topics and conventions
  (:data:`MAVROS`): ``/mavros/global_position/global`` -> ``global_position_int`` (lat, lon in
  degrees, alt in m), ``/mavros/global_position/raw/fix`` -> ``gps_raw_int``,
  ``/mavros/global_position/rel_alt`` -> ``altitude.altitude_relative``,
  ``/mavros/local_position/pose`` -> ``local_position_ned`` (ENU to NED: x north, y east, z down),
  ``/mavros/imu/data`` -> ``highres_imu`` (FLU to FRD: z about -9.8 at rest),
  ``/mavros/battery`` -> ``battery_status`` (voltage, current, remaining 0..1),
  ``/mavros/extended_state`` -> ``extended_sys_state`` (landed_state). A namespace before
  ``/mavros`` is allowed.
- **PX4 uXRCE-DDS topics** (``px4_msgs``, ``/fmu/out/<topic>``) keep their uORB names and
  fields, as in a ULog: ``/fmu/out/vehicle_gps_position`` -> ``vehicle_gps_position``, a
  version suffix dropped (``vehicle_status_v1`` -> ``vehicle_status``), arrays as ``q_0`` ...,
  integer lat/lon (1e-7 deg) and alt (mm) in degrees and metres, ``timestamp`` dropped.
- **Other topics**: the topic name sanitised (``/camera/info`` -> ``camera_info``), every numeric
  field flattened (``header.stamp.sec`` -> ``header_stamp_sec``, arrays ``_0``, ``_1`` ...); text,
  lists of messages and the message definition's constants (``STATUS_FIX``: no reading) dropped.
- **Orientations** stay ROS quaternions (ENU world, FLU body; ``orientation_w`` ...; MAVROS
  ``imu/data`` and ``local_position/pose`` keep theirs); csv mode reads them as roll, pitch and
  yaw (generator.logs.orientation).
- A bag that cannot be opened is an error; one that fails while read is refused unless
  ``allow_corrupt`` (then the messages read before the failure are used).
"""

from __future__ import annotations

import dataclasses
import logging
import re
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.dataset import DatasetError
from scart_bench.generator.logs.tables import RawTopics, sanitize_topic_name

logger = logging.getLogger(__name__)

#: MAVROS topic (after ``/mavros/``) -> (project topic, {field: (flattened ROS field, sign)}).
MAVROS: dict[str, tuple[str, dict[str, tuple[str, float]]]] = {
    "global_position/global": ("global_position_int", {
        "lat": ("latitude", 1.0), "lon": ("longitude", 1.0), "alt": ("altitude", 1.0)}),
    "global_position/raw/fix": ("gps_raw_int", {
        "lat": ("latitude", 1.0), "lon": ("longitude", 1.0), "alt": ("altitude", 1.0)}),
    "global_position/rel_alt": ("altitude", {"altitude_relative": ("data", 1.0)}),
    "local_position/pose": ("local_position_ned", {  # ENU -> NED
        "x": ("pose_position_y", 1.0), "y": ("pose_position_x", 1.0), "z": ("pose_position_z", -1.0),
        **{f"pose_orientation_{a}": (f"pose_orientation_{a}", 1.0) for a in "wxyz"}}),  # as in ROS: ENU/FLU
    "imu/data": ("highres_imu", {  # FLU body -> FRD body
        "xacc": ("linear_acceleration_x", 1.0), "yacc": ("linear_acceleration_y", -1.0),
        "zacc": ("linear_acceleration_z", -1.0), "xgyro": ("angular_velocity_x", 1.0),
        "ygyro": ("angular_velocity_y", -1.0), "zgyro": ("angular_velocity_z", -1.0),
        **{f"orientation_{a}": (f"orientation_{a}", 1.0) for a in "wxyz"}}),  # as in ROS: ENU world, FLU body
    "battery": ("battery_status", {
        "voltage": ("voltage", 1.0), "current": ("current", 1.0), "remaining": ("percentage", 1.0)}),
    "extended_state": ("extended_sys_state", {
        "landed_state": ("landed_state", 1.0), "vtol_state": ("vtol_state", 1.0)}),
}
BAG_SUFFIXES = (".bag", ".db3", ".mcap")


def bag_path(path: Path) -> Path:
    """The path rosbags opens: a ROS 1 ``.bag`` file, or the ROS 2 bag folder (``metadata.yaml``)
    of a folder or of a ``.db3`` / ``.mcap`` file in it."""
    if path.is_dir() or path.suffix.lower() == ".bag":
        return path
    if (path.parent / "metadata.yaml").exists():
        return path.parent
    raise DatasetError(f"{path}: a ROS 2 bag is read from its folder, which holds metadata.yaml beside the "
                       f"{path.suffix} file; {path.parent} has none (expected the folder ros2 bag record wrote)")


def is_constant(f: dataclasses.Field) -> bool:
    """A message definition's constant (``uint8 STATUS_FIX=0``): rosbags declares it a ``ClassVar`` field
    with its value as default; it is the same in every message, no reading."""
    return str(f.type).replace("typing.", "").startswith("ClassVar")


def flatten(msg, prefix: str = "") -> dict[str, float]:
    """A message's numeric fields, nested names joined by ``_``, arrays expanded ``_0``, ``_1`` ..."""
    out: dict[str, float] = {}
    for f in dataclasses.fields(msg):
        if f.name == "__msgtype__" or is_constant(f):
            continue
        value = getattr(msg, f.name)
        name = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            out.update(flatten(value, f"{name}_"))
        elif isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
            out.update({f"{name}_{k}": float(v) for k, v in enumerate(value.ravel())})
        elif isinstance(value, (bool, int, float, np.number)):
            out[name] = float(value)
    return out


def topic_rule(topic: str, msgtype: str) -> tuple[str, str]:
    """(table name, rule: ``mavros``, ``px4`` or ``generic``) of a bag topic."""
    m = re.search(r"(?:^|/)mavros/(.+)$", topic)
    if m and m.group(1) in MAVROS:
        return MAVROS[m.group(1)][0], "mavros"
    if msgtype.startswith("px4_msgs/") and "/fmu/out/" in topic:
        return re.sub(r"_v\d+$", "", sanitize_topic_name(topic.split("/fmu/out/", 1)[1])), "px4"
    return sanitize_topic_name(topic), "generic"


def px4_fields(fields: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict]:
    """A px4_msgs message's fields as the ULog importer gives them: older messages hold ``lat``/``lon``
    as int32 1e-7 degrees (seen here as values beyond +/-180) and ``alt``/``alt_ellipsoid`` in mm."""
    lat, lon = fields.get("lat"), fields.get("lon")
    if lat is None or lon is None or not (np.nanmax(np.abs(np.r_[lat, lon])) > 180.0):
        return fields, {}
    out = {**fields, "lat": lat / 1e7, "lon": lon / 1e7}
    converted = {"lat": "degE7 -> deg", "lon": "degE7 -> deg"}
    for alt in ("alt", "alt_ellipsoid"):
        if alt in fields:
            out[alt] = fields[alt] / 1e3
            converted[alt] = "mm -> m"
    return out, {"converted": converted}


def _fields(topic: str, rule: str, rows: list[dict[str, float]]) -> tuple[dict[str, np.ndarray], dict]:
    table = pd.DataFrame(rows, dtype=np.float64)
    if rule == "mavros":
        key = re.search(r"mavros/(.+)$", topic).group(1)
        mapping = MAVROS[key][1]
        have = {k: v for k, v in mapping.items() if v[0] in table.columns}
        return {k: table[src].to_numpy() * sign for k, (src, sign) in have.items()}, {"ros_topic": topic}
    fields = {c: table[c].to_numpy() for c in table.columns}
    if rule == "px4":
        fields.pop("timestamp", None)
        fields, notes = px4_fields(fields)
        return fields, {"ros_topic": topic, **notes}
    return fields, {"ros_topic": topic}


def read_rosbag(path: Path, topics: list[str] | None = None, allow_corrupt: bool = False) -> tuple[RawTopics, int]:
    """(raw topics, time zero in microseconds) of a ROS 1 or ROS 2 bag; see the module doc."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError as exc:
        raise DatasetError(f"{path}: reading ROS bags needs the 'rosbags' package (pip install "
                           "'scart-bench[ros]')") from exc
    bag = bag_path(path)
    try:
        reader = AnyReader([bag])
        reader.open()
    except Exception as exc:
        raise DatasetError(f"{path}: not a readable ROS bag ({type(exc).__name__}: {exc}); expected a ROS 1 .bag file "
                           "or a ROS 2 bag folder (metadata.yaml with .db3 or .mcap storage)") from exc
    try:
        names = {c.id: topic_rule(c.topic, c.msgtype) for c in reader.connections}
        by_name: dict[str, str] = {}
        for c in reader.connections:
            other = by_name.setdefault(names[c.id][0], c.topic)
            if other != c.topic:
                raise DatasetError(f"{path}: bag topics {other!r} and {c.topic!r} both become topic "
                                   f"{names[c.id][0]!r}; expected one of them")
        if topics is not None:
            missing = [t for t in topics if t not in by_name]
            if missing:
                raise DatasetError(f"{path}: topic(s) {missing} not found in the bag; it has: {sorted(by_name)} "
                                   f"(from {sorted(by_name.values())})")
        wanted = [c for c in reader.connections if topics is None or names[c.id][0] in topics]
        origin = int(reader.start_time) // 1000
        rows: dict[int, list] = {c.id: [] for c in wanted}
        times: dict[int, list[int]] = {c.id: [] for c in wanted}
        damage: dict = {}
        try:
            for conn, t_ns, data in reader.messages(connections=wanted):
                rows[conn.id].append(flatten(reader.deserialize(data, conn.msgtype)))
                times[conn.id].append((int(t_ns) + 500) // 1000)
        except Exception as exc:
            n = sum(len(v) for v in rows.values())
            if not allow_corrupt:
                raise DatasetError(f"{path}: the bag failed after {n} message(s) ({type(exc).__name__}: {exc}); pass "
                                   "--allow-corrupt (allow_corrupt=True) to use what was read") from exc
            logger.warning("%s: the bag failed after %d message(s) (%s); using them", path, n, exc)
            damage = {"file_corruption": True}
    finally:
        reader.close()
    raw: RawTopics = {}
    for c in wanted:
        if not rows[c.id]:
            continue
        name, rule = names[c.id]
        fields, notes = _fields(c.topic, rule, rows[c.id])
        raw[name] = (np.asarray(times[c.id], dtype=np.int64), fields, {**notes, "ros_type": c.msgtype, **damage})
    return dict(sorted(raw.items())), origin
