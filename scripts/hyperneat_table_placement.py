"""What HyperNEAT's table placement saves: ``python scripts/hyperneat_table_placement.py [--rounds 15]``.

On the trained 4v3 population of ``kx.bench policies`` (``kx/bench/data/policies/hyperneat_4v3.npz``) and its
150 x 30 lanes, in one process on every host device, each path timed in turn for ``--rounds`` rounds (medians):

* the three copies of the table the run loop made before (stacked, sliced, replicated onto every device);
* ``build, every hidden row, one device`` against ``build as the run loop makes it`` (``encoding.policy_params``:
  only the hidden rows the population uses, the rows of the table split over the devices);
* a generation's build and evaluation the way the run loop made it before 2026-12-04 (the table built on one
  device with every hidden row, stacked into the group's ``[R, P, ...]``, sliced again for the evaluator call,
  then copied whole onto every device by ``evaluate``) against ``RunGroup.evaluate`` now.

Both paths must give the same fitness of every episode (checked first); docs/hyperneat.md, "Where the table
lives", gives the figures."""

from __future__ import annotations

import argparse

from kx import runtime


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=15)
    args = p.parse_args()
    runtime.setup()
    import jax
    import numpy as np

    from kx.bench.common import in_turn
    from kx.bench.policies import load_fixture
    from kx.evolve import streams
    from kx.evolve import trainer as trm
    from kx.hyperneat import substrate as sb
    from kx.sim import env, lanes
    from kx.sim import evaluate as ev

    trainer, population, meta = load_fixture("hyperneat")
    enc, exp = trainer.encoding, trainer.exp
    keys = streams.training(meta["seed"], meta["generation"])
    trials = trainer.cfg.trials
    starts = env.reset_batch(keys.starts, trials, exp.sim_params, exp.sim)
    group = trm.RunGroup([trainer])
    runs = jax.tree.map(lambda a: a[None], population)

    def before():
        table = trm.stack_states([sb.build(population, enc.neat_config, enc.substrate)])
        params, s = trm._runs_slice(table, starts, np.int32(0), runs=1, trials=trials)
        return np.asarray(ev.evaluate(enc.policy, params, s, exp.sim_params, exp.sim, key=keys.eval[None]).fitness)

    def now():
        return np.asarray(group.evaluate(runs, starts, keys.eval[None]).fitness)

    whole = jax.block_until_ready(sb.build(population, enc.neat_config, enc.substrate))
    stacked = jax.block_until_ready(trm.stack_states([whole]))
    paths = {
        # the three copies the path before made of the table (docs/hyperneat.md, "Where the table lives")
        "copy 1: stacked into the group's [R, P, ...]": lambda: jax.block_until_ready(trm.stack_states([whole])),
        "copy 2: sliced again for the evaluator call": lambda: jax.block_until_ready(
            trm._runs_slice(stacked, starts, np.int32(0), runs=1, trials=trials)),
        "copy 3: whole onto every device (evaluate)": lambda: jax.block_until_ready(
            lanes.put_replicated(whole, jax.local_device_count())),
        "build, every hidden row, one device": lambda: jax.block_until_ready(
            sb.build(population, enc.neat_config, enc.substrate)),
        "build as the run loop makes it": lambda: jax.block_until_ready(enc.policy_params(population)),
        "generation's build + evaluation, before": before,
        "generation's build + evaluation, now (RunGroup.evaluate)": now,
    }
    if not np.array_equal(before(), now()):
        raise SystemExit("the two paths played different episodes")
    for f in paths.values():
        f()
    times = in_turn(paths, args.rounds)
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; {args.rounds} rounds in turn; "
          f"every episode the same on both paths")
    for k, v in times.items():
        print(f"{k}: {1e3 * np.median(v):.0f} ms (median; {1e3 * min(v):.0f} to {1e3 * max(v):.0f})")


if __name__ == "__main__":
    main()
