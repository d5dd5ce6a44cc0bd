"""``python -m kx.bench novelty``: the novelty hybrid's generation step (k-NN over the population and a full
archive, archive update, hybrid score) against evaluating the population on 30 trials."""

from __future__ import annotations

import time


def _first_and_warm(fn, repeats: int):
    """``(first result, seconds of the first call, seconds of each of ``repeats`` warm calls)``."""
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return out, first, times


def run(args) -> None:
    """Milliseconds of the hybrid objective's generation step (SPEC section 4; :mod:`kx.novelty`): the
    novelty of 150 behaviour vectors against the rest of the population and a full archive of 1000 (the
    k = 15 nearest of 1149), the archive update and the hybrid score, jitted, as the run loop calls it
    (:class:`kx.evolve.objective.Hybrid`), against evaluating the same 150 genomes on 30 trials with
    the default config (``Trainer.evaluate`` on ``env.reset_batch`` starts). Both warm (medians of
    repeated calls, blocked until ready), with the first call's cost (compilation) beside them."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.evolve import config as cfg_lib
    from kx.evolve import objective as objectives
    from kx.evolve import run as run_lib
    from kx.evolve import streams
    from kx.sim import env

    cfg = cfg_lib.load(None, [f"seed={args.seed}"])
    trainer = run_lib.Trainer(cfg)
    enc, exp = trainer.encoding, trainer.exp
    population, _ = enc.ask(streams.learner_ask(cfg.seed, 0), trainer.init().learner)
    keys = streams.training(cfg.seed, 0)
    starts = env.reset_batch(keys.starts, cfg.trials, exp.sim_params, exp.sim)
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; config configs/neat_3v2.py: "
          f"{cfg.task} {enc.describe()}, population {cfg.population_size}, {cfg.trials} trials")

    def evaluate():
        stats = trainer.evaluate(population, starts, keys.eval)
        return jax.block_until_ready((stats.fitness.mean(axis=1), stats.behaviour.mean(axis=2)))

    (fitness, behaviour), eval_first, eval_times = _first_and_warm(evaluate, max(args.repeats, 5))
    e = float(np.median(eval_times))
    print(f"evaluation ({cfg.population_size} genomes x {cfg.trials} trials): first call {eval_first:.2f} s "
          f"(compiling every width); warm median {e * 1e3:.1f} ms over {len(eval_times)} calls (min "
          f"{min(eval_times) * 1e3:.1f}); mean fitness {float(fitness.mean()):.4f}")

    hcfg = cfg_lib.load(None, [f"seed={args.seed}", "objective=hybrid"])
    hybrid = objectives.make(hcfg)
    n = hcfg.novelty
    # a full archive: 1000 behaviour vectors in [0, 1]^3, the ring's head mid-way
    archive = hybrid.init(cfg.population_size)
    archive = archive.replace(entries=jax.random.uniform(jax.random.key(args.seed), archive.entries.shape),
                              size=jnp.int32(n.archive_size), head=jnp.int32(n.archive_size // 2),
                              added=jnp.int32(n.archive_size))

    def step():
        return jax.block_until_ready(hybrid.score(fitness, behaviour, archive))

    (_, after, m), nov_first, nov_times = _first_and_warm(step, 500)
    t = float(np.median(nov_times))
    print(f"novelty step (k {n.k}, rho {n.rho}, archive {int(after.size)}/{n.archive_size} full, threshold "
          f"{n.threshold}): first call {nov_first:.2f} s (compiling); warm median {t * 1e3:.3f} ms over "
          f"{len(nov_times)} calls (min {min(nov_times) * 1e3:.3f}); mean novelty {float(m['mean_novelty']):.4f}, "
          f"{int(m['archive_added'])} admitted, score sd {float(m['score_std']):.4f}")
    print(f"novelty: {t * 1e3:.3f} ms/generation (ratio {t / e:.4f} vs evaluation)")
