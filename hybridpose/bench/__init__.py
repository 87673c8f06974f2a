"""Sequence benchmarks: seeded suites, the three modes (tracker-only, CNN-only, hybrid) on the same
frames, and per-sequence statistics."""
