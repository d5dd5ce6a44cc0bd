"""HyperNEAT's substrate build against the reference build it replaced (2026-12-05), on trained 4v3 CPPNs:

    python scripts/substrate_build.py [--rounds 15]

On the trained 4v3 population of ``kx.bench policies`` (``kx/bench/data/policies/hyperneat_4v3.npz``, 150
CPPNs) and its 150 x 30 lanes, in one process on every host device:

* ``build``: :func:`kx.hyperneat.substrate.build` as the run loop calls it (``encoding.policy_params``: the
  hidden rows the population uses, the table's rows over the devices) against the same call with
  ``reference=True`` (the build until 2026-12-05: each hidden node's sum over all those rows, all three
  CPPN outputs on every link);
* ``generation``: ``RunGroup.evaluate`` (the substrates built, then the 4500 episodes), once with each build.

First it checks that both builds give the same bits and both generations the same fitness of every
episode; then each path is timed in turn for ``--rounds`` rounds (medians; min to max beside). The last
line: ``substrate_build: <ms> ms (ratio <x> vs reference)``. docs/hyperneat.md ("What it costs")
gives the figures.
"""

from __future__ import annotations

import argparse
import functools

from kx import runtime


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=15)
    args = p.parse_args()
    if args.rounds < 1:
        raise SystemExit(f"--rounds: allowed an integer >= 1, got {args.rounds}")
    runtime.setup()
    import jax
    import numpy as np

    from kx.bench.common import in_turn
    from kx.bench.policies import load_fixture
    from kx.evolve import streams
    from kx.evolve import trainer as trm
    from kx.hyperneat import substrate as sb
    from kx.sim import env

    trainer, population, meta = load_fixture("hyperneat")
    enc, exp = trainer.encoding, trainer.exp
    cfg, substrate = enc.neat_config, enc.substrate
    keys = streams.training(meta["seed"], meta["generation"])
    starts = env.reset_batch(keys.starts, trainer.cfg.trials, exp.sim_params, exp.sim)
    group = trm.RunGroup([trainer])
    runs = jax.tree.map(lambda a: a[None], population)
    build = sb.build
    reference = functools.partial(build, reference=True)

    def generation(which):
        sb.build = build if which == "build" else reference  # what encoding.policy_params calls
        try:
            return np.asarray(group.evaluate(runs, starts, keys.eval[None]).fitness)
        finally:
            sb.build = build

    n_dev = jax.local_device_count()
    rows, devices = sb.hidden_rows(population, cfg), n_dev if len(population.node_id) % n_dev == 0 else 1
    paths = {
        "build": lambda: jax.block_until_ready(enc.policy_params(population)),
        "reference": lambda: jax.block_until_ready(reference(population, cfg, substrate, devices, rows)),
        "generation with build": lambda: generation("build"),
        "generation with reference": lambda: generation("reference"),
    }
    new, old = paths["build"](), paths["reference"]()
    for k in ("w", "b"):
        if not np.array_equal(np.asarray(new[k]).view(np.uint32), np.asarray(old[k]).view(np.uint32)):
            raise SystemExit(f"the two builds differ in {k!r}")
    if not np.array_equal(generation("build"), generation("reference")):
        raise SystemExit("the two generations played different episodes")
    for f in paths.values():
        f()
    times = in_turn(paths, args.rounds)
    med = {k: 1e3 * float(np.median(v)) for k, v in times.items()}
    hidden = np.asarray(jax.vmap(sb.gn.n_hidden)(population))
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; {args.rounds} rounds in turn; "
          f"{len(hidden)} CPPNs of {hidden.min()}-{hidden.max()} hidden nodes ({rows} rows, {devices} device(s)); "
          "the same bits and the same episodes on both paths")
    for k, v in times.items():
        print(f"{k}: {med[k]:.0f} ms (median; {1e3 * min(v):.0f} to {1e3 * max(v):.0f})")
    print(f"generation: {med['generation with build']:.0f} ms (ratio "
          f"{med['generation with reference'] / med['generation with build']:.2f} vs reference)")
    print(f"substrate_build: {med['build']:.0f} ms (ratio {med['reference'] / med['build']:.2f} vs "
          "reference)")


if __name__ == "__main__":
    main()
