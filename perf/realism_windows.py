"""Window-level realism check: can a classifier tell generated flights from real logs? (issue 47)

Usage (command line)::

    python -m perf.realism_windows --dataset DIR [--logs FILE_OR_DIR ...] [--phases ground,hover,cruise]
                                   [--signals attitude,imu,baro] [--no-timing] [--view simulator] [--markdown]

``--dataset`` is a generated dataset (its normal flights, the ``simulator`` view by default);
each ``--logs`` argument is one log set (a folder: every log in it that ``scart-bench import``
reads; a file: that log); by default the three sets in ``../shared/data`` (the 4 PX4 ULogs, the
2 ArduCopter logs, the 12-log fleet). ``python -m perf.realism --windows ...`` is the same.

Usage (from Python: the realism fixes, `generate --like` and a jMAVSim comparison call these)::

    from perf.realism_windows import read_dataset, read_logs, compare
    gen = read_dataset("/tmp/gen")                 # list[FlightSignals]
    real = read_logs(["../shared/data/dataflash/fleet"])
    result = compare(gen, real)                    # a Comparison
    print(result.report())                         # AUC per phase, top features, signals used
    result.flight_auc_by_phase["hover"]            # one number

    result.phases["hover"].features               # each feature alone: AUC, medians, ratio
    rates = common_rates(gen + real, list(SIGNALS))   # per signal, the rate both sides reach
    table = window_table(gen + real, rates)        # the features: one row per 10 s window
    f = signals_from_tables("mine", tables, "generated")   # {topic: DataFrame} of any flight

What it does:

1. **Signals by meaning.** Each flight (a dataset's topic tables or a log's, read with
   ``generator.logs.importers.load_flight_file``) gives the signals of :data:`SIGNALS` --
   position N/E/D, velocity N/E/D, roll/pitch/yaw, accelerometer and gyro x/y/z, baro altitude --
   found through ``generator.scart.meanings.QUANTITIES`` (the first candidate topic.field the
   tables have, whatever the format or firmware) and converted to SI units with
   ``generator.scart.units.scale`` (ArduPilot's degrees). Quaternions become roll/pitch/yaw and
   constant fields (a GPS-less log's zero position) are dropped by
   ``generator.logs.orientation.listen_view``. Position and velocity of a log without a 3-D GPS
   fix are left out (dead reckoning, no measurement).
2. **Common rate.** Per signal, both sides are sampled at the same rate: the lower of the two
   sides' median native rates, snapped down to :data:`RATES`, at most 50 Hz (enough for the
   5-25 Hz band; an ArduCopter ATT at 10 Hz is compared at 10 Hz, so the logging rate is no
   tell). The sample is the latest at each tick (as a link streams it); a tick more than
   :func:`max_gap` after its sample is a gap.
3. **Windows.** 10 s windows every 5 s; a window where any used signal has a gap is dropped
   (logs with logging gaps keep their whole stretches). Each window's phase: ``ground`` (the
   flight's phases, ``generator.logs.phases.flight_phases``, say landed for >= 80 % of it),
   ``hover`` (airborne, median horizontal speed < 1 m/s and :func:`vertical_speed` < 0.5 m/s), ``cruise``
   (airborne and moving), ``air`` (airborne, a log without velocity: not moving vertically but
   its horizontal speed unknown), ``mixed`` (take-off or landing inside the window). Both sides
   use the same signals: a generated flight whose mission was recovered from a log of the
   comparison without GPS velocity takes its phases without its own velocity too
   (:func:`pair_phase_speed`; its still windows are ``air``, as its log's are).
4. **Features** per window per signal (:data:`FEATURES`): std, std of first differences,
   log10 power in 0-0.5 / 0.5-2 / 2-5 / 5-25 Hz (bands above the signal's Nyquist frequency are
   left out), lag-1 autocorrelation of the detrended window and of its first differences, and
   the timing jitter of its source topic (std / median of the message intervals).
5. **The check** (:func:`compare`): per phase and overall, a HistGradientBoostingClassifier,
   cross-validated by flight (StratifiedGroupKFold), every flight weighing the same and the two
   sides weighing the same; window AUC of the out-of-fold probabilities and flight AUC of each
   flight's mean out-of-fold probability. What separates: each feature alone (the window-level
   AUC of its values, with the median ratio generated / real) and each signal group alone (the
   flight AUC of the classifier on that group's features).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

#: the real logs shipped next to the checkout
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
#: the default log sets: name -> folder (its logs)
DEFAULT_LOG_SETS = {
    "ulog (PX4)": SHARED_DATA / "ulog",
    "dataflash (ArduCopter)": SHARED_DATA / "dataflash",
    "fleet (ArduCopter)": SHARED_DATA / "dataflash" / "fleet",
}
#: signal -> (quantity, field) of generator.scart.meanings.QUANTITIES (candidates in its order)
SIGNALS: dict[str, tuple[str, str]] = {
    "pos_n": ("position", "x"), "pos_e": ("position", "y"), "pos_d": ("altitude", "z"),
    "vel_n": ("velocity", "vn"), "vel_e": ("velocity", "ve"), "vel_d": ("velocity", "vd"),
    "roll": ("attitude", "roll"), "pitch": ("attitude", "pitch"), "yaw": ("attitude", "yaw"),
    "acc_x": ("imu", "xacc"), "acc_y": ("imu", "yacc"), "acc_z": ("imu", "zacc"),
    "gyro_x": ("imu", "xgyro"), "gyro_y": ("imu", "ygyro"), "gyro_z": ("imu", "zgyro"),
    "baro_alt": ("baro", "alt"),
}
#: signal groups (for --signals and the per-group AUC)
GROUPS: dict[str, tuple[str, ...]] = {
    "position": ("pos_n", "pos_e", "pos_d"), "velocity": ("vel_n", "vel_e", "vel_d"),
    "attitude": ("roll", "pitch", "yaw"), "accelerometer": ("acc_x", "acc_y", "acc_z"),
    "gyro": ("gyro_x", "gyro_y", "gyro_z"), "baro": ("baro_alt",),
}
#: group aliases accepted by --signals
GROUP_ALIASES = {"imu": ("accelerometer", "gyro"), "all": tuple(GROUPS)}
#: signals that need a GPS fix to be a measurement
GPS_SIGNALS = GROUPS["position"] + GROUPS["velocity"]
#: GPS topics and their fix field (a log has a fix when one message says >= 3)
GPS_TOPICS = (("gps_raw_int", "fix_type"), ("vehicle_gps_position", "fix_type"), ("sensor_gps", "fix_type"),
              ("gps", "Status"), ("gps_0", "Status"))
#: topics that carry the baro's value on another sensor's message (MAVLink's HIGHRES_IMU at the IMU's
#: rate): the baro altitude is read from the baro's own message where a flight has one (ArduPilot's BARO,
#: PX4's vehicle_air_data, MAVLink's SCALED_PRESSURE), so that both sides' samples and message timing are
#: the barometer's, not the IMU's
BARO_CARRIERS = ("highres_imu",)
#: pressure fields (baro altitude from a pressure where no altitude is logged)
PRESSURE_FIELDS = ("press_abs", "abs_pressure", "pressure", "baro_pressure_pa", "Press", "fluid_pressure")
#: per-window features of a signal
FEATURES = ("std", "dstd", "p0_0.5", "p0.5_2", "p2_5", "p5_25", "ac1", "dac1", "jitter")
#: spectral bands (Hz) of the power features, in FEATURES' order
BANDS = ((0.0, 0.5), (0.5, 2.0), (2.0, 5.0), (5.0, 25.0))
#: common sampling rates (Hz): a signal is compared at the highest of these both sides reach
RATES = (50.0, 25.0, 20.0, 10.0, 5.0, 2.0, 1.0)
WINDOW_S = 10.0
#: the classifier's settings (small tables: hundreds of windows, ~100 features)
MODEL = {"max_iter": 100, "learning_rate": 0.1, "max_leaf_nodes": 15, "min_samples_leaf": 3, "max_bins": 32,
         "max_features": 0.3, "early_stopping": False}
# max_features: each split sees 30 % of the features. Where many features separate the training flights
# perfectly, every tree would otherwise split on the first of them (equal gains tie by column order),
# and a held-out flight's fate would hang on that one feature (fleet ground windows: flight AUC 0.61
# with all features per split, 0.96 with 30 %).
STEP_S = 5.0
#: a window is of a phase when this share of it is (ground) or when its median speed says so
PHASE_SHARE = 0.8
HOVER_SPEED_M_S = 1.0
HOVER_CLIMB_M_S = 0.5
#: the phases reported (``all``: every window, whatever its phase)
PHASES = ("ground", "hover", "cruise", "all")


@dataclass
class FlightSignals:
    """One flight's (or log's) signals, in seconds from its start, and its ground/air timeline."""

    name: str
    side: str  # "generated" or the log set's name
    signals: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # name -> (t_s, values)
    sources: dict[str, str] = field(default_factory=dict)  # name -> "topic.field" it came from
    ground: tuple[np.ndarray, np.ndarray] | None = None  # (t_s, True on the ground)
    altitude: tuple[np.ndarray, np.ndarray] | None = None  # (t_s, m above the ground) of the phases
    notes: list[str] = field(default_factory=list)  # what was left out and why
    #: the log a generated flight's mission was recovered from (its ``mission_file``'s stem; None for a log)
    mission: str | None = None
    #: whether the horizontal speed (GPS velocity) decides hover / cruise (see :func:`window_phase`);
    #: :func:`compare` sets it False on a generated flight whose mission comes from a log without it
    phase_speed: bool = True


# --- reading --------------------------------------------------------------------------------------------
def _has_fix(tables: dict[str, pd.DataFrame]) -> bool | None:
    """True/False when the tables have a GPS topic with/without a 3-D fix; None without a GPS topic."""
    seen = None
    for topic, col in GPS_TOPICS:
        df = tables.get(topic)
        if df is not None and col in df.columns:
            seen = False
            if (pd.to_numeric(df[col], errors="coerce") >= 3).any():
                return True
    return seen


def pressure_altitude(pressure: np.ndarray, topic: str, col: str) -> np.ndarray:
    """The ISA barometric altitude (m) of a pressure field (hPa or Pa, by its unit in
    ``generator.scart.units``): the atmosphere's own curve, not one Pa-per-metre figure, so that a
    flight's baro read from its pressure has the same metres as one logged as an altitude (a linear
    ``HPA_PER_M`` read a generated flight's ``scaled_pressure.press_abs`` 1.5 % larger than its
    ``highres_imu.pressure_alt``)."""
    from scart_bench.generator.geo import altitude_at
    from scart_bench.generator.scart.units import HPA_PER_M, scale

    pa_per_unit = 100.0 if np.isclose(scale(topic, col), HPA_PER_M) else 1.0
    return altitude_at(np.asarray(pressure, np.float64) * pa_per_unit)


def signals_from_tables(name: str, tables: dict[str, pd.DataFrame], side: str) -> FlightSignals:
    """A flight's signals from its topic tables (``{topic: DataFrame}`` with an int64 ``Timestamp`` in
    µs, as the importers and the dataset reader give), found by meaning."""
    from scart_bench.generator.logs.orientation import listen_view
    from scart_bench.generator.scart.meanings import QUANTITIES
    from scart_bench.generator.scart.units import scale

    view = listen_view(tables)
    f = FlightSignals(name, side)
    fix = _has_fix(tables)
    for sig, (quantity, fld) in SIGNALS.items():
        if sig in GPS_SIGNALS and not fix:
            continue
        candidates = list(QUANTITIES[quantity][fld])
        if sig == "baro_alt":  # a pressure where no altitude is logged
            candidates += list(QUANTITIES["baro"]["pressure"])
        best = None
        for cand in candidates:
            topic, _, col = cand.partition(".")
            df = view.get(topic)
            if df is None or col not in df.columns or col in df.attrs.get("constant_fields", {}):
                continue
            t = df["Timestamp"].to_numpy(np.int64) / 1e6
            x = df[col].to_numpy(np.float64)
            ok = np.isfinite(x)
            if ok.sum() < 10:
                continue
            # the candidate spanning most of the flight (to the second), then the fastest: a ULog's
            # sensor_combined (200 Hz) over its sensor_accel (1 Hz), a flight's local position (from
            # the start) over its global position (from the GPS fix); the baro from its own message
            own = not (sig == "baro_alt" and topic in BARO_CARRIERS)
            rank = (own, round(float(t[ok][-1] - t[ok][0])), int(ok.sum()))
            if best is None or rank > best[0]:
                best = rank, cand, t[ok], x[ok] if col in PRESSURE_FIELDS else x[ok] / scale(topic, col)
        if best is not None:
            _, cand, t, x = best
            if cand.partition(".")[2] in PRESSURE_FIELDS:
                x = pressure_altitude(x, *cand.split(".", 1))
            if sig == "yaw":
                x = np.unwrap(x)
            f.signals[sig] = (t, x)
            f.sources[sig] = cand
    if fix is None and not any(s in f.signals for s in GPS_SIGNALS):
        f.notes.append("no GPS topic: position and velocity left out")
    elif fix is False:
        f.notes.append("no 3-D GPS fix: position and velocity left out")
    try:
        from scart_bench.generator.logs.phases import LANDED, PHASES, flight_phases

        ph = flight_phases(tables)
        t = ph["Timestamp"].to_numpy(np.int64) / 1e6
        f.ground = t, ph["phase"].to_numpy() == PHASES[LANDED]
        f.altitude = t, ph["altitude_m"].to_numpy(np.float64)
    except ValueError as exc:
        f.notes.append(f"no phases ({exc}): its windows count only in 'all'")
    return f


def read_log(path: str | Path, side: str = "real") -> FlightSignals:
    """One real log (any format ``scart-bench import`` reads) as signals."""
    from scart_bench.generator.logs.importers import load_flight_file

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tables = load_flight_file(path, allow_corrupt=True)
    return signals_from_tables(Path(path).name, tables, side)


def log_files(path: str | Path) -> list[Path]:
    """The logs a path names: the file itself, or every log of a folder (not its subfolders)."""
    from scart_bench.generator.logs.importers import LOG_SUFFIXES

    p = Path(path)
    if p.is_dir():
        return sorted(x for x in p.iterdir() if x.is_file() and x.suffix.lower() in LOG_SUFFIXES)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such log file or folder")
    return [p]


def read_logs(paths, side: str | None = None) -> list[FlightSignals]:
    """Every log of ``paths`` (files or folders); a log that cannot be read is said on stderr and left out."""
    out = []
    for path in paths:
        for f in log_files(path):
            try:
                out.append(read_log(f, side or str(path)))
            except Exception as exc:  # a damaged log: say which and go on
                print(f"{f}: cannot read it ({type(exc).__name__}: {exc}); left out", file=sys.stderr)
    return out


def read_dataset(path: str | Path, view: str = "simulator", n: int | None = None) -> list[FlightSignals]:
    """Up to ``n`` normal flights of a generated dataset, one view (``simulator`` by default: the
    flight controller's own telemetry before any attack; ``uorb`` where written: PX4's topics at a
    log's rates)."""
    from scart_bench.dataset import open_dataset

    ds = open_dataset(path)
    m = ds.manifest
    ids = m.loc[m["mode"] == "normal", "flight_id"].astype(str).tolist()[:n]
    out = []
    for fid in ids:
        tables = {t: ds.topic(fid, t, view) for t in ds.topics(fid, view)}
        f = signals_from_tables(fid, tables, "generated")
        f.mission = _mission_log(ds, fid)
        out.append(f)
    return out


def _mission_log(ds, fid: str) -> str | None:
    """The log a generated flight's mission came from: the stem of its ``mission_file`` (``generate
    --like`` names each recovered mission after its log), None without one."""
    try:
        name = ds.config(fid).get("mission_file")
    except Exception:  # a dataset without raw/config.json: no mission to pair
        return None
    return Path(str(name)).stem if name else None


def log_stem(name: str) -> str:
    """A log's name without its folder and suffix (``real/arducopter_181.bin`` -> ``arducopter_181``)."""
    return Path(name.rsplit("/", 1)[-1]).stem


def pair_phase_speed(generated: list[FlightSignals], real: list[FlightSignals]) -> list[str]:
    """The same phase signals on both sides: a generated flight whose mission was recovered from a log
    of ``real`` that has no horizontal speed (no GPS fix) takes its phases without its own speed too
    (``phase_speed`` False: its non-climbing airborne windows are ``air``, as its log's are). Returns the
    logs so paired."""
    speedless = {log_stem(f.name) for f in real if not ("vel_n" in f.signals and "vel_e" in f.signals)}
    paired = set()
    for f in generated:
        if f.mission is not None and f.mission in speedless:
            f.phase_speed = False
            paired.add(f.mission)
    return sorted(paired)


# --- resampling and features ----------------------------------------------------------------------------
def native_hz(t: np.ndarray) -> float:
    """A signal's native rate: 1 / its median message interval."""
    dt = np.diff(np.unique(t))
    return float(1.0 / np.median(dt)) if len(dt) else 0.0


def snap_rate(hz: float, max_hz: float = 50.0) -> float:
    """The highest of :data:`RATES` at or below ``hz`` (with 10 % slack for clock jitter) and ``max_hz``."""
    for r in RATES:
        if r <= max_hz and r <= hz * 1.1:
            return r
    return 0.0


def common_rates(flights: list[FlightSignals], signals: list[str], max_hz: float = 50.0) -> dict[str, float]:
    """Per signal, the rate both sides are compared at: the lowest side median of native rates, snapped."""
    rates = {}
    for sig in signals:
        per_side: dict[str, list[float]] = {}
        for f in flights:
            if sig in f.signals:
                per_side.setdefault(f.side == "generated" and "g" or "r", []).append(native_hz(f.signals[sig][0]))
        if per_side:
            rates[sig] = snap_rate(min(float(np.median(v)) for v in per_side.values()), max_hz)
    return {s: r for s, r in rates.items() if r > 0}


def max_gap(hz_native: float) -> float:
    """The longest interval (s) between messages that is not a gap: 4 native intervals, at least 0.5 s."""
    return max(0.5, 4.0 / hz_native) if hz_native > 0 else 0.5


def latest_at(t: np.ndarray, x: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The latest sample at each tick of ``grid`` and the age (s) of that sample (inf before the first)."""
    i = np.searchsorted(t, grid, side="right") - 1
    ok = i >= 0
    j = np.clip(i, 0, None)
    return np.where(ok, x[j], np.nan), np.where(ok, grid - t[j], np.inf)


def band_powers(x: np.ndarray, hz: float, bands=BANDS) -> np.ndarray:
    """log10 power (signal units^2) of the mean-removed window in each band; NaN above Nyquist.

    A Hann-windowed periodogram (resolution 1 / window length: 0.1 Hz for 10 s), the power in a band
    is the sum over its bins [lo, hi) times the bin width (the top band includes Nyquist)."""
    from scipy.signal import periodogram

    freqs, pxx = periodogram(x, fs=hz, window="hann", detrend="constant", scaling="density")
    df = freqs[1] - freqs[0]
    nyq = hz / 2.0
    out = np.full(len(bands), np.nan)
    for k, (lo, hi) in enumerate(bands):
        if lo >= nyq - 1e-9:
            continue
        sel = (freqs >= lo) & ((freqs < hi) | ((hi >= nyq) & (freqs <= nyq)))
        out[k] = np.log10(pxx[sel].sum() * df + 1e-20)
    return out


def _ac1(x: np.ndarray) -> float:
    x = x - x.mean()
    d = float(np.dot(x, x))
    return float(np.dot(x[:-1], x[1:]) / d) if d > 0 else 0.0


def signal_features(x: np.ndarray, hz: float, times: np.ndarray | None = None) -> np.ndarray:
    """The :data:`FEATURES` of one window of a signal sampled at ``hz`` (``times``: its source messages'
    times inside the window, for the jitter)."""
    n = np.arange(len(x))
    detrended = x - np.polyval(np.polyfit(n, x, 1), n)
    d = np.diff(x)
    jitter = np.nan
    if times is not None and len(times) > 2:
        dt = np.diff(times)
        med = np.median(dt)
        jitter = float(np.std(dt) / med) if med > 0 else np.nan
    return np.concatenate([[np.log10(np.std(x) + 1e-12), np.log10(np.std(d) + 1e-12)], band_powers(x, hz),
                           [_ac1(detrended), _ac1(d), jitter]])


def vertical_speed(altitude: tuple[np.ndarray, np.ndarray] | None, a: float, b: float, block_s: float = 2.0) -> float:
    """How fast the window [a, b) climbs or descends (m/s): the largest change between consecutive
    ``block_s`` means of the altitude, per second. Robust to a noisy or stepped altitude (an
    ArduCopter CTUN.Alt at 10 Hz: its 1 s climb rate reads 1-3 m/s in a hover); NaN without one."""
    if altitude is None:
        return float("nan")
    t, h = altitude
    means = []
    for k in range(int(round((b - a) / block_s))):
        s = (t >= a + k * block_s) & (t < a + (k + 1) * block_s)
        if s.any():
            means.append(float(np.mean(h[s])))
    if len(means) < 2:
        return float("nan")
    return float(np.max(np.abs(np.diff(means))) / block_s)


def window_phase(f: FlightSignals, a: float, b: float) -> str:
    """The phase of the window [a, b) of a flight (see the module doc)."""
    if f.ground is None:
        return "unknown"
    t, g = f.ground
    sel = (t >= a) & (t < b)
    if not sel.any():
        return "unknown"
    share = float(g[sel].mean())
    if share >= PHASE_SHARE:
        return "ground"
    if share > 1 - PHASE_SHARE:
        return "mixed"
    climb = vertical_speed(f.altitude, a, b)
    if f.phase_speed and "vel_n" in f.signals and "vel_e" in f.signals:
        (tn, vn), (te, ve) = f.signals["vel_n"], f.signals["vel_e"]
        s = (tn >= a) & (tn < b)
        if s.any():
            ve_at = np.interp(tn[s], te, ve)
            speed = float(np.median(np.hypot(vn[s], ve_at)))
            if speed < HOVER_SPEED_M_S and not climb >= HOVER_CLIMB_M_S:
                return "hover"
            return "cruise"
    if climb >= HOVER_CLIMB_M_S:
        return "cruise"
    return "air"


def flight_windows(f: FlightSignals, rates: dict[str, float], window_s: float = WINDOW_S,
                   step_s: float = STEP_S) -> pd.DataFrame:
    """One row per window of a flight where every signal of ``rates`` is present without a gap:
    ``flight``, ``side``, ``start_s``, ``phase`` and ``<signal>__<feature>`` columns."""
    sigs = [s for s in rates if s in f.signals]
    if len(sigs) < len(rates):
        return pd.DataFrame()
    start = max(f.signals[s][0][0] for s in sigs)
    end = min(f.signals[s][0][-1] for s in sigs)
    gaps = {s: max_gap(native_hz(f.signals[s][0])) for s in sigs}
    rows = []
    a = start
    while a + window_s <= end + 1e-9:
        b = a + window_s
        feats = {}
        for s in sigs:
            t, x = f.signals[s]
            hz = rates[s]
            grid = a + np.arange(int(round(window_s * hz))) / hz
            v, age = latest_at(t, x, grid)
            if not np.all(age <= gaps[s]):
                feats = None
                break
            inside = t[np.searchsorted(t, a):np.searchsorted(t, b)]
            for name, val in zip(FEATURES, signal_features(v, hz, inside), strict=True):
                feats[f"{s}__{name}"] = val
        if feats is not None:
            rows.append({"flight": f.name, "side": f.side, "start_s": round(a, 3),
                         "phase": window_phase(f, a, b), **feats})
        a += step_s
    return pd.DataFrame(rows)


def window_table(flights: list[FlightSignals], rates: dict[str, float], window_s: float = WINDOW_S,
                 step_s: float = STEP_S) -> pd.DataFrame:
    """The windows of every flight (see :func:`flight_windows`); feature columns that are NaN for
    every window (a band above every signal's Nyquist) are dropped."""
    parts = [flight_windows(f, rates, window_s, step_s) for f in flights]
    parts = [p for p in parts if len(p)]
    if not parts:
        return pd.DataFrame(columns=["flight", "side", "start_s", "phase"])
    table = pd.concat(parts, ignore_index=True)
    return table.dropna(axis=1, how="all")


# --- the check ------------------------------------------------------------------------------------------
def select_signals(spec: str | None) -> list[str]:
    """Signal names of a ``--signals`` spec: groups (``attitude,imu,baro``) or signal names; all by default."""
    if not spec:
        return list(SIGNALS)
    out: list[str] = []
    for part in (p.strip() for p in spec.split(",") if p.strip()):
        groups = GROUP_ALIASES.get(part, (part,) if part in GROUPS else ())
        names = [s for g in groups for s in GROUPS[g]] or ([part] if part in SIGNALS else [])
        if not names:
            raise ValueError(f"--signals: unknown signal or group {part!r}; expected one of "
                             f"{', '.join([*GROUPS, *GROUP_ALIASES, *SIGNALS])}")
        out += [n for n in names if n not in out]
    return out


def usable_signals(generated: list[FlightSignals], real: list[FlightSignals],
                   wanted: list[str]) -> tuple[list[str], dict[str, str]]:
    """The signals every flight of both sides has, and why each other one is left out."""
    used, left = [], {}
    for s in wanted:
        lacking = [f.name for f in (*generated, *real) if s not in f.signals]
        if lacking:
            more = f" and {len(lacking) - 3} more" if len(lacking) > 3 else ""
            left[s] = f"lacking in {len(lacking)} flight(s): {', '.join(lacking[:3])}{more}"
        else:
            used.append(s)
    return used, left


def _weights(flights: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Every flight weighs the same within its side, and the two sides weigh the same."""
    w = np.empty(len(y))
    for side in (0, 1):
        m = y == side
        names, inv, counts = np.unique(flights[m], return_inverse=True, return_counts=True)
        w[m] = 1.0 / (counts[inv] * len(names))
    return w * len(y) / 2.0


def oof_probabilities(x: np.ndarray, y: np.ndarray, groups: np.ndarray, seed: int = 0,
                      folds: int = 5) -> np.ndarray:
    """Out-of-fold P(generated) per window: gradient boosting, folds by flight (StratifiedGroupKFold)."""
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.model_selection import StratifiedGroupKFold
    from threadpoolctl import threadpool_limits

    n_flights = min(len(np.unique(groups[y == k])) for k in (0, 1))
    k = max(2, min(folds, n_flights))
    cv = StratifiedGroupKFold(n_splits=k, shuffle=True, random_state=seed)
    p = np.full(len(y), np.nan)
    w = _weights(groups, y)
    # one thread: OpenMP's default of one thread per core is many times slower on these small tables
    # when the machine is shared, and the result does not depend on it
    with threadpool_limits(limits=1, user_api="openmp"):
        for train, test in cv.split(x, y, groups):
            if len(np.unique(y[train])) < 2:
                continue
            xtr, xte = quantize(x[train], x[test], MODEL["max_bins"])
            model = HistGradientBoostingClassifier(**MODEL, random_state=seed)
            model.fit(xtr, y[train], sample_weight=w[train])
            p[test] = model.predict_proba(xte)[:, 1]
    return p


def quantize(train: np.ndarray, test: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Each feature as its quantile bin (0 .. bins-1) among the training windows; NaN stays NaN.

    The same binning the classifier does itself, but unweighted and once: with sample weights,
    scikit-learn 1.9 bins by weighted percentiles, one sort per threshold (80 % of the check's time)."""
    qs = np.linspace(0, 1, bins + 1)[1:-1]
    out_tr, out_te = np.empty_like(train), np.empty_like(test)
    for j in range(train.shape[1]):
        col = train[:, j]
        ok = np.isfinite(col)
        edges = np.unique(np.quantile(col[ok], qs)) if ok.any() else np.array([])
        for src, dst in ((train, out_tr), (test, out_te)):
            v = src[:, j]
            dst[:, j] = np.where(np.isfinite(v), np.searchsorted(edges, v, side="right"), np.nan)
    return out_tr, out_te


def _auc(y: np.ndarray, s: np.ndarray) -> float:
    from sklearn.metrics import roc_auc_score

    ok = np.isfinite(s)
    if len(np.unique(y[ok])) < 2:
        return float("nan")
    return float(roc_auc_score(y[ok], s[ok]))


def flight_auc(table: pd.DataFrame, p: np.ndarray) -> float:
    """AUC over flights of each flight's mean out-of-fold window probability."""
    per = pd.DataFrame({"flight": table["flight"].to_numpy(), "y": (table["side"] == "generated").to_numpy(int),
                        "p": p}).groupby("flight").agg(y=("y", "first"), p=("p", "mean"))
    return _auc(per["y"].to_numpy(), per["p"].to_numpy())


def feature_columns(table: pd.DataFrame) -> list[str]:
    return [c for c in table.columns if "__" in c]


def feature_auc(table: pd.DataFrame) -> pd.DataFrame:
    """Each feature alone: window AUC of its values (generated high > 0.5), the medians of both
    sides and their ratio generated / real in linear units (std and power features are log10; NaN for
    the autocorrelations, compare their difference); sorted by |AUC - 0.5|, then how far apart."""
    y = (table["side"] == "generated").to_numpy(int)
    rows = []
    for c in feature_columns(table):
        v = table[c].to_numpy(np.float64)
        a = _auc(y, v)
        g, r = np.nanmedian(v[y == 1]), np.nanmedian(v[y == 0])
        kind = c.split("__")[1]
        logged = kind not in ("ac1", "dac1", "jitter")
        ratio = 10 ** (g - r) if logged else (g / r if r and kind == "jitter" else np.nan)
        rows.append({"feature": c, "auc": a, "generated": 10 ** g if logged else g,
                     "real": 10 ** r if logged else r, "ratio": ratio})
    out = pd.DataFrame(rows)
    if len(out):
        # ties (many features separate every window) by how far apart the medians are
        # (decades between the medians; for an autocorrelation, its difference: 1 counts as a decade)
        apart = np.abs(np.log10(out["ratio"].to_numpy(np.float64)))
        apart = np.where(np.isfinite(apart), apart, (out["generated"] - out["real"]).abs())
        out = out.assign(sep=(out["auc"] - 0.5).abs().round(3), apart=np.nan_to_num(apart))
        out = out.sort_values(["sep", "apart", "feature"], ascending=[False, False, True])
        out = out.drop(columns=["sep", "apart"]).reset_index(drop=True)
    return out


@dataclass
class PhaseResult:
    """The check on one phase's windows."""

    phase: str
    flights: dict[str, int]  # side -> flights with a window of this phase
    windows: dict[str, int]  # side -> windows
    window_auc: float = float("nan")
    flight_auc: float = float("nan")
    group_auc: dict[str, float] = field(default_factory=dict)  # signal group alone -> flight AUC
    features: pd.DataFrame | None = None  # feature_auc
    note: str = ""


@dataclass
class Comparison:
    """The check between generated flights and one log set (see :func:`compare`)."""

    log_set: str
    signals: list[str]
    rates: dict[str, float]
    left_out: dict[str, str]
    phases: dict[str, PhaseResult]
    notes: list[str]

    @property
    def flight_auc_by_phase(self) -> dict[str, float]:
        return {k: v.flight_auc for k, v in self.phases.items()}

    def report(self, top: int = 8) -> str:
        """A plain-text report: signals used and left out, AUC per phase, the most separating features."""
        lines = [f"== generated vs {self.log_set}",
                 "signals used (Hz): " + ", ".join(f"{s} {self.rates[s]:g}" for s in self.signals)]
        lines += [f"left out: {s} ({why})" for s, why in self.left_out.items()]
        lines += self.notes
        lines.append(f"{'phase':8} {'flights g/r':>12} {'windows g/r':>12} {'window AUC':>10} {'flight AUC':>10}")
        for ph in self.phases.values():
            lines.append(f"{ph.phase:8} {ph.flights['generated']:>5}/{ph.flights['real']:<6} "
                         f"{ph.windows['generated']:>5}/{ph.windows['real']:<6} {ph.window_auc:>10.3f} "
                         f"{ph.flight_auc:>10.3f}  {ph.note}")
        for ph in self.phases.values():
            if ph.features is None or not len(ph.features):
                continue
            lines.append(f"-- {ph.phase}: each signal group alone (flight AUC): "
                         + ", ".join(f"{g} {a:.2f}" for g, a in ph.group_auc.items()))
            lines.append(f"-- {ph.phase}: most separating features (window AUC alone; median generated / real)")
            for r in ph.features.head(top).itertuples():
                how = f"x{r.ratio:.2g}" if np.isfinite(r.ratio) else f"{r.generated - r.real:+.2f}"
                lines.append(f"   {r.feature:22} AUC {r.auc:.2f}  generated {r.generated:.3g}, real {r.real:.3g} ({how})")
        return "\n".join(lines)


def _phase_result(table: pd.DataFrame, phase: str, seed: int, folds: int, groups: bool) -> PhaseResult:
    sub = table if phase == "all" else table[table["phase"] == phase]
    gen = sub["side"] == "generated"
    res = PhaseResult(phase, {"generated": int(sub.loc[gen, "flight"].nunique()),
                              "real": int(sub.loc[~gen, "flight"].nunique())},
                      {"generated": int(gen.sum()), "real": int((~gen).sum())})
    if min(res.flights.values()) < 2:
        res.note = "too few flights (< 2 on a side)"
        return res
    cols = feature_columns(sub)
    y = gen.to_numpy(int)
    grp = sub["flight"].to_numpy()
    p = oof_probabilities(sub[cols].to_numpy(np.float64), y, grp, seed, folds)
    res.window_auc = _auc(y, p)
    res.flight_auc = flight_auc(sub, p)
    res.features = feature_auc(sub)
    if groups:
        for g, names in GROUPS.items():
            gc = [c for c in cols if c.split("__")[0] in names]
            if gc:
                pg = oof_probabilities(sub[gc].to_numpy(np.float64), y, grp, seed, folds)
                res.group_auc[g] = flight_auc(sub, pg)
    return res


def compare(generated: list[FlightSignals], real: list[FlightSignals], phases=PHASES, signals: list[str] | None = None,
            seed: int = 0, folds: int = 5, log_set: str = "real", groups: bool = True,
            window_s: float = WINDOW_S, step_s: float = STEP_S, max_hz: float = 50.0,
            features: tuple[str, ...] = FEATURES) -> Comparison:
    """The window check between generated flights and real ones (see the module doc).

    Signals that a flight of either side lacks are left out (named in ``left_out``); each used
    signal is compared at the common rate of :func:`common_rates`; ``features``: the kinds of
    :data:`FEATURES` the classifier sees (e.g. all but ``jitter``: the signals' values only)."""
    unknown = [k for k in features if k not in FEATURES]
    if unknown:
        raise ValueError(f"unknown feature {unknown[0]!r}; expected some of {', '.join(FEATURES)}")
    if not generated or not real:
        raise ValueError(f"the window check needs flights on both sides (generated {len(generated)}, "
                         f"{log_set} {len(real)})")
    gen = [FlightSignals(f.name, "generated", f.signals, f.sources, f.ground, f.altitude, f.notes,
                         getattr(f, "mission", None)) for f in generated]
    rl = [FlightSignals(f"{log_set}/{f.name}", "real", f.signals, f.sources, f.ground, f.altitude, f.notes)
          for f in real]
    paired = pair_phase_speed(gen, rl)
    used, left = usable_signals(gen, rl, signals or list(SIGNALS))
    rates = common_rates(gen + rl, used, max_hz)
    used = [s for s in used if s in rates]
    rates = {s: rates[s] for s in used}
    notes = [f"{f.name}: {n}" for f in rl for n in f.notes]
    if paired:
        n = sum(not f.phase_speed for f in gen)
        notes.append(f"phases without the horizontal speed (as their logs'): {n} generated flight(s) of the "
                     f"missions of {', '.join(paired)}")
    if not used:
        raise ValueError(f"no signal is common to every generated flight and every log of {log_set}: "
                         + "; ".join(f"{s} {why}" for s, why in left.items()))
    table = window_table(gen + rl, rates, window_s, step_s)
    table = table.drop(columns=[c for c in feature_columns(table) if c.split("__")[1] not in features])
    none = sorted({f.name for f in rl} - set(table["flight"]))
    if none:
        notes.append(f"no full {window_s:g} s window without a gap in: {', '.join(none)}")
    results = {ph: _phase_result(table, ph, seed, folds, groups) for ph in phases}
    return Comparison(log_set, used, rates, left, results, notes)


def markdown_table(results: list[Comparison], phases=PHASES) -> str:
    """Flight AUC (window AUC; flights generated/real) per log set x phase, as Markdown."""
    head = "| log set | signals | " + " | ".join(phases) + " |"
    lines = [head, "|" + "---|" * (len(phases) + 2)]
    for c in results:
        groups = [g for g, names in GROUPS.items() if any(s in c.signals for s in names)]
        cells = []
        for ph in phases:
            r = c.phases.get(ph)
            if r is None or not np.isfinite(r.flight_auc):
                cells.append(f"n/a ({r.flights['real'] if r else 0} real flights)")
            else:
                cells.append(f"{r.flight_auc:.2f} ({r.window_auc:.2f}; {r.flights['generated']}/{r.flights['real']})")
        lines.append(f"| {c.log_set} | {', '.join(groups)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.realism_windows", description=__doc__.split("\n")[0])
    p.add_argument("--dataset", required=True, help="a generated dataset (its normal flights)")
    p.add_argument("--logs", nargs="+", default=None, metavar="FILE_OR_DIR",
                   help="real logs, one log set per argument (a folder: its logs); default the three sets "
                   f"in {SHARED_DATA}")
    p.add_argument("--view", default="simulator", help="the dataset's view (default simulator)")
    p.add_argument("--flights", type=int, default=None, help="at most this many generated flights")
    p.add_argument("--phases", default="ground,hover,cruise", help="phases to report besides 'all' "
                   "(default ground,hover,cruise)")
    p.add_argument("--signals", default=None, help="signal groups or signals (position, velocity, attitude, "
                   "accelerometer, gyro, imu, baro, or e.g. roll); default all")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--top", type=int, default=8, help="features listed per phase (default 8)")
    p.add_argument("--no-groups", action="store_true", help="skip the per-signal-group AUC (faster)")
    p.add_argument("--no-timing", action="store_true", help="leave the timing jitter out of the features "
                   "(the signals' values only)")
    p.add_argument("--markdown", action="store_true", help="also print the AUC table as Markdown")
    args = p.parse_args(argv)
    try:
        wanted = select_signals(args.signals)
    except ValueError as exc:
        p.error(str(exc))
    phases = [x.strip() for x in args.phases.split(",") if x.strip()]
    bad = [x for x in phases if x not in PHASES]
    if bad:
        p.error(f"--phases: unknown phase {bad[0]!r}; expected some of ground, hover, cruise")
    phases = [*(x for x in phases if x != "all"), "all"]
    if not Path(args.dataset).is_dir():
        p.error(f"--dataset {args.dataset}: no such folder")
    sets = ({str(x): [x] for x in args.logs} if args.logs else {k: [v] for k, v in DEFAULT_LOG_SETS.items()})
    for paths in sets.values():
        for x in paths:
            if not Path(x).exists():
                p.error(f"--logs {x}: no such file or folder")
    generated = read_dataset(args.dataset, args.view, args.flights)
    if not generated:
        p.error(f"--dataset {args.dataset}: no normal flights in view {args.view}")
    results, failed = [], []
    for name, paths in sets.items():
        real = read_logs(paths, name)
        if not real:
            print(f"== {name}: no readable log (expected {', '.join(_suffixes())} files); skipped", file=sys.stderr)
            failed.append(name)
            continue
        try:
            c = compare(generated, real, phases, wanted, args.seed, log_set=name, groups=not args.no_groups,
                        features=tuple(k for k in FEATURES if not (args.no_timing and k == "jitter")))
        except ValueError as exc:
            print(f"== {name}: {exc}", file=sys.stderr)
            failed.append(name)
            continue
        results.append(c)
        print(c.report(args.top), flush=True)
        print()
    if args.markdown and results:
        print(markdown_table(results, phases))
    return 2 if failed else 0


def _suffixes() -> tuple[str, ...]:
    from scart_bench.generator.logs.importers import LOG_SUFFIXES

    return LOG_SUFFIXES


if __name__ == "__main__":
    raise SystemExit(main())
