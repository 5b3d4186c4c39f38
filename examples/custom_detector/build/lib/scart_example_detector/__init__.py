"""Example scart-bench detector plugin (see README.md): ``RollingZScore``."""

from scart_example_detector.zscore import RollingZScore

__all__ = ["RollingZScore"]
