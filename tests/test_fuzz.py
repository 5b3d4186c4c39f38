"""Fuzz tests: the scenario parser and the CSV importer take any input and either give a valid result
or the project's own error (a ScartBenchError with a message), never another exception."""

from __future__ import annotations

import math
import string

import pytest

hypothesis = pytest.importorskip("hypothesis", reason="hypothesis is in the dev extra (make test installs it)")
from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from scart_bench.errors import ScartBenchError  # noqa: E402
from scart_bench.generator.logs.importers import load_flight_file  # noqa: E402
from scart_bench.generator.scart.actions import ACTIONS  # noqa: E402
from scart_bench.generator.scart.conditions import CONDITIONS  # noqa: E402
from scart_bench.generator.scart.scenario import Scenario, scenario_from_dict  # noqa: E402
from scart_bench.generator.scart.spec import ScenarioError  # noqa: E402

FUZZ = settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow],
                derandomize=True)

_KEYS = sorted({"id", "injection_point", "listeners", "start", "end", "actions", "max_windows", "kind", "callback",
                "description", "condition", "action", "target", "std", "offset", "k", "start_s", "end_s", "seconds",
                "low_s", "high_s", "topic", "count", "center", "radius", "rate_deg_s", "delay_s", "factor",
                "window", "probability", "scenario", "after_s", "direction_deg", "speed", "motor"})
_NAMES = sorted({*ACTIONS, *CONDITIONS, "attitude", "attitude.roll", "global_position_int", "link", "sensor",
                 "environment", "vehicle", "command", "attack", "fault", "../x", "a/b", ""})
_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(_NAMES),
    st.text(alphabet=string.printable, max_size=20))
_values = st.recursive(_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.sampled_from(_KEYS), inner, max_size=5)), max_leaves=12)
_tables = st.dictionaries(st.sampled_from(_KEYS), _values, max_size=8)


@FUZZ
@given(table=st.one_of(_tables, _values))
@example(table={"start": {"condition": []}})  # found by this test: a list as the condition's name
def test_scenario_parser_gives_a_scenario_or_a_scenario_error(table):
    try:
        sc = scenario_from_dict(table, source="fuzz.toml")
    except ScenarioError as exc:
        assert str(exc).startswith("fuzz.toml"), exc
        return
    assert isinstance(sc, Scenario) and sc.actions
    for _, p in sc.actions + sc.start + sc.end:
        for v in p.values():
            assert not (isinstance(v, float) and math.isnan(v))


_cells = st.one_of(st.integers(min_value=-(10**20), max_value=10**20).map(str),
                   st.floats(allow_nan=True, allow_infinity=True).map(repr),
                   st.sampled_from(["", "inf", "-inf", "nan", "NaN", "1e400", "abc", "0x10", "1,5", '"q"', " "]),
                   st.text(alphabet=string.printable.replace("\r", ""), max_size=8))
_headers = st.lists(st.sampled_from(["timestamp", "Timestamp", "time", "t", "x", "y", "a.b", "gps.lat", "", "x"]),
                    min_size=1, max_size=5)


@FUZZ
@given(header=_headers, rows=st.lists(st.lists(_cells, min_size=0, max_size=6), max_size=12),
       raw=st.binary(max_size=64))
def test_csv_importer_gives_topics_or_its_own_error(tmp_path_factory, header, rows, raw):
    f = tmp_path_factory.mktemp("fuzz") / "flight.csv"
    text = ",".join(header) + "\n" + "\n".join(",".join(r) for r in rows)
    f.write_bytes(text.encode("utf-8", "replace") + (raw if len(rows) % 3 == 0 else b""))
    try:
        topics = load_flight_file(f)
    except ScartBenchError as exc:
        assert str(f) in str(exc) or "flight.csv" in str(exc), exc
        return
    assert isinstance(topics, dict) and topics
    for df in topics.values():
        ts = df["Timestamp"].to_numpy()
        assert (ts[1:] >= ts[:-1]).all()
