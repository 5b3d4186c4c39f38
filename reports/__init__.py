"""Leaderboards and figures from benchmark runs."""
