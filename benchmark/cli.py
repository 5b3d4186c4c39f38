"""The ``scart-bench`` command line: a thin layer over functions a user can call from Python."""

from __future__ import annotations

import argparse
import sys


class UsageError(Exception):
    """Bad input from the user: printed as one clear line, exit code 2."""


def _cmd_detectors(args: argparse.Namespace) -> int:
    from detectors import registry

    for spec in args.plugin or []:
        registry.load_plugin(spec)
    for name, info in registry.available().items():
        params = ", ".join(f"{k}={v!r}" for k, v in info.parameters().items())
        print(f"{name:<14} {info.source:<28} {info.description}")
        if args.verbose:
            print(f"{'':<14} params: {params}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="scart-bench", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("detectors", help="list the known detectors (built-ins and plugins)")
    d.add_argument("--plugin", action="append", help="module:Class or path/to/file.py:Class")
    d.add_argument("-v", "--verbose", action="store_true", help="also print each detector's parameters")
    d.set_defaults(func=_cmd_detectors)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UsageError as exc:
        print(f"scart-bench {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
