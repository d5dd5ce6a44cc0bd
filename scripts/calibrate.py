"""Calibration table of SPEC §1: hand-coded baselines on all four tasks, written to docs/calibration.md.

    python scripts/calibrate.py [--trials 1000] [--out docs/calibration.md]

Every baseline meets the same start states of a task (common random numbers). Besides the defaults it
measures the heuristic under the rules the calibration changed: without kick noise, with the instant
tackle (tackle_iterations=1) and no noise (the first kx rules), and with the takers reacting to a pass
in its own iteration (taker_reaction_delay=0).
"""

from __future__ import annotations

import argparse
import datetime
import pathlib
import time

from kx import runtime

TASKS = ("3v2", "4v3", "5v3", "6v4")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=1000)
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--out", default="docs/calibration.md")
    args = p.parse_args(argv)
    runtime.setup()
    import jax
    import numpy as np

    from kx.sim import env, policies
    from kx.sim import evaluate as ev
    from kx.sim.types import KeepAwayConfig, KeepAwayParams, Reason

    variants = [  # (label suffix, parameter changes, policies)
        ("", {}, ["random", "hold", "heuristic"]),  # random first: every row is also given as x random
        (", no kick noise", dict(kick_noise_deg=0.0), ["heuristic"]),
        (", first rules (instant tackle, no noise)", dict(kick_noise_deg=0.0, tackle_iterations=1), ["heuristic"]),
        (", takers react at once", dict(taker_reaction_delay=0), ["heuristic"]),
    ]
    rows = []
    t_start = time.time()
    for task in TASKS:
        config = KeepAwayConfig.from_task(task)
        random_mean = None
        for suffix, change, names in variants:
            params = KeepAwayParams(**change)
            starts = env.reset_batch(jax.random.fold_in(jax.random.key(args.seed), TASKS.index(task)),
                                     args.trials, params, config)
            for name in names:
                policy = policies.BASELINES[name](config)
                stats = ev.evaluate(policy, None, starts, params, config, key=jax.random.key(args.seed))
                f = np.asarray(stats.fitness).ravel()
                reasons = np.bincount(np.asarray(stats.reason).ravel(), minlength=len(Reason)) / f.size
                if name == "random" and not change:
                    random_mean = f.mean()
                row = dict(task=task, policy=name + suffix, mean=f.mean(), sd=f.std(ddof=1),
                           median=float(np.median(f)), full=reasons[Reason.TIME_LIMIT],
                           intercepted=reasons[Reason.INTERCEPTED], tackled=reasons[Reason.TACKLED],
                           out=reasons[Reason.OUT_OF_FIELD], passes=float(np.asarray(stats.passes).mean()),
                           x_random=f.mean() / random_mean)
                rows.append(row)
                print(f"{task} {row['policy']:45s} mean {row['mean']:.4f} sd {row['sd']:.4f} "
                      f"median {row['median']:.4f} ({row['median'] / max(row['mean'], 1e-12):.2f} of the mean) "
                      f"at the cap {row['full']:.3f} passes {row['passes']:.1f} x random {row['x_random']:.1f}",
                      flush=True)
    lines = [
        "# Calibration: hand-coded baselines",
        "",
        f"Produced by `python scripts/calibrate.py --trials {args.trials} --seed {args.seed}` "
        f"({datetime.date.today().isoformat()}, {time.time() - t_start:.0f} s on this machine). "
        "Fitness is the portion of the 4500 iterations the keepers held the ball; every policy of a "
        "task meets the same start states and kick noise. Defaults: `tackle_iterations=3`, "
        "`kick_noise_deg=10`, `taker_reaction_delay=1`. Mean and sample standard deviation over the "
        "trials, the median and its ratio to the mean, the share of trials that ran all 4500 iterations "
        "(at the cap) and that ended each other way, the mean completed passes, and the mean over the "
        "random policy's under the defaults.",
        "",
        "| task | policy | mean (sd) | median | median / mean | at the cap | intercepted | tackled | out "
        "| passes | x random |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['task']} | {r['policy']} | {r['mean']:.4f} ({r['sd']:.4f}) | {r['median']:.4f} | "
                     f"{r['median'] / max(r['mean'], 1e-12):.2f} | {r['full']:.3f} | {r['intercepted']:.3f} | "
                     f"{r['tackled']:.3f} | {r['out']:.3f} | {r['passes']:.1f} | {r['x_random']:.1f} |")
    lines += ["", "See docs/simulator.md, \"Calibration\", for what these numbers decided.", ""]
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
