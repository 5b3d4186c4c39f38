"""Attacks on the control link itself: whole messages forged, dropped, replayed or crowded out.

- ``inject_command`` (``command`` point): a forged COMMAND_LONG to the flight controller (disarm,
  land, return, hold, set mode, reposition). The flight controller's commander
  (generator.flight_software.commander) accepts it only when PX4 would.
- ``mission_tamper`` (``command`` point): mission items the navigator receives are moved (shifted
  by metres, or replaced by a position).
- ``link_loss``, ``replay``, ``flood`` (``link`` point, both directions: telemetry to the navigator
  and setpoints/commands to the flight controller; in csv mode every topic of the recording):
  nothing gets through; captured messages are played again; flooding frames fill the link so the
  real messages arrive late, and once its queue is full some never arrive.

Their targets default to every topic that passes (``target = ["*"]``), so a scenario may name none.
"""

from __future__ import annotations

import math

import numpy as np

from scart_bench.dataset.schema import COMMAND_TOPICS, HOME_ALT
from scart_bench.generator.flight_software.commander import (
    CONTROL_TOPICS,
    FORCE_DISARM,
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_REPOSITION,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_RETURN_TO_LAUNCH,
    MAX_MISSION_ITEMS,
    PX4_MAIN_AUTO,
    PX4_MAIN_OFFBOARD,
    PX4_MAIN_POSCTL,
    PX4_SUB_LAND,
    PX4_SUB_LOITER,
    PX4_SUB_RTL,
)
from scart_bench.generator.geo import ned_to_latlon
from scart_bench.generator.scart.action_base import MAX_DELAY_S, Action
from scart_bench.generator.scart.spec import Param, ScenarioError

#: Actions on the flight controller or the navigator themselves: only the closed loop (simulation
#: mode) can show them, and they change the simulator view (the vehicle) rather than a message.
CLOSED_LOOP_ACTIONS = ("inject_command", "mission_tamper")
#: ``target = ["*"]``: every topic passing the action's point(s).
ALL = "*"
_ANY_TARGET = Param("target", list, [ALL], help='"*" (every topic that passes) or a list of "topic"', item=str,
                    min_items=1)

COMMANDS = ("disarm", "land", "return", "hold", "set_mode", "reposition")
#: set_mode's ``mode`` -> (PX4 custom main mode, AUTO sub mode)
SET_MODES = {"hold": (PX4_MAIN_AUTO, PX4_SUB_LOITER), "return": (PX4_MAIN_AUTO, PX4_SUB_RTL),
             "land": (PX4_MAIN_AUTO, PX4_SUB_LAND), "offboard": (PX4_MAIN_OFFBOARD, 0), "position": (PX4_MAIN_POSCTL, 0)}


def _col(params: dict, name: str, n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(params[name], dtype=float).reshape(-1), (n,))


class InjectCommand(Action):
    """A forged COMMAND_LONG, sent when the attack starts (and every ``repeat_s`` after, if > 0)."""

    name = "inject_command"
    points = ("command",)
    spec = (Param("target", list, ["command_long"], item=str, min_items=1, max_items=1,
                  help='["command_long"]'),
            Param("command", str, "disarm", choices=COMMANDS),
            Param("mode", str, "hold", choices=tuple(SET_MODES), help="set_mode's mode"),
            Param("force", bool, True, help="disarm with PX4's force code 21196 (needed in the air)"),
            Param("north_m", float, 0.0, help="reposition target, m north of home"),
            Param("east_m", float, 0.0, help="reposition target, m east of home"),
            Param("alt_m", float, 10.0, minimum=0.0, maximum=10_000.0, help="reposition altitude above home"),
            Param("target_system", int, 1, minimum=0, maximum=255),
            Param("target_component", int, 1, minimum=0, maximum=255),
            Param("repeat_s", float, 0.0, minimum=0.0, maximum=MAX_DELAY_S, help="0: sent once"))

    @staticmethod
    def check_params(params: dict, where: str) -> None:
        if params["target"] != ["command_long"]:
            raise ScenarioError(f"{where}.target: inject_command forges a command_long message; "
                                f"got {params['target']!r}")

    def message(self, n: int) -> np.ndarray:
        """(n, 10) the forged COMMAND_LONG rows."""
        p = self.params
        out = np.zeros((n, 10))
        cmd = p["command"]
        if cmd == "disarm":
            out[:, 0] = MAV_CMD_COMPONENT_ARM_DISARM
            out[:, 2] = FORCE_DISARM if p["force"] else 0.0
        elif cmd == "land":
            out[:, 0] = MAV_CMD_NAV_LAND
        elif cmd == "return":
            out[:, 0] = MAV_CMD_NAV_RETURN_TO_LAUNCH
        elif cmd in ("hold", "set_mode"):
            main, sub = SET_MODES["hold" if cmd == "hold" else p["mode"]]
            out[:, 0], out[:, 1], out[:, 2], out[:, 3] = MAV_CMD_DO_SET_MODE, 1.0, main, sub
        else:
            lat, lon = ned_to_latlon(_col(p, "north_m", n), _col(p, "east_m", n))
            out[:, 0], out[:, 5], out[:, 6] = MAV_CMD_DO_REPOSITION, lat, lon
            out[:, 7] = HOME_ALT + _col(p, "alt_m", n)
        out[:, 8] = _col(p, "target_system", n)
        out[:, 9] = _col(p, "target_component", n)
        return out

    def alter(self, ctx, topic, cur, active):
        n = cur.shape[0]
        k = self.messages_since_start(ctx, topic)
        every = np.maximum(np.round(_col(self.params, "repeat_s", n) * 50.0), 0).astype(np.int64)
        send = (k == 0) | ((every > 0) & (k % np.maximum(every, 1) == 0))
        return np.where(send[:, None], self.message(n), cur), np.ones(n, dtype=bool)


class MissionTamper(Action):
    """Moves mission item ``item`` the navigator receives: by ``shift_m`` along ``direction_deg``
    (``mode = "shift"``) or to ``north_m``/``east_m`` from home (``mode = "replace"``)."""

    name = "mission_tamper"
    points = ("command",)
    spec = (Param("target", list, ["mission"], item=str, min_items=1, max_items=1, help='["mission"]'),
            Param("item", int, 2, minimum=0, maximum=MAX_MISSION_ITEMS - 1,
                  help="mission item (0 take-off, 1-4 the corners, 5 home)"),
            Param("mode", str, "shift", choices=("shift", "replace")),
            Param("shift_m", float, 20.0, minimum=-10_000.0, maximum=10_000.0),
            Param("direction_deg", float, 90.0, help="heading of the shift, 0 = north"),
            Param("north_m", float, 0.0), Param("east_m", float, 0.0))

    @staticmethod
    def check_params(params: dict, where: str) -> None:
        if params["target"] != ["mission"]:
            raise ScenarioError(f"{where}.target: mission_tamper changes the mission message; got {params['target']!r}")

    def alter(self, ctx, topic, cur, active):
        n = cur.shape[0]
        p = self.params
        items = np.asarray(p["item"], dtype=np.int64).reshape(-1)
        items = np.broadcast_to(items, (n,))
        out = cur.copy()
        rows = np.arange(n)
        cn, ce = 3 * items, 3 * items + 1
        if p["mode"] == "shift":
            d = np.deg2rad(_col(p, "direction_deg", n))
            s = _col(p, "shift_m", n)
            out[rows, cn] = cur[rows, cn] + s * np.cos(d)
            out[rows, ce] = cur[rows, ce] + s * np.sin(d)
        else:
            out[rows, cn] = _col(p, "north_m", n)
            out[rows, ce] = _col(p, "east_m", n)
        return out, np.ones(n, dtype=bool)


class _LinkAction(Action):
    """Acts on whole messages in both directions of the link."""

    points = ("link", "command")
    spec = (_ANY_TARGET,)
    bidirectional = True


class LinkLoss(_LinkAction):
    """Both directions silent (``direction`` may keep one): nothing is delivered while active."""

    name = "link_loss"
    spec = (_ANY_TARGET, Param("direction", str, "both", choices=("both", "telemetry", "command")))

    def alter(self, ctx, topic, cur, active):
        direction = self.params["direction"]
        is_cmd = topic in COMMAND_TOPICS or topic in CONTROL_TOPICS
        lost = direction == "both" or (direction == "command") == is_cmd
        return cur, np.full(cur.shape[0], not lost)


class _ValueAction(_LinkAction):
    """A link action that delivers other values: its wildcard leaves the control messages (commands,
    mission) alone, which carry no value of their own to replay or delay."""

    @classmethod
    def wildcard(cls, available):
        return sorted(t for t in available if t not in CONTROL_TOPICS)


class Replay(_ValueAction):
    """Replays a captured span of ``span_s`` seconds that began ``age_s`` before the attack, in a loop
    (re-stamped: each replayed message arrives in place of a real one, at its time)."""

    name = "replay"
    spec = (_ANY_TARGET,
            Param("span_s", float, 2.0, minimum=0.0, exclusive_min=True, maximum=MAX_DELAY_S),
            Param("age_s", float, 0.0, minimum=0.0, maximum=MAX_DELAY_S,
                  help="how long before the attack the span began (0: span_s, the span just before)"))

    def lookback(self, topic, rate_hz):
        age = np.maximum(np.asarray(self.params["age_s"], dtype=float), np.asarray(self.params["span_s"]))
        return int(math.ceil(float(np.max(age)) * rate_hz)) + 2

    def source_us(self, ctx) -> np.ndarray:
        """(N,) time of the captured message replayed now."""
        span = np.round(np.asarray(self.params["span_s"], dtype=float) * 1e6).astype(np.int64).reshape(-1)
        age = np.round(np.asarray(self.params["age_s"], dtype=float) * 1e6).astype(np.int64).reshape(-1)
        age = np.where(age > 0, age, span)
        since = np.maximum(ctx.t_us - ctx.start_us, 0)
        return ctx.start_us - age + np.mod(since, span)

    def capture(self, ctx, topic: str, active: np.ndarray) -> None:
        """At the attack's first message, keep the messages of the span (the History moves on)."""
        h = ctx.history.get(topic)
        if topic not in self._captured:
            n = ctx.rows.shape[0]
            self._captured[topic] = (np.full((n, h.depth, h.values.shape[2]), np.nan),
                                     np.full((n, h.depth), -1, dtype=np.int64), np.full(n, -1, dtype=np.int64))
        vals, times, start = self._captured[topic]
        fresh = active & (start != ctx.start_us)
        if fresh.any():
            avail = min(h.count, h.depth)
            order = [(h.count - avail + k) % h.depth for k in range(avail)]  # oldest first
            rows = ctx.rows[fresh]
            vals[fresh] = np.nan
            vals[np.ix_(np.flatnonzero(fresh), np.arange(h.depth - avail, h.depth))] = \
                h.values[order][:, rows].transpose(1, 0, 2)
            times[fresh] = -1
            times[np.ix_(np.flatnonzero(fresh), np.arange(h.depth - avail, h.depth))] = h.times[order]
            start[fresh] = ctx.start_us[fresh]

    def alter(self, ctx, topic, cur, active):
        if not hasattr(self, "_captured"):
            self._captured: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.capture(ctx, topic, active)
        vals, times, _ = self._captured[topic]
        src = self.source_us(ctx)
        k = (times <= src[:, None]).sum(axis=1) - 1  # the latest captured message at or before src
        first = (times < 0).sum(axis=1)
        k = np.maximum(k, np.minimum(first, times.shape[1] - 1))
        old = vals[np.arange(vals.shape[0]), k]
        return old[:, list(self.fields[topic])], np.ones(cur.shape[0], dtype=bool)


class Flood(_ValueAction):
    """Flooding frames at ``rate_hz`` (``frame_bytes`` each) share a link of ``capacity_bps`` bytes/s with
    the real traffic (``load``: its share of the capacity). Once the offered traffic exceeds the
    capacity the queue grows and real messages arrive later (each carries the value sent ``delay``
    ago); when the queue reaches ``max_queue_s`` the surplus real messages are dropped."""

    name = "flood"
    spec = (_ANY_TARGET,
            Param("rate_hz", float, 200.0, minimum=0.0, exclusive_min=True, maximum=1e6),
            Param("frame_bytes", float, 53.0, minimum=1.0, maximum=300.0, help="MAVLink 2 COMMAND_LONG: 53"),
            Param("capacity_bps", float, 5760.0, minimum=1.0, exclusive_min=True, maximum=1e9,
                  help="bytes/s (a 57600 baud telemetry radio: 5760)"),
            Param("load", float, 0.5, minimum=0.0, exclusive_min=True, maximum=1.0),
            Param("max_queue_s", float, 1.0, minimum=0.0, exclusive_min=True, maximum=60.0))

    def lookback(self, topic, rate_hz):
        return int(math.ceil(float(np.max(self.params["max_queue_s"])) * rate_hz)) + 2

    def overload(self) -> np.ndarray:
        """(N,) offered traffic / capacity."""
        p = self.params
        flood = np.asarray(p["rate_hz"], dtype=float) * np.asarray(p["frame_bytes"], dtype=float)
        return (flood / np.asarray(p["capacity_bps"], dtype=float) + np.asarray(p["load"], dtype=float)).reshape(-1)

    def delay_us(self, ctx) -> np.ndarray:
        """(N,) queueing delay of a real message sent now (µs), and whether the queue is full."""
        grow = np.maximum(self.overload() - 1.0, 0.0)
        since = np.maximum(ctx.t_us - ctx.start_us, 0) / 1e6
        cap = np.asarray(self.params["max_queue_s"], dtype=float).reshape(-1)
        return np.round(np.minimum(since * grow, cap) * 1e6).astype(np.int64), since * grow >= cap

    def alter(self, ctx, topic, cur, active):
        n = cur.shape[0]
        k = self.messages_since_start(ctx, topic)
        delay, full = self.delay_us(ctx)
        f = np.minimum(1.0 / self.overload(), 1.0)  # share of the real messages the full queue lets through
        kept = np.floor((k + 1) * f) > np.floor(k * f)
        old = ctx.history.get(topic).at_time(ctx.t_us - ctx.per_batch(delay, 0))
        delivered = np.broadcast_to(~full | kept, (n,)).copy()
        return old[ctx.rows][:, list(self.fields[topic])], delivered


LINK_ACTIONS = {a.name: a for a in (InjectCommand, MissionTamper, LinkLoss, Replay, Flood)}
