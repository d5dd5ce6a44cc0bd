"""The spread of the behaviour vector's three dimensions over a real population, before and after the
rule-derived bounds (kx.sim.env.behaviour_bounds); the table of docs/simulator.md, "Behaviour".

    python scripts/behaviour_spread.py [--tasks 3v2 4v3] [--generations 3] [--seed 0]

Per task: a NEAT population (configs/neat_<task>.py, 150 genomes) trained ``--generations``
generations in memory, then generation ``--generations``'s population (the one the run would evaluate
next) on that generation's 30 training start states and evaluation key, as the trainer does; each
genome's behaviour is its mean over the 30 trials (``stats.behaviour.mean(axis=2)``). The hand-coded
baselines (kx.sim.policies.BASELINES) play the same 30 trials. "old" is the first kx normalisation:
completed passes / max_iterations, mean pairwise keeper distance / the diagonal, ball distance from the
centre / half the diagonal (unchanged); it is computed from the same episodes. The nearest-neighbour
columns are over the population alone (no archive): how many distinct behaviour vectors it has (genomes
that play alike on the shared trials have equal vectors), the median distance from a distinct vector to
the nearest other, the median novelty (mean distance to the k = 15 nearest genomes) and the share of
genomes whose novelty exceeds the archive threshold 0.03.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

from kx import runtime

DIMS = ("passes", "dispersion", "ball centre")
K_NN, THRESHOLD = 15, 0.03


def _old_from_new(beh, passes, max_iterations, config, env):
    """``[3, ...]`` the first kx normalisation of episodes whose new behaviour is ``beh``."""
    import numpy as np

    _, disp_bound, _ = env.behaviour_bounds(config)
    diag = (config.field_size - 1) * math.sqrt(2.0)
    return np.stack([passes / max_iterations, np.minimum(beh[1] * disp_bound / diag, 1.0), beh[2]])


def _nn(b):
    """Of ``b [3, P]``: (distinct vectors, median nearest-neighbour distance among the distinct ones,
    median k-NN novelty, share of novelty > threshold)."""
    import numpy as np

    def sorted_distances(x):
        d = np.sqrt(((x[:, None] - x[None]) ** 2).sum(-1))
        np.fill_diagonal(d, np.inf)
        return np.sort(d, axis=1)

    x = b.T.astype(np.float64)
    distinct = np.unique(np.round(x, 6), axis=0)
    nn = float(np.median(sorted_distances(distinct)[:, 0])) if len(distinct) > 1 else 0.0
    nov = sorted_distances(x)[:, :K_NN].mean(axis=1)
    return len(distinct), nn, float(np.median(nov)), float((nov > THRESHOLD).mean())


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=["3v2", "4v3"])
    p.add_argument("--generations", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    runtime.setup()
    import numpy as np

    from kx.evolve import config as cfg_lib
    from kx.evolve import run, streams
    from kx.sim import env
    from kx.sim import evaluate as ev
    from kx.sim.policies import BASELINES

    spread_rows, nn_rows = [], []
    t0 = time.time()
    for task in args.tasks:
        path = pathlib.Path(__file__).resolve().parents[1] / "configs" / f"neat_{task}.py"
        cfg = cfg_lib.load(path, [f"generations={args.generations}", "gif=false", f"seed={args.seed}"])
        trainer = run.Trainer(cfg)
        state, _ = run.evolve_in_memory(trainer)
        g = args.generations
        population, _ = trainer.encoding.ask(streams.learner_ask(cfg.seed, g), state.learner)
        keys = streams.training(cfg.seed, g)
        sim, params = trainer.exp.sim, trainer.exp.sim_params
        starts = env.reset_batch(keys.starts, cfg.trials, params, sim)
        max_it = float(np.asarray(params.max_iterations))

        def both(stats):
            new = np.asarray(stats.behaviour)
            old = _old_from_new(new, np.asarray(stats.passes, np.float64), max_it, sim, env)
            return {"old": old.mean(axis=-1), "new": new.mean(axis=-1)}

        pop = both(trainer.evaluate(population, starts, keys.eval))  # [3, P]
        base = {name: both(ev.evaluate(make(sim), None, starts, params, sim, key=keys.eval))
                for name, make in BASELINES.items()}  # [3, 1]
        for which in ("old", "new"):
            b = pop[which]
            for i, dim in enumerate(DIMS):
                v = b[i]
                q = np.percentile(v, [5, 50, 95])
                spread_rows.append([task, which, dim, v.min(), *q, v.max(), v.std(ddof=1)]
                                   + [base[n][which][i, 0] for n in ("random", "hold", "heuristic")])
            nn_rows.append([task, which, *_nn(b)])
        print(f"{task}: {time.time() - t0:.0f} s", file=sys.stderr)

    print("| task | bounds | dimension | min | p5 | p50 | p95 | max | sd | random | hold | heuristic |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in spread_rows:
        print("| " + " | ".join(r[:3]) + " | " + " | ".join(f"{x:.4f}" for x in r[3:]) + " |")
    print()
    print(f"| task | bounds | distinct vectors | nearest distinct neighbour (median) | novelty, k = {K_NN} (median) "
          f"| novelty > {THRESHOLD} |")
    print("|---|---|---|---|---|---|")
    for r in nn_rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.4f} | {r[4]:.4f} | {r[5]:.2f} |")
    print(f"\n{time.time() - t0:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
