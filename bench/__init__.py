"""Benchmarks of hostd against peer slicers and of the daemon's latency (not part of the tests)."""
