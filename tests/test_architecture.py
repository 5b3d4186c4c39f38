"""The import graph of the package: no circle between modules, and imports go one way between the rooms.

The rooms, from the top: the command line (``scart_bench.cli``) -> the reports -> the benchmark (the run
and its evaluation) -> the detectors and the generator (side by side, neither imports the other) ->
the shared services (``scart_bench.storage``: URLs; ``scart_bench.cluster``: Dask) -> the dataset format
(``scart_bench.dataset``) -> the shared base (``scart_bench.errors``, ``names``, ``progress``, ``jsonfile``). A
room imports only rooms below it, so no package imports one that imports it (a loop between
packages fails here even when no two modules form a circle).
"""

from __future__ import annotations

import ast
from pathlib import Path

import scart_bench

ROOT = Path(__file__).resolve().parents[1]
#: subpackage -> its folder in the source tree (pyproject.toml maps them)
FOLDERS = {"benchmark": ROOT / "benchmark", "detectors": ROOT / "detectors", "generator": ROOT / "generator",
           "reports": ROOT / "reports", "cli": ROOT / "scart_bench" / "cli", "dataset": ROOT / "scart_bench" / "dataset"}

#: room -> the rooms it may import (besides itself)
BASE = {"base"}
#: the shared services beside the dataset format: datasets and run folders at URLs (``scart_bench.storage``,
#: which uses the dataset's folder lock) and the connection to a Dask cluster (``scart_bench.cluster``)
SERVICES = {"storage", "cluster"}
ALLOWED = {
    "base": set(),
    "dataset": BASE,
    "cluster": BASE,
    "storage": {"dataset"} | BASE,
    "generator": {"dataset"} | SERVICES | BASE,
    "detectors": {"dataset"} | BASE,
    "testing": {"generator", "detectors", "dataset"} | BASE,  # the conformance kit for plugin authors
    "benchmark": {"generator", "detectors", "dataset"} | SERVICES | BASE,
    "reports": {"benchmark", "generator", "detectors", "dataset"} | SERVICES | BASE,
    "cli": {"reports", "benchmark", "generator", "detectors", "dataset"} | SERVICES | BASE,
    "main": {"cli"},
}


def _modules() -> dict[str, Path]:
    out = {"scart_bench": ROOT / "scart_bench" / "__init__.py"}
    for f in (ROOT / "scart_bench").glob("*.py"):
        if f.stem != "__init__":
            out[f"scart_bench.{f.stem}"] = f
    for sub, folder in FOLDERS.items():
        for f in folder.rglob("*.py"):
            parts = list(f.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(["scart_bench", sub, *parts])] = f
    return out


def _room(module: str) -> str:
    parts = module.split(".")
    if len(parts) == 1 or parts[1] in ("errors", "names", "progress", "jsonfile"):
        return "base"
    if parts[1] == "__main__":
        return "main"
    return parts[1]


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """Project modules imported anywhere in the file (module level or inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        for n in names:
            if n in modules:
                found.add(n)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {m: _imports(p, modules) - {m} for m, p in modules.items()}


def test_every_module_is_under_the_one_import_name():
    assert Path(scart_bench.__file__).parent == ROOT / "scart_bench"
    assert len(_modules()) > 40
    assert set(map(_room, _modules())) <= set(ALLOWED), set(map(_room, _modules())) - set(ALLOWED)


def test_no_import_circle():
    graph = _graph()
    # package __init__ modules are containers: an import of a.b.c also runs a and a.b, which is no circle
    edges = {m: {d for d in deps if not m.startswith(d + ".")} for m, deps in graph.items()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(edges.get(m, ())):
            if state.get(d) == 1:
                cycle = stack[stack.index(d):] + [d]
                raise AssertionError("import circle: " + " -> ".join(cycle))
            if d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(edges):
        if m not in state:
            visit(m)


def test_rooms_import_only_the_rooms_below_them():
    bad = []
    for module, deps in _graph().items():
        room = _room(module)
        for d in deps:
            if _room(d) != room and _room(d) not in ALLOWED[room]:
                bad.append(f"{module} ({room}) imports {d} ({_room(d)})")
    assert not bad, "\n".join(bad)


def test_the_layers_have_no_loop_between_packages():
    """The allowed imports themselves form no loop, so no package can import one that imports it."""
    seen: dict[str, int] = {}

    def visit(room: str) -> None:
        seen[room] = 1
        for below in ALLOWED[room]:
            assert seen.get(below) != 1, f"the rooms {room} and {below} may import each other"
            if below not in seen:
                visit(below)
        seen[room] = 2

    for room in ALLOWED:
        visit(room)


def test_the_dataset_format_stands_alone():
    """A plugin author or a report reader reads a dataset without the simulator, the benchmark or the reports."""
    for module, deps in _graph().items():
        if _room(module) == "dataset":
            assert all(_room(d) in ("dataset", "base") for d in deps), (module, deps)


def test_the_command_line_is_one_folder_one_module_per_command():
    from scart_bench.cli.main import COMMAND_MODULES, build_parser

    assert not list((ROOT / "benchmark").glob("cli*.py")), "command modules belong in scart_bench/cli/"
    commands = build_parser()._subparsers._group_actions[0].choices  # noqa: SLF001 (argparse has no public list)
    assert len(COMMAND_MODULES) == len(commands), (COMMAND_MODULES, sorted(commands))


def test_no_private_name_is_imported_across_modules():
    bad = []
    modules = _modules()
    for module, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module in modules:
                bad += [f"{module} imports {node.module}.{a.name}" for a in node.names
                        if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, "\n".join(bad)


def test_the_generator_top_level_stays_small():
    """Subsystems live in their folders; about a dozen modules stay at the top."""
    assert len(list((ROOT / "generator").glob("*.py"))) <= 12


#: The generator's rooms, from the bottom: a subfolder (or a top-level module) imports only rooms on a lower
#: line, at module level or inside a function. The order is the one the code follows: the shared base
#: (constants, geodesy, the package's own ``__init__``) -> the vehicle and its sensors -> the flight software
#: -> the telemetry streams and tables -> the engines that fly a batch -> the attack layer (with the
#: profiles and the defences beside it) -> the run modes -> recorded logs and the MAVLink link -> ROS ->
#: the attacks -> the plan of a dataset -> hardware in the loop -> the sitl, the like-a-log profiles and
#: the sharded run -> the generate entry point.
GENERATOR_ROOMS = [
    {"__init__", "params", "geo", "attack_effect", "impact"},
    {"physics"},
    {"flight_software"},
    {"telemetry"},
    {"engine"},
    {"scart", "profiles", "defense"},
    {"modes"},
    {"logs", "mavlink"},
    {"ros"},
    {"attacks"},
    {"plan"},
    {"hil"},
    {"sitl", "like", "sharded"},
    {"generate"},
]
GENERATOR_LEVEL = {room: level for level, rooms in enumerate(GENERATOR_ROOMS) for room in rooms}


def _generator_room(module: str) -> str | None:
    parts = module.split(".")
    if parts[:2] != ["scart_bench", "generator"]:
        return None
    return parts[2] if len(parts) > 2 else "__init__"


def _generator_imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """Project modules a file imports; ``from package import module`` counts as the module only."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name in modules}
        elif isinstance(node, ast.ImportFrom) and node.module in modules:
            subs = {f"{node.module}.{a.name}" for a in node.names} & set(modules)
            found |= subs
            if len(subs) < len(node.names):
                found.add(node.module)
    return found


def test_every_generator_module_has_a_room():
    rooms = {_generator_room(m) for m in _modules()} - {None}
    assert rooms <= set(GENERATOR_LEVEL), rooms - set(GENERATOR_LEVEL)


def test_the_generator_rooms_import_one_way():
    """No subfolder imports one that imports it (physics <-> flight software, scart <-> ros ... were loops)."""
    modules = _modules()
    bad = []
    for module, path in sorted(modules.items()):
        room = _generator_room(module)
        if room is None:
            continue
        for d in sorted(_generator_imports(path, modules)):
            below = _generator_room(d)
            if below is not None and below != room and GENERATOR_LEVEL[below] >= GENERATOR_LEVEL[room]:
                bad.append(f"{module} ({room}) imports {d} ({below})")
    assert not bad, "\n".join(bad)


def test_no_two_generator_classes_share_a_name():
    """A class name says which class it is (two ``Commander`` s, the batch engines' and the sitl's, were one name)."""
    where: dict[str, list[str]] = {}
    for f in sorted((ROOT / "generator").rglob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ClassDef):
                where.setdefault(node.name, []).append(str(f.relative_to(ROOT)))
    shared = {name: files for name, files in where.items() if len(files) > 1}
    assert not shared, shared
