"""What several benchmarks share: the held-out test states' seed and the spread of a figure over seeds."""

from __future__ import annotations

LEARNING_TEST_SEED = 2026  # the test stream of this seed: the same 1000 test states for every run


def sd(values) -> float:
    """The sample standard deviation of a numpy array of figures over seeds (0 for a single one)."""
    return values.std(ddof=1) if values.size > 1 else 0.0
