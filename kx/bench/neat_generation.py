"""``python -m kx.bench neat_generation``: one NEAT generation step (speciate and reproduce) against
evaluating the same population of 150 networks on 30 keep-away trials, over a real 3v2 run."""

from __future__ import annotations

import time


def run(args) -> None:
    """Seconds of one NEAT generation step (``tell``: speciate and reproduce) against evaluating the same
    population of 150 networks on 30 keep-away trials (3v2, 13/3 layout), generation by generation of a
    real run, both after compilation."""
    import jax
    import numpy as np

    from kx.evolve.policy import neat_policy
    from kx.neat import presets
    from kx.neat.algorithm import NEAT
    from kx.sim import env
    from kx.sim import evaluate as ev
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    ncfg, nparams = presets.keepaway()
    neat = NEAT(ncfg, nparams)
    policy = neat_policy(config, ncfg)
    key = jax.random.key(args.seed)
    k_start, k_init, k_loop, k_noise = jax.random.split(key, 4)
    starts = env.reset_batch(k_start, 30, params, config)
    state = neat.init(k_init)
    # Compile tell once on the initial population (timed separately).
    t0 = time.perf_counter()
    jax.block_until_ready(neat.tell(k_loop, state.population, jax.numpy.zeros(ncfg.population_size), state))
    compile_tell = time.perf_counter() - t0
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; 3v2, population "
          f"{ncfg.population_size}, 30 trials, {args.generations} generations; tell compiled in {compile_tell:.1f} s")
    rows = []
    for g in range(args.generations):
        t0 = time.perf_counter()
        nets = neat.networks(state.population)
        c = ev.EvalCounters()
        stats = ev.evaluate(policy, nets, starts, params, config, counters=c, key=k_noise)
        fitness = stats.fitness.mean(axis=1)
        jax.block_until_ready(fitness)
        t_eval = time.perf_counter() - t0
        t0 = time.perf_counter()
        state, m = neat.tell(jax.random.fold_in(k_loop, g), state.population, fitness, state)
        jax.block_until_ready(state)
        t_tell = time.perf_counter() - t0
        rows.append((t_eval, t_tell))
        print(f"gen {g:3d}  best {float(m['best_fitness']):.4f}  mean {float(m['mean_fitness']):.4f}  "
              f"species {int(m['n_species'])}  hidden {float(m['mean_hidden']):.2f}  live steps {c.live_steps}  "
              f"eval {t_eval * 1e3:.1f} ms  tell {t_tell * 1e3:.1f} ms  ({t_tell / t_eval:.3f})", flush=True)
    # The first generations compile the evaluator's batch widths; report the rest.
    body = np.array(rows[args.skip:])
    e, t = np.median(body[:, 0]), np.median(body[:, 1])
    print(f"median over generations {args.skip}..{args.generations - 1}: evaluation {e * 1e3:.1f} ms, "
          f"tell {t * 1e3:.1f} ms")
    print(f"neat_generation: {t * 1e3:.2f} ms (ratio {t / e:.3f} vs evaluation)")
