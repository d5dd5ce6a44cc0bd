"""``python -m kx.bench sim``: live episode-steps per second of the batched evaluator (heuristic and a small
neural policy on 4500 episodes of 3v2) and of the step alone, against the plain-Python reference on the
same rules.

One evaluation of 4500 short episodes is about 30 ms of work, too little to time once on a shared
machine (the same code measured 4.1M and 6.4M live-steps/s minutes apart). Each figure is therefore
the median of ``--repeats`` samples, each sample repeating the work for at least ``--sample-seconds``,
with the spread (lowest and highest sample) beside it. The reference is sampled the same way, its
samples taken in turn with the evaluator's (one of each, then the next pair): on this shared machine
its median moved from 7,900 to 11,800 steps/s between runs minutes apart, and a ratio of two figures
taken minutes apart would carry that drift."""

from __future__ import annotations

import time


def _samples(work, repeats: int, seconds: float) -> list[tuple[float, int, int]]:
    """``repeats`` samples of ``work()`` (which returns ``(live steps, executed steps)``), each repeating
    it for at least ``seconds``: ``(seconds, live steps, executed steps)`` per sample."""
    out = []
    for _ in range(repeats):
        live = executed = 0
        t0 = time.perf_counter()
        while True:
            a, b = work()
            live, executed = live + a, executed + b
            dt = time.perf_counter() - t0
            if dt >= seconds:
                break
        out.append((dt, live, executed))
    return out


def _summary(samples) -> tuple[float, float, float]:
    """Median, lowest and highest rate (live steps per second) of ``samples``."""
    import numpy as np

    rates = [live / dt for dt, live, _ in samples]
    return float(np.median(rates)), min(rates), max(rates)


def _interleaved(works, repeats: int, seconds) -> list[list[tuple[float, int, int]]]:
    """:func:`_samples` of several works taken in turn (one sample of each, ``repeats`` times), so that
    the machine's drift falls on all of them alike: ``seconds[i]`` per sample of ``works[i]``."""
    out = [[] for _ in works]
    for _ in range(repeats):
        for i, work in enumerate(works):
            out[i] += _samples(work, 1, seconds[i])
    return out


def _eval_work(policy, policy_params, starts, params, config):
    """The evaluator's work (compiled here) for :func:`_samples`, the counters and the statistics of
    its first evaluation."""
    import jax

    from kx.sim import evaluate as ev

    key = jax.random.key(1)  # the kick noise (on by default)
    first = ev.EvalCounters()
    stats = ev.evaluate(policy, policy_params, starts, params, config, key=key, counters=first)  # compiles

    def work():
        c = ev.EvalCounters()
        jax.block_until_ready(ev.evaluate(policy, policy_params, starts, params, config, counters=c, key=key).fitness)
        return c.live_steps, c.executed_steps

    return work, first, stats


def _reference_work(config, params, seed: int = 0):
    """The reference's work for :func:`_samples`: the reference's steps, on episodes from the same reset, holding
    unless a taker is within 2 king moves and then passing to a random teammate (plain Python
    decisions), with the kick noise of ``params`` drawn per iteration like the evaluator's."""
    import jax
    import numpy as np

    from kx.sim import env
    from kx.sim import reference as ref

    starts = env.as_numpy(env.reset_batch(jax.random.key(seed), 256, params, config))
    rng = np.random.default_rng(seed)
    s_max = int(env.noise_limit(params.kick_noise_deg))
    episode = iter(range(10**9))

    def work():
        i = next(episode)
        s = ref.RefState.from_arrays({k: v[..., i % 256] for k, v in starts.items()})
        steps = 0
        while not s.done:
            a = s.holder
            if s.holder >= 0 and min(ref.cheb(s.keepers[s.holder], t) for t in s.takers) <= 2:
                a = int(rng.integers(0, config.n_keepers))
            noise = int(rng.integers(-s_max, s_max + 1)) if s_max else 0
            s = ref.step(s, a, noise, config, int(params.max_iterations), int(params.taker_reaction_delay),
                         int(params.tackle_iterations))
            steps += 1
        return steps, steps

    return work


def lockstep(policy, lane_params, lanes, params, config, *, key, iterations: int):
    """The step alone: ``iterations`` iterations of every lane of ``lanes`` (``[.., n]``, lane ``i`` trial
    ``i`` of the kick noise of ``key``) in lockstep on every device, finished lanes stepped too (no
    narrowing, no early return), with a per-lane policy's ``lane_params``
    (:func:`kx.sim.evaluate.advance`). Returns the state and, per device, the iterations it ran and its
    live lanes ``[n_dev, 2]``. :func:`run` times it beside :func:`kx.sim.evaluate.evaluate`."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.sim import env
    from kx.sim import evaluate as ev

    ids = jnp.arange(lanes.done.shape[-1], dtype=jnp.int32)
    return ev.advance(lanes, lane_params, env.noise_words(key, ids), ids, key[None], np.int32(ids.shape[0]), params,
                      np.int32(iterations), np.int32(-1), policy=policy, config=config,
                      n_dev=jax.local_device_count())


def _fmt(summary) -> str:
    med, lo, hi = summary
    return f"{med:,.0f}/s (median; samples {lo:,.0f} to {hi:,.0f}, spread {100 * (hi - lo) / med:.0f}%)"


def run(args) -> None:
    import jax

    from kx.sim import env, policies
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; task {config.name}; "
          f"{args.episodes} episodes; max_iterations {params.max_iterations}, tackle_iterations "
          f"{params.tackle_iterations}, kick noise {params.kick_noise_deg} degrees")
    starts = env.reset_batch(jax.random.key(args.seed), args.episodes, params, config)

    reps, sec = args.repeats, args.sample_seconds
    print(f"each figure: the median of {reps} samples of at least {sec} s of work each", flush=True)
    work, c, stats = _eval_work(policies.heuristic(config), None, starts, params, config)
    samples, ref_samples = _interleaved([work, _reference_work(config, params, args.seed)], reps,
                                        [sec, args.reference_seconds / reps])
    heur, ref_rate = _summary(samples), _summary(ref_samples)
    print(f"heuristic: {_fmt(heur)} live episode-steps; one evaluation: {c.live_steps} live steps, executed "
          f"{c.executed_steps} lane-steps ({c.live_steps / c.executed_steps:.2f} live) in {c.chunks} rungs; widths "
          f"{list(c.widths)}; {len(samples) and samples[0][1] // c.live_steps} evaluations per sample; mean fitness "
          f"{float(stats.fitness.mean()):.4f}", flush=True)

    n_pol = 150
    trials = jax.tree.map(lambda a: a[..., : args.episodes // n_pol], starts)
    mlp = policies.mlp_init(jax.random.key(args.seed + 1), n_pol, config)
    work2, c2, stats2 = _eval_work(policies.mlp_policy(config), mlp, trials, params, config)
    nn_rate = _summary(_samples(work2, reps, sec))
    print(f"mlp 13-8-3 ({n_pol} networks x {args.episodes // n_pol} trials): {_fmt(nn_rate)} live episode-steps; "
          f"executed {c2.executed_steps} ({c2.live_steps / max(c2.executed_steps, 1):.2f} live); mean fitness "
          f"{float(stats2.fitness.mean()):.4f}", flush=True)

    # The step alone: 400 lockstep iterations of 4096 lanes with no narrowing (finished lanes are
    # stepped too), so that the per-call costs of the evaluator's ladder do not count.
    import numpy as np

    lanes = jax.tree.map(lambda a: a[..., :4096], starts)
    n_lanes = int(lanes.done.shape[-1])  # 4096, or every episode when there are fewer

    def lock():
        np.asarray(lockstep(policies.heuristic(config), None, lanes, params, config, key=jax.random.key(1),
                            iterations=400)[1])
        return 400 * n_lanes, 400 * n_lanes

    lock()
    lock_rate = _summary(_samples(lock, reps, sec))
    print(f"the step alone (heuristic, {n_lanes} lanes in lockstep for 400 iterations, finished lanes included): "
          f"{_fmt(lock_rate)} lane-steps", flush=True)

    print(f"reference (plain Python, one episode at a time; sampled in turn with the heuristic's evaluator): "
          f"{_fmt(ref_rate)} steps")
    print(f"mlp: {nn_rate[0]:.0f} live-steps/s (ratio {nn_rate[0] / ref_rate[0]:.1f} vs reference)")
    print(f"step alone: {lock_rate[0]:.0f} lane-steps/s (ratio {lock_rate[0] / ref_rate[0]:.1f} vs reference)")
    print(f"sim: {heur[0]:.0f} live-steps/s (ratio {heur[0] / ref_rate[0]:.1f} vs reference)")
