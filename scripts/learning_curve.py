"""Learning curves of a training config over several seeds, as a Markdown table.

For each seed the config runs its generations in memory (no run directory) and records, per
generation, the best and mean training fitness and the run's validated champion so far (its score on
the run's ``validation_trials`` validation states; the ``best_validation`` column of ``metrics.csv``).
The table gives the mean over seeds per generation, with the hand-coded policies on the same validation
states.

    python scripts/learning_curve.py --seeds 0 1 2 3
    python scripts/learning_curve.py --seeds 0 1 2 3 --config configs/neat_3v2_literal.py --out /tmp/c.md
"""

from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np

from kx import runtime


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default=None, help="config file (default configs/neat_3v2.py)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="a config override")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    p.add_argument("--out", default=None, help="write the Markdown table here too")
    args = p.parse_args(argv)
    runtime.setup()

    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib

    keys = ("best_fitness", "mean_fitness", "best_validation")
    curves, bases = [], []
    t0 = time.perf_counter()
    for seed in args.seeds:
        cfg = cfg_lib.load(args.config, [*args.set, f"seed={seed}"])
        trainer = run_lib.Trainer(cfg)
        bases.append(trainer.validation_baselines())
        _, metrics = run_lib.evolve_in_memory(trainer)
        rows = [[r[k] for k in keys] for r in metrics]
        curves.append(rows)
        c = np.asarray(rows)
        print(f"seed {seed}: validated champion {c[0, 2]:.4f} at generation 1, {c[-1, 2]:.4f} at the end; "
              f"best training fitness {c[:, 0].max():.4f}", flush=True)
    c = np.asarray(curves)  # [seeds, generations, 3]
    base = {k: np.mean([b[k] for b in bases]) for k in bases[0]}
    over = " ".join(args.set) or "none"
    lines = [f"Config `{args.config or 'configs/neat_3v2.py'}`, overrides: {over}; seeds {args.seeds}; "
             f"{cfg.validation_trials} validation start states per seed ({time.perf_counter() - t0:.0f} s).",
             "",
             "Hand-coded policies on the same validation states (mean over seeds): "
             + ", ".join(f"{k} {v:.4f}" for k, v in base.items()) + ".",
             "",
             "| generation | best (training trials) | mean (training trials) | validated champion | "
             "validated champion per seed |",
             "|---|---|---|---|---|"]
    for g in range(c.shape[1]):
        per_seed = " ".join(f"{v:.4f}" for v in c[:, g, 2])
        lines.append(f"| {g + 1} | {c[:, g, 0].mean():.4f} | {c[:, g, 1].mean():.4f} | {c[:, g, 2].mean():.4f} | "
                     f"{per_seed} |")
    first, last = c[:, 0, 2].mean(), c[:, -1, 2].mean()
    lines += ["", f"Validated champion: {first:.4f} at generation 1, {last:.4f} at generation {c.shape[1]} "
              f"({last / base['random']:.1f}x the random policy, {last / base['heuristic']:.1f}x the heuristic), "
              "on the validation states it was chosen on (kx.evaluate and kx.bench learning give test figures)."]
    text = "\n".join(lines)
    print(text)
    if args.out:
        pathlib.Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
