"""Reading the project's small JSON files (dataset.json, config.json, status.json, ...) as data that
may be damaged or hostile: bounded in size and nesting, and every failure one line naming the file.

``json.loads`` of 100,000 nested ``[`` raises RecursionError, and a multi-GB file is read whole;
:func:`read_json` turns both, and every parse error, into a :class:`JsonFileError` that names the
file and what was expected.
"""

from __future__ import annotations

import json
from pathlib import Path

from scart_bench.errors import ScartBenchError

#: the largest JSON file the project reads (its own are a few kB; a run's config with a big grid ~1 MB)
MAX_JSON_BYTES = 64 * 1024 * 1024
#: the deepest nesting accepted (the project's own files nest 4-6 levels)
MAX_JSON_DEPTH = 100


class JsonFileError(ScartBenchError):
    """A JSON file that cannot be read, is not JSON, is too large or too deeply nested, or has the
    wrong shape."""


def _depth(text: str, limit: int) -> int:
    """The deepest bracket nesting of ``text`` (strings skipped), stopping once past ``limit``."""
    depth = deepest = 0
    in_string = escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            if depth > deepest:
                deepest = depth
                if deepest > limit:
                    return deepest
        elif ch in "]}":
            depth -= 1
    return deepest


def loads_bounded(text: str | bytes, source: str, max_depth: int = MAX_JSON_DEPTH) -> object:
    """``json.loads(text)``, refused with one line naming ``source`` when it is not JSON or nests
    deeper than ``max_depth``."""
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise JsonFileError(f"{source}: not UTF-8 text ({exc}); expected a JSON document") from None
    if text.count("[") + text.count("{") > max_depth and _depth(text, max_depth) > max_depth:
        raise JsonFileError(f"{source}: nested more than {max_depth} levels deep; expected a scart-bench JSON "
                            "file (damaged or not written by scart-bench)")
    try:
        return json.loads(text)
    except RecursionError:
        raise JsonFileError(f"{source}: nested too deeply to read; expected a scart-bench JSON file") from None
    except ValueError as exc:
        raise JsonFileError(f"{source}: not valid JSON ({exc}); expected a scart-bench JSON file "
                            "(damaged or not written by scart-bench)") from None


def read_json(path: str | Path, expect: type | tuple[type, ...] | None = dict,
              max_bytes: int = MAX_JSON_BYTES, max_depth: int = MAX_JSON_DEPTH) -> object:
    """The JSON document in ``path``, bounded and checked.

    ``expect``: the type the top level must have (a JSON object by default; None for any). Every
    failure (unreadable, larger than ``max_bytes``, not JSON, too deep, wrong top-level type) is a
    :class:`JsonFileError` naming the file.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise JsonFileError(f"{path}: {size:,} bytes; expected a JSON file of at most {max_bytes:,} bytes "
                                "(damaged or not written by scart-bench)")
        with open(path, "rb") as fh:
            raw = fh.read(max_bytes + 1)
    except OSError as exc:
        raise JsonFileError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if len(raw) > max_bytes:
        raise JsonFileError(f"{path}: more than {max_bytes:,} bytes; expected a small JSON file")
    value = loads_bounded(raw, str(path), max_depth)
    if expect is not None and not isinstance(value, expect):
        names = " or ".join(t.__name__ for t in (expect if isinstance(expect, tuple) else (expect,)))
        shown = {"dict": "a JSON object", "list": "a JSON array"}.get(names, names)
        raise JsonFileError(f"{path}: the top level is {type(value).__name__}; expected {shown}")
    return value
