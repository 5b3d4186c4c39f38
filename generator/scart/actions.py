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

from scart_bench.generator.scart import units
from scart_bench.generator.scart.action_base import (  # noqa: F401  (re-exported: the public names live on here)
    DIRECTION,
    MAX_DELAY_S,
    MAX_HISTORY_MESSAGES,
    TARGET,
    Action,
    from_metres,
    keep_where,
    to_metres,
)
from scart_bench.generator.scart.link_actions import LINK_ACTIONS
from scart_bench.generator.scart.spec import Param


class AddWhiteNoise(Action):
    """Adds zero-mean Gaussian noise of standard deviation ``std`` (physical units)."""

    name = "add_white_noise"
    metric = True
    spec = (TARGET, Param("std", float, required=True, minimum=0.0, exclusive_min=True))
    random = True

    def idle_draws(self, topic):
        return len(self.fields[topic]) if type(self) is AddWhiteNoise else None  # a subclass may alter more

    def alter(self, ctx, topic, cur, active):
        z = ctx.normal(self, topic, cur.shape[1])
        return cur + z * self.p("std") * self.scales(topic), keep_where(cur.shape[0])


class RandomChange(Action):
    """Adds a uniform random change in [-range, +range] (physical units) to each message."""

    name = "random_change"
    metric = True
    spec = (TARGET, Param("range", float, required=True, minimum=0.0, exclusive_min=True))
    random = True

    def idle_draws(self, topic):
        return len(self.fields[topic]) if type(self) is RandomChange else None  # a subclass may alter more

    def alter(self, ctx, topic, cur, active):
        u = ndtr(ctx.normal(self, topic, cur.shape[1]))
        return cur + (2 * u - 1) * self.p("range") * self.scales(topic), keep_where(cur.shape[0])


class Duplicate(Action):
    """Replays the value received ``k`` messages earlier (the paper's Duplicate)."""

    name = "duplicate"
    spec = (TARGET, Param("k", int, required=True, minimum=1, maximum=MAX_HISTORY_MESSAGES))

    def lookback(self, topic, rate_hz):
        return int(np.max(self.params["k"])) + 1

    def alter(self, ctx, topic, cur, active):
        old = ctx.history.get(topic).back(ctx.per_batch(self.params["k"], 0))
        return old[ctx.rows][:, list(self.fields[topic])], keep_where(cur.shape[0])


class DisconnectSensor(Action):
    """Drops messages (with ``probability``; 1 drops all: the sensor is disconnected)."""

    name = "disconnect_sensor"
    spec = (TARGET, Param("probability", float, 1.0, minimum=0.0, maximum=1.0))
    random = True

    def idle_draws(self, topic):
        return 1 if type(self) is DisconnectSensor else None  # a subclass may alter more

    def alter(self, ctx, topic, cur, active):
        u = ndtr(ctx.normal(self, topic, 1))[:, 0]
        return cur, u >= np.asarray(self.params["probability"]).reshape(-1)


class AvgSensors(Action):
    """Replaces the value by the mean of the last ``window`` messages (a smoothing attack)."""

    name = "avg_sensors"
    spec = (TARGET, Param("window", int, required=True, minimum=2, maximum=MAX_HISTORY_MESSAGES))

    def lookback(self, topic, rate_hz):
        return int(np.max(self.params["window"])) + 1

    def alter(self, ctx, topic, cur, active):
        n = np.broadcast_to(np.asarray(self.params["window"]).reshape(-1), ctx.rows.shape)
        mean = ctx.history.get(topic).mean_last(n, ctx.rows)
        return mean[:, list(self.fields[topic])], keep_where(cur.shape[0])


#: Course-over-ground fields (radians, 0 = north) that gps_spoof turns with the velocity.
COURSE_FIELDS = ("cog", "cog_rad")
#: The same in degrees (ArduPilot's GPS GCrs).
COURSE_DEG_FIELDS = ("GCrs",)


class GpsSpoof(Action):
    """GPS spoofing with a growing angular deviation (the paper's spoofing attack).

    Reported positions are rotated about the position at attack start by an angle growing at
    ``rate_deg_s`` up to ``max_deg``; velocities are rotated by the same angle, so position and
    velocity stay consistent. Applies to lat/lon, x/y and north/east velocity pairs.
    """

    name = "gps_spoof"
    spec = (TARGET, Param("rate_deg_s", float, required=True, minimum=0.0, exclusive_min=True),
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
            elif names[i] in COURSE_DEG_FIELDS:
                out[:, i] = np.mod(work[:, i] + np.rad2deg(theta), 360.0)
        if pair is not None:
            return from_metres(ctx, values, out, pair, idx, active), keep_where(values.shape[0])
        values = np.where(active[:, None], out, values)
        return values, keep_where(values.shape[0])


class Off(Action):
    """PX4 failure "off": the messages stop."""

    name = "off"
    spec = (TARGET,)

    def alter(self, ctx, topic, cur, active):
        return cur, np.zeros(cur.shape[0], dtype=bool)


class Stuck(Action):
    """PX4 failure "stuck": the value freezes at its value when the attack started."""

    name = "stuck"
    spec = (TARGET,)

    def alter(self, ctx, topic, cur, active):
        return self.start_values(ctx, topic, cur), keep_where(cur.shape[0])


class Garbage(Action):
    """PX4 failure "garbage": values replaced by uniform noise in [-range, +range] (physical units)."""

    name = "garbage"
    metric = True
    spec = (TARGET, Param("range", float, 1000.0, minimum=0.0, exclusive_min=True))
    random = True

    def idle_draws(self, topic):
        return len(self.fields[topic]) if type(self) is Garbage else None  # a subclass may alter more

    def alter(self, ctx, topic, cur, active):
        u = ndtr(ctx.normal(self, topic, cur.shape[1]))
        return (2 * u - 1) * self.p("range") * self.scales(topic), keep_where(cur.shape[0])


class Wrong(Action):
    """PX4 failure "wrong": a constant wrong value, ``offset`` away from the value at attack start."""

    name = "wrong"
    metric = True
    spec = (TARGET, Param("offset", float, required=True), DIRECTION)

    def alter(self, ctx, topic, cur, active):
        return self.start_values(ctx, topic, cur) + self.p("offset") * self.signed(topic), keep_where(cur.shape[0])


class Slow(Action):
    """PX4 failure "slow": only every ``factor``-th message gets through."""

    name = "slow"
    spec = (TARGET, Param("factor", int, required=True, minimum=2, maximum=MAX_HISTORY_MESSAGES))

    def alter(self, ctx, topic, cur, active):
        k = self.messages_since_start(ctx, topic)
        return cur, (k % np.asarray(self.params["factor"]).reshape(-1)) == 0


class Delayed(Action):
    """PX4 failure "delayed": each message carries the value of ``delay_s`` seconds earlier."""

    name = "delayed"
    spec = (TARGET, Param("delay_s", float, required=True, minimum=0.0, exclusive_min=True, maximum=MAX_DELAY_S))

    def lookback(self, topic, rate_hz):
        return int(math.ceil(float(np.max(self.params["delay_s"])) * rate_hz)) + 2

    def alter(self, ctx, topic, cur, active):
        delay_us = np.round(np.asarray(self.params["delay_s"], dtype=float) * 1e6).astype(np.int64)
        old = ctx.history.get(topic).at_time(ctx.t_us - ctx.per_batch(delay_us, 0))
        return old[ctx.rows][:, list(self.fields[topic])], keep_where(cur.shape[0])


class Intermittent(Action):
    """PX4 failure "intermittent": the messages drop out for ``off_fraction`` of every ``period_s``."""

    name = "intermittent"
    spec = (TARGET, Param("period_s", float, 1.0, minimum=0.0, exclusive_min=True),
            Param("off_fraction", float, 0.5, minimum=0.0, maximum=1.0))

    def alter(self, ctx, topic, cur, active):
        period = np.asarray(self.params["period_s"]).reshape(-1)
        phase = np.mod((ctx.t_us - ctx.start_us) / 1e6, period) / period
        return cur, phase >= np.asarray(self.params["off_fraction"]).reshape(-1)


class Bias(Action):
    """Adds a constant ``offset`` (physical units, along ``direction_deg`` for horizontal fields)."""

    name = "bias"
    metric = True
    spec = (TARGET, Param("offset", float, required=True), DIRECTION)

    def alter(self, ctx, topic, cur, active):
        return cur + self.p("offset") * self.signed(topic), keep_where(cur.shape[0])


class Scaling(Action):
    """Scales the change since attack start by ``factor`` (unit-free: v0 + factor (v - v0))."""

    name = "scaling"
    spec = (TARGET, Param("factor", float, required=True))

    def alter(self, ctx, topic, cur, active):
        v0 = self.start_values(ctx, topic, cur)
        return v0 + self.p("factor") * (cur - v0), keep_where(cur.shape[0])


class Sinusoid(Action):
    """Adds ``amplitude`` sin(2 pi frequency_hz (t - start)) (physical units)."""

    name = "sinusoid"
    metric = True
    spec = (TARGET, Param("amplitude", float, required=True),
            Param("frequency_hz", float, 0.5, minimum=0.0, exclusive_min=True), DIRECTION)

    def alter(self, ctx, topic, cur, active):
        tt = (ctx.t_us - ctx.start_us) / 1e6
        wave = np.sin(2 * math.pi * np.asarray(self.params["frequency_hz"]).reshape(-1) * tt)
        return cur + (self.p("amplitude")[:, 0] * wave)[:, None] * self.signed(topic), keep_where(cur.shape[0])


class Drift(Action):
    """Stealthy drift: positions move at ``rate`` (m/s) along ``direction_deg`` and velocities carry
    that same ``rate``, so position and velocity stay consistent (other fields drift at rate/s)."""

    name = "drift"
    metric = True
    spec = (TARGET, Param("rate", float, required=True), DIRECTION)

    def alter(self, ctx, topic, cur, active):
        names = self.field_names[topic]
        tt = np.maximum(ctx.t_us - ctx.start_us, 0) / 1e6
        vel = np.array([units.is_velocity(topic, names[i]) for i in self.fields[topic]])
        k = self.p("rate") * self.signed(topic)
        return cur + np.where(vel[None, :], k, k * tt[:, None]), keep_where(cur.shape[0])


ACTIONS: dict[str, type[Action]] = {
    a.name: a for a in (AddWhiteNoise, RandomChange, Duplicate, DisconnectSensor, AvgSensors, GpsSpoof, Off, Stuck,
                        Garbage, Wrong, Slow, Delayed, Intermittent, Bias, Scaling, Sinusoid, Drift)
}

ACTIONS.update(LINK_ACTIONS)
