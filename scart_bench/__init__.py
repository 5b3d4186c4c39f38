"""scart-bench: simulated cyber-attacks on drone telemetry, labelled flight datasets and a benchmark of
anomaly detectors on them.

One import name for the whole project; the source tree keeps the project's top-level folders, mapped in
``pyproject.toml``:

- :mod:`scart_bench.generator`: the flight generator and the SCART attack layer (``generator/``);
- :mod:`scart_bench.detectors`: the detector protocol, registry and built-in adapters (``detectors/``);
- :mod:`scart_bench.dataset`: the dataset format: schema, records, layouts, reading, writing (``scart_bench/dataset/``);
- :mod:`scart_bench.benchmark`: the run and its evaluation: protocol, runner, jobs, executors, scoring, results
  store (``benchmark/``);
- :mod:`scart_bench.reports`: leaderboards, the HTML report and figures (``reports/``);
- :mod:`scart_bench.cli`: the ``scart-bench`` command line, one module per command (``scart_bench/cli/``);
- :mod:`scart_bench.data`: the shipped scenario grids and examples (``data/scenarios/``);
- :mod:`scart_bench.testing`: conformance checks for detector plugins.
"""

from __future__ import annotations

from pathlib import Path

__version__ = "0.1.0"

# Run from a source checkout without an install (or from a second work tree beside an editable install):
# the subpackages are the checkout's top-level folders next to this one.
_root = Path(__file__).resolve().parent.parent
if (_root / "pyproject.toml").is_file() and (_root / "generator" / "__init__.py").is_file():
    __path__.append(str(_root))  # noqa: F821 (module __path__)
