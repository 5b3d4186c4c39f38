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
