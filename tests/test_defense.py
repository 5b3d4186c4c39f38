"""Defense in the loop (issue 32): a detector scoring the navigator's stream while the flight is flown, and
the flight controller's response on its alarm (generator.defense, benchmark.defense)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from scart_bench.benchmark.defense import (
    BatchMonitor,
    DefendedDetector,
    defend,
    defense_table,
    table_markdown,
)
from scart_bench.dataset.labels import combine
from scart_bench.detectors.base import Detector
from scart_bench.detectors.statistical import Statistical
from scart_bench.generator.defense import DefenseHook, Response
from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.geo import latlon_to_ned
from scart_bench.generator.modes import _builtin_rates
from scart_bench.generator.scart.layer import AttackLayer
from scart_bench.generator.scart.scenario import scenario_from_dict
from scart_bench.generator.telemetry.tables import flight_views, truth_table

CFG = FlightConfig(timing="ideal")
NORMAL_SEEDS = [11, 12]
ATTACK_SEEDS = [1, 2]
#: A 40 m GPS position jump at the sensor level that lasts to the end of the flight: the estimator's gate
#: rejects it, then (14 s without position fusion) EKF2's reset takes it in and the mission is flown 40 m off.
JUMP = scenario_from_dict(
    {
        "id": "gps-jump-40",
        "injection_point": "sensor",
        "start": [{"condition": "altitude_above", "height": 5.0}],
        "end": [{"condition": "duration", "seconds": 600.0}],
        "actions": [
            {"action": "bias", "target": ["gps.lat", "gps.lon"], "offset": 40.0, "direction_deg": 90.0}
        ],
    }
)


class GpsDisagreement(Detector):
    """A small real detector: the horizontal distance (m) between the GPS receiver's fix and the estimate."""

    name = "gps_disagreement"

    def __init__(self, columns: list[str] | None = None, random_state: int = 0):
        self.columns = columns
        self.random_state = random_state

    def _fit(self, X_list) -> None:
        self.history_rows_ = 1

    def _score(self, X: np.ndarray) -> np.ndarray:
        raw = X * self.scale_ + self.mean_
        n1, e1 = latlon_to_ned(raw[:, 0], raw[:, 1])
        n2, e2 = latlon_to_ned(raw[:, 2], raw[:, 3])
        return np.hypot(n1 - n2, e1 - e2)


COLUMNS = ["global_position_int.lat", "global_position_int.lon", "gps_raw_int.lat", "gps_raw_int.lon"]


@pytest.fixture(scope="module")
def normal():
    return simulate(NORMAL_SEEDS, CFG)


@pytest.fixture(scope="module")
def tables(normal):
    return [combine(flight_views(normal, i)[0], [])["most_frequent"] for i in range(len(NORMAL_SEEDS))]


@pytest.fixture(scope="module")
def disagreement(tables):
    """Fitted on the normal flights; threshold twice their largest score."""
    det = GpsDisagreement(columns=COLUMNS).fit(tables)
    return det, 2.0 * max(float(det.score(t).max()) for t in tables)


@pytest.fixture(scope="module")
def undefended():
    return simulate(ATTACK_SEEDS, CFG, layer=_layer(ATTACK_SEEDS))


def _layer(seeds):
    return AttackLayer([[JUMP] for _ in seeds], seeds, rates=_builtin_rates())


def _same(a, b) -> None:
    assert a.status == b.status and np.array_equal(a.exit_step, b.exit_step)
    for view in ("simulator", "navigator"):
        va, vb = getattr(a, view), getattr(b, view)
        for topic in va:
            if topic in vb:
                for x, y in zip(va[topic], vb[topic]):
                    assert np.array_equal(x, y), (view, topic)


def test_reject_gps_then_return_brings_a_spoofed_flight_home(disagreement, undefended):
    det, threshold = disagreement
    n = len(ATTACK_SEEDS)
    twin = simulate(ATTACK_SEEDS, CFG)
    hook = DefenseHook(
        BatchMonitor(det, threshold, n, burn_in_s=1.0),
        Response("reject_gps_then_return"),
        n,
        layer=_layer(ATTACK_SEEDS),
    )
    defended = simulate(ATTACK_SEEDS, CFG, layer=hook)
    for i in range(n):
        plan = truth_table(twin, i)[["x", "y"]].to_numpy()[-1]
        und = truth_table(undefended, i)[["x", "y"]].to_numpy()
        assert np.hypot(*(und[-1] - plan)) >= 20.0  # undefended: lands at least 20 m off its planned landing
        d = truth_table(defended, i)[["x", "y"]].to_numpy()
        assert defended.status[i] == "landed"
        assert np.hypot(*(d[-1] - d[0])) <= 5.0  # defended: within 5 m of home
        onset = hook.labelled_windows(i, 10**12)[0][0]
        assert (
            onset <= hook.notice_us[i] <= hook.response_us[i] < onset + 5_000_000
        )  # alarmed during the attack
        log = hook.event_log(i, 10**12)
        events = [(e["event"], e["scenario_id"]) for e in log]
        assert ("alarm", "defense") in events and ("response", "defense") in events
        assert [e["timestamp_us"] for e in log] == sorted(e["timestamp_us"] for e in log)


@pytest.mark.parametrize("response", ["reject_gps_then_return", "hold"])
def test_a_never_alarming_defense_is_byte_identical(normal, undefended, disagreement, response):
    det, _ = disagreement
    n = len(NORMAL_SEEDS)
    hook = DefenseHook(BatchMonitor(det, math.inf, n), Response(response), n)
    _same(normal, simulate(NORMAL_SEEDS, CFG, layer=hook))
    assert (hook.response_us < 0).all() and not hook.events
    if response.startswith("reject"):  # an attacked batch too: the layer's own flight, unchanged
        hook = DefenseHook(BatchMonitor(det, math.inf, 2), Response(response), 2, layer=_layer(ATTACK_SEEDS))
        _same(undefended, simulate(ATTACK_SEEDS, CFG, layer=hook))


def test_an_always_alarming_defense_aborts_every_normal_flight(disagreement):
    det, _ = disagreement
    always = DefendedDetector("always", det, threshold=-1.0, burn_in_s=1.0)  # distances are >= 0
    run = defend([always], [Response("land")], [], [], NORMAL_SEEDS, flight_config=CFG)
    table = defense_table(run.flights)
    row = table.iloc[0]
    assert row["normal"] == len(NORMAL_SEEDS) and row["false_aborts"] == len(NORMAL_SEEDS)
    assert row["false_abort_low"] > 0.0
    assert "always | land (x1)" in table_markdown(table)


def test_the_monitor_scores_the_rows_the_recorded_flight_has(normal, tables):
    """Block scoring in the loop gives the detector's batch scores on the recorded navigator view."""
    det = Statistical(window=20).fit(tables)
    mon = BatchMonitor(det, math.inf, len(NORMAL_SEEDS), block_rows=7)
    _same(normal, simulate(NORMAL_SEEDS, CFG, layer=DefenseHook(mon, Response("hold"), len(NORMAL_SEEDS))))
    times = np.concatenate([t for t, _ in mon.blocks])
    scores = np.concatenate([s for _, s in mon.blocks], axis=1)
    for i, table in enumerate(tables):
        want = pd.Series(det.score(table), index=table["Timestamp"].to_numpy())
        got = pd.Series(scores[i], index=times)
        common = want.index.intersection(got.index[np.isfinite(got.to_numpy())])
        assert len(common) > 0.9 * len(want)
        np.testing.assert_allclose(
            got[common].to_numpy(), want[common].to_numpy(), rtol=1e-6, atol=1e-9
        )  # rolling sums: window vs flight


def test_response_parameters_are_checked():
    with pytest.raises(ValueError, match="expected one of"):
        Response("explode")
    with pytest.raises(ValueError, match="alarms"):
        Response("hold", alarms=0)
