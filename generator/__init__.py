"""scart-bench: the flight generator and the SCART attack layer."""

__version__ = "0.1.0"
