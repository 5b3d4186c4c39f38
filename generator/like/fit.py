"""Measure a user's logs and fit the generator to them (``scart-bench generate --like LOG...``).

Per log (:func:`measure_log`, any format :func:`load_flight_file` reads, quantities found by
meaning through :data:`scart_bench.generator.scart.meanings.QUANTITIES`): its mission
(:mod:`.tracks`), duration, take-off and landing (time on the ground before take-off, climb rate,
hover after take-off, descent rate), wind (the estimator's wind states where logged, else the mean
tilt at hover), sensor noise per axis on its hover and ground segments (the per-sample standard
deviation after removing a 1 s moving average, as ``perf/realism.py`` measures it), message rates
and interval jitter per quantity, GPS accuracy (eph/epv) and the site. Anything a log cannot give is
one line in :attr:`LogMeasure.notes`, and that quantity keeps the generator's default.

Over the fleet (:func:`fit_fleet`) each quantity is the median over the logs that measured it. The
sensor noise is mapped onto :class:`SensorParams` by flying a few calibration flights with the base
parameters, measuring them with the same code, and scaling each noise parameter by the ratio log /
generated (:func:`calibrate_noise`): the generated flights are then measured like the logs, whatever
filtering the generator's sensor model applies between its noise densities and the written rows.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.generator.like import flow as like_flow
from scart_bench.generator.like import pilot as like_pilot
from scart_bench.generator.like import timing as like_timing
from scart_bench.generator.like import tracks
from scart_bench.generator.scart.meanings import QUANTITIES

#: figures' clock (Hz) and high-pass window (s), as perf/realism.py
NOISE_HZ = 50.0
BARO_HZ = 10.0
HP_WINDOW_S = 1.0
#: a hover for the noise figures: in the air, vertical / horizontal speed below these (m/s)
HOVER_V_M_S = 0.5
HOVER_H_M_S = 1.0
#: least still time (s) a noise figure is measured on
MIN_SEGMENT_S = 2.0
EDGE_S = 0.5
#: the estimator's wind states, by meaning (north, east)
WIND_FIELDS = (("ekf2.VWN", "ekf2.VWE"), ("nkf2.VWN", "nkf2.VWE"), ("xkf2.VWN", "xkf2.VWE"),
               ("wind_estimate.windspeed_north", "wind_estimate.windspeed_east"),
               ("wind.windspeed_north", "wind.windspeed_east"),
               ("estimator_wind.windspeed_north", "estimator_wind.windspeed_east"))
#: a larger mean tilt at hover is not taken for wind (m/s ~ 9 at the generator's airframe)
MAX_WIND_TILT_DEG = 8.0
#: GPS accuracy fields (m), by meaning (horizontal, vertical)
GPS_ACCURACY_FIELDS = (("vehicle_gps_position.eph", "vehicle_gps_position.epv"), ("sensor_gps.eph", "sensor_gps.epv"),
                       ("ubx3.hAcc", "ubx3.vAcc"), ("gpa.HAcc", "gpa.VAcc"))
#: the estimator's velocity (for the still mask), preferred over a GPS velocity
VELOCITY_FIELDS = (("vehicle_local_position.vx", "vehicle_local_position.vy", "vehicle_local_position.vz"),
                   ("local_position_ned.vx", "local_position_ned.vy", "local_position_ned.vz"),
                   ("ekf1.VN", "ekf1.VE", "ekf1.VD"), ("nkf1.VN", "nkf1.VE", "nkf1.VD"),
                   ("xkf1.VN", "xkf1.VE", "xkf1.VD"))
#: logical topic -> candidate topics, for the message rates and jitter
RATE_TOPICS = {
    "imu": ("highres_imu", "sensor_combined", "imu"),
    "attitude": ("attitude", "vehicle_attitude", "att"),
    "local_position": ("local_position_ned", "vehicle_local_position", "ekf1", "nkf1", "xkf1"),
    "gps": ("gps_raw_int", "vehicle_gps_position", "sensor_gps", "gps"),
    "baro": ("scaled_pressure", "vehicle_air_data", "baro"),
    "mag": ("sensor_mag", "vehicle_magnetometer", "mag"),
}
AXES = "xyz"


@dataclass
class LogMeasure:
    """What one log gives (NaN / None: not measured, with a line in ``notes`` saying why)."""

    name: str
    path: str
    logged_s: float = math.nan
    airborne_s: float = math.nan
    ground_before_s: float = math.nan
    climb_rate: float = math.nan
    takeoff_hover_s: float = math.nan
    descent_rate: float = math.nan
    cruise_speed: float = math.nan
    altitude: float = math.nan
    wind_speed: float = math.nan
    wind_source: str = ""
    hover: dict[str, float] = field(default_factory=dict)  # "acc_x" ... "baro_alt": std on the hover
    hover_s: float = 0.0
    hover_white: dict[str, float] = field(default_factory=dict)  # the same, sample-to-sample (white) noise
    #: the same, its std above :data:`BAND_HZ` (the power a log's 5-25 Hz band holds at 50 Hz; :func:`_band_std`)
    hover_band: dict[str, float] = field(default_factory=dict)
    ground_white: dict[str, float] = field(default_factory=dict)
    #: the noise's colour: lag-1 autocorrelation of the first differences on the hover / ground (white: -0.5)
    hover_dlag1: dict[str, float] = field(default_factory=dict)
    ground_dlag1: dict[str, float] = field(default_factory=dict)
    hover_still: bool = True  # False: no still hover, the noise figures are on every airborne row
    #: still hover, 10 s windows: the baro altitude's std below 0.5 Hz (m) and the estimated altitude's std over the
    #: baro's (both detrended), medians over the windows (:func:`baro_slow_figures`); NaN: no 10 s of still hover
    baro_lf: float = math.nan
    alt_ratio: float = math.nan
    #: the baro altitude's sample-to-sample noise (m) on the airborne rows at :data:`MOVING_M_S` or faster (GPS or
    #: estimated horizontal velocity); NaN: none
    moving_baro: float = math.nan
    pilot: dict[str, float] = field(default_factory=dict)  # hand flight and attitude spectra (generator.like.pilot)
    flow: dict[str, float] = field(default_factory=dict)  # roll/pitch power moving (generator.like.flow.figures)
    ground: dict[str, float] = field(default_factory=dict)  # the same on the ground before take-off
    ground_s: float = 0.0
    rates: dict[str, tuple[float, float]] = field(default_factory=dict)  # logical topic -> (Hz, interval CV)
    #: logical topic -> (Hz, CV near the period, drop, late): generator.like.timing.interval_figures
    timing: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)
    eph: float = math.nan
    epv: float = math.nan
    home: tuple[float, float, float] | None = None
    mag_field_ned: tuple[float, float, float] | None = None
    mission: list[tracks.Waypoint] | None = None
    mission_rows: list | None = None  # the log's own mission items (ArduPilot CMD), WPL rows
    #: the IMU's offset from the centre of gravity (m, body frame; :func:`lever_arm_figures`), None: not measured
    #: or not meaningful (then ``imu_offset_fit`` says why), and the correlation of its fit
    imu_offset: tuple[float, float, float] | None = None
    imu_offset_fit: float = math.nan
    mission_source: str = ""
    track_error_m: float = math.nan  # the recovered mission's largest distance from the flown track
    notes: list[str] = field(default_factory=list)


# --- series -------------------------------------------------------------------------------------------------
def _series(tables, candidates, densest: bool = False) -> tuple[str, np.ndarray, np.ndarray] | None:
    """The first candidate the log has (``densest``: the one with the most samples: a log may hold a raw
    sensor topic at 1 Hz beside the filtered one at 250 Hz)."""
    if not densest:
        return tracks.column(tables, tuple(candidates))
    hits = [h for h in (tracks.column(tables, (c,)) for c in candidates) if h is not None]
    return max(hits, key=lambda h: len(h[1])) if hits else None


def resample(t: np.ndarray, x: np.ndarray, hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The latest sample at every tick of a ``hz`` clock."""
    grid = np.arange(t[0], t[-1], 1.0 / hz)
    idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)
    return grid, x[idx]


def highpass(x: np.ndarray, hz: float) -> np.ndarray:
    """``x`` minus its centred moving average over :data:`HP_WINDOW_S`."""
    w = max(3, int(round(HP_WINDOW_S * hz)) | 1)
    k = np.ones(w)
    return x - np.convolve(x, k, mode="same") / np.convolve(np.ones_like(x), k, mode="same")


def _shrink(mask: np.ndarray, hz: float) -> np.ndarray:
    """``mask`` without the samples within :data:`EDGE_S` of a False one (the high-pass edges)."""
    pad = int(round(EDGE_S * hz))
    if not pad or not len(mask):
        return mask
    bad = np.convolve((~mask).astype(float), np.ones(2 * pad + 1), mode="same") > 0
    return mask & ~bad


def _std_on(t: np.ndarray, x: np.ndarray, hz: float, segments: list[tuple[float, float]]
            ) -> tuple[float, float, float]:
    """Over ``segments`` (s): the high-passed standard deviation of ``x``, its sample-to-sample (white)
    noise (the standard deviation of its first differences / sqrt 2: the vehicle's slow motion hardly
    moves it) and their length (s). ``x`` is read at ``hz`` or its own rate if slower."""
    return _noise_figures(t, x, hz, segments)[:3]


def _noise_figures(t: np.ndarray, x: np.ndarray, hz: float, segments: list[tuple[float, float]]
                   ) -> tuple[float, float, float, float]:
    """:func:`_std_on`'s figures and the noise's colour: the lag-1 autocorrelation of the first differences
    (pairs of differences inside ``segments``; white noise -0.5, low-passed noise or smooth motion above)."""
    if len(t) < 10 or not segments:
        return math.nan, math.nan, 0.0, math.nan
    native = 1.0 / float(np.median(np.diff(t))) if np.median(np.diff(t)) > 0 else hz
    hz = min(hz, native * 1.05)
    grid, v = resample(t, x, hz)
    mask = np.zeros(len(grid), bool)
    for a, b in segments:
        mask |= (grid >= a) & (grid <= b)
    # no sample across a logging gap
    dt = np.diff(t)
    for k in np.flatnonzero(dt > 0.5):
        mask &= ~((grid > t[k]) & (grid < t[k + 1]))
    mask = _shrink(mask, hz)
    if mask.sum() < MIN_SEGMENT_S * hz:
        return math.nan, math.nan, float(mask.sum() / hz), math.nan
    both = mask[1:] & mask[:-1]
    d = np.diff(v)
    white = float(np.std(d[both]) / math.sqrt(2.0))
    pairs = both[1:] & both[:-1]
    d = d - d[both].mean()
    den = float(np.sqrt(np.sum(d[:-1][pairs] ** 2) * np.sum(d[1:][pairs] ** 2)))
    dlag1 = float(np.sum(d[:-1][pairs] * d[1:][pairs]) / den) if den > 0 else math.nan
    return float(np.std(highpass(v, hz)[mask])), white, float(mask.sum() / hz), dlag1


#: Hz: a series' power above this (to its 50 Hz reading's Nyquist) is its vibration's floor, which a 0.5-2 Hz motion does
#: not reach (the window classifier's 5-25 Hz band)
BAND_HZ = 5.0


def _band_std(t: np.ndarray, x: np.ndarray, hz: float, segments: list[tuple[float, float]]) -> float:
    """The std (over ``segments``, s) of ``x`` read at ``hz`` and high-passed at :data:`BAND_HZ` (fourth-order
    Butterworth, forward and back); NaN without :data:`MIN_SEGMENT_S` of it or at a rate without that band."""
    from scipy.signal import butter, sosfiltfilt

    if len(t) < 10 or not segments:
        return math.nan
    native = 1.0 / float(np.median(np.diff(t))) if np.median(np.diff(t)) > 0 else hz
    hz = min(hz, native * 1.05)
    if BAND_HZ >= 0.45 * hz:
        return math.nan
    grid, v = resample(t, x, hz)
    mask = np.zeros(len(grid), bool)
    for a, b in segments:
        mask |= (grid >= a) & (grid <= b)
    for k in np.flatnonzero(np.diff(t) > 0.5):
        mask &= ~((grid > t[k]) & (grid < t[k + 1]))
    mask = _shrink(mask, hz)
    if mask.sum() < MIN_SEGMENT_S * hz or len(v) < 30:
        return math.nan
    return float(np.std(sosfiltfilt(butter(4, BAND_HZ, "highpass", fs=hz, output="sos"), v)[mask]))


def _segments(t: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    d = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return [(float(t[a]), float(t[b - 1])) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1))]


def noise_series(tables) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    """The sensor series by meaning: name -> (t s, values, clock Hz); magnetometers in gauss."""
    out = {}
    imu = QUANTITIES["imu"]
    for key, fld in (("acc", "acc"), ("gyro", "gyro")):
        for a in AXES:
            hit = _series(tables, imu[f"{a}{fld}"], densest=True)
            if hit is not None:
                out[f"{key}_{a}"] = (hit[1], hit[2], NOISE_HZ)
    for a in AXES:
        hit = _series(tables, QUANTITIES["mag"][a] + (f"vehicle_magnetometer.magnetometer_ga_{'xyz'.index(a)}",),
                      densest=True)
        if hit is not None:
            out[f"mag_{a}"] = (hit[1], hit[2], NOISE_HZ)
    norm = [np.median(np.abs(out[f"mag_{a}"][1])) for a in AXES if f"mag_{a}" in out]
    if norm and max(norm) > 20.0:  # ArduPilot's raw milligauss (logs without FMTU multipliers)
        for a in AXES:
            if f"mag_{a}" in out:
                t, v, hz = out[f"mag_{a}"]
                out[f"mag_{a}"] = (t, v / 1000.0, hz)
    hit = _series(tables, QUANTITIES["baro"]["alt"])
    if hit is not None:
        out["baro_alt"] = (hit[1], hit[2], BARO_HZ)
    else:
        hit = _series(tables, QUANTITIES["baro"]["pressure"])
        if hit is not None:
            from scart_bench.generator.geo import altitude_at

            scale = 100.0 if hit[0].startswith(("scaled_pressure", "highres_imu")) else 1.0  # hPa
            out["baro_alt"] = (hit[1], np.asarray(altitude_at(hit[2] * scale), float), BARO_HZ)
    return out


def _velocity(tables) -> tuple[np.ndarray, np.ndarray] | None:
    for names in VELOCITY_FIELDS:
        cols = [_series(tables, (n,)) for n in names]
        if all(c is not None for c in cols):
            t = cols[0][1]
            return t, np.column_stack([np.interp(t, c[1], c[2]) for c in cols])
    return None


def _tilt(tables) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(t, roll, pitch) in radians: ArduPilot's degrees or PX4's quaternion."""
    r = _series(tables, QUANTITIES["attitude"]["roll"])
    p = _series(tables, QUANTITIES["attitude"]["pitch"])
    if r is not None and p is not None:
        deg = r[0].split(".")[0] in ("att", "ahr2", "ekf1", "nkf1", "xkf1")
        k = math.pi / 180.0 if deg else 1.0
        return r[1], k * r[2], k * np.interp(r[1], p[1], p[2])
    df = tables.get("vehicle_attitude")
    if df is not None and {"q_0", "q_1", "q_2", "q_3"} <= set(df.columns):
        w, x, y, z = (df[f"q_{k}"].to_numpy(float) for k in range(4))
        roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
        return df["Timestamp"].to_numpy(np.int64) / 1e6, roll, pitch
    return None


# --- one log ------------------------------------------------------------------------------------------------
def measure_log(path: str | Path, base_sensors=None, vehicle=None) -> LogMeasure:
    """Everything :class:`LogMeasure` holds, from one log of any format ``import`` reads."""
    from scart_bench.generator.logs.importers import load_flight_file
    from scart_bench.generator.logs.logged_time import gap_line, log_times, logging_gaps
    from scart_bench.generator.logs.phases import flight_phases

    tables = load_flight_file(path, allow_corrupt=True)
    m = LogMeasure(Path(path).name, str(path))
    times = log_times(tables)
    gaps = logging_gaps(tables)
    m.logged_s = float((times[-1] - times[0]) / 1e6 - sum(b - a for a, b in gaps) / 1e6) if len(times) else 0.0
    if gaps:
        m.notes.append(f"{gap_line(gaps)}: durations and rates on the logged time only")
    try:
        phases = flight_phases(tables)
    except ValueError as e:
        m.notes.append(f"no phases ({e}): mission, take-off and landing defaults kept")
        phases = None
    track = tracks.flown_track(tables, phases) if phases is not None else None
    if phases is not None and track is None:
        m.notes.append("never airborne (or for under 2 s): mission, take-off, landing and hover noise defaults kept")
    if track is not None:
        _flight_shape(m, track, phases, tables)
    _noise(m, tables, phases)
    _lever_arm(m, tables, phases)
    _wind(m, tables, phases, vehicle)
    _rates(m, tables, gaps)
    _gps(m, tables)
    _mag_field(m, tables, phases)
    m.pilot = pilot_figures(tables, phases)
    m.flow = flow_figures(tables, phases)
    return m


def flow_figures(tables, phases) -> dict[str, float]:
    """A log's roll/pitch rocking in forward flight (generator.like.flow.figures) from its series found by meaning."""
    return like_flow.figures(phases, _tilt(tables), _velocity(tables))


def pilot_figures(tables, phases) -> dict[str, float]:
    """A log's hand flight and attitude spectra (generator.like.pilot.figures) from its series found by meaning."""
    imu = QUANTITIES["imu"]
    return like_pilot.figures(tables, phases, _tilt(tables), _velocity(tables),
                              _series(tables, imu["zgyro"], densest=True), _series(tables, imu["zacc"], densest=True))


def _flight_shape(m: LogMeasure, track: tracks.Track, phases: pd.DataFrame, tables) -> None:
    m.notes.extend(track.notes)
    m.airborne_s = track.landing_s - track.takeoff_s
    t_ph = phases["Timestamp"].to_numpy(np.int64) / 1e6
    start = float(t_ph[0])
    m.ground_before_s = track.takeoff_s - start
    m.home = track.home
    rate = phases["climb_rate_m_s"].to_numpy(float)
    h = phases["altitude_m"].to_numpy(float)
    first = (t_ph >= track.takeoff_s) & (t_ph <= track.takeoff_s + 60.0) & (rate > 0.3) & (h < np.nanmax(h) + 1)
    if first.sum() >= 3:
        m.climb_rate = float(np.median(rate[first]))
    last = (t_ph >= track.landing_s - 60.0) & (t_ph <= track.landing_s) & (rate < -0.2)
    if last.sum() >= 3:
        m.descent_rate = float(np.median(-rate[last]))
    m.altitude = float(np.median(track.up))
    if track.has_position:
        n = pd.Series(track.north).ffill().bfill().to_numpy()
        e = pd.Series(track.east).ffill().bfill().to_numpy()
        sp = np.hypot(np.gradient(n, 1 / tracks.TRACK_HZ), np.gradient(e, 1 / tracks.TRACK_HZ))
        if (sp > 1.0).sum() >= 4:
            m.cruise_speed = float(np.median(sp[sp > 1.0]))
    else:
        m.notes.append("no horizontal position (no GPS fix, no local position): the mission is its altitude "
                       "profile over home, the cruise speed default kept")
    # hover after take-off: the first still stretch above 1.5 m
    still = tracks._holds(track) & (track.up > 1.5)
    runs = tracks._runs(still, int(tracks.TRACK_HZ))
    if runs and track.t[runs[0][0]] - track.takeoff_s < 60.0:
        a, b = runs[0]
        m.takeoff_hover_s = float(track.t[b] - track.t[a])
    rows = tracks.mission_from_cmd(tables)
    if rows is not None:
        m.mission_rows = rows
        m.mission_source = f"the log's {len(rows)} mission item(s) (CMD)"
    else:
        wps = tracks.recover_mission(track)
        m.mission = wps
        count = f"{len(wps)} waypoint{'' if len(wps) == 1 else 's'}"
        m.mission_source = (f"the flown track ({track.horizontal}) simplified to {count}"
                            if track.has_position else f"the altitude profile over home ({count})")
        m.track_error_m = track_error(track, wps)


def track_error(track: tracks.Track, wps: list[tracks.Waypoint]) -> float:
    """The largest 3-D distance (m) of the flown track (its logged samples: not inside a gap) from the
    recovered mission's polyline."""
    if len(wps) < 2:
        return math.nan
    n = pd.Series(track.north if track.has_position else np.zeros(len(track.t))).ffill().bfill().fillna(0.0)
    e = pd.Series(track.east if track.has_position else np.zeros(len(track.t))).ffill().bfill().fillna(0.0)
    pts = np.column_stack([n.to_numpy(), e.to_numpy(), track.up])[track.logged]
    poly = np.array([[w.north, w.east, w.up] for w in wps])
    best = np.full(len(pts), np.inf)
    for a, b in zip(poly[:-1], poly[1:]):
        seg = b - a
        length2 = float(seg @ seg)
        s = np.clip((pts - a) @ seg / length2, 0, 1) if length2 > 0 else np.zeros(len(pts))
        best = np.minimum(best, np.linalg.norm(pts - (a + np.outer(s, seg)), axis=1))
    return float(best.max())


#: the baro's slow wander: 10 s windows (every 5 s) inside a still hover, read at 10 Hz, power below 0.5 Hz
SLOW_WINDOW_S = 10.0
SLOW_HZ = 0.5


def baro_slow_figures(tb: np.ndarray, xb: np.ndarray, ta: np.ndarray, xa: np.ndarray,
                      segments: list[tuple[float, float]]) -> tuple[float, float]:
    """(the baro altitude's std below :data:`SLOW_HZ` (m: the square root of its Hann periodogram's power there,
    the window's mean removed, as the window classifier reads a band), the estimated altitude's std over the
    baro's (both detrended)): medians over the 10 s windows inside ``segments``, the baro (``tb``, ``xb``) and the
    estimate (``ta``, ``xa``, the phases' altitude) read at 10 Hz. NaN without a window. The ArduCopter fleet at
    still hover: 0.10-0.46 m, its estimate 0.2-0.5x as wide as its baro (its filter follows the baro slowly)."""
    from scipy.signal import periodogram

    lf, ratio = [], []
    n = int(SLOW_WINDOW_S * BARO_HZ)
    k = np.arange(n)
    for a, b in segments:
        start = a + EDGE_S
        while start + SLOW_WINDOW_S <= b - EDGE_S + 1e-9:
            grid = start + k / BARO_HZ
            ib, ia = np.searchsorted(tb, grid, side="right") - 1, np.searchsorted(ta, grid, side="right") - 1
            if ib[0] >= 0 and ia[0] >= 0 and np.diff(tb[ib[0]:ib[-1] + 1]).max(initial=0.0) < 1.0:
                vb, va = xb[ib], xa[ia]
                f, p = periodogram(vb, fs=BARO_HZ, window="hann", detrend="constant", scaling="density")
                lf.append(math.sqrt(float(p[f < SLOW_HZ].sum() * (f[1] - f[0]))))
                db, da = vb - np.polyval(np.polyfit(k, vb, 1), k), va - np.polyval(np.polyfit(k, va, 1), k)
                if np.std(db) > 0:
                    ratio.append(float(np.std(da) / np.std(db)))
            start += SLOW_WINDOW_S / 2
    return (float(np.median(lf)) if lf else math.nan, float(np.median(ratio)) if ratio else math.nan)


#: m/s: the rows at this horizontal speed or faster are forward flight (the fleet's baro noise is as loud at 2-3 m/s as
#: at 16 m/s; SensorParams.baro_speed_full_m_s)
MOVING_M_S = 2.0


def moving_baro_noise(tables, baro: tuple[np.ndarray, np.ndarray, float], phases: pd.DataFrame) -> float:
    """The baro altitude's sample-to-sample noise (m, at 10 Hz) on the airborne rows whose horizontal speed is
    :data:`MOVING_M_S` or more; NaN without 2 s of them (or without a velocity)."""
    vel = _velocity(tables)
    if vel is None:
        return math.nan
    t = phases["Timestamp"].to_numpy(np.int64) / 1e6
    air = (phases["phase"].to_numpy(object) != "landed") & (phases["altitude_m"].to_numpy(float) > 1.0)
    speed = np.hypot(np.interp(t, vel[0], vel[1][:, 0]), np.interp(t, vel[0], vel[1][:, 1]))
    return _noise_figures(baro[0], baro[1], baro[2], _segments(t, air & (speed >= MOVING_M_S)))[1]


def _noise(m: LogMeasure, tables, phases: pd.DataFrame | None) -> None:
    series = noise_series(tables)
    if not series:
        m.notes.append("no IMU, magnetometer or barometer: sensor noise defaults kept")
        return
    hover, ground = [], []
    if phases is not None:
        t = phases["Timestamp"].to_numpy(np.int64) / 1e6
        landed = phases["phase"].to_numpy(object) == "landed"
        h = phases["altitude_m"].to_numpy(float)
        v = phases["climb_rate_m_s"].to_numpy(float)
        air = ~landed & (h > 1.0)
        still = air & (np.abs(v) < HOVER_V_M_S)
        vel = _velocity(tables)
        if vel is not None:
            vh = np.hypot(np.interp(t, vel[0], vel[1][:, 0]), np.interp(t, vel[0], vel[1][:, 1]))
            still &= vh < HOVER_H_M_S
        hover = _segments(t, still)
        if sum(b - a for a, b in hover) < MIN_SEGMENT_S + 2 * EDGE_S + 1.0:
            hover = _segments(t, air)
            m.hover_still = False
            if hover:
                m.notes.append("no still hover of 3 s: sensor noise measured on all airborne rows (used only if no log "
                             "has a still hover)")
        before = np.flatnonzero(~landed)
        ground = _segments(t, landed & (np.arange(len(t)) < (before[0] if len(before) else len(t))))
    if "baro_alt" in series and phases is not None:
        m.moving_baro = moving_baro_noise(tables, series["baro_alt"], phases)
    if "baro_alt" in series and phases is not None and hover and m.hover_still:
        m.baro_lf, m.alt_ratio = baro_slow_figures(series["baro_alt"][0], series["baro_alt"][1], t, h, hover)
    for name, (ts, x, hz) in series.items():
        m.hover[name], m.hover_white[name], hs, m.hover_dlag1[name] = _noise_figures(ts, x, hz, hover)
        if name in BAND_AXES:
            m.hover_band[name] = _band_std(ts, x, hz, hover)
        m.ground[name], m.ground_white[name], gs, m.ground_dlag1[name] = _noise_figures(ts, x, hz, ground)
        if name == "acc_x":
            m.hover_s, m.ground_s = hs, gs
    if all(math.isnan(v) for v in m.hover.values()):
        m.notes.append(f"hover too short to measure sensor noise ({m.hover_s:.1f} s still in the air, "
                       f"{MIN_SEGMENT_S:g} s needed): defaults kept")
    missing = [k for k in ("acc", "gyro", "mag", "baro") if not any(n.startswith(k) for n in series)]
    if missing:
        m.notes.append(f"no {', '.join(missing)} in the log: {'that' if len(missing) == 1 else 'their'} "
                       "noise default kept")


#: the lever arm's band (Hz): the rocking, above the flight's manoeuvres and below the frame's vibration
LEVER_BAND_HZ = (0.5, 5.0)
#: least airborne time (s) and correlation of the fitted lever arm's acceleration with the logged one for a log's
#: fit to count, and the largest offset (m) taken for one (a larger one is something else following the rates)
LEVER_MIN_S = 10.0
LEVER_MIN_CORR = 0.3
LEVER_MAX_M = 0.3


def lever_arm_figures(stretches: list[np.ndarray], hz: float = NOISE_HZ) -> tuple[np.ndarray, float, float]:
    """(r (3,) m in the body frame, correlation, seconds used): the IMU's offset from the centre of gravity that
    best explains the band-passed (:data:`LEVER_BAND_HZ`) horizontal accelerometer by the angular acceleration (the
    band-passed gyro, differentiated): acc_x = alpha_y r_z - alpha_z r_y, acc_y = alpha_z r_x - alpha_x r_z (alpha x r;
    the centripetal part is second order at these rates), least squares over both axes and every stretch; the
    correlation is of that fit with the logged x/y. ``stretches``: (n, 6) arrays of acc x/y/z (m/s^2) and gyro x/y/z
    (rad/s), each evenly sampled at ``hz`` without a gap, band-passed on its own (those under 3 s are left out);
    acc_z is not used (the throttle moves it)."""
    from scipy import signal

    b, a = signal.butter(2, LEVER_BAND_HZ, btype="band", fs=hz)
    ok = [x for x in stretches if len(x) > 3 * hz]
    if not ok:
        return np.zeros(3), math.nan, 0.0
    acc = np.vstack([signal.filtfilt(b, a, x[:, 0:2], axis=0) for x in ok])
    alpha = np.vstack([np.gradient(signal.filtfilt(b, a, x[:, 3:6], axis=0), 1.0 / hz, axis=0) for x in ok])
    zero = np.zeros(len(acc))
    design = np.vstack([np.column_stack([zero, -alpha[:, 2], alpha[:, 1]]),
                        np.column_stack([alpha[:, 2], zero, -alpha[:, 0]])])
    y = np.r_[acc[:, 0], acc[:, 1]]
    r, *_ = np.linalg.lstsq(design, y, rcond=None)
    pred = design @ r
    den = float(np.sqrt(np.dot(pred, pred) * np.dot(y, y)))
    return r, (float(np.dot(pred, y) / den) if den > 0 else math.nan), len(acc) / hz


def _lever_arm(m: LogMeasure, tables, phases: pd.DataFrame | None) -> None:
    """The log's IMU offset (:func:`lever_arm_figures`) on its airborne rows, each stretch between logging gaps
    on its own; a fit that explains little (correlation under :data:`LEVER_MIN_CORR`) or gives more than
    :data:`LEVER_MAX_M` is not kept (one line in the notes, as is a log without :data:`LEVER_MIN_S` of air)."""
    imu = QUANTITIES["imu"]
    cols = [_series(tables, imu[f"{a}{q}"], densest=True) for q in ("acc", "gyro") for a in AXES]
    if any(c is None for c in cols):
        m.notes.append("IMU lever arm: no accelerometer and gyro on all three axes in the log: offset 0 kept")
        return
    if phases is None:
        return  # said with the phases
    t_ph = phases["Timestamp"].to_numpy(np.int64) / 1e6
    air = (phases["phase"].to_numpy(object) != "landed") & (phases["altitude_m"].to_numpy(float) > 1.0)
    t0 = cols[0][1]
    hz = min(NOISE_HZ, 1.05 / float(np.median(np.diff(t0)))) if len(t0) > 1 else NOISE_HZ
    cut = np.r_[t0[0] - 1.0, t0[np.flatnonzero(np.diff(t0) > 0.5)], t0[-1]]  # stretches between logging gaps
    stretches = []
    for a, b in _segments(t_ph, air):
        for lo, hi in zip(cut[:-1], cut[1:]):
            g0, g1 = max(a, lo) + EDGE_S, min(b, hi) - EDGE_S
            if g1 - g0 >= 5.0:
                grid = np.arange(g0, g1, 1.0 / hz)
                stretches.append(np.column_stack([np.interp(grid, c[1], c[2]) for c in cols]))
    r, corr, seconds = lever_arm_figures(stretches, hz)
    if seconds < LEVER_MIN_S:
        m.notes.append(f"IMU lever arm: {seconds:.0f} s in the air in stretches of 5 s between logging gaps, "
                       f"{LEVER_MIN_S:g} s needed: offset 0 kept")
        return
    m.imu_offset_fit = corr
    if not (corr >= LEVER_MIN_CORR and float(np.max(np.abs(r))) <= LEVER_MAX_M):
        m.notes.append(f"IMU lever arm: the accelerometer does not follow the angular acceleration (correlation "
                       f"{corr:.2f}, r {', '.join(f'{v:+.3f}' for v in r)} m): offset 0 kept")
        return
    m.imu_offset = (float(r[0]), float(r[1]), float(r[2]))


def _wind(m: LogMeasure, tables, phases: pd.DataFrame | None, vehicle) -> None:
    if phases is None:
        return
    t = phases["Timestamp"].to_numpy(np.int64) / 1e6
    air = (phases["phase"].to_numpy(object) != "landed") & (phases["altitude_m"].to_numpy(float) > 1.0)
    if air.sum() < 10:
        m.notes.append("no airborne rows: wind default kept")
        return
    for wn, we in WIND_FIELDS:
        a, b = _series(tables, (wn,)), _series(tables, (we,))
        if a is None or b is None:
            continue
        sel = (a[1] >= t[air][0]) & (a[1] <= t[air][-1])
        if sel.sum() < 10:
            continue
        speed = np.hypot(a[2][sel], np.interp(a[1][sel], b[1], b[2]))
        if np.nanmax(speed) > 0.05:  # a wind state the estimator kept at zero (no GPS) says nothing
            m.wind_speed = float(np.median(speed))
            m.wind_source = f"the estimator's wind states ({wn.split('.')[0]} {wn.split('.')[1]}/{we.split('.')[1]})"
            return
    tilt = _tilt(tables)
    if tilt is None:
        m.notes.append("no wind states and no attitude: wind default kept")
        return
    tt, roll, pitch = tilt
    vel = _velocity(tables)
    still = np.interp(tt, t, air.astype(float)) > 0.5
    if vel is not None:
        still &= np.hypot(np.interp(tt, vel[0], vel[1][:, 0]), np.interp(tt, vel[0], vel[1][:, 1])) < tracks.STILL_H_M_S
    if still.sum() * float(np.median(np.diff(tt))) < 5.0:
        m.notes.append("under 5 s of hover: wind from the tilt not measured, default kept")
        return
    # the mean tilt at hover holds the drag of the wind: m g tan(tilt) = (rotor drag) v + (body drag) v^2
    tan = math.hypot(math.tan(float(np.mean(roll[still]))), math.tan(float(np.mean(pitch[still]))))
    if tan > math.tan(math.radians(MAX_WIND_TILT_DEG)):
        m.notes.append(f"mean tilt at hover {math.degrees(math.atan(tan)):.0f} deg: not wind (an uncalibrated level "
                       "or no real hover), wind default kept")
        return
    from scart_bench.generator.params import GRAVITY, VehicleParams

    veh = vehicle or VehicleParams()
    omega = math.sqrt(veh.mass * GRAVITY / (4 * veh.motor_constant))
    k1, k2 = 4 * veh.rotor_drag_coefficient * omega, veh.body_drag
    f = veh.mass * GRAVITY * tan
    m.wind_speed = float((-k1 + math.sqrt(k1 * k1 + 4 * k2 * f)) / (2 * k2))
    m.wind_source = f"the mean tilt at hover ({math.degrees(math.atan(tan)):.1f} deg, drag of the generator's airframe)"


def _rates(m: LogMeasure, tables, gaps) -> None:
    for logical, topics in RATE_TOPICS.items():
        for topic in topics:
            df = tables.get(topic)
            if df is None or len(df) < 20:
                continue
            t = np.sort(df["Timestamp"].to_numpy(np.int64)) / 1e6
            dt = np.diff(t)
            dt = dt[(dt > 0) & (dt < 2.0)]  # a logging gap is not jitter
            if len(dt) < 10:
                continue
            m.rates[logical] = (float(1.0 / np.median(dt)), float(dt.std() / dt.mean()))
            figures = like_timing.interval_figures(t)
            if figures is not None:
                m.timing[logical] = figures
            break


def _gps(m: LogMeasure, tables) -> None:
    fix = tracks._gps_fixed(tables)
    if fix is None:
        m.notes.append("no GPS fix: GPS accuracy (position noise) default kept")
        return
    def field_of(name: str):  # a constant accuracy (a simulator's GPS) is a value too
        topic, _, fld = name.partition(".")
        df = tables.get(topic)
        if df is None or fld not in df.columns:
            return None
        v = df[fld].to_numpy(float)
        return name, None, v[np.isfinite(v)]

    for he, ve in GPS_ACCURACY_FIELDS:
        a, b = field_of(he), field_of(ve)
        if a is None and b is None:
            continue
        if a is not None:
            m.eph = float(np.median(a[2][(a[2] > 0) & (a[2] < 50)]))
        if b is not None:
            m.epv = float(np.median(b[2][(b[2] > 0) & (b[2] < 50)]))
        return
    m.notes.append("GPS fix but no accuracy (eph/epv, hAcc/vAcc) logged: GPS accuracy default kept")


def _mag_field(m: LogMeasure, tables, phases: pd.DataFrame | None) -> None:
    """The Earth field (NED, gauss) at the site: the magnetometer on the ground rotated by the attitude."""
    series = noise_series(tables)
    tilt = _tilt(tables)
    yaw = _series(tables, QUANTITIES["attitude"]["yaw"])
    if phases is None or tilt is None or yaw is None or not all(f"mag_{a}" in series for a in AXES):
        return
    t = phases["Timestamp"].to_numpy(np.int64) / 1e6
    landed = phases["phase"].to_numpy(object) == "landed"
    tm = series["mag_x"][0]
    on_ground = np.interp(tm, t, landed.astype(float)) > 0.5
    if on_ground.sum() < 20:
        return
    tm = tm[on_ground]
    b = np.column_stack([np.interp(tm, series[f"mag_{a}"][0], series[f"mag_{a}"][1]) for a in AXES])
    deg = yaw[0].split(".")[0] in ("att", "ahr2", "ekf1", "nkf1", "xkf1")
    psi = np.interp(tm, yaw[1], yaw[2]) * (math.pi / 180.0 if deg else 1.0)
    phi, th = np.interp(tm, tilt[0], tilt[1]), np.interp(tm, tilt[0], tilt[2])
    # body FRD -> NED: R = Rz(psi) Ry(theta) Rx(phi)
    cp, sp, ct, st, cy, sy = np.cos(phi), np.sin(phi), np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
    n = cy * ct * b[:, 0] + (cy * st * sp - sy * cp) * b[:, 1] + (cy * st * cp + sy * sp) * b[:, 2]
    e = sy * ct * b[:, 0] + (sy * st * sp + cy * cp) * b[:, 1] + (sy * st * cp - cy * sp) * b[:, 2]
    d = -st * b[:, 0] + ct * sp * b[:, 1] + ct * cp * b[:, 2]
    field_ned = (float(np.median(n)), float(np.median(e)), float(np.median(d)))
    # the Earth's field is 0.25-0.65 gauss and points down in the northern hemisphere, up in the southern
    hemisphere = 1.0 if m.home is None or m.home[0] >= 0 else -1.0
    if 0.1 < math.hypot(*field_ned) < 1.0 and field_ned[2] * hemisphere > 0:
        m.mag_field_ned = field_ned
    else:
        m.notes.append(f"magnetometer on the ground reads {math.hypot(*field_ned):.2f} gauss, down {field_ned[2]:+.2f}: "
                       "not the Earth's field (uncalibrated), site field default kept")


# --- the fleet ----------------------------------------------------------------------------------------------
@dataclass
class Figure:
    """A fleet figure: the value, how many logs gave it, and where from."""

    value: float
    n: int
    source: str


def _median(values: list[float]) -> tuple[float, int]:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return (float(np.median(v)), len(v)) if v else (math.nan, 0)


def fleet_figures(logs: list[LogMeasure]) -> dict[str, Figure]:
    """The fleet's median of every per-log figure."""
    out: dict[str, Figure] = {}
    simple = {
        "logged_s": "logged time (gaps not counted)", "airborne_s": "take-off to landing",
        "ground_before_s": "log start to take-off", "climb_rate": "median climb rate, first minute after take-off",
        "takeoff_hover_s": "first still stretch above 1.5 m after take-off",
        "descent_rate": "median descent rate, last minute before landing",
        "cruise_speed": "median horizontal speed above 1 m/s", "altitude": "median height above take-off",
        "wind_speed": "median wind speed in the air", "eph": "median GPS eph (3-D fix)", "epv": "median GPS epv (3-D fix)",
        "baro_lf": "still hover, 10 s windows: baro altitude std below 0.5 Hz (m)",
        "alt_ratio": "still hover, 10 s windows: the estimated altitude's std over the baro's (detrended)",
        "moving_baro": f"airborne at {MOVING_M_S:g} m/s or faster: the baro altitude's sample-to-sample noise (m)",
    }
    for key, what in simple.items():
        v, n = _median([getattr(m, key) for m in logs])
        out[key] = Figure(v, n, what)
    keys = sorted({k for m in logs for k in m.hover})
    # the noise of a still hover; the logs without one (hand-flown throughout) only when no log has one
    still = [m for m in logs if m.hover_still and any(math.isfinite(v) for v in m.hover.values())]
    for k in keys:
        v, n = _median([m.hover.get(k, math.nan) for m in still])
        what = "still hover (speed < 1 m/s horizontal, 0.5 m/s vertical), high-passed per-sample std"
        if not n:
            v, n = _median([m.hover.get(k, math.nan) for m in logs])
            what = "every airborne row (no log has a still hover), high-passed per-sample std"
        out[f"hover_{k}"] = Figure(v, n, what)
        v, n = _median([m.hover_white.get(k, math.nan) for m in (still if n and what.startswith("still") else logs)])
        out[f"white_hover_{k}"] = Figure(v, n, what.replace("high-passed per-sample std",
                                                             "sample-to-sample noise (std of differences / sqrt 2)"))
        if any(k in m.hover_band for m in logs):
            v, n = _median([m.hover_band.get(k, math.nan) for m in (still if n and what.startswith("still") else logs)])
            out[f"band_hover_{k}"] = Figure(v, n, what.replace("high-passed per-sample std",
                                                                f"std above {BAND_HZ:g} Hz (at 50 Hz)"))
        v, n = _median([m.hover_dlag1.get(k, math.nan) for m in (still if n and what.startswith("still") else logs)])
        out[f"dlag1_hover_{k}"] = Figure(v, n, what.replace("high-passed per-sample std",
                                                             "lag-1 autocorrelation of the differences (white: -0.5)"))
        v, n = _median([m.ground_dlag1.get(k, math.nan) for m in logs])
        out[f"dlag1_ground_{k}"] = Figure(v, n, "on the ground before take-off, lag-1 autocorrelation of the "
                                                "differences (white: -0.5)")
        v, n = _median([m.ground.get(k, math.nan) for m in logs])
        out[f"ground_{k}"] = Figure(v, n, "on the ground before take-off, high-passed per-sample std")
        v, n = _median([m.ground_white.get(k, math.nan) for m in logs])
        out[f"white_ground_{k}"] = Figure(v, n, "on the ground before take-off, sample-to-sample noise")
    for logical in RATE_TOPICS:
        v, n = _median([m.rates[logical][0] for m in logs if logical in m.rates])
        out[f"rate_{logical}_hz"] = Figure(v, n, "median message rate")
        v, n = _median([m.rates[logical][1] for m in logs if logical in m.rates])
        out[f"jitter_{logical}_cv"] = Figure(v, n, "interval coefficient of variation")
    return out


def calibration_figures(config, n: int = 3, seed: int = 12345) -> dict[str, float]:
    """The hover noise figures of ``n`` generated hover flights of ``config``, measured as a log's."""
    from scart_bench.generator.engine.simulate import simulate
    from scart_bench.generator.plan import normal_seeds
    from scart_bench.generator.telemetry.tables import flight_views

    mission = dataclasses.replace(config.mission, missions=(), takeoff_hold_s=25.0)
    cfg = dataclasses.replace(config, mission=mission)
    batch = simulate(normal_seeds(seed, n), cfg)
    landed = float(np.mean(np.asarray(batch.status) == "landed"))
    per = []
    for i in range(n):
        _, sim = flight_views(batch, i, ())
        tables = {k: v for k, v in sim.items() if k not in ("truth", "setpoint")}
        m = LogMeasure(f"calibration-{i}", "")
        from scart_bench.generator.logs.phases import flight_phases

        _noise(m, tables, flight_phases(tables))
        per.append({**m.hover, "baro_lf": m.baro_lf, "alt_ratio": m.alt_ratio,
                    **{f"white_{k}": v for k, v in m.hover_white.items()},
                    **{f"band_{k}": v for k, v in m.hover_band.items()},
                    **{f"dlag1_{k}": v for k, v in m.hover_dlag1.items()}})
    keys = {k for p in per for k in p}
    return {**{k: _median([p.get(k, math.nan) for p in per])[0] for k in keys}, "landed": landed}


@dataclass
class Fit:
    """The fitted parameters (section -> field -> (value, comment)) and the lines said about the logs."""

    values: dict[str, dict[str, tuple[object, str]]]
    measured: dict[str, tuple[float, str]]
    missions: list[tuple[str, str]]  # (file name, comment)
    lines: list[str]
    logs: list[LogMeasure]
    #: log name -> its vehicle's accelerometer x/y/z, gyro x/y/z vibration over the fleet's (:func:`vibration_levels`); empty:
    #: every vehicle alike (no calibration, or a sensor model without per-flight levels)
    vibration_levels: dict[str, tuple[float, ...]] = field(default_factory=dict)
    #: log name -> its vehicle's rocking (rad/s^2 per step, roll/pitch/yaw; :func:`fit_rocking`); empty: none fitted
    rocking_levels: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    #: log name -> its vehicle's rocking in forward flight (rad/s^2 at full speed, roll/pitch; generator.like.flow)
    flow_levels: dict[str, tuple[float, float]] = field(default_factory=dict)


def next_level(history: list[tuple[float, float]], target: float) -> float:
    """The next noise parameter toward ``target`` from the (parameter, generated figure) pairs so far.

    A generated figure is the sensor noise and the flight's own motion together, adding in squares:
    figure^2 = motion^2 + (gain * parameter)^2. One pair: scale by target / figure; two or more: solve
    for motion and gain from the last two pairs (a secant in the squares) and aim the noise at the rest."""
    p1, g1 = history[-1]
    if p1 == 0.0:  # a vibration off so far (per sample, like the figure): the rest, in squares
        return math.sqrt(max(target * target - g1 * g1, 0.0))
    if len(history) >= 2:
        p0, g0 = history[-2]
        if abs(p1 - p0) > 1e-12 * max(p0, p1):
            gain2 = (g1 * g1 - g0 * g0) / (p1 * p1 - p0 * p0)
            if gain2 > 0:
                motion2 = g1 * g1 - gain2 * p1 * p1
                return math.sqrt(max(target * target - motion2, 0.0) / gain2) or 0.05 * p1
    return p1 * target / g1


#: noise parameters and the figures they follow: (SensorParams field, tuple index or None, figures); the first of
#: a field's alternatives that the sensor model has is fitted (``accel_vibration``: per axis, motors running)
NOISE_PLAN = (
    (("accel_vibration", 0, ("acc_x",)), ("accel_vibration", 1, ("acc_y",)), ("accel_vibration", 2, ("acc_z",))),
    (("gyro_vibration", 0, ("gyro_x",)), ("gyro_vibration", 1, ("gyro_y",)), ("gyro_vibration", 2, ("gyro_z",))),
    (("mag_noise", None, ("mag_x", "mag_y", "mag_z")),),
    (("baro_noise_pa", None, ("baro_alt",)),),
)
#: the axes whose vibration is fitted to the still hover's power above BAND_HZ instead of the sample-to-sample noise: the
#: fleet's gyro z gets its sample-to-sample noise from a 0.5-2 Hz yaw motion and a white floor, the generated one from
#: its low-passed vibration (fitted on the sample-to-sample noise, its 2-5 and 5-25 Hz power were 4x the fleet's at hover)
BAND_AXES = ("gyro_z",)
#: fitted when the sensor model has no vibration
FALLBACK = {"accel_vibration": (("accel_noise_density", None, ("acc_x", "acc_y")),),
            "gyro_vibration": (("gyro_noise_density", None, ("gyro_x", "gyro_y", "gyro_z")),)}


#: coloured noise: (SensorParams cutoff field, the noise fields it colours (the IMU's: the vibration), figures, the sensor's rate field (None:
#: the IMU, sampled every simulation step), the figures' clock (Hz))
COLOUR_PLAN = (
    ("accel_noise_cutoff_hz", ("accel_vibration",), ("acc_x", "acc_y", "acc_z"), None, NOISE_HZ),
    ("gyro_noise_cutoff_hz", ("gyro_vibration",), ("gyro_x", "gyro_y", "gyro_z"), None, NOISE_HZ),
    ("baro_noise_cutoff_hz", ("baro_noise_pa", "baro_downwash_pa"), ("baro_alt",), "baro_rate_hz", BARO_HZ),
)
#: a lag-1 autocorrelation of the differences at or below this is white noise (cutoff 0; white: -0.5)
WHITE_DLAG1 = -0.45
#: the most colour aimed at (a lag-1 of the differences of 1 is a noise that never changes)
MAX_DLAG1 = 0.95


def _sampling(sensors, rate_field: str | None, clock_hz: float) -> tuple[float, int]:
    """(the sensor's sample rate, how many of its samples per tick of the figures' clock)."""
    from scart_bench.generator.params import DT

    rate = 1.0 / DT if rate_field is None else float(getattr(sensors, rate_field))
    return rate, max(1, int(round(rate / clock_hz)))


def cutoff_for(dlag1: float, rate_hz: float, every: int) -> float:
    """The low-pass cutoff (Hz) whose coloured white noise at ``rate_hz``, read every ``every`` samples, has
    lag-1 autocorrelation of its differences ``dlag1`` (:func:`physics.sensors.lowpass_lag1`); 0 (white) at or
    below :data:`WHITE_DLAG1`. Searched between 0.2 Hz and the figures' Nyquist frequency, where the figure
    falls with the cutoff."""
    from scart_bench.generator.physics.sensors import lowpass_lag1

    if not dlag1 > WHITE_DLAG1:
        return 0.0
    dlag1 = min(dlag1, MAX_DLAG1)
    lo, hi = math.log(0.2), math.log(0.5 * rate_hz / every)
    if lowpass_lag1(math.exp(hi), rate_hz, every)[1] >= dlag1:
        return 0.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if lowpass_lag1(math.exp(mid), rate_hz, every)[1] > dlag1 else (lo, mid)
    return round(math.exp(0.5 * (lo + hi)), 3)


def cutoff_at_least(factor: float, rate_hz: float, every: int) -> float:
    """The lowest cutoff (Hz) whose :func:`white_factor` is at least ``factor`` (0: white is needed)."""
    if factor >= white_factor(0.5 * rate_hz / every, rate_hz, every):
        return 0.0
    lo, hi = math.log(0.2), math.log(0.5 * rate_hz / every)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if white_factor(math.exp(mid), rate_hz, every) >= factor else (mid, hi)
    return math.ceil(math.exp(hi) * 1000.0) / 1000.0


def white_factor(cutoff_hz: float, rate_hz: float, every: int) -> float:
    """The sample-to-sample noise of the low-passed noise read every ``every`` samples, per unit of its sigma
    (white: 1): sqrt(1 - lag-1 autocorrelation)."""
    from scart_bench.generator.physics.sensors import lowpass_lag1

    return math.sqrt(max(1.0 - lowpass_lag1(cutoff_hz, rate_hz, every)[0], 1e-6))


def pa_per_m() -> float:
    """The static pressure's fall per metre up at the generator's home altitude (Pa/m)."""
    from scart_bench.dataset.schema import HOME_ALT
    from scart_bench.generator.geo import pressure_at

    return float(pressure_at(HOME_ALT) - pressure_at(HOME_ALT + 1.0))


#: the downwash is fitted when the logs' baro on the ground is at most this fraction of the hover's sample-to-sample
#: noise (a quieter ground: the rotors' air stirs the baro in flight)
DOWNWASH_GROUND_RATIO = 0.8


def _with_downwash(s, plan: list, figures: dict[str, Figure], out: dict, lines: list[str]) -> tuple[object, list, dict]:
    """(sensors, plan, starting levels): where the logs' baro is quieter on the ground than at hover
    (:data:`DOWNWASH_GROUND_RATIO`), its noise split in two: ``baro_noise_pa`` the ground's sample-to-sample
    noise (set here, white: the sensor's own) and ``baro_downwash_pa`` calibrated for the hover's in place of the
    ``baro_noise_pa`` of ``plan``, starting from the rest in squares; its comment goes to ``out``."""
    i = next((k for k, item in enumerate(plan) if item[0] == "baro_noise_pa"), None)
    if i is None or not hasattr(s, "baro_downwash_pa"):
        return s, plan, {}
    ground, hover = figures.get("white_ground_baro_alt"), figures.get("white_hover_baro_alt")
    if ground is None or not ground.n or not math.isfinite(ground.value) or not ground.value > 0:
        lines.append("baro downwash: no log's baro measured on the ground before take-off: one baro noise for "
                     "ground and air kept")
        return s, plan, {}
    ratio = ground.value / hover.value
    if ratio > DOWNWASH_GROUND_RATIO:
        lines.append(f"baro downwash: the logs' baro on the ground is {ratio:.2f}x the hover's sample-to-sample noise "
                     f"(over {DOWNWASH_GROUND_RATIO:g}x): one baro noise for ground and air kept")
        return s, plan, {}
    k = pa_per_m()
    own = round(ground.value * k, 6)
    out["baro_noise_pa"] = (own, f"the sensor's own noise, white: sample-to-sample baro altitude on the ground before "
                                 f"take-off {ground.value:.4g} m x {k:.2f} Pa/m (median over {ground.n} logs; "
                                 f"{ratio:.2f}x the hover's {hover.value:.4g} m: baro_downwash_pa is the rest)")
    start = {"baro_downwash_pa": math.sqrt(max(hover.value ** 2 - ground.value ** 2, (0.3 * hover.value) ** 2)) * k}
    plan = [*plan[:i], ("baro_downwash_pa", None, plan[i][2]), *plan[i + 1:]]
    return dataclasses.replace(s, baro_noise_pa=own), plan, start


def calibrate_noise(config, figures: dict[str, Figure], rounds: int = 4) -> tuple[dict[str, tuple[object, str]], list[str]]:
    """SensorParams noise fields set so that generated hover flights measure like the fleet, in level and colour.

    The level fitted is each axis's sample-to-sample (white) noise at hover (``white_hover_*``: the std of
    first differences / sqrt 2, which the vehicle's slow motion hardly moves: a log's hover std is mostly
    the pilot's and the wind's doing, the generator's mostly its controller's). The colour fitted is the lag-1
    autocorrelation of those differences (``dlag1_hover_*``, mean over a sensor's axes; white noise -0.5, the
    ArduCopter fleet's gyro 0.7-0.9), through the sensor's noise cutoff (``*_noise_cutoff_hz``, :data:`COLOUR_PLAN`):
    first the cutoff that theory gives (:func:`cutoff_for`), then each round moves it by what the calibration
    flights measured beyond theory (their own motion). Each round flies calibration flights
    (:func:`calibration_figures`) with the current fields and moves each level toward the fleet's figure
    (:func:`next_level`, in the sample-to-sample noise the level gives at its cutoff, :func:`white_factor`, so
    that a new cutoff does not upset the secant); a last round measures the result for the comments. Returns
    field -> (value, comment) and lines on what could not be fitted."""
    from scart_bench.generator.physics.sensors import lowpass_lag1

    s = config.sensors
    out: dict[str, tuple[object, str]] = {}
    lines: list[str] = []
    want = {k[len("white_hover_"):]: f for k, f in figures.items() if k.startswith("white_hover_") and f.n
            and math.isfinite(f.value)}
    for k in BAND_AXES:  # these axes' vibration level on their floor above BAND_HZ, not their sample-to-sample noise
        f = figures.get(f"band_hover_{k}")
        if k in want and f is not None and f.n and math.isfinite(f.value) and f.value > 0:
            want[k] = f

    def kind(k: str) -> str:
        return "band" if k in BAND_AXES and want.get(k) is figures.get(f"band_hover_{k}") else "white"
    plan = []
    for group in NOISE_PLAN:
        if not hasattr(s, group[0][0]):
            group = FALLBACK.get(group[0][0], ())
        plan.extend(item for item in group if hasattr(s, item[0]) and all(k in want for k in item[2]))
    if not plan:
        return out, ["no hover noise measured in any log: sensor noise defaults kept"]
    s, plan, start = _with_downwash(s, plan, figures, out, lines)
    colour_want = {k[len("dlag1_hover_"):]: f for k, f in figures.items() if k.startswith("dlag1_hover_") and f.n
                   and math.isfinite(f.value)}
    fitted = {f for f, _, _ in plan}
    colours = [c for c in COLOUR_PLAN if hasattr(s, c[0]) and any(f in fitted for f in c[1])
               and all(k in colour_want for k in c[2])]
    colour_of = {f: c for c in colours for f in c[1]}  # noise field -> its colour plan
    cutoff = {c[0]: float(getattr(s, c[0])) for c in colours}
    sampling = {c[0]: _sampling(s, c[3], c[4]) for c in colours}

    def factor(f: str) -> float:
        c = colour_of.get(f)
        return white_factor(cutoff[c[0]], *sampling[c[0]]) if c is not None else 1.0

    def value(field_name, idx):
        v = getattr(s, field_name)
        return float(v[idx] if idx is not None else v)

    level = {(f, i): start.get(f, value(f, i)) for f, i, _ in plan}
    floor = {key: 0.1 * v for key, v in level.items()}  # below a tenth of the base's, the figure is the flight's motion
    history: dict[tuple, list[tuple[float, float]]] = {key: [] for key in level}
    # the theory's cutoffs to start from, each level scaled to keep its sample-to-sample noise
    before = {f: factor(f) for f, _, _ in plan}
    for c in colours:
        cutoff[c[0]] = cutoff_for(float(np.mean([colour_want[k].value for k in c[2]])), *sampling[c[0]])
    for f, i, _ in plan:
        level[(f, i)] *= before[f] / factor(f)

    def fields() -> dict:
        changed: dict[str, object] = dict(cutoff)
        for (f, i), v in level.items():
            if i is None:
                changed[f] = v
            else:
                cur = list(changed.get(f, getattr(s, f)))
                cur[i] = v
                changed[f] = tuple(cur)
        return changed

    # a coloured vibration no larger per sample than the logs' hover signal (high-passed std): the noise enters
    # the estimator and the controllers, and a larger one stands for motion the vehicle does not make
    cap = {(f, i): min((figures[f"hover_{k}"].value for k in ks if f"hover_{k}" in figures
                        and math.isfinite(figures[f"hover_{k}"].value)), default=math.inf)
           for f, i, ks in plan if f in colour_of and f.endswith("_vibration")}  # the IMU's: in the figure's unit

    def least_cutoff(c) -> float:
        """The lowest cutoff at which the capped levels still reach the logs' sample-to-sample noise."""
        need = [float(np.mean([want[k].value for k in ks])) / cap[(f, i)] for f, i, ks in plan
                if colour_of.get(f) is c and (f, i) in cap and math.isfinite(cap[(f, i)]) and cap[(f, i)] > 0]
        return cutoff_at_least(max(need), *sampling[c[0]]) if need else 0.0

    def capped(c, fc: float) -> float:
        low = least_cutoff(c)
        return fc if fc == 0.0 or fc >= low else low

    for c in colours:
        cutoff[c[0]] = capped(c, cutoff[c[0]])
    gen: dict[str, float] = {}
    good: tuple[dict, dict] | None = None
    for r in range(rounds + 1):
        gen = calibration_figures(dataclasses.replace(config, sensors=dataclasses.replace(s, **fields())))
        if gen.get("landed", 1.0) < 1.0 and good is not None:  # a calibration flight crashed or did not land:
            level, cutoff = dict(good[0]), dict(good[1])          # back to the last round whose flights all landed
            lines.append(f"calibration round {r + 1}: {1 - gen['landed']:.0%} of the flights did not land; the noise "
                         "of the round before kept")
            gen = calibration_figures(dataclasses.replace(config, sensors=dataclasses.replace(s, **fields())))
            break
        good = (dict(level), dict(cutoff))
        if r == rounds:
            break
        before = {f: factor(f) for f, _, _ in plan}
        for c in colours:
            if not any(level[(f, i)] > 0 for f, i, _ in plan if colour_of.get(f) is c):
                continue  # nothing coloured yet: the flights' figure is their motion's
            target = float(np.mean([colour_want[k].value for k in c[2]]))
            got = float(np.nanmean([gen.get(f"dlag1_{k}", math.nan) for k in c[2]]))
            if math.isfinite(got):  # aim the theory past the target by what the flights add to it, 1.5x at most a round
                theory = lowpass_lag1(cutoff[c[0]], *sampling[c[0]])[1]
                fc = cutoff_for(float(np.clip(target - (got - theory), -0.5, MAX_DLAG1)), *sampling[c[0]])
                old = cutoff[c[0]]
                if old > 0 and fc > 0:
                    fc = float(np.clip(fc, old / 1.5, old * 1.5))
                cutoff[c[0]] = round(capped(c, fc), 3)
        for f, i, ks in plan:
            target = float(np.mean([want[k].value for k in ks]))
            got = float(np.nanmean([gen.get(f"{kind(k)}_{k}", math.nan) for k in ks]))
            if math.isfinite(got) and got > 0:
                history[(f, i)].append((level[(f, i)] * before[f], got))
                nxt = next_level(history[(f, i)], target) / factor(f)
                level[(f, i)] = float(np.clip(nxt, floor[(f, i)], min(1e3, cap.get((f, i), math.inf))))
    final = fields()
    notes: dict[str, list[str]] = {}
    for f, _i, ks in plan:
        where = "still hover" if want[ks[0]].source.startswith("still") else "airborne"
        got = [gen.get(f"{kind(k)}_{k}", math.nan) for k in ks]
        notes.setdefault(f, []).append(
            f"{', '.join(f'{k} {want[k].value:.4g}' + (f' above {BAND_HZ:g} Hz' if kind(k) == 'band' else '') for k in ks)}"
            f" (generated {', '.join(f'{g:.4g}' for g in got)})")
        target = float(np.mean([want[k].value for k in ks]))
        if np.nanmean(got) > 1.5 * target:
            lines.append(f"{f}: the generated flights give {np.nanmean(got):.3g} at a tenth of the base's noise, "
                         f"above the logs' {target:.3g}: their own motion is larger than the logs'")
    for f, parts in notes.items():
        n = min(want[k].n for ff, _, ks in plan if ff == f for k in ks)
        v = final[f]
        v = [round(x, 6) for x in v] if isinstance(v, tuple) else round(v, 8)
        low = f", low-passed at {cutoff[colour_of[f][0]]:g} Hz" if f in colour_of and cutoff[colour_of[f][0]] else ""
        out[f] = (v, f"sample-to-sample noise at {where} (median over {n} logs){low}: {'; '.join(parts)}")
    for c in colours:
        where = "still hover" if colour_want[c[2][0]].source.startswith("still") else "airborne"
        n = min(colour_want[k].n for k in c[2])
        got = [gen.get(f"dlag1_{k}", math.nan) for k in c[2]]
        out[c[0]] = (cutoff[c[0]], f"lag-1 autocorrelation of the differences at {where}, white -0.5 (median over "
                                   f"{n} logs): {', '.join(f'{k} {colour_want[k].value:.2f}' for k in c[2])} "
                                   f"(generated {', '.join(f'{g:.2f}' for g in got)})")
    return out, lines


#: Hz, the pilot's sticks high-passed here (MissionParams.pilot_stick_highpass_hz; 0: two lags alone): the fleet's
#: roll below 0.5 Hz is 0.3x the generated one's at the fitted 0.5-2 Hz power
PILOT_HIGHPASS_HZ = 0.5


def fit_imu_offset(logs: list[LogMeasure], sensors, lines: list[str]) -> dict[str, tuple[object, str]]:
    """``imu_offset_m``: per axis the median of the logs' fitted offsets (:func:`_lever_arm`, the logs whose
    accelerometer follows their angular acceleration); none (a line in ``lines``) when no log's does."""
    if not hasattr(sensors, "imu_offset_m"):
        return {}
    fits = [m for m in logs if m.imu_offset is not None]
    if not fits:
        lines.append(f"IMU lever arm: no log's accelerometer follows its angular acceleration ({len(logs)} logs): "
                     "offset 0 kept")
        return {}
    r = [round(float(np.median([m.imu_offset[a] for m in fits])), 4) for a in range(3)]
    corr = [m.imu_offset_fit for m in fits]
    return {"imu_offset_m": (r, f"IMU offset from the centre of gravity (m, FRD): the 0.5-5 Hz horizontal accelerometer "
                                f"on the angular acceleration (alpha x r), median over {len(fits)} of {len(logs)} logs "
                                f"(correlation {min(corr):.2f}-{max(corr):.2f}; r_z "
                                f"{min(m.imu_offset[2] for m in fits):+.3f} to {max(m.imu_offset[2] for m in fits):+.3f})")}


#: a vehicle's vibration level is kept within this factor of the fleet's (either way)
VIBRATION_LEVEL_MAX = 30.0
#: fit the gyro's vibration levels above 1 too (False: at most 1, see :func:`vibration_levels`)
GYRO_LEVELS = False
#: the gyro axes whose levels go above 1 all the same, the rest as high-frequency vibration (:func:`vibration_levels`):
#: the fleet's rough vehicles' yaw gyro is near white where their roll and pitch gyros are coloured (lag-1 of the
#: differences in the air -0.14 to +0.07 on `6-3-2014_7`, `8-10-2014_10`/`_11`, `181`, at 3.6-13x the fleet's noise)
GYRO_HF_AXES = ("gyro_z",)


def vibration_levels(logs: list[LogMeasure], figs: dict[str, Figure], coloured: tuple[str, ...] = (),
                     per_sigma: dict[str, float] | None = None) -> dict[str, tuple[float, ...]]:
    """Per log, its vehicle's accelerometer x/y/z and gyro x/y/z vibration as multiples of the fleet's: the log's
    sample-to-sample noise in the air (its still hover, or every airborne row of a log without one: :func:`_noise`)
    over the fleet's (``white_hover_*``, what ``accel_vibration`` / ``gyro_vibration`` are calibrated to), within
    :data:`VIBRATION_LEVEL_MAX` either way; 1 where a log has no such figure. The fleet's vehicles differ by 3-50x in
    amplitude: the logs without a still hover are the roughest.

    The gyro's levels are at most 1 (:data:`GYRO_LEVELS`; a quieter vehicle's below): the rough vehicles' gyro
    differences stay coloured
    (lag-1 -0.2 to 0.7 in cruise, 0.3-0.8 at still hover), their extra is rocking, not vibration. As high-frequency
    vibration (above 1, physics.sensors.Sensors.imu) it whitened the generated cruise gyro (lag-1 of the differences
    -0.41 against the fleet's 0.73, the most separating feature; 20 flights), and as low-passed noise in the
    flight controller's loop it is flown (timeouts); their rocking is :func:`fit_rocking`'s. Up to 1 a level scales
    the fleet's vibration as it is (white or low-passed), so the sample-to-sample noise with it; above 1 the rest is
    high-frequency, which is the log's sample-to-sample figure only for a white vibration: a sensor in ``coloured``
    ("acc", "gyro": its fitted vibration low-passed) is kept at most 1 too, except the axes of :data:`GYRO_HF_AXES`
    with ``per_sigma`` (axis -> the fleet's sample-to-sample figure over the fitted vibration's per-sample sigma): there a
    level r above 1 becomes sqrt(1 + (r^2 - 1) per_sigma^2), whose high-frequency rest (per-sample sigma sqrt(l^2 - 1)
    times the vibration's, white at a log's rate) adds the log's sample-to-sample noise beyond the fleet's."""
    out = {}
    per_sigma = per_sigma or {}
    for m in logs:
        levels = []
        for k in (f"{sensor}_{a}" for sensor in ("acc", "gyro") for a in AXES):
            fleet = figs.get(f"white_hover_{k}")
            hf = k in GYRO_HF_AXES and k in per_sigma
            top = (1.0 if not hf and ((k.startswith("gyro") and not GYRO_LEVELS) or k.split("_")[0] in coloured)
                   else VIBRATION_LEVEL_MAX)
            r = m.hover_white.get(k, math.nan) / fleet.value if fleet is not None and fleet.value > 0 else math.nan
            r = r if math.isfinite(r) and r > 0 else 1.0
            if hf and r > 1.0:  # the rest as high-frequency vibration, of the coloured vibration's per-sample sigma
                r = math.sqrt(1.0 + (r * r - 1.0) * per_sigma[k] ** 2)
            levels.append(round(float(np.clip(r, 1.0 / VIBRATION_LEVEL_MAX, top)), 3))
        out[m.name] = tuple(levels)
    return out


#: the rocking level (rad/s^2 per step; roll, pitch, yaw) the calibration flights measure the gyro's response at
ROCKING_REF = (20.0, 20.0, 5.0)
#: a vehicle's rocking level is kept at or below this (rad/s^2 per step)
ROCKING_MAX = 100.0
#: the axes fitted (the others 0): a yaw rocking of the rough logs' gyro z (12-18 rad/s^2) made the heading wander
#: (cruise yaw std x5.2 and its power below 0.5 Hz x18 the fleet's, 20 flights): the yaw loop is too weak to hold it
ROCKING_AXES = "xy"


def fit_rocking(logs: list[LogMeasure], config, lines: list[str]) -> dict[str, tuple[float, float, float]]:
    """Per log, its vehicle's rocking (MissionParams.rocking_levels): the white angular acceleration whose gyro
    sample-to-sample noise in the air, added in squares to the generated flights' without rocking, gives the log's
    (its still hover, or every airborne row). Two rounds of calibration flights (:func:`calibration_figures`): none,
    and :data:`ROCKING_REF` on every flight; the response is linear in the level. A log at or below the generated
    figure gets 0; one without a gyro figure 0."""
    base = calibration_figures(config)
    ref_cfg = dataclasses.replace(config, mission=dataclasses.replace(config.mission, rocking_levels=(ROCKING_REF,)))
    ref = calibration_figures(ref_cfg)
    gain2, g0 = [], []
    for i, a in enumerate(AXES):
        b, r = base.get(f"white_gyro_{a}", math.nan), ref.get(f"white_gyro_{a}", math.nan)
        g0.append(b)
        gain2.append((r * r - b * b) / (ROCKING_REF[i] ** 2) if math.isfinite(b) and math.isfinite(r) else math.nan)
    out = {}
    for m in logs:
        lv = []
        for i, a in enumerate(AXES):
            t = m.hover_white.get(f"gyro_{a}", math.nan)
            ok = a in ROCKING_AXES and math.isfinite(t) and math.isfinite(gain2[i]) and gain2[i] > 0
            lv.append(round(float(min(math.sqrt(max(t * t - g0[i] * g0[i], 0.0) / gain2[i]), ROCKING_MAX)), 2)
                      if ok else 0.0)
        out[m.name] = tuple(lv)
    at_ref = ", ".join(f"{ref.get('white_gyro_' + a, math.nan):.3g}" for a in AXES)
    lines.append(f"rocking: the gyro's sample-to-sample noise of calibration flights {', '.join(f'{x:.3g}' for x in g0)} "
                 f"rad/s (x, y, z), {at_ref} at "
                 f"{ROCKING_REF} rad/s^2 per step; {sum(any(v) for v in out.values())} of {len(logs)} logs rock more")
    return out


#: the baro wander's time constant (s; SensorParams.baro_wander_tau_s): not fitted. Its lag-of-a-Gauss-Markov shape
#: puts its power below ~0.1 Hz at 2 s, under the window classifier's 0.5 Hz band edge, off the sample-to-sample noise
BARO_WANDER_TAU_S = 2.0
#: the wander (Pa) the calibration flights measure the baro's response at, and the most fitted
BARO_WANDER_REF = 3.0
BARO_WANDER_MAX = 30.0
#: the estimator's baro noise (m, EstimatorParams.baro_noise) candidates: the one whose calibration flights' estimated
#: altitude moves, over their baro, nearest the logs' (log scale) is kept
BARO_TRUST = (0.3, 1.0, 3.0)


def fit_baro_wander(figs: dict[str, Figure], config, lines: list[str]) -> dict[str, tuple[object, str]]:
    """``baro_wander_pa`` (and ``baro_wander_tau_s``) and ``[estimator] baro_noise``: the baro's slow error and how much
    the estimator trusts the baro, from the logs' still hover (:func:`baro_slow_figures`).

    A real flight controller's altitude filter follows its baro slowly (ArduCopter's inertial navigation: its
    altitude at still hover moves 0.2-0.5x as much as its baro in 10 s windows), so the baro's slow error shows in the
    baro and not in the vehicle's height. First the estimator's trust: of :data:`BARO_TRUST`, the one whose calibration
    flights (the wander at :data:`BARO_WANDER_REF`) give the estimated altitude's std over the baro's nearest the
    logs' (``alt_ratio``). Then the wander: calibration flights without it and at the reference, the baro's std below
    0.5 Hz adding in squares (linear in the wander), the rest to the logs' ``baro_lf``. Nothing (a line said) without
    a still hover's 10 s window in any log."""
    target, ratio = figs.get("baro_lf"), figs.get("alt_ratio")
    if target is None or not target.n or not math.isfinite(target.value):
        lines.append("baro wander: no log has 10 s of still hover with a baro: none fitted")
        return {}
    est = config.estimator
    ref = dataclasses.replace(config.sensors, baro_wander_pa=BARO_WANDER_REF, baro_wander_tau_s=BARO_WANDER_TAU_S)
    trial: dict[float, dict[str, float]] = {}
    for bn in BARO_TRUST if ratio is not None and ratio.n and ratio.value > 0 else (est.baro_noise,):
        trial[bn] = calibration_figures(dataclasses.replace(config, sensors=ref,
                                                            estimator=dataclasses.replace(est, baro_noise=bn)))
    ok = {bn: g for bn, g in trial.items() if g.get("landed", 1.0) == 1.0 and g.get("alt_ratio", 0.0) > 0}
    if not ok:
        lines.append("baro wander: the calibration flights did not all land or measure: none fitted")
        return {}
    if ratio is not None and ratio.n and ratio.value > 0:
        bn = min(ok, key=lambda b: abs(math.log(ok[b]["alt_ratio"] / ratio.value)))
    else:
        bn = est.baro_noise
    at_ref = ok[bn]["baro_lf"]
    base = calibration_figures(dataclasses.replace(config, estimator=dataclasses.replace(est, baro_noise=bn)))
    lf0 = base.get("baro_lf", math.nan)
    gain2 = (at_ref * at_ref - lf0 * lf0) / (BARO_WANDER_REF * BARO_WANDER_REF)
    if not (math.isfinite(gain2) and gain2 > 0):
        lines.append(f"baro wander: the calibration flights' baro below 0.5 Hz does not grow with it ({lf0:.3g} m "
                     f"without, {at_ref:.3g} m at {BARO_WANDER_REF:g} Pa): none fitted")
        return {}
    pa = round(float(min(math.sqrt(max(target.value ** 2 - lf0 ** 2, 0.0) / gain2), BARO_WANDER_MAX)), 4)
    ratios = ", ".join(f"{g.get('alt_ratio', math.nan):.2f} at {b:g} m" for b, g in trial.items())
    out: dict[str, tuple[object, str]] = {}
    if pa > 0:
        out["baro_wander_pa"] = (pa, f"the baro's slow wander (Pa, sigma): still hover, 10 s windows, baro altitude std below "
                                     f"0.5 Hz {target.value:.3g} m (median over {target.n} logs), calibration flights "
                                     f"{lf0:.3g} m without it, {at_ref:.3g} m at {BARO_WANDER_REF:g} Pa")
        out["baro_wander_tau_s"] = (BARO_WANDER_TAU_S, "the wander's time constant (s; not fitted)")
    if len(trial) > 1:
        out["baro_noise"] = (bn, f"EKF2_BARO_NOISE (m): the estimated altitude's std over the baro's at still hover, "
                                 f"10 s windows, {ratio.value:.2f} in the logs (median over {ratio.n}); calibration "
                                 f"flights with the wander {ratios}")
    lines.append(f"baro wander: {pa:g} Pa, the estimator's baro noise {bn:g} m")
    return out


#: the forward flight's baro noise (Pa per sample) the calibration flights measure the baro's response at, the most
#: fitted, and the calibration flights' cruise speed (m/s: above MOVING_M_S)
BARO_SPEED_REF = 4.0
BARO_SPEED_MAX = 40.0
BARO_SPEED_CAL_M_S = 3.0


def moving_figures(config, n: int = 3, seed: int = 777) -> float:
    """The baro's sample-to-sample noise in forward flight (:func:`moving_baro_noise`, median over ``n`` flights) of
    generated flights of ``config`` flying the base square at :data:`BARO_SPEED_CAL_M_S`; NaN if none measures it."""
    from scart_bench.generator.engine.simulate import simulate
    from scart_bench.generator.logs.phases import flight_phases
    from scart_bench.generator.plan import normal_seeds
    from scart_bench.generator.telemetry.tables import flight_views

    mission = dataclasses.replace(config.mission, missions=(), families=(), cruise_speed=BARO_SPEED_CAL_M_S)
    batch = simulate(normal_seeds(seed, n), dataclasses.replace(config, mission=mission, airframes=()))
    out = []
    for i in range(n):
        _, sim = flight_views(batch, i, ())
        tables = {k: v for k, v in sim.items() if k not in ("truth", "setpoint")}
        baro = noise_series(tables).get("baro_alt")
        if baro is not None:
            out.append(moving_baro_noise(tables, baro, flight_phases(tables)))
    return _median(out)[0]


def fit_baro_speed(figs: dict[str, Figure], config, lines: list[str]) -> dict[str, tuple[object, str]]:
    """``baro_speed_pa`` (and ``baro_speed_full_m_s``): the baro's noise in forward flight, from the logs' baro on their
    airborne rows at :data:`MOVING_M_S` or faster (``moving_baro``), by calibration flights flying a square at
    :data:`BARO_SPEED_CAL_M_S` without it and at :data:`BARO_SPEED_REF`: the noise adds in squares. Nothing (a line
    said) when no log moves that fast with a baro, or the logs' figure is at or below the flights' without it."""
    target = figs.get("moving_baro")
    if target is None or not target.n or not math.isfinite(target.value):
        lines.append(f"baro in forward flight: no log's baro measured at {MOVING_M_S:g} m/s or faster: none fitted")
        return {}
    g0 = moving_figures(config)
    ref = moving_figures(dataclasses.replace(config, sensors=dataclasses.replace(
        config.sensors, baro_speed_pa=BARO_SPEED_REF, baro_speed_full_m_s=MOVING_M_S)))
    gain2 = (ref * ref - g0 * g0) / (BARO_SPEED_REF * BARO_SPEED_REF)
    if not (math.isfinite(gain2) and gain2 > 0):
        lines.append(f"baro in forward flight: the calibration flights' baro noise does not grow with it ({g0:.3g} m "
                     f"without, {ref:.3g} m at {BARO_SPEED_REF:g} Pa): none fitted")
        return {}
    pa = round(float(min(math.sqrt(max(target.value ** 2 - g0 * g0, 0.0) / gain2), BARO_SPEED_MAX)), 4)
    lines.append(f"baro in forward flight: {pa:g} Pa")
    if not pa > 0:
        return {}
    return {"baro_speed_pa": (pa, f"the baro's noise in forward flight (Pa per sample, from 1 m/s to full at "
                                  f"{MOVING_M_S:g} m/s): airborne at {MOVING_M_S:g} m/s or faster, sample-to-sample baro "
                                  f"altitude {target.value:.3g} m (median over {target.n} logs); calibration flights at "
                                  f"{BARO_SPEED_CAL_M_S:g} m/s {g0:.3g} m without it, {ref:.3g} m at {BARO_SPEED_REF:g} Pa"),
            "baro_speed_full_m_s": (MOVING_M_S, "the speed of the full noise (m/s; not fitted)")}


def _fmt(v: float) -> str:
    return f"{v:.3g}" if math.isfinite(v) else "n/a"


def fit_fleet(logs: list[LogMeasure], config, calibrate: bool = True) -> Fit:
    """The fitted profile of ``logs`` on top of ``config`` (the base FlightConfig)."""
    figs = fleet_figures(logs)
    n_logs = len(logs)
    values: dict[str, dict[str, tuple[object, str]]] = {"sensors": {}, "estimator": {}, "mission": {}}
    lines: list[str] = []

    def of(key: str) -> str:
        f = figs[key]
        return f"{f.source}, median over {f.n} of {n_logs} logs"

    from scart_bench.generator.telemetry.timing import MAX_CV

    # message timing per topic; the calibration flights below are stamped with it, as the flights will be
    values["timing"] = like_timing.fleet_table([m.timing for m in logs], n_logs, MAX_CV)
    config = like_timing.with_table(config, values["timing"])
    if calibrate:  # the pilot in attitude mode first: its motion is part of what the noise calibration measures
        if hasattr(config.mission, "pilot_stick_highpass_hz") and PILOT_HIGHPASS_HZ:  # a band-pass stick
            config = dataclasses.replace(config, mission=dataclasses.replace(
                config.mission, pilot_stick_highpass_hz=PILOT_HIGHPASS_HZ))
        pilot, said = like_pilot.fit_pilot([m.pilot for m in logs], [m.name for m in logs], config, pilot_figures,
                                           figs["cruise_speed"].value)
        if pilot and config.mission.pilot_stick_highpass_hz:
            pilot["pilot_stick_highpass_hz"] = (config.mission.pilot_stick_highpass_hz, "the sticks' high-pass (Hz; not "
                                                "fitted: the low edge of the roll/pitch band the pilot is fitted on)")
        values["mission"].update(pilot)
        lines.extend(said)
        config = dataclasses.replace(config, mission=dataclasses.replace(config.mission, **{k: v for k, (v, _) in pilot.items()}))
    # the IMU's lever arm: its acceleration is part of what the noise calibration measures
    values["sensors"].update(fit_imu_offset(logs, config.sensors, lines))
    if "imu_offset_m" in values["sensors"]:
        config = dataclasses.replace(config, sensors=dataclasses.replace(
            config.sensors, imu_offset_m=tuple(values["sensors"]["imu_offset_m"][0])))
    # sensor noise, by flying calibration flights
    if calibrate:
        noise, said = calibrate_noise(config, figs)
        values["sensors"].update(noise)
        lines.extend(said)
        if hasattr(config.sensors, "baro_wander_pa"):  # the baro's slow wander, on the fitted noise
            fitted = {k: tuple(v) if isinstance(v, list) else v for k, (v, _) in noise.items() if hasattr(config.sensors, k)}
            wander = fit_baro_wander(figs, dataclasses.replace(config, sensors=dataclasses.replace(config.sensors, **fitted)),
                                     lines)
            for k, v in wander.items():
                values["sensors" if k.startswith("baro_wander") else "estimator"][k] = v
        if hasattr(config.sensors, "baro_speed_pa"):  # the baro's noise in forward flight, on the fitted noise
            fitted = {k: tuple(v) if isinstance(v, list) else v for k, (v, _) in values["sensors"].items()
                      if hasattr(config.sensors, k)}
            est = {k: v for k, (v, _) in values["estimator"].items() if hasattr(config.estimator, k)}
            values["sensors"].update(fit_baro_speed(figs, dataclasses.replace(
                config, sensors=dataclasses.replace(config.sensors, **fitted),
                estimator=dataclasses.replace(config.estimator, **est)), lines))
    fields = {f.name for f in dataclasses.fields(config.sensors)}
    fm = [m.mag_field_ned for m in logs if m.mag_field_ned is not None]
    if fm and "mag_field_ned" in fields:
        med = tuple(round(float(x), 4) for x in np.median(np.array(fm), axis=0))
        values["sensors"]["mag_field_ned"] = (list(med), f"magnetometer on the ground rotated by the attitude, "
                                                         f"median over {len(fm)} of {n_logs} logs")
    else:
        lines.append(f"magnetic field: no log with a calibrated magnetometer and attitude on the ground "
                     f"({n_logs} logs): default kept")
    eph, epv = figs["eph"], figs["epv"]
    s = config.sensors
    if eph.n:
        noise_h = s.gps_noise_h if eph.value < 1.0 else max(s.gps_noise_h, 0.5)
        values["sensors"]["gps_noise_h"] = (round(noise_h, 3), "white part of the GPS error (m, per axis)")
        values["sensors"]["gps_bias_h"] = (round(math.sqrt(max(eph.value ** 2 - noise_h ** 2, 0.01)), 3),
                                           f"eph = hypot(noise, bias) = {eph.value:.2f} m: {of('eph')}")
        values["estimator"]["gps_max_eph"] = (round(max(3.0, 2.0 * eph.value), 2),
                                              "EKF2_REQ_EPH: 2 x the fleet's eph, or GPS would not be fused")
    else:
        lines.append(f"GPS accuracy: no log with a 3-D fix and eph logged ({n_logs} logs): default kept")
    if epv.n:
        noise_v = s.gps_noise_v if epv.value < 1.0 else max(s.gps_noise_v, 1.0)
        values["sensors"]["gps_noise_v"] = (round(noise_v, 3), "white part of the GPS height error (m)")
        values["sensors"]["gps_bias_v"] = (round(math.sqrt(max(epv.value ** 2 - noise_v ** 2, 0.01)), 3),
                                           f"epv = hypot(noise, bias) = {epv.value:.2f} m: {of('epv')}")
    mp = config.mission
    mission_map = (("climb_speed", "climb_rate", 0.3, 6.0), ("land_speed", "descent_rate", 0.2, 3.0),
                   ("takeoff_hold_s", "takeoff_hover_s", 0.0, 120.0), ("cruise_speed", "cruise_speed", 0.5, 20.0))
    for fld, key, lo, hi in mission_map:
        f = figs[key]
        if f.n and hasattr(mp, fld):
            values["mission"][fld] = (round(float(np.clip(f.value, lo, hi)), 2), of(key))
        else:
            lines.append(f"{key.replace('_', ' ')}: no log measured it: default {getattr(mp, fld, 'n/a')} kept")
    w = figs["wind_speed"]
    if w.n and hasattr(mp, "wind_max"):
        src = sorted({m.wind_source.split(" (")[0] for m in logs if m.wind_source})
        values["mission"]["wind_max"] = (round(float(np.clip(2.0 * w.value, 0.0, 20.0)), 2),
                                         f"drawn in [0, wind_max]: 2 x the median wind {w.value:.2f} m/s "
                                         f"({' / '.join(src)}; {w.n} of {n_logs} logs)")
    else:
        lines.append("wind: no log gave a wind estimate: default kept")
    measured: dict[str, tuple[float, str]] = {}
    for key, f in figs.items():
        if key.startswith(("ground_", "white_ground_", "dlag1_", "rate_", "jitter_")) or key in ("ground_before_s", "logged_s", "airborne_s",
                                                                       "altitude", "baro_lf", "alt_ratio",
                                                                       "moving_baro"):
            measured[key] = (f.value, f"{f.source}, median over {f.n} of {n_logs} logs")
    for key, f in figs.items():
        if key.startswith(("hover_", "white_hover_")):
            measured[key] = (f.value, f"{f.source}, median over {f.n} of {n_logs} logs")
    levels = {}
    if calibrate and hasattr(config.sensors, "vibration_levels"):  # each vehicle's, over the calibrated vibration
        cut = {k: values["sensors"].get(f"{k}_noise_cutoff_hz", (getattr(config.sensors, f"{k}_noise_cutoff_hz"), ""))[0]
               for k in ("accel", "gyro")}
        vib = values["sensors"].get("gyro_vibration", (config.sensors.gyro_vibration, ""))[0]
        fig = figs.get("white_hover_gyro_z")
        per_sigma = {"gyro_z": fig.value / float(vib[2])} if fig is not None and fig.n and float(vib[2]) > 0 else {}
        levels = vibration_levels(logs, figs, tuple(k[:3] if k == "accel" else k for k, c in cut.items() if c), per_sigma)
    rocking, flow = {}, {}
    if calibrate:  # each vehicle's rocking, at rest and in forward flight, flown on the fitted noise
        noise = {k: tuple(v) if isinstance(v, list) else v for k, (v, _) in values["sensors"].items()
                 if hasattr(config.sensors, k)}
        noisy = dataclasses.replace(config, sensors=dataclasses.replace(config.sensors, **noise))
        rocking = fit_rocking(logs, noisy, lines)
        flow, fields = like_flow.fit_flow({m.name: m.flow for m in logs}, noisy, flow_figures, lines)
        values["mission"].update(fields)
    return Fit(values, measured, [], lines, logs, levels, rocking, flow)


def log_line(m: LogMeasure) -> str:
    """One line summing up what a log gave."""
    parts = [f"{m.logged_s:.0f} s logged"]
    if math.isfinite(m.airborne_s):
        parts.append(f"{m.airborne_s:.0f} s airborne")
    if m.mission_source:
        err = f", within {m.track_error_m:.1f} m of the track" if math.isfinite(m.track_error_m) else ""
        parts.append(f"mission: {m.mission_source}{err}")
    if m.wind_source:
        parts.append(f"wind {m.wind_speed:.1f} m/s from {m.wind_source.split(' (')[0]}")
    if m.hover_s:
        parts.append(f"noise on {m.hover_s:.0f} s of {'still hover' if m.hover_still else 'airborne rows'}")
    return f"{m.name}: " + "; ".join(parts)
