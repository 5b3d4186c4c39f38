"""The one rule for every id that becomes a file or folder name (scenario, flight, detector, run), and
a path join that cannot leave its folder.

An id is 1-200 characters of ``A-Z a-z 0-9 _ . + -``, does not start with a dot, and holds no ``..``.
So ``../x``, ``a/b``, ``normal-0000/.``, a NUL byte or a 300-character id never reach the file system.

A relative name that comes from data (a bucket key under a URL, a manifest path, a run-folder
entry, an archive member) is joined to its local folder by :func:`join_inside` only: plain
``/``-separated segments, nothing absolute, no ``.``/``..``/empty segment, backslash or NUL, and the
joined path (links resolved) still inside the folder. A hostile key such as
``ds/flights/../../../../home/u/.bashrc`` is refused before anything is written.
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


def relative_parts(name: object, what: str, root: str | Path | None = None) -> tuple[str, ...]:
    """The segments of ``name``, a ``/``-separated relative name from data (bucket key, manifest
    path, archive member); IdError unless every segment is a plain name, so that it cannot leave the
    folder it is joined to. ``what`` says where the name comes from, e.g. ``"s3://b/ds: object key"``
    or ``"ds/manifest.parquet: field 'path'"``; the message is ``<what> '<name>' <why>...``."""
    shown = repr(name if not isinstance(name, str) or len(name) <= 120 else name[:117] + "...")
    why = None
    if not isinstance(name, str):
        why = "is not a string"
    elif not name:
        why = "is empty"
    elif "\0" in name:
        why = "holds a NUL byte"
    elif "\\" in name:
        why = "holds a backslash"
    elif name.startswith("/"):
        why = "is absolute"
    elif "" in name.split("/"):
        why = "has an empty segment ('//' or a trailing '/')"
    elif any(part in (".", "..") for part in name.split("/")):
        why = "has a '.' or '..' segment"
    if why:
        where = f" {root}" if root is not None else " its folder"
        raise IdError(f"{what} {shown} {why}, so it could leave{where}; refused (expected a relative path of "
                      "plain names separated by '/')")
    return tuple(name.split("/"))


def join_inside(root: str | Path, name: object, what: str) -> Path:
    """``root / name`` for a relative name from data (see :func:`relative_parts`), refused (IdError,
    one line naming ``what``, the name and ``root``) when it would leave ``root``, links included.
    The one join for every remote or relative name mapped to a local folder."""
    parts = relative_parts(name, what, root)
    try:
        return inside(root, *parts)
    except IdError:
        raise IdError(f"{what} {'/'.join(parts)!r} resolves outside {root} (through a link); refused") from None
