"""Fit the pilot in attitude mode (``MissionParams.pilot_*``, generator.flight_software.pilot) to a fleet.

Why: a fleet flown by hand rocks at 0.5-5 Hz (the ArduCopter fleet's cruise roll and pitch carry 40-70x
the 0.5-5 Hz power of flights that follow waypoints with PX4's position controller, docs/like.md).
Per log (:func:`figures`): is it hand-flown (its flight modes: ArduCopter ``MODE`` STABILIZE, ALT_HOLD,
LOITER, ...; or its cruise attitude spectrum), and on 10 s windows of its airborne time, moving (cruise:
median horizontal speed above 1 m/s) or still (hover), the median power of roll and pitch in 0.5-2 and
2-5 Hz (at 10 Hz, as an ArduCopter ATT), of the yaw rate (gyro z) and the vertical accelerometer in
0.5-2 Hz. Over the fleet (:func:`fit_pilot`) the median of each over the hand-flown logs; the pilot's
amplitudes and corner are then set by calibration flights (a square at the fleet's cruise speed, measured
with the same code), as the sensor noise is (``fit.calibrate_noise``): power is linear in the square of a
stick's amplitude, and the share of 2-5 Hz in the roll's power grows with the corner.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

#: ArduCopter flight modes flown with the sticks (MODE.Mode): STABILIZE, ACRO, ALT_HOLD, LOITER, DRIFT, SPORT,
#: FLIP, POSHOLD; AUTO (3), GUIDED (4), RTL (6), CIRCLE (7), LAND (9) are not
HAND_MODES = {0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 5: "LOITER", 11: "DRIFT", 13: "SPORT", 14: "FLIP",
              16: "POSHOLD"}
#: rad^2: cruise roll/pitch power in 0.5-2 Hz above which a log without mode messages counts as hand-flown
#: (PX4 position control in the generator: ~1e-4; the fleet: 2e-3 to 2e-2)
HAND_TILT_POWER = 1e-3
ATT_HZ = 10.0
IMU_HZ = 50.0
WINDOW_S = 10.0
STEP_S = 5.0
BANDS = ((0.5, 2.0), (2.0, 5.0))
#: calibration: flights, rounds (the square flown at the fleet's cruise speed, at least 1 m/s: a leg, full stick)
CAL_FLIGHTS = 3
CAL_ROUNDS = 4
#: the starting point of the calibration (deg, deg, g, Hz)
START = {"pilot_stick_deg": 4.0, "pilot_yaw_deg": 1.0, "pilot_throttle": 0.03, "pilot_stick_hz": 1.5}


def _band_power(x: np.ndarray, hz: float, lo: float, hi: float) -> float:
    from scipy.signal import periodogram

    f, p = periodogram(x, fs=hz, window="hann", detrend="constant", scaling="density")
    return float(p[(f >= lo) & (f < hi)].sum() * (f[1] - f[0]))


def _at(t: np.ndarray, x: np.ndarray, grid: np.ndarray) -> np.ndarray:
    return x[np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)]


def hand_modes(tables) -> list[str]:
    """The hand-flown flight modes a log's mode messages name (ArduPilot MODE.Mode; empty: none logged)."""
    df = tables.get("mode")
    if df is None:
        return []
    col = "Mode" if "Mode" in df.columns else "ModeNum" if "ModeNum" in df.columns else None
    if col is None:
        return []
    seen = {int(v) for v in df[col].dropna().to_numpy(float)}
    return sorted({HAND_MODES[v] for v in seen if v in HAND_MODES})


def figures(tables, phases, tilt, vel, gz, az) -> dict[str, float]:
    """A log's pilot figures (see the module doc) from its mode messages (``tables``), phases and series
    (``generator.like.fit.pilot_figures`` finds them by meaning: (t, roll, pitch) in rad, (t, (n, 3) velocity),
    (topic, t, gyro z) and (topic, t, accelerometer z), or None): ``{phase}_tilt_{band}`` (rad^2, mean of roll and
    pitch), ``{phase}_yaw`` ((rad/s)^2 of gyro z in 0.5-2 Hz), ``{phase}_accz`` ((m/s^2)^2 in 0.5-2 Hz),
    ``{phase}_windows``, and ``hand`` (1: hand-flown modes logged, 0: only other modes, NaN: no mode messages)."""
    out: dict[str, float] = {}
    df = tables.get("mode")
    out["hand"] = float(bool(hand_modes(tables))) if df is not None and len(df) else math.nan
    if tilt is None or phases is None:
        return out
    tp = phases["Timestamp"].to_numpy(np.int64) / 1e6
    air = (phases["phase"].to_numpy(object) != "landed") & (phases["altitude_m"].to_numpy(float) > 1.5)
    t0, t1 = float(tilt[0][0]), float(tilt[0][-1])
    per: dict[str, list[list[float]]] = {"cruise": [], "hover": []}
    a = t0
    while a + WINDOW_S <= t1:
        b = a + WINDOW_S
        sel = (tp >= a) & (tp < b)
        inside = tilt[0][(tilt[0] >= a) & (tilt[0] < b)]
        if sel.sum() >= 3 and air[sel].all() and len(inside) >= 0.8 * WINDOW_S * ATT_HZ and np.diff(inside).max() < 1.0:
            phase = None
            if vel is not None:
                vs = (vel[0] >= a) & (vel[0] < b)
                if vs.sum() >= 3:
                    phase = "cruise" if np.median(np.hypot(vel[1][vs, 0], vel[1][vs, 1])) > 1.0 else "hover"
            if phase is not None:
                grid = a + np.arange(int(WINDOW_S * ATT_HZ)) / ATT_HZ
                row = []
                for lo, hi in BANDS:
                    row.append(0.5 * sum(_band_power(_at(tilt[0], x, grid), ATT_HZ, lo, hi) for x in (tilt[1], tilt[2])))
                grid50 = a + np.arange(int(WINDOW_S * IMU_HZ)) / IMU_HZ
                for hit in (gz, az):
                    row.append(_band_power(_at(hit[1], hit[2], grid50), IMU_HZ, *BANDS[0]) if hit is not None
                               and ((hit[1] >= a) & (hit[1] < b)).sum() >= 0.8 * WINDOW_S * IMU_HZ else math.nan)
                per[phase].append(row)
        a += STEP_S
    for phase, rows in per.items():
        out[f"{phase}_windows"] = float(len(rows))
        if rows:
            med = np.nanmedian(np.array(rows, float), axis=0)
            out[f"{phase}_tilt_0.5_2"], out[f"{phase}_tilt_2_5"], out[f"{phase}_yaw"], out[f"{phase}_accz"] = map(float, med)
    return out


def is_hand_flown(fig: dict[str, float]) -> bool:
    """Hand-flown by its modes, or (no mode messages) by its cruise attitude spectrum."""
    if math.isfinite(fig.get("hand", math.nan)):
        return fig["hand"] > 0
    return fig.get("cruise_tilt_0.5_2", 0.0) > HAND_TILT_POWER


def _median(figs: list[dict[str, float]], key: str) -> tuple[float, int]:
    v = [f[key] for f in figs if math.isfinite(f.get(key, math.nan))]
    return (float(np.median(v)), len(v)) if v else (math.nan, 0)


def calibration_figures(config, measure, n: int = CAL_FLIGHTS, seed: int = 4242) -> dict[str, float]:
    """The pilot figures (median over ``n`` flights) of generated flights of ``config``: the square at its
    cruise speed with a 15 s hover after take-off, measured as a log's (``measure(tables, phases)``)."""
    mission = dataclasses.replace(config.mission, missions=(), families=(), takeoff_hold_s=15.0, pilot_share=1.0)
    per = fly_measured(config, mission, measure, n, seed)
    return {k: _median(per, k)[0] for k in {k for p in per for k in p}}


def fly_measured(config, mission, measure, n: int, seed: int) -> list[dict[str, float]]:
    """``n`` calibration flights of ``config`` flying ``mission`` on its own vehicle (no airframe mix), each
    measured as a log is (``measure(tables, phases)`` on its simulator view)."""
    from scart_bench.generator.engine.simulate import simulate
    from scart_bench.generator.logs.phases import flight_phases
    from scart_bench.generator.plan import normal_seeds
    from scart_bench.generator.telemetry.tables import flight_views

    batch = simulate(normal_seeds(seed, n), dataclasses.replace(config, mission=mission, airframes=()))
    per = []
    for i in range(n):
        _, sim = flight_views(batch, i, ())
        tables = {k: v for k, v in sim.items() if k not in ("truth", "setpoint")}
        per.append(measure(tables, flight_phases(tables)))
    return per


def fit_pilot(figs: list[dict[str, float]], names: list[str], config, measure, cruise_speed: float = math.nan
              ) -> tuple[dict[str, tuple[object, str]], list[str]]:
    """``[mission]`` fields (value, comment) of the pilot fitted to the logs' figures, and lines said.

    On when at least half of the logs that say (modes or cruise spectrum) are hand-flown; each amplitude
    scaled by sqrt(fleet / generated) of its figure per round, the corner by the square root of the ratio of
    the fleet's 2-5 Hz share of the roll power to the generated one, the hover factor (starting at the fleet's
    sqrt(hover / cruise) roll power) by sqrt(fleet / generated) of the hover's. ``measure(tables, phases)``: a
    flight's figures (``generator.like.fit.pilot_figures``)."""
    hand = [f for f in figs if is_hand_flown(f)]
    said = [f for f, n in zip(figs, names) if math.isfinite(f.get("hand", math.nan)) or "cruise_tilt_0.5_2" in f]
    lines: list[str] = []
    if not said or 2 * len(hand) < len(said):
        return {}, [f"pilot: {len(hand)} of {len(said)} logs hand-flown (modes or attitude spectrum): flown by the "
                    f"navigator's setpoints only"]
    target = {k: _median(hand, f"cruise_{k}") for k in ("tilt_0.5_2", "tilt_2_5", "yaw", "accz")}
    if not target["tilt_0.5_2"][1]:
        return {}, [f"pilot: {len(hand)} hand-flown logs, none with a cruise (velocity and 10 s moving): not fitted"]
    hover, n_hover = _median(hand, "hover_tilt_0.5_2")
    factor = float(np.clip(math.sqrt(hover / target["tilt_0.5_2"][0]), 0.2, 1.0)) if n_hover else 0.5
    level = dict(START)
    speed = max(cruise_speed if math.isfinite(cruise_speed) else config.mission.cruise_speed, 1.0)
    gen: dict[str, float] = {}
    plan = (("pilot_stick_deg", "tilt_0.5_2"), ("pilot_yaw_deg", "yaw"), ("pilot_throttle", "accz"))
    for r in range(CAL_ROUNDS + 1):
        mission = dataclasses.replace(config.mission, cruise_speed=speed, pilot_hover_factor=factor, **level)
        gen = calibration_figures(dataclasses.replace(config, mission=mission), measure)
        if r == CAL_ROUNDS:
            break
        for fld, key in plan:
            want, got = target[key][0], gen.get(f"cruise_{key}", math.nan)
            if math.isfinite(want) and math.isfinite(got) and got > 0:
                level[fld] = float(np.clip(level[fld] * math.sqrt(want / got), level[fld] / 4, level[fld] * 4))
        got_hover = gen.get("hover_tilt_0.5_2", math.nan)
        if n_hover and math.isfinite(got_hover) and got_hover > 0:
            factor = float(np.clip(factor * math.sqrt(hover / got_hover), 0.05, 1.0))
        want_share = target["tilt_2_5"][0] / target["tilt_0.5_2"][0]
        got_share = gen.get("cruise_tilt_2_5", math.nan) / gen.get("cruise_tilt_0.5_2", math.nan)
        if math.isfinite(want_share) and math.isfinite(got_share) and got_share > 0:
            level["pilot_stick_hz"] = float(np.clip(level["pilot_stick_hz"] * math.sqrt(want_share / got_share), 0.3, 5.0))
    n = len(hand)

    def cmp(key: str) -> str:
        return f"fleet {target[key][0]:.3g}, generated {gen.get(f'cruise_{key}', math.nan):.3g}"

    out: dict[str, tuple[object, str]] = {
        "pilot_stick_deg": (round(level["pilot_stick_deg"], 3), f"roll/pitch stick std on a leg: cruise roll/pitch power "
                            f"0.5-2 Hz (rad^2) {cmp('tilt_0.5_2')}; median over {target['tilt_0.5_2'][1]} of {n} "
                            f"hand-flown logs"),
        "pilot_stick_hz": (round(level["pilot_stick_hz"], 3), f"the sticks' corner: cruise roll/pitch power 2-5 Hz "
                           f"{cmp('tilt_2_5')}"),
        "pilot_yaw_deg": (round(level["pilot_yaw_deg"], 3), f"yaw stick: cruise gyro z power 0.5-2 Hz {cmp('yaw')}"),
        "pilot_throttle": (round(level["pilot_throttle"], 4), f"throttle stick (g): cruise accelerometer z power "
                           f"0.5-2 Hz {cmp('accz')}"),
        "pilot_hover_factor": (round(factor, 3), f"the sticks at hover: hover roll/pitch power 0.5-2 Hz fleet {hover:.3g} "
                               f"({n_hover} logs with a hover), generated {gen.get('hover_tilt_0.5_2', math.nan):.3g}"),
    }
    lines.append(f"pilot: {n} of {len(said)} logs hand-flown: a pilot in attitude mode on every flight "
                 f"(roll/pitch stick {level['pilot_stick_deg']:.2f} deg at {level['pilot_stick_hz']:.2f} Hz)")
    return out, lines
