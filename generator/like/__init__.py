"""Generated flights fitted to a user's logs: ``scart-bench generate --like LOG...`` and the profile
TOML files ``generate --profile FILE.toml`` reads (docs/like.md)."""
