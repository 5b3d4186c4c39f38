"""Scenarios: the paper's three lists (listeners, start/end conditions, actions) from TOML files.

```toml
[scenario]
id = "gps-spoof"                 # default: the file name
injection_point = "link"         # link | sensor | command | environment | vehicle
listeners = ["local_position_ned"]   # default: every topic the conditions and actions use
max_windows = 1                  # attack windows per flight (one contiguous window by default)
kind = "attack"                  # attack | fault (labels; default fault at "vehicle")
callback = "my-callback"         # optional: a callback installed in the entry-point group scart_bench.callbacks

[[scenario.start]]               # all must hold to start
condition = "time_window"
start_s = 20.0

[[scenario.end]]                 # any one ends the attack
condition = "duration"
seconds = 30.0

[[scenario.actions]]
action = "gps_spoof"
target = ["global_position_int", "local_position_ned", "gps_raw_int"]
rate_deg_s = 2.0
```
A file holds one ``[scenario]`` or several ``[[scenario]]`` tables (applied together).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

from scart_bench.dataset.schema import COMMAND_TOPICS, TELEMETRY_TOPICS, TOPICS
from scart_bench.generator.flight_software.commander import CONTROL_TOPICS
from scart_bench.generator.scart.actions import ACTIONS
from scart_bench.generator.scart.conditions import CONDITIONS
from scart_bench.generator.scart.effects import EFFECTS, PHYSICAL_POINTS
from scart_bench.generator.scart.meanings import ConstantQuantity, resolve_condition_topic, resolve_target
from scart_bench.generator.scart.spec import ScenarioError, read_toml, validate_params
from scart_bench.generator.telemetry.schedule import SENSOR_TOPICS
from scart_bench.names import IdError, check_id

INJECTION_POINTS = ("link", "sensor", "command", "environment", "vehicle")
KINDS = ("attack", "fault")


def point_topics(point: str) -> dict[str, tuple[str, ...]]:
    """Topics (with their fields) that pass an injection point of the built-in generator."""
    if point == "link":
        return {t: TOPICS[t].field_names for t in TELEMETRY_TOPICS}
    if point == "command":
        return {**{t: TOPICS[t].field_names for t in COMMAND_TOPICS}, **CONTROL_TOPICS}
    if point == "sensor":
        return {t: f for t, (_, f) in SENSOR_TOPICS.items()}
    if point in PHYSICAL_POINTS:
        return {}  # physical actions touch no message
    raise ScenarioError(f"injection_point {point!r}: expected one of {', '.join(INJECTION_POINTS)}")


def scenario_topics(point: str, actions: list[tuple[str, dict]]) -> dict[str, tuple[str, ...]]:
    """Topics a scenario's actions may target at ``point``: the point's own, and at ``link`` also the
    command direction when an action works on both directions (link_loss, replay, flood)."""
    out = point_topics(point)
    if point == "link" and any(getattr(ACTIONS.get(n), "bidirectional", False) for n, _ in actions):
        out = {**out, **point_topics("command")}
    return out


def listened_topics() -> dict[str, tuple[str, ...]]:
    """Every topic a condition can listen to in the generator (all points that carry messages)."""
    return {**point_topics("link"), **point_topics("command"), **point_topics("sensor")}


@dataclass
class Scenario:
    """A validated scenario. Conditions and actions are (name, params) pairs."""

    id: str
    injection_point: str = "link"
    listeners: list[str] = field(default_factory=list)
    start: list[tuple[str, dict]] = field(default_factory=list)
    end: list[tuple[str, dict]] = field(default_factory=list)
    actions: list[tuple[str, dict]] = field(default_factory=list)
    max_windows: int = 1
    kind: str = "attack"
    callback: str | None = None
    description: str = ""
    source: str = "<memory>"

    # -- identity ----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "id": self.id, "injection_point": self.injection_point, "listeners": list(self.listeners),
            "start": [{"condition": n, **p} for n, p in self.start],
            "end": [{"condition": n, **p} for n, p in self.end],
            "actions": [{"action": n, **p} for n, p in self.actions],
            "max_windows": self.max_windows, "kind": self.kind, "callback": self.callback,
        }

    def params_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, default=_finite)

    def structure_key(self) -> str:
        """Everything but the numeric parameters: scenarios with the same key run as one group."""
        def strip(items):
            return [(n, {k: v for k, v in p.items() if not isinstance(v, int | float) or isinstance(v, bool)})
                    for n, p in items]
        return json.dumps([self.injection_point, sorted(self.listeners), strip(self.start), strip(self.end),
                           strip(self.actions), self.max_windows, self.kind, self.callback], sort_keys=True,
                          default=_finite)

    # -- what it touches --------------------------------------------------------------------------
    def targets(self) -> dict[str, list[str] | None]:
        """topic -> target fields (None: every field of the topic), over all actions."""
        out: dict[str, list[str] | None] = {}
        for _, p in self.actions:
            for t in p.get("target", ()):
                topic, _, fld = t.partition(".")
                if not fld:
                    out[topic] = None
                elif out.get(topic, []) is not None:
                    out.setdefault(topic, []).append(fld)
        return out

    def used_topics(self) -> set[str]:
        topics = set(self.listeners) | set(self.targets())
        for _n, p in self.start + self.end:
            if isinstance(p.get("topic"), str):
                topics.add(p["topic"])
        return topics

    @property
    def physical(self) -> bool:
        """True for environment and vehicle scenarios (they act on the physics, not on messages)."""
        return self.injection_point in PHYSICAL_POINTS

    def references(self) -> list[tuple[str, int, str, str]]:
        """(list, index, condition, other scenario id) of every condition on another scenario."""
        out = []
        for key, items in (("start", self.start), ("end", self.end)):
            for i, (name, p) in enumerate(items):
                if CONDITIONS[name].refers:
                    out.append((key, i, name, p["scenario"]))
        return out

    def primary_action(self) -> str:
        return self.actions[0][0] if self.actions else ""

    def target_label(self) -> str:
        return ",".join(sorted(self.targets()))

    def resolved(self, available: dict[str, tuple[str, ...]], listen: dict[str, tuple[str, ...]] | None = None,
                 where: str | None = None) -> Scenario:
        """This scenario with every quantity (generator.scart.meanings) replaced by the concrete
        topics/fields of an input: ``available`` for action targets, ``listen`` (default the same)
        for condition topics and listeners. Raises ScenarioError naming what the input lacks."""
        where = where or self.source
        listen = available if listen is None else listen
        actions = []
        for i, (name, p) in enumerate(self.actions):
            if "target" in p:
                targets: list[str] = []
                if p["target"] == ["*"]:  # every topic that passes (the link actions)
                    p = {**p, "target": ACTIONS[name].wildcard(available)}
                missing: list[ScenarioError] = []
                for t in p["target"]:
                    try:
                        found = resolve_target(t, available, f"{where}: scenario.actions[{i}].target")
                    except ScenarioError as exc:  # a quantity this input lacks: the others still apply
                        missing.append(exc)
                        continue
                    targets.extend(r for r in found if r not in targets)
                if missing and not targets:  # the reason that says most: a quantity there but constant
                    raise next((e for e in missing if isinstance(e, ConstantQuantity)), missing[0])
                p = {**p, "target": targets}
            actions.append((name, p))
        conds = {}
        for key, items in (("start", self.start), ("end", self.end)):
            conds[key] = [(n, resolve_condition_topic(n, p, listen, f"{where}: scenario.{key}[{i}]"))
                          for i, (n, p) in enumerate(items)]
        listeners: list[str] = []
        for t in self.listeners:
            for r in resolve_target(t, listen, f"{where}: scenario.listeners"):
                if r.partition(".")[0] not in listeners:
                    listeners.append(r.partition(".")[0])
        return dataclasses.replace(self, actions=actions, start=conds["start"], end=conds["end"], listeners=listeners)

    def validate_topics(self, available: dict[str, tuple[str, ...]], where: str | None = None,
                        listen: dict[str, tuple[str, ...]] | None = None) -> None:
        """Check that every topic and field the scenario names (after resolving quantities) exists in
        ``available`` (``listen``, default the same, for conditions)."""
        where = where or self.source
        listen = available if listen is None else listen
        self = self.resolved(available, listen, where)
        names = sorted(available)
        allowed = ", ".join(names[:40]) + (f", ... ({len(names)} topics)" if len(names) > 40 else "")
        for i, (_, p) in enumerate(self.actions):
            for t in p.get("target", ()):
                topic, _, fld = t.partition(".")
                if topic not in available:
                    raise ScenarioError(f"{where}: scenario.actions[{i}].target: unknown topic {topic!r} at "
                                        f"injection point {self.injection_point!r}; allowed: {allowed}")
                if fld and fld not in available[topic]:
                    raise ScenarioError(f"{where}: scenario.actions[{i}].target: unknown field {t!r}; "
                                        f"{topic} has: {', '.join(available[topic])}")
        for t in self.listeners:
            if t not in listen:
                raise ScenarioError(f"{where}: scenario.listeners: topic {t!r} is not in this input")


def _finite(obj):
    raise TypeError(type(obj).__name__)


def _items(table: dict, key: str, registry: dict, kind_key: str, where: str, end: bool = False,
           context: str = "") -> list:
    raw = table.get(key, [])
    if isinstance(raw, dict):
        raw = [raw]
    if not isinstance(raw, list):
        raise ScenarioError(f"{where}.{key}: expected a list of tables ([[...{key}]]), got {raw!r}")
    out = []
    for i, item in enumerate(raw):
        w = f"{where}.{key}[{i}]"
        if not isinstance(item, dict):
            raise ScenarioError(f"{w}: expected a table, got {item!r}")
        name = item.get(kind_key)
        if not isinstance(name, str) or name not in registry:  # a list or table is no name (and unhashable)
            raise ScenarioError(f"{w}.{kind_key}: unknown {kind_key} {name!r}{context}; "
                                f"allowed: {', '.join(sorted(registry))}")
        cls = registry[name]
        if kind_key == "condition" and cls.end_only and not end:
            raise ScenarioError(f"{w}: condition {name!r} can only end an attack (use it under [[...end]])")
        params = validate_params(item, cls.spec, w, kind_key)
        if hasattr(cls, "check_params"):  # constraints between a table's parameters
            cls.check_params(params, w)
        out.append((name, params))
    return out


_SCENARIO_KEYS = ("id", "injection_point", "listeners", "start", "end", "actions", "max_windows", "kind", "callback",
                  "description")


def scenario_from_dict(table: dict, source: str = "<memory>", default_id: str = "scenario",
                       where: str = "scenario", check_topics: bool = True) -> Scenario:
    """Validate one scenario table (as parsed from TOML)."""
    loc = f"{source}: {where}"
    if not isinstance(table, dict):
        raise ScenarioError(f"{loc}: expected a table")
    unknown = [k for k in table if k not in _SCENARIO_KEYS]
    if unknown:
        raise ScenarioError(f"{loc}: unknown key(s) {', '.join(map(repr, unknown))}; allowed: {', '.join(_SCENARIO_KEYS)}")
    point = table.get("injection_point", "link")
    if point not in INJECTION_POINTS:
        raise ScenarioError(f"{loc}.injection_point: {point!r} is not one of {', '.join(INJECTION_POINTS)}")
    kind = table.get("kind", "fault" if point == "vehicle" else "attack")
    if kind not in KINDS:
        raise ScenarioError(f"{loc}.kind: {kind!r} is not one of {', '.join(KINDS)}")
    max_windows = table.get("max_windows", 1)
    if isinstance(max_windows, bool) or not isinstance(max_windows, int) or max_windows < 1:
        raise ScenarioError(f"{loc}.max_windows: expected an integer >= 1, got {max_windows!r}")
    sid = table.get("id", default_id)
    try:
        check_id(sid, f"{loc}.id")
    except IdError as exc:
        raise ScenarioError(str(exc)) from None
    listeners = table.get("listeners", [])
    if isinstance(listeners, str):
        listeners = [listeners]
    if not isinstance(listeners, list) or not all(isinstance(x, str) for x in listeners):
        raise ScenarioError(f"{loc}.listeners: expected a list of topic names, got {listeners!r}")
    callback = table.get("callback")
    if callback is not None:
        if isinstance(callback, str) and ":" in callback:
            raise ScenarioError(f"{loc}.callback: {callback!r} names code to import; a scenario file names an "
                                "installed callback instead (its entry-point name in the group "
                                "'scart_bench.callbacks'), so that reading a scenario never runs code")
        try:
            check_id(callback, f"{loc}.callback")
        except IdError as exc:
            raise ScenarioError(str(exc)) from None
    start = _items(table, "start", CONDITIONS, "condition", loc)
    end = _items(table, "end", CONDITIONS, "condition", loc, end=True)
    physical = point in PHYSICAL_POINTS
    registry = {k: v for k, v in EFFECTS.items() if v.point == point} if physical else ACTIONS
    actions = _items(table, "actions", registry, "action", loc, context=f" at injection point {point!r}")
    if not actions:
        raise ScenarioError(f"{loc}.actions: a scenario needs at least one [[scenario.actions]] table; "
                            f"allowed actions at injection point {point!r}: {', '.join(sorted(registry))}")
    sc = Scenario(id=sid, injection_point=point, listeners=list(listeners), start=start, end=end,
                  actions=actions, max_windows=max_windows, kind=kind, callback=callback,
                  description=str(table.get("description", "")), source=source)
    if check_topics:
        sc.validate_topics(scenario_topics(point, actions), where=source, listen=listened_topics())
    return sc


def load_scenarios(path: str | Path, check_topics: bool = True) -> list[Scenario]:
    """Read and validate a scenario file (one [scenario] or several [[scenario]])."""
    path = Path(path)
    doc = read_toml(path)
    if "scenario" not in doc:
        raise ScenarioError(f"{path}: expected a [scenario] table (or [[scenario]] tables); found keys: "
                            f"{', '.join(doc) or '(none)'}")
    extra = [k for k in doc if k != "scenario"]
    if extra:
        raise ScenarioError(f"{path}: unknown top-level key(s) {', '.join(map(repr, extra))}; allowed: 'scenario'")
    tables = doc["scenario"] if isinstance(doc["scenario"], list) else [doc["scenario"]]
    out = []
    for i, t in enumerate(tables):
        where = "scenario" if len(tables) == 1 else f"scenario[{i}]"
        default_id = path.stem if len(tables) == 1 else f"{path.stem}-{i}"
        out.append(scenario_from_dict(t, str(path), default_id, where, check_topics))
    check_composition(out, str(path))
    return out


def check_composition(scenarios: list[Scenario], where: str = "<memory>") -> list[Scenario]:
    """Check the scenarios of one flight and return them in dependency order.

    Ids must be unique, every condition on another scenario must name one of them, and the
    references must not form a cycle (a scenario cannot wait on one that waits on it).
    """
    ids = [s.id for s in scenarios]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise ScenarioError(f"{where}: scenario ids must be unique within a flight; repeated: {', '.join(dup)}")
    by_id = {s.id: s for s in scenarios}
    deps: dict[str, list[str]] = {}
    for s in scenarios:
        deps[s.id] = []
        for key, i, name, other in s.references():
            if other not in by_id:
                raise ScenarioError(
                    f"{where}: scenario {s.id!r} {key}[{i}] ({name}) refers to unknown scenario {other!r}; "
                    f"scenarios of this flight: {', '.join(ids)}")
            deps[s.id].append(other)
    order: list[str] = []
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(sid: str, path: list[str]) -> None:
        if state.get(sid) == 2:
            return
        if state.get(sid) == 1:
            cycle = path[path.index(sid):] + [sid]
            raise ScenarioError(f"{where}: scenarios refer to each other in a cycle: {' -> '.join(cycle)} "
                                f"(a scenario cannot wait on one that waits on it)")
        state[sid] = 1
        for other in deps[sid]:
            visit(other, path + [sid])
        state[sid] = 2
        order.append(sid)

    for sid in ids:
        visit(sid, [])
    return [by_id[i] for i in order]
