"""The example plugin against scart-bench's detector conformance kit (as a plugin author would test)."""

import numpy as np
import pytest

pytest.importorskip("scart_example_detector", reason="the example plugin is not installed (make test installs it)")

from scart_example_detector import RollingZScore  # noqa: E402

from scart_bench.testing import attacked_flight, check_detector, detector_checks, normal_flights


@pytest.mark.parametrize("check", detector_checks(RollingZScore, {"window": 10}), ids=str)
def test_conformance(check):
    check()


def test_check_detector_passes():
    check_detector(RollingZScore)


def test_attacked_flight_scores_above_normal_flights():
    detector = RollingZScore().fit(normal_flights(4, seed=0))
    attacked = attacked_flight(seed=2)
    normal = [detector.score(f).max() for f in normal_flights(3, seed=1)]
    scores = detector.score(attacked)
    assert scores.max() > max(normal)
    inside = attacked["Is_Anomaly"].to_numpy() == 1
    assert np.argmax(scores) in np.flatnonzero(inside)
