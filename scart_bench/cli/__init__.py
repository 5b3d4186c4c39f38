"""The ``scart-bench`` command line: :mod:`.main` builds the parser, one module per sub-command."""
