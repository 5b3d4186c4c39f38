"""Same bytes: the sha256 of every file a generation writes, to compare two versions of the generator.

    python -m perf.generate_hashes --profile quick --flights 4 --seed 3 --timing realistic --out after.json
    OTHER/venv/bin/python perf/generate_hashes.py ... --out before.json   # run from outside the checkout
    python -m perf.generate_hashes --compare before.json after.json

Generates with attacks (both modes) through ``generate_dataset``, as ``scart-bench generate`` does, into
a temporary folder, and writes ``{"files": {relative path: sha256}}``. ``--compare A B`` prints the files
that differ or are missing and exits 1 when any does (issue 51: realistic timing made cheaper with the
same bytes, realistic and ideal timing alike).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path


def hashes(folder: Path) -> dict[str, str]:
    """relative path -> sha256 of every file under ``folder``."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def compare(a: dict[str, str], b: dict[str, str]) -> list[str]:
    """The paths whose bytes differ, or that only one side has."""
    return sorted(p for p in set(a) | set(b) if a.get(p) != b.get(p))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--profile", default="quick")
    p.add_argument("--flights", type=int, default=4)
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--timing", default="realistic", help="ideal | realistic")
    p.add_argument("--scenarios", default=None, help="a scenario, grid or sweep file instead of the profile's grid")
    p.add_argument("--out", default=None, help="JSON file of the hashes")
    p.add_argument("--compare", nargs=2, metavar=("A", "B"), default=None, help="two JSON files of hashes")
    args = p.parse_args(argv)
    if args.compare:
        a, b = (json.loads(Path(f).read_text())["files"] for f in args.compare)
        bad = compare(a, b)
        print(f"{len(set(a) | set(b))} files, {len(bad)} differ" + "".join(f"\n  {x}" for x in bad[:20]))
        return 1 if bad else 0
    import dataclasses

    from scart_bench.generator.generate import generate_dataset
    from scart_bench.generator.profiles import get_profile

    cfg = dataclasses.replace(get_profile(args.profile), timing=args.timing).flight_config()
    tmp = Path(tempfile.mkdtemp(prefix="generate_hashes_"))
    try:
        t0 = time.perf_counter()
        out = generate_dataset(args.profile, tmp / "ds", seed=args.seed, n_normal=args.flights, config=cfg,
                               scenarios=args.scenarios)
        files = hashes(Path(out))
        wall = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    digest = hashlib.sha256(json.dumps(files, sort_keys=True).encode()).hexdigest()
    print(f"{args.profile} --flights {args.flights} --seed {args.seed} --timing {args.timing}: {len(files)} files, "
          f"sha256 of all {digest[:16]}, {wall:.1f} s", flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps({"args": vars(args), "digest": digest, "files": files}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
