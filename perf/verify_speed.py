"""What verifying a dataset's checksums costs, beside reading its flights.

    python -m perf.verify_speed DATASET [--read N]

Hashes every flight folder as ``Dataset.verify`` does (BLAKE2b over every file's bytes) and prints
the flights, bytes, wall time, MB/s and ms per flight; then reads ``--read`` flights (default 50)
the way a benchmark job does (``Dataset.flight``, navigator view) and prints the ratio of one
flight's hash to one flight's read. A run verifies every flight it uses once, before it starts.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from scart_bench.dataset import flight_checksum, open_dataset


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("dataset", type=Path)
    p.add_argument("--read", type=int, default=50, help="flights read for the comparison")
    args = p.parse_args(argv)
    ds = open_dataset(args.dataset)
    ids = ds.manifest["flight_id"].astype(str).tolist()
    size = sum(f.stat().st_size for fid in ids for f in ds.flight_dir(fid).rglob("*") if f.is_file())
    t0 = time.perf_counter()
    for fid in ids:
        flight_checksum(ds.flight_dir(fid))
    hash_s = time.perf_counter() - t0
    print(f"checksums: {len(ids)} flights, {size / 1e6:.1f} MB in {hash_s:.2f} s "
          f"({size / 1e6 / max(hash_s, 1e-9):.0f} MB/s, {1e3 * hash_s / len(ids):.2f} ms per flight)")
    sample = ids[: args.read]
    t0 = time.perf_counter()
    for fid in sample:
        ds.trust(fid)  # time the read alone
        ds.flight(fid)
    read_s = time.perf_counter() - t0
    per_read = read_s / max(len(sample), 1)
    print(f"reading: {len(sample)} flights in {read_s:.2f} s ({1e3 * per_read:.1f} ms per flight); "
          f"hash / read = {hash_s / len(ids) / per_read:.3f}")


if __name__ == "__main__":
    main()
