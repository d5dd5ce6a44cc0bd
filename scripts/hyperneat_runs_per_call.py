"""HyperNEAT on a CPU: R runs' episodes in one evaluator call against one call per run.

``python scripts/hyperneat_runs_per_call.py --runs 4``                       (the trained 4v3 fixture)
``python scripts/hyperneat_runs_per_call.py --runs 4 --run-dir RUN_DIR``     (a run's last population)

The population (the trained 4v3 fixture of ``python -m kx.bench policies``, or the population a HyperNEAT
run directory's last checkpoint evaluates next) is replicated over R runs, each with its own 30 start
states and evaluation key; its substrate table is built once and copied R times, as a batched group's
shared table holds R runs' substrates. One side plays all R runs in one evaluator call (R x 150 tables),
the other one call per run; both play the same episodes (checked), and the figure is the median of 4
rounds taken in turn. What it decides: :data:`kx.evolve.trainer.CPU_TABLE_BYTES`, how many runs a group
plays per call on a CPU. Pause other work on the machine while it runs.
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=4, help="R, the runs played together (default 4)")
    p.add_argument("--run-dir", default=None, help="a HyperNEAT run directory: its last checkpoint's population")
    p.add_argument("--rounds", type=int, default=4)
    args = p.parse_args()
    if args.runs < 1 or args.rounds < 1:
        raise SystemExit("--runs and --rounds: allowed integers >= 1")

    from kx import runtime

    runtime.setup()
    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.bench import policies as bench_policies
    from kx.evolve import run as run_lib
    from kx.sim import env
    from kx.sim import evaluate as ev

    r_n, trials = args.runs, 30
    if args.run_dir:
        trainer, _, state, _ = run_lib.restore(args.run_dir)
        population = trainer.encoding.ask(jax.random.key(7), state.learner)
        population = population[0] if isinstance(population, tuple) else population
        what = f"the population of {args.run_dir} after {int(state.generation)} generations"
    else:
        trainer, population, _ = bench_policies.load_fixture("hyperneat")
        what = "the trained 4v3 fixture of kx.bench policies"
    if trainer.cfg.method != "hyperneat":
        raise SystemExit(f"--run-dir: a HyperNEAT run, got method {trainer.cfg.method!r}")
    enc, world = trainer.encoding, (trainer.exp.sim_params, trainer.exp.sim)
    n_pol = int(jax.tree.leaves(population)[0].shape[0])
    table = jax.tree.map(lambda a: jnp.concatenate([a] * r_n), enc.policy_params(population))
    starts = jax.tree.map(lambda *a: jnp.concatenate(a, axis=-1),
                          *[env.reset_batch(jax.random.key(500 + r), trials, *world) for r in range(r_n)])
    keys = jnp.stack([jax.random.key(900 + r) for r in range(r_n)])

    def one_call():
        c = ev.EvalCounters()
        stats = ev.evaluate(enc.policy, table, starts, *world, key=keys, counters=c)
        return jax.block_until_ready(stats.fitness), c.live_steps

    def per_run():
        out, live = [], 0
        for r in range(r_n):
            c = ev.EvalCounters()
            part = jax.tree.map(lambda a: a[r * n_pol:(r + 1) * n_pol], table)
            s = jax.tree.map(lambda a: a[..., r * trials:(r + 1) * trials], starts)
            out.append(jax.block_until_ready(ev.evaluate(enc.policy, part, s, *world, key=keys[r:r + 1],
                                                         counters=c).fitness))
            live += c.live_steps
        return jnp.concatenate(out), live

    (a, live), (b, _) = one_call(), per_run()  # compiles every width of both
    if not np.array_equal(np.asarray(a), np.asarray(b)):
        raise SystemExit("the two sides played different episodes")
    print(f"{what}; R = {r_n} runs of {n_pol} x {trials} lanes: {live} live steps, mean fitness "
          f"{float(a.mean()):.4f}", flush=True)
    times = {"one call": [], "one call per run": []}
    for i in range(args.rounds):
        for name, fn in (("one call", one_call), ("one call per run", per_run)):
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
        print(f"round {i}: " + ", ".join(f"{k} {v[-1]:.2f} s" for k, v in times.items()), flush=True)
    med = {k: float(np.median(v)) for k, v in times.items()}
    print(f"R = {r_n}: one call {med['one call']:.2f} s, one call per run {med['one call per run']:.2f} s: "
          f"one call {med['one call per run'] / med['one call']:.2f}x as fast")


if __name__ == "__main__":
    main()
