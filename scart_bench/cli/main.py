"""The ``scart-bench`` command line: a thin layer over functions a user can call from Python.

Each sub-command lives in its own module of this folder exposing ``register(subparsers)``; the handler it sets
with ``set_defaults(func=...)`` returns the exit code. Bad options raise ``UsageError``; the library
raises the errors of :mod:`scart_bench.errors` (``ValueError`` subclasses). Both exit with code 2 and
one clear line; ``run`` exits 3
when a job ended ERROR or TIMEOUT (after writing the run folder and naming those jobs).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from scart_bench.cli.common import UsageError
from scart_bench.errors import ScartBenchError

#: One module per sub-command, in the order ``scart-bench --help`` lists them.
COMMAND_MODULES = tuple(f"scart_bench.cli.{name}" for name in (
    "detectors", "generate", "import_logs", "attack", "run", "score", "report", "plot", "proxy", "sitl", "ros",
    "defend",
))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="scart-bench",
        description="SCART attack simulation, labelled flight datasets and an anomaly-detection benchmark.",
    )
    sub = p.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return p


def _check_text(args: argparse.Namespace) -> None:
    """Refuse an option value that is not valid UTF-8 (a file name in another encoding reaches Python as
    lone surrogates, which Parquet, JSON and the report cannot write): before anything runs."""
    from pathlib import Path

    for name, value in vars(args).items():
        for v in value if isinstance(value, list | tuple) else [value]:
            if isinstance(v, str | Path):
                try:
                    str(v).encode("utf-8")
                except UnicodeEncodeError:
                    option = "--" + name.replace("_", "-")
                    raise UsageError(f"{option} {str(v).encode('utf-8', 'replace').decode()!r}: not valid UTF-8; "
                                     "use a file or folder name in UTF-8") from None


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        _check_text(args)
        return int(args.func(args) or 0)
    except (ScartBenchError, ValueError) as exc:
        print(f"scart-bench {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # no space, read-only, permission, missing file: one line naming the path
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"scart-bench {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"scart-bench {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
