"""The mission computer (the paper's "Navigator"): flies the mission by what it perceives.

It reads telemetry from the link (LOCAL_POSITION_NED and ATTITUDE), and sends offboard velocity
and yaw setpoints back to the flight controller. Because it steers by the position it *receives*,
an attack on the link changes the real path while the navigator's own view stays on course.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scart_bench.generator.flight_software.startup import takeoff_after_arm
from scart_bench.generator.params import MissionParams
from scart_bench.generator.physics.rotation import wrap_pi

PHASE_IDLE, PHASE_TAKEOFF, PHASE_MISSION, PHASE_LAND = 0, 1, 2, 3
#: m/s^2: towards an item of a mission file the navigator slows so as to stop there at this deceleration
#: (half MPC_ACC_HOR: the velocity loop lags its setpoint), so a fast leg or a sharp turn does not overshoot
BRAKE_ACC = 1.5


@dataclass
class NavigatorState:
    """Per-flight mission state and the latest telemetry received."""

    phase: np.ndarray  # (N,) int
    seq: np.ndarray  # (N,) index of the current mission item
    hold_until: np.ndarray  # (N,) s
    yaw_sp: np.ndarray  # (N,) rad
    pos: np.ndarray  # (N, 3) last received LOCAL_POSITION_NED position
    vel: np.ndarray  # (N, 3)
    yaw: np.ndarray  # (N,) last received ATTITUDE yaw
    xt_int: np.ndarray  # (N,) integral of the cross-track error on the current leg (m s)


def mission_waypoints(mission: MissionParams, rngs: list[np.random.Generator]) -> tuple[np.ndarray, np.ndarray]:
    """Per-flight mission items (N, K, 3) NED and cruise speeds (N,), with small jitter.

    Items: take-off point above home, the four corners of the square at mission altitude,
    then home at mission altitude (the return leg); landing follows the last item.
    """
    base = [(0.0, 0.0)] + [tuple(c) for c in mission.corners] + [(0.0, 0.0)]
    n = len(rngs)
    wps = np.zeros((n, len(base), 3))
    speeds = np.zeros(n)
    for i, g in enumerate(rngs):
        jitter = g.uniform(-mission.jitter_m, mission.jitter_m, size=(len(base), 3))
        jitter[0, :2] = 0.0
        jitter[-1, :2] = 0.0
        wps[i, :, :2] = np.array(base) + jitter[:, :2]
        wps[i, :, 2] = -(mission.altitude + jitter[:, 2])
        speeds[i] = mission.cruise_speed + g.uniform(-mission.jitter_speed, mission.jitter_speed)
    return wps, speeds


def mission_table(mission: MissionParams, seeds: list[int], rngs: list[np.random.Generator]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-flight mission: items (N, K, 3) NED, cruise speeds (N,), the item table (N, K, 6: north,
    east, down, speed of the leg to the item, hold at it in s, braking deceleration towards it in m/s^2
    or 0) and each flight's last item (N,).

    With ``mission.families`` (and no files) each flight flies the mission its seed draws
    (:func:`scart_bench.generator.flight_software.families.draw_mission`). Without either, every flight
    flies the jittered square (:func:`mission_waypoints`);
    with them, flight ``i`` flies mission file ``seeds[i] mod len(missions)`` as written
    (:mod:`scart_bench.generator.flight_software.mission_files`). A flight with fewer items than the batch's longest
    repeats its last one; it lands after its own last item all the same.
    """
    if mission.families and not mission.missions:  # a mix of families (generator.flight_software.families)
        from scart_bench.generator.flight_software.families import draw_mission

        draws = [draw_mission(s, mission) for s in seeds]
        k = max(len(d.items) for d in draws)
        table = np.array([np.vstack([d.items, np.repeat(d.items[-1:], k - len(d.items), axis=0)]) for d in draws])
        last = np.array([len(d.items) - 1 for d in draws], dtype=np.int64)
        return table[:, :, :3].copy(), np.array([d.cruise_speed for d in draws]), table, last
    if not mission.missions:
        wps, cruise = mission_waypoints(mission, rngs)
        table = np.zeros(wps.shape[:2] + (6,))
        table[:, :, :3] = wps
        table[:, :, 3] = cruise[:, None]
        return wps, cruise, table, np.full(len(rngs), wps.shape[1] - 1, dtype=np.int64)
    from scart_bench.generator.flight_software.mission_files import mission_for_seed

    flown = [mission.missions[mission_for_seed(mission.missions, s)].navigator_items(mission.cruise_speed)
             for s in seeds]
    k = max(len(t) for t in flown)
    table = np.array([np.vstack([t, np.repeat(t[-1:], k - len(t), axis=0)]) for t in flown])
    table = np.concatenate([table, np.full(table.shape[:2] + (1,), BRAKE_ACC)], axis=2)
    last = np.array([len(t) - 1 for t in flown], dtype=np.int64)
    return table[:, :, :3].copy(), table[:, 0, 3].copy(), table, last


class Navigator:
    """Mission state machine for a batch: arm, take off, mission items, land."""

    def __init__(self, mission: MissionParams, waypoints: np.ndarray, cruise: np.ndarray,
                 arm_s: np.ndarray | None = None, table: np.ndarray | None = None, last: np.ndarray | None = None):
        self.m = mission
        self.wps = waypoints
        self.cruise = cruise
        #: (N,) when each flight arms (generator.flight_software.startup); default: the mission's arm_delay_s
        self.arm_s = np.full(waypoints.shape[0], mission.arm_delay_s) if arm_s is None else np.asarray(arm_s)
        n, k = waypoints.shape[:2]
        #: (N, K) speed of the leg to each item and hold at it (s), (N,) each flight's last item
        #: (:func:`mission_table`; default: the cruise speed on every leg, no holds, all K items)
        self.speeds = np.repeat(np.asarray(cruise, dtype=float)[:, None], k, axis=1) if table is None else table[:, :, 3]
        self.holds = np.zeros((n, k)) if table is None else table[:, :, 4]
        self.brake = np.zeros((n, k)) if table is None else table[:, :, 5]
        self.last = np.full(n, k - 1, dtype=np.int64) if last is None else np.asarray(last, dtype=np.int64)

    def init_state(self, n: int, yaw0: np.ndarray) -> NavigatorState:
        return NavigatorState(
            phase=np.zeros(n, dtype=np.int64), seq=np.zeros(n, dtype=np.int64), hold_until=np.zeros(n),
            yaw_sp=yaw0.copy(), pos=np.zeros((n, 3)), vel=np.zeros((n, 3)), yaw=yaw0.copy(),
            xt_int=np.zeros(n),
        )

    def receive(self, s: NavigatorState, topic: str, values: np.ndarray, delivered: np.ndarray,
                fields: tuple[str, ...]) -> None:
        """Take in a telemetry message (only rows whose message was delivered)."""
        if topic == "local_position_ned":
            s.pos[delivered] = values[delivered][:, 0:3]
            s.vel[delivered] = values[delivered][:, 3:6]
        elif topic == "attitude":
            s.yaw[delivered] = values[delivered][:, fields.index("yaw")]

    def step(self, s: NavigatorState, t: float) -> np.ndarray:
        """The setpoint message (N, 6): vx, vy, vz, yaw, seq, armed."""
        m = self.m
        n = s.phase.shape[0]
        out = np.zeros((n, 6))
        armed = t >= self.arm_s
        start = (s.phase == PHASE_IDLE) & (t >= self.arm_s + takeoff_after_arm(self.m.ground_phase))
        s.phase[start] = PHASE_TAKEOFF
        k_last = self.last
        rows = np.arange(n)
        ti = np.minimum(s.seq, k_last)
        target = self.wps[rows, ti]
        d = target - s.pos
        dist_h = np.hypot(d[:, 0], d[:, 1])
        flying = (s.phase == PHASE_TAKEOFF) | (s.phase == PHASE_MISSION)
        brake = self.brake[rows, ti]
        # a fly-through item (brake < 0: an orbit's points, a pilot's stick): passed at the leg's speed
        speed = np.where(brake < 0, self.speeds[rows, ti], np.minimum(self.speeds[rows, ti], m.approach_gain * dist_h))
        # a mission file's item: slow down so as to stop there (sharp turns, faster legs); the square does not
        speed = np.where(brake > 0, np.minimum(speed, np.sqrt(2.0 * np.maximum(brake, 0.0) * dist_h)), speed)
        speed = np.where(s.phase == PHASE_TAKEOFF, np.minimum(speed, 1.0), speed)
        dir_h = d[:, :2] / np.maximum(dist_h, 1e-6)[:, None]
        vh = dir_h * speed[:, None]
        # on a leg, follow the line from the previous item (PI on the cross-track error), as a
        # mission computer does; the integral carries over legs (a steady sideways push stays one)
        prev = self.wps[np.arange(n), np.clip(s.seq - 1, 0, k_last)]
        leg = target[:, :2] - prev[:, :2]
        leg_len = np.linalg.norm(leg, axis=1)
        u = leg / np.maximum(leg_len, 1e-6)[:, None]
        normal = np.column_stack([-u[:, 1], u[:, 0]])
        xt = np.einsum("ni,ni->n", s.pos[:, :2] - prev[:, :2], normal)
        on_leg = (s.phase == PHASE_MISSION) & (leg_len > 1.0)
        dt = 1.0 / 50.0
        s.xt_int = np.where(on_leg, np.clip(s.xt_int + xt * dt * (np.abs(xt) < 5.0), -10.0, 10.0), 0.0)
        side = np.clip(-(0.8 * xt + 0.3 * s.xt_int), -0.7 * speed, 0.7 * speed)
        along = np.sqrt(np.maximum(speed**2 - side**2, 0.0))
        # a fly-through leg: along the line itself (its end is passed, not aimed at)
        v_line = along[:, None] * np.where((brake < 0)[:, None], u, dir_h) + side[:, None] * normal
        vh = np.where(on_leg[:, None], v_line, vh)
        vz = np.clip(1.0 * d[:, 2], -m.climb_speed, 1.5)
        out[:, 0:2] = np.where(flying[:, None], vh, 0.0)
        out[:, 2] = np.where(flying, vz, 0.0)
        turn = flying & (dist_h > 3.0) & (s.phase == PHASE_MISSION)
        # turn towards the next item no faster than MPC_YAWRAUTO_MAX, as PX4's auto modes do
        step_max = m.yaw_rate_max * dt
        turn_by = np.clip(wrap_pi(np.arctan2(d[:, 1], d[:, 0]) - s.yaw_sp), -step_max, step_max)
        s.yaw_sp = np.where(turn, wrap_pi(s.yaw_sp + turn_by), s.yaw_sp)
        radius = np.where(brake < 0, -brake, m.acceptance_radius)  # a fly-through item's own radius
        # a fly-through item is also passed once the vehicle is abreast of it
        abreast = (brake < 0) & on_leg & (np.einsum("ni,ni->n", s.pos[:, :2] - prev[:, :2], u) >= leg_len)
        reached = flying & ((dist_h < radius) | abreast) & (np.abs(d[:, 2]) < 0.5)
        # take-off item: hold for takeoff_hold_s once reached
        tk = reached & (s.phase == PHASE_TAKEOFF)
        new_hold = tk & (s.hold_until == 0)
        s.hold_until[new_hold] = t + m.takeoff_hold_s
        go = tk & (s.hold_until > 0) & (t >= s.hold_until)
        s.phase[go] = PHASE_MISSION
        s.seq[go] += 1
        s.hold_until[go] = -1.0  # no hold begun at the next item
        adv = reached & (s.phase == PHASE_MISSION) & ~go
        # an item with a hold time (NAV_WAYPOINT param1, NAV_LOITER_TIME): stay from its arrival until it has passed
        hold = self.holds[rows, ti]
        wait = adv & (hold > 0)
        begin = wait & (s.hold_until < 0)
        s.hold_until[begin] = t + hold[begin]
        adv &= ~wait | (t >= s.hold_until)
        last = adv & (s.seq >= k_last)
        s.seq[adv & ~last] += 1
        s.hold_until[adv & ~last] = -1.0
        s.phase[last] = PHASE_LAND
        land = s.phase == PHASE_LAND
        home = self.wps[rows, k_last, :2]
        dh = home - s.pos[:, :2]
        vh_land = np.clip(1.0 * dh, -1.0, 1.0)
        out[land, 0:2] = vh_land[land]
        alt = -s.pos[:, 2]
        out[land, 2] = np.where(alt[land] > 3.0, 1.5, m.land_speed)
        out[:, 3] = s.yaw_sp
        out[:, 4] = s.seq
        out[:, 5] = armed
        return out
