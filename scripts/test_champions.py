"""Validated champions of a training config over several seeds, on test states: how a reading of the NEAT
parameters (or any other config change) is judged.

Each seed runs the config's generations in memory (no run directory); its validated champion (the
per-generation champion with the best validation score, as ``python -m kx.train`` keeps it) then plays
``--test-trials`` states of the test stream of seed 2026 (the states of ``python -m kx.bench learning``,
never trained or validated on). Prints one line per seed and the mean.

    python scripts/test_champions.py --seeds 0 1 2 3 4 5 6 7 8 9
    python scripts/test_champions.py --config configs/neat_3v2_literal.py
    python scripts/test_champions.py --set neat.initial_link_fraction=1.0
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from kx import runtime


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default=None, help="config file (default configs/neat_3v2.py)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="a config override")
    p.add_argument("--seeds", type=int, nargs="+", default=list(range(10)))
    p.add_argument("--test-trials", type=int, default=1000)
    args = p.parse_args(argv)
    runtime.setup()
    from kx.bench.common import LEARNING_TEST_SEED
    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib
    from kx.evolve import streams
    from kx.evolve.encoding import stack
    from kx.sim import env

    keys = streams.test(LEARNING_TEST_SEED)
    results = []
    for seed in args.seeds:
        t0 = time.perf_counter()
        cfg = cfg_lib.load(args.config, [*args.set, "gif=false", f"seed={seed}"])
        trainer = run_lib.Trainer(cfg)
        state, rows = run_lib.evolve_in_memory(trainer)
        curve = [r["best_validation"] for r in rows]
        starts = env.reset_batch(keys.starts, args.test_trials, trainer.exp.sim_params, trainer.exp.sim)
        f = float(trainer.evaluate(stack([state.champion]), starts, keys.eval).fitness.mean())
        results.append(f)
        print(f"seed {seed}: test {f:.4f}, validated champion of generation {int(state.champion_generation) + 1} "
              f"({float(state.champion_validation):.4f} on validation); validated curve every 5 generations "
              f"{' '.join(f'{c:.3f}' for c in curve[4::5])} ({time.perf_counter() - t0:.0f} s)", flush=True)
    r = np.array(results)
    print(f"config {args.config or 'configs/neat_3v2.py'} {' '.join(args.set)}: mean test {r.mean():.4f} "
          f"(sd {r.std(ddof=1) if r.size > 1 else 0.0:.4f}) over seeds {args.seeds}; per seed "
          + " ".join(f"{x:.3f}" for x in r))


if __name__ == "__main__":
    main()
