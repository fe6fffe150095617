"""Benchmarks that print figures (speed goals live here, not in timed tests)."""
