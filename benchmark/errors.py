"""Errors shown to the user as one line with exit code 2."""


class UsageError(ValueError):
    """Bad input from the user (unknown name, missing file, conflicting options)."""
