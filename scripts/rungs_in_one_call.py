"""The evaluator's rungs in one compiled call against one call per rung, on real populations.

``python scripts/rungs_in_one_call.py``                          (the trained 4v3 fixtures of kx.bench policies)
``python scripts/rungs_in_one_call.py RUN_DIR [RUN_DIR ...]``    (each run directory's last population)

Each population (150 genomes) plays 30 start states with one evaluation key, its lanes split over the
process's devices (one XLA host device per core), twice: with every rung of the evaluation in one call
(:data:`kx.sim.evaluate.RUNGS_IN_ONE_CALL`, the evaluator's way since 2026-12-04) and with one call per rung,
dispatched back to back (the way before). Both must play the same episodes (checked: every statistic of
every lane); the figure is the median of ``--rounds`` evaluations taken in turn. With one call per rung, a
call ends when its slowest device does: where one device's lanes (one half of the population: the lanes
are policy-major) hold the long episodes, the devices wait for each other at every rung. Pause other work
on the machine while it runs. Each case also prints each side's first call, compilation included
(``KX_CACHE_DIR=off`` to compile rather than load from the persistent cache).
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dirs", nargs="*", help="run directories (default: the fixtures of kx.bench policies)")
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args()
    if args.rounds < 1:
        raise SystemExit("--rounds: allowed integers >= 1")

    from kx import runtime

    runtime.setup()
    import jax
    import numpy as np

    from kx.bench import policies as bench_policies
    from kx.bench.common import in_turn
    from kx.evolve import run as run_lib
    from kx.sim import env
    from kx.sim import evaluate as ev

    cases = []
    for run_dir in args.run_dirs:
        trainer, _, state, _ = run_lib.restore(run_dir)
        population = trainer.encoding.ask(jax.random.key(7), state.learner)
        population = population[0] if isinstance(population, tuple) else population
        cases.append((run_dir, trainer, population))
    if not args.run_dirs:
        for method in ("neat", "hyperneat"):
            trainer, population, _ = bench_policies.load_fixture(method)
            cases.append((f"the {method} fixture", trainer, population))

    print(f"{jax.local_device_count()} devices; medians of {args.rounds} rounds in turn", flush=True)
    totals = {True: 0.0, False: 0.0}
    for name, trainer, population in cases:
        enc, world = trainer.encoding, (trainer.exp.sim_params, trainer.exp.sim)
        table = enc.policy_params(population)
        starts = env.reset_batch(jax.random.key(500), 30, *world)
        key = jax.random.key(900)

        def play(one_call):
            ev.RUNGS_IN_ONE_CALL = one_call
            try:
                c = ev.EvalCounters()
                stats = jax.block_until_ready(ev.evaluate(enc.policy, table, starts, *world, key=key, counters=c))
                return stats, c
            finally:
                ev.RUNGS_IN_ONE_CALL = True

        t0 = time.perf_counter()
        a, ca = play(True)  # the first calls compile (or load from the persistent cache: KX_CACHE_DIR=off)
        t1 = time.perf_counter()
        b, cb = play(False)
        first = (t1 - t0, time.perf_counter() - t1)
        for f in a.__dataclass_fields__:
            if not np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f))):
                raise SystemExit(f"{name}: the two ways played different episodes ({f})")
        if (ca.executed_steps, ca.widths) != (cb.executed_steps, cb.widths):
            raise SystemExit(f"{name}: the two ways stepped different lane-steps")
        times = in_turn({True: lambda: play(True), False: lambda: play(False)}, args.rounds)
        med = {k: float(np.median(v)) for k, v in times.items()}
        for k in totals:
            totals[k] += med[k]
        print(f"{name} ({trainer.cfg.method}, {trainer.cfg.task}): {ca.live_steps} live steps; one call "
              f"{med[True]:.3f} s, one call per rung {med[False]:.3f} s: {med[False] / med[True]:.2f}x; first calls "
              f"{first[0]:.1f} and {first[1]:.1f} s", flush=True)
    print(f"rungs_in_one_call: {totals[True]:.2f} s for {len(cases)} evaluations "
          f"(ratio {totals[False] / totals[True]:.2f} vs one_call_per_rung)")


if __name__ == "__main__":
    main()
