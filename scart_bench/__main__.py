"""``python -m scart_bench``: the ``scart-bench`` command."""

from scart_bench.cli.main import main

if __name__ == "__main__":  # not again in worker processes started by spawn (they import this module)
    raise SystemExit(main())
