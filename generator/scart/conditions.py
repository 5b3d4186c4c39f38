"""Start and end conditions, vectorised over the flights of a scenario group.

A condition receives the group context (time, History, rows of the batch, per-flight attack
start) and returns one boolean per flight. Numeric parameters are arrays with one value per
flight, so one group evaluates many parameter settings at once.
"""

from __future__ import annotations

import re

import numpy as np

from scart_bench.generator.geo import ne_from_latlon
from scart_bench.generator.scart.spec import Param, ScenarioError
from scart_bench.generator.scart.units import latlon_pair, quantity
from scart_bench.generator.telemetry.phases import ANCHORS, LANDED, PHASES


class Condition:
    """Base class; subclasses set ``name``, ``spec`` and implement ``__call__``."""

    name = "condition"
    spec: tuple[Param, ...] = ()
    end_only = False
    #: True for conditions on another scenario's state (its id is the ``scenario`` parameter)
    refers = False

    def __init__(self, params: dict, rng_uniform: np.ndarray):
        self.params = params
        self.u = rng_uniform  # (N,) per-flight uniform draw in [0, 1), for random conditions

    def topics(self) -> set[str]:
        topic = self.params.get("topic")
        return {topic} if isinstance(topic, str) else set()

    def __call__(self, ctx) -> np.ndarray:
        raise NotImplementedError

    def earliest_s(self) -> float | None:
        """A time (s) before which the condition is False for every flight (None: no such time known).

        Lets the layer skip evaluating a group that cannot start yet; the built-in time conditions
        give the same comparison as their ``__call__``."""
        return None


def _latest(ctx, topic: str) -> tuple[np.ndarray, tuple[str, ...]] | tuple[None, None]:
    h = ctx.history.get(topic)
    if h is None or h.count == 0:
        return None, None
    return h.latest()[ctx.rows], ctx.fields(topic)


def position_ne(values: np.ndarray, fields: tuple[str, ...], origin: np.ndarray, topic: str = "") -> np.ndarray:
    """(N, 2) north/east metres from a message with lat/lon fields (in the WGS-84 tangent plane at
    each flight's ``origin``, (N, 2) lat/lon) or x/y fields (already metres from the origin)."""
    pair = latlon_pair(topic, fields)
    if pair is not None:
        o = np.asarray(origin, dtype=np.float64)
        lat, lon = values[:, pair[0]], values[:, pair[1]]
        o0 = np.where(np.isfinite(o[:, 0]), o[:, 0], lat)
        o1 = np.where(np.isfinite(o[:, 1]), o[:, 1], lon)
        n, e = ne_from_latlon(lat, lon, o0, o1)
        return np.column_stack([n, e])
    q = [quantity(topic, f) for f in fields]
    if "position_n" in q and "position_e" in q:  # by quantity: an ENU pose (ROS) has x east, y north
        return np.column_stack([values[:, q.index("position_n")], values[:, q.index("position_e")]])
    if "x" in fields and "y" in fields:
        return np.column_stack([values[:, fields.index("x")], values[:, fields.index("y")]])
    raise KeyError(f"{topic}: no position fields (lat/lon or x/y) in {', '.join(fields)}")


def altitude(values: np.ndarray, fields: tuple[str, ...], field: str | None = None, topic: str = "") -> np.ndarray:
    """(N,) altitude above home (m) from a position message: its ``field`` when given (a down
    position, such as ``z``, is negated), else its relative altitude or ``-z``."""
    if field:
        sign = -1.0 if quantity(topic, field) == "position_d" else 1.0
        return sign * values[:, fields.index(field)]
    for name in ("relative_alt", "altitude_relative"):
        if name in fields:
            return values[:, fields.index(name)]
    if "z" in fields:  # a down position, or an up one (ENU: ROS)
        sign = 1.0 if quantity(topic, "z") == "position_up" else -1.0
        return sign * values[:, fields.index("z")]
    raise KeyError("no altitude field (relative_alt, altitude_relative or z)")


class TimeWindow(Condition):
    """Holds while ``start_s <= t < end_s`` (seconds from the start of the flight)."""

    name = "time_window"
    spec = (Param("start_s", float, 0.0, minimum=0.0),
            Param("end_s", float, float("inf"), minimum=0.0, allow_inf=True))

    @staticmethod
    def check_params(params: dict, where: str) -> None:
        if params["start_s"] >= params["end_s"]:
            raise ScenarioError(f"{where}: start_s ({params['start_s']:g}) must be before end_s "
                                f"({params['end_s']:g}); the window would never hold")

    def __call__(self, ctx):
        t = ctx.t_us / 1e6
        return (t >= self.params["start_s"]) & (t < self.params["end_s"])

    def earliest_s(self):
        return float(np.min(self.params["start_s"]))


class MessageCount(Condition):
    """Holds once ``count`` messages of ``topic`` have been received."""

    name = "message_count"
    spec = (Param("topic", str, required=True, help="listened topic"),
            Param("count", int, required=True, minimum=0))

    def __call__(self, ctx):
        return np.broadcast_to(ctx.history.count(self.params["topic"]) >= self.params["count"], ctx.rows.shape)


class Geofence(Condition):
    """Holds while the received position is within ``radius`` m of ``center`` [north, east] (or outside)."""

    name = "geofence"
    spec = (Param("center", list, required=True, help="[north_m, east_m] from home", item=float, min_items=2,
                  max_items=2),
            Param("radius", float, required=True, minimum=0.0, exclusive_min=True),
            Param("inside", bool, True), Param("topic", str, "position",
                                               help="a position topic or the quantity 'position'"))

    def __call__(self, ctx):
        vals, fields = _latest(ctx, self.params["topic"])
        if vals is None:
            return np.zeros(ctx.rows.shape, bool)
        pos = position_ne(vals, fields, ctx.origin, self.params["topic"])
        c = np.asarray(self.params["center"], dtype=float)
        d = np.hypot(pos[:, 0] - c[..., 0], pos[:, 1] - c[..., 1])
        inside = d <= self.params["radius"]
        return inside if self.params["inside"] else ~inside


class AltitudeAbove(Condition):
    """Holds while the received altitude above home exceeds ``height`` m."""

    name = "altitude_above"
    spec = (Param("height", float, required=True),
            Param("topic", str, "altitude", help="a topic with z, relative_alt or altitude_relative, or the "
                  "quantity 'altitude'"))

    def __call__(self, ctx):
        vals, fields = _latest(ctx, self.params["topic"])
        if vals is None:
            return np.zeros(ctx.rows.shape, bool)
        return altitude(vals, fields, self.params.get("field"), self.params["topic"]) > self.params["height"]


class MissionPhase(Condition):
    """Holds once the mission has passed waypoint ``after_waypoint`` (current item > k)."""

    name = "mission_phase"
    spec = (Param("after_waypoint", int, required=True, minimum=0),
            Param("topic", str, "mission", help="the quantity 'mission' (setpoint.seq on generated flights, "
                  "mission_result.seq_current on PX4 logs) or a topic"),
            Param("field", str, "seq"))

    def __call__(self, ctx):
        vals, fields = _latest(ctx, self.params["topic"])
        if vals is None:
            return np.zeros(ctx.rows.shape, bool)
        return vals[:, fields.index(self.params["field"])] > self.params["after_waypoint"]


class FlightPhase(Condition):
    """Holds while the flight is in phase ``phase`` (landed, takeoff, climb, cruise, descent), as csv
    mode derives it from the recording (generator.logs.phases). (csv mode only)"""

    name = "flight_phase"
    spec = (Param("phase", str, required=True, help="one of " + ", ".join(PHASES)),
            Param("topic", str, "phase", help="the quantity 'phase' (the flight_phase topic csv mode derives)"))

    @staticmethod
    def check_params(params: dict, where: str) -> None:
        if params["phase"] not in PHASES:
            raise ScenarioError(f"{where}.phase: {params['phase']!r} is not a phase; expected one of {', '.join(PHASES)}")

    def __call__(self, ctx):
        vals, fields = _latest(ctx, self.params["topic"])
        if vals is None:
            return np.zeros(ctx.rows.shape, bool)
        return vals[:, fields.index("phase")] == PHASES.index(self.params["phase"])


#: ``after_phase``'s ``after``: an anchor and seconds after it, or a phase and a share of it.
_AFTER = re.compile(r"^\s*(?P<anchor>[a-z]+)\s*(?:\+\s*(?P<s>\d+(?:\.\d*)?|\.\d+)\s*s|"
                    r"(?P<pct>\d+(?:\.\d*)?|\.\d+)\s*%)?\s*$")


def parse_after(text: str, where: str = "after") -> tuple[str, str, float]:
    """``"takeoff + 10 s"`` -> (``takeoff``, ``s``, 10.0); ``"cruise 30 %"`` -> (``cruise``, ``%``, 30.0);
    a bare anchor is ``+ 0 s``. ScenarioError naming what is expected otherwise."""
    m = _AFTER.match(text) if isinstance(text, str) else None
    if m is None or m["anchor"] not in ANCHORS or (m["pct"] is not None and float(m["pct"]) > 100):
        raise ScenarioError(f"{where}: {text!r}: expected '<anchor> + <seconds> s' or '<phase> <0-100> %' with "
                            f"an anchor of {', '.join(ANCHORS)} (e.g. 'takeoff + 10 s', 'cruise 30 %')")
    if m["pct"] is not None:
        return m["anchor"], "%", float(m["pct"])
    return m["anchor"], "s", float(m["s"] or 0.0)


class AfterPhase(Condition):
    """Holds from a point of the flight's own phases on: ``after = "takeoff + 10 s"`` (seconds of
    logged flight after leaving the ground, or after first entering climb, cruise or descent) or
    ``after = "cruise 30 %"`` (once 30 % of the flight's cruise time has passed; ``airborne``: of its
    time off the ground). ``random``: the onset is drawn per flight in ``[after, after + random]``
    (in after's unit). Reads the phases csv mode derives from a recording (generator.logs.phases;
    logs only: a generated flight has its mission computer's setpoint instead)."""

    name = "after_phase"
    spec = (Param("after", str, required=True, help="'takeoff + 10 s' or 'cruise 30 %'"),
            Param("random", float, 0.0, minimum=0.0, help="spread of a random onset, in after's unit (s or %)"),
            Param("topic", str, "phase", help="the quantity 'phase' (the flight_phase topic csv mode derives)"))

    @staticmethod
    def check_params(params: dict, where: str) -> None:
        _, unit, value = parse_after(params["after"], f"{where}.after")
        if unit == "%" and value + params["random"] > 100:
            raise ScenarioError(f"{where}.random: {params['after']!r} plus {params['random']:g} % passes 100 %")

    def __call__(self, ctx):
        vals, fields = _latest(ctx, self.params["topic"])
        if vals is None:
            return np.zeros(ctx.rows.shape, bool)
        anchor, unit, value = parse_after(self.params["after"])
        onset = value + np.asarray(self.params["random"]) * self.u
        if unit == "%":
            name, onset = f"{anchor}_fraction", onset / 100.0
        else:
            name = f"since_{anchor}_s"
        if name not in fields:
            return np.zeros(ctx.rows.shape, bool)
        with np.errstate(invalid="ignore"):
            return vals[:, fields.index(name)] >= onset  # NaN (before the anchor) is False


class Airborne(Condition):
    """Holds while the flight is off the ground (its phase is not ``landed``), as csv mode derives it
    from the recording (generator.logs.phases). (csv mode only)"""

    name = "airborne"
    spec = (Param("topic", str, "phase", help="the quantity 'phase' (the flight_phase topic csv mode derives)"),)

    def __call__(self, ctx):
        vals, fields = _latest(ctx, self.params["topic"])
        if vals is None:
            return np.zeros(ctx.rows.shape, bool)
        return vals[:, fields.index("phase")] != LANDED


class RandomStart(Condition):
    """Holds from a time drawn per flight, uniformly in [low_s, high_s]."""

    name = "random_start"
    spec = (Param("low_s", float, required=True, minimum=0.0), Param("high_s", float, required=True, minimum=0.0))

    @staticmethod
    def check_params(params: dict, where: str) -> None:
        if params["low_s"] > params["high_s"]:
            raise ScenarioError(f"{where}: low_s ({params['low_s']:g}) must be <= high_s ({params['high_s']:g})")

    def __call__(self, ctx):
        lo, hi = self.params["low_s"], self.params["high_s"]
        return ctx.t_us / 1e6 >= lo + (hi - lo) * self.u

    def earliest_s(self):
        lo, hi = self.params["low_s"], self.params["high_s"]
        return float(np.min(lo + (hi - lo) * self.u))


class Duration(Condition):
    """End condition: holds ``seconds`` after the attack started."""

    name = "duration"
    spec = (Param("seconds", float, required=True, minimum=0.0, exclusive_min=True),)
    end_only = True

    def __call__(self, ctx):
        return (ctx.start_us >= 0) & (ctx.t_us - ctx.start_us >= self.params["seconds"] * 1e6)


_OTHER = Param("scenario", str, required=True, help="id of another scenario of the same flight")


class ScenarioActive(Condition):
    """Holds while the scenario ``scenario`` (of the same flight) is active: runs two at once."""

    name = "scenario_active"
    spec = (_OTHER,)
    refers = True

    def __call__(self, ctx):
        return ctx.scenario_state(self.params["scenario"])["active"]


class ScenarioStarted(Condition):
    """Holds from ``after_s`` seconds after the scenario ``scenario`` started (its latest window)."""

    name = "scenario_started"
    spec = (_OTHER, Param("after_s", float, 0.0, minimum=0.0))
    refers = True

    def __call__(self, ctx):
        st = ctx.scenario_state(self.params["scenario"])
        return (st["start_us"] >= 0) & (ctx.t_us - st["start_us"] >= self.params["after_s"] * 1e6)


class ScenarioEnded(Condition):
    """Holds from ``after_s`` seconds after the scenario ``scenario`` ended (and is not active again)."""

    name = "scenario_ended"
    spec = (_OTHER, Param("after_s", float, 0.0, minimum=0.0))
    refers = True

    def __call__(self, ctx):
        st = ctx.scenario_state(self.params["scenario"])
        return ~st["active"] & (st["end_us"] >= 0) & (ctx.t_us - st["end_us"] >= self.params["after_s"] * 1e6)


CONDITIONS: dict[str, type[Condition]] = {
    c.name: c for c in (TimeWindow, MessageCount, Geofence, AltitudeAbove, MissionPhase, FlightPhase, AfterPhase,
                        Airborne, RandomStart, Duration, ScenarioActive, ScenarioStarted, ScenarioEnded)
}

#: The built-in conditions: pure functions of the context (no state, no random draws), so the layer
#: may leave one unevaluated when its value cannot change the outcome.
PURE_CONDITIONS = frozenset(CONDITIONS.values())
