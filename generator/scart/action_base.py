"""The base class of the attack actions and what they share (lat/lon as metres, limits).

See :mod:`scart_bench.generator.scart.actions` for the actions themselves.
"""
from __future__ import annotations

import numpy as np

from scart_bench.generator import geo
from scart_bench.generator.scart import units
from scart_bench.generator.scart.spec import Param

TARGET = Param("target", list, required=True, help='list of "topic" or "topic.field"', item=str, min_items=1)
#: Deepest history an action may reach back (messages): 30 min of a 50 Hz topic.
MAX_HISTORY_MESSAGES = 90_000
#: Longest delay or window an action may hold (s).
MAX_DELAY_S = 1800.0
DIRECTION = Param("direction_deg", float, 45.0, help="heading of a displacement, 0 = north")


class Action:
    """Base class. ``apply`` returns the altered values and the delivered mask."""

    name = "action"
    spec: tuple[Param, ...] = ()
    #: True for actions that need random numbers on every message of a target topic
    random = False
    #: True for actions whose magnitudes are lengths: lat/lon are edited as metres (see module doc)
    metric = False
    #: True for actions on whole messages in both directions of the link (telemetry and commands)
    bidirectional = False
    #: injection points the action can act at (empty: the scenario's own point)
    points: tuple[str, ...] = ()

    def __init__(self, params: dict, fields: dict[str, tuple[int, ...]], field_names: dict[str, tuple[str, ...]]):
        self.params = params
        self.fields = fields  # topic -> indices of the target fields
        self.field_names = field_names  # topic -> all field names of the topic
        self.v0: dict[str, np.ndarray] = {}
        self.v0_start: dict[str, np.ndarray] = {}
        self.n_since: dict[str, np.ndarray] = {}

    @classmethod
    def wildcard(cls, available: dict[str, tuple[str, ...]]) -> list[str]:
        """The targets of ``target = ["*"]``: every topic that passes."""
        return sorted(available)

    def lookback(self, topic: str, rate_hz: float) -> int:
        """Messages of history this action needs for ``topic``."""
        return 1

    def _cached(self, key: tuple, make) -> np.ndarray:
        """``make()``, kept: parameters and targets never change after construction (read-only)."""
        cache = self.__dict__.setdefault("_cache", {})
        out = cache.get(key)
        if out is None:
            out = cache[key] = make()
            out.flags.writeable = False
        return out

    def p(self, name: str) -> np.ndarray:
        """A numeric parameter as a column (N, 1) for broadcasting over fields."""
        return self._cached(("p", name), lambda: np.array(self.params[name], dtype=float).reshape(-1, 1))

    def scales(self, topic: str) -> np.ndarray:
        names = self.field_names[topic]
        return self._cached(("scales", topic), lambda: np.array([units.scale(topic, names[i])
                                                                   for i in self.fields[topic]]))

    def signed(self, topic: str) -> np.ndarray:
        """(N, F) field units per physical unit along each flight's direction."""
        names = self.field_names[topic]

        def make():
            d = np.deg2rad(np.asarray(self.params.get("direction_deg", 45.0), dtype=float)).reshape(-1)
            return np.array([[units.signed(topic, names[i], di) for i in self.fields[topic]] for di in d])
        return self._cached(("signed", topic), make)

    def start_values(self, ctx, topic: str, current: np.ndarray) -> np.ndarray:
        """Values of the target fields when the attack started (captured on its first message)."""
        if topic not in self.v0:
            self.v0[topic] = np.full_like(current, np.nan)
            self.v0_start[topic] = np.full(current.shape[0], -1, dtype=np.int64)
        fresh = self.v0_start[topic] != ctx.start_us
        if fresh.any():
            self.v0[topic][fresh] = current[fresh]
            self.v0_start[topic][fresh] = ctx.start_us[fresh]
        return self.v0[topic]

    def messages_since_start(self, ctx, topic: str) -> np.ndarray:
        """Index of this message among the target topic's messages since the attack started."""
        if topic not in self.n_since:
            self.n_since[topic] = np.zeros(ctx.rows.shape[0], dtype=np.int64)
            self.v0_start.setdefault("__count__" + topic, np.full(ctx.rows.shape[0], -1, dtype=np.int64))
        key = "__count__" + topic
        fresh = self.v0_start[key] != ctx.start_us
        self.n_since[topic][fresh] = 0
        self.v0_start[key][fresh] = ctx.start_us[fresh]
        out = self.n_since[topic].copy()
        self.n_since[topic] += 1
        return out

    def idle_draws(self, topic: str) -> int | None:
        """Standard normals (per flight) ``apply`` draws on a message of ``topic`` while no flight of
        the group is active, where that is all it does (the layer then only draws them); None: call
        ``apply``."""
        return None

    def apply(self, ctx, topic: str, values: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Alter ``values`` (N, F, a copy) where ``active``; returns (values, delivered)."""
        got = self.__dict__.setdefault("_targets", {}).get(topic)
        if got is None:  # the target columns and the lat/lon pair of a topic never change
            got = self._targets[topic] = (list(self.fields[topic]), units.latlon_pair(
                topic, self.field_names[topic]) if self.metric else None)
        idx, pair = got
        idx = list(idx)
        if pair is None or not active.any():  # inactive: alter only for its random draws, nothing changes
            cur = values[:, idx]
            new, delivered = self.alter(ctx, topic, cur, active)
            values[:, idx] = np.where(active[:, None], new, cur)
            return values, np.where(active, delivered, True)
        work = to_metres(ctx, values, pair)
        cur = work[:, idx]
        new, delivered = self.alter(ctx, topic, cur, active)
        work[:, idx] = new
        return from_metres(ctx, values, work, pair, idx, active), np.where(active, delivered, True)

    def alter(self, ctx, topic: str, cur: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError


def _origin(ctx, values: np.ndarray, pair: tuple[int, int]) -> np.ndarray:
    """(N, 2) lat/lon origin of each flight; a flight with none yet uses this message's position."""
    o = np.array(ctx.origin, dtype=np.float64, copy=True)
    unknown = ~np.isfinite(o).all(axis=1)
    if unknown.any():
        o[unknown, 0] = values[unknown, pair[0]]
        o[unknown, 1] = values[unknown, pair[1]]
    return o


def _origin_and_ecef(ctx, values: np.ndarray, pair: tuple[int, int]) -> tuple[np.ndarray, tuple | None]:
    """:func:`_origin` and, once the origins are fixed, their ECEF (kept by the context)."""
    fixed = getattr(ctx, "fixed_origin", None)
    got = fixed() if fixed is not None else None
    return got if got is not None else (_origin(ctx, values, pair), None)


def to_metres(ctx, values: np.ndarray, pair: tuple[int, int]) -> np.ndarray:
    """A copy of ``values`` with the lat/lon columns ``pair`` as north/east metres from the origin."""
    work = values.copy()
    o, ecef0 = _origin_and_ecef(ctx, values, pair)
    n, e = geo.ne_from_latlon(values[:, pair[0]], values[:, pair[1]], o[:, 0], o[:, 1], ecef0)
    work[:, pair[0]], work[:, pair[1]] = n, e
    return work


def from_metres(ctx, values: np.ndarray, work: np.ndarray, pair: tuple[int, int], idx: list[int],
                active: np.ndarray) -> np.ndarray:
    """``values`` with the target columns ``idx`` taken from ``work`` where ``active`` (metres ->
    lat/lon for the pair); everything else unchanged, bit for bit."""
    out = values.copy()
    o, ecef0 = _origin_and_ecef(ctx, values, pair)
    lat, lon = geo.latlon_from_ne(work[:, pair[0]], work[:, pair[1]], o[:, 0], o[:, 1], ecef0)
    back = work.copy()
    back[:, pair[0]], back[:, pair[1]] = lat, lon
    out[:, idx] = np.where(active[:, None], back[:, idx], values[:, idx])
    return out


def keep_where(n: int) -> np.ndarray:
    return np.ones(n, dtype=bool)
