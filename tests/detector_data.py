"""Generated flights for the detector tests (the same flights as the conformance kit's).

``normal_flights`` and ``attacked_flight`` come from :mod:`scart_bench.testing`, which flies one
batch of normal flights per process with the real generator and caches it.
"""

from scart_bench.testing import (
    ATTACK_NOISE_M,
    ATTACK_WINDOW,
    POSITION_FIELDS,
    attacked_flight,
    normal_flights,
)

__all__ = ["ATTACK_NOISE_M", "ATTACK_WINDOW", "POSITION_FIELDS", "attacked_flight", "normal_flights"]
