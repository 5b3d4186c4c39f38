"""A recording's topics as csv mode's layer sees them: attitude by meaning, constants marked.

:func:`listen_view` (the layer's view of a recording; generator.logs.offline.with_phases):

- a topic that logs its attitude as a quaternion (PX4's ``vehicle_attitude.q``, a ROS orientation)
  and is a candidate of ``attitude.roll`` (generator.scart.meanings) gets ``roll``, ``pitch`` and
  ``yaw`` fields derived from it (rad; ZYX, FRD body in the NED world, as PX4 and MAVLink's
  ATTITUDE; a ROS orientation is ENU/FLU and converted), so scenarios on attitude apply to it;
- every candidate field of a quantity an action may target that reads one value for the whole flight
  (a zero GPS latitude on a log without GPS, an EKF position held at 0) is listed in the table's
  ``attrs["constant_fields"]``: resolution by meaning leaves it out (it is no measurement to attack).

:func:`recorded_view` turns the replayed tables back into the recording's fields: where an attack
changed a derived angle, the quaternion is rebuilt from the attacked roll, pitch and yaw (a rotation:
still a unit quaternion, its roll as read back moved by the attack's amount, pitch and yaw as they
were); rows the attack left alone keep their logged quaternion bit for bit; the derived fields go.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from scart_bench.generator.scart.meanings import CONTROL_QUANTITIES, QUANTITIES

#: Derived attitude fields, in this order.
ANGLES = ("roll", "pitch", "yaw")
#: Quaternion fields, (w, x, y, z) in that order, and their frames: ``ned`` (FRD body -> NED world:
#: PX4, MAVLink) or ``enu`` (FLU body -> ENU world: ROS, REP 103).
QUATERNIONS: tuple[tuple[tuple[str, str, str, str], str], ...] = (
    (("q_0", "q_1", "q_2", "q_3"), "ned"),
    (("qw", "qx", "qy", "qz"), "enu"),  # the ROS node's topics (generator.ros.topics)
    (("orientation_w", "orientation_x", "orientation_y", "orientation_z"), "enu"),  # sensor_msgs/Imu
    (("pose_orientation_w", "pose_orientation_x", "pose_orientation_y", "pose_orientation_z"), "enu"),
)
#: Topics whose quaternion gives the attitude: the candidates of attitude.roll the recording lacks as fields.
ATTITUDE_TOPICS = tuple(c.partition(".")[0] for c in QUANTITIES["attitude"]["roll"])


def euler_from_quaternion(q: np.ndarray, frame: str = "ned") -> np.ndarray:
    """(N, 3) roll, pitch, yaw (rad, ZYX, FRD body in NED) of quaternions ``q`` (N, 4; w, x, y, z)."""
    w, x, y, z = (q[:, i] for i in range(4))
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    if frame == "enu":  # FLU/ENU angles -> FRD/NED: roll as is, pitch negated, yaw from north clockwise
        pitch = -pitch
        yaw = np.arctan2(np.cos(yaw), np.sin(yaw))  # pi/2 - yaw, wrapped to (-pi, pi]
    return np.column_stack([roll, pitch, yaw])


def quaternion_from_euler(angles: np.ndarray, frame: str = "ned") -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z) of roll, pitch, yaw ``angles`` (N, 3; the inverse of
    :func:`euler_from_quaternion`)."""
    roll, pitch, yaw = (angles[:, i] for i in range(3))
    if frame == "enu":
        pitch = -pitch
        yaw = np.pi / 2 - yaw
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.column_stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def quaternion_of(columns) -> tuple[tuple[str, str, str, str], str] | None:
    """The (components, frame) of the first quaternion whose four fields are all in ``columns``."""
    have = set(columns)
    for names, frame in QUATERNIONS:
        if all(n in have for n in names):
            return names, frame
    return None


def _constant_candidates() -> dict[str, set[str]]:
    """topic -> fields that stand for a quantity an action may target (control state excluded)."""
    out: dict[str, set[str]] = {}
    for q, fields in QUANTITIES.items():
        if q in CONTROL_QUANTITIES:
            continue
        for cands in fields.values():
            for c in cands:
                topic, _, fld = c.partition(".")
                out.setdefault(topic, set()).add(fld)
    return out


_CANDIDATES = _constant_candidates()


def constant_fields(df: pd.DataFrame, fields) -> dict[str, float]:
    """field -> its one value, for those of ``fields`` in ``df`` that read one value (or none) for
    the whole flight."""
    out = {}
    for f in fields:
        if f not in df.columns:
            continue
        v = df[f].to_numpy(np.float64)
        ok = v[np.isfinite(v)]
        if v.size and (ok.size == 0 or ok.min() == ok.max()) and ok.size in (0, v.size):
            out[f] = float(ok[0]) if ok.size else float("nan")
    return out


def listen_view(tables: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    """The recording's topics for the layer (see the module doc); the input tables are not changed."""
    out = {}
    for topic, df in tables.items():
        quat = quaternion_of(df.columns) if topic in ATTITUDE_TOPICS else None
        derive = quat is not None and not any(a in df.columns for a in ANGLES)
        const = constant_fields(df, _CANDIDATES.get(topic, ()))
        if not derive and not const:
            out[topic] = df
            continue
        view = df.copy(deep=False)
        if derive:
            names, frame = quat
            q = df[list(names)].to_numpy(np.float64)
            angles = euler_from_quaternion(q, frame)
            for i, a in enumerate(ANGLES):
                view[a] = angles[:, i]
            view.attrs["quaternion"] = tuple(names)
        view.attrs["constant_fields"] = const
        out[topic] = view
    return out


def recorded_view(nav: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    """Replayed tables with the recording's own fields (see the module doc); a topic csv mode left
    out (None: passed unchanged, generator.modes.csv_mode ``leave_passed``) stays None."""
    out = {}
    for topic, df in nav.items():
        if df is None:
            out[topic] = None
            continue
        quat = quaternion_of(df.columns)
        if quat is None or not all(a in df.columns for a in ANGLES):
            out[topic] = df
            continue
        names, frame = quat
        q = df[list(names)].to_numpy(np.float64)
        angles = df[list(ANGLES)].to_numpy(np.float64)
        logged = euler_from_quaternion(q, frame)
        same = (angles == logged) | (np.isnan(angles) & np.isnan(logged))
        moved = ~same.all(axis=1)
        df = df.drop(columns=list(ANGLES))
        if moved.any():
            new = quaternion_from_euler(angles[moved], frame)
            # q and -q are one rotation: keep the logged sign, so that a small attack is a small change
            flip = np.sum(new * q[moved], axis=1) < 0
            new[flip] *= -1
            q = q.copy()
            q[moved] = new
            df = df.copy()
            for i, n in enumerate(names):
                df[n] = q[:, i]
        out[topic] = df
    return out

