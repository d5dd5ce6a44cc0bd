"""``python -m kx.bench transfer``: transferred against fresh populations at the start of each target task,
for NEAT and HyperNEAT: the first generation of the Table 3 protocol's target runs
(:mod:`kx.experiments.table3`, measured by :mod:`kx.experiments.measure`)."""

from __future__ import annotations

import time

from kx.bench.common import LEARNING_TEST_SEED, sd

#: the target arms, per objective: the Table 3 setups seeded with the source's population, and fresh
ARMS = {"fitness": {"transfer": "fitness", "fresh": "none"},
        "hybrid": {"transfer": "hybrid", "fresh": "none_hybrid"}}


def run(args) -> None:
    """Transferred against fresh populations at the start of each target task, for NEAT and HyperNEAT.

    The runs are the Table 3 protocol's (:func:`kx.experiments.table3.config`, protocol seed 0, no
    overrides): for each run index 0..``--seeds``-1, the method's source run in 3v2 (its shipped config:
    150 genomes, 20 generations of 30 trials, ``--objective``; the same source the protocol trains)
    trains in a temporary run directory; then in each target task (4v3, 5v3, 6v4) the protocol's two
    target runs of that index play their first generation: one seeded with the source's whole final
    population (setup ``fitness``, or ``hybrid`` with ``--objective hybrid``), one fresh (``none``,
    ``none_hybrid``). Each run has the protocol's seed of its own (:func:`kx.experiments.table3.run_seed`),
    so the two arms train on different start states. Each first-generation champion (the fittest on the
    generation's 30 training trials, the run's validated champion after one generation) plays the same
    ``--test-trials`` held-out test states of the target task (the test stream of seed 2026), and so does
    the population's mean training fitness. Same test states, same evaluation budget, same stopping point
    for both arms."""
    import tempfile

    import numpy as np

    from kx.evolve import run as run_lib
    from kx.evolve import streams
    from kx.experiments import measure, table3

    if args.objective not in ARMS:
        raise SystemExit(f"--objective: allowed {' or '.join(ARMS)}, got {args.objective!r}")
    arms = ARMS[args.objective]
    runs = list(range(args.seeds))
    methods = {"NEAT": "neat", "HyperNEAT": "hyperneat"}
    tasks = table3.TARGETS
    protocol = table3.Protocol(seed=0, test_trials=args.test_trials, source_generations=20, target_generations=1)
    keys = streams.test(LEARNING_TEST_SEED)
    print(f"transfer: sources 3v2 (20 generations, 150 x 30, objective {args.objective}), the Table 3 protocol's "
          f"runs {runs[0]}..{runs[-1]} (protocol seed 0); first-generation champions of its transferred and fresh "
          f"target runs on {args.test_trials} test states of each target", flush=True)
    res = {(m, t, arm): [] for m in methods for t in tasks for arm in arms}
    mean_first = {k: [] for k in res}
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="kx-bench-transfer-") as tmp:
        for name, method in methods.items():
            for i in runs:
                source = table3.RunSpec(method, args.objective, "source", table3.SOURCE_TASK, i)
                t0 = time.perf_counter()
                row = run_lib.train(table3.config(protocol, source, tmp), table3.run_dir(tmp, source),
                                    log=lambda s: None)
                print(f"{name} run {i}: source 3v2 best validation {row['best_validation']:.4f} "
                      f"({time.perf_counter() - t0:.0f} s)", flush=True)
                for task in tasks:
                    for arm, setup in arms.items():
                        target = table3.RunSpec(method, setup, "target", task, i)
                        first = measure.first_generation(table3.config(protocol, target, tmp), keys, args.test_trials)
                        res[(name, task, arm)].append(first.test)
                        mean_first[(name, task, arm)].append(first.mean_fitness)
                print(f"{name} run {i}: " + "; ".join(
                    f"{t} transferred {res[(name, t, 'transfer')][-1]:.4f} fresh {res[(name, t, 'fresh')][-1]:.4f}"
                    for t in tasks), flush=True)
    print("first-generation champion on the target's test states, mean (sd) over runs; the population's mean "
          "training fitness in that generation:")
    ratios = []
    for name in methods:
        for task in tasks:
            a, b = np.array(res[(name, task, "transfer")]), np.array(res[(name, task, "fresh")])
            ma, mb = np.mean(mean_first[(name, task, "transfer")]), np.mean(mean_first[(name, task, "fresh")])
            wins = int(np.sum(a > b))
            print(f"  {name} {task}: transferred {a.mean():.4f} ({sd(a):.4f}), fresh {b.mean():.4f} ({sd(b):.4f}), "
                  f"ratio {a.mean() / max(b.mean(), 1e-9):.2f}, transferred better in {wins}/{a.size} runs; "
                  f"population mean {ma:.4f} vs {mb:.4f}")
            ratios.append((a.mean(), b.mean()))
    print(f"{time.perf_counter() - t_all:.0f} s in all (compilation included)")
    ta, fr = np.mean([r[0] for r in ratios]), np.mean([r[1] for r in ratios])
    print(f"transfer: {ta:.4f} fitness (ratio {ta / max(fr, 1e-9):.2f} vs fresh)")
