"""Benchmarks runnable as ``gaintune bench <name>`` or ``python -m gaintune.bench.<name>``."""
