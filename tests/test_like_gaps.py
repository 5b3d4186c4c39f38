"""generate --like: a logging gap is no hold (issue 47 acc. 3).

``arducopter_7-9-2014_7.bin`` has a 176 s logging gap (77.7-254.0 s) in the middle of its flight
(ArduCopter stops logging while disarmed). Interpolated across it, the track read as a 174 s hold at
about 1 m, so every flight fitted to this log hovered at full thrust through minutes that the log's
own flight spent on the ground, unlogged.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scart_bench.generator.like import tracks

FLEET = Path(__file__).parents[1].parent / "shared/data/dataflash/fleet"
GAPPED = FLEET / "arducopter_7-9-2014_7.bin"


@pytest.fixture(scope="module")
def gapped_track():
    if not GAPPED.exists():
        pytest.skip("needs ../shared/data")
    from scart_bench.generator.logs.importers import load_flight_file
    from scart_bench.generator.logs.phases import flight_phases

    tables = load_flight_file(GAPPED, allow_corrupt=True)
    return tracks.flown_track(tables, flight_phases(tables))


def test_the_logs_gap_is_a_gap_of_the_track(gapped_track):
    long = [(a, b) for a, b in gapped_track.gaps if b - a > 100]
    assert len(long) == 1 and long[0][0] == pytest.approx(77.7, abs=0.2) and long[0][1] == pytest.approx(254.0, abs=0.2)
    assert not gapped_track.logged[(gapped_track.t > 80) & (gapped_track.t < 250)].any()
    assert any("gap" in n for n in gapped_track.notes)


def test_recovered_mission_does_not_hold_through_the_gap(gapped_track):
    wps = tracks.recover_mission(gapped_track)
    # before: one waypoint held 174 s, the whole mission 188 s of holds
    assert max(w.hold_s for w in wps) < 30.0
    assert sum(w.hold_s for w in wps) < 30.0


def test_a_hand_made_gap_is_cut_from_the_mission():
    """A climb to 10 m, a 100 s gap at 10 m, and a descent: no hold, the logged time kept, the leg across the
    gap keeps the speed before it (0: no speed change)."""
    t = np.arange(0.0, 140.0, 1.0 / tracks.TRACK_HZ)
    up = np.interp(t, [0, 10, 20, 120, 130, 139.5], [1, 10, 10, 10, 10, 1])
    north = np.interp(t, [0, 20, 120, 139.5], [0, 40, 40, 80])
    track = tracks.Track(t, north, np.zeros_like(t), up, "test", None, 0.0, 139.5, gaps=[(20.0, 120.0)])
    wps = tracks.recover_mission(track)
    assert sum(w.hold_s for w in wps) < tracks.MIN_HOLD_S * 2
    # without the gap, the same track holds for 100 s
    held = tracks.recover_mission(tracks.Track(t, north, np.zeros_like(t), up, "test", None, 0.0, 139.5))
    assert max(w.hold_s for w in held) > 90.0
