"""Per-flight random streams, so that a flight's noise depends only on its own seed.

Every flight owns a ``numpy.random.Generator``; each simulation step draws the same number of
standard normals per flight, refilled in chunks, so a flight flown alone and the same flight
flown inside a batch of thousands see the same noise.
"""

from __future__ import annotations

import numpy as np


class NoiseStream:
    """Standard-normal draws of shape (n_flights, dim) per step, from per-flight generators."""

    def __init__(self, rngs: list[np.random.Generator], dim: int, chunk: int = 250):
        self.rngs = rngs
        self.dim = dim
        self.chunk = chunk
        self._buf = np.empty((len(rngs), chunk, dim))
        self._pos = chunk

    def next(self) -> np.ndarray:
        """The next (n_flights, dim) block of standard normals."""
        if self._pos == self.chunk:
            for i, g in enumerate(self.rngs):
                self._buf[i] = g.standard_normal((self.chunk, self.dim))
            self._pos = 0
        out = self._buf[:, self._pos, :]
        self._pos += 1
        return out


# -- the per-step noise vector of the flight simulator: named fields ------------------------------
#: Offsets of the standard normals each flight draws per step (NOISE_DIM in all).
NZ_ACC = 0  # 3: accelerometer white noise
NZ_GYRO = 3  # 3: gyro white noise
NZ_ACC_BIAS = 6  # 3: accelerometer bias random walk
NZ_GYRO_BIAS = 9  # 3: gyro bias random walk
NZ_MAG = 12  # 3: magnetometer noise
NZ_BARO = 15  # 2: pressure, temperature
NZ_GPS_BIAS = 17  # 3: GPS Gauss-Markov error
NZ_GPS_POS = 20  # 3: GPS white position noise
NZ_GPS_VEL = 23  # 3: GPS velocity noise
NZ_WIND = 26  # 3: gusts
NZ_BATTERY = 29  # 1: battery voltage noise
NOISE_DIM = 30

#: The same fields as slices, for the numpy reference step.
NOISE_FIELDS: dict[str, slice] = {
    "imu": slice(NZ_ACC, NZ_GYRO_BIAS + 3), "mag": slice(NZ_MAG, NZ_MAG + 3), "baro": slice(NZ_BARO, NZ_BARO + 2),
    "gps": slice(NZ_GPS_BIAS, NZ_GPS_VEL + 3), "wind": slice(NZ_WIND, NZ_WIND + 3),
    "battery": slice(NZ_BATTERY, NZ_BATTERY + 1),
}


def fill_block(rngs: list[np.random.Generator], rows: np.ndarray, out: np.ndarray) -> None:
    """Fill ``out[j]`` (steps, dim) with flight ``rows[j]``'s next normals (numpy releases the GIL)."""
    for j, i in enumerate(rows):
        rngs[i].standard_normal(out=out[j])  # out[j] is C-contiguous: a (steps, dim) block
