"""Grid files: the Cartesian product of scenario parameters, with stable ids.

```toml
[grid]
id = "paper"
injection_point = "link"
[grid.axes]                       # each axis a list; the product is the set of configurations
action = ["add_white_noise", "bias"]
target = ["position", "attitude"]
level = [0, 1, 2, 3]              # index into the target's magnitudes (or the action's levels)
duration_s = [10.0, 30.0]
trigger = ["time", "waypoint"]

[targets.position]                # fields an attack on "position" alters, and its magnitudes
fields = ["global_position_int.lat", "global_position_int.lon"]
magnitudes = [1.0, 3.0, 10.0, 30.0]     # physical units (m)

[actions.add_white_noise]         # which parameter the level sets
param = "std"                     # takes the target's magnitude (times `factor`, default 1)
[actions.duplicate]
param = "k"
levels = [5, 10, 25, 50]          # absolute values, whatever the target
targets = ["position"]            # optional: only these targets (other combinations are skipped)
extra = { direction_deg = 90.0 }  # optional fixed parameters

[triggers.time]
start = [{ condition = "time_window", start_s = 20.0 }]
```
Each configuration's id is ``<grid id>-<action>-<target>-L<level>-d<duration>-<trigger>``.

Combinations of attacks (several action/target pairs in one flight) are an optional axis,
``combine``: each entry lists its parts and how they run, and joins the action x target pairs as
one more attack (it is not multiplied with them; it is multiplied with level, duration and trigger):

```toml
combine = [
  { mode = "concurrent", parts = [["gps_spoof", "position"], ["bias", "altitude"]] },
  { mode = "chained", parts = [["disconnect_sensor", "position"], ["drift", "position"]] },
]
```
Every part takes the configuration's level (on its own target's magnitudes), lasts the
configuration's duration, and is a scenario of its own. The first part starts on the trigger;
``concurrent`` parts start with it (``scenario_started``), ``chained`` parts each when the previous
part ends (``scenario_ended``). Part ids: the first part's is the single attack's id, later parts
end in ``-with`` (concurrent) or ``-then`` (chained) instead of the trigger; the configuration's
id joins its parts' ids with ``+`` (at most 200 characters, the id rule).

Compositions (several scenarios per flight) expand with a *sweep*: a scenario file with
``[[scenario]]`` tables and a ``[sweep]`` table whose keys are parameter paths and whose values
are lists; every combination is one configuration (one flight).

```toml
[sweep]
"gps-jam.end.0.seconds" = [3.0, 5.0]          # <scenario id>.<start|end|actions>.<index>.<key>
"link-drift.actions.0.rate" = [0.1, 0.3]
"link-drift.max_windows" = [1, 2]             # <scenario id>.<key> for a scenario's own keys
```
A swept scenario's id gains the values (``gps-jam-seconds3``); references to it follow.
"""

from __future__ import annotations

import copy
import itertools
from pathlib import Path

from scart_bench.generator.scart.actions import ACTIONS
from scart_bench.generator.scart.scenario import (
    Scenario,
    check_composition,
    load_scenarios,
    scenario_from_dict,
)
from scart_bench.generator.scart.spec import ScenarioError, read_toml
from scart_bench.names import IdError, check_id

AXES = ("action", "target", "level", "duration_s", "trigger")
#: optional axis: combinations of attacks (see the module docstring)
OPTIONAL_AXES = ("combine",)
COMBINE_MODES = ("concurrent", "chained")
#: Configurations a grid or sweep may expand to unless its file raises the limit
#: (``max_configurations = N`` in ``[grid]`` or ``[sweep]``); the paper's grid has 2,048.
MAX_CONFIGURATIONS = 20_000


def _limit(table: dict, where: str) -> int:
    """The file's own ``max_configurations`` (popped from ``table``), or the default."""
    value = table.pop("max_configurations", MAX_CONFIGURATIONS)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ScenarioError(f"{where}.max_configurations: expected a positive integer, got {value!r}")
    return value


def _check_count(count: int, limit: int, where: str, table: str) -> None:
    if count > limit:
        raise ScenarioError(f"{where}: expands to {count:,} configurations, more than the limit of {limit:,}; "
                            f"if that is intended, set max_configurations = {count} in [{table}]")


def _need(table: dict, key: str, where: str, kind: type | tuple):
    if key not in table:
        raise ScenarioError(f"{where}: missing required key {key!r}")
    value = table[key]
    if not isinstance(value, kind):
        raise ScenarioError(f"{where}.{key}: expected {getattr(kind, '__name__', kind)}, got {value!r}")
    return value


def load_grid(path: str | Path, check_topics: bool = True) -> list[Scenario]:
    """Expand a grid file into validated scenarios (one per configuration), in a stable order.

    ``check_topics=False`` leaves topic names to be checked against a recorded flight's topics.
    A grid with a ``combine`` axis has configurations of several scenarios: read it with
    :func:`load_grid_configurations` (or :func:`load_configurations`).
    """
    configs = load_grid_configurations(path, check_topics)
    if any(len(c) > 1 for c in configs):
        raise ScenarioError(f"{path}: the grid has combinations of attacks (a 'combine' axis); "
                            f"its configurations are lists of scenarios: use load_configurations")
    return [c[0] for c in configs]


def _combinations(entries: list, src: str, actions: dict, targets: dict) -> list[tuple[str, list[tuple[str, str]]]]:
    """The ``combine`` axis checked: (mode, [(action, target), ...]) per entry."""
    out = []
    seen: set = set()
    for i, entry in enumerate(entries):
        where = f"{src}: grid.axes.combine[{i}]"
        if not isinstance(entry, dict):
            raise ScenarioError(f"{where}: expected a table {{ mode = \"concurrent\"|\"chained\", "
                                f"parts = [[action, target], ...] }}, got {entry!r}")
        unknown = [k for k in entry if k not in ("mode", "parts")]
        if unknown:
            raise ScenarioError(f"{where}: unknown key {unknown[0]!r}; allowed: 'mode', 'parts'")
        mode = _need(entry, "mode", where, str)
        if mode not in COMBINE_MODES:
            raise ScenarioError(f"{where}.mode: expected one of {', '.join(COMBINE_MODES)}, got {mode!r}")
        parts = _need(entry, "parts", where, list)
        if len(parts) < 2:
            raise ScenarioError(f"{where}.parts: a combination needs at least 2 parts, got {len(parts)}")
        pairs = []
        for j, part in enumerate(parts):
            if (not isinstance(part, list) or len(part) != 2 or not all(isinstance(x, str) for x in part)):
                raise ScenarioError(f"{where}.parts[{j}]: expected [action, target], got {part!r}")
            action, target = part
            if action not in ACTIONS:
                raise ScenarioError(f"{where}.parts[{j}]: unknown action {action!r}; "
                                    f"allowed: {', '.join(sorted(ACTIONS))}")
            if action not in actions:
                raise ScenarioError(f"{where}.parts[{j}]: missing table [actions.{action}] "
                                    f"(which parameter the level sets)")
            if target not in targets:
                raise ScenarioError(f"{where}.parts[{j}]: {target!r} has no [targets.{target}] table; "
                                    f"defined: {', '.join(targets) or '(none)'}")
            allowed = actions[action].get("targets")
            if allowed is not None and target not in allowed:
                raise ScenarioError(f"{where}.parts[{j}]: [actions.{action}] applies only to "
                                    f"{', '.join(allowed)}, not {target!r}")
            pairs.append((action, target))
        if len(set(pairs)) != len(pairs):
            raise ScenarioError(f"{where}.parts: the same [action, target] appears twice; parts must differ")
        key = (mode, tuple(sorted(pairs)) if mode == "concurrent" else tuple(pairs))
        if key in seen:
            raise ScenarioError(f"{where}: repeats an earlier combination (concurrent parts in another order "
                                f"are the same combination)")
        seen.add(key)
        out.append((mode, pairs))
    return out


def load_grid_configurations(path: str | Path, check_topics: bool = True) -> list[list[Scenario]]:
    """Expand a grid file into validated configurations (the scenarios of one flight each), in a
    stable order: the single action x target attacks first, then the ``combine`` entries."""
    path = Path(path)
    doc = read_toml(path, "grid file")
    src = str(path)
    grid = _need(doc, "grid", src, dict)
    gid = grid.get("id", path.stem)
    point = grid.get("injection_point", "link")
    limit = _limit(grid, f"{src}: grid")
    axes = _need(grid, "axes", f"{src}: grid", dict)
    unknown = [k for k in axes if k not in AXES + OPTIONAL_AXES]
    if unknown:
        raise ScenarioError(f"{src}: grid.axes: unknown axis {unknown[0]!r}; "
                            f"allowed: {', '.join(AXES + OPTIONAL_AXES)}")
    for k in AXES:
        v = axes.get(k)
        if v is None:
            raise ScenarioError(f"{src}: grid.axes: missing axis {k!r} (a list)")
        if not isinstance(v, list) or not v:
            raise ScenarioError(f"{src}: grid.axes.{k}: expected a non-empty list, got {v!r}")
    combine = axes.get("combine", [])
    if not isinstance(combine, list):
        raise ScenarioError(f"{src}: grid.axes.combine: expected a list of combinations, got {combine!r}")
    targets = doc.get("targets", {})
    actions = doc.get("actions", {})
    triggers = doc.get("triggers", {})
    for a in axes["action"]:
        if a not in ACTIONS:
            raise ScenarioError(f"{src}: grid.axes.action: unknown action {a!r}; allowed: {', '.join(sorted(ACTIONS))}")
        if a not in actions:
            raise ScenarioError(f"{src}: missing table [actions.{a}] (which parameter the level sets)")
    for t in axes["target"]:
        if t not in targets:
            raise ScenarioError(f"{src}: grid.axes.target: {t!r} has no [targets.{t}] table; "
                                f"defined: {', '.join(targets) or '(none)'}")
    for tr in axes["trigger"]:
        if tr not in triggers:
            raise ScenarioError(f"{src}: grid.axes.trigger: {tr!r} has no [triggers.{tr}] table; "
                                f"defined: {', '.join(triggers) or '(none)'}")
    for d in axes["duration_s"]:
        if isinstance(d, bool) or not isinstance(d, int | float) or d <= 0:
            raise ScenarioError(f"{src}: grid.axes.duration_s: durations must be positive numbers, got {d!r}")
    combos = _combinations(combine, src, actions, targets)
    singles = [(a, t) for a, t in itertools.product(axes["action"], axes["target"])
               if actions[a].get("targets") is None or t in actions[a]["targets"]]
    attacks: list[tuple[str, list[tuple[str, str]]]] = [("single", [p]) for p in singles] + combos
    settings = list(itertools.product(axes["level"], axes["duration_s"], axes["trigger"]))
    _check_count(len(attacks) * len(settings), limit, src, "grid")

    def part(action: str, target: str, level, dur: float, tag: str, start: list, end: list) -> dict:
        aspec, tspec = actions[action], targets[target]
        param = _need(aspec, "param", f"{src}: [actions.{action}]", str)
        if "levels" in aspec:
            levels = aspec["levels"]
        else:
            mags = _need(tspec, "magnitudes", f"{src}: [targets.{target}]", list)
            levels = [m * aspec.get("factor", 1.0) for m in mags]
        if isinstance(level, bool) or not isinstance(level, int) or not 0 <= level < len(levels):
            raise ScenarioError(f"{src}: grid.axes.level: level {level!r} out of range for {action} on {target} "
                                f"(0..{len(levels) - 1})")
        act = {"action": action, "target": list(_need(tspec, "fields", f"{src}: [targets.{target}]", list)),
               param: levels[level], **aspec.get("extra", {})}
        return {"id": f"{gid}-{action}-{target}-L{level}-d{dur:g}-{tag}",
                "injection_point": tspec.get("injection_point", point),
                "start": start, "end": [{"condition": "duration", "seconds": dur}, *end], "actions": [act]}

    out: list[list[Scenario]] = []
    for (mode, pairs), (level, duration, trigger) in itertools.product(attacks, settings):
        trig = triggers[trigger]
        dur = float(duration)
        tables = [part(*pairs[0], level, dur, trigger, trig.get("start", []), trig.get("end", []))]
        for action, target in pairs[1:]:
            if mode == "concurrent":
                start = [{"condition": "scenario_started", "scenario": tables[0]["id"]}]
            else:
                start = [{"condition": "scenario_ended", "scenario": tables[-1]["id"]}]
            tables.append(part(action, target, level, dur, "with" if mode == "concurrent" else "then", start, []))
        config = [scenario_from_dict(t, src, t["id"], f"grid[{t['id']}]", check_topics) for t in tables]
        if len(config) > 1:
            check_composition(config, src)
            name = "+".join(sc.id for sc in config)
            try:
                check_id(name, f"{src}: grid configuration")
            except IdError as exc:
                raise ScenarioError(f"{exc}; shorten the grid id, action or target names, or use fewer parts") from None
        out.append(config)
    names = ["+".join(sc.id for sc in c) for c in out]
    if len(set(names)) != len(names):
        raise ScenarioError(f"{src}: the grid expands to duplicate ids; make the axes' values distinct")
    return out


def _tag(value) -> str:
    return f"{value:g}" if isinstance(value, int | float) and not isinstance(value, bool) else str(value)


def load_sweep(path: str | Path, check_topics: bool = True) -> list[list[Scenario]]:
    """Expand a scenario file with a ``[sweep]`` table into compositions, one per combination."""
    path = Path(path)
    src = str(path)
    doc = read_toml(path, "sweep file")
    extra = [k for k in doc if k not in ("scenario", "sweep")]
    if extra:
        raise ScenarioError(f"{src}: unknown top-level key(s) {', '.join(map(repr, extra))}; allowed: 'scenario', 'sweep'")
    tables = doc.get("scenario")
    if isinstance(tables, dict):
        tables = [tables]
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict) for t in tables):
        raise ScenarioError(f"{src}: a sweep needs [[scenario]] tables to sweep")
    sweep = _need(doc, "sweep", src, dict)
    limit = _limit(sweep, f"{src}: sweep")
    if not sweep:
        raise ScenarioError(f"{src}: [sweep] is empty; give at least one \"<scenario id>.<...>.<key>\" = [values]")
    ids = [t.get("id", f"{path.stem}-{i}" if len(tables) > 1 else path.stem) for i, t in enumerate(tables)]
    for t, sid in zip(tables, ids):
        t["id"] = sid
    axes = []
    for key, values in sweep.items():
        where = f"{src}: sweep.{key!r}"
        if not isinstance(values, list) or not values:
            raise ScenarioError(f"{where}: expected a non-empty list of values, got {values!r}")
        sid, _, rest = key.partition(".")
        if sid not in ids:
            raise ScenarioError(f"{where}: unknown scenario {sid!r}; scenarios: {', '.join(ids)}")
        parts = rest.split(".")
        if len(parts) == 1 and parts[0]:
            pass
        elif len(parts) == 3 and parts[0] in ("start", "end", "actions") and parts[1].isdigit():
            items = tables[ids.index(sid)].get(parts[0], [])
            items = [items] if isinstance(items, dict) else items
            if int(parts[1]) >= len(items):
                raise ScenarioError(f"{where}: scenario {sid!r} has {len(items)} {parts[0]} table(s); "
                                    f"index {parts[1]} is out of range")
        else:
            raise ScenarioError(f"{where}: expected \"<scenario id>.<start|end|actions>.<index>.<key>\" "
                                f"or \"<scenario id>.<key>\"")
        axes.append((sid, parts, values))
    count = 1
    for _, _, values in axes:
        count *= len(values)
    _check_count(count, limit, src, "sweep")
    out: list[list[Scenario]] = []
    seen: set[str] = set()
    for combo in itertools.product(*(values for _, _, values in axes)):
        doc_tables = copy.deepcopy(tables)
        by_id = dict(zip(ids, doc_tables))
        tags: dict[str, list[str]] = {sid: [] for sid in ids}
        for (sid, parts, _), value in zip(axes, combo):
            t = by_id[sid]
            if len(parts) == 1:
                t[parts[0]] = value
            else:
                items = t[parts[0]]
                item = items if isinstance(items, dict) else items[int(parts[1])]
                item[parts[2]] = value
            tags[sid].append(f"{parts[-1]}{_tag(value)}")
        rename = {sid: "-".join([sid, *tags[sid]]) for sid in ids}
        for t in doc_tables:
            t["id"] = rename[t["id"]]
            for key in ("start", "end"):
                items = t.get(key, [])
                for item in [items] if isinstance(items, dict) else items:
                    if isinstance(item, dict) and isinstance(item.get("scenario"), str):
                        item["scenario"] = rename.get(item["scenario"], item["scenario"])
        config = [scenario_from_dict(t, src, t["id"], f"scenario[{t['id']}]", check_topics) for t in doc_tables]
        check_composition(config, src)
        name = "+".join(sc.id for sc in config)
        if name in seen:
            raise ScenarioError(f"{src}: the sweep expands to duplicate configurations ({name}); "
                                f"make the swept values distinct")
        seen.add(name)
        out.append(config)
    return out


def load_configurations(path: str | Path, check_topics: bool = True) -> list[list[Scenario]]:
    """The flights a file describes: one scenario list per flight.

    A grid gives one single-scenario flight per configuration, a sweep one composition per
    combination, and a plain scenario file one flight running all its scenarios together.
    """
    doc = read_toml(path)
    if "grid" in doc:
        return load_grid_configurations(path, check_topics)
    if "sweep" in doc:
        return load_sweep(path, check_topics)
    return [load_scenarios(path, check_topics)]


def is_grid(path: str | Path) -> bool:
    """True when the file is a grid file (has a [grid] table)."""
    return "grid" in read_toml(path)
