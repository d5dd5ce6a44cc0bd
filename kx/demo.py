"""The main job until training lands: the simulator at work.

``python -m kx.demo [--task 3v2] [--trials 300] [--out checkpoints/demo]`` evaluates the hand-coded
baselines on shared start states with the batched evaluator, prints their fitness, and writes an
animated GIF of one heuristic episode and a CSV of the per-trial results into the output folder.
"""

from __future__ import annotations

import argparse
import csv
import pathlib
import time

from kx import runtime


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="3v2")
    p.add_argument("--trials", type=int, default=300)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="checkpoints/demo")
    args = p.parse_args(argv)
    runtime.setup()
    import jax
    import numpy as np

    from kx.sim import env, policies
    from kx.sim import evaluate as ev
    from kx.sim.render import render_policy
    from kx.sim.types import KeepAwayConfig, KeepAwayParams, Reason

    config, params = KeepAwayConfig.from_task(args.task), KeepAwayParams()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    starts = env.reset_batch(jax.random.key(args.seed), args.trials, params, config)
    print(f"kx demo: {config.name}, {args.trials} shared start states, {jax.local_device_count()} device(s)")
    rows = []
    for name, make in policies.BASELINES.items():
        t0 = time.time()
        c = ev.EvalCounters()
        stats = ev.evaluate(make(config), None, starts, params, config, key=jax.random.key(args.seed + 1),
                            counters=c)
        f = np.asarray(stats.fitness).ravel()
        print(f"  {name:10s} fitness mean {f.mean():.4f} sd {f.std():.4f} max {f.max():.4f}  "
              f"survived {np.mean(np.asarray(stats.reason) == Reason.TIME_LIMIT):.2f}  "
              f"({c.live_steps} live steps, {time.time() - t0:.1f} s incl. compile)", flush=True)
        for i in range(f.size):
            rows.append(dict(policy=name, trial=i, fitness=float(f[i]),
                             iterations=int(np.asarray(stats.iterations).ravel()[i]),
                             reason=Reason(int(np.asarray(stats.reason).ravel()[i])).name,
                             passes=int(np.asarray(stats.passes).ravel()[i])))
    with open(out / "baselines.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    gif = render_policy("heuristic", config, out / f"heuristic_{config.name}.gif", seed=args.seed,
                        max_frames=300)
    print(f"wrote {out / 'baselines.csv'} and {gif}")


if __name__ == "__main__":
    main()
