"""What several benchmarks share: the held-out test states' seed, the spread of a figure over seeds, paths
timed in turn, and a decision repeated inside one compiled loop."""

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


def repeated(fn, reps: int):
    """``loop(params, state)``, jitted: ``fn(params, state)`` (a decision: an int or float array ``[*B]``)
    applied ``reps`` times inside one compiled loop (so that dispatch does not count), the sum of its
    answers returned. Each iteration's state depends on the last one's result (a nudge that is always 0,
    which XLA cannot prove), so the work is redone every iteration instead of hoisted out of the loop."""
    import jax
    import jax.numpy as jnp

    @jax.jit
    def loop(params, state):
        def body(i, carry):
            state, acc = carry
            acc = acc + fn(params, state).astype(jnp.float32)
            nudge = (acc > 3e38).astype(state.keeper_x.dtype)
            return state.replace(keeper_x=state.keeper_x + nudge[None], t=state.t + 1), acc
        return jax.lax.fori_loop(0, reps, body, (state, jnp.zeros(state.holder.shape, jnp.float32)))[1]

    return loop
