"""``python -m scart_bench``: the ``scart-bench`` command."""

from scart_bench.benchmark.cli import main

raise SystemExit(main())
