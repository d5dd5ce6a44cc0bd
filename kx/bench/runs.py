"""``python -m kx.bench runs``: R runs of the default config trained as one batched group
(:mod:`kx.evolve.group`) against the same R runs one after another, in one process.

Both sides run in memory (no run directories), every generation through the same code as ``kx.train``
and ``kx.train --seeds``. The runs one after another are the same seeds 0..R-1 as the groups, each
timed alone; the figure for R is the sum of seeds 0..R-1's times. Compilation is measured apart in the
same pass (JAX's tracing, lowering and backend-compile events), and each program is compiled once in
the process: the warm figure is the wall time less the compilation that happened inside it. Each
group's runs are checked against the same seeds alone (every metrics row but the execution figures).
Before the timed runs, each side runs untimed once on other seeds (a run alone for 3 generations; a
group of R for one generation), so that neither side's figure carries the process's first-call costs
(loading programs from the persistent cache, first dispatches); their compilation counts in the
compilation figure of their side. The last line is the ratio at the largest R.
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


def run(args) -> None:
    import jax

    from kx.evolve import config as cfg_lib
    from kx.evolve import outputs
    from kx.evolve import run as run_lib
    from kx.evolve import trainer as trainer_lib

    sizes = sorted({int(r) for r in args.group_sizes.split(",")})
    clock = _CompileClock()
    cfg0 = cfg_lib.load(args.config, [f"generations={args.generations}", "gif=false"])
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; config "
          f"{args.config or 'configs/neat_3v2.py'}: {cfg0.task} {cfg0.method}, population {cfg0.population_size}, "
          f"{cfg0.trials} trials, {args.generations} generations; R = {sizes}", flush=True)
    cfgs = [cfg_lib.load(args.config, [f"generations={args.generations}", "gif=false", f"seed={s}"])
            for s in range(max(sizes))]
    strip = lambda row: {k: v for k, v in row.items() if k not in outputs.EXECUTION_FIELDS}  # noqa: E731

    warm_seed = 10_000  # seeds of the untimed warm-up runs, outside the timed ones

    def other(seed, generations):
        return cfg_lib.load(args.config, [f"generations={generations}", "gif=false", f"seed={seed}"])

    # the runs one after another: each seed alone, timed, after an untimed warm-up run
    compiled0 = clock.seconds
    run_lib.evolve_in_memory(run_lib.Trainer(other(warm_seed, 3)))
    warm_compile_alone = clock.seconds - compiled0
    alone, alone_rows = [], []
    for c in cfgs:
        compiled0, t0 = clock.seconds, time.perf_counter()
        _, rows = run_lib.evolve_in_memory(run_lib.Trainer(c))
        wall = time.perf_counter() - t0
        alone.append((wall, clock.seconds - compiled0))
        alone_rows.append([strip(r) for r in rows])
        print(f"  seed {c.seed} alone: {wall:.1f} s ({alone[-1][1]:.1f} s compiling); validated champion "
              f"{rows[-1]['best_validation']:.4f}", flush=True)
    results = []
    for r in sizes:
        compiled0 = clock.seconds
        warm_group = trainer_lib.RunGroup.from_configs([other(warm_seed + 1 + i, 1) for i in range(r)])
        warm_group.step(warm_group.init())
        warm_compile = clock.seconds - compiled0
        compiled0, t0 = clock.seconds, time.perf_counter()
        group = trainer_lib.RunGroup.from_configs(cfgs[:r])
        state, rows = group.init(), []
        for _ in range(args.generations):
            state, got = group.step(state)
            rows.append(got)
        jax.block_until_ready(state)
        wall = time.perf_counter() - t0
        compiling = clock.seconds - compiled0
        warm_b = wall - compiling
        wall, compiling = wall + warm_compile, compiling + warm_compile  # with the warm-up's compilation
        same = all(strip(rows[g][i]) == alone_rows[i][g] for i in range(r) for g in range(args.generations))
        # with the warm-up's compilation, as on the batched side
        one_wall = sum(w for w, _ in alone[:r]) + warm_compile_alone
        one_compile = sum(c for _, c in alone[:r]) + warm_compile_alone
        warm_1 = one_wall - one_compile
        ratio = warm_1 / warm_b
        results.append((r, ratio, warm_b))
        print(f"R = {r:3d}: batched {wall:.1f} s ({compiling:.1f} s compiling, {warm_b:.1f} s warm) = "
              f"{3600 * r / warm_b:.0f} runs/h warm, {3600 * r / wall:.0f} with compilation; one after another "
              f"{one_wall:.1f} s ({one_compile:.1f} s compiling, {warm_1:.1f} s warm) = {3600 * r / warm_1:.0f} "
              f"runs/h warm, {3600 * r / one_wall:.0f} with compilation; ratio {ratio:.2f} warm, "
              f"{one_wall / wall:.2f} with compilation; every run's rows identical to its seed alone: {same}",
              flush=True)
        if not same:
            raise SystemExit(f"runs: the batched group of {r} computed other rows than its runs alone")
    r, ratio, warm_b = results[-1]
    print(f"runs: {3600 * r / warm_b:.0f} runs/h at R = {r} (ratio {ratio:.2f} vs one_by_one)")
