"""Metres <-> lat/lon at the flight's own origin: attacks measure the same anywhere on Earth."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pymap3d
import pytest

from scart_bench.generator.geo import latlon_from_ne, ne_from_latlon, offset_latlon
from scart_bench.generator.modes import csv_mode
from scart_bench.generator.scart.scenario import scenario_from_dict


def vdist(lat1, lon1, lat2, lon2):
    """(distance m, azimuth deg) between points on the WGS-84 surface: the straight-line (ECEF)
    distance, which equals the geodesic to a micrometre below a kilometre (pymap3d's Vincenty
    loop stops at decimetres for some near-meridian pairs)."""
    lat1, lon1, lat2, lon2 = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (lat1, lon1, lat2, lon2)))
    a = np.array(pymap3d.geodetic2ecef(lat1, lon1, 0.0))
    b = np.array(pymap3d.geodetic2ecef(lat2, lon2, 0.0))
    n, e = ne_from_latlon(lat2, lon2, lat1, lon1)
    return np.sqrt(((a - b) ** 2).sum(axis=0)), np.mod(np.rad2deg(np.arctan2(e, n)), 360.0)


RATE = 10
N = 600  # 60 s


def _gps_stream(lat0: float, lon0: float, moving: bool = False) -> dict[str, pd.DataFrame]:
    """A 10 Hz lat/lon stream at (lat0, lon0); ``moving``: a 200 m x 150 m loop around it."""
    t = np.arange(N, dtype=np.int64) * (1_000_000 // RATE)
    n = e = np.zeros(N)
    if moving:
        a = np.linspace(0, 2 * np.pi, N)
        n, e = 100.0 * np.sin(a), 75.0 * np.sin(2 * a)
    lat, lon = latlon_from_ne(n, e, lat0, lon0)
    return {"vehicle_gps_position": pd.DataFrame({"Timestamp": t, "lat": lat, "lon": lon,
                                                  "alt": np.full(N, 100.0)})}


def _run(src, action: dict, start_s: float = 10.0, seconds: float = 30.0):
    sc = scenario_from_dict({"id": "geo", "start": [{"condition": "time_window", "start_s": start_s}],
                             "end": [{"condition": "duration", "seconds": seconds}], "actions": [action]}, check_topics=False)
    (nav, windows, _), = csv_mode([src], [[sc]], [0])
    (s, e, *_), = windows
    ts = nav["vehicle_gps_position"]["Timestamp"].to_numpy()
    return nav["vehicle_gps_position"], (ts >= s) & (ts < e)


@pytest.mark.parametrize("lat", [0.0, 40.0, 47.4, 63.0, -33.0])
def test_a_50_m_bias_east_is_50_m_at_any_latitude(lat):
    src = _gps_stream(lat, 8.5)
    out, m = _run(src, {"action": "bias", "target": ["vehicle_gps_position.lat", "vehicle_gps_position.lon"],
                        "offset": 50.0, "direction_deg": 90.0})
    a, b = src["vehicle_gps_position"], out
    dist, az = vdist(a["lat"].to_numpy()[m], a["lon"].to_numpy()[m], b["lat"].to_numpy()[m], b["lon"].to_numpy()[m])
    assert m.sum() > 100
    assert np.all(np.abs(dist - 50.0) <= 0.05), (lat, dist.min(), dist.max())
    assert np.all(np.abs(az - 90.0) < 0.01)  # east
    # outside the window nothing moves, bit for bit
    np.testing.assert_array_equal(a["lat"].to_numpy()[~m], b["lat"].to_numpy()[~m])


def test_gps_spoof_rotation_preserves_distances_at_60_deg():
    src = _gps_stream(60.0, 10.0, moving=True)
    out, m = _run(src, {"action": "gps_spoof", "target": ["vehicle_gps_position"], "rate_deg_s": 3.0,
                        "max_deg": 30.0}, start_s=5.0, seconds=50.0)
    a = src["vehicle_gps_position"]
    la, lo = a["lat"].to_numpy()[m], a["lon"].to_numpy()[m]
    lb, lb_lon = out["lat"].to_numpy()[m], out["lon"].to_numpy()[m]
    # every point keeps its distance from the position at attack start (the centre of rotation)
    d_true, _ = vdist(la[0], lo[0], la, lo)
    d_spoof, _ = vdist(lb[0], lb_lon[0], lb, lb_lon)
    assert np.max(np.abs(d_true - d_spoof)) < 0.01
    # once the angle is at its maximum (after 10 s) the spoofed track is a rigid copy of the true one
    k = np.flatnonzero(out["Timestamp"].to_numpy()[m] >= 16_000_000)
    i, j = k[:-40], k[40:]
    dt, _ = vdist(la[i], lo[i], la[j], lo[j])
    ds, _ = vdist(lb[i], lb_lon[i], lb[j], lb_lon[j])
    assert np.max(np.abs(dt - ds)) < 0.01
    assert np.max(d_true) > 50 and np.max(np.hypot(*ne_from_latlon(lb, lb_lon, la, lo))) > 10  # it did rotate


def test_geofence_on_a_lat_lon_topic_fires_at_the_flights_own_origin():
    src = _gps_stream(-33.0, 151.0, moving=True)  # far from the generator's home
    sc = scenario_from_dict({"id": "fence", "start": [{"condition": "geofence", "center": [100.0, 0.0],
                                                       "radius": 20.0, "topic": "vehicle_gps_position"}],
                             "end": [{"condition": "duration", "seconds": 2.0}],
                             "actions": [{"action": "bias", "target": ["vehicle_gps_position.alt"], "offset": 5.0}]}, check_topics=False)
    (nav, windows, _), = csv_mode([src], [[sc]], [0])
    assert windows, "the geofence never fired"
    s = windows[0][0]
    row = src["vehicle_gps_position"].set_index("Timestamp").loc[s]
    n, e = ne_from_latlon(row["lat"], row["lon"], -33.0, 151.0)
    assert np.hypot(n - 100.0, e) <= 20.0 + 1.5  # within the fence (plus one sample of travel)


def test_offset_round_trip_is_exact_to_a_micrometre():
    lat, lon = offset_latlon(63.0, 10.0, 30.0, -40.0)
    n, e = ne_from_latlon(lat, lon, 63.0, 10.0)
    assert abs(n - 30.0) < 1e-6 and abs(e + 40.0) < 1e-6


def test_latlon_from_ne_gives_pymap3d_bit_for_bit():
    # the fast path must not move a single bit, or datasets change (the poles and scalars go to pymap3d)
    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 64):
        lat0, lon0 = rng.uniform(-89.9, 89.9, n), rng.uniform(-180, 180, n)
        north, east = rng.normal(0, 500, n), rng.normal(0, 500, n)
        lat, lon = latlon_from_ne(north, east, lat0, lon0)
        ref_lat, ref_lon, _ = pymap3d.enu2geodetic(east, north, np.zeros(n), lat0, lon0, 0.0)
        assert np.array_equal(lat, ref_lat) and np.array_equal(lon, ref_lon)
    lat, lon = latlon_from_ne(np.array([0.0]), np.array([0.0]), np.array([90.0]), np.array([0.0]))
    ref = pymap3d.enu2geodetic(0.0, 0.0, 0.0, 90.0, 0.0, 0.0)
    assert np.array_equal(lat, [ref[0]]) and np.array_equal(lon, [ref[1]])
    assert latlon_from_ne(10.0, 20.0, 63.0, 10.0) == tuple(float(v) for v in pymap3d.enu2geodetic(20.0, 10.0, 0.0, 63.0, 10.0, 0.0)[:2])


def test_a_given_origin_ecef_changes_no_bit():
    from scart_bench.generator.geo import origin_ecef

    rng = np.random.default_rng(1)
    lat0, lon0 = rng.uniform(-80, 80, 5), rng.uniform(-180, 180, 5)
    north, east = rng.normal(0, 300, 5), rng.normal(0, 300, 5)
    ecef0 = origin_ecef(lat0, lon0)
    lat, lon = latlon_from_ne(north, east, lat0, lon0)
    assert all(np.array_equal(a, b) for a, b in zip((lat, lon), latlon_from_ne(north, east, lat0, lon0, ecef0)))
    ne = ne_from_latlon(lat, lon, lat0, lon0)
    assert all(np.array_equal(a, b) for a, b in zip(ne, ne_from_latlon(lat, lon, lat0, lon0, ecef0)))
