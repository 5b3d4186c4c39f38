"""``scart-bench detectors``: list the known detectors with their source, tag and parameters."""

from __future__ import annotations

import argparse


def cmd_detectors(args: argparse.Namespace) -> int:
    from scart_bench.detectors import registry

    for spec in args.plugin or []:
        registry.load_plugin(spec)
    from scart_bench.detectors.base import DetectorError

    shown = 0
    for name, info in registry.available().items():
        tag = registry.tag_of(name)
        if args.tag and tag != args.tag:
            continue
        source = f"{info.source} ({tag})" if tag else info.source
        shown += 1
        try:
            description, parameters = info.description, info.parameters()
        except DetectorError as exc:  # e.g. deepod not installed: say how to install it
            print(f"{name:<14} {source:<40} unavailable: {exc}")
            continue
        print(f"{name:<14} {source:<40} {description}")
        params = ", ".join(f"{k}={v!r}" for k, v in parameters.items())
        print(f"{'':<14} params: {params}")
    print(f"{shown} detectors; `run --detectors all` runs the paper's eight (and plugins), "
          "`--detectors zoo` the zoo")
    return 0


def register(sub) -> None:
    d = sub.add_parser("detectors", help="list the known detectors (built-ins and plugins)")
    d.add_argument("--plugin", action="append", metavar="SPEC",
                   help="load a detector from module:Class or path/to/file.py:Class (repeatable)")
    d.add_argument("--tag", choices=("paper", "zoo"), help="list only the built-ins with this tag")
    d.set_defaults(func=cmd_detectors)
