"""Benchmarks that print numbers and write JSON (never timed unit tests)."""
