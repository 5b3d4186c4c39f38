"""Only real attacks count: what each attacked flight changed, csv sources and copies (acceptance 2)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from scart_bench.benchmark.protocol import ProtocolError, Splits, assign_roles
from scart_bench.benchmark.tables import rate_summary
from scart_bench.dataset import open_dataset
from scart_bench.generator.attack_effect import attack_effect, field_stds
from scart_bench.generator.attacks import csv_applicable, csv_flights
from scart_bench.generator.scart.scenario import load_scenarios

SCENARIOS = "data/scenarios"


def _topic(values, ts=None):
    ts = np.arange(len(values), dtype=np.int64) * 1000 if ts is None else np.asarray(ts, dtype=np.int64)
    return pd.DataFrame({"Timestamp": ts, "Is_Anomaly": 0, "x": np.asarray(values, dtype=np.float64)})


def test_attack_effect_counts_changed_and_dropped_messages():
    ref = {"pos": _topic([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])}
    window = [(2000, 5000)]  # rows 2, 3, 4
    same = attack_effect({"pos": ref["pos"].copy()}, ref, window, {"pos.x": 2.0})
    assert same == {"effect_rows": 0, "effect_fields": 0, "no_effect": True, "detectability": same["detectability"]}
    assert np.isnan(same["detectability"])
    moved = _topic([0.0, 1.0, 2.0, 9.0, 4.0, 7.0])  # row 5 changed too, but after the window
    got = attack_effect({"pos": moved}, ref, window, {"pos.x": 2.0})
    assert (got["effect_rows"], got["effect_fields"], got["no_effect"]) == (1, 1, False)
    assert got["detectability"] == pytest.approx(6.0 / 2.0)
    dropped = ref["pos"].drop(index=[3])
    got = attack_effect({"pos": dropped}, ref, window)
    assert (got["effect_rows"], got["no_effect"]) == (1, False)
    # a sensor attack changes the simulator view itself: unknown, never a false "no effect"
    unknown = attack_effect({"pos": ref["pos"].copy()}, ref, window, injection_points="sensor")
    assert unknown["no_effect"] is False and np.isnan(unknown["effect_rows"])


def test_field_stds():
    stds = field_stds([{"pos": _topic([0.0, 2.0])}, {"pos": _topic([4.0, 6.0])}])
    assert stds == {"pos.x": pytest.approx(np.std([0, 2, 4, 6]))}


@pytest.mark.parametrize("name", ["sensor_gps_jump", "sensor_gps_drift", "env_wind_gust", "fault_battery_sag"])
def test_no_csv_copy_for_scenarios_off_the_link(name):
    config = load_scenarios(f"{SCENARIOS}/{name}.toml")
    assert not csv_applicable(config)
    written, said = [], []

    class Writer:
        def write(self, record):
            written.append(record)

    csv_flights(Writer(), [config], [("normal-x", {}, 1)], {}, 8, said.append)
    assert written == [] and "no copy" in said[0]
    assert csv_applicable(load_scenarios(f"{SCENARIOS}/gps_spoof.toml"))


def test_quick_dataset_attacks_are_real_and_sources_reserved(quick_dataset):
    ds = open_dataset(quick_dataset)
    m = ds.manifest.set_index("flight_id")
    attacked = m[m["mode"] != "normal"]
    assert len(attacked) and not attacked["no_effect"].any()
    for fid, row in attacked.iterrows():
        # differs from its simulator view (or csv source) inside its window, on the table detectors read
        nav, sim = ds.flight(fid, "navigator"), ds.flight(fid, "simulator")
        inside = nav["Is_Anomaly"].to_numpy() == 1
        cols = [c for c in nav.columns if "." in c and c in sim.columns]
        ref = sim.set_index("Timestamp").reindex(nav["Timestamp"], method="ffill")[cols].to_numpy()
        assert (nav[cols].to_numpy()[inside] != ref[inside]).any(), fid
        assert row["effect_rows"] > 0 and row["effect_fields"] > 0 and np.isfinite(row["detectability"])
    csv = attacked[attacked["mode"] == "csv"]
    assert len(csv) and csv["source_flight"].map(m["split"]).eq("csv_source").all()
    assert not attacked["source_flight"].isin(m.index[m["split"].isin(["train", "validation"])]).any()
    splits = Splits.from_manifest(ds.manifest)
    assert set(splits.csv_source).isdisjoint(splits.scored + splits.train)


def _manifest(rows):
    return pd.DataFrame(rows, columns=["flight_id", "mode", "split", "source_flight", "no_effect"])


def test_protocol_refuses_a_csv_copy_of_a_train_or_validation_flight():
    rows = [("a", "normal", "train", "", False), ("b", "normal", "validation", "", False),
            ("c", "normal", "csv_source", "", False)]
    ok = _manifest([*rows, ("x", "csv", "test", "c", False)])
    assert assign_roles(ok).tolist() == ["train", "validation", "csv_source", "test_attacked"]
    for src, split in (("a", "train"), ("b", "validation")):
        with pytest.raises(ProtocolError, match=f"replays '{src}', a {split} flight"):
            assign_roles(_manifest([*rows, ("x", "csv", "test", src, False)]))


def test_no_effect_flights_are_left_out_and_listed():
    m = _manifest([("a", "normal", "train", "", False), ("b", "normal", "validation", "", False),
                   ("x", "simulation", "test", "", False), ("y", "simulation", "test", "", True)])
    s = Splits.from_manifest(m)
    assert (s.test_attacked, s.no_effect) == (("x",), ("y",)) and "y" not in s.scored
    metrics = pd.DataFrame([{"detector": "d", "status": "OK", "n_simulation": 1, "n_csv": 0, "n_no_attack": 0}])
    text = "\n".join(rate_summary(metrics, list(s.no_effect)))
    assert "(no_effect, excluded from every rate): 1: y" in text
