"""Detectors: the protocol, the registry and the built-in adapters."""
