"""The project's errors. Every error that bad input can cause derives from :class:`ScartBenchError`;
library code raises these, and only the command line turns them into exit code 2 and one line."""


class ScartBenchError(ValueError):
    """Bad input to scart-bench: a file, field or value that is not what was expected.

    A ``ValueError`` so that callers that catch bad values in general also catch these.
    """


class RunError(ScartBenchError):
    """A benchmark run cannot be made, resumed or read as asked (unknown detector or parameter, a
    run folder of another config, an unreachable scheduler, a dataset workers cannot read)."""


class ReportError(ScartBenchError):
    """A report cannot be made from the given run folders."""


class ClusterError(ScartBenchError):
    """A dask cluster cannot be reached, or work sent to it failed (the task, the worker and why)."""
