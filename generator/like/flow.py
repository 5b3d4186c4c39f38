"""Fit each vehicle's rocking in forward flight (``MissionParams.rocking_flow_levels``, physics.vehicle.FlowRocking).

Why: the ArduCopter fleet's hand-flown vehicles rock in roll and pitch at 1-5 Hz when they move and much less at rest
(gyro x power in 1-5 Hz by GPS speed, 10 s windows: 0.002-0.008 (rad/s)^2 below 0.5 m/s, 0.02-0.1 at 1-1.5 m/s,
0.2-1.2 at 2-5 m/s on the logs with a GPS), where the generated flights' cruise roll was too smooth at 10 Hz (lag-1
0.95 against 0.90, 2-5 Hz power x0.25; docs/like.md "Rocking in forward flight").
Per log (:func:`figures`): on 10 s airborne windows moving faster than :data:`MOVING_M_S`, the median power of roll
and pitch in 1-5 Hz (at 10 Hz, as an ArduCopter ATT) and the windows' median speed. Over the fleet
(:func:`fit_flow`): calibration flights (the square at :data:`CAL_SPEED_M_S`, where the rocking is full) without it
and at :data:`REF` give the generated power and its response (linear in the square of the level); a log's level adds
the rest of its power, divided by the rocking's gain at the log's speed (a log flying at 1.5 m/s needs 4x the level
of one at full speed for the same rocking). A log without moving windows gets the median level of those with them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

ATT_HZ = 10.0
WINDOW_S = 10.0
STEP_S = 5.0
#: m/s: a window moving faster than this counts (the window classifier's cruise: 1 m/s)
MOVING_M_S = 1.0
BAND = (1.0, 5.0)
#: the rocking's shape (not fitted): a first-order low-pass at 1 Hz (at 2 Hz the cruise's flight AUC stayed 0.996-1.000,
#: 60 flights); from 0.5 m/s (from 1 m/s half the generated cruise windows, which move at 0.9 m/s (median) where the
#: fleet's move at 1.6, got none: cruise flight AUC 1.000, from 0.5 m/s 0.983-0.996 on the same levels) to full at 3 m/s
FLOW_HZ = 1.0
FROM_M_S = 0.5
FULL_M_S = 3.0
#: calibration: the square at this speed (the rocking full), flights, the reference level (rad/s^2)
CAL_SPEED_M_S = 3.0
CAL_FLIGHTS = 3
REF = 20.0
#: the most fitted (rad/s^2), the most at a log's own speed (the level times its gain: 28.5 and 20 at full speed
#: crashed 2 of the 60 flights of `arducopter_181`'s mission, which flies at 5-15 m/s; 14 and 10 landed all 60), and
#: the least gain a log's speed is credited with
MAX_LEVEL = 150.0
MAX_AT_SPEED = 12.0
MIN_GAIN = 0.25


def _band_power(x: np.ndarray, hz: float, lo: float, hi: float) -> float:
    from scipy.signal import periodogram

    f, p = periodogram(x, fs=hz, window="hann", detrend="linear", scaling="density")
    return float(p[(f >= lo) & (f < hi)].sum() * (f[1] - f[0]))


def _at(t: np.ndarray, x: np.ndarray, grid: np.ndarray) -> np.ndarray:
    return x[np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)]


def figures(phases, tilt, vel) -> dict[str, float]:
    """A log's forward-flight rocking figures from its phases, (t, roll, pitch) in rad and (t, (n, 3) velocity):
    ``moving_roll``, ``moving_pitch`` (rad^2 in :data:`BAND`, medians over the moving windows), ``moving_speed``
    (m/s, their median) and ``moving_windows``; empty without attitude, velocity or phases."""
    if tilt is None or vel is None or phases is None:
        return {}
    tp = phases["Timestamp"].to_numpy(np.int64) / 1e6
    air = (phases["phase"].to_numpy(object) != "landed") & (phases["altitude_m"].to_numpy(float) > 1.5)
    t0, t1 = float(tilt[0][0]), float(tilt[0][-1])
    rows = []
    a = t0
    while a + WINDOW_S <= t1:
        b = a + WINDOW_S
        sel = (tp >= a) & (tp < b)
        inside = tilt[0][(tilt[0] >= a) & (tilt[0] < b)]
        vs = (vel[0] >= a) & (vel[0] < b)
        if (sel.sum() >= 3 and air[sel].all() and len(inside) >= 0.8 * WINDOW_S * ATT_HZ
                and np.diff(inside).max() < 1.0 and vs.sum() >= 3):
            speed = float(np.median(np.hypot(vel[1][vs, 0], vel[1][vs, 1])))
            if speed > MOVING_M_S:
                grid = a + np.arange(int(WINDOW_S * ATT_HZ)) / ATT_HZ
                rows.append([_band_power(_at(tilt[0], x, grid), ATT_HZ, *BAND) for x in (tilt[1], tilt[2])] + [speed])
        a += STEP_S
    if not rows:
        return {"moving_windows": 0.0}
    med = np.median(np.array(rows), axis=0)
    return {"moving_roll": float(med[0]), "moving_pitch": float(med[1]), "moving_speed": float(med[2]),
            "moving_windows": float(len(rows))}


def gain(speed: float) -> float:
    """The rocking's gain at ``speed`` (physics.vehicle.FlowRocking), at least :data:`MIN_GAIN`."""
    return float(np.clip((speed - FROM_M_S) / (FULL_M_S - FROM_M_S), MIN_GAIN, 1.0))


def calibration(config, measure, level: float, n: int = CAL_FLIGHTS, seed: int = 4343) -> dict[str, float]:
    """The figures (median over ``n`` flights) of the square flown at :data:`CAL_SPEED_M_S` with the rocking at
    ``level`` on every flight, measured as a log's (``measure(tables, phases)``)."""
    from scart_bench.generator.like.pilot import fly_measured

    mission = dataclasses.replace(config.mission, missions=(), families=(), takeoff_hold_s=15.0, pilot_share=1.0,
                                  cruise_speed=CAL_SPEED_M_S, rocking_levels=(),
                                  rocking_flow_levels=((level, level),) if level > 0 else (),
                                  rocking_flow_hz=FLOW_HZ, rocking_flow_from_m_s=FROM_M_S,
                                  rocking_flow_full_m_s=FULL_M_S)
    per = fly_measured(config, mission, measure, n, seed)
    keys = ("moving_roll", "moving_pitch")
    return {k: float(np.median([p[k] for p in per if math.isfinite(p.get(k, math.nan))] or [math.nan])) for k in keys}


def fit_flow(figs: dict[str, dict[str, float]], config, measure, lines: list[str]
             ) -> tuple[dict[str, tuple[float, float]], dict[str, tuple[object, str]]]:
    """Per log (name -> its :func:`figures`), its vehicle's forward-flight rocking (roll, pitch; rad/s^2 at full
    speed), and the ``[mission]`` fields of its shape (value, comment); empty when no log moves 10 s."""
    moving = {k: f for k, f in figs.items() if f.get("moving_windows", 0.0) > 0}
    if not moving:
        lines.append("forward-flight rocking: no log with 10 s moving faster than 1 m/s (a GPS velocity): not fitted")
        return {}, {}
    base = calibration(config, measure, 0.0)
    ref = calibration(config, measure, REF)
    out: dict[str, tuple[float, float]] = {}
    for name, f in moving.items():
        lv = []
        for ax in ("roll", "pitch"):
            b, r, t = base[f"moving_{ax}"], ref[f"moving_{ax}"], f[f"moving_{ax}"]
            k = (r - b) / REF ** 2 if math.isfinite(b) and math.isfinite(r) else math.nan
            ok = math.isfinite(k) and k > 0 and math.isfinite(t)
            at_speed = min(math.sqrt(max(t - b, 0.0) / k), MAX_AT_SPEED)
            lv.append(round(min(at_speed / gain(f["moving_speed"]), MAX_LEVEL), 2) if ok else 0.0)
        out[name] = (lv[0], lv[1])
    med = tuple(round(float(np.median([v[i] for v in out.values()])), 2) for i in range(2))
    for name in figs:
        out.setdefault(name, med)
    lines.append(f"forward-flight rocking: roll/pitch power {BAND[0]:g}-{BAND[1]:g} Hz of calibration flights at "
                 f"{CAL_SPEED_M_S:g} m/s {base['moving_roll']:.3g}/{base['moving_pitch']:.3g} rad^2, "
                 f"{ref['moving_roll']:.3g}/{ref['moving_pitch']:.3g} at {REF:g} rad/s^2; {len(moving)} of {len(figs)} "
                 f"logs move 10 s (the others get their median {med[0]:g}/{med[1]:g})")
    fields = {"rocking_flow_hz": (FLOW_HZ, "the forward-flight rocking's low-pass (Hz; not fitted)"),
              "rocking_flow_from_m_s": (FROM_M_S, "the speed it starts from (m/s; not fitted)"),
              "rocking_flow_full_m_s": (FULL_M_S, "the speed of the full rocking (m/s; not fitted)")}
    return out, fields
