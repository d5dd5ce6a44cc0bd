"""Benchmarks: ``python -m kx.bench NAME``.

Each prints its figures and ends with one line ``name: value unit (ratio X vs BASELINE)``, where the
baseline is measured in the same run (these machines are shared and noisy).

* ``sim``: live episode-steps per second (steps of episodes still running) of the batched evaluator
  on 4500 episodes of 3v2, with the heuristic policy and with a small neural policy on the 13-input
  layout (150 random networks x 30 trials), against the plain-Python reference on the same rules.
"""

from __future__ import annotations

import argparse
import time

from kx import runtime


def _timed_eval(policy, policy_params, starts, params, config, repeats: int):
    import jax

    from kx.sim import evaluate as ev

    ev.evaluate(policy, policy_params, starts, params, config)  # compile every width once
    best = None
    for _ in range(repeats):
        c = ev.EvalCounters()
        t0 = time.perf_counter()
        stats = ev.evaluate(policy, policy_params, starts, params, config, counters=c)
        jax.block_until_ready(stats.fitness)
        dt = time.perf_counter() - t0
        if best is None or c.live_steps / dt > best[0].live_steps / best[1]:
            best = (c, dt, stats)
    return best


def _reference_rate(config, params, seconds: float, seed: int = 0) -> tuple[float, int]:
    """Steps per second of the reference, on episodes from the same reset, holding unless a taker
    is within 2 king moves and then passing to a random teammate (plain Python decisions)."""
    import jax
    import numpy as np

    from kx.sim import env
    from kx.sim import reference as ref

    starts = env.as_numpy(env.reset_batch(jax.random.key(seed), 256, params, config))
    rng = np.random.default_rng(seed)
    steps, t0, i = 0, time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        s = ref.RefState.from_arrays({k: v[..., i % 256] for k, v in starts.items()})
        i += 1
        while not s.done:
            a = s.holder
            if s.holder >= 0 and min(ref.cheb(s.keepers[s.holder], t) for t in s.takers) <= 2:
                a = int(rng.integers(0, config.n_keepers))
            s = ref.step(s, a, 0, config, int(params.max_iterations))
            steps += 1
    return steps / (time.perf_counter() - t0), steps


def bench_sim(args) -> None:
    import jax

    from kx.sim import env, policies
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; task {config.name}; "
          f"{args.episodes} episodes; max_iterations {params.max_iterations}")
    starts = env.reset_batch(jax.random.key(args.seed), args.episodes, params, config)

    c, dt, stats = _timed_eval(policies.heuristic(config), None, starts, params, config, args.repeats)
    heur = c.live_steps / dt
    print(f"heuristic: {c.live_steps} live steps in {dt:.3f} s = {heur:.0f} live-steps/s; "
          f"executed {c.executed_steps} lane-steps ({c.live_steps / c.executed_steps:.2f} live); "
          f"widths {list(c.widths)}; mean fitness {float(stats.fitness.mean()):.4f}")

    n_pol = 150
    trials = jax.tree.map(lambda a: a[..., : args.episodes // n_pol], starts)
    mlp = policies.mlp_init(jax.random.key(args.seed + 1), n_pol, config)
    c2, dt2, stats2 = _timed_eval(policies.mlp_policy(config), mlp, trials, params, config, args.repeats)
    nn_rate = c2.live_steps / dt2
    print(f"mlp 13-8-3 ({n_pol} networks x {args.episodes // n_pol} trials): {c2.live_steps} live steps in "
          f"{dt2:.3f} s = {nn_rate:.0f} live-steps/s; executed {c2.executed_steps} "
          f"({c2.live_steps / max(c2.executed_steps, 1):.2f} live); mean fitness "
          f"{float(stats2.fitness.mean()):.4f}")

    ref_rate, ref_steps = _reference_rate(config, params, args.reference_seconds, args.seed)
    print(f"reference (plain Python, one episode at a time): {ref_steps} steps = {ref_rate:.0f} steps/s")
    print(f"mlp: {nn_rate:.0f} live-steps/s (ratio {nn_rate / ref_rate:.1f} vs reference)")
    print(f"sim: {heur:.0f} live-steps/s (ratio {heur / ref_rate:.1f} vs reference)")


BENCHES = {"sim": bench_sim}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", choices=sorted(BENCHES))
    p.add_argument("--episodes", type=int, default=4500)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--reference-seconds", type=float, default=5.0)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    runtime.setup()
    BENCHES[args.name](args)


if __name__ == "__main__":
    main()
