"""How close generated flights are to real PX4 logs: rates, timing jitter, sensor noise, GPS accuracy.

    python -m perf.realism [--flights N] [--seed S] [--gps-accuracy LEVEL] [--sensor-profile P] [--timing T] [--markdown]
                           [--dataset DIR] [--view VIEW] [--logs DIR] [--ulog FILE ...] [--two-sample]
    python -m perf.realism --windows --dataset DIR [--logs FILE_OR_DIR ...] [--phases ground,hover,cruise] [--markdown]

``--windows`` runs the window-level realism check of :mod:`perf.realism_windows` (issue 47; every
other argument is its own), which replaces ``--two-sample``: that per-flight check was too weak to
see the tells a classifier on 10 s windows finds (docs/realism.md, "The window classifier").

Flies ``N`` default-mission normal flights (holding 12 s in hover after take-off), or reads up to
``N`` normal flights of a generated dataset (``--dataset``, its simulator view by default), and
reads the given ULogs (``--ulog`` files and every ``*.ulg`` of ``--logs``; by default every
``*.ulg`` in ``../shared/data/ulog`` next to the checkout), then prints one row per figure and
axis: the generated value (median over the flights), each log's value and the ratio generated /
log. ``--two-sample`` (superseded by ``--windows``; kept for the old figures) also prints the cross-validated AUC of a classifier that tells the generated
flights from the logs by their timing and noise figures (:func:`two_sample_auc`; 0.5: it cannot).

Figures, computed the same way on both sides:

- ``rate`` and ``jitter CV`` per topic: messages per second over the topic's span, and the
  coefficient of variation (std / mean) of the intervals between messages; ``first msg`` the
  time of the topic's first message after the start of the flight (log). Topics are matched by
  meaning (``highres_imu`` <-> ``sensor_combined``, ``gps_raw_int`` <-> ``vehicle_gps_position``,
  ...); a log without a topic falls back on a related one (``vehicle_angular_velocity`` and
  ``vehicle_acceleration`` for the IMU, ``sensor_gps`` for GPS, ``sensor_baro`` for the baro).
- Noise at hover: the IMU sampled at 50 Hz (the latest sample every 20 ms, as the MAVLink link
  streams it), minus its 1 s centred moving average (so manoeuvres do not count), std over the
  still samples: horizontal speed < 0.5 m/s, vertical < 0.3 m/s and yaw rate (1 s average)
  < 0.05 rad/s (no turn on the spot), airborne (> 1 m above the
  first position) when the log has such samples ("hover"), else on the ground ("ground": a bench
  log). Gyro x, y, z (rad/s), accelerometer x, y, z (m/s^2), magnetometer x, y, z (gauss).
- Baro altitude noise: the barometric altitude sampled at 10 Hz, minus its 1 s moving average,
  std over the same still samples (m).
- GPS accuracy: median reported ``eph`` / ``epv`` (m) over messages with a 3-D fix.
- Hover thrust: the median collective thrust demand (0-1: ``actuator_controls_0`` control[3], else
  ``vehicle_thrust_setpoint`` or ``vehicle_rates_setpoint``) over the still airborne samples; a
  generated flight has it in the uORB view (``--view uorb``). It is the vehicle's (its
  thrust-to-weight ratio), not a realism figure: the two-sample check leaves it out.

A log's rates are its logger's rates (the SD-card logging profile), not the rates PX4 streams
on the MAVLink link that the generator's topics follow; ``docs/realism.md`` explains which
differences are expected.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: real PX4 logs shipped next to the checkout
DEFAULT_ULOG_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ulog"

#: logical topic -> (generated topic names, ULog topic names), first found wins
TOPICS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "imu": (("highres_imu", "sensor_combined"), ("sensor_combined", "vehicle_imu")),
    "attitude": (("attitude", "vehicle_attitude"), ("vehicle_attitude",)),
    "local_position": (("local_position_ned", "vehicle_local_position"), ("vehicle_local_position",)),
    "global_position": (("global_position_int", "vehicle_global_position"), ("vehicle_global_position",)),
    "gps": (("gps_raw_int", "vehicle_gps_position", "sensor_gps"), ("vehicle_gps_position", "sensor_gps")),
    "baro": (("scaled_pressure", "vehicle_air_data"), ("vehicle_air_data", "sensor_baro")),
    "battery": (("battery_status",), ("battery_status",)),
    "actuators": (("actuator_outputs",), ("actuator_outputs",)),
}
IMU_HZ = 50.0
BARO_HZ = 10.0
HP_WINDOW_S = 1.0
STILL_H = 0.5  # m/s
STILL_V = 0.3  # m/s
STILL_YAW = 0.05  # rad/s, yaw rate averaged over HP_WINDOW_S
AIRBORNE_M = 1.0
EDGE_S = 0.5  # still samples this close to a moving one are left out
HOVER_S = 12.0  # the generated flights hold this long after take-off
#: noise figures of the IMU and magnetometer: (figure, Flight attribute), every axis
NOISE_AXES = tuple((f"{sensor} {axis} std {unit}", f"{attr}_{axis}")
                   for sensor, attr, unit in (("gyro", "gyro", "rad/s"), ("acc", "acc", "m/s2"), ("mag", "mag", "gauss"))
                   for axis in "xyz")


@dataclass
class Flight:
    """The series the figures need, in seconds from the start of the flight (or log)."""

    name: str
    times: dict[str, np.ndarray] = field(default_factory=dict)  # logical topic -> message times
    gyro_x: tuple[np.ndarray, np.ndarray] | None = None
    gyro_y: tuple[np.ndarray, np.ndarray] | None = None
    gyro_z: tuple[np.ndarray, np.ndarray] | None = None
    acc_x: tuple[np.ndarray, np.ndarray] | None = None
    acc_y: tuple[np.ndarray, np.ndarray] | None = None
    acc_z: tuple[np.ndarray, np.ndarray] | None = None
    mag_x: tuple[np.ndarray, np.ndarray] | None = None
    mag_y: tuple[np.ndarray, np.ndarray] | None = None
    mag_z: tuple[np.ndarray, np.ndarray] | None = None
    baro_alt: tuple[np.ndarray, np.ndarray] | None = None
    velocity: tuple[np.ndarray, np.ndarray] | None = None  # t, (n, 3) NED
    height: tuple[np.ndarray, np.ndarray] | None = None  # t, metres above the first position
    eph: np.ndarray | None = None
    epv: np.ndarray | None = None
    thrust: tuple[np.ndarray, np.ndarray] | None = None  # collective thrust demand, 0-1


def pressure_altitude(pa: np.ndarray) -> np.ndarray:
    """ISA altitude (m) of a static pressure (Pa)."""
    return 44330.0 * (1.0 - (np.asarray(pa, float) / 101325.0) ** (1.0 / 5.255))


# --- reading a ULog -------------------------------------------------------------------------------------
def _first(data: dict, names: tuple[str, ...]) -> tuple[str, dict] | None:
    for n in names:
        if n in data:
            return n, data[n]
    return None


def _col(d: dict, *names: str) -> np.ndarray | None:
    for n in names:
        if n in d:
            return np.asarray(d[n], dtype=float)
    return None


def ulog_topics(path: str | Path) -> dict[str, dict[str, np.ndarray]]:
    """A ULog's topics (first instance of each) as {topic: {field: array, "t": seconds from the log's start}}."""
    from pyulog import ULog

    ulog = ULog(str(path))
    start = int(ulog.start_timestamp)
    data: dict[str, dict] = {}
    for d in sorted(ulog.data_list, key=lambda d: d.multi_id):
        if d.name in data:
            continue
        ts = np.asarray(d.data["timestamp"], dtype=np.uint64).astype(np.int64)
        keep = ts > 0
        if not keep.any():
            continue
        row = {k: np.asarray(v)[keep] for k, v in d.data.items()}
        row["t"] = (ts[keep] - start) / 1e6
        data[d.name] = row
    return data


def read_ulog(path: str | Path) -> Flight:
    """The figures' series from a PX4 ULog."""
    return from_ulog_topics(Path(path).name, ulog_topics(path))


def from_ulog_topics(name: str, data: dict[str, dict[str, np.ndarray]]) -> Flight:
    """The figures' series from a ULog's topics (see :func:`ulog_topics`), whichever of them it has."""
    f = Flight(name)
    for logical, (_, names) in TOPICS.items():
        hit = _first(data, names)
        if hit is not None:
            f.times[logical] = hit[1]["t"]
    if "sensor_combined" in data:
        d = data["sensor_combined"]
        f.gyro_x, f.gyro_y, f.gyro_z = ((d["t"], _col(d, f"gyro_rad[{k}]")) for k in range(3))
        f.acc_x, f.acc_y, f.acc_z = ((d["t"], _col(d, f"accelerometer_m_s2[{k}]")) for k in range(3))
    else:
        if "vehicle_angular_velocity" in data:
            d = data["vehicle_angular_velocity"]
            f.gyro_x, f.gyro_y, f.gyro_z = ((d["t"], _col(d, f"xyz[{k}]")) for k in range(3))
        if "vehicle_acceleration" in data:
            d = data["vehicle_acceleration"]
            f.acc_x, f.acc_y, f.acc_z = ((d["t"], _col(d, f"xyz[{k}]")) for k in range(3))
    hit = _first(data, ("sensor_mag", "vehicle_magnetometer"))
    if hit is not None:
        d = hit[1]
        f.mag_x, f.mag_y, f.mag_z = ((d["t"], _col(d, axis, f"magnetometer_ga[{k}]"))
                                     for k, axis in enumerate("xyz"))
    if "vehicle_air_data" in data:
        d = data["vehicle_air_data"]
        f.baro_alt = d["t"], _col(d, "baro_alt_meter")
    elif "sensor_baro" in data:
        d = data["sensor_baro"]
        f.baro_alt = d["t"], pressure_altitude(_col(d, "pressure"))
    if "vehicle_local_position" in data:
        d = data["vehicle_local_position"]
        f.velocity = d["t"], np.column_stack([_col(d, "vx"), _col(d, "vy"), _col(d, "vz")])
        z = _col(d, "z")
        f.height = d["t"], z[0] - z
    if "actuator_controls_0" in data:
        d = data["actuator_controls_0"]
        f.thrust = d["t"], _col(d, "control[3]")
    elif "vehicle_thrust_setpoint" in data:  # PX4 1.13 and later: body z, up is negative
        d = data["vehicle_thrust_setpoint"]
        f.thrust = d["t"], -_col(d, "xyz[2]")
    elif "vehicle_rates_setpoint" in data:
        d = data["vehicle_rates_setpoint"]
        f.thrust = d["t"], -_col(d, "thrust_body[2]")
    hit = _first(data, ("vehicle_gps_position", "sensor_gps"))
    if hit is not None:
        d = hit[1]
        fix = _col(d, "fix_type")
        ok = fix >= 3 if fix is not None else np.ones(len(d["t"]), bool)
        f.eph, f.epv = _col(d, "eph")[ok], _col(d, "epv")[ok]
    return f


# --- generated flights ----------------------------------------------------------------------------------
def from_tables(name: str, tables: dict) -> Flight:
    """The figures' series from one generated flight's topic tables ({topic: DataFrame}, MAVLink names)."""
    f = Flight(name)
    t = {k: df["Timestamp"].to_numpy(np.int64) / 1e6 for k, df in tables.items() if len(df)}
    for logical, (names, _) in TOPICS.items():
        hit = _first(t, names)
        if hit is not None:
            f.times[logical] = hit[1]
    if "highres_imu" in tables:
        d = tables["highres_imu"]
        ti = t["highres_imu"]
        f.gyro_x, f.gyro_y, f.gyro_z = ((ti, d[f"{a}gyro"].to_numpy(float)) for a in "xyz")
        f.acc_x, f.acc_y, f.acc_z = ((ti, d[f"{a}acc"].to_numpy(float)) for a in "xyz")
        f.mag_x, f.mag_y, f.mag_z = ((ti, d[f"{a}mag"].to_numpy(float)) for a in "xyz")
    elif "sensor_combined" in tables:  # the uORB view
        d = tables["sensor_combined"]
        ti = t["sensor_combined"]
        f.gyro_x, f.gyro_y, f.gyro_z = ((ti, d[f"gyro_rad_{k}"].to_numpy(float)) for k in range(3))
        f.acc_x, f.acc_y, f.acc_z = ((ti, d[f"accelerometer_m_s2_{k}"].to_numpy(float)) for k in range(3))
    if "sensor_mag" in tables and f.mag_x is None:
        d = tables["sensor_mag"]
        f.mag_x, f.mag_y, f.mag_z = ((t["sensor_mag"], d[a].to_numpy(float)) for a in "xyz")
    if "scaled_pressure" in tables:
        d = tables["scaled_pressure"]
        f.baro_alt = t["scaled_pressure"], pressure_altitude(d["press_abs"].to_numpy(float) * 100.0)
    elif "vehicle_air_data" in tables:
        f.baro_alt = t["vehicle_air_data"], tables["vehicle_air_data"]["baro_alt_meter"].to_numpy(float)
    for name in ("local_position_ned", "vehicle_local_position"):
        if name in tables:
            d = tables[name]
            f.velocity = t[name], d[["vx", "vy", "vz"]].to_numpy(float)
            z = d["z"].to_numpy(float)
            f.height = t[name], z[0] - z
            break
    if "actuator_controls_0" in tables:  # the uORB view of a flight flown with it
        f.thrust = t["actuator_controls_0"], tables["actuator_controls_0"]["control_3"].to_numpy(float)
    for name in ("gps_raw_int", "vehicle_gps_position"):
        if name in tables:
            d = tables[name]
            ok = d["fix_type"].to_numpy(float) >= 3
            f.eph, f.epv = d["eph"].to_numpy(float)[ok], d["epv"].to_numpy(float)[ok]
            break
    return f


def generated_flights(n: int, seed: int = 0, gps_accuracy: str | None = None, timing: str | None = None,
                      view: str = "simulator", sensor_profile: str | None = None) -> list[Flight]:
    """Fly ``n`` normal default-mission flights (in one batch) and read them like a log, by their
    ``view`` (``simulator``: MAVLink names and rates; ``uorb``: flown with the uORB view, PX4's topics
    at a log's rates; ``navigator``: the same as the simulator view, no attack).

    The flights hold ``HOVER_S`` s after take-off (instead of 1 s) so that they have a hover.
    """
    import dataclasses

    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.plan import normal_seeds
    from scart_bench.generator.telemetry.tables import flight_views, uorb_stream_tables
    from scart_bench.generator.telemetry.uorb import uorb_view

    config = FlightConfig(uorb=view == "uorb")
    if timing is not None:
        config = dataclasses.replace(config, timing=timing)
    # hold HOVER_S (the default mission holds takeoff_hold_s) so there is a long hover to measure
    config = dataclasses.replace(config, mission=dataclasses.replace(config.mission, takeoff_hold_s=HOVER_S))
    if gps_accuracy is not None:
        from scart_bench.generator.params import with_gps_accuracy

        config = with_gps_accuracy(config, gps_accuracy)
    if sensor_profile is not None:
        from scart_bench.generator.params import with_sensor_profile

        config = with_sensor_profile(config, sensor_profile)
    batch = simulate(normal_seeds(seed, n), config)
    flights = []
    for i in range(n):
        nav, sim = flight_views(batch, i, ())
        tables = {"simulator": sim, "navigator": nav}.get(view) or uorb_view(sim, uorb_stream_tables(batch, i))
        flights.append(from_tables(f"generated-{i}", tables))
    return flights


def dataset_flights(path: str | Path, n: int | None = None, view: str = "simulator") -> list[Flight]:
    """Up to ``n`` normal flights of a generated dataset, read like a log (one view of each:
    ``simulator``, ``navigator`` or ``uorb``)."""
    from scart_bench.dataset import open_dataset

    ds = open_dataset(path)
    m = ds.manifest
    ids = m.loc[m["mode"] == "normal", "flight_id"].astype(str).tolist()[:n]
    flights = []
    for fid in ids:
        tables = {t: ds.topic(fid, t, view) for t in ds.topics(fid, view)}
        flights.append(from_tables(f"{Path(path).name}/{fid}", tables))
    return flights


# --- figures --------------------------------------------------------------------------------------------
def resample(t: np.ndarray, x: np.ndarray, hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The latest sample at every tick of a ``hz`` clock (as a link streams a topic)."""
    order = np.argsort(t, kind="stable")
    t, x = t[order], x[order]
    grid = np.arange(t[0], t[-1], 1.0 / hz)
    idx = np.searchsorted(t, grid, side="right") - 1
    return grid, x[idx]


def highpass(x: np.ndarray, hz: float) -> np.ndarray:
    """``x`` minus its centred moving average over HP_WINDOW_S (edges use the shorter window)."""
    w = max(3, int(round(HP_WINDOW_S * hz)) | 1)
    kernel = np.ones(w)
    num = np.convolve(x, kernel, mode="same")
    den = np.convolve(np.ones_like(x), kernel, mode="same")
    return x - num / den


def still_mask(f: Flight, grid: np.ndarray) -> tuple[np.ndarray, str]:
    """Still samples of ``grid`` (airborne ones when there are at least 2 s of them) and the phase."""
    if f.velocity is None:
        return np.ones(len(grid), bool), "all"
    tv, v = f.velocity
    vi = np.column_stack([np.interp(grid, tv, v[:, k]) for k in range(3)])
    still = (np.hypot(vi[:, 0], vi[:, 1]) < STILL_H) & (np.abs(vi[:, 2]) < STILL_V)
    if f.gyro_z is not None and f.gyro_z[1] is not None:  # no yaw turn on the spot either
        tg, g = resample(*f.gyro_z, IMU_HZ)
        slow = g - highpass(g, IMU_HZ)
        still &= np.abs(np.interp(grid, tg, slow)) < STILL_YAW
    # leave out samples near a moving one
    dt = np.median(np.diff(grid)) if len(grid) > 1 else 1.0
    pad = int(round(EDGE_S / dt))
    if pad:
        moving = np.convolve((~still).astype(float), np.ones(2 * pad + 1), mode="same") > 0
        still &= ~moving
    still &= (grid > grid[0] + HP_WINDOW_S) & (grid < grid[-1] - HP_WINDOW_S)
    if f.height is not None:
        air = np.interp(grid, *f.height) > AIRBORNE_M
        if (still & air).sum() * dt >= 2.0:
            return still & air, "hover"
    return still, "ground"


def noise(f: Flight, series: tuple[np.ndarray, np.ndarray] | None, hz: float) -> tuple[float, str]:
    if series is None or series[1] is None or len(series[0]) < 10:
        return math.nan, ""
    grid, x = resample(series[0], series[1], hz)
    mask, phase = still_mask(f, grid)
    if mask.sum() < 10:
        return math.nan, phase
    return float(np.std(highpass(x, hz)[mask])), phase


def figures(f: Flight) -> dict[str, tuple[float, str]]:
    """Every figure of one flight or log: name -> (value, note)."""
    out: dict[str, tuple[float, str]] = {}
    for logical in TOPICS:
        t = f.times.get(logical)
        if t is None or len(t) < 3:
            for k in ("rate Hz", "jitter CV", "first msg s"):
                out[f"{logical} {k}"] = (math.nan, "")
            continue
        t = np.sort(t)
        dt = np.diff(t)
        out[f"{logical} rate Hz"] = ((len(t) - 1) / (t[-1] - t[0]), "")
        cv = float(dt.std() / dt.mean())
        out[f"{logical} jitter CV"] = (cv if cv > 1e-9 else 0.0, "")  # float rounding of a perfect clock: 0
        out[f"{logical} first msg s"] = (float(t[0]), "")
    for name, attr in NOISE_AXES:
        out[name] = noise(f, getattr(f, attr), IMU_HZ)
    out["baro alt std m"] = noise(f, f.baro_alt, BARO_HZ)
    out["gps eph m"] = (float(np.median(f.eph)) if f.eph is not None and len(f.eph) else math.nan, "")
    out["gps epv m"] = (float(np.median(f.epv)) if f.epv is not None and len(f.epv) else math.nan, "")
    out["hover thrust 0-1"] = hover_thrust(f)
    return out


def hover_thrust(f: Flight) -> tuple[float, str]:
    """The median collective thrust demand (0-1) over the still airborne samples at 10 Hz: the hover
    throttle, a property of the vehicle (its thrust-to-weight ratio); NaN without a hover."""
    if f.thrust is None or f.thrust[1] is None or len(f.thrust[0]) < 10:
        return math.nan, ""
    grid, x = resample(f.thrust[0], f.thrust[1], BARO_HZ)
    mask, phase = still_mask(f, grid)
    if phase != "hover" or mask.sum() < 10:
        return math.nan, phase
    return float(np.median(x[mask])), phase


def _fmt(x: float) -> str:
    if x is None or not np.isfinite(x):
        return "-"
    if x == 0:
        return "0"
    return f"{x:.3g}" if abs(x) >= 1e-3 else f"{x:.2e}"


def _ratio(a: float, b: float) -> str:
    if not (np.isfinite(a) and np.isfinite(b)) or b == 0:
        return "-"
    return f"{a / b:.2f}"


def table(generated: list[Flight], logs: list[Flight], markdown: bool = False) -> str:
    """The side-by-side table: generated (median over flights), then each log and the ratio."""
    gen = [figures(f) for f in generated]
    real = [figures(f) for f in logs]
    names = list(gen[0] if gen else real[0])
    header = ["figure", f"generated (n={len(generated)})"]
    for f in logs:
        short = f.name.removesuffix(".ulg")[:22]
        header += [short, "gen/log"]
    rows = []
    for name in names:
        vals = [v[name][0] for v in gen]
        g = float(np.nanmedian(vals)) if vals and not all(np.isnan(vals)) else math.nan
        phase = next((v[name][1] for v in gen if v[name][1]), "")
        row = [name, _fmt(g) + (f" ({phase})" if phase else "")]
        for r in real:
            value, note = r[name]
            row += [_fmt(value) + (f" ({note})" if note else ""), _ratio(g, value)]
        rows.append(row)
    if markdown:
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        return "\n".join(lines)
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    fmt = lambda r: "  ".join(str(x).ljust(w) if i == 0 else str(x).rjust(w)  # noqa: E731
                              for i, (x, w) in enumerate(zip(r, widths)))
    return "\n".join([fmt(header), "  ".join("-" * w for w in widths)] + [fmt(r) for r in rows])


#: the per-flight figures the two-sample check compares: timing (jitter, late topics) and noise
TWO_SAMPLE_FEATURES = (
    "imu jitter CV", "attitude jitter CV", "local_position jitter CV", "gps jitter CV", "baro jitter CV",
    "battery jitter CV", "gps first msg s", "global_position first msg s",
    *(name for name, _ in NOISE_AXES), "baro alt std m", "gps eph m", "gps epv m",
)


def two_sample_features(flights: list[Flight]) -> np.ndarray:
    """(n_flights, n_features) log10 of the :data:`TWO_SAMPLE_FEATURES` (NaN where a flight lacks one;
    0, a perfect clock, counts as 1e-4)."""
    rows = []
    for f in flights:
        fig = figures(f)
        rows.append([fig[name][0] for name in TWO_SAMPLE_FEATURES])
    x = np.asarray(rows, dtype=float)
    return np.log10(np.maximum(x, 1e-4))


def two_sample_auc(generated: list[Flight], logs: list[Flight], repeats: int = 20, seed: int = 0) -> float:
    """Cross-validated ROC AUC of a logistic regression telling generated flights from real logs by
    their timing and noise figures (median-imputed, standardised, classes weighted alike): 0.5
    means it cannot tell them apart, 1.0 that every flight gives itself away. Stratified k-fold
    (k = at most 5 and the smaller class), out-of-fold probabilities, averaged over ``repeats``
    shuffles."""
    from sklearn.impute import SimpleImputer
    from sklearn.linear_model import LogisticRegression
    from sklearn.metrics import roc_auc_score
    from sklearn.model_selection import StratifiedKFold, cross_val_predict
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    x = np.vstack([two_sample_features(generated), two_sample_features(logs)])
    y = np.r_[np.zeros(len(generated)), np.ones(len(logs))]
    x = x[:, ~np.isnan(x).all(axis=0)]  # a figure no flight has
    k = int(min(5, len(generated), len(logs)))
    if k < 2:
        raise ValueError("the two-sample check needs at least 2 generated flights and 2 logs")
    aucs = []
    for r in range(repeats):
        model = make_pipeline(SimpleImputer(strategy="median", keep_empty_features=True), StandardScaler(),
                              LogisticRegression(C=1.0, class_weight="balanced", max_iter=1000))
        folds = StratifiedKFold(n_splits=k, shuffle=True, random_state=seed + r)
        p = cross_val_predict(model, x, y, cv=folds, method="predict_proba")[:, 1]
        aucs.append(roc_auc_score(y, p))
    return float(np.mean(aucs))


def main(argv: list[str] | None = None) -> int:
    import sys

    argv = list(sys.argv[1:] if argv is None else argv)
    if "--windows" in argv:  # the window-level check (issue 47): its own arguments
        from perf.realism_windows import main as windows_main

        argv.remove("--windows")
        return windows_main(argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--flights", type=int, default=8, help="generated normal flights (default 8)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gps-accuracy", default=None,
                   help="GPS accuracy level of the generated flights (default: the generator's default)")
    p.add_argument("--sensor-profile", default=None, choices=("gazebo", "rflymad"),
                   help="magnetometer and barometer noise of the flown flights (default gazebo)")
    p.add_argument("--timing", default=None, choices=("ideal", "realistic"),
                   help="message timing of the generated flights (generator.telemetry.timing; default: the generator's)")
    p.add_argument("--dataset", default=None, help="read up to --flights normal flights of this generated dataset "
                   "instead of flying them")
    p.add_argument("--view", default="simulator", choices=("simulator", "navigator", "uorb"),
                   help="the view of the flights read (--dataset) or flown (uorb: flown with the uORB view, "
                   "PX4's topics at a log's rates); default simulator")
    p.add_argument("--logs", default=None, help=f"a folder of PX4 ULogs (its *.ulg; default {DEFAULT_ULOG_DIR} "
                   "when no --ulog is given)")
    p.add_argument("--ulog", nargs="*", default=None, help="PX4 ULog files")
    p.add_argument("--markdown", action="store_true", help="print a Markdown table")
    p.add_argument("--two-sample", action="store_true",
                   help="superseded by --windows (too weak: 20 per-flight figures); also print the two-sample "
                   "classifier's cross-validated AUC (generated vs logs)")
    p.add_argument("--windows", action="store_true",
                   help="run the window-level realism check instead (perf.realism_windows; its own arguments: "
                   "--dataset DIR [--logs ...] [--phases ...] [--markdown]); replaces --two-sample")
    args = p.parse_args(argv)
    if args.flights < 1:
        p.error("--flights must be at least 1")
    paths = [Path(x) for x in args.ulog or ()]
    if args.logs is not None:
        if not Path(args.logs).is_dir():
            p.error(f"--logs {args.logs}: no such folder")
        paths += sorted(Path(args.logs).glob("*.ulg"))
    elif args.ulog is None:
        paths = sorted(DEFAULT_ULOG_DIR.glob("*.ulg"))
    missing = [str(x) for x in paths if not x.is_file()]
    if missing:
        p.error(f"no such ULog file: {missing[0]}")
    logs = []
    for path in paths:
        try:
            logs.append(read_ulog(path))
        except Exception as exc:  # a damaged log: say which and go on with the others
            print(f"{path}: cannot read it as a ULog ({type(exc).__name__}: {exc}); left out")
    if args.dataset is not None:
        generated = dataset_flights(args.dataset, args.flights, args.view)
        if not generated:
            p.error(f"--dataset {args.dataset}: no normal flights")
    else:
        generated = generated_flights(args.flights, args.seed, args.gps_accuracy, args.timing, args.view,
                                      args.sensor_profile)
    print(table(generated, logs, markdown=args.markdown))
    if args.two_sample:
        auc = two_sample_auc(generated, logs)
        print(f"\ntwo-sample AUC (generated n={len(generated)} vs logs n={len(logs)}; 0.5 = indistinguishable): "
              f"{auc:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
