"""Shipped data: scenario grids and example scenarios under ``scenarios/`` (read through importlib.resources)."""
