"""scart-bench: the flight generator and the SCART attack layer."""
