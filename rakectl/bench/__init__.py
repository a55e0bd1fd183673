"""Benchmarks that print figures (never pass/fail): loop latency, tick stages, bus, excavation."""
