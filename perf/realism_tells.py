"""The five tells of issue 47 (item 5) by which generated flights give themselves away, measured.

    python -m perf.realism_tells [--dataset DIR] [--flights N] [--seed S] [--view simulator|navigator]
                                 [--logs FILE_OR_DIR ...] [--markdown]

Reads up to ``N`` normal flights of a generated dataset (``--dataset``; its simulator view unless
``--view`` says otherwise), or flies ``N`` default flights in-process, and the real logs (by default
every ``*.ulg`` of ``../shared/data/ulog`` and every ``*.bin`` of ``../shared/data/dataflash`` and
its ``fleet/``), each read with the project's importers (``generator.logs.importers``), its
quantities found by meaning (``generator.scart.meanings``) and its phases by
``generator.logs.phases.flight_phases``. It prints, per log set (generated, PX4 ULogs, ArduCopter
DataFlash), the median over flights of:

(a) **roll / pitch wander at hover**: attitude resampled to 10 Hz (the latest sample every 100 ms,
    ArduCopter's ATT rate), cut in 10 s windows of the ``cruise`` phase with horizontal speed
    under 1 m/s; per window the standard deviation (deg) and the share of its power below 0.5 Hz.
(b) **accelerometer noise at hover**: x/y/z resampled to 50 Hz (the MAVLink view's and
    ArduCopter's IMU rate; PX4's 250 Hz IMU is taken every 20 ms), in the same 10 s windows: the
    lag-1 autocorrelation of the window minus its mean, and the standard deviation of first
    differences (m/s^2), the sample-to-sample noise.
(c) **baro timing jitter**: the coefficient of variation of the intervals between baro messages
    (``scaled_pressure`` / ArduCopter ``BARO`` / PX4 ``vehicle_air_data``), and their std (ms),
    over the whole flight; a gap over 1 s (a logging gap) is left out.
(d) **hover before the climb**: seconds from leaving the ground (the first airborne phase row)
    to the start of the first horizontal leg (horizontal speed over 1 m/s for 1 s), and the
    airborne still time before it (horizontal speed < 0.5 m/s, vertical < 0.3 m/s).
(e) **accelerometer noise on the ground**: (b)'s std of first differences over the ``landed``
    rows (10 s windows), with motors armed where the log says so (generated: the setpoint's armed
    flag; ArduCopter: EV armed/disarmed; PX4: actuator_armed), else every ground window.

Like is compared with like: the same resampling, windows and phase rule on every side.
"""

from __future__ import annotations

import argparse
import glob
import logging
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
WINDOW_S = 10.0
ATT_HZ = 10.0
IMU_HZ = 50.0
GAP_S = 1.0
STILL_H = 1.0  # m/s, hover windows
LEG_SPEED = 1.0  # m/s, start of the first horizontal leg


def default_logs() -> list[Path]:
    pats = ["ulog/*.ulg", "dataflash/*.bin", "dataflash/fleet/*.bin"]
    return [Path(p) for pat in pats for p in sorted(glob.glob(str(SHARED / pat)))]


# --- finding quantities by meaning ---------------------------------------------------------------
def _find(tables: dict[str, pd.DataFrame], quantity: str, field: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(t s, values) of the candidate of ``quantity.field`` (generator.scart.meanings) the log has
    most rows of (a ULog logs ``sensor_accel`` at 1 Hz beside ``sensor_combined`` at 250 Hz)."""
    from scart_bench.generator.scart.meanings import QUANTITIES

    best = None
    for cand in QUANTITIES[quantity][field]:
        topic, _, name = cand.partition(".")
        df = tables.get(topic)
        if df is not None and name in df.columns and len(df) > 2 and (best is None or len(df) > len(best[0])):
            best = df, name
    if best is None:
        return None
    v = best[0][best[1]].to_numpy(np.float64)
    ok = np.isfinite(v)
    return best[0]["Timestamp"].to_numpy(np.int64)[ok] / 1e6, v[ok]


def _attitude_deg(tables) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """roll and pitch in degrees: ArduPilot's ATT (deg), the MAVLink attitude (rad), PX4's quaternion."""
    out = {}
    if "vehicle_attitude" in tables and "q_0" in tables["vehicle_attitude"]:
        df = tables["vehicle_attitude"]
        w, x, y, z = (df[f"q_{i}"].to_numpy(float) for i in range(4))
        t = df["Timestamp"].to_numpy(np.int64) / 1e6
        out["roll"] = t, np.degrees(np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)))
        out["pitch"] = t, np.degrees(np.arcsin(np.clip(2 * (w * y - z * x), -1, 1)))
        return out
    for f in ("roll", "pitch"):
        got = _find(tables, "attitude", f)
        if got is None:
            continue
        t, v = got
        deg = "att" in tables and f.capitalize() in tables["att"].columns or np.nanmax(np.abs(v)) > 3.2
        out[f] = t, v if deg else np.degrees(v)
    return out


def _velocity(tables) -> tuple[np.ndarray, np.ndarray] | None:
    """(t, (n, 3) NED m/s) of the estimate's velocity."""
    parts = [_find(tables, "velocity", f) for f in ("vn", "ve", "vd")]
    if any(p is None for p in parts) or not (len(parts[0][0]) == len(parts[1][0]) == len(parts[2][0])):
        return None
    v = np.column_stack([p[1] for p in parts])
    if np.nanmax(np.abs(v[:, :2])) > 100:  # cm/s (MAVLink GLOBAL_POSITION_INT)
        v = v / 100.0
    return parts[0][0], v


def _baro_times(tables) -> np.ndarray | None:
    for topic in ("scaled_pressure", "baro", "vehicle_air_data", "sensor_baro"):
        if topic in tables and len(tables[topic]) > 10:
            return tables[topic]["Timestamp"].to_numpy(np.int64) / 1e6
    return None


def _armed(tables, grid: np.ndarray) -> np.ndarray | None:
    """Armed at each grid time (s), where the log says."""
    if "setpoint" in tables and "armed" in tables["setpoint"]:
        df = tables["setpoint"]
        return _hold(df["Timestamp"].to_numpy() / 1e6, df["armed"].to_numpy(float), grid) > 0.5
    if "actuator_armed" in tables:
        df = tables["actuator_armed"]
        return _hold(df["Timestamp"].to_numpy() / 1e6, df["armed"].to_numpy(float), grid) > 0.5
    if "ev" in tables:
        df = tables["ev"]
        ids = df["Id"].to_numpy(int)
        keep = np.isin(ids, (10, 11))
        if keep.any():
            state = (ids[keep] == 10).astype(float)
            t = df["Timestamp"].to_numpy()[keep] / 1e6
            return _hold(np.r_[0.0, t], np.r_[0.0, state], grid) > 0.5
    return None


def _hold(t: np.ndarray, v: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The latest value at each grid time (the first one before it starts)."""
    i = np.searchsorted(t, grid, side="right") - 1
    return v[np.clip(i, 0, len(v) - 1)]


def _resample(t: np.ndarray, v: np.ndarray, hz: float) -> tuple[np.ndarray, np.ndarray]:
    grid = np.arange(t[0], t[-1], 1.0 / hz)
    return grid, _hold(t, v, grid)


# --- the figures --------------------------------------------------------------------------------
def _windows(grid: np.ndarray, mask: np.ndarray, hz: float, t_src: np.ndarray) -> list[slice]:
    """Consecutive WINDOW_S (10 s, ``--window``) runs of ``mask`` on ``grid`` with no source gap over GAP_S."""
    n = int(WINDOW_S * hz)
    gap = np.zeros(grid.size, bool)
    big = np.flatnonzero(np.diff(t_src) > GAP_S)
    for i in big:
        gap |= (grid > t_src[i]) & (grid < t_src[i + 1])
    ok = mask & ~gap
    out, i = [], 0
    while i + n <= grid.size:
        if ok[i:i + n].all():
            out.append(slice(i, i + n))
            i += n
        else:
            i += int(np.flatnonzero(~ok[i:i + n])[-1]) + 1
    return out


def _lag1(x: np.ndarray) -> float:
    x = x - x.mean()
    d = float(np.dot(x, x))
    return float(np.dot(x[1:], x[:-1]) / d) if d > 0 else np.nan


def _lowfreq_share(x: np.ndarray, hz: float, f_hi: float = 0.5) -> float:
    x = x - x.mean()
    p = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(x.size, 1.0 / hz)
    tot = p[1:].sum()
    return float(p[1:][f[1:] <= f_hi].sum() / tot) if tot > 0 else np.nan


def _acc_figures(out: dict, key: str, ax: str, name: str, x: np.ndarray, ws: list[slice]) -> None:
    if not ws:
        return
    out[f"{key} acc {ax} lag-1 autocorr ({name})"] = float(np.median([_lag1(x[w]) for w in ws]))
    out[f"{key} acc {ax} diff std m/s2 ({name})"] = float(np.median([np.diff(x[w]).std() for w in ws]))


def measure(tables: dict[str, pd.DataFrame]) -> dict[str, float]:
    """The five tells of one flight (NaN where the log lacks what a figure needs)."""
    from scart_bench.generator.logs.phases import flight_phases

    out: dict[str, float] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            ph = flight_phases(tables)
        except ValueError:
            return out
    pt = ph["Timestamp"].to_numpy() / 1e6
    pcode = ph["phase"].to_numpy()
    vel = _velocity(tables)

    def phase_at(grid):
        return _hold(pt, pcode, grid)

    def hspeed_at(grid):
        if vel is None:
            return np.zeros(grid.size)
        return _hold(vel[0], np.hypot(vel[1][:, 0], vel[1][:, 1]), grid)

    # (a) roll / pitch at hover
    att = _attitude_deg(tables)
    for f in ("roll", "pitch"):
        if f not in att:
            continue
        t, v = att[f]
        grid, x = _resample(t, v, ATT_HZ)
        hov = (phase_at(grid) == "cruise") & (hspeed_at(grid) < STILL_H)
        ws = _windows(grid, hov, ATT_HZ, t)
        if ws:
            out[f"a {f} std deg (hover)"] = float(np.median([x[w].std() for w in ws]))
            out[f"a {f} power <0.5 Hz share"] = float(np.median([_lowfreq_share(x[w], ATT_HZ) for w in ws]))
    # (b) and (e) accelerometer
    for ax in ("x", "y", "z"):
        got = _find(tables, "imu", f"{ax}acc")
        if got is None:
            continue
        t, v = got
        grid, x = _resample(t, v, IMU_HZ)
        phase = phase_at(grid)
        hov = (phase == "cruise") & (hspeed_at(grid) < STILL_H)
        for name, mask in (("hover", hov), ("ground", phase == "landed")):
            if name == "ground":
                armed = _armed(tables, grid)
                if armed is not None:
                    _acc_figures(out, "e", ax, "ground armed", x, _windows(grid, mask & armed, IMU_HZ, t))
                    mask, name = mask & ~armed, "ground disarmed"
            _acc_figures(out, "e" if name.startswith("ground") else "b", ax, name, x,
                         _windows(grid, mask, IMU_HZ, t))
    # (c) baro timing
    bt = _baro_times(tables)
    if bt is not None:
        d = np.diff(np.sort(bt))
        d = d[(d > 0) & (d < GAP_S)]
        if d.size > 10:
            out["c baro interval CV"] = float(d.std() / d.mean())
            out["c baro interval std ms"] = float(1e3 * d.std())
            out["c baro rate Hz"] = float(1.0 / d.mean())
    # (d) hover before the climb
    air = np.flatnonzero(pcode != "landed")
    if air.size:
        armed = _armed(tables, pt)
        if armed is not None and armed[: air[0] + 1].any():
            first = int(np.flatnonzero(armed[: air[0] + 1])[0])
            out["d armed on the ground before take-off s"] = float(pt[air[0]] - pt[first])
    if air.size and vel is not None:
        t_off = pt[air[0]]
        tv, vv = vel
        h = np.hypot(vv[:, 0], vv[:, 1])
        after = tv >= t_off
        fast = after & (h > LEG_SPEED)
        # the first 1 s run of speed over LEG_SPEED
        leg = np.nan
        idx = np.flatnonzero(fast)
        for i in idx:
            j = np.searchsorted(tv, tv[i] + 1.0)
            if j <= len(tv) and fast[i:j].all():
                leg = tv[i]
                break
        if np.isfinite(leg):
            out["d airborne to first leg s"] = float(leg - t_off)
            seg = after & (tv < leg)
            dt = np.diff(tv, append=tv[-1])
            still = seg & (h < 0.5) & (np.abs(vv[:, 2]) < 0.3) & (dt < GAP_S)
            out["d still hover before first leg s"] = float(dt[still].sum())
    return out


# --- flights and logs ----------------------------------------------------------------------------
def generated_tables(dataset: str | None, n: int, seed: int, view: str, hold_s: float | None = None
                     ) -> list[tuple[str, dict]]:
    """(name, {topic: table}) of up to ``n`` normal generated flights (a dataset's, or default
    flights flown here, holding ``hold_s`` at the take-off point if given: 12 s fits a 10 s hover
    window, which the default hold does not)."""
    if dataset:
        from scart_bench.dataset import open_dataset

        ds = open_dataset(dataset)
        m = ds.manifest
        ids = m.loc[m["mode"] == "normal", "flight_id"].astype(str).tolist()[:n]
        return [(fid, {t: ds.topic(fid, t, view) for t in ds.topics(fid, view)}) for fid in ids]
    import dataclasses

    from scart_bench.generator.engine.simulate import FlightConfig, simulate
    from scart_bench.generator.plan import normal_seeds
    from scart_bench.generator.telemetry.tables import flight_views

    cfg = FlightConfig()
    if hold_s is not None:
        cfg = dataclasses.replace(cfg, mission=dataclasses.replace(cfg.mission, takeoff_hold_s=hold_s))
    batch = simulate(normal_seeds(seed, n), cfg)
    out = []
    for i in range(n):
        nav, sim = flight_views(batch, i, ())
        tables = sim if view == "simulator" else nav
        if "setpoint" not in tables:
            tables = {**tables, "setpoint": sim["setpoint"]}
        out.append((f"flown-{i}", tables))
    return out


def log_tables(path: Path) -> dict[str, pd.DataFrame] | None:
    from scart_bench.generator.logs.importers import load_flight_file

    logging.disable(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return load_flight_file(path, allow_corrupt=True)
    except Exception as exc:  # a log a reader cannot take is said and skipped
        print(f"# {path.name}: not read ({exc})")
        return None
    finally:
        logging.disable(logging.NOTSET)


def log_set(path: Path) -> str:
    return "PX4 ULog" if path.suffix == ".ulg" else "ArduCopter"


def summarise(rows: dict[str, list[dict[str, float]]]) -> pd.DataFrame:
    """figure x log set: the median over the set's flights (n flights with the figure in brackets)."""
    keys = sorted({k for fl in rows.values() for r in fl for k in r})
    table = {}
    for name, fl in rows.items():
        col = {}
        for k in keys:
            vals = [r[k] for r in fl if k in r and np.isfinite(r[k])]
            col[k] = f"{np.median(vals):.4g} ({len(vals)})" if vals else "-"
        table[name] = col
    return pd.DataFrame(table)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dataset", default=None, help="a generated dataset (default: fly --flights here)")
    p.add_argument("--flights", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--hold", type=float, default=None,
                   help="flown here: hover hold after take-off, s (default: the mission's; 12 makes 10 s hover windows)")
    p.add_argument("--view", default="simulator", choices=("simulator", "navigator"))
    p.add_argument("--logs", nargs="*", default=None, help="real logs or folders (default: ../shared/data)")
    p.add_argument("--no-logs", action="store_true", help="generated flights only")
    p.add_argument("--window", type=float, default=10.0, help="window length, s (default 10)")
    p.add_argument("--markdown", action="store_true")
    a = p.parse_args(argv)
    globals()["WINDOW_S"] = a.window
    rows: dict[str, list[dict[str, float]]] = {"generated": []}
    for _, tables in generated_tables(a.dataset, a.flights, a.seed, a.view, a.hold):
        rows["generated"].append(measure(tables))
    if not a.no_logs:
        paths = default_logs() if a.logs is None else [
            q for x in a.logs for q in (sorted(Path(x).glob("*.ulg")) + sorted(Path(x).glob("*.bin"))
                                        if Path(x).is_dir() else [Path(x)])]
        for path in paths:
            tables = log_tables(path)
            if tables is not None:
                rows.setdefault(log_set(path), []).append(measure(tables))
    df = summarise(rows)
    print(df.to_markdown() if a.markdown else df.to_string())


if __name__ == "__main__":
    main()
