"""Mission families: the missions a profile's flights are drawn from, each a small function turning a
flight's own random stream into the navigator's item table.

Why: a detector trained on one mission (the square) learns that mission; a fleet flies surveys,
inspections, deliveries, hovers and hand-flown legs at other heights, speeds and durations. A
profile's ``missions`` mix (family -> weight, ``MissionParams.families``) draws one family per flight,
then its altitude, cruise speed, planned duration and payload (:func:`draw_mission`); the draws
come from the flight's seed alone, so a flight flies the same mission in any batch.

Each family returns the item table the navigator flies (``navigator.mission_table``): rows of north,
east, down (m), speed of the leg to the item (m/s), hold at the item (s) and braking towards it
(m/s^2; 0: the square's approach only; negative: a fly-through item, accepted within ``-brake`` m
and passed at the leg's speed, how a pilot's smooth stick input or an orbit is flown). Row 0 is the
take-off point above home, the last is home, where the vehicle lands.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from scart_bench.generator.params import MissionParams

#: m/s^2: braking towards an item where the vehicle stops (as navigator.BRAKE_ACC; not imported: the
#: navigator imports this module)
BRAKE = 1.5
#: m/s^2: the most centripetal acceleration an orbit or a hand-flown turn asks for (PX4's
#: MPC_ACC_HOR 3 m/s^2, with margin for the wind and the velocity loop's lag)
TURN_ACC = 1.2
#: s between the items of a hand-flown leg (a pilot's stick, sampled)
STICK_DT = 1.0

FAMILIES = ("square", "survey", "orbit", "corridor", "delivery", "random_waypoints", "hover", "hand_flown")

#: per family: altitude (m) and cruise speed (m/s) ranges, drawn uniformly (the square's are the
#: square's own: MissionParams.altitude and cruise_speed, with its jitter)
RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "survey": {"altitude": (20.0, 50.0), "speed": (3.0, 8.0)},
    "orbit": {"altitude": (10.0, 40.0), "speed": (2.0, 6.0)},
    "corridor": {"altitude": (5.0, 20.0), "speed": (1.5, 4.0)},
    "delivery": {"altitude": (20.0, 50.0), "speed": (5.0, 10.0)},
    "random_waypoints": {"altitude": (5.0, 30.0), "speed": (2.0, 8.0)},
    "hover": {"altitude": (2.0, 15.0), "speed": (1.0, 2.0)},
    "hand_flown": {"altitude": (3.0, 20.0), "speed": (1.0, 6.0)},
}
#: payload as a fraction of the airframe's mass, and its probabilities (delivery flights always carry one)
PAYLOAD_LEVELS = (0.0, 0.1, 0.2)
PAYLOAD_WEIGHTS = (0.6, 0.25, 0.15)


@dataclass(frozen=True)
class MissionDraw:
    """What one flight flies: its family, altitude (m), cruise speed (m/s), planned duration of the
    mission (s, take-off to landing, without the ground phase), payload (fraction of the airframe's
    mass) and item table (K, 6); ``shape`` holds the family's geometry (a survey's polygon, an orbit's
    circle) for checks and figures."""

    family: str
    altitude: float
    cruise_speed: float
    duration_s: float
    payload: float
    items: np.ndarray
    shape: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """Plain numbers for a flight's metadata (dataset per-flight config)."""
        xy = self.items[:, :2]
        return {"family": self.family, "altitude_m": round(self.altitude, 3),
                "cruise_speed_ms": round(self.cruise_speed, 3), "planned_duration_s": round(self.duration_s, 1),
                "path_length_m": round(float(np.sum(np.hypot(*np.diff(xy, axis=0).T))), 1),
                "payload_fraction": self.payload, "items": int(len(self.items))}


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), 0xFA31]))


def _row(n: float, e: float, alt: float, speed: float, hold: float = 0.0, brake: float = BRAKE) -> list[float]:
    return [float(n), float(e), -float(alt), float(speed), float(hold), float(brake)]


def mission_time(items: np.ndarray, climb: float = 1.5) -> float:
    """Planned time (s) of flying ``items`` from the take-off point: legs at their speed, braking into
    stop items, climbs and holds (what the families fit their duration to)."""
    t = 0.0
    for a, b in zip(items[:-1], items[1:]):
        t += math.hypot(b[0] - a[0], b[1] - a[1]) / max(b[3], 0.3) + abs(b[2] - a[2]) / climb + b[4]
        t += b[3] / BRAKE if b[5] > 0 else 0.0
    return t


def time_bound(items: np.ndarray, land_speed: float = 0.7) -> float:
    """A generous bound (s) of a flight flying ``items``: ground phase, take-off, the mission at 70 % of
    its planned pace, the landing."""
    return 30.0 + 10.0 + (-items[0, 2]) / 1.0 + mission_time(items) / 0.7 + (-items[-1, 2]) / land_speed + 30.0


def _square(g: np.random.Generator, m: MissionParams, alt: float, v: float, t: float) -> tuple[list, dict]:
    base = [(0.0, 0.0)] + [tuple(c) for c in m.corners] + [(0.0, 0.0)]
    jitter = g.uniform(-m.jitter_m, m.jitter_m, size=(len(base), 3))
    jitter[0, :2] = 0.0
    jitter[-1, :2] = 0.0
    # braking into the corners (the paper profile's square, flown without the families, has none): a heavy
    # frame (an x500 with 20 % payload hovers at 72 % thrust) otherwise overshot a corner and circled it
    rows = [_row(n + j[0], e + j[1], alt + j[2], v) for (n, e), j in zip(base, jitter)]
    return rows, {}


def _survey(g, m, alt, v, t):
    """A lawnmower over a quadrilateral (a trapezoid turned and set off from home): lanes ``spacing``
    apart, half a spacing in from its edges, so every point of it is within half a spacing of a lane."""
    spacing = g.uniform(8.0, 20.0)
    width = g.uniform(30.0, 120.0)  # the long side
    taper = g.uniform(0.6, 1.0)  # the far side's length over the near side's
    per_lane = width * (1 + taper) / 2 / v + spacing / v + 2 * v / BRAKE
    lanes = int(np.clip(round(t / per_lane), 2, 60))
    height = lanes * spacing
    theta = g.uniform(0, 2 * np.pi)
    off = g.uniform(10.0, 40.0)
    phi = g.uniform(0, 2 * np.pi)
    c, s = math.cos(theta), math.sin(theta)
    origin = np.array([off * math.cos(phi), off * math.sin(phi)])

    def world(x: float, y: float) -> np.ndarray:
        return origin + np.array([c * x - s * y, s * x + c * y])

    def length(y: float) -> float:
        return width * (1 + (taper - 1) * y / height)

    rows = [_row(0, 0, alt, v)]
    for k in range(lanes):
        y = (k + 0.5) * spacing
        ends = [(0.0, y), (length(y), y)]
        for x, yy in (ends if k % 2 == 0 else ends[::-1]):
            rows.append(_row(*world(x, yy), alt, v))
    rows.append(_row(0, 0, alt, v))
    polygon = np.array([world(0, 0), world(width, 0), world(width * taper, height), world(0, height)])
    return rows, {"polygon": polygon, "spacing": spacing}


def _orbit(g, m, alt, v, t):
    """Laps of a circle flown through points every 15 degrees (fly-through items), entered at its
    nearest point, left there for home."""
    radius = g.uniform(15.0, 40.0)
    v = min(v, math.sqrt(TURN_ACC * radius))
    dist = g.uniform(radius + 10.0, radius + 50.0)
    phi = g.uniform(0, 2 * np.pi)
    centre = dist * np.array([math.cos(phi), math.sin(phi)])
    turn = 1.0 if g.random() < 0.5 else -1.0
    sweep = float(np.clip(t * v / radius, 1.5 * np.pi, 40 * np.pi))
    step = np.deg2rad(15.0)
    n = int(math.ceil(sweep / step))
    a0 = phi + np.pi  # the circle's point nearest home
    spacing = 2 * radius * math.sin(step / 2)
    rows = [_row(0, 0, alt, v), _row(*(centre + radius * np.array([math.cos(a0), math.sin(a0)])), alt, v)]
    for k in range(1, n + 1):
        a = a0 + turn * k * step
        rows.append(_row(*(centre + radius * np.array([math.cos(a), math.sin(a)])), alt, v * min(1.0, 0.2 + 0.2 * k),
                         0.0, BRAKE if k == n else -0.5 * spacing))  # speeding up over the first 60 degrees
    rows.append(_row(0, 0, alt, v))
    return rows, {"centre": centre, "radius": radius}


def _corridor(g, m, alt, v, t):
    """An inspection of a line (a power line, a facade): passes back and forth along it, each
    ``step`` higher than the last, stopping at inspection points to hold."""
    length = g.uniform(30.0, 150.0)
    step = g.uniform(3.0, 8.0)
    stops = int(g.integers(2, 6))
    hold = g.uniform(2.0, 6.0)
    theta = g.uniform(0, 2 * np.pi)
    off = g.uniform(5.0, 20.0)
    u = np.array([math.cos(theta), math.sin(theta)])
    start = off * np.array([-u[1], u[0]])
    per_pass = length / v + stops * (hold + 2 * v / BRAKE) + step / 1.5
    passes = int(np.clip(round(t / per_pass), 1, 30))
    rows = [_row(0, 0, alt, v), _row(*start, alt, v)]
    a = alt
    for p in range(passes):
        xs = np.linspace(0, length, stops + 1)[1:]
        if p % 2 == 1:
            xs = length - xs
        for x in xs:
            rows.append(_row(*(start + x * u), a, v, hold))
        a = a + step
        rows.append(_row(*rows[-1][:2], a, v))
    rows.append(_row(0, 0, a, v))
    return rows, {"line": np.array([start, start + length * u])}


def _delivery(g, m, alt, v, t):
    """Out to a drop point at cruise height, down to the drop height, hover there, back up, home."""
    drop_alt = g.uniform(2.0, 6.0)
    hold = g.uniform(5.0, 20.0)
    dist = float(np.clip(v * max(t - hold - 2 * (alt - drop_alt) / 1.5, 0.5 * t) / 2, 30.0, 3000.0))
    phi = g.uniform(0, 2 * np.pi)
    drop = dist * np.array([math.cos(phi), math.sin(phi)])
    rows = [_row(0, 0, alt, v), _row(*drop, alt, v), _row(*drop, drop_alt, v, hold), _row(*drop, alt, v),
            _row(0, 0, alt, v)]
    return rows, {"drop": drop, "drop_altitude": drop_alt}


def _random_waypoints(g, m, alt, v, t):
    """Legs between random points within a radius, at heights and speeds of their own, some held."""
    radius = g.uniform(20.0, 120.0)
    rows = [_row(0, 0, alt, v)]
    while mission_time(np.array(rows + [_row(0, 0, alt, v)])) < t or len(rows) < 3:
        r, phi = radius * math.sqrt(g.random()), g.uniform(0, 2 * np.pi)
        rows.append(_row(r * math.cos(phi), r * math.sin(phi), max(3.0, alt + g.uniform(-5, 5)),
                         v * g.uniform(0.6, 1.0), g.uniform(2, 8) if g.random() < 0.2 else 0.0))
    rows.append(_row(0, 0, alt, v))
    return rows, {"radius": radius}


def _hover(g, m, alt, v, t):
    """Position hold: move a few metres off the take-off point and hold there, then land."""
    r, phi = g.uniform(0, 3.0), g.uniform(0, 2 * np.pi)
    spot = (r * math.cos(phi), r * math.sin(phi))
    rows = [_row(0, 0, alt, v), _row(*spot, alt, v, max(t - 10.0, 5.0)), _row(0, 0, alt, v)]
    return rows, {"spot": np.array(spot)}


def _hand_flown(g, m, alt, v, t):
    """A pilot in position mode: stretches of smooth stick input (speed ramped in and out over 2 s,
    heading and height wandering smoothly, pulled back towards home beyond ``radius``) between hovers
    with the stick centred. Sampled every STICK_DT as fly-through items, so the navigator follows the
    velocity the pilot gave."""
    radius = g.uniform(20.0, 80.0)
    pos = np.zeros(2)
    a = alt
    heading = g.uniform(0, 2 * np.pi)
    rows = [_row(0, 0, alt, v)]
    elapsed = 0.0
    while elapsed < t:
        if g.random() < 0.3:  # the stick centred: a hover
            hold = g.uniform(2.0, 12.0)
            rows.append(_row(*pos, a, 1.0, hold))
            elapsed += hold + 2.0
            continue
        dur = g.uniform(5.0, 30.0)
        top = v * g.uniform(0.4, 1.0)
        rate = g.normal(0, 0.3)  # rad/s, the turn the pilot holds
        climb = g.uniform(-0.2, 0.2)  # m/s
        n = max(int(dur / STICK_DT), 2)
        for k in range(1, n + 1):
            tk = k * STICK_DT
            speed = top * min(1.0, tk / 2.0, (dur - tk + STICK_DT) / 2.0)
            rate = 0.8 * rate + 0.2 * g.normal(0, 0.3)
            rate = min(abs(rate), TURN_ACC / max(speed, 0.5)) * np.sign(rate)
            if np.linalg.norm(pos) > radius:  # back towards home
                home = math.atan2(-pos[1], -pos[0])
                rate = float(np.clip(math.remainder(home - heading, 2 * np.pi), -0.5, 0.5))
            heading += rate * STICK_DT
            pos = pos + speed * STICK_DT * np.array([math.cos(heading), math.sin(heading)])
            a = float(np.clip(a + climb * STICK_DT, 2.0, alt + 10.0))
            last = k == n
            rows.append(_row(*pos, a, max(speed, 0.5), 0.0, BRAKE if last else -max(1.0, 0.6 * speed * STICK_DT)))
        elapsed += dur + 2.0
    rows.append(_row(0, 0, a, v))
    return rows, {}


_BUILD = {"square": _square, "survey": _survey, "orbit": _orbit, "corridor": _corridor, "delivery": _delivery,
          "random_waypoints": _random_waypoints, "hover": _hover, "hand_flown": _hand_flown}


def draw_mission(seed: int, mission: MissionParams) -> MissionDraw:
    """The mission of the flight with ``seed`` under ``mission.families`` (sorted (family, weight)
    pairs summing to 1): family, then planned duration (log-uniform in ``mission.duration_range``),
    altitude and speed (uniform in the family's RANGES), payload, then the family's geometry."""
    from scart_bench.generator.physics.airframes import pick

    g = _rng(seed)
    family = pick(mission.families, float(g.random()))
    lo, hi = mission.duration_range
    t = float(math.exp(g.uniform(math.log(lo), math.log(hi))))
    if family == "square":
        alt, v = mission.altitude, mission.cruise_speed + g.uniform(-mission.jitter_speed, mission.jitter_speed)
    else:
        alt, v = (float(g.uniform(*RANGES[family][k])) for k in ("altitude", "speed"))
    payload = float(g.choice(PAYLOAD_LEVELS, p=PAYLOAD_WEIGHTS))
    if family == "delivery":
        payload = max(payload, PAYLOAD_LEVELS[1])
    rows, shape = _BUILD[family](g, mission, alt, v, t)
    items = np.array(rows, dtype=float)
    return MissionDraw(family, float(alt), float(v), float(mission_time(items)), payload, items, shape)
