"""What several benchmarks share: the held-out test states' seed, the spread of a figure over seeds, and
paths timed in turn."""

from __future__ import annotations

import time
from collections.abc import Callable

LEARNING_TEST_SEED = 2026  # the test stream of this seed: the same 1000 test states for every run


def sd(values) -> float:
    """The sample standard deviation of a numpy array of figures over seeds (0 for a single one)."""
    return values.std(ddof=1) if values.size > 1 else 0.0


def in_turn(paths: dict[str, Callable[[], object]], rounds: int) -> dict[str, list[float]]:
    """Each path's wall seconds over ``rounds`` rounds, the paths called one after another in each round
    (so that a machine's load moving over the minutes falls on all of them alike); each path returns once
    its work is done (block on its results)."""
    times = {k: [] for k in paths}
    for _ in range(rounds):
        for k, f in paths.items():
            t0 = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
    return times
