"""Attack actions: what the layer does to a message while a scenario is active.

Each action alters the current value of its target fields (or drops the message) for the
flights where the scenario is active, leaving the others untouched. Magnitudes are in physical
units (m, m/s, rad, ...) and converted per field by scart_bench.generator.scart.units. Actions that move a
value by metres (``metric = True``) see a message's latitude/longitude as north/east metres in the
WGS-84 tangent plane at the flight's origin (``ctx.origin``) and their result is converted back,
so a displacement has the same length at any latitude. Numeric parameters
are per-flight arrays, so one group applies many parameter settings at once.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr

from scart_bench.generator import geo
from scart_bench.generator.scart import units
from scart_bench.generator.scart.spec import Param

_TARGET = Param("target", list, required=True, help='list of "topic" or "topic.field"', item=str, min_items=1)
#: Deepest history an action may reach back (messages): 30 min of a 50 Hz topic.
MAX_HISTORY_MESSAGES = 90_000
#: Longest delay or window an action may hold (s).
MAX_DELAY_S = 1800.0
_DIRECTION = Param("direction_deg", float, 45.0, help="heading of a displacement, 0 = north")


class Action:
    """Base class. ``apply`` returns the altered values and the delivered mask."""

    name = "action"
    spec: tuple[Param, ...] = ()
    #: True for actions that need random numbers on every message of a target topic
    random = False
    #: True for actions whose magnitudes are lengths: lat/lon are edited as metres (see module doc)
    metric = False
    #: True for actions on whole messages in both directions of the link (telemetry and commands)
    bidirectional = False
    #: injection points the action can act at (empty: the scenario's own point)
    points: tuple[str, ...] = ()

    def __init__(self, params: dict, fields: dict[str, tuple[int, ...]], field_names: dict[str, tuple[str, ...]]):
        self.params = params
        self.fields = fields  # topic -> indices of the target fields
        self.field_names = field_names  # topic -> all field names of the topic
        self.v0: dict[str, np.ndarray] = {}
        self.v0_start: dict[str, np.ndarray] = {}
        self.n_since: dict[str, np.ndarray] = {}

    @classmethod
    def wildcard(cls, available: dict[str, tuple[str, ...]]) -> list[str]:
        """The targets of ``target = ["*"]``: every topic that passes."""
        return sorted(available)

    def lookback(self, topic: str, rate_hz: float) -> int:
        """Messages of history this action needs for ``topic``."""
        return 1

    def p(self, name: str) -> np.ndarray:
        """A numeric parameter as a column (N, 1) for broadcasting over fields."""
        return np.asarray(self.params[name], dtype=float).reshape(-1, 1)

    def scales(self, topic: str) -> np.ndarray:
        names = self.field_names[topic]
        return np.array([units.scale(topic, names[i]) for i in self.fields[topic]])

    def signed(self, topic: str) -> np.ndarray:
        """(N, F) field units per physical unit along each flight's direction."""
        names = self.field_names[topic]
        d = np.deg2rad(np.asarray(self.params.get("direction_deg", 45.0), dtype=float)).reshape(-1)
        return np.array([[units.signed(topic, names[i], di) for i in self.fields[topic]] for di in d])

    def start_values(self, ctx, topic: str, current: np.ndarray) -> np.ndarray:
        """Values of the target fields when the attack started (captured on its first message)."""
        if topic not in self.v0:
            self.v0[topic] = np.full_like(current, np.nan)
            self.v0_start[topic] = np.full(current.shape[0], -1, dtype=np.int64)
        fresh = self.v0_start[topic] != ctx.start_us
        if fresh.any():
            self.v0[topic][fresh] = current[fresh]
            self.v0_start[topic][fresh] = ctx.start_us[fresh]
        return self.v0[topic]

    def messages_since_start(self, ctx, topic: str) -> np.ndarray:
        """Index of this message among the target topic's messages since the attack started."""
        if topic not in self.n_since:
            self.n_since[topic] = np.zeros(ctx.rows.shape[0], dtype=np.int64)
            self.v0_start.setdefault("__count__" + topic, np.full(ctx.rows.shape[0], -1, dtype=np.int64))
        key = "__count__" + topic
        fresh = self.v0_start[key] != ctx.start_us
        self.n_since[topic][fresh] = 0
        self.v0_start[key][fresh] = ctx.start_us[fresh]
        out = self.n_since[topic].copy()
        self.n_since[topic] += 1
        return out

    def apply(self, ctx, topic: str, values: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Alter ``values`` (N, F, a copy) where ``active``; returns (values, delivered)."""
        idx = list(self.fields[topic])
        pair = units.latlon_pair(topic, self.field_names[topic]) if self.metric else None
        if pair is None or not active.any():  # inactive: alter only for its random draws, nothing changes
            cur = values[:, idx]
            new, delivered = self.alter(ctx, topic, cur, active)
            values[:, idx] = np.where(active[:, None], new, cur)
            return values, np.where(active, delivered, True)
        work = to_metres(ctx, values, pair)
        cur = work[:, idx]
        new, delivered = self.alter(ctx, topic, cur, active)
        work[:, idx] = new
        return from_metres(ctx, values, work, pair, idx, active), np.where(active, delivered, True)

    def alter(self, ctx, topic: str, cur: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError


def _origin(ctx, values: np.ndarray, pair: tuple[int, int]) -> np.ndarray:
    """(N, 2) lat/lon origin of each flight; a flight with none yet uses this message's position."""
    o = np.array(ctx.origin, dtype=np.float64, copy=True)
    unknown = ~np.isfinite(o).all(axis=1)
    if unknown.any():
        o[unknown, 0] = values[unknown, pair[0]]
        o[unknown, 1] = values[unknown, pair[1]]
    return o


def to_metres(ctx, values: np.ndarray, pair: tuple[int, int]) -> np.ndarray:
    """A copy of ``values`` with the lat/lon columns ``pair`` as north/east metres from the origin."""
    work = values.copy()
    o = _origin(ctx, values, pair)
    n, e = geo.ne_from_latlon(values[:, pair[0]], values[:, pair[1]], o[:, 0], o[:, 1])
    work[:, pair[0]], work[:, pair[1]] = n, e
    return work


def from_metres(ctx, values: np.ndarray, work: np.ndarray, pair: tuple[int, int], idx: list[int],
                active: np.ndarray) -> np.ndarray:
    """``values`` with the target columns ``idx`` taken from ``work`` where ``active`` (metres ->
    lat/lon for the pair); everything else unchanged, bit for bit."""
    out = values.copy()
    o = _origin(ctx, values, pair)
    lat, lon = geo.latlon_from_ne(work[:, pair[0]], work[:, pair[1]], o[:, 0], o[:, 1])
    back = work.copy()
    back[:, pair[0]], back[:, pair[1]] = lat, lon
    out[:, idx] = np.where(active[:, None], back[:, idx], values[:, idx])
    return out


def _keep(n: int) -> np.ndarray:
    return np.ones(n, dtype=bool)


class AddWhiteNoise(Action):
    """Adds zero-mean Gaussian noise of standard deviation ``std`` (physical units)."""

    name = "add_white_noise"
    metric = True
    spec = (_TARGET, Param("std", float, required=True, minimum=0.0, exclusive_min=True))
    random = True

    def alter(self, ctx, topic, cur, active):
        z = ctx.normal(self, topic, cur.shape[1])
        return cur + z * self.p("std") * self.scales(topic), _keep(cur.shape[0])


class RandomChange(Action):
    """Adds a uniform random change in [-range, +range] (physical units) to each message."""

    name = "random_change"
    metric = True
    spec = (_TARGET, Param("range", float, required=True, minimum=0.0, exclusive_min=True))
    random = True

    def alter(self, ctx, topic, cur, active):
        u = ndtr(ctx.normal(self, topic, cur.shape[1]))
        return cur + (2 * u - 1) * self.p("range") * self.scales(topic), _keep(cur.shape[0])


class Duplicate(Action):
    """Replays the value received ``k`` messages earlier (the paper's Duplicate)."""

    name = "duplicate"
    spec = (_TARGET, Param("k", int, required=True, minimum=1, maximum=MAX_HISTORY_MESSAGES))

    def lookback(self, topic, rate_hz):
        return int(np.max(self.params["k"])) + 1

    def alter(self, ctx, topic, cur, active):
        old = ctx.history.get(topic).back(ctx.per_batch(self.params["k"], 0))
        return old[ctx.rows][:, list(self.fields[topic])], _keep(cur.shape[0])


class DisconnectSensor(Action):
    """Drops messages (with ``probability``; 1 drops all: the sensor is disconnected)."""

    name = "disconnect_sensor"
    spec = (_TARGET, Param("probability", float, 1.0, minimum=0.0, maximum=1.0))
    random = True

    def alter(self, ctx, topic, cur, active):
        u = ndtr(ctx.normal(self, topic, 1))[:, 0]
        return cur, u >= np.asarray(self.params["probability"]).reshape(-1)


class AvgSensors(Action):
    """Replaces the value by the mean of the last ``window`` messages (a smoothing attack)."""

    name = "avg_sensors"
    spec = (_TARGET, Param("window", int, required=True, minimum=2, maximum=MAX_HISTORY_MESSAGES))

    def lookback(self, topic, rate_hz):
        return int(np.max(self.params["window"])) + 1

    def alter(self, ctx, topic, cur, active):
        n = np.broadcast_to(np.asarray(self.params["window"]).reshape(-1), ctx.rows.shape)
        mean = ctx.history.get(topic).mean_last(n, ctx.rows)
        return mean[:, list(self.fields[topic])], _keep(cur.shape[0])


#: Course-over-ground fields (radians, 0 = north) that gps_spoof turns with the velocity.
COURSE_FIELDS = ("cog", "cog_rad")


class GpsSpoof(Action):
    """GPS spoofing with a growing angular deviation (the paper's spoofing attack).

    Reported positions are rotated about the position at attack start by an angle growing at
    ``rate_deg_s`` up to ``max_deg``; velocities are rotated by the same angle, so position and
    velocity stay consistent. Applies to lat/lon, x/y and north/east velocity pairs.
    """

    name = "gps_spoof"
    spec = (_TARGET, Param("rate_deg_s", float, required=True, minimum=0.0, exclusive_min=True),
            Param("max_deg", float, 90.0, minimum=0.0, maximum=180.0))

    def apply(self, ctx, topic, values, active):
        names = self.field_names[topic]
        idx = sorted(set(self.fields[topic]))
        q = {units.quantity(topic, names[i]): i for i in idx}
        theta = np.deg2rad(np.minimum(self.p("rate_deg_s")[:, 0] * (ctx.t_us - ctx.start_us) / 1e6,
                                      self.p("max_deg")[:, 0]))
        c, s = np.cos(theta), np.sin(theta)
        pair = units.latlon_pair(topic, names)
        work = to_metres(ctx, values, pair) if pair is not None else values.copy()
        v0 = self.start_values(ctx, topic, work.copy())
        out = work.copy()
        # lat/lon are north/east metres here: a rotation in the tangent plane keeps distances
        for a, b in (("latitude", "longitude"), ("position_n", "position_e")):
            if a in q and b in q:
                ia, ib = q[a], q[b]
                dn = work[:, ia] - v0[:, ia]
                de = work[:, ib] - v0[:, ib]
                out[:, ia] = v0[:, ia] + (c * dn - s * de)
                out[:, ib] = v0[:, ib] + (s * dn + c * de)
        if "velocity_n" in q and "velocity_e" in q:
            ia, ib = q["velocity_n"], q["velocity_e"]
            out[:, ia] = c * work[:, ia] - s * work[:, ib]
            out[:, ib] = s * work[:, ia] + c * work[:, ib]
        for i in idx:  # course over ground turns with the velocity
            if names[i] in COURSE_FIELDS:
                out[:, i] = np.mod(work[:, i] + theta, 2 * math.pi)
        if pair is not None:
            return from_metres(ctx, values, out, pair, idx, active), _keep(values.shape[0])
        values = np.where(active[:, None], out, values)
        return values, _keep(values.shape[0])


class Off(Action):
    """PX4 failure "off": the messages stop."""

    name = "off"
    spec = (_TARGET,)

    def alter(self, ctx, topic, cur, active):
        return cur, np.zeros(cur.shape[0], dtype=bool)


class Stuck(Action):
    """PX4 failure "stuck": the value freezes at its value when the attack started."""

    name = "stuck"
    spec = (_TARGET,)

    def alter(self, ctx, topic, cur, active):
        return self.start_values(ctx, topic, cur), _keep(cur.shape[0])


class Garbage(Action):
    """PX4 failure "garbage": values replaced by uniform noise in [-range, +range] (physical units)."""

    name = "garbage"
    metric = True
    spec = (_TARGET, Param("range", float, 1000.0, minimum=0.0, exclusive_min=True))
    random = True

    def alter(self, ctx, topic, cur, active):
        u = ndtr(ctx.normal(self, topic, cur.shape[1]))
        return (2 * u - 1) * self.p("range") * self.scales(topic), _keep(cur.shape[0])


class Wrong(Action):
    """PX4 failure "wrong": a constant wrong value, ``offset`` away from the value at attack start."""

    name = "wrong"
    metric = True
    spec = (_TARGET, Param("offset", float, required=True), _DIRECTION)

    def alter(self, ctx, topic, cur, active):
        return self.start_values(ctx, topic, cur) + self.p("offset") * self.signed(topic), _keep(cur.shape[0])


class Slow(Action):
    """PX4 failure "slow": only every ``factor``-th message gets through."""

    name = "slow"
    spec = (_TARGET, Param("factor", int, required=True, minimum=2, maximum=MAX_HISTORY_MESSAGES))

    def alter(self, ctx, topic, cur, active):
        k = self.messages_since_start(ctx, topic)
        return cur, (k % np.asarray(self.params["factor"]).reshape(-1)) == 0


class Delayed(Action):
    """PX4 failure "delayed": each message carries the value of ``delay_s`` seconds earlier."""

    name = "delayed"
    spec = (_TARGET, Param("delay_s", float, required=True, minimum=0.0, exclusive_min=True, maximum=MAX_DELAY_S))

    def lookback(self, topic, rate_hz):
        return int(math.ceil(float(np.max(self.params["delay_s"])) * rate_hz)) + 2

    def alter(self, ctx, topic, cur, active):
        delay_us = np.round(np.asarray(self.params["delay_s"], dtype=float) * 1e6).astype(np.int64)
        old = ctx.history.get(topic).at_time(ctx.t_us - ctx.per_batch(delay_us, 0))
        return old[ctx.rows][:, list(self.fields[topic])], _keep(cur.shape[0])


class Intermittent(Action):
    """PX4 failure "intermittent": the messages drop out for ``off_fraction`` of every ``period_s``."""

    name = "intermittent"
    spec = (_TARGET, Param("period_s", float, 1.0, minimum=0.0, exclusive_min=True),
            Param("off_fraction", float, 0.5, minimum=0.0, maximum=1.0))

    def alter(self, ctx, topic, cur, active):
        period = np.asarray(self.params["period_s"]).reshape(-1)
        phase = np.mod((ctx.t_us - ctx.start_us) / 1e6, period) / period
        return cur, phase >= np.asarray(self.params["off_fraction"]).reshape(-1)


class Bias(Action):
    """Adds a constant ``offset`` (physical units, along ``direction_deg`` for horizontal fields)."""

    name = "bias"
    metric = True
    spec = (_TARGET, Param("offset", float, required=True), _DIRECTION)

    def alter(self, ctx, topic, cur, active):
        return cur + self.p("offset") * self.signed(topic), _keep(cur.shape[0])


class Scaling(Action):
    """Scales the change since attack start by ``factor`` (unit-free: v0 + factor (v - v0))."""

    name = "scaling"
    spec = (_TARGET, Param("factor", float, required=True))

    def alter(self, ctx, topic, cur, active):
        v0 = self.start_values(ctx, topic, cur)
        return v0 + self.p("factor") * (cur - v0), _keep(cur.shape[0])


class Sinusoid(Action):
    """Adds ``amplitude`` sin(2 pi frequency_hz (t - start)) (physical units)."""

    name = "sinusoid"
    metric = True
    spec = (_TARGET, Param("amplitude", float, required=True),
            Param("frequency_hz", float, 0.5, minimum=0.0, exclusive_min=True), _DIRECTION)

    def alter(self, ctx, topic, cur, active):
        tt = (ctx.t_us - ctx.start_us) / 1e6
        wave = np.sin(2 * math.pi * np.asarray(self.params["frequency_hz"]).reshape(-1) * tt)
        return cur + (self.p("amplitude")[:, 0] * wave)[:, None] * self.signed(topic), _keep(cur.shape[0])


class Drift(Action):
    """Stealthy drift: positions move at ``rate`` (m/s) along ``direction_deg`` and velocities carry
    that same ``rate``, so position and velocity stay consistent (other fields drift at rate/s)."""

    name = "drift"
    metric = True
    spec = (_TARGET, Param("rate", float, required=True), _DIRECTION)

    def alter(self, ctx, topic, cur, active):
        names = self.field_names[topic]
        tt = np.maximum(ctx.t_us - ctx.start_us, 0) / 1e6
        vel = np.array([units.is_velocity(topic, names[i]) for i in self.fields[topic]])
        k = self.p("rate") * self.signed(topic)
        return cur + np.where(vel[None, :], k, k * tt[:, None]), _keep(cur.shape[0])


ACTIONS: dict[str, type[Action]] = {
    a.name: a for a in (AddWhiteNoise, RandomChange, Duplicate, DisconnectSensor, AvgSensors, GpsSpoof, Off, Stuck,
                        Garbage, Wrong, Slow, Delayed, Intermittent, Bias, Scaling, Sinusoid, Drift)
}


def _register_link_actions() -> None:
    from scart_bench.generator.scart.link_actions import LINK_ACTIONS

    ACTIONS.update(LINK_ACTIONS)


_register_link_actions()
