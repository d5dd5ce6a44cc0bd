"""``python -m kx.bench runs``: R runs of the default config trained as one batched group
(:mod:`kx.evolve.group`) against the same R runs one after another, in one process.

Both sides run in memory (no run directories), every generation through the same code as ``kx.train``
and ``kx.train --seeds``. The runs one after another are the same seeds 0..R-1 as the group, each timed
alone; the figure for R is the sum of seeds 0..R-1's times. **Rounds in turn:** for each R, a round times
the group and then the same seeds alone, right after it, and ``--rounds`` rounds are taken; the warm ratio
is the median of the rounds' ratios (each the alone side's warm seconds over the group's), so that both
sides of a ratio meet the same minutes of a shared, noisy machine. Compilation is measured apart (JAX's
tracing, lowering and backend-compile events), and each program is compiled once in the process: the warm
figure is the wall time less the compilation that happened inside it. The figure with compilation is the
first round's, each side charged with every program it compiled (the alone side's in its seeds' first
runs). Each group's runs are checked against the same seeds alone (every metrics row but the execution
figures), in every round. Before the timed runs, each side runs untimed once on other seeds (a run alone
for 3 generations; a group of R for one generation), so that neither side's figure carries the process's
first-call costs (loading programs from the persistent cache, first dispatches); their compilation counts
in the compilation figure of their side. The last line is the ratio at the largest R.
"""

from __future__ import annotations

import time


class _CompileClock:
    """Seconds JAX spends compiling (trace, lower, backend compile), summed from its monitoring events."""

    EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
              "/jax/core/compile/backend_compile_duration")

    def __init__(self):
        import jax

        self.seconds = 0.0
        jax.monitoring.register_event_duration_secs_listener(self._on)

    def _on(self, event, duration, **_):
        if event in self.EVENTS:
            self.seconds += duration


def ratio_of_rounds(rounds: list[tuple[float, float]]) -> tuple[float, list[float]]:
    """``rounds``: each round's (the runs alone's warm seconds, the group's warm seconds). The median of the
    rounds' ratios (alone over group) and the ratios in the order taken."""
    import numpy as np

    ratios = [alone / group for alone, group in rounds]
    return float(np.median(ratios)), ratios


def run(args) -> None:
    import jax
    import numpy as np

    from kx.evolve import config as cfg_lib
    from kx.evolve import outputs
    from kx.evolve import run as run_lib
    from kx.evolve import trainer as trainer_lib

    sizes = sorted({int(r) for r in args.group_sizes.split(",")})
    if args.rounds < 1:
        raise SystemExit(f"--rounds: allowed an integer >= 1, got {args.rounds}")
    clock = _CompileClock()
    cfg0 = cfg_lib.load(args.config, [f"generations={args.generations}", "gif=false"])
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; config "
          f"{args.config or 'configs/neat_3v2.py'}: {cfg0.task} {cfg0.method}, population {cfg0.population_size}, "
          f"{cfg0.trials} trials, {args.generations} generations; R = {sizes}; {args.rounds} round(s) in turn "
          "per R (the group, then its seeds alone)", flush=True)
    cfgs = [cfg_lib.load(args.config, [f"generations={args.generations}", "gif=false", f"seed={s}"])
            for s in range(max(sizes))]
    strip = lambda row: {k: v for k, v in row.items() if k not in outputs.EXECUTION_FIELDS}  # noqa: E731

    warm_seed = 10_000  # seeds of the untimed warm-up runs, outside the timed ones

    def other(seed, generations):
        return cfg_lib.load(args.config, [f"generations={generations}", "gif=false", f"seed={seed}"])

    def timed(fn):
        compiled0, t0 = clock.seconds, time.perf_counter()
        out = fn()
        return out, time.perf_counter() - t0, clock.seconds - compiled0

    # the alone side's untimed warm-up run
    _, _, warm_compile_alone = timed(lambda: run_lib.evolve_in_memory(run_lib.Trainer(other(warm_seed, 3))))
    first_compile = {}  # seed -> the compilation in its first run alone

    def alone(c):
        (_, rows), wall, compiling = timed(lambda: run_lib.evolve_in_memory(run_lib.Trainer(c)))
        first_compile.setdefault(c.seed, compiling)
        return [strip(r) for r in rows], wall, compiling

    def grouped(r):
        def go():
            group = trainer_lib.RunGroup.from_configs(cfgs[:r])
            state, rows = group.init(), []
            for _ in range(args.generations):
                state, got = group.step(state)
                rows.append(got)
            jax.block_until_ready(state)
            return rows
        return timed(go)

    results = []
    for r in sizes:
        # the group side's untimed warm-up: a group of R for one generation, on other seeds
        def warm_up():
            warm_group = trainer_lib.RunGroup.from_configs([other(warm_seed + 1 + i, 1) for i in range(r)])
            warm_group.step(warm_group.init())
        _, _, warm_compile = timed(warm_up)
        rounds = []
        for k in range(args.rounds):
            rows, wall_b, compile_b = grouped(r)
            ran = [alone(c) for c in cfgs[:r]]
            same = all(strip(rows[g][i]) == ran[i][0][g] for i in range(r) for g in range(args.generations))
            if not same:
                raise SystemExit(f"runs: the batched group of {r} computed other rows than its runs alone "
                                 f"(round {k + 1})")
            warm_b = wall_b - compile_b
            warm_1 = sum(w - c for _, w, c in ran)
            rounds.append((warm_1, warm_b))
            print(f"  R = {r} round {k + 1}: batched {warm_b:.1f} s warm, one after another {warm_1:.1f} s warm, "
                  f"ratio {warm_1 / warm_b:.2f}", flush=True)
            if k == 0:
                first_wall, first_compiling = wall_b, compile_b
        ratio, ratios = ratio_of_rounds(rounds)
        warm_11, warm_b1 = rounds[0]
        # with compilation (the first round): each side charged with every program it compiled
        wall, compiling = first_wall + warm_compile, first_compiling + warm_compile
        one_compile = sum(first_compile[c.seed] for c in cfgs[:r]) + warm_compile_alone
        one_wall = warm_11 + one_compile
        warm_b = float(np.median([b for _, b in rounds]))
        warm_1 = float(np.median([a for a, _ in rounds]))
        results.append((r, ratio, warm_b))
        print(f"R = {r:3d}: first round: batched {wall:.1f} s ({compiling:.1f} s compiling, {warm_b1:.1f} s warm), "
              f"one after another {one_wall:.1f} s ({one_compile:.1f} s compiling, {warm_11:.1f} s warm), "
              f"{3600 * r / wall:.0f} against {3600 * r / one_wall:.0f} runs/h with compilation, ratio "
              f"{one_wall / wall:.2f}; warm, the median of {len(rounds)} round(s): {3600 * r / warm_b:.0f} against "
              f"{3600 * r / warm_1:.0f} runs/h, ratio {ratio:.2f} (by round {', '.join(f'{x:.2f}' for x in ratios)}); "
              "every run's rows identical to its seed alone: True", flush=True)
    r, ratio, warm_b = results[-1]
    print(f"runs: {3600 * r / warm_b:.0f} runs/h at R = {r} (ratio {ratio:.2f} vs one_by_one)")
