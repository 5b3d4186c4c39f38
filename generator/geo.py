"""Geodesy.

Two kinds of conversion live here:

- the simulator's own projection, PX4's azimuthal-equidistant plane on a sphere at home
  (``ned_to_latlon`` / ``latlon_to_ned``), which the generator uses because PX4 does;
- metres <-> latitude/longitude for everything that edits or reads a *recorded* position (attack
  actions, conditions, the geofence): a WGS-84 local tangent plane (ENU) at each flight's own
  origin, through pymap3d (``ne_from_latlon`` / ``latlon_from_ne``, ``offset_latlon``,
  ``metres_per_degree``). A 50 m offset east is 50 m east at any latitude.
"""


from __future__ import annotations

import numpy as np

from scart_bench.dataset.schema import HOME_LAT, HOME_LON

EARTH_RADIUS = 6371000.0  # m, CONSTANTS_RADIUS_OF_EARTH in PX4
_LAT0 = np.deg2rad(HOME_LAT)
_LON0 = np.deg2rad(HOME_LON)
SEA_LEVEL_PRESSURE = 101325.0  # Pa


def ned_to_latlon(x: np.ndarray, y: np.ndarray, lat0: float = HOME_LAT, lon0: float = HOME_LON):
    """Local north/east (m) -> latitude/longitude (deg), PX4 ``map_projection_reproject``."""
    x = np.asarray(x, dtype=np.float64) / EARTH_RADIUS
    y = np.asarray(y, dtype=np.float64) / EARTH_RADIUS
    la0, lo0 = np.deg2rad(lat0), np.deg2rad(lon0)
    c = np.hypot(x, y)
    safe = np.where(c > 0, c, 1.0)
    sin_c, cos_c = np.sin(c), np.cos(c)
    lat = np.where(c > 0, np.arcsin(np.clip(cos_c * np.sin(la0) + x * sin_c * np.cos(la0) / safe, -1, 1)), la0)
    lon = np.where(
        c > 0,
        lo0 + np.arctan2(y * sin_c, c * np.cos(la0) * cos_c - x * np.sin(la0) * sin_c),
        lo0,
    )
    return np.rad2deg(lat), np.rad2deg(lon)


def latlon_to_ned(lat: np.ndarray, lon: np.ndarray, lat0: float = HOME_LAT, lon0: float = HOME_LON):
    """Latitude/longitude (deg) -> local north/east (m), PX4 ``map_projection_project``."""
    la = np.deg2rad(np.asarray(lat, dtype=np.float64))
    lo = np.deg2rad(np.asarray(lon, dtype=np.float64))
    la0, lo0 = np.deg2rad(lat0), np.deg2rad(lon0)
    cos_d = np.cos(lo - lo0)
    arg = np.clip(np.sin(la0) * np.sin(la) + np.cos(la0) * np.cos(la) * cos_d, -1.0, 1.0)
    c = np.arccos(arg)
    k = np.where(np.abs(c) > 1e-12, c / np.where(np.sin(c) != 0, np.sin(c), 1.0), 1.0)
    x = k * (np.cos(la0) * np.sin(la) - np.sin(la0) * np.cos(la) * cos_d) * EARTH_RADIUS
    y = k * np.cos(la) * np.sin(lo - lo0) * EARTH_RADIUS
    return x, y


def metres_per_degree(lat=HOME_LAT) -> tuple[np.ndarray, np.ndarray]:
    """Metres per degree of latitude and of longitude at latitude ``lat`` (WGS-84; arrays work).

    From the meridian and transverse radii of curvature (pymap3d.rcurve), so a degree of
    longitude at 63 deg N is 50.7 km, not the sphere's 50.5 km.
    """
    from pymap3d import rcurve

    lat = np.asarray(lat, dtype=np.float64)
    m_lat = np.deg2rad(1.0) * rcurve.meridian(lat, deg=True)
    m_lon = np.deg2rad(1.0) * rcurve.parallel(lat, deg=True)
    return m_lat, m_lon


def origin_ecef(lat0, lon0) -> tuple:
    """ECEF (m) of tangent-plane origins on the ellipsoid: pass it as ``ecef0`` to
    :func:`ne_from_latlon` / :func:`latlon_from_ne` with the same origins to skip recomputing it."""
    import pymap3d

    return pymap3d.geodetic2ecef(lat0, lon0, 0.0)


def ne_from_latlon(lat, lon, lat0, lon0, ecef0: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """North/east metres of ``lat``/``lon`` in the WGS-84 tangent plane at ``lat0``/``lon0`` (deg).

    All arguments broadcast (one origin per flight: pass ``lat0`` with the flights' shape).
    Heights are taken as 0 on the ellipsoid: a horizontal conversion. ``ecef0``: the origins'
    :func:`origin_ecef`, if known (the result is the same, bit for bit).
    """
    import pymap3d

    lat, lon = np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
    if ecef0 is None:
        e, n, _ = pymap3d.geodetic2enu(lat, lon, np.zeros_like(lat), lat0, lon0, 0.0)
    else:  # pymap3d.geodetic2enu's own steps, with the origin's ECEF given
        x1, y1, z1 = pymap3d.geodetic2ecef(lat, lon, np.zeros_like(lat))
        x2, y2, z2 = ecef0
        e, n, _ = pymap3d.uvw2enu(x1 - x2, y1 - y2, z1 - z2, lat0, lon0)
    return np.asarray(n, dtype=np.float64), np.asarray(e, dtype=np.float64)


def latlon_from_ne(n, e, lat0, lon0, ecef0: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`ne_from_latlon`: the latitude/longitude (deg) of a tangent-plane point.

    Only latitude/longitude are returned (the plane's height above the surface, d^2 / 2R,
    moves them by less than a micrometre within kilometres of the origin). ``ecef0``: as in
    :func:`ne_from_latlon`.
    """
    import pymap3d

    n, e = np.asarray(n, dtype=np.float64), np.asarray(e, dtype=np.float64)
    # pymap3d.enu2geodetic is enu2ecef then ecef2geodetic; the latter is taken bit for bit from
    # pymap3d without its per-call overhead where it can be (see _ecef_to_latlon)
    if ecef0 is None:
        x, y, z = pymap3d.enu2ecef(e, n, np.zeros_like(n), lat0, lon0, 0.0)
    else:  # pymap3d.enu2ecef's own steps, with the origin's ECEF given
        x0, y0, z0 = ecef0
        u, v, w = pymap3d.enu2uvw(e, n, np.zeros_like(n), lat0, lon0)
        x, y, z = x0 + u, y0 + v, z0 + w
    fast = _ecef_to_latlon(x, y, z)
    if fast is None:
        lat, lon, _ = pymap3d.ecef2geodetic(x, y, z)
    else:
        lat, lon = fast
    return np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)


def _ecef_to_latlon(x, y, z) -> tuple[np.ndarray, np.ndarray] | None:
    """Latitude/longitude (deg) of ECEF points on WGS-84: the operations of pymap3d 3.2's
    ``ecef2geodetic`` (You, 2000) for arrays, in the same order, so the results are the same bits;
    without its checks' overhead and the altitude. None where pymap3d's special cases apply (a
    point at the centre or on the axis, or not an array): the caller then asks pymap3d itself."""
    from pymap3d import Ellipsoid

    x, y, z = np.asarray(x), np.asarray(y), np.asarray(z)
    if x.ndim == 0 or x.shape != y.shape or x.shape != z.shape or x.dtype != np.float64:
        return None
    ell = Ellipsoid.from_name("wgs84")
    a, b = ell.semimajor_axis, ell.semiminor_axis
    r = np.sqrt(x**2 + y**2 + z**2)
    E = np.sqrt(a**2 - b**2)
    u = np.sqrt(0.5 * (r**2 - E**2) + 0.5 * np.hypot(r**2 - E**2, 2 * E * z))
    hxy = np.hypot(x, y)
    huE = np.hypot(u, E)
    # pymap3d's np.isclose(v, 0) is |v| <= 1e-8
    if not ((np.abs(u) > 1e-8) & (np.abs(hxy) > 1e-8)).all():
        return None
    beta = np.arctan(huE / u * z / hxy)
    beta = beta + ((b * u - a * huE + E**2) * np.sin(beta)) / (a * huE * 1 / np.cos(beta) - E**2 * np.cos(beta))
    lat = np.arctan(a / b * np.tan(beta))
    lim_pi2 = np.pi / 2 - np.finfo(beta.dtype).eps
    lat = np.where(beta >= lim_pi2, np.pi / 2, lat)
    lat = np.where(beta <= -lim_pi2, -np.pi / 2, lat)
    lon = np.arctan2(y, x)
    return np.degrees(lat), np.degrees(lon)


def offset_latlon(lat, lon, d_north, d_east, lat0=None, lon0=None) -> tuple[np.ndarray, np.ndarray]:
    """``lat``/``lon`` moved by ``d_north``/``d_east`` metres in the tangent plane at the origin.

    The origin defaults to the point itself (an exact local displacement).
    """
    lat0 = lat if lat0 is None else lat0
    lon0 = lon if lon0 is None else lon0
    n, e = ne_from_latlon(lat, lon, lat0, lon0)
    return latlon_from_ne(n + d_north, e + d_east, lat0, lon0)


def pressure_at(alt_amsl: np.ndarray) -> np.ndarray:
    """ISA static pressure (Pa) at an altitude above mean sea level (m)."""
    return SEA_LEVEL_PRESSURE * (1.0 - 2.25577e-5 * np.asarray(alt_amsl)) ** 5.25588


def altitude_at(pressure_pa: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pressure_at`: barometric altitude AMSL (m)."""
    return (1.0 - (np.asarray(pressure_pa) / SEA_LEVEL_PRESSURE) ** (1.0 / 5.25588)) / 2.25577e-5


