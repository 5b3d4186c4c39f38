"""The SCART layer: a man-in-the-middle that runs scenarios on every message passing through it.

For each batch of flights the layer holds scenario *groups*: flights whose scenarios differ only
in numeric parameters run as one group with per-flight parameter arrays. On every call at an
injection point the layer (1) appends the messages of listened topics to the History (before any
change), (2) runs each group's callback: the vanilla one starts the attack when all start
conditions hold and stops it when any end condition holds, (3) applies the active groups' actions.
It records the attack event log and the windows that become the ``Is_Anomaly`` labels.

Scenarios at the ``environment`` and ``vehicle`` points act on the physics instead: the simulator
calls ``on_physics`` once per step and applies the returned Disturbances. A flight's scenarios are
evaluated in dependency order, so a condition on another scenario sees its state of this step.
In csv mode (``physics=False``) physical scenarios still keep their timing, so chains through them
work, but they change nothing and their windows are not labelled.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from scart_bench.generator.flight_software.commander import CONTROL_TOPICS
from scart_bench.generator.geo import origin_ecef
from scart_bench.generator.physics.disturbances import Disturbances
from scart_bench.generator.physics.noise import NoiseStream
from scart_bench.generator.scart.actions import ACTIONS, Action
from scart_bench.generator.scart.conditions import CONDITIONS, PURE_CONDITIONS, Condition
from scart_bench.generator.scart.effects import EFFECTS
from scart_bench.generator.scart.history import History
from scart_bench.generator.scart.scenario import (
    Scenario,
    check_composition,
    listened_topics,
    point_topics,
    scenario_topics,
)
from scart_bench.generator.scart.spec import ScenarioError
from scart_bench.generator.telemetry.schedule import field_names as builtin_fields


def _stack(items: list[dict]) -> dict:
    """Per-flight parameter arrays from a list of parameter dicts of one structure."""
    out = {}
    for key in items[0]:
        vals = [it[key] for it in items]
        if isinstance(vals[0], int | float) and not isinstance(vals[0], bool):
            out[key] = np.asarray(vals, dtype=float if isinstance(vals[0], float) else np.int64)
        else:
            out[key] = vals[0]
    return out


#: Entry-point group of scenario callbacks: a scenario names one by its entry-point name. A scenario
#: file is data: it can only pick among callbacks installed as plugins, never import a module itself.
CALLBACK_GROUP = "scart_bench.callbacks"


def load_callback(name: str, source: str = "<memory>"):
    """The callback installed under ``name`` in the entry-point group ``scart_bench.callbacks``."""
    from importlib.metadata import entry_points

    found = {ep.name: ep for ep in entry_points(group=CALLBACK_GROUP)}
    if name not in found:
        raise ScenarioError(f"{source}: callback {name!r} is not an installed callback; scenario files name "
                            f"callbacks registered in the entry-point group {CALLBACK_GROUP!r} (installed: "
                            f"{', '.join(sorted(found)) or 'none'})")
    try:
        fn = found[name].load()
    except Exception as exc:  # a broken plugin: say which
        raise ScenarioError(f"{source}: callback {name!r} ({found[name].value}) cannot be loaded: {exc}") from exc
    if not callable(fn):
        raise ScenarioError(f"{source}: callback {name!r} ({found[name].value}) is not callable")
    return fn


def vanilla_callback(ctx, start: np.ndarray, end: np.ndarray, active: np.ndarray, can_start: np.ndarray
                     ) -> np.ndarray:
    """The paper's callback: start when all start conditions hold, stop when any end condition holds."""
    return np.where(active, ~end, start & can_start)


#: Built-in conditions that read only the History (and the origin, learnt from messages): no time,
#: no other scenario's state. Between two messages they keep their value (AttackLayer.next_change).
_UNTIMED = ("message_count", "geofence", "altitude_above", "mission_phase", "flight_phase", "after_phase",
            "airborne")


def _untimed(c: Condition) -> bool:
    return c.name in _UNTIMED and type(c) is CONDITIONS.get(c.name)


class _Context:
    """What conditions and actions see for one group at one call."""

    def __init__(self, layer: AttackLayer, group: _Group, t_us: int):
        self.layer = layer
        self.group = group
        self.t_us = t_us
        self.history = layer.history
        self.rows = group.rows
        self.n_batch = layer.n
        self.start_us = group.start_us

    @property
    def origin(self) -> np.ndarray:
        """(N, 2) latitude/longitude origin (deg) of the group's flights (NaN: none seen yet)."""
        return self.layer.origin[self.rows]

    def fields(self, topic: str) -> tuple[str, ...]:
        return self.layer.fields(topic)

    def fixed_origin(self) -> tuple[np.ndarray, tuple] | None:
        """(origin, its ECEF) of the group's flights once every flight of the batch has its origin
        (it never changes then; read-only), else None."""
        if self.layer._origin_open:
            return None
        g = self.group
        if g.origin_cache is None:
            o = np.array(self.layer.origin[self.rows], dtype=np.float64, copy=True)
            o.flags.writeable = False
            g.origin_cache = (o, origin_ecef(o[:, 0], o[:, 1]))
        return g.origin_cache

    def per_batch(self, values, fill) -> np.ndarray:
        """A per-group parameter spread to the whole batch (other flights get ``fill``)."""
        full = np.full(self.n_batch, fill, dtype=np.asarray(values).dtype)
        full[self.rows] = values
        return full

    def normal(self, action: Action, topic: str, dim: int) -> np.ndarray:
        return self.group.stream(action, topic, dim).next()

    def scenario_state(self, scenario_id: str) -> dict[str, np.ndarray]:
        return self.layer.state_of(scenario_id, self.rows)


class _Group:
    """Flights (rows of the batch) that run scenarios of one structure, in one slot."""

    def __init__(self, layer: AttackLayer, slot: int, scenarios: list[Scenario], rows: np.ndarray,
                 seeds: list[int]):
        first = scenarios[0]
        self.layer = layer
        self.slot = slot
        self.point = first.injection_point
        self.physical = first.physical
        self.kind = first.kind
        self.ids = [s.id for s in scenarios]
        self.rows = rows
        self.seeds = seeds
        self.max_windows = first.max_windows
        n = len(rows)
        key = zlib.crc32(first.structure_key().encode())
        self._rngs = [np.random.default_rng(np.random.SeedSequence([int(s), slot, key])) for s in seeds]
        u = np.array([g.uniform(size=len(first.start) + len(first.end) + 1) for g in self._rngs])
        self.start_conds: list[Condition] = [
            CONDITIONS[name](_stack([s.start[i][1] for s in scenarios]), u[:, i])
            for i, (name, _) in enumerate(first.start)]
        off = len(first.start)
        self.end_conds: list[Condition] = [
            CONDITIONS[name](_stack([s.end[i][1] for s in scenarios]), u[:, off + i])
            for i, (name, _) in enumerate(first.end)]
        self.actions: list[Action] = []
        for i, (name, p) in enumerate(first.actions):
            params = _stack([s.actions[i][1] for s in scenarios])
            if self.physical:
                self.actions.append(EFFECTS[name](params))
                continue
            fields, names = {}, {}
            for t in p["target"]:
                topic, _, fld = t.partition(".")
                all_f = layer.fields(topic)
                names[topic] = all_f
                sel = fields.setdefault(topic, [])
                for f in (all_f if not fld else [fld]):
                    if f not in all_f:
                        raise ScenarioError(f"{first.source}: action {name!r} target {t!r}: no field {f!r} "
                                            f"in {topic} ({', '.join(all_f)})")
                    j = all_f.index(f)
                    if j not in sel:
                        sel.append(j)
            self.actions.append(ACTIONS[name](params, {k: tuple(v) for k, v in fields.items()}, names))
        # the points the group acts at: its own, and for a link action also the command direction
        self.points = {self.point}
        if not self.physical and self.point == "link":
            command = point_topics("command")
            self.points |= {"command" for a in self.actions if a.bidirectional and set(a.fields) & set(command)}
        self.callback = vanilla_callback
        if first.callback:
            self.callback = load_callback(first.callback, first.source)
        self.listeners = set(first.used_topics())
        for c in self.start_conds + self.end_conds:
            self.listeners |= c.topics()
        self.active = np.zeros(n, dtype=bool)
        self.any_active = self.all_active = False  # active.any() and .all(), kept by _transitions
        self.start_us = np.full(n, -1, dtype=np.int64)
        self.end_us = np.full(n, -1, dtype=np.int64)
        self.windows_used = np.zeros(n, dtype=np.int64)
        self._streams: dict[tuple[int, str], NoiseStream] = {}
        # Shortcuts that leave the result unchanged (the paper's callback and the built-in, pure
        # conditions only): a group none of whose flights is active cannot start before its time
        # conditions allow, and never again once every flight has used its windows; the start
        # conditions do not matter while all its flights are active, nor the end ones while none is.
        self._vanilla = self.callback is vanilla_callback and all(
            type(c) in PURE_CONDITIONS for c in self.start_conds + self.end_conds)
        times = [c.earliest_s() for c in self.start_conds] if self._vanilla else []
        self._wake_s = max((t for t in times if t is not None), default=None)
        self._dead = False
        #: the last update changed nothing (see first_change); untimed: its conditions read only
        #: the History (no time, no other scenario), so they hold the same until a message arrives
        self._settled = False
        self._untimed_start = all(_untimed(c) for c in self.start_conds)
        self._untimed_end = all(_untimed(c) for c in self.end_conds)
        #: (action, topic) in the order they act on a message, and those of the random actions
        self.action_targets = [(a, topic) for a in self.actions for topic in a.fields]
        self.random_targets = [(a, topic) for a, topic in self.action_targets if a.random]
        self._ctx: _Context | None = None
        #: the topics the start and the end conditions read (a message of one can change them)
        self._start_topics = set().union(*(c.topics() for c in self.start_conds))
        self._end_topics = set().union(*(c.topics() for c in self.end_conds))
        #: csv replay (AttackLayer.plan_ticks): updates before this time (µs) change nothing, while no
        #: group has changed state since (the layer's epoch) and the conditions that count read no topic
        self._quiet_until = -1
        self._quiet_epoch = -1
        self.origin_cache: tuple[np.ndarray, tuple] | None = None  # see _Context.fixed_origin  # made on first use (the layer's History comes after its groups)

    def stream(self, action: Action, topic: str, dim: int) -> NoiseStream:
        key = (id(action), topic)
        if key not in self._streams:
            self._streams[key] = NoiseStream(self._rngs, dim, chunk=64)
        return self._streams[key]

    def targets(self) -> set[str]:
        out = set()
        for a in self.actions:
            out |= set(a.fields)
        return out

    def lookback(self, rates: dict[str, float]) -> dict[str, int]:
        out: dict[str, int] = {}
        for a in self.actions:
            for topic in a.fields:
                out[topic] = max(out.get(topic, 1), a.lookback(topic, rates.get(topic, 250.0)))
        return out

    @property
    def finished(self) -> bool:
        """True once the group can never act again: no flight active, none may start again (the
        paper's callback), and no random action that must keep drawing."""
        return self._dead and not self.random_targets

    def context(self, t_us: int) -> _Context:
        """The group's context at ``t_us`` (one object, reused)."""
        ctx = self._ctx
        if ctx is None:
            ctx = self._ctx = _Context(self.layer, self, t_us)
        ctx.t_us = t_us
        ctx.start_us = self.start_us
        return ctx

    def update(self, t_us: int) -> _Context:
        """Evaluate the callback; log transitions."""
        if t_us < self._quiet_until and self._quiet_epoch == self.layer._epoch:
            return self.context(t_us)  # a change point further on: this update would change nothing
        ctx = self.context(t_us)
        self._settled = True  # until _transitions changes something
        if self._vanilla:
            epoch = self.layer._epoch
            self._update_vanilla(ctx, t_us)
            if self.layer._ticks is not None and self.layer._epoch == epoch:
                self._plan_quiet(t_us)
                ctx = self.context(t_us)  # first_change moved its time
            return ctx
        start, end = self._conditions(ctx)
        can_start = self.windows_used < self.max_windows
        new_active = np.asarray(self.callback(ctx, start, end, self.active, can_start), dtype=bool)
        self._transitions(new_active, t_us)
        return ctx

    def _update_vanilla(self, ctx: _Context, t_us: int) -> _Context:
        """``update`` for the paper's callback and pure conditions, skipping what cannot matter."""
        if self._dead:
            return ctx
        active = self.active
        if not self.any_active:
            if self._wake_s is not None and t_us / 1e6 < self._wake_s:
                return ctx  # a time condition is False for every flight: nothing starts
            can_start = self.windows_used < self.max_windows
            if not can_start.any():
                self._dead = True  # no flight active and none may start again
                return ctx
            start = np.ones(len(self.rows), dtype=bool)
            for c in self.start_conds:
                start &= np.asarray(c(ctx), dtype=bool)
                if not start.any():
                    return ctx  # nothing starts
            self._transitions(start & can_start, t_us)
            return ctx
        if self.all_active:
            end = np.zeros(len(self.rows), dtype=bool)
            for c in self.end_conds:
                end |= np.asarray(c(ctx), dtype=bool)
            if not end.any():
                return ctx  # every flight stays active
            self._transitions(~end, t_us)
            return ctx
        start, end = self._conditions(ctx)
        can_start = self.windows_used < self.max_windows
        self._transitions(np.where(active, ~end, start & can_start), t_us)
        return ctx

    def _plan_quiet(self, t_us: int, span: int = 512) -> None:
        """After an update at ``t_us`` that changed nothing: the time of the next of the replay's
        calls (AttackLayer.plan_ticks) at which an update could change this group, looking ``span``
        calls ahead, when what its conditions read is time and state only (no message can change
        them). The updates before it are left out: the same as making them (the same comparisons as
        :meth:`first_change`); any group's transition (the layer's epoch) ends the span."""
        if self._dead:
            return
        ticks = self.layer._ticks
        lo = int(np.searchsorted(ticks, t_us, side="right"))
        part = ticks[lo:lo + span]
        if not len(part):
            return
        k = self.first_change(part)
        until = int(part[k]) if k < len(part) else (
            int(ticks[lo + span]) if lo + span < len(ticks) else np.iinfo(np.int64).max)
        # a message of a topic the conditions that count read: the update at its time is made
        topics = (self._start_topics if not self.all_active else set()) | (self._end_topics if self.any_active else set())
        for topic in topics:
            arrive = self.layer._arrivals.get(topic)
            if arrive is None:
                continue  # not in the replay: no message of it arrives
            j = int(np.searchsorted(arrive, t_us, side="right"))
            if j < len(arrive):
                until = min(until, int(arrive[j]))
        self._quiet_until = until
        self._quiet_epoch = self.layer._epoch

    def first_change(self, ticks: np.ndarray) -> int:
        """Index of the first of ``ticks`` (µs, ascending, after the last call) at which ``update``
        could change this vanilla group's state when no message it listens to arrives in between
        (len(ticks) if at none): its pure conditions evaluated on all the ticks at once, the time
        as a column (the same comparisons as one call per tick)."""
        m = len(ticks)
        if self._dead:
            return m
        can_start = self.windows_used < self.max_windows
        if not self.any_active and not can_start.any():
            return m  # the next update marks the group dead: no transition
        if self._settled and (self._untimed_start or self.all_active) and (self._untimed_end or not self.any_active):
            return m  # what it evaluated last time reads only the History, which has not changed
        ctx = self.context(int(ticks[0]))
        ctx.t_us = ticks[:, None]
        try:
            n = len(self.rows)
            start = end = None
            if not self.all_active:
                start = np.ones((m, n), dtype=bool)
                for c in self.start_conds:
                    start &= np.asarray(c(ctx), dtype=bool)
            if self.any_active:
                end = np.zeros((m, n), dtype=bool)
                for c in self.end_conds:
                    end |= np.asarray(c(ctx), dtype=bool)
        finally:
            ctx.t_us = int(ticks[0])
        if end is None:
            hit = (start & can_start).any(axis=1)
        elif start is None:
            hit = end.any(axis=1)
        else:
            hit = (np.where(self.active, ~end, start & can_start) != self.active).any(axis=1)
        return int(np.argmax(hit)) if hit.any() else m

    def _conditions(self, ctx: _Context) -> tuple[np.ndarray, np.ndarray]:
        """Every start condition and'ed, every end condition or'ed, per flight of the group."""
        n = len(self.rows)
        start = np.ones(n, dtype=bool)
        for c in self.start_conds:
            start &= np.asarray(c(ctx), dtype=bool)
        end = np.zeros(n, dtype=bool)
        for c in self.end_conds:
            end |= np.asarray(c(ctx), dtype=bool)
        return start, end

    def _transitions(self, new_active: np.ndarray, t_us: int) -> None:
        """Take ``new_active``: log starts and ends."""
        began = new_active & ~self.active
        ended = self.active & ~new_active
        self._settled = self._settled and not (began.any() or ended.any())
        if not self._settled:
            self.layer._epoch += 1  # a state other groups' conditions may read, and this group's own
        if began.any():
            self.start_us[began] = t_us
            self.windows_used[began] += 1
            for r in np.flatnonzero(began):
                self.layer.log(int(self.rows[r]), t_us, "start", self.ids[r], self.kind)
        if ended.any():
            self.end_us[ended] = t_us
            for r in np.flatnonzero(ended):
                self.layer.log(int(self.rows[r]), t_us, "end", self.ids[r], self.kind)
        self.active = new_active
        self.any_active = bool(new_active.any())
        self.all_active = bool(new_active.all())


@dataclass
class Event:
    """One entry of the attack event log."""

    flight: int
    timestamp_us: int
    event: str
    scenario_id: str
    kind: str


class AttackLayer:
    """The layer for a batch: ``scenarios[i]`` is the list of scenarios of flight ``i``."""

    def __init__(self, scenarios: list[list[Scenario]], seeds: list[int],
                 fields: dict[str, tuple[str, ...]] | None = None, rates: dict[str, float] | None = None,
                 physics: bool = True, origin: np.ndarray | None = None):
        self.n = len(scenarios)
        self.physics = physics
        #: each flight's origin (lat, lon in deg): the tangent plane where metres meet degrees.
        #: Given, or learnt from the first message with a valid lat/lon pair (see learn_origin).
        self.origin = np.full((self.n, 2), np.nan)
        if origin is not None:
            self.origin[:] = np.asarray(origin, dtype=np.float64).reshape(-1, 2)[:, :2]
        self._origin_open = not np.isfinite(self.origin).all()
        scenarios = [check_composition(lst, lst[0].source if lst else "<memory>") for lst in scenarios]
        given = dict(fields) if fields is not None else None
        resolved: dict[int, Scenario] = {}
        for lst in scenarios:  # quantities -> this input's topics (the same object resolves once)
            for sc in lst:
                if id(sc) not in resolved:
                    resolved[id(sc)] = (sc.resolved(given) if given is not None else
                                        sc.resolved(scenario_topics(sc.injection_point, sc.actions),
                                                    listened_topics()))
        scenarios = [[resolved[id(sc)] for sc in lst] for lst in scenarios]
        self._state_maps: dict[tuple[str, int], list | tuple] = {}
        self._fields = dict(fields or {})
        self.events: list[Event] = []
        self.groups: list[_Group] = []
        by_key: dict[tuple[int, str], list[int]] = {}
        for i, lst in enumerate(scenarios):
            for slot, sc in enumerate(lst):
                by_key.setdefault((slot, sc.structure_key()), []).append(i)
        for (slot, _), rows in sorted(by_key.items(), key=lambda kv: (kv[0][0], kv[1][0])):
            scs = [scenarios[i][slot] for i in rows]
            self.groups.append(_Group(self, slot, scs, np.asarray(rows), [seeds[i] for i in rows]))
        self.physical_groups = [g for g in self.groups if g.physical]
        self._live = list(self.groups)  # the groups on_messages still runs (see _Group.finished)
        self.physical_ids = {sid for g in self.physical_groups for sid in g.ids}
        self.points = frozenset(p for g in self.groups if not g.physical for p in g.points)
        depths: dict[str, int] = {}
        for g in self.groups:
            for topic, d in g.lookback(rates or {}).items():
                depths[topic] = max(depths.get(topic, 1), d)
        self.history = History(self.n, depths)
        self.listened = set().union(*(g.listeners | g.targets() for g in self.groups)) if self.groups else set()
        # the simulator calls a point when a group acts there or a listener needs its messages
        self.points = self.points | {p for p in ("link", "sensor", "command") if self.listened & set(point_topics(p))}
        self.final_us: int | None = None
        #: csv replay: the times of every call to come, ascending (plan_ticks); None: not known
        self._ticks: np.ndarray | None = None
        self._arrivals: dict[str, np.ndarray] = {}
        #: group transitions so far (a group's quiet span, _Group._plan_quiet, holds within one epoch)
        self._epoch = 0
        self._all_kept = np.ones(self.n, dtype=bool)
        self._all_kept.flags.writeable = False

    def plan_ticks(self, ticks: np.ndarray, arrivals: dict[str, np.ndarray]) -> None:
        """csv mode: the times (µs, ascending) of the calls the replay may make, and per topic handed
        to the layer the times (ascending, distinct) of the calls that carry one of its messages.
        A group then skips the updates before its next change point (the next time its conditions
        can change, or a message they read arrives), which change nothing."""
        self._ticks = np.asarray(ticks, dtype=np.int64)
        self._arrivals = {t: np.asarray(v, dtype=np.int64) for t, v in arrivals.items()}

    def fields(self, topic: str) -> tuple[str, ...]:
        if topic not in self._fields:
            self._fields[topic] = builtin_fields(topic)
        return self._fields[topic]

    def log(self, flight: int, t_us: int, event: str, scenario_id: str, kind: str) -> None:
        self.events.append(Event(flight, t_us, event, scenario_id, kind))

    def state_of(self, scenario_id: str, rows: np.ndarray) -> dict[str, np.ndarray]:
        """Active flag, latest start and end times (-1: never) of another scenario, for ``rows``."""
        key = (scenario_id, id(rows))
        maps = self._state_maps.get(key)
        if maps is None:
            maps = []
            where = {int(r): k for k, r in enumerate(rows)}
            for g in self.groups:
                src = [j for j, r in enumerate(g.rows) if int(r) in where and g.ids[j] == scenario_id]
                if src:
                    maps.append((g, np.asarray(src), np.asarray([where[int(g.rows[j])] for j in src])))
            if len(maps) == 1 and len(maps[0][2]) == len(rows):  # one group holds it for every row
                g, src, dst = maps[0]
                maps = (g, src[np.argsort(dst)])
            self._state_maps[key] = maps
        if isinstance(maps, tuple):
            g, src = maps
            return {"active": g.active[src], "start_us": g.start_us[src], "end_us": g.end_us[src]}
        active = np.zeros(len(rows), dtype=bool)
        start = np.full(len(rows), -1, dtype=np.int64)
        end = np.full(len(rows), -1, dtype=np.int64)
        for g, src, dst in maps:
            active[dst] = g.active[src]
            start[dst] = g.start_us[src]
            end[dst] = g.end_us[src]
        return {"active": active, "start_us": start, "end_us": end}

    # -- the hooks the simulator (or the csv replayer) calls --------------------------------------
    def on_messages(self, point: str | None, step: int, t_us: int, messages: dict[str, np.ndarray]
                    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Run the scenarios at ``point`` (None: every scenario, as in csv mode) on this step's messages."""
        if self._origin_open:
            self.learn_origin(messages)
        for topic, vals in messages.items():
            if topic in self.listened:
                self._fields.setdefault(topic, self.fields(topic))
                self.history.append(topic, t_us, vals)
        if self._ticks is None:
            out = {t: (v, np.ones(self.n, dtype=bool)) for t, v in messages.items()}
        else:  # csv replay: it only reads them (an action copies before it changes one, below)
            out = {t: (v, self._all_kept) for t, v in messages.items()}
        done = False
        for g in self._live:
            if point is not None and point not in g.points:
                continue
            if g.finished:
                done = True
                continue
            # a group is evaluated at its own point; at the other direction of the link it acts as it stands
            ctx = g.update(t_us) if point is None or point == g.point else g.context(t_us)
            idle = not g.any_active
            # inactive: only the random actions act (for their draws), in the same order
            for a, topic in (g.random_targets if idle else g.action_targets):
                if topic not in out:
                    continue
                if idle:
                    dim = a.idle_draws(topic)
                    if dim is not None:  # all it would do is draw: the message stays as it is
                        g.stream(a, topic, dim).next()
                        continue
                vals, ok = out[topic]
                sub = vals[g.rows].copy()
                new, delivered = a.apply(ctx, topic, sub, g.active)
                if vals is messages[topic]:
                    vals = vals.copy()
                    ok = ok.copy()
                vals[g.rows] = new
                ok[g.rows] &= delivered
                out[topic] = (vals, ok)
            if g.finished:
                done = True
        if done:  # a finished group does nothing more at any point
            self._live = [g for g in self._live if not g.finished]
        return out

    @property
    def origin_open(self) -> bool:
        """Whether a flight's origin is still unknown (the layer then reads every lat/lon pair)."""
        return self._origin_open

    def must_see(self, topics) -> set[str]:
        """Those of ``topics`` whose messages can matter to the layer: listened to, targeted, or
        (while a flight's origin is unknown) carrying a latitude/longitude pair. A call with only
        other topics' messages changes none of them; it only evaluates the groups at its time
        (which :meth:`next_change` can say is a no-op)."""
        out = {t for t in topics if t in self.listened}
        if self._origin_open:
            from scart_bench.generator.scart.units import latlon_pair

            out |= {t for t in topics if t not in CONTROL_TOPICS and latlon_pair(t, self.fields(t)) is not None}
        return out

    def next_change(self, ticks: np.ndarray, chunk: int = 4096) -> int:
        """Index of the first of ``ticks`` (µs, ascending, after the last call) at which a call
        without messages, ``on_messages(None, 0, t, {})``, could change any group's state; the calls
        before it are no-ops and may be left out (csv mode's replay). 0 when a group has a callback
        or condition of its own (every call counts); len(ticks) when none changes."""
        groups = []
        for g in self._live:
            if g.finished or (g._vanilla and g._dead):
                continue
            if not g._vanilla:
                return 0
            groups.append(g)
        for lo in range(0, len(ticks), chunk):
            part = ticks[lo:lo + chunk]
            first = min((g.first_change(part) if g._quiet_epoch != self._epoch or part[0] >= g._quiet_until
                         else int(np.searchsorted(part, g._quiet_until)) for g in groups), default=len(part))
            if first < len(part):
                return lo + first
        return len(ticks)

    def learn_origin(self, messages: dict[str, np.ndarray]) -> None:
        """Take a flight's origin from the first finite, non-zero lat/lon pair it receives."""
        from scart_bench.generator.scart.units import latlon_pair

        for topic, vals in messages.items():
            if topic in CONTROL_TOPICS:  # commands and mission items carry no position of the vehicle
                continue
            pair = latlon_pair(topic, self.fields(topic))
            if pair is None:
                continue
            lat, lon = vals[:, pair[0]], vals[:, pair[1]]
            need = ~np.isfinite(self.origin).all(axis=1) & np.isfinite(lat) & np.isfinite(lon) \
                & ((lat != 0) | (lon != 0)) & (np.abs(lat) <= 90)
            if need.any():
                self.origin[need, 0] = lat[need]
                self.origin[need, 1] = lon[need]
        self._origin_open = not np.isfinite(self.origin).all()

    def on_physics(self, step: int, t_us: int) -> Disturbances | dict:
        """Run the environment and vehicle scenarios: this step's physical disturbances."""
        if not self.physical_groups:
            return {}
        dist = Disturbances.none(self.n)
        for g in self.physical_groups:
            ctx = g.update(t_us)
            if g.active.any():
                for a in g.actions:
                    a.apply(ctx, g.active, dist)
        return dist

    def on_finish(self, step: int) -> None:
        self.final_us = None

    # -- labels -----------------------------------------------------------------------------------
    def windows(self, flight: int, end_us: int) -> list[tuple[int, int]]:
        """Anomaly windows [start, end) of one flight, closed at ``end_us`` if still open."""
        return [(s, e) for s, e, _, _ in self.labelled_windows(flight, end_us)]

    def labelled_windows(self, flight: int, end_us: int) -> list[tuple[int, int, str, str]]:
        """(start, end, scenario id, kind) of every window of one flight, in time order.

        In csv mode the windows of physical scenarios are left out: they changed nothing.
        """
        out, open_at = [], {}
        for e in self.events:
            if e.flight != flight:
                continue
            if not self.physics and e.scenario_id in self.physical_ids:
                continue
            if e.event == "start":
                open_at[e.scenario_id] = (e.timestamp_us, e.kind)
            elif e.event == "end" and e.scenario_id in open_at:
                s, kind = open_at.pop(e.scenario_id)
                if s < end_us:
                    out.append((s, min(e.timestamp_us, end_us), e.scenario_id, kind))
        for sid, (s, kind) in open_at.items():
            if s < end_us:
                out.append((s, end_us, sid, kind))
        return sorted(out)

    def event_log(self, flight: int, end_us: int) -> list[dict]:
        """The attack event log of one flight (events after the flight ended are dropped)."""
        rows = []
        for e in self.events:
            if e.flight == flight and e.timestamp_us < end_us:
                detail = e.kind
                if not self.physics and e.scenario_id in self.physical_ids:
                    detail = f"{e.kind} (timing only: physical scenarios change nothing in csv mode)"
                rows.append({"timestamp_us": e.timestamp_us, "event": e.event, "scenario_id": e.scenario_id,
                             "detail": detail})
        balance: dict[str, int] = {}
        kinds: dict[str, str] = {}
        for r in rows:
            balance[r["scenario_id"]] = balance.get(r["scenario_id"], 0) + (1 if r["event"] == "start" else -1)
            kinds[r["scenario_id"]] = r["detail"]
        for sid in sorted(k for k, v in balance.items() if v > 0):
            rows.append({"timestamp_us": end_us, "event": "end", "scenario_id": sid,
                         "detail": f"{kinds[sid]} (flight ended)"})
        return rows
