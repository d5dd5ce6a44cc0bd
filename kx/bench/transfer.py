"""``python -m kx.bench transfer``: transferred against fresh populations at the start of each target task,
for NEAT and HyperNEAT (the protocol: :mod:`kx.experiments.measure`)."""

from __future__ import annotations

import time

from kx.bench.common import LEARNING_TEST_SEED, sd


def run(args) -> None:
    """Transferred against fresh populations at the start of each target task, for NEAT and HyperNEAT.

    For each of ``--seeds`` seeds: the method's default 3v2 config (150 genomes, 20 generations of 30
    trials, ``--objective``) trains a source run in a temporary run directory; then in each target task
    (4v3, 5v3, 6v4) two runs of the target config with the same seed play their first generation: one
    seeded with the source's whole final population (``transfer.source``, the default seeding), one
    fresh. Each first-generation champion (the fittest on the generation's 30 training trials, the
    run's validated champion after one generation) plays the same ``--test-trials`` held-out test
    states of the target task (the test stream of seed 2026), and so does the population's mean
    training fitness. Same start states, same evaluation budget, same stopping point for both arms."""
    import pathlib
    import tempfile

    import numpy as np

    from kx.evolve import streams
    from kx.experiments import measure as protocol

    seeds = list(range(args.seeds))
    methods = {"NEAT": "neat", "HyperNEAT": "hyperneat"}
    tasks = protocol.TARGET_TASKS
    keys = streams.test(LEARNING_TEST_SEED)
    print(f"transfer: sources 3v2 (20 generations, 150 x 30, objective {args.objective}), seeds "
          f"{seeds[0]}..{seeds[-1]}; first-generation champions of transferred and fresh target runs on "
          f"{args.test_trials} test states of each target", flush=True)
    res = {(m, t, arm): [] for m in methods for t in tasks for arm in protocol.ARMS}
    mean_first = {k: [] for k in res}
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="kx-bench-transfer-") as tmp:
        for name, method in methods.items():
            for seed in seeds:
                src = pathlib.Path(tmp) / f"{method}-{seed}"
                t0 = time.perf_counter()
                row = protocol.train_source(method, seed, src, args.objective)
                print(f"{name} seed {seed}: source 3v2 best validation {row['best_validation']:.4f} "
                      f"({time.perf_counter() - t0:.0f} s)", flush=True)
                for task in tasks:
                    arms = protocol.seeded_and_fresh(method, task, seed, src, keys, args.test_trials, args.objective)
                    for arm, first in arms.items():
                        res[(name, task, arm)].append(first.test)
                        mean_first[(name, task, arm)].append(first.mean_fitness)
                print(f"{name} seed {seed}: " + "; ".join(
                    f"{t} transferred {res[(name, t, 'transfer')][-1]:.4f} fresh {res[(name, t, 'fresh')][-1]:.4f}"
                    for t in tasks), flush=True)
    print("first-generation champion on the target's test states, mean (sd) over seeds; the population's mean "
          "training fitness in that generation:")
    ratios = []
    for name in methods:
        for task in tasks:
            a, b = np.array(res[(name, task, "transfer")]), np.array(res[(name, task, "fresh")])
            ma, mb = np.mean(mean_first[(name, task, "transfer")]), np.mean(mean_first[(name, task, "fresh")])
            wins = int(np.sum(a > b))
            print(f"  {name} {task}: transferred {a.mean():.4f} ({sd(a):.4f}), fresh {b.mean():.4f} ({sd(b):.4f}), "
                  f"ratio {a.mean() / max(b.mean(), 1e-9):.2f}, transferred better in {wins}/{a.size} seeds; "
                  f"population mean {ma:.4f} vs {mb:.4f}")
            ratios.append((a.mean(), b.mean()))
    print(f"{time.perf_counter() - t_all:.0f} s in all (compilation included)")
    ta, fr = np.mean([r[0] for r in ratios]), np.mean([r[1] for r in ratios])
    print(f"transfer: {ta:.4f} fitness (ratio {ta / max(fr, 1e-9):.2f} vs fresh)")
