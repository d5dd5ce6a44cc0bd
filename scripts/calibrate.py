"""Calibration table of SPEC §1: hand-coded baselines on all four tasks, written to docs/calibration.md.

    python scripts/calibrate.py [--trials 1000] [--out docs/calibration.md]

Every baseline meets the same start states of a task (common random numbers). Also measures the
heuristic with the takers reacting to a pass in its own iteration (taker_reaction_delay=0), the rule
the calibration changed.
"""

from __future__ import annotations

import argparse
import datetime
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from kx import runtime  # noqa: E402

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

    rows = []
    t_start = time.time()
    for task in TASKS:
        config = KeepAwayConfig.from_task(task)
        for delay in (1, 0):
            params = KeepAwayParams(taker_reaction_delay=delay)
            starts = env.reset_batch(jax.random.fold_in(jax.random.key(args.seed), TASKS.index(task)),
                                     args.trials, params, config)
            names = ["hold", "random", "heuristic"] if delay == 1 else ["heuristic"]
            for name in names:
                policy = policies.BASELINES[name](config)
                stats = ev.evaluate(policy, None, starts, params, config, key=jax.random.key(args.seed))
                f = np.asarray(stats.fitness).ravel()
                reasons = np.bincount(np.asarray(stats.reason).ravel(), minlength=len(Reason)) / f.size
                row = dict(task=task, policy=name if delay else f"{name}, takers react at once",
                           mean=f.mean(), sd=f.std(ddof=1), median=float(np.median(f)),
                           full=reasons[Reason.TIME_LIMIT], intercepted=reasons[Reason.INTERCEPTED],
                           tackled=reasons[Reason.TACKLED], out=reasons[Reason.OUT_OF_FIELD],
                           passes=float(np.asarray(stats.passes).mean()))
                rows.append(row)
                print(f"{task} {row['policy']:32s} mean {row['mean']:.4f} sd {row['sd']:.4f} "
                      f"median {row['median']:.4f} full {row['full']:.3f} passes {row['passes']:.1f}",
                      flush=True)
    lines = [
        "# Calibration: hand-coded baselines",
        "",
        f"Produced by `python scripts/calibrate.py --trials {args.trials} --seed {args.seed}` "
        f"({datetime.date.today().isoformat()}, {time.time() - t_start:.0f} s on this machine). "
        "Fitness is the portion of the 4500 iterations the keepers held the ball; every policy of a "
        "task meets the same start states. Mean and sample standard deviation over the trials; the "
        "last columns are the share of trials that ended each way and the mean completed passes.",
        "",
        "| task | policy | mean (sd) | median | survived 4500 | intercepted | tackled | out | passes |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['task']} | {r['policy']} | {r['mean']:.4f} ({r['sd']:.4f}) | {r['median']:.4f} | "
                     f"{r['full']:.3f} | {r['intercepted']:.3f} | {r['tackled']:.3f} | {r['out']:.3f} | "
                     f"{r['passes']:.1f} |")
    lines += ["", "See docs/simulator.md, \"Calibration\", for what these numbers decided.", ""]
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
