"""Conformance checks for detectors: the same checks the built-ins pass, for a plugin author's own class.

Plain Python (no pytest needed)::

    from scart_bench.testing import check_detector
    check_detector(MyDetector, params={"window": 10})     # AssertionError naming the failed check

With pytest, one test case per check::

    from scart_bench.testing import detector_checks

    @pytest.mark.parametrize("check", detector_checks(MyDetector), ids=str)
    def test_conformance(check):
        check()

The flights are real: a small batch of normal flights from the built-in generator (flown once per
process and cached), in the combined navigator-view layout that ``fit`` and ``score`` receive in a
benchmark run. ``params`` should keep a fit on two short flights quick (e.g. one epoch).
"""

from __future__ import annotations

import copy
import inspect
import pickle
import random
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import pandas as pd

from scart_bench.detectors.base import Detector, DetectorError, NotFittedError

#: Seeds of the generated flights that the checks use (a fixed, small fleet).
FLEET_SEEDS = tuple(range(9000, 9012))
#: Fraction of the rows of the attacked flight, (start, end), where the attack is active.
ATTACK_WINDOW = (0.4, 0.6)
#: Standard deviation of the position noise of the attacked flight, metres.
ATTACK_NOISE_M = 20.0
POSITION_FIELDS = ["global_position_int.lat", "global_position_int.lon", "local_position_ned.x",
                   "local_position_ned.y", "gps_raw_int.lat", "gps_raw_int.lon"]


# -- flights ------------------------------------------------------------------------------------

@lru_cache(maxsize=1)
def _fleet() -> tuple[dict[str, pd.DataFrame], ...]:
    from scart_bench.dataset import LABEL_COLUMNS
    from scart_bench.generator.engine.simulate import simulate
    from scart_bench.generator.telemetry.tables import flight_views

    batch = simulate(list(FLEET_SEEDS))
    views = []
    for i in range(len(FLEET_SEEDS)):
        nav, _ = flight_views(batch, i)
        views.append({t: df.drop(columns=list(LABEL_COLUMNS)) for t, df in nav.items()})
    return tuple(views)


def _pick(n: int, seed: int) -> list[int]:
    size = len(FLEET_SEEDS)
    if not 0 < n <= size:
        raise ValueError(f"n={n}: expected 1..{size} flights")
    start = (seed * 4) % size
    return [(start + k) % size for k in range(n)]


def normal_flights(n: int, seed: int, rows: int = 1500) -> list[pd.DataFrame]:
    """``n`` generated normal flights (navigator ``most_frequent`` tables), the first ``rows`` rows of each.

    ``seed`` picks which flights of the cached fleet are returned (same seed, same flights).
    """
    from scart_bench.dataset import combine

    fleet = _fleet()
    return [combine(fleet[i], [])["most_frequent"].iloc[:rows].reset_index(drop=True) for i in _pick(n, seed)]


def attacked_flight(seed: int, rows: int = 1500) -> pd.DataFrame:
    """A normal flight with 20 m GPS noise injected on the link over the middle fifth of ``rows``."""
    from scart_bench.dataset import combine
    from scart_bench.generator.modes import csv_mode
    from scart_bench.generator.scart.scenario import scenario_from_dict

    topics = _fleet()[_pick(1, seed)[0]]
    t_end = int(topics["attitude"]["Timestamp"].iloc[min(rows, len(topics["attitude"])) - 1])
    start_s = ATTACK_WINDOW[0] * t_end / 1e6
    seconds = (ATTACK_WINDOW[1] - ATTACK_WINDOW[0]) * t_end / 1e6
    scenario = scenario_from_dict({
        "id": "gps-noise-20m", "start": [{"condition": "time_window", "start_s": start_s}],
        "end": [{"condition": "duration", "seconds": seconds}],
        "actions": [{"action": "add_white_noise", "target": POSITION_FIELDS, "std": ATTACK_NOISE_M}]})
    (nav, windows, _), = csv_mode([topics], [[scenario]], [seed])
    return combine(nav, windows)["most_frequent"].iloc[:rows].reset_index(drop=True)


# -- the subject of the checks ------------------------------------------------------------------

@dataclass
class _Subject:
    """A detector class with the parameters to check it with, fitted once on demand."""

    cls: type
    params: dict
    _fitted: Detector | None = field(default=None, repr=False)

    @property
    def label(self) -> str:
        return getattr(self.cls, "name", None) or self.cls.__name__

    def fresh(self, **overrides) -> Detector:
        return self.cls(**{**self.params, **overrides})

    def fitted(self) -> Detector:
        if self._fitted is None:
            self._fitted = self.fresh().fit(train_flights())
        return self._fitted


@lru_cache(maxsize=1)
def _small_data() -> tuple[tuple[pd.DataFrame, ...], pd.DataFrame]:
    return tuple(normal_flights(2, seed=10, rows=500)), normal_flights(1, seed=11, rows=300)[0]


def train_flights() -> list[pd.DataFrame]:
    """The two short training flights of the checks."""
    return list(_small_data()[0])


def probe_flight() -> pd.DataFrame:
    """The short held-out flight the checks score."""
    return _small_data()[1]


def _raises(exc_type: type[BaseException], fn: Callable[[], object], what: str) -> BaseException:
    try:
        fn()
    except exc_type as exc:
        return exc
    except Exception as exc:  # noqa: BLE001 - reported as a conformance failure
        raise AssertionError(f"{what}: expected {exc_type.__name__}, got {type(exc).__name__}: {exc}") from exc
    raise AssertionError(f"{what}: expected {exc_type.__name__}, nothing was raised")


# -- the checks ---------------------------------------------------------------------------------

def check_is_detector(s: _Subject) -> None:
    """A Detector subclass with a ``name`` and a ``description``."""
    assert inspect.isclass(s.cls) and issubclass(s.cls, Detector), (
        f"{s.cls!r} is not a subclass of scart_bench.detectors.base.Detector")
    name = s.cls.__dict__.get("name")
    assert isinstance(name, str) and name and name != "detector", (
        f"{s.cls.__name__} must set a class attribute `name` (the name users type in --detectors)")
    desc = s.cls.description or (s.cls.__doc__ or "").strip()
    assert desc, f"{s.cls.__name__} has neither a `description` nor a docstring"


def check_takes_what_the_run_passes(s: _Subject) -> None:
    """What a run passes is declared: ``random_state`` and ``columns`` are constructor parameters, and
    ``fit(flights, features=..., exclude=...)`` applies the run's feature rule."""
    signature = inspect.signature(s.cls.__init__).parameters
    for name in ("random_state", "columns"):
        assert name in signature, f"{s.label}: __init__ lacks the parameter {name!r} the run passes"
    fit_params = inspect.signature(s.cls.fit).parameters
    for name in ("features", "exclude"):
        assert name in fit_params, f"{s.label}.fit lacks the keyword argument {name!r} (the run's --{name})"
    wanted = [c for c in s.fitted().columns_ if not c.endswith((":sin", ":cos"))][:3]
    detector = s.fresh().fit(train_flights(), features=wanted, exclude=[wanted[-1]])
    assert list(detector.columns_) == wanted[:-1], (
        f"{s.label}: fit(features={wanted}, exclude={[wanted[-1]]}) used the columns {list(detector.columns_)}, "
        f"expected {wanted[:-1]}")


def check_init_only_stores_parameters(s: _Subject) -> None:
    """``__init__`` stores its arguments unchanged and sets no fitted attribute (scikit-learn rule)."""
    params = {**s.params, "random_state": 7, "columns": None}
    try:
        detector = s.fresh(random_state=7, columns=None)
    except TypeError as exc:
        raise AssertionError(f"{s.label}: __init__ must accept the shared parameters `columns` and "
                             f"`random_state` ({exc})") from exc
    fitted_attrs = [k for k in vars(detector) if k.endswith("_")]
    assert fitted_attrs == [], f"{s.label}: __init__ sets fitted attributes {fitted_attrs} (do that in fit)"
    signature = inspect.signature(type(detector).__init__).parameters
    expected = {k: p.default for k, p in signature.items() if k != "self"
                and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)} | params
    try:
        got = detector.get_params()
    except AttributeError as exc:
        raise AssertionError(f"{s.label}: get_params() fails ({exc}): store each constructor argument "
                             "unchanged under its own name") from exc
    assert got == expected, (f"{s.label}: get_params() {got} differs from the constructor arguments "
                             f"{expected}: store each argument unchanged under its own name")
    from sklearn.base import clone

    assert clone(detector).get_params() == expected, f"{s.label}: sklearn.base.clone changes the parameters"


def check_fit_leaves_parameters_unchanged(s: _Subject) -> None:
    """``fit`` does not change the constructor parameters."""
    before = copy.deepcopy(s.fresh().get_params())
    after = s.fitted().get_params()
    assert after == before, f"{s.label}: fit changed the parameters from {before} to {after}"


def check_score_before_fit_raises(s: _Subject) -> None:
    """Scoring an unfitted detector raises NotFittedError."""
    _raises(NotFittedError, lambda: s.fresh().score(probe_flight()), f"{s.label}.score before fit")


def check_fit_without_flights_raises(s: _Subject) -> None:
    """Fitting on no flights raises DetectorError."""
    _raises(DetectorError, lambda: s.fresh().fit([]), f"{s.label}.fit([])")


def check_missing_column_is_named(s: _Subject) -> None:
    """A flight lacking a trained column raises DetectorError naming that column."""
    detector = s.fitted()
    column = detector.columns_[len(detector.columns_) // 2]
    exc = _raises(DetectorError, lambda: detector.score(probe_flight().drop(columns=[column])),
                  f"{s.label}.score on a flight without {column!r}")
    assert column in str(exc), f"{s.label}: the error for a missing column does not name it: {exc}"


def check_one_finite_score_per_row(s: _Subject) -> None:
    """``score`` gives one finite float64 per row."""
    probe = probe_flight()
    scores = s.fitted().score(probe)
    assert isinstance(scores, np.ndarray), f"{s.label}.score returned {type(scores).__name__}, not a numpy array"
    assert scores.dtype == np.float64, f"{s.label}.score returned dtype {scores.dtype}, expected float64"
    assert scores.shape == (len(probe),), f"{s.label}.score returned shape {scores.shape} for {len(probe)} rows"
    bad = np.flatnonzero(~np.isfinite(scores))
    assert bad.size == 0, f"{s.label}.score returned {bad.size} non-finite scores (first at row {bad[0] if bad.size else ''})"


def check_pickle_round_trip(s: _Subject) -> None:
    """A fitted detector survives pickling (jobs run in worker processes) and scores the same."""
    detector = s.fitted()
    restored = pickle.loads(pickle.dumps(detector))
    np.testing.assert_array_equal(restored.score(probe_flight()), detector.score(probe_flight()),
                                  err_msg=f"{s.label}: scores change after a pickle round trip")


def check_same_seed_same_scores(s: _Subject) -> None:
    """The same ``random_state`` and flights give identical scores (determinism)."""
    again = s.fresh().fit(train_flights())
    np.testing.assert_array_equal(again.score(probe_flight()), s.fitted().score(probe_flight()),
                                  err_msg=f"{s.label}: two fits with the same random_state score differently")


def check_causal_scores(s: _Subject) -> None:
    """Scores of the first k rows do not depend on later rows (batch scores = streaming scores)."""
    probe = probe_flight()
    detector = s.fitted()
    full = detector.score(probe)
    for k in (1, 2, 37, len(probe) // 2 + 3):
        np.testing.assert_allclose(detector.score(probe.iloc[:k]), full[:k], rtol=1e-6, atol=1e-9,
                                   err_msg=f"{s.label}: the scores of the first {k} rows change when later "
                                           "rows are added (scores must be causal)")


def check_no_global_side_effects(s: _Subject) -> None:
    """Fitting and scoring leave the global random generators (numpy, random, torch) as they were."""
    torch = sys.modules.get("torch")
    np_state, py_state = np.random.get_state(), random.getstate()
    torch_state = torch.get_rng_state() if torch is not None else None
    s.fresh(random_state=5).fit(train_flights()).score(probe_flight())
    after = np.random.get_state()
    assert all(np.array_equal(a, b) for a, b in zip(np_state, after)), (
        f"{s.label}: fit/score changed numpy's global random state (use a local Generator)")
    assert random.getstate() == py_state, f"{s.label}: fit/score changed the `random` module's state"
    if torch_state is not None:
        assert torch.equal(torch.get_rng_state(), torch_state), f"{s.label}: fit/score changed torch's global RNG"


CHECKS: tuple[Callable[[_Subject], None], ...] = (
    check_is_detector,
    check_takes_what_the_run_passes,
    check_init_only_stores_parameters,
    check_fit_leaves_parameters_unchanged,
    check_score_before_fit_raises,
    check_fit_without_flights_raises,
    check_missing_column_is_named,
    check_one_finite_score_per_row,
    check_pickle_round_trip,
    check_same_seed_same_scores,
    check_causal_scores,
    check_no_global_side_effects,
)


@dataclass(frozen=True)
class DetectorCheck:
    """One conformance check bound to one detector class; call it to run it."""

    subject: _Subject
    check: Callable[[_Subject], None]

    @property
    def name(self) -> str:
        return self.check.__name__.removeprefix("check_")

    def __str__(self) -> str:
        return f"{self.subject.label}-{self.name}"

    def __call__(self) -> None:
        self.check(self.subject)


def detector_checks(detector_cls: type, params: dict | None = None) -> list[DetectorCheck]:
    """Every conformance check for ``detector_cls`` (constructed with ``params``), one callable each.

    The checks of one class share one fitted detector, so the whole list costs about two fits.
    """
    subject = _Subject(detector_cls, dict(params or {}))
    return [DetectorCheck(subject, c) for c in CHECKS]


def check_detector(detector_cls: type, params: dict | None = None) -> None:
    """Run every conformance check on ``detector_cls``; AssertionError naming the first failed check."""
    for check in detector_checks(detector_cls, params):
        try:
            check()
        except AssertionError as exc:
            raise AssertionError(f"{detector_cls.__name__} fails the conformance check "
                                 f"{check.name!r} ({check.check.__doc__.strip()}): {exc}") from exc
