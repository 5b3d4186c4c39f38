"""The docs' reference tables are the code's: one test per generated table (issue 49).

A failure means a doc and the code disagree; ``python -m scart_bench.cli.doc_tables`` rewrites the tables.
"""

from __future__ import annotations

import shutil

import pytest

from scart_bench.cli import doc_tables
from scart_bench.cli.doc_tables import DOCS, TABLES, in_page


@pytest.mark.parametrize("name", list(TABLES))
def test_the_doc_table_is_the_codes(name):
    page, make = TABLES[name]
    assert in_page(name) == make(), (f"docs/{page}: the table {name!r} differs from the code; "
                                     "run python -m scart_bench.cli.doc_tables")


def test_a_hand_edited_row_is_caught_and_rewritten(tmp_path):
    docs = tmp_path / "docs"
    shutil.copytree(DOCS, docs)
    page = docs / "scenarios.md"
    page.write_text(page.read_text().replace("| `stuck` |", "| `stuck_at` |", 1))
    assert in_page("actions", docs) != TABLES["actions"][1]()
    assert doc_tables.write("actions", docs) is True
    assert in_page("actions", docs) == TABLES["actions"][1]()
    assert doc_tables.write("actions", docs) is False  # nothing left to change


def test_every_command_and_action_is_in_its_table():
    from scart_bench.cli.main import COMMAND_MODULES
    from scart_bench.generator.scart.actions import ACTIONS

    assert in_page("cli").count("\n| `") == len(COMMAND_MODULES)
    assert all(f"| `{a}` |" in in_page("actions") for a in ACTIONS)
