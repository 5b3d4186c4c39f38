"""Mission phases of a recorded flight, derived from the log itself.

Every row of a flight gets one of :data:`PHASES`: ``landed``, ``takeoff``, ``climb``, ``cruise``,
``descent``. The rule (docs/own_logs.md, "Mission phases"):

1. **Altitude** above the ground: the first source the log has in :data:`ALTITUDE_SOURCES` (the
   local position's ``-z``, the relative altitude, ArduPilot's CTUN/GPS/BARO altitude, else an
   AMSL altitude), minus the ground level (its median while the log says the vehicle is landed
   before take-off, else over the first second). The grid of the phases is that source's rows.
2. **Vertical speed**: the altitude's change over :data:`RATE_WINDOW_S` centred on the row.
3. **Landed** where the log's land detector says so (PX4 ``vehicle_land_detected.landed``,
   MAVLink ``extended_sys_state.landed_state``, ArduPilot ``EV`` events: armed, disarmed and
   land complete are on the ground, not-landed is in the air); without one, where the altitude
   is below :data:`GROUND_HEIGHT_M` and the vertical speed below :data:`CLIMB_RATE_M_S` (or the
   altitude below the ground level: an estimator settling after a hard landing).
4. In the air: the log's own take-off or landing mode where it has one (PX4 ``nav_state``
   AUTO_TAKEOFF -> ``takeoff``, AUTO_LAND / DESCEND -> ``descent``; ArduCopter ``MODE`` LAND ->
   ``descent``); else ``takeoff`` from leaving the ground until the altitude first reaches
   :data:`TAKEOFF_HEIGHT_M`, then ``climb`` / ``descent`` while the vertical speed is above /
   below +-:data:`CLIMB_RATE_M_S`, ``cruise`` otherwise; below the take-off height again and not
   climbing, ``descent`` (the landing, before a land detector confirms the touch-down).
5. Runs shorter than :data:`MIN_RUN_S` take the phase of the run before them (a land detector's
   flicker, a gust), except the log's first and last run and, once the landed flag is settled,
   ``landed`` runs.

The phases use the whole log (the vertical speed looks half a window ahead): they describe a
recording, offline. :func:`mission_progress` turns them into a mission item index for logs that
carry no mission, so ``mission_phase`` conditions apply to them (see its docstring).

It lives with the telemetry tables, below the attack layer whose phase conditions read it
(generator.scart.conditions) and the log importers; ``scart_bench.generator.logs.phases`` still names it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from scart_bench.generator.params import MissionParams

#: The phases, in their code order (the derived topic's ``phase`` field is the index).
PHASES = ("landed", "takeoff", "climb", "cruise", "descent")
LANDED, TAKEOFF, CLIMB, CRUISE, DESCENT = range(len(PHASES))
#: Altitude (m above the ground) below which a flight without a land detector is on the ground.
GROUND_HEIGHT_M = 1.0
#: Altitude (m above the ground) that ends the take-off.
TAKEOFF_HEIGHT_M = 2.0
#: Vertical speed (m/s) beyond which the vehicle climbs or descends.
CLIMB_RATE_M_S = 0.5
#: Window (s) over which the vertical speed is measured.
RATE_WINDOW_S = 1.0
#: Shortest phase run (s); shorter runs join the run before them.
MIN_RUN_S = 1.0
#: Name of the derived topic csv mode listens to (never written to a dataset).
PHASE_TOPIC = "flight_phase"

#: (topic, field, sign, relative): altitude sources in order of preference; ``relative`` sources are
#: already above home (their ground level is still measured: an estimator may start off zero).
ALTITUDE_SOURCES = (
    ("vehicle_local_position", "z", -1.0), ("local_position_ned", "z", -1.0),
    ("global_position_int", "relative_alt", 1.0), ("altitude", "altitude_relative", 1.0),
    ("ctun", "Alt", 1.0), ("gps", "RelAlt", 1.0), ("pos", "RelHomeAlt", 1.0), ("baro", "Alt", 1.0),
    ("vehicle_global_position", "alt", 1.0), ("vehicle_air_data", "baro_alt_meter", 1.0),
    ("vehicle_gps_position", "alt", 1.0), ("vehicle_gps_position", "altitude_msl_m", 1.0),
    ("sensor_gps", "alt", 1.0), ("sensor_gps", "altitude_msl_m", 1.0), ("gps_raw_int", "alt", 1.0),
)
#: PX4 navigation states that name a phase (vehicle_status.nav_state).
PX4_NAV_PHASES = {17: TAKEOFF, 18: DESCENT, 12: DESCENT, 20: DESCENT}
#: ArduCopter flight modes that name a phase (MODE.Mode): LAND.
ARDUCOPTER_MODE_PHASES = {9: DESCENT}
#: ArduCopter event ids (EV.Id) -> on the ground: ARMED, DISARMED, LAND_COMPLETE; NOT_LANDED: in the air.
ARDUCOPTER_EVENTS = {10: True, 11: True, 18: True, 28: False}


def _step_at(times: np.ndarray, values: np.ndarray, grid: np.ndarray, before: float) -> np.ndarray:
    """The latest value at or before each grid time (``before`` ahead of the first)."""
    k = np.searchsorted(times, grid, side="right") - 1
    return np.where(k >= 0, values[np.clip(k, 0, None)], before)


def altitude_source(tables: dict[str, pd.DataFrame]) -> tuple[str, str, float] | None:
    """The first altitude source of :data:`ALTITUDE_SOURCES` with finite values in the log."""
    for topic, field, sign in ALTITUDE_SOURCES:
        df = tables.get(topic)
        if df is not None and field in df.columns and np.isfinite(df[field].to_numpy(np.float64)).sum() >= 2:
            return topic, field, sign
    return None


def land_state(tables: dict[str, pd.DataFrame], grid: np.ndarray) -> tuple[np.ndarray, str] | None:
    """(landed per grid time, its source) from the log's land detector, or None when it has none."""
    ld = tables.get("vehicle_land_detected")
    if ld is not None and "landed" in ld.columns and len(ld):
        v = ld["landed"].to_numpy(np.float64) >= 0.5
        return _step_at(ld["Timestamp"].to_numpy(), v, grid, v[0]).astype(bool), "vehicle_land_detected.landed"
    es = tables.get("extended_sys_state")
    if es is not None and "landed_state" in es.columns:
        s = es["landed_state"].to_numpy(np.float64)
        known = s > 0  # 0: MAV_LANDED_STATE_UNDEFINED
        if known.any():
            v = s[known] == 1  # 1: on the ground; 2 in air, 3 taking off, 4 landing
            return (_step_at(es["Timestamp"].to_numpy()[known], v, grid, v[0]).astype(bool),
                    "extended_sys_state.landed_state")
    ev = tables.get("ev")
    if ev is not None and "Id" in ev.columns:
        ids = ev["Id"].to_numpy(np.float64)
        keep = np.isin(ids, list(ARDUCOPTER_EVENTS))
        if (ids[keep] == 28).any():  # a log that never left the ground has no NOT_LANDED event
            v = np.array([ARDUCOPTER_EVENTS[int(i)] for i in ids[keep]], dtype=bool)
            # ArduCopter boots on the ground
            return _step_at(ev["Timestamp"].to_numpy()[keep], v, grid, True).astype(bool), "ev.Id"
    return None


def mode_phase(tables: dict[str, pd.DataFrame], grid: np.ndarray) -> tuple[np.ndarray, str] | None:
    """(phase code the flight mode names, -1 where it names none, per grid time; its source) or None."""
    for topic, field, table in (("vehicle_status", "nav_state", PX4_NAV_PHASES),
                                ("mode", "Mode", ARDUCOPTER_MODE_PHASES)):
        df = tables.get(topic)
        if df is None or field not in df.columns or not len(df):
            continue
        codes = np.array([table.get(int(m), -1) if np.isfinite(m) else -1
                          for m in df[field].to_numpy(np.float64)])
        return _step_at(df["Timestamp"].to_numpy(), codes, grid, -1).astype(int), f"{topic}.{field}"
    return None


def climb_rate(t_us: np.ndarray, h: np.ndarray, window_s: float = RATE_WINDOW_S) -> np.ndarray:
    """Vertical speed (m/s, up) over ``window_s`` centred on each row (shortened at the ends)."""
    t = t_us / 1e6
    lo = np.maximum(t - window_s / 2, t[0])
    hi = np.minimum(t + window_s / 2, t[-1])
    span = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        v = (np.interp(hi, t, h) - np.interp(lo, t, h)) / span
    return np.where(span > 0, v, 0.0)


def _merge_short_runs(codes: np.ndarray, t_us: np.ndarray, min_s: float = MIN_RUN_S,
                      keep: int | None = None) -> np.ndarray:
    """Runs shorter than ``min_s`` take the code of the run before them; the first and the last run
    (the log's own start and end) and runs of code ``keep`` stay."""
    out = codes.copy()
    starts = np.flatnonzero(np.r_[True, out[1:] != out[:-1]])
    ends = np.r_[starts[1:], len(out)]
    end_t = np.r_[t_us[1:], t_us[-1]]
    for a, b in zip(starts[1:-1], ends[1:-1]):
        if out[a] != keep and (end_t[b - 1] - t_us[a]) / 1e6 < min_s:
            out[a:b] = out[a - 1]
    return out


def _airborne_phases(h: np.ndarray, v: np.ndarray, landed: np.ndarray) -> np.ndarray:
    """Phase codes from altitude, vertical speed and the landed flag (rule 4 without a mode)."""
    codes = np.where(v > CLIMB_RATE_M_S, CLIMB, np.where(v < -CLIMB_RATE_M_S, DESCENT, CRUISE))
    low = h < TAKEOFF_HEIGHT_M
    lifted = np.flatnonzero(np.r_[True, landed[:-1]] & ~landed)  # first airborne row of each flight
    for a in lifted:
        b = a
        while b < len(h) and not landed[b] and low[b] and v[b] >= -CLIMB_RATE_M_S:
            b += 1
        codes[a:b] = TAKEOFF
        end = a + int(np.argmax(landed[a:])) if landed[a:].any() else len(h)
        # low again later in the flight and not climbing: the landing (touched down, not yet detected)
        late = np.arange(b, end)
        codes[late[low[late] & (v[late] <= CLIMB_RATE_M_S)]] = DESCENT
    return np.where(landed, LANDED, codes)


def flight_phases(tables: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Per-row mission phases of a recorded flight (``{topic: table}`` as the importers give).

    Returns a table on the altitude source's rows: ``Timestamp`` (µs), ``phase`` (a name of
    :data:`PHASES`), ``altitude_m`` (above the ground) and ``climb_rate_m_s``; ``attrs`` name the
    sources used (``altitude``, ``landed``, ``mode``). Raises ValueError naming what the log
    lacks when it has no altitude (:data:`ALTITUDE_SOURCES`).
    """
    src = altitude_source(tables)
    if src is None:
        wanted = ", ".join(f"{t}.{f}" for t, f, _ in ALTITUDE_SOURCES)
        raise ValueError(f"the flight's phases need an altitude; the log has none of {wanted}")
    topic, field, sign = src
    df = tables[topic]
    h_raw = sign * df[field].to_numpy(np.float64)
    ok = np.isfinite(h_raw)
    t = df["Timestamp"].to_numpy(np.int64)[ok]
    h_raw = h_raw[ok]
    detector = land_state(tables, t)
    landed_log = detector[0] if detector is not None else None
    h = h_raw - _ground_level(t, h_raw, landed_log)
    v = climb_rate(t, h)
    landed = landed_log if landed_log is not None else (h < GROUND_HEIGHT_M) & ((np.abs(v) < CLIMB_RATE_M_S) | (h < 0))
    landed = _merge_short_runs(landed.astype(int), t).astype(bool)
    codes = _airborne_phases(h, v, landed)
    mode = mode_phase(tables, t)
    if mode is not None:
        codes = np.where(~landed & (mode[0] >= 0), mode[0], codes)
    codes = _merge_short_runs(codes, t, keep=LANDED)
    out = pd.DataFrame({"Timestamp": t, "phase": np.asarray(PHASES, dtype=object)[codes], "altitude_m": h,
                        "climb_rate_m_s": v})
    out.attrs = {"altitude": f"{topic}.{field}", "landed": detector[1] if detector else "altitude",
                 "mode": mode[1] if mode else None}
    return out


def _ground_level(t: np.ndarray, h: np.ndarray, landed: np.ndarray | None) -> float:
    """The altitude of the ground: its median while landed before the first take-off, else over the
    first second of the log."""
    if landed is not None and landed[0]:
        first = np.flatnonzero(~landed)
        stop = first[0] if len(first) else len(h)
        return float(np.median(h[:stop]))
    return float(np.median(h[t <= t[0] + 1_000_000]))


def phase_at(phases: pd.DataFrame, timestamps: np.ndarray) -> np.ndarray:
    """The phase of each of ``timestamps`` (µs): the phase of the latest row at or before it (the
    first row's before the phases start)."""
    t = phases["Timestamp"].to_numpy(np.int64)
    names = phases["phase"].to_numpy(object)
    k = np.clip(np.searchsorted(t, np.asarray(timestamps, dtype=np.int64), side="right") - 1, 0, None)
    return names[k]


def mission_progress(phases: pd.DataFrame, legs: int | None = None) -> np.ndarray:
    """A mission item index per row for a log that carries no mission (what ``setpoint.seq`` is on a
    generated flight), read from its phases.

    The project's mission is a take-off item (index 0) and ``legs`` items flown in cruise (the
    corners and home, index 1 .. legs), landing after the last. A log without mission items is
    read as that mission: item 0 until its first cruise, its cruise time (first to last cruise
    row) split into ``legs`` equal legs, and the last item from then on. So ``mission_phase``
    with ``after_waypoint = 1`` ("once the first corner is reached") holds from a fifth of the
    way through the cruise, and a flight that never cruises never passes item 0.
    """
    legs = legs or len(MissionParams().corners) + 1
    t = phases["Timestamp"].to_numpy(np.int64)
    cruise = np.flatnonzero(phases["phase"].to_numpy(object) == "cruise")
    seq = np.zeros(len(t), dtype=np.int64)
    if not len(cruise):
        return seq
    c0, c1 = t[cruise[0]], t[cruise[-1]]
    frac = (t - c0) / max(c1 - c0, 1)
    seq = np.clip(1 + np.floor(legs * frac).astype(np.int64), 1, legs)
    return np.where(t < c0, 0, seq)


def phase_topic(tables: dict[str, pd.DataFrame]) -> pd.DataFrame | None:
    """The derived topic csv mode listens to (:data:`PHASE_TOPIC`): ``phase`` (the index in
    :data:`PHASES`) and ``seq`` (the mission item: the log's own ``mission_result.seq_current``
    where it carries a mission, else :func:`mission_progress`), on the altitude source's rows.
    None when the log has no altitude."""
    try:
        phases = flight_phases(tables)
    except ValueError:
        return None
    t = phases["Timestamp"].to_numpy(np.int64)
    codes = np.array([PHASES.index(p) for p in phases["phase"]], dtype=np.float64)
    mission = tables.get("mission_result")
    if _carries_mission(mission):
        seq = _step_at(mission["Timestamp"].to_numpy(), mission["seq_current"].to_numpy(np.float64), t, 0.0)
    else:
        seq = mission_progress(phases).astype(np.float64)
    return pd.DataFrame({"Timestamp": t, "phase": codes, "seq": seq})


def _carries_mission(mission: pd.DataFrame | None) -> bool:
    """True for a PX4 mission_result that describes a mission with items (seq_total > 0)."""
    if mission is None or "seq_current" not in mission.columns or not len(mission):
        return False
    total = mission["seq_total"].to_numpy(np.float64) if "seq_total" in mission.columns else np.ones(1)
    return bool(np.nanmax(total) > 0)


#: Where a phase-relative trigger counts from (``after_phase``): ``takeoff`` (or ``airborne``) is the
#: first row off the ground; ``climb``, ``cruise``, ``descent`` the first row of that phase after it.
ANCHORS = ("takeoff", "airborne", "climb", "cruise", "descent")


def phase_progress(topic: pd.DataFrame, logged_us: np.ndarray | None = None) -> pd.DataFrame:
    """The derived phase topic with the fields phase-relative triggers read (conditions
    ``after_phase`` and ``airborne``), counted in logged time (``logged_us``: each row's logged
    time, generator.logs.logged_time; default its ``Timestamp``):

    - ``since_<anchor>_s``: seconds since the anchor (:data:`ANCHORS`; NaN before it, and for a
      phase the flight never enters);
    - ``<phase>_fraction``: the share of the flight's time in that phase (``airborne``: off the
      ground) spent up to this row, 0 to 1 (NaN for a phase the flight never enters).
    """
    t = np.asarray(topic["Timestamp"] if logged_us is None else logged_us, dtype=np.int64)
    codes = topic["phase"].to_numpy(np.float64).astype(int)
    out = topic.copy()
    airborne = codes != LANDED
    first_air = int(np.argmax(airborne)) if airborne.any() else None
    dt = np.r_[np.diff(t), 0].astype(np.float64)
    for name in ANCHORS:
        mask = airborne if name in ("takeoff", "airborne") else codes == PHASES.index(name)
        if first_air is not None:
            mask = mask & (np.arange(len(t)) >= first_air)
        since = np.full(len(t), np.nan)
        if mask.any():
            k = int(np.argmax(mask))
            since[k:] = (t[k:] - t[k]) / 1e6
        out[f"since_{name}_s"] = since
        in_phase = airborne if name == "airborne" else codes == PHASES.index(name)
        spent = np.r_[0.0, np.cumsum(dt * in_phase)[:-1]]
        total = float(np.sum(dt * in_phase))
        out[f"{name}_fraction"] = spent / total if total > 0 else np.nan
    return out
