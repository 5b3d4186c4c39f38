"""The benchmark: CLI, protocol, runner, scoring and results store."""
