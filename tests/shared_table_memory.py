"""Peak memory of an evaluation with a shared table (run by tests/test_shared_tables.py in a fresh process,
so that the peak is this evaluation's): 150 policies share 400 x 400 float32 matrices (96 MB, the size of
150 HyperNEAT substrates on the 20 x 20 Bird's Eye View) over 4500 lanes (150 x 30 trials). Copied into
every lane, as per-lane parameters are, the matrices would take 4500 x 400 x 400 x 4 bytes = 2.9 GB.

Episodes last at most 12 iterations by default (``python tests/shared_table_memory.py [max_iterations]``):
the memory does not depend on their length, and short ones visit a few widths of the ladder, each a
compilation, rather than ten. Prints ``peak_kib <ru_maxrss> widths <widths> mean_fitness <f>``.
"""

import os
import resource
import sys

import jax
import jax.numpy as jnp

from kx.sim import env
from kx.sim import evaluate as ev
from kx.sim.ops import pick
from kx.sim.policies import Policy, Shared
from kx.sim.types import KeepAwayConfig, KeepAwayParams

N_POL, N_TRIALS = 150, 30


def toy_policy(config: KeepAwayConfig) -> Policy:
    """Passes to the teammate ``k`` with the largest ``m[g, holder's cell, k's cell]`` if it is positive,
    else holds: a few entries of a 400 x 400 matrix, chosen by the state, decide."""
    w = config.field_size

    def apply(params: Shared, state, key):
        h = jnp.maximum(state.holder, 0)
        cell = state.keeper_y * w + state.keeper_x  # [K, *B]
        here = pick(cell, h)
        best, target = jnp.zeros(h.shape, jnp.float32), h
        for k in range(config.n_keepers):
            v = params.table["m"][params.index, here, cell[k]]  # [*B]: one entry per lane
            better = (k != h) & (v > best)
            best, target = jnp.where(better, v, best), jnp.where(better, k, target)
        return target

    return Policy("toy-shared", apply, shared=True)


def peak_kib() -> int:
    """This process's peak resident set size in KiB: ``VmHWM`` of /proc/self/status, the high-water mark
    of this program's own memory. Not ``ru_maxrss``: Linux carries that over from the process image
    before ``exec``, so a child of a pytest worker that holds 5 GB would report the worker's 5 GB."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux, may include the parent's


def main() -> None:
    if os.environ.get("KX_CACHE_DIR", "off") != "off":  # the test suite's compilation cache
        jax.config.update("jax_compilation_cache_dir", os.environ["KX_CACHE_DIR"])
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    config, params = KeepAwayConfig(), KeepAwayParams(max_iterations=int(sys.argv[1]) if len(sys.argv) > 1 else 12)
    cells = config.field_size ** 2
    table = {"m": jax.random.normal(jax.random.key(0), (N_POL, cells, cells), jnp.float32) - 1.5}
    starts = env.reset_batch(jax.random.key(1), N_TRIALS, params, config)
    c = ev.EvalCounters()
    stats = ev.evaluate(toy_policy(config), table, starts, params, config, key=jax.random.key(2), counters=c)
    assert stats.fitness.shape == (N_POL, N_TRIALS)
    peak = peak_kib()
    print(f"peak_kib {peak} widths {','.join(map(str, c.widths))} mean_fitness {float(stats.fitness.mean()):.4f}")


if __name__ == "__main__":
    main()
