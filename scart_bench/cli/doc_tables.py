"""The docs' reference tables, generated from the code so that they cannot drift.

Each table sits in its page between ``<!-- generated: NAME -->`` and ``<!-- /generated: NAME -->``;
``python -m scart_bench.cli.doc_tables`` rewrites them all, ``--check`` lists the tables whose page
disagrees with the code (exit 1) and writes nothing. ``tests/test_doc_tables.py`` runs the check per table.
It lives beside the command line because one table is the command line's own (the parser).
"""

from __future__ import annotations

import argparse
import inspect
import re
import sys
from collections.abc import Callable
from pathlib import Path

#: the repository's docs/ folder (the tables are the repository's, not the installed package's)
DOCS = Path(__file__).resolve().parents[2] / "docs"


def _markdown(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    return "\n".join([*lines, *("| " + " | ".join(c.replace("|", "\\|") for c in r) + " |" for r in rows)])


def _doc(cls) -> str:
    """A class's docstring as one line (a table cell)."""
    return " ".join(inspect.cleandoc(cls.__doc__ or "").split())


def _param(p) -> str:
    """One scenario parameter as the tables show it: `name` (type, required or default, range, choices)."""
    parts = [p.kind.__name__, "required" if p.required else f"default {p.default!r}"]
    if p.minimum is not None:
        parts.append(f"{'>' if p.exclusive_min else '>='} {p.minimum:g}")
    if p.maximum is not None:
        parts.append(f"<= {p.maximum:g}")
    if p.choices:
        parts.append("one of " + ", ".join(map(str, p.choices)))
    return f"`{p.name}` ({', '.join(parts)}{': ' + p.help if p.help else ''})"


def _params(spec) -> str:
    return "; ".join(_param(p) for p in spec) or "(none)"


def conditions_table() -> str:
    """Every start/end condition a scenario may name (``generator/scart/conditions.py``)."""
    from scart_bench.generator.scart.conditions import CONDITIONS

    return _markdown(["condition", "meaning", "parameters"],
                     [[f"`{name}`", _doc(c), _params(c.spec)] for name, c in CONDITIONS.items()])


def actions_table() -> str:
    """Every action on messages (``generator/scart/actions.py``, ``link_actions.py``)."""
    from scart_bench.generator.scart.actions import ACTIONS

    return _markdown(["action", "meaning", "parameters"],
                     [[f"`{name}`", _doc(a), _params(a.spec)] for name, a in ACTIONS.items()])


def physical_actions_table() -> str:
    """Every action on the physics (``generator/scart/effects.py``): injection points environment, vehicle."""
    from scart_bench.generator.scart.effects import EFFECTS

    return _markdown(["action", "point", "meaning", "parameters"],
                     [[f"`{name}`", f"`{e.point}`", _doc(e), _params(e.spec)] for name, e in EFFECTS.items()])


def quantities_table() -> str:
    """Quantities by meaning and what each resolves to (``generator/scart/meanings.py``)."""
    from scart_bench.generator.scart.meanings import QUANTITIES

    return _markdown(["quantity", "field", "resolves to (every one the input has)"],
                     [[q, f, ", ".join(f"`{c}`" for c in cands)]
                      for q, fields in QUANTITIES.items() for f, cands in fields.items()])


def topics_table() -> str:
    """The link topics with their fields, units and rates (``scart_bench/dataset/schema.py``)."""
    from scart_bench.dataset.schema import topics_markdown

    return topics_markdown().rstrip("\n")


def cli_table() -> str:
    """Every command of ``scart-bench`` with its help and options (``scart_bench/cli/main.py``'s parser)."""
    from scart_bench.cli.main import build_parser

    commands = build_parser()._subparsers._group_actions[0]  # noqa: SLF001 (argparse has no public list)
    helps = {a.dest: a.help for a in commands._choices_actions}  # noqa: SLF001
    rows = []
    for name, sub in commands.choices.items():
        options = [a.option_strings[-1] if a.option_strings else a.metavar or a.dest
                   for a in sub._actions if not isinstance(a, argparse._HelpAction)]  # noqa: SLF001
        rows.append([f"`{name}`", helps.get(name) or "",
                     ", ".join(f"`{o}`" for o in options if o not in (argparse.SUPPRESS,))])
    return _markdown(["command", "what it does", "options"], rows)


#: table name -> (the page it sits in, the function that makes it)
TABLES: dict[str, tuple[str, Callable[[], str]]] = {
    "conditions": ("scenarios.md", conditions_table),
    "actions": ("scenarios.md", actions_table),
    "physical-actions": ("scenarios.md", physical_actions_table),
    "quantities": ("scenarios.md", quantities_table),
    "topics": ("topics.md", topics_table),
    "cli": ("cli.md", cli_table),
}


def _block(name: str) -> re.Pattern:
    return re.compile(rf"(<!-- generated: {re.escape(name)} -->\n)(.*?)(<!-- /generated: {re.escape(name)} -->)",
                      re.DOTALL)


def in_page(name: str, docs: Path = DOCS) -> str:
    """The table ``name`` as its page holds it (ValueError when the page has no markers for it)."""
    page = docs / TABLES[name][0]
    m = _block(name).search(page.read_text(encoding="utf-8"))
    if m is None:
        raise ValueError(f"{page}: no '<!-- generated: {name} -->' ... '<!-- /generated: {name} -->' block")
    return m.group(2).rstrip("\n")


def write(name: str, docs: Path = DOCS) -> bool:
    """Rewrite the table ``name`` in its page; True when it changed."""
    page = docs / TABLES[name][0]
    text = page.read_text(encoding="utf-8")
    in_page(name, docs)  # the markers are there
    new = _block(name).sub(lambda m: m.group(1) + TABLES[name][1]() + "\n" + m.group(3), text, count=1)
    if new != text:
        page.write_text(new, encoding="utf-8")
    return new != text


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scart_bench.cli.doc_tables", description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="list the tables whose page disagrees with the code; "
                   "write nothing (exit 1 when any does)")
    p.add_argument("names", nargs="*", metavar="NAME", help=f"tables ({', '.join(TABLES)}; "
                   "default all)")
    args = p.parse_args(argv)
    names = args.names or list(TABLES)
    unknown = [n for n in names if n not in TABLES]
    if unknown:
        p.error(f"unknown table(s) {', '.join(unknown)}; expected some of {', '.join(TABLES)}")
    if args.check:
        stale = [n for n in names if in_page(n) != TABLES[n][1]()]
        for n in stale:
            print(f"docs/{TABLES[n][0]}: table {n!r} differs from the code; run python -m scart_bench.cli.doc_tables",
                  file=sys.stderr)
        return 1 if stale else 0
    for n in names:
        print(f"docs/{TABLES[n][0]} {n}: {'rewritten' if write(n) else 'unchanged'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
