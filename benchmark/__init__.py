"""The benchmark: a run and its evaluation (protocol, runner, jobs, executors, scoring, results store).

The command line that drives it lives in :mod:`scart_bench.cli`; the reports that read run folders in
:mod:`scart_bench.reports` (docs/architecture.md)."""
