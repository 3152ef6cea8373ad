"""Benchmark scripts, each run as ``python -m backend.bench.<name>``, and the modules only they use."""
