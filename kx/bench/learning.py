"""``python -m kx.bench learning``: the validated champions of NEAT, HyperNEAT, CMA-ES and PPO (the same
budget of episodes) over 10 seeds on 1000 test states, and the same 3v2 champions zero-shot on 4v3, 5v3 and 6v4."""

from __future__ import annotations

import time

from kx.bench.common import LEARNING_TEST_SEED, sd


def _train_and_test(config: str | None, seeds, starts, keys, log_name: str, targets=(), overrides=()):
    """Each seed's run of ``config`` through the run loop (no run directory), its validated champion
    played on ``starts`` and, unchanged, on each target task's ``(sim, starts)`` of ``targets``; returns
    the test figures, the validated-champion curves, the seconds and the target figures ``[seed][task]``.
    Each run's trainer is dropped before the next."""
    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib
    from kx.evolve.encoding import stack
    from kx.sim import evaluate as ev

    test, curves, secs, transfer = [], [], [], []
    for seed in seeds:
        t0 = time.perf_counter()
        trainer = run_lib.Trainer(cfg_lib.load(config, ["gif=false", f"seed={seed}", *overrides]))
        state, rows = run_lib.evolve_in_memory(trainer)
        f = float(trainer.evaluate(stack([state.champion]), starts, keys.eval).fitness.mean())
        test.append(f)
        curves.append([r["best_validation"] for r in rows])
        secs.append(time.perf_counter() - t0)
        enc, params = trainer.encoding, trainer.exp.sim_params
        transfer.append([float(ev.evaluate(enc.policy_for(sim), enc.policy_params(stack([state.champion])), t_starts,
                                           params, sim, key=keys.eval).fitness.mean()) for sim, t_starts in targets])
        print(f"{log_name} seed {seed}: test {f:.4f} (validated champion of generation "
              f"{int(state.champion_generation) + 1}, validation {float(state.champion_validation):.4f}; "
              f"{secs[-1]:.0f} s)" + "".join(f"; {sim.name} {v:.4f}" for (sim, _), v in zip(targets, transfer[-1])),
              flush=True)
        del trainer, state, enc
    return test, curves, secs, transfer


def run(args) -> None:
    """The default config of ``python -m kx.train`` (NEAT, 3v2, 150 genomes x 20 generations of 30 shared
    trials) and the default HyperNEAT config (``configs/hyperneat_3v2.py``, the same population and
    budget) over ``--seeds`` seeds, beside the same budget of CMA-ES (``configs/cma_es_3v2.py``: evosax,
    default parameters, population 50, initial step size 1, mean starting at zero, 60 generations of 30
    trials, a linear policy of the 13/3 layout; :mod:`kx.evolve.encodings.cma_es`). All run through the same
    run loop, and each run's champion is its validated champion (the generation champion by training
    fitness that did best on the run's validation states). Every champion and the hand-coded policies
    play the same ``--test-trials`` test states (the test stream of seed 2026, which no run trains or
    validates on) with the same kick noise. Zero-shot transfer: the same 3v2 champions, unchanged, on
    the test states of 4v3, 5v3 and 6v4 (HyperNEAT's substrate and the fixed 13/3 layout fit every
    task), beside the hand-coded policies there. PPO (``configs/ppo_3v2.py``: 20 generations of 4500 training
    episodes, NEAT's 150 x 30 a generation) through the same run loop, its generation champions the
    network's greedy decisions (:mod:`kx.evolve.encodings.ppo`)."""
    import numpy as np

    from kx import runtime
    from kx.evolve import config as cfg_lib
    from kx.evolve import streams
    from kx.sim import env
    from kx.sim import evaluate as ev
    from kx.sim.policies import BASELINES
    from kx.sim.types import KeepAwayConfig

    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    configs = {"NEAT": None, "HyperNEAT": "configs/hyperneat_3v2.py", "CMA-ES": "configs/cma_es_3v2.py",
               "PPO": "configs/ppo_3v2.py", "PPO-2dev": "configs/ppo_3v2.py", "PPO-smdp": "configs/ppo_3v2_smdp.py",
               "PPO-entity": "configs/ppo_entity_3v2.py",
               # the names of the iteration shape before it was PPO's shipped one (older commands in the docs)
               "PPO-iteration": "configs/ppo_3v2_iteration.py", "PPO-iteration-2dev": "configs/ppo_3v2_iteration.py"}
    # a method that is a config with overrides: PPO data-parallel over two devices
    overrides = {"PPO-2dev": ("ppo.devices=2",), "PPO-iteration-2dev": ("ppo.devices=2",)}
    chosen = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not chosen or any(m not in configs for m in chosen):
        raise SystemExit(f"--methods: allowed a comma-separated subset of {tuple(configs)}, got {args.methods!r}")
    configs = {k: v for k, v in configs.items() if k in chosen}
    loaded = {k: cfg_lib.load(v, ["gif=false", *overrides.get(k, ())]) for k, v in configs.items()}
    exp = cfg_lib.validate(next(iter(loaded.values())))
    sim, params = exp.sim, exp.sim_params
    keys = streams.test(LEARNING_TEST_SEED)
    starts = env.reset_batch(keys.starts, args.test_trials, params, sim)
    def budget(c):
        if c.method in ("ppo", "ppo_entity"):
            per = c[c.method].episodes_per_generation
            return (f"{per} training episodes a generation, {c.generations} generations: {per * c.generations:,} "
                    "episodes")
        return (f"population {c.population_size}, {c.generations} generations, {c.trials} trials: "
                f"{c.population_size * c.generations} evaluations, {c.population_size * c.generations * c.trials:,} "
                "episodes")

    print(f"learning: {sim.name}; " + "; ".join(f"{k} ({c.method}, {budget(c)})" for k, c in loaded.items())
        + f"; seeds {seeds[0]}..{seeds[-1]}; validated champions on {args.test_trials} test states", flush=True)
    test = {}
    for name, make in BASELINES.items():
        test[name] = float(ev.evaluate(make(sim), None, starts, params, sim, key=keys.eval).fitness.mean())
    print("hand-coded policies on the test states: " + ", ".join(f"{k} {v:.4f}" for k, v in test.items()))
    targets, target_base = [], {}
    for task in ("4v3", "5v3", "6v4"):
        target = KeepAwayConfig.from_task(task, field_size=sim.field_size, agent_speed=sim.agent_speed,
                                          ball_speed=sim.ball_speed, n_chasers=sim.n_chasers)
        t_starts = env.reset_batch(keys.starts, args.test_trials, params, target)
        targets.append((target, t_starts))
        target_base[task] = {n: float(ev.evaluate(make(target), None, t_starts, params, target,
                                                  key=keys.eval).fitness.mean()) for n, make in BASELINES.items()}
    results = {}
    neat_warm = None
    for name, path in configs.items():
        results[name] = _train_and_test(path, seeds, starts, keys, name, targets, overrides.get(name, ()))
        if name == "NEAT" and any(k.startswith("PPO") for k in configs):
            # NEAT's wall time a run without its compilation, for the PPO ratios: its runs after the first, or,
            # with one seed, its first seed run once more now, while its programs are still compiled
            neat_warm = np.array(results[name][2][1:]) if len(seeds) > 1 else np.array(
                _train_and_test(path, seeds[:1], starts, keys, "NEAT (warm, again)")[2])
            print(f"NEAT: {neat_warm.mean():.1f} s a run warm, {results[name][2][0]:.1f} s its first run "
                  "(compiling)", flush=True)
        # a finished method's compiled programs are released: each holds memory maps of the process, and
        # three methods' would near the kernel's limit (kx.runtime.check_maps)
        before = runtime.memory_maps()
        runtime.release_compiled()
        after = runtime.memory_maps()
        if before and after:
            print(f"{name}: memory maps {before[0]} after its runs (limit {before[1]}), {after[0]} once its compiled "
                  "programs are released", flush=True)
    for name, (_, curves, _, _) in results.items():
        print(f"{name} validated champion per generation, mean over seeds: "
              + " ".join(f"{c:.3f}" for c in np.array(curves).mean(axis=0)))
    for name, (vals, _, secs, _) in results.items():
        v = np.array(vals)
        print(f"{name}: mean {v.mean():.4f} sd {sd(v):.4f} "
              f"({v.mean() / test['heuristic']:.1f}x the heuristic); per seed {' '.join(f'{x:.3f}' for x in v)}; "
              f"{np.sum(secs):.0f} s in all (the first run includes compilation)")
    print("zero-shot: the 3v2 champions unchanged on each target task's test states (the test stream of "
          f"seed {LEARNING_TEST_SEED}, {args.test_trials} states):")
    for i, (target, _) in enumerate(targets):
        base = target_base[target.name]
        parts = []
        for name, (_, _, _, transfer) in results.items():
            v = np.array([t[i] for t in transfer])
            parts.append(f"{name} {v.mean():.4f} sd {sd(v):.4f} "
                         f"({v.mean() / base['heuristic']:.1f}x)")
        print(f"  {target.name}: " + ", ".join(parts) + "; hand-coded " + ", ".join(f"{k} {v:.4f}"
                                                                                  for k, v in base.items()))
    mean = {k: float(np.mean(v[0])) for k, v in results.items()}
    if "HyperNEAT" in mean and "NEAT" in mean:
        hyper, neat = mean["HyperNEAT"], mean["NEAT"]
        print(f"HyperNEAT: {hyper:.4f} fitness ({hyper / test['heuristic']:.1f}x the heuristic, "
              f"{hyper / neat:.2f}x NEAT)")
    for name in (k for k in mean if k.startswith("PPO")):
        if neat_warm is not None:
            print(f"{name}: {mean[name]:.4f} fitness ({mean[name] / test['heuristic']:.1f}x the heuristic, "
                  f"{mean[name] / mean['NEAT']:.2f}x NEAT)")
            # wall time a run, the first (compiling) run left out where there are others
            own = np.array(results[name][2][1:] or results[name][2])
            print(f"{name} wall time: {own.mean():.0f} s a run (ratio {own.mean() / neat_warm.mean():.1f} vs NEAT's "
                  f"warm run, {neat_warm.mean():.1f} s in this process; {name}'s first run, which compiles, left out "
                  "where there are others)")
    if "NEAT" in mean and "CMA-ES" in mean:
        print(f"learning: {mean['NEAT']:.4f} fitness (ratio {mean['NEAT'] / mean['CMA-ES']:.2f} vs cma_es)")
