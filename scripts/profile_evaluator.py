"""Where one evaluation of the batched evaluator goes: its stages and rungs timed one by one.

``python scripts/profile_evaluator.py [--episodes 4500] [--repeats 20]``

4500 episodes of the default 3v2 task played by the heuristic (what ``python -m kx.bench sim`` times),
with one XLA host device per core. Each stage is synchronised before the next starts (each rung its own
call of :func:`kx.sim.evaluate._rungs`), so the sum is a little above what ``kx.bench sim`` measures with
every rung in one call. Prints, as medians
over ``--repeats`` evaluations: preparing the lanes (:func:`kx.sim.evaluate._prepare` and the split
over the devices), every rung's time, iterations and cost per executed lane-step and device; a rung
with nothing to do (every lane finished), with and without its compaction; and the step alone (4096
lanes in lockstep, as in ``kx.bench sim``) compiled with and without
:data:`kx.sim.evaluate.LOOP_COMPILER_OPTIONS`, alternated.

Measured 2026-12-02 (2-core CPU, nothing else running): preparing the lanes 0.62 ms; the rungs 28.8 ms
in all (54.8 ms before the heuristic was vectorised and the lanes packed; 7.6 ms at 4500 lanes, 77 ns
per lane-step and device; 2.4 ms for the last rung's 399 iterations at 64 lanes, 252 ns); a rung with
nothing to do 0.33 ms (0.21 ms without its compaction); the step alone 22-27M lane-steps/s without the
option, 27-30M with it (three alternated pairs over two runs).
"""

from __future__ import annotations

import argparse
import time

from kx import runtime


def _median_ms(fn, repeats: int) -> float:
    import jax
    import numpy as np

    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=4500)
    p.add_argument("--repeats", type=int, default=20)
    args = p.parse_args()
    runtime.setup()
    import jax
    import numpy as np

    from kx.sim import env, lanes, policies
    from kx.sim import evaluate as ev
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    starts = env.reset_batch(jax.random.key(0), args.episodes, params, config)
    policy, n_dev, keys = policies.heuristic(config), jax.local_device_count(), jax.random.key(1)[None]
    ladder = ev.width_ladder(args.episodes, multiple=n_dev)
    chain, layout = ev.rungs(ladder), lanes.lane_layout(starts, False)

    def prepare():
        rows, _ = ev._prepare(starts, None, keys, shared=False, n_groups=1, n_pol=1, n_trials=args.episodes,
                              width=ladder[0])
        return lanes.put_lanes(rows, n_dev)

    scalars = lanes.put_replicated(lanes.pack_scalars(params, args.episodes, keys), n_dev)
    rung = dict(policy=policy, config=config, n_dev=n_dev, layout=layout, n_groups=1, impl="threefry2x32")
    print(f"devices: {n_dev}; {args.episodes} heuristic episodes of 3v2; medians over {args.repeats} evaluations")
    print(f"prepare the lanes: {_median_ms(prepare, args.repeats):.2f} ms")

    per = {w: [] for w in chain}
    for _ in range(args.repeats + 1):
        rows = jax.block_until_ready(prepare())
        for k, w in enumerate(chain):
            nxt = chain[k + 1] if k + 1 < len(chain) else 0
            t0 = time.perf_counter()
            *compacted, _, ran = jax.block_until_ready(ev._rungs(rows, None, scalars, targets=(nxt,), **rung))
            per[w].append((time.perf_counter() - t0, np.asarray(ran)[:, 0, 0]))
            rows = compacted[0] if compacted else None
    total = 0.0
    for w in chain:
        secs = float(np.median([s for s, _ in per[w][1:]]))  # the first pass warms up
        ran = per[w][-1][1]
        executed = int(ran.sum()) * (w // n_dev)
        total += secs
        print(f"rung {w:5d} lanes: {secs * 1e3:6.2f} ms, {int(ran.max()):4d} iterations, {executed:7d} lane-steps, "
              f"{secs / max(executed, 1) * n_dev * 1e9:6.1f} ns per lane-step and device")
    print(f"the rungs in all: {total * 1e3:.1f} ms")

    rows = prepare()
    i_done = [i for i, (_, dtype) in enumerate(layout.leaves) if dtype == "bool"][0]
    done = jax.device_put(rows.at[layout.n_rows(i_done)].set(1), rows.sharding)  # every lane finished
    for w in (chain[1], 0):
        ms = _median_ms(lambda w=w: ev._rungs(done, None, scalars, targets=(w,), **rung), args.repeats * 10)
        print(f"a rung with nothing to do, {'compacting to ' + str(w) if w else 'no compaction'}: {ms:.3f} ms")

    block = jax.tree.map(lambda a: a[..., :4096], starts)
    n = int(block.done.shape[-1])
    ids = np.arange(n, dtype=np.int32)
    plain = jax.jit(ev.advance.__wrapped__, static_argnames=("policy", "config", "n_dev"))
    args_ = (block, None, env.noise_words(keys[0], ids), ids, keys, np.int32(n), params, np.int32(400), np.int32(-1))
    for name, fn in [("default", plain), ("LOOP_COMPILER_OPTIONS", ev.advance)] * 2:
        ms = _median_ms(lambda fn=fn: fn(*args_, policy=policy, config=config, n_dev=n_dev)[1], 5)
        print(f"the step alone, {n} lanes x 400 iterations, compiled with {name}: {400 * n / ms / 1e3:.1f}M "
              f"lane-steps/s")


if __name__ == "__main__":
    main()
