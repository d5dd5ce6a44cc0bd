"""``python -m kx.bench sim``: live episode-steps per second of the batched evaluator (heuristic and a small
neural policy on 4500 episodes of 3v2) and of the step alone, against the plain-Python reference on the
same rules."""

from __future__ import annotations

import time


def _timed_eval(policy, policy_params, starts, params, config, repeats: int):
    import jax

    from kx.sim import evaluate as ev

    key = jax.random.key(1)  # the kick noise (on by default)
    ev.evaluate(policy, policy_params, starts, params, config, key=key)  # compile every width once
    best = None
    for _ in range(repeats):
        c = ev.EvalCounters()
        t0 = time.perf_counter()
        stats = ev.evaluate(policy, policy_params, starts, params, config, counters=c, key=key)
        jax.block_until_ready(stats.fitness)
        dt = time.perf_counter() - t0
        if best is None or c.live_steps / dt > best[0].live_steps / best[1]:
            best = (c, dt, stats)
    return best


def _reference_rate(config, params, seconds: float, seed: int = 0) -> tuple[float, int]:
    """Steps per second of the reference, on episodes from the same reset, holding unless a taker
    is within 2 king moves and then passing to a random teammate (plain Python decisions), with the
    kick noise of ``params`` drawn per iteration like the evaluator's."""
    import jax
    import numpy as np

    from kx.sim import env
    from kx.sim import reference as ref

    starts = env.as_numpy(env.reset_batch(jax.random.key(seed), 256, params, config))
    rng = np.random.default_rng(seed)
    s_max = int(env.noise_limit(params.kick_noise_deg))
    steps, t0, i = 0, time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        s = ref.RefState.from_arrays({k: v[..., i % 256] for k, v in starts.items()})
        i += 1
        while not s.done:
            a = s.holder
            if s.holder >= 0 and min(ref.cheb(s.keepers[s.holder], t) for t in s.takers) <= 2:
                a = int(rng.integers(0, config.n_keepers))
            noise = int(rng.integers(-s_max, s_max + 1)) if s_max else 0
            s = ref.step(s, a, noise, config, int(params.max_iterations), int(params.taker_reaction_delay),
                         int(params.tackle_iterations))
            steps += 1
    return steps / (time.perf_counter() - t0), steps


def run(args) -> None:
    import jax

    from kx.sim import env, policies
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; task {config.name}; "
          f"{args.episodes} episodes; max_iterations {params.max_iterations}, tackle_iterations "
          f"{params.tackle_iterations}, kick noise {params.kick_noise_deg} degrees")
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

    # The step alone: 400 lockstep iterations of 4096 lanes with no narrowing (finished lanes are
    # stepped too), so that the per-call costs of the evaluator's ladder do not count.
    import numpy as np

    from kx.sim import evaluate as ev
    lanes = jax.tree.map(lambda a: a[..., :4096], starts)
    n_lanes = int(lanes.done.shape[-1])  # 4096, or every episode when there are fewer
    lock = lambda: ev.lockstep(policies.heuristic(config), None, lanes, params, config,  # noqa: E731
                               key=jax.random.key(1), iterations=400)
    np.asarray(lock()[1])
    t0 = time.perf_counter()
    np.asarray(lock()[1])
    lock_rate = 400 * n_lanes / (time.perf_counter() - t0)
    print(f"the step alone (heuristic, {n_lanes} lanes in lockstep for 400 iterations, finished lanes included): "
          f"{lock_rate:.0f} lane-steps/s")

    ref_rate, ref_steps = _reference_rate(config, params, args.reference_seconds, args.seed)
    print(f"reference (plain Python, one episode at a time): {ref_steps} steps = {ref_rate:.0f} steps/s")
    print(f"mlp: {nn_rate:.0f} live-steps/s (ratio {nn_rate / ref_rate:.1f} vs reference)")
    print(f"step alone: {lock_rate:.0f} lane-steps/s (ratio {lock_rate / ref_rate:.1f} vs reference)")
    print(f"sim: {heur:.0f} live-steps/s (ratio {heur / ref_rate:.1f} vs reference)")
