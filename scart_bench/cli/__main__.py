"""``python -m scart_bench.cli``: the ``scart-bench`` command."""

from scart_bench.cli.main import main

if __name__ == "__main__":
    raise SystemExit(main())
