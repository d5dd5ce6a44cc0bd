"""Speed of the Bird's Eye View policy in the batched evaluator, against the heuristic.

``python scripts/bench_bev.py [--policies bev,heuristic,dense] [--repeats 2]``

150 random substrates (``w ~ U(-5, 5)`` where a random expression mask, about half the links, is on;
``b ~ U(-5, 5)``) x 30 start states of the default 3v2 task with its default parameters, evaluated by
:func:`kx.sim.evaluate.evaluate` with one XLA host device per core (as ``kx.bench`` runs). Prints, per
policy, the first call (compilation of every batch width plus one evaluation) and the best warm call's
live lane-steps per second; the heuristic policy plays the same starts with the same kick noise.

Measured 2026 on the 2-core development machine (idle; its persistent compilation cache warm, cold
figures in brackets, taken under load): heuristic 8.6M live-steps/s (first call 9.8 s [27 s]); BEV
"paper" 0.49M live-steps/s (first call 15 s [46 s]), a ratio of 0.06. Random substrates end their
episodes after about 14 iterations (the heuristic's after 124), so the evaluator's per-call costs
weigh on the BEV figure; the step alone (4096 lanes in lockstep for 50 iterations, 2 devices) ran the
heuristic at 12.0M lane-steps/s, the BEV policy at 1.62M (0.13) and the dense reference at 0.086M.
What dominated the BEV policy then: XLA CPU's gather, about 1.2 ns per weight, 231 weights per lane and
iteration for 3v2 (a measured 280 ns of the policy's ~600 ns), then the 231 products (~120 ns) and the
sparse image (~95 ns). These figures are of the code before 2026-12-03, which gathered every slot of the
image; the policy now leaves the padding out and reads the weights inside its sums (docs/hyperneat.md,
"What it costs"). Random substrates lose the ball within a few iterations: ``python -m kx.bench policies``
measures a trained population.
"""

from __future__ import annotations

import argparse
import time

from kx import runtime


def substrates(key, g: int, n: int):
    import jax
    import jax.numpy as jnp

    kw, km, kb = jax.random.split(key, 3)
    w = jax.random.uniform(kw, (g, n, n), jnp.float32, -5.0, 5.0)
    w = jnp.where(jax.random.bernoulli(km, 0.5, (g, n, n)), w, 0.0)
    return {"w": w, "b": jax.random.uniform(kb, (g, n), jnp.float32, -5.0, 5.0)}


def timed(name, policy, table, starts, params, config, repeats: int) -> float:
    import jax

    from kx.sim import evaluate as ev

    key = jax.random.key(1)
    t0 = time.perf_counter()
    c0 = ev.EvalCounters()
    jax.block_until_ready(ev.evaluate(policy, table, starts, params, config, key=key, counters=c0).fitness)
    first = time.perf_counter() - t0
    best = None
    for _ in range(repeats):
        c = ev.EvalCounters()
        t0 = time.perf_counter()
        stats = ev.evaluate(policy, table, starts, params, config, key=key, counters=c)
        jax.block_until_ready(stats.fitness)
        dt = time.perf_counter() - t0
        if best is None or dt < best[1]:
            best = (c, dt, stats)
    c, dt, stats = best
    rate = c.live_steps / dt
    print(f"{name}: first call {first:.1f} s (compile + run); warm {dt:.3f} s for {c.live_steps} live steps = "
          f"{rate:,.0f} live-steps/s; executed {c.executed_steps} ({c.live_steps / c.executed_steps:.2f} live); "
          f"mean fitness {float(stats.fitness.mean()):.4f}", flush=True)
    return rate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--policies", default="bev,heuristic,dense")
    ap.add_argument("--image", default="paper")
    ap.add_argument("--genomes", type=int, default=150)
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    runtime.setup()
    import jax
    import jax.numpy as jnp

    from kx.hyperneat import bev
    from kx.sim import env, policies
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    k_start, k_sub = jax.random.split(jax.random.key(args.seed))
    starts = env.reset_batch(k_start, args.trials, params, config)
    table = substrates(k_sub, args.genomes, config.field_size**2)
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; {config.name}; {args.genomes} "
          f"substrates x {args.trials} trials; {bev.n_entries(config)} sparse entries per lane", flush=True)
    rates = {}
    for name in args.policies.split(","):
        if name == "bev":
            rates[name] = timed(f"bev ({args.image})", bev.bev_policy(config, args.image), table, starts, params,
                                config, args.repeats)
        elif name == "heuristic":
            # a dummy parameter set per substrate, so that the heuristic plays the same G x T lanes
            rates[name] = timed("heuristic", policies.heuristic(config), jnp.zeros((args.genomes,)), starts,
                                params, config, args.repeats)
        elif name == "dense":
            rates[name] = timed(f"dense reference ({args.image})", bev.dense_policy(config, args.image), table,
                                starts, params, config, max(1, args.repeats - 1))
        else:
            raise SystemExit(f"--policies: allowed bev, heuristic, dense; got {name!r}")
    if "bev" in rates and "heuristic" in rates:
        print(f"bev / heuristic: {rates['bev'] / rates['heuristic']:.2f} (target >= 0.40)")
    if "bev" in rates and "dense" in rates:
        print(f"bev / dense: {rates['bev'] / rates['dense']:.1f}x")


if __name__ == "__main__":
    main()
