"""The command line's own error: bad options, shown as one line with exit code 2.

Library code raises the errors of :mod:`scart_bench.errors`; this one is for the CLI modules.
"""

from scart_bench.errors import ScartBenchError


class UsageError(ScartBenchError):
    """Bad command-line input (unknown name, missing file, conflicting options)."""
