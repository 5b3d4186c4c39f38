"""A log's flown track and the mission recovered from it (``generate --like``).

The track is the log's local north/east position (the estimator's where logged, else GPS
latitude/longitude about the take-off point) and its height above the ground
(:func:`scart_bench.generator.logs.phases.flight_phases`), on the airborne rows. A mission is the
log's own mission items where it logged them (ArduPilot ``CMD`` messages of a mission of more than
one item), otherwise the flown track simplified to waypoints with the Ramer-Douglas-Peucker algorithm
(:func:`rdp`), each with the speed of the leg to it and the time the vehicle held still there.
A log without a horizontal position (no GPS fix) gives the altitude profile over home: its holds
and climbs as waypoints at home.

A logging gap is no hold: the track's samples inside a gap (the log's gaps as ``import`` reports
them, or any stretch of :data:`GAP_S` without an altitude row) are left out and the mission is
recovered on the logged time, so the flight goes on from where the log stopped to where it
resumed without the gap's time (an ArduCopter log stops while disarmed: interpolated, a landing
and the next take-off read as minutes of hover at 1 m).

The mission is written as a MAVLink WPL file (``QGC WPL 110``) that
:func:`scart_bench.generator.flight_software.mission_files.read_wpl` reads back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from scart_bench.generator.flight_software import mission_files as mf

#: RDP tolerance (m) of the track simplification; raised until the mission fits the navigator's table
RDP_EPSILON_M = 2.0
#: horizontal / vertical speed (m/s) below which the vehicle holds still
STILL_H_M_S = 0.5
STILL_V_M_S = 0.3
#: shortest hold (s) kept as a hold of a waypoint
MIN_HOLD_S = 2.0
#: the track's sampling (Hz) for the simplification
TRACK_HZ = 2.0
#: s, the smoothing of the track before its speed is read (a 5 Hz GPS fix wanders by decimetres)
SMOOTH_S = 2.0
#: waypoints closer than this (m) to the previous one are merged into it
MIN_LEG_M = 1.0
#: s, the longest interval between the altitude's rows that is not a gap in the track
GAP_S = 2.0


@dataclass
class Track:
    """A log's airborne track: time (s from the log's start), north/east (m from the take-off point,
    NaN without a horizontal position) and height above the ground (m), at :data:`TRACK_HZ`."""

    t: np.ndarray
    north: np.ndarray
    east: np.ndarray
    up: np.ndarray
    horizontal: str  # where north/east come from ("" when the log has none)
    home: tuple[float, float, float] | None  # lat, lon, alt AMSL of the take-off point, when known
    takeoff_s: float
    landing_s: float
    notes: list[str] = field(default_factory=list)
    gaps: list[tuple[float, float]] = field(default_factory=list)  # (s, s): no row between, inside the flight

    @property
    def logged(self) -> np.ndarray:
        """Per track sample: False strictly inside a gap (the track's value there is interpolation)."""
        ok = np.ones(len(self.t), bool)
        for a, b in self.gaps:
            ok &= ~((self.t > a) & (self.t < b))
        return ok

    @property
    def has_position(self) -> bool:
        return bool(self.horizontal)


@dataclass(frozen=True)
class Waypoint:
    """One recovered mission item: north/east (m from home), height above home (m), the speed of the
    leg to it (m/s) and its hold time (s)."""

    north: float
    east: float
    up: float
    speed: float
    hold_s: float


def column(tables: dict[str, pd.DataFrame], candidates: tuple[str, ...]) -> tuple[str, np.ndarray, np.ndarray] | None:
    """The first ``topic.field`` of ``candidates`` the log has with finite values: (name, t s, values)."""
    for name in candidates:
        topic, _, fld = name.partition(".")
        df = tables.get(topic)
        if df is None or fld not in df.columns:
            continue
        v = df[fld].to_numpy(np.float64)
        t = df["Timestamp"].to_numpy(np.int64) / 1e6
        ok = np.isfinite(v)
        if ok.sum() >= 2 and np.nanstd(v[ok]) > 0:
            return name, t[ok], v[ok]
    return None


def _gps_fixed(tables: dict[str, pd.DataFrame]) -> tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """GPS rows with a 3-D fix: (topic, t s, lat, lon, alt AMSL)."""
    for topic, lat, lon, alt, fix in (("gps", "Lat", "Lng", "Alt", "Status"),
                                      ("vehicle_gps_position", "lat", "lon", "alt", "fix_type"),
                                      ("sensor_gps", "lat", "lon", "alt", "fix_type"),
                                      ("vehicle_gps_position", "latitude_deg", "longitude_deg", "altitude_msl_m",
                                       "fix_type"),
                                      ("gps_raw_int", "lat", "lon", "alt", "fix_type")):
        df = tables.get(topic)
        if df is None or not {lat, lon, fix} <= set(df.columns):
            continue
        ok = (df[fix].to_numpy(float) >= 3) & np.isfinite(df[lat].to_numpy(float))
        ok &= (df[lat].to_numpy(float) != 0.0) | (df[lon].to_numpy(float) != 0.0)
        if ok.sum() < 10:
            continue
        a = df[alt].to_numpy(float)[ok] if alt in df.columns else np.full(int(ok.sum()), np.nan)
        return (topic, df["Timestamp"].to_numpy(np.int64)[ok] / 1e6, df[lat].to_numpy(float)[ok],
                df[lon].to_numpy(float)[ok], a)
    return None


def track_gaps(tables: dict[str, pd.DataFrame], phases: pd.DataFrame, t0: float, t1: float) -> list[tuple[float, float]]:
    """The gaps (s) that overlap ``t0``-``t1``: the log's logging gaps and the stretches of more than
    :data:`GAP_S` (and 20 typical intervals, as a logging gap) between the phases' altitude rows, merged."""
    from scart_bench.generator.logs.logged_time import GAP_FACTOR, logging_gaps

    found = [(a / 1e6, b / 1e6) for a, b in logging_gaps(tables)]
    t_ph = phases["Timestamp"].to_numpy(np.int64) / 1e6
    d = np.diff(t_ph)
    k = np.flatnonzero(d > max(GAP_S, GAP_FACTOR * float(np.median(d)))) if len(d) else np.zeros(0, int)
    found += [(float(t_ph[i]), float(t_ph[i + 1])) for i in k]
    merged: list[tuple[float, float]] = []
    for a, b in sorted(found):
        if b <= t0 or a >= t1:
            continue
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], b))
        else:
            merged.append((a, b))
    return merged


def flown_track(tables: dict[str, pd.DataFrame], phases: pd.DataFrame) -> Track | None:
    """The airborne track of a log (None when it never leaves the ground), with its gaps."""
    from scart_bench.generator.geo import ne_from_latlon

    t_ph = phases["Timestamp"].to_numpy(np.int64) / 1e6
    air = phases["phase"].to_numpy(object) != "landed"
    air &= phases["altitude_m"].to_numpy(float) > 0.5
    if air.sum() < 4:
        return None
    t0, t1 = float(t_ph[np.flatnonzero(air)[0]]), float(t_ph[np.flatnonzero(air)[-1]])
    if t1 - t0 < 2.0:
        return None
    grid = np.arange(t0, t1, 1.0 / TRACK_HZ)
    up = np.interp(grid, t_ph, phases["altitude_m"].to_numpy(float))
    notes: list[str] = []
    gps = _gps_fixed(tables)
    home = None
    north = east = np.full(len(grid), np.nan)
    horizontal = ""
    if gps is not None:
        topic, tg, lat, lon, alt = gps
        k = int(np.clip(np.searchsorted(tg, t0), 0, len(tg) - 1))
        home = (float(lat[k]), float(lon[k]), float(alt[k]))
        n, e = ne_from_latlon(lat, lon, home[0], home[1])
        inside = (grid >= tg[0]) & (grid <= tg[-1])
        north = np.where(inside, np.interp(grid, tg, np.asarray(n, float)), np.nan)
        east = np.where(inside, np.interp(grid, tg, np.asarray(e, float)), np.nan)
        horizontal = f"{topic} latitude/longitude (3-D fix)"
        if np.isnan(north).mean() > 0.5:
            notes.append(f"GPS fix for {100 * (1 - np.isnan(north).mean()):.0f} % of the flight only")
    for xs, ys in (("vehicle_local_position.x", "vehicle_local_position.y"),
                   ("local_position_ned.x", "local_position_ned.y")):
        if horizontal:
            break
        x, y = column(tables, (xs,)), column(tables, (ys,))
        if x is not None and y is not None:
            north = np.interp(grid, x[1], x[2]) - np.interp(t0, x[1], x[2])
            east = np.interp(grid, y[1], y[2]) - np.interp(t0, y[1], y[2])
            horizontal = f"{xs.split('.')[0]} x/y"
    gaps = track_gaps(tables, phases, t0, t1)
    if gaps:
        notes.append(f"{len(gaps)} gap{'' if len(gaps) == 1 else 's'} in the flight "
                     f"({sum(b - a for a, b in gaps):.0f} s): the mission goes on across each without its time")
    return Track(grid, north, east, up, horizontal, home, t0, t1, notes, gaps)


def rdp(points: np.ndarray, epsilon: float) -> np.ndarray:
    """Indices of the points the Ramer-Douglas-Peucker simplification keeps (first and last always),
    for ``points`` (n, d): every dropped point is within ``epsilon`` of the kept polyline."""
    n = len(points)
    keep = np.zeros(n, bool)
    keep[[0, n - 1]] = True
    stack = [(0, n - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        seg = points[b] - points[a]
        rel = points[a + 1:b] - points[a]
        length = float(np.linalg.norm(seg))
        if length < 1e-9:
            d = np.linalg.norm(rel, axis=1)
        else:
            u = seg / length
            proj = np.clip(rel @ u, 0.0, length)
            d = np.linalg.norm(rel - np.outer(proj, u), axis=1)
        k = int(np.argmax(d))
        if d[k] > epsilon:
            m = a + 1 + k
            keep[m] = True
            stack.extend(((a, m), (m, b)))
    return np.flatnonzero(keep)


def _smooth(x: np.ndarray) -> np.ndarray:
    """``x`` averaged over :data:`SMOOTH_S` (centred): a GPS position's noise is no motion."""
    w = max(1, int(round(SMOOTH_S * TRACK_HZ)) | 1)
    k = np.ones(w)
    return np.convolve(x, k, mode="same") / np.convolve(np.ones_like(x), k, mode="same")


def _holds(track: Track) -> np.ndarray:
    """Per track sample: True where the vehicle holds still (horizontally and vertically), on the
    track smoothed over :data:`SMOOTH_S`."""
    dt = 1.0 / TRACK_HZ
    vz = np.gradient(_smooth(track.up), dt)
    still = np.abs(vz) < STILL_V_M_S
    if track.has_position:
        n = _smooth(pd.Series(track.north).ffill().bfill().fillna(0.0).to_numpy())
        e = _smooth(pd.Series(track.east).ffill().bfill().fillna(0.0).to_numpy())
        still &= np.hypot(np.gradient(n, dt), np.gradient(e, dt)) < STILL_H_M_S
    return still & track.logged


def recover_mission(track: Track, epsilon: float = RDP_EPSILON_M) -> list[Waypoint]:
    """The flown track as waypoints (take-off point first, the landing spot last), at most
    :data:`mission_files.MAX_NAV_ITEMS` - 1 positions: the RDP tolerance doubles until it fits.
    Samples inside the track's gaps are left out and time is the logged time (each gap's dropped): a
    leg across a gap keeps the speed before it."""
    n = np.nan_to_num(track.north, nan=np.nan) if track.has_position else np.zeros(len(track.t))
    # a stretch without a fix keeps the last known position (the mission flies straight across it)
    n = pd.Series(n).ffill().bfill().fillna(0.0).to_numpy()
    e = pd.Series(track.east if track.has_position else np.zeros(len(track.t))).ffill().bfill().fillna(0.0).to_numpy()
    u = track.up
    still = _holds(track)
    keep = track.logged
    t = track.t.copy()
    for a, b in track.gaps:  # the logged clock: each gap's time taken out of what follows it
        t[track.t >= b] -= b - a
    resumed = np.zeros(len(t), bool)  # the first kept sample after a gap
    for _a, b in track.gaps:
        after = np.flatnonzero(keep & (track.t >= b))
        if len(after):
            resumed[after[0]] = True
    n, e, u, t, still, resumed = n[keep], e[keep], u[keep], t[keep], still[keep], resumed[keep]
    # breakpoints: RDP vertices, plus the start and end of every hold long enough to count
    runs = _runs(still, int(math.ceil(MIN_HOLD_S * TRACK_HZ)))
    pts = np.column_stack([n, e, u])
    while True:
        idx = set(rdp(pts, epsilon).tolist())
        for a, b in runs:
            idx.update((a, b))
        idx = sorted(idx)
        wps = _waypoints(t, pts, idx, runs, resumed)
        if len(wps) <= mf.MAX_NAV_ITEMS - 2 or epsilon > 1e4:
            return wps
        epsilon *= 2.0
        runs = runs[::2] if len(runs) > (mf.MAX_NAV_ITEMS - 2) // 2 else runs


def _runs(mask: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """(first, last) sample of every run of True at least ``min_len`` long."""
    d = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    return [(int(a), int(b)) for a, b in zip(starts, ends) if b - a + 1 >= min_len]


def _waypoints(t: np.ndarray, pts: np.ndarray, idx: list[int], runs: list[tuple[int, int]],
               resumed: np.ndarray | None = None) -> list[Waypoint]:
    """Waypoints at the breakpoints ``idx``: a hold run becomes one waypoint (its mean position) with its
    duration; a leg's speed is its horizontal path length over its time (0, the speed before kept, for a
    leg across a gap: True in ``resumed`` at the first sample after it)."""
    resumed = np.zeros(len(t), bool) if resumed is None else resumed
    hold_of = {a: b for a, b in runs}
    inside = np.zeros(len(t), bool)
    for a, b in runs:
        inside[a + 1:b + 1] = True
    out: list[Waypoint] = []
    last = 0
    for i in idx:
        if inside[i] and i not in hold_of:
            continue
        end = hold_of.get(i, i)
        p = pts[i:end + 1].mean(axis=0)
        hold = float(t[end] - t[i]) if i in hold_of else 0.0
        seg = pts[last:i + 1]
        path = float(np.sum(np.hypot(np.diff(seg[:, 0]), np.diff(seg[:, 1])))) if len(seg) > 1 else 0.0
        dur = float(t[i] - t[last]) if i > last else 0.0
        speed = path / dur if dur > 0 and not resumed[last + 1:i + 1].any() else 0.0
        if out and math.hypot(p[0] - out[-1].north, p[1] - out[-1].east) < MIN_LEG_M and abs(p[2] - out[-1].up) < MIN_LEG_M:
            prev = out[-1]
            out[-1] = Waypoint(prev.north, prev.east, prev.up, prev.speed, prev.hold_s + hold + dur)
        else:
            out.append(Waypoint(float(p[0]), float(p[1]), float(p[2]), speed, hold))
        last = end
    return out


def mission_from_cmd(tables: dict[str, pd.DataFrame]) -> list[tuple[int, int, list[float]]] | None:
    """An ArduPilot log's mission items (``CMD`` messages of a mission of more than one item) as
    WPL rows (command, frame, [p1..p4, lat, lon, alt relative]); None when the log holds none."""
    df = tables.get("cmd")
    if df is None or not {"CTot", "CNum", "CId", "Lat", "Lng", "Alt"} <= set(df.columns):
        return None
    items = df[(df["CTot"] > 1) & (df["CNum"] >= 1)].drop_duplicates("CNum", keep="last").sort_values("CNum")
    if len(items) < 1:
        return None
    rows = []
    for _, r in items.iterrows():
        p = [float(r.get(f"Prm{k}", 0.0)) for k in range(1, 5)]
        rows.append((int(r["CId"]), mf.FRAME_GLOBAL_REL, [*p, float(r["Lat"]), float(r["Lng"]), float(r["Alt"])]))
    return rows


def write_wpl(path: str | Path, waypoints: list[Waypoint], home: tuple[float, float, float],
              cruise: float) -> Path:
    """Write ``waypoints`` as a ``QGC WPL 110`` file about ``home`` (lat, lon, alt AMSL): take-off to
    the first waypoint's height, a speed change before every leg whose speed differs by more than
    0.3 m/s, waypoints (global, relative altitude) with their holds, and a land item where the last one is."""
    from scart_bench.generator.geo import latlon_from_ne

    lines = ["QGC WPL 110", _wpl(0, 0, 0, 16, [0, 0, 0, 0, home[0], home[1], home[2]])]

    def add(cmd: int, frame: int, p: list[float]) -> None:
        lines.append(_wpl(len(lines) - 1, frame, 0, cmd, p))

    clip_up = [float(np.clip(w.up, mf.MIN_HEIGHT_M, mf.MAX_HEIGHT_M)) for w in waypoints]
    add(mf.CMD_TAKEOFF, mf.FRAME_GLOBAL_REL, [0, 0, 0, 0, home[0], home[1], max(clip_up[0], 2.0)])
    speed = cruise
    for k, (w, up) in enumerate(zip(waypoints, clip_up)):
        if k == 0 and w.hold_s <= 0 and math.hypot(w.north, w.east) < MIN_LEG_M:
            continue  # the take-off point itself
        if k and w.speed >= 0.5 and abs(w.speed - speed) > 0.3:
            speed = float(np.clip(round(w.speed, 1), 0.5, mf.MAX_SPEED))
            add(mf.CMD_CHANGE_SPEED, mf.FRAME_MISSION, [1, speed, -1, 0, 0, 0, 0])
        lat, lon = latlon_from_ne(w.north, w.east, home[0], home[1])
        add(mf.CMD_WAYPOINT, mf.FRAME_GLOBAL_REL, [round(min(w.hold_s, mf.MAX_HOLD_S), 1), 0, 0, 0,
                                                   float(lat), float(lon), round(up, 2)])
    add(mf.CMD_LAND, mf.FRAME_GLOBAL_REL, [0, 0, 0, 0, 0, 0, 0])  # where it is: the last waypoint
    p = Path(path)
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def _wpl(index: int, frame: int, current: int, cmd: int, p: list[float]) -> str:
    nums = [f"{v:.8f}" if k in (4, 5) else f"{v:g}" for k, v in enumerate(p)]
    return "\t".join([str(index), str(current), str(frame), str(cmd), *nums, "1"])
