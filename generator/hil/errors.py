"""The bridge's one error: what is missing or went wrong between the flight software and a simulator."""

from __future__ import annotations

from scart_bench.errors import ScartBenchError


class HilError(ScartBenchError):
    """A simulator that cannot be started or reached (no Java, no jar, no first message), or a
    scenario the bridge does not carry; the command line prints it in one line and exits 2."""
