"""Geodesy used by PX4: the azimuthal-equidistant local tangent plane at home and the ISA baro model."""

from __future__ import annotations

import numpy as np

from scart_bench.generator.topics import HOME_ALT, HOME_LAT, HOME_LON

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


def metres_per_degree(lat: float = HOME_LAT) -> tuple[float, float]:
    """Metres per degree of latitude and of longitude near ``lat`` (for unit conversion)."""
    m_lat = np.deg2rad(1.0) * EARTH_RADIUS
    return m_lat, m_lat * np.cos(np.deg2rad(lat))


def pressure_at(alt_amsl: np.ndarray) -> np.ndarray:
    """ISA static pressure (Pa) at an altitude above mean sea level (m)."""
    return SEA_LEVEL_PRESSURE * (1.0 - 2.25577e-5 * np.asarray(alt_amsl)) ** 5.25588


def altitude_at(pressure_pa: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pressure_at`: barometric altitude AMSL (m)."""
    return (1.0 - (np.asarray(pressure_pa) / SEA_LEVEL_PRESSURE) ** (1.0 / 5.25588)) / 2.25577e-5


HOME_PRESSURE = float(pressure_at(HOME_ALT))
