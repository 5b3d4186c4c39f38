"""The one rule for every id that becomes a file or folder name (scenario, flight, detector, run), and
a path join that cannot leave its folder.

An id is 1-200 characters of ``A-Z a-z 0-9 _ . + -``, does not start with a dot, and holds no ``..``.
So ``../x``, ``a/b``, ``normal-0000/.``, a NUL byte or a 300-character id never reach the file system.
"""

from __future__ import annotations

import re
from pathlib import Path

from scart_bench.errors import ScartBenchError

MAX_ID_LENGTH = 200
_ID = re.compile(r"[A-Za-z0-9_.+-]+")


class IdError(ScartBenchError):
    """An id or a path that would not stay inside its folder."""


def check_id(value: object, what: str) -> str:
    """``value`` if it is a valid id; IdError naming ``what`` (e.g. "--flight-id") and the rule otherwise."""
    if not isinstance(value, str):
        raise IdError(f"{what}: expected a string id, got {value!r}")
    shown = value if len(value) <= 60 else value[:57] + "..."
    if not value:
        raise IdError(f"{what}: the id is empty; expected 1-{MAX_ID_LENGTH} characters of A-Z a-z 0-9 _ . + -")
    if len(value) > MAX_ID_LENGTH:
        raise IdError(f"{what} {shown!r}: {len(value)} characters; ids are at most {MAX_ID_LENGTH}")
    if not _ID.fullmatch(value) or value.startswith(".") or ".." in value:
        raise IdError(f"{what} {shown!r}: not a valid id; expected characters A-Z a-z 0-9 _ . + - only, "
                         "not starting with '.' and without '..' (ids become file names)")
    return value


def inside(root: str | Path, *parts: str) -> Path:
    """``root / parts...``, refused (IdError) unless the resolved path stays inside ``root``."""
    base = Path(root).resolve()
    path = base.joinpath(*parts).resolve()
    if path != base and base not in path.parents:
        raise IdError(f"{Path(root).joinpath(*parts)}: resolves to {path}, outside {base}")
    return path
