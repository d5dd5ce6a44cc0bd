"""What the heuristic's margin tolerance (``kx.sim.policies.MARGIN_TOL``) changes on this machine: the same
episodes played with it and with it set to 0 (the heuristic before 2026-12-04, which compared its float32
margins exactly), on 3 x 4500 start states of every task, and on ``kx.bench policies``' 4v3 lanes.

    python scripts/heuristic_tolerance.py

Prints, per state set, the episodes whose fitness differs and each side's mean fitness and live steps
(docs/benchmarks.md, "On a GPU" and ``policies``).
"""

from __future__ import annotations

import argparse


def _play(tol: float, config, starts, params, key):
    import numpy as np

    from kx.sim import evaluate as ev
    from kx.sim import policies

    policies.MARGIN_TOL = tol
    policies.heuristic.cache_clear()  # a new policy object: traced again with this tolerance
    c = ev.EvalCounters()
    got = ev.evaluate(policies.heuristic(config), None, starts, params, config, key=key, counters=c)
    return np.asarray(got.fitness), c.live_steps


def main(argv=None) -> None:
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    from kx import runtime

    runtime.setup()
    import jax
    import jax.numpy as jnp

    from kx.bench.policies import load_fixture
    from kx.evolve import streams
    from kx.sim import env, policies
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    tol = policies.MARGIN_TOL
    params = KeepAwayParams()
    sets = []
    for task in ("3v2", "4v3", "5v3", "6v4"):
        config = KeepAwayConfig.from_task(task)
        for s in range(3):
            sets.append((f"{task} states of key {100 + s}", config, params,
                         env.reset_batch(jax.random.key(100 + s), 4500, params, config), jax.random.key(s)))
    trainer, _, meta = load_fixture("neat")
    exp = trainer.exp
    starts = env.reset_batch(streams.training(meta["seed"], meta["generation"]).starts, trainer.cfg.trials,
                             exp.sim_params, exp.sim)
    sets.append(("kx.bench policies' 4v3 lanes (150 x 30)", exp.sim, exp.sim_params,
                 jax.tree.map(lambda a: jnp.tile(a, meta["population_size"]), starts), jax.random.key(3)))
    total = changed = 0
    for name, config, prm, starts, key in sets:
        # every task's and tolerance's evaluator rungs compile; without this the process passes the kernel's
        # memory-map limit before the last set (kx.runtime: released at 75% of it, as the run loop does)
        notice = runtime.check_maps()
        if notice:
            print(notice, flush=True)
        exact, live_exact = _play(0.0, config, starts, prm, key)
        tolerant, live_tol = _play(tol, config, starts, prm, key)
        n = int((exact.view("uint32") != tolerant.view("uint32")).sum())
        total, changed = total + exact.size, changed + n
        print(f"{name}: {n} of {exact.size} episodes differ ({100 * n / exact.size:.1f}%); mean fitness "
              f"{exact.mean():.5f} exact, {tolerant.mean():.5f} with MARGIN_TOL {tol:g}; live steps {live_exact} "
              f"exact, {live_tol} with it", flush=True)
    print(f"heuristic_tolerance: {changed} of {total} episodes differ ({100 * changed / total:.2f}%)")


if __name__ == "__main__":
    main()
