"""The flight controller's commander: commands it accepts, its modes and its link-loss failsafe.

Both flight engines (the numpy reference step and the compiled kernel's hooks) run this same code
at the ``command`` injection point, on the setpoint the navigator sent, after the SCART layer:

- a COMMAND_LONG (``command_long``, usually forged by ``inject_command``) is accepted as PX4's
  commander would: only when it is addressed to this vehicle (target system, and target component
  or broadcast 0) and the vehicle is armed; disarming in the air needs the force code 21196;
- modes: ``offboard`` (the navigator's setpoints fly the vehicle), ``hold`` (position hold where
  entered), ``return`` (climb to the return altitude, fly home, land), ``land`` (descend where
  entered), ``goto`` (a DO_REPOSITION target, then hold), ``disarmed`` (motors off: in the air the
  vehicle falls; an impact faster than ``crash_speed`` ends the flight as crashed);
- link loss (PX4's rules and defaults, configurable in :class:`ControlParams`, the same as the live
  sitl's commander): with no setpoint for ``offboard_loss_s`` (COM_OF_LOSS_T) the vehicle takes
  ``offboard_loss_action`` (COM_OBL_ACT: land by default, or hold / return); while it holds, with no
  message from the navigator for ``datalink_loss_s`` (COM_DL_LOSS_T) it takes ``datalink_action``
  (NAV_DLL_ACT). When setpoints come back, a vehicle that only held resumes offboard (the mission
  computer re-engages it, as MAVSDK's ``offboard.start`` does); after a land or return it resumes
  only with ``resume_after_action``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scart_bench.dataset.schema import HOME_ALT
from scart_bench.generator.geo import latlon_to_ned

MODES = ("offboard", "hold", "return", "land", "goto", "disarmed")
OFFBOARD, HOLD, RETURN, LAND, GOTO, DISARMED = range(len(MODES))

#: COMMAND_LONG message of the command point: MAVLink's fields, in order.
COMMAND_FIELDS = ("command", "param1", "param2", "param3", "param4", "param5", "param6", "param7",
                  "target_system", "target_component")
#: MAV_CMD numbers the commander understands.
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_REPOSITION = 192
MAV_CMD_COMPONENT_ARM_DISARM = 400
#: PX4's magic number in param2 of a disarm that must go through in the air.
FORCE_DISARM = 21196.0
#: PX4 custom main modes (param2 of DO_SET_MODE) and AUTO sub modes (param3).
PX4_MAIN_POSCTL, PX4_MAIN_AUTO, PX4_MAIN_OFFBOARD = 3, 4, 6
PX4_SUB_LOITER, PX4_SUB_RTL, PX4_SUB_LAND = 3, 5, 6
#: The mission as the navigator receives it (MISSION_ITEM_INT, local NED): up to this many items.
MAX_MISSION_ITEMS = 32
MISSION_FIELDS = tuple(f"item{k}_{a}" for k in range(MAX_MISSION_ITEMS) for a in ("n", "e", "d"))

#: COM_OBL_ACT: the failsafe taken when offboard setpoints are lost, by PX4's parameter value
#: (PX4 v1.13, the no-RC case: 0 Land, its default, 1 Hold, 2 Return). The live sitl reads the same table.
OFFBOARD_LOSS_ACTIONS = ("land", "hold", "return")

#: Topics of the command point besides the setpoint, with their fields.
CONTROL_TOPICS: dict[str, tuple[str, ...]] = {"command_long": COMMAND_FIELDS, "mission": MISSION_FIELDS}


@dataclass(frozen=True)
class ControlParams:
    """The commander's parameters (PX4 names and defaults where PX4 has them)."""

    target_system: int = 1  # MAV_SYS_ID
    target_component: int = 1  # the autopilot's component id
    offboard_loss_s: float = 1.0  # COM_OF_LOSS_T: no setpoint for this long -> offboard_loss_action
    offboard_loss_action: str = "land"  # COM_OBL_ACT: "land" (PX4's default), "hold" or "return"
    datalink_loss_s: float = 10.0  # COM_DL_LOSS_T: holding, nothing from the navigator this long -> action
    datalink_action: str = "return"  # NAV_DLL_ACT: "hold", "return" or "land"
    resume_after_action: bool = False  # back to offboard after the datalink action when the link returns
    return_alt_m: float = 10.0  # RTL_RETURN_ALT (PX4: 60 m; here the mission altitude)
    return_speed: float = 5.0  # MPC_XY_CRUISE
    land_speed: float = 0.7  # MPC_LAND_SPEED below 3 m (1.5 m/s above)
    crash_speed: float = 3.0  # m/s, true descent rate at touchdown that counts as a crash
    brake_speed: float = 0.3  # m/s: a hold or land locks its position once slower than this

    def __post_init__(self) -> None:
        for name in ("offboard_loss_action", "datalink_action"):
            if getattr(self, name) not in OFFBOARD_LOSS_ACTIONS:
                raise ValueError(f"control.{name}: expected one of {list(OFFBOARD_LOSS_ACTIONS)}, "
                                 f"got {getattr(self, name)!r}")


def empty_command(n: int) -> np.ndarray:
    """(N, 10) COMMAND_LONG rows that carry no command (command 0)."""
    return np.zeros((n, len(COMMAND_FIELDS)))


def mission_message(waypoints: np.ndarray) -> np.ndarray:
    """(N, 3 * MAX_MISSION_ITEMS) the mission items (N, K, 3) as one message, NaN-padded; a mission
    of more items (a long survey, a hand-flown flight's stick samples) carries its first
    MAX_MISSION_ITEMS (:func:`exchange` flies the rest as they are)."""
    n, k, _ = waypoints.shape
    k = min(k, MAX_MISSION_ITEMS)
    out = np.full((n, 3 * MAX_MISSION_ITEMS), np.nan)
    out[:, :3 * k] = waypoints[:, :k].reshape(n, 3 * k)
    return out


def mission_items(message: np.ndarray, k: int) -> np.ndarray:
    """(N, k, 3) the first ``k`` mission items of a mission message."""
    return message[:, :3 * k].reshape(message.shape[0], k, 3)


_ACTION_MODES = {"hold": HOLD, "land": LAND, "return": RETURN}


class BatchCommander:
    """Per-flight commander state for a batch, stepped at the setpoint rate."""

    def __init__(self, params: ControlParams, n: int, home: np.ndarray, land_speed: float):
        self.p = params
        self.mode = np.zeros(n, dtype=np.int64)
        self.failsafe = np.zeros(n, dtype=bool)  # the mode was entered by the link-loss failsafe
        self.target = np.zeros((n, 3))  # hold / land / goto position (NED m)
        self.yaw = np.zeros(n)
        self.last_sp_t = np.zeros(n)  # time of the last setpoint delivered
        self.prev_vd = np.zeros(n)  # true descent rate at the previous call
        self.vel = np.zeros((n, 3))  # estimated velocity at this call
        self.braking = np.zeros(n, dtype=bool)  # slowing down before the hold position is locked
        self.home = np.asarray(home, dtype=float)[:, :2]
        self.land_speed = land_speed
        #: (flight, time s, command, accepted, reason) of every command received
        self.log: list[tuple[int, float, int, bool, str]] = []

    def _enter(self, rows: np.ndarray, mode: int, pos: np.ndarray, yaw: np.ndarray) -> None:
        """Switch ``rows`` to ``mode``; a hold or land first brakes, then holds the point where it stopped
        (PX4 locks the position once the vehicle has slowed down)."""
        self.mode[rows] = mode
        self.target[rows] = pos[rows]
        self.braking[rows] = True
        self.yaw[rows] = yaw[rows]

    def step(self, t: float, sp: np.ndarray, sp_ok: np.ndarray, command: np.ndarray | None, est_pos: np.ndarray,
             est_vel: np.ndarray, yaw_in: np.ndarray, armed: np.ndarray, true_vd: np.ndarray, on_ground: np.ndarray, done: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The setpoint the controllers use and whether it is new: (sp (N, 6), ok (N,), crashed (N,)).

        ``sp``/``sp_ok``: the setpoint that reached the flight controller; ``command``: (N, 10)
        COMMAND_LONG rows (or None); ``est_pos``/``est_vel`` (N, 3) its position and velocity estimates; ``yaw_in`` (N,) the
        yaw setpoint in use (kept by the commander's own modes); ``armed`` (N,) its
        armed state before this setpoint; ``true_vd``/``on_ground``: the vehicle's true descent rate
        and ground contact (for the impact check only); ``done``: flights that have ended.
        """
        p = self.p
        live = ~done
        self.vel = np.asarray(est_vel, dtype=float)
        sp_ok = np.asarray(sp_ok, dtype=bool)
        yaw_now = np.asarray(yaw_in, dtype=float)
        self.last_sp_t[sp_ok & live] = t
        if command is not None:
            self._commands(t, command, est_pos, armed & live, yaw_now)
        # link-loss failsafe
        silent = t - self.last_sp_t
        off = live & (self.mode == OFFBOARD) & armed & (silent >= p.offboard_loss_s)
        if off.any():
            rows = np.flatnonzero(off)
            self._enter(rows, _ACTION_MODES[p.offboard_loss_action], est_pos, yaw_now)
            self.failsafe[rows] = True
        dl = live & self.failsafe & (self.mode == HOLD) & (silent >= p.datalink_loss_s)
        if dl.any() and p.datalink_action != "hold":
            self._enter(np.flatnonzero(dl), _ACTION_MODES[p.datalink_action], est_pos, yaw_now)
        regained = live & self.failsafe & sp_ok
        back = regained & ((self.mode == HOLD) | p.resume_after_action)
        self.mode[back] = OFFBOARD
        self.failsafe[back] = False
        settled = self.braking & (np.hypot(self.vel[:, 0], self.vel[:, 1]) < p.brake_speed)
        self.target[settled, :2] = est_pos[settled, :2]
        self.braking &= ~settled
        # the setpoint the controllers use
        out = np.array(sp, dtype=float, copy=True)
        ok = sp_ok.copy()
        own = live & (self.mode != OFFBOARD)
        if own.any():
            mode_sp = self._mode_setpoint(est_pos, out)
            out[own] = mode_sp[own]
            ok[own] = True
        # impact: a vehicle that fell (disarmed in the air) hitting the ground
        crashed = live & on_ground & (self.prev_vd > p.crash_speed) & (self.mode == DISARMED)
        self.prev_vd = np.where(on_ground, 0.0, true_vd)
        return out, ok, crashed

    def _mode_setpoint(self, pos: np.ndarray, sp: np.ndarray) -> np.ndarray:
        """Velocity setpoints (N, 6) of the commander's own modes (every row; used where not offboard)."""
        p = self.p
        out = sp.copy()
        alt = -pos[:, 2]
        d = self.target[:, :2] - pos[:, :2]
        hold_v = np.where(self.braking[:, None], 0.0, np.clip(1.0 * d, -p.return_speed, p.return_speed))
        vz_hold = np.clip(1.0 * (self.target[:, 2] - pos[:, 2]), -2.5, 1.5)
        descend = np.where(alt > 3.0, 1.5, self.land_speed)
        # return: climb to the return altitude, fly home, then land there
        dh = self.home - pos[:, :2]
        dist = np.hypot(dh[:, 0], dh[:, 1])
        speed = np.minimum(p.return_speed, 1.0 * dist)
        v_home = dh / np.maximum(dist, 1e-6)[:, None] * speed[:, None]
        low = alt < p.return_alt_m - 0.5
        at_home = dist < 1.0
        ret_v = np.where((low & ~at_home)[:, None], 0.0, v_home)
        ret_vz = np.where(at_home, descend, np.where(low, -2.5, np.clip(-(p.return_alt_m - alt), -2.5, 1.5)))
        m = self.mode
        out[:, 0:2] = np.where((m == RETURN)[:, None], ret_v, hold_v)
        out[:, 2] = np.select([m == RETURN, m == LAND], [ret_vz, descend], vz_hold)
        out[:, 3] = self.yaw
        out[:, 5] = np.where(m == DISARMED, 0.0, 1.0)
        out[m == DISARMED, 0:3] = 0.0
        return out

    def _commands(self, t: float, cmd: np.ndarray, pos: np.ndarray, armed: np.ndarray, yaw: np.ndarray) -> None:
        """Accept or refuse the COMMAND_LONGs received (command 0: none)."""
        p = self.p
        for i in np.flatnonzero(cmd[:, 0] != 0):
            c = cmd[i]
            number = int(round(c[0]))
            if int(round(c[8])) != p.target_system or int(round(c[9])) not in (0, p.target_component):
                self.log.append((int(i), t, number, False, "not addressed to this vehicle"))
                continue
            if not armed[i]:
                self.log.append((int(i), t, number, False, "vehicle not armed"))
                continue
            rows = np.array([i])
            in_air = -pos[i, 2] > 0.5
            mode = None
            if number == MAV_CMD_COMPONENT_ARM_DISARM and c[1] < 0.5:
                if in_air and abs(c[2] - FORCE_DISARM) > 0.5:
                    self.log.append((int(i), t, number, False, "disarm refused in the air (no force code)"))
                    continue
                mode = DISARMED
            elif number == MAV_CMD_NAV_LAND:
                mode = LAND
            elif number == MAV_CMD_NAV_RETURN_TO_LAUNCH:
                mode = RETURN
            elif number == MAV_CMD_DO_REPOSITION:
                x, y = latlon_to_ned(np.array([c[5]]), np.array([c[6]]))
                self._enter(rows, GOTO, pos, yaw)
                self.braking[i] = False
                self.target[i] = (x[0], y[0], -(c[7] - HOME_ALT))
                self.failsafe[i] = False
                self.log.append((int(i), t, number, True, "reposition"))
                continue
            elif number == MAV_CMD_DO_SET_MODE:
                main, sub = int(round(c[2])), int(round(c[3]))
                mode = {(PX4_MAIN_POSCTL, 0): HOLD, (PX4_MAIN_AUTO, PX4_SUB_LOITER): HOLD,
                        (PX4_MAIN_AUTO, PX4_SUB_RTL): RETURN, (PX4_MAIN_AUTO, PX4_SUB_LAND): LAND,
                        (PX4_MAIN_OFFBOARD, 0): OFFBOARD}.get((main, sub if main == PX4_MAIN_AUTO else 0))
            if mode is None:
                self.log.append((int(i), t, number, False, "unsupported command"))
                continue
            self._enter(rows, mode, pos, yaw)
            self.failsafe[i] = False
            self.log.append((int(i), t, number, True, MODES[mode]))


def exchange(layer, step: int, t_us: int, sp: np.ndarray, mission: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """The command point's messages through the layer: the setpoint the navigator sent, no command
    (an attack may forge one) and the mission items (N, K, 3) it flies (an attack may tamper with
    them). Returns (setpoint, delivered, COMMAND_LONG rows that arrived or None, mission items)."""
    n, k, _ = mission.shape
    msgs = {"setpoint": sp, "command_long": empty_command(n), "mission": mission_message(mission)}
    out = layer.on_messages("command", step, t_us, msgs)
    sp_vals, sp_ok = out["setpoint"]
    cmd_vals, cmd_ok = out["command_long"]
    cmd_ok = np.asarray(cmd_ok, dtype=bool)
    command = None
    if (cmd_vals[:, 0] != 0).any():
        command = np.where(cmd_ok[:, None], cmd_vals, 0.0)
    m_vals, m_ok = out["mission"]
    kk = min(k, MAX_MISSION_ITEMS)  # the items the message carries; any after them fly as they are
    head = np.where(np.asarray(m_ok, dtype=bool)[:, None, None], mission_items(m_vals, kk), mission[:, :kk])
    items = mission.copy() if kk < k else np.empty_like(mission)
    items[:, :kk] = np.where(np.isfinite(head), head, mission[:, :kk])
    return sp_vals, np.asarray(sp_ok, dtype=bool), command, items
