"""The import graph of the package: no circle between modules, and imports go one way
(benchmark and reports -> detectors / generator; generator and detectors never import the benchmark)."""

from __future__ import annotations

import ast
from pathlib import Path

import scart_bench

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"benchmark": "benchmark", "detectors": "detectors", "generator": "generator", "reports": "reports"}


def _modules() -> dict[str, Path]:
    out = {"scart_bench": ROOT / "scart_bench" / "__init__.py"}
    for f in (ROOT / "scart_bench").glob("*.py"):
        if f.stem != "__init__":
            out[f"scart_bench.{f.stem}"] = f
    for sub, folder in PACKAGES.items():
        for f in (ROOT / folder).rglob("*.py"):
            parts = list(f.relative_to(ROOT / folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(["scart_bench", sub, *parts])] = f
    return out


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


def test_generator_and_detectors_never_import_the_benchmark_or_reports():
    for module, deps in _graph().items():
        for low in ("scart_bench.generator", "scart_bench.detectors"):
            if module.startswith(low):
                bad = [d for d in deps if d.startswith(("scart_bench.benchmark", "scart_bench.reports"))]
                assert not bad, f"{module} imports {bad}"
        if module.startswith("scart_bench.generator"):
            bad = [d for d in deps if d.startswith("scart_bench.detectors")]
            assert not bad, f"{module} imports {bad}"
