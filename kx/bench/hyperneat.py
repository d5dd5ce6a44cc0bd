"""``python -m kx.bench hyperneat``: seconds per generation of HyperNEAT and of NEAT (3v2, 150 x 30) on the
same start states in one run, split into building the policies, evaluation, evolution and validation;
the cost per live step of the three policies (the heuristic, NEAT's, HyperNEAT's) in the evaluator, and
where it goes: the world's step, the observation and the network, each timed alone on the lanes of a
generation."""

from __future__ import annotations

import time


def _timed_generations(cfg, generations: int, log_name: str):
    """``generations`` generations of ``cfg`` through the run loop, each split into building the
    policies' parameters (NEAT: the networks; HyperNEAT: the substrates), playing the trials, evolution
    (``tell``) and the champion's validation. Returns one dict per generation."""
    import jax

    from kx.evolve import outputs
    from kx.evolve import run as run_lib

    trainer = run_lib.Trainer(cfg)
    enc = trainer.encoding
    build, built = enc.policy_params, []

    def timed_build(population):  # the loop calls it once per evaluation: the generation's, then validation's
        t0 = time.perf_counter()
        out = jax.block_until_ready(build(population))
        built.append(time.perf_counter() - t0)
        return out

    enc.policy_params = timed_build
    state, rows = trainer.init(), []
    for _ in range(generations):
        built.clear()
        res = trainer.step(state)
        state, row = res.state, res.row
        row = dict(row, build_seconds=built[0], play_seconds=row["eval_seconds"] - built[0])
        rows.append(row)
        print(f"{log_name} " + outputs.progress_line(row, generations, None, enc)
              + f"  build {row['build_seconds']:.3f} s  play {row['play_seconds']:.3f} s  live steps "
              f"{row['live_steps']}", flush=True)
    return trainer, rows


def run(args) -> None:
    """Seconds per generation of HyperNEAT (``configs/hyperneat_3v2.py``) and of NEAT (the default config)
    in one run, on the same 3v2 start states (the training stream of ``--seed``: each generation's 30
    states are the same for both) and the same population (150 x 30), through the run loop, split into
    building the policies (HyperNEAT: every CPPN queried over the substrate's 160,000 links; NEAT: the
    networks), evaluation (playing the 4500 episodes), evolution (``tell``) and the champion's
    validation. The first ``--skip`` generations compile and are left out of the medians, which are
    reported with the live lane-steps (episode lengths differ between the two methods' teams) and the
    cost per live step."""
    import numpy as np

    from kx.evolve import config as cfg_lib

    runs = {}
    for name, path in (("neat", None), ("hyperneat", "configs/hyperneat_3v2.py")):
        cfg = cfg_lib.load(path, [f"seed={args.seed}", f"generations={args.generations}", "gif=false"])
        t0 = time.perf_counter()
        trainer, rows = _timed_generations(cfg, args.generations, name)
        runs[name] = (trainer, rows, time.perf_counter() - t0)
    med = {}
    for name, (trainer, rows, wall) in runs.items():
        body = rows[args.skip:] or rows
        m = {k: float(np.median([r[k] for r in body])) for k in (
            "generation_seconds", "build_seconds", "play_seconds", "evolve_seconds", "validation_seconds",
            "live_steps")}
        first = rows[0]["generation_seconds"]
        med[name] = m
        print(f"{name}: {trainer.encoding.describe()}; median over generations {min(args.skip, len(rows) - 1)}.."
              f"{len(rows) - 1}: {m['generation_seconds']:.3f} s per generation = build {m['build_seconds']:.3f} s "
              f"+ evaluation {m['play_seconds']:.3f} s + evolution {m['evolve_seconds']:.4f} s + validation "
              f"{m['validation_seconds']:.3f} s; {m['live_steps'] / 1e6:.2f}M live lane-steps per generation, "
              f"{m['play_seconds'] / max(m['live_steps'], 1) * 1e9:.0f} ns each; generation 0 (compiling) "
              f"{first:.1f} s; {wall:.0f} s in all")
    costs = _per_live_step(runs, args)
    _components(runs, args)
    print("per live step in the evaluator (2 cores): " + ", ".join(f"{k} {v:.0f} ns" for k, v in costs.items()))
    h, n = med["hyperneat"], med["neat"]
    per_step = (h["play_seconds"] / h["live_steps"]) / (n["play_seconds"] / n["live_steps"])
    print(f"per live lane-step, HyperNEAT's evaluation costs {per_step:.2f}x NEAT's")
    ratio = h["generation_seconds"] / n["generation_seconds"]
    print(f"hyperneat: {h['generation_seconds']:.3f} s/generation (ratio {ratio:.2f} vs neat)")


def _lanes(trainer, population, starts):
    """The evaluator's lanes of ``population`` on ``starts`` on one device (lane ``g * T + i``: policy g,
    trial i): the states and each lane's policy parameters (a :class:`Shared` table for a shared policy)."""
    import jax
    import jax.numpy as jnp

    from kx.sim.policies import Shared

    enc = trainer.encoding
    # on one device (HyperNEAT's table comes with its rows split over the devices, for the evaluator)
    params = jax.device_put(enc.policy_params(population), jax.devices()[0])
    n_pol = jax.tree.leaves(params)[0].shape[0]
    n_trials = starts.holder.shape[-1]
    lane = jnp.arange(n_pol * n_trials, dtype=jnp.int32)
    state = jax.tree.map(lambda a: jnp.take(a, lane % n_trials, axis=-1), starts)
    if enc.policy.shared:
        return state, Shared(params, lane // n_trials)
    return state, jax.tree.map(lambda p: jnp.moveaxis(jnp.take(p, lane // n_trials, axis=0), 0, -1), params)


def _time_per_lane(fn, state, params, reps: int = 40, samples: int = 5) -> float:
    """Median nanoseconds per lane of ``fn(params, state)`` (an int or float array ``[*B]``), applied
    ``reps`` times inside one compiled loop (so that dispatch does not count), over ``samples`` calls."""
    import jax
    import numpy as np

    from kx.bench.common import repeated

    loop = repeated(fn, reps)
    jax.block_until_ready(loop(params, state))
    times = []
    for _ in range(samples):
        t0 = time.perf_counter()
        jax.block_until_ready(loop(params, state))
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) / reps / state.holder.shape[-1] * 1e9


def _per_live_step(runs, args) -> dict:
    """Nanoseconds per live episode-step of each policy in the evaluator, on the same 4500 start states:
    the heuristic on them, and each method's generation-0 population on the first generation's 30 (150
    x 30 lanes), the median of 5 evaluations."""
    import jax
    import numpy as np

    from kx.evolve import streams
    from kx.sim import env
    from kx.sim import evaluate as ev
    from kx.sim.policies import heuristic

    out = {}
    trainer = runs["neat"][0]
    exp = trainer.exp
    keys = streams.training(args.seed, 0)
    many = env.reset_batch(keys.starts, 4500, exp.sim_params, exp.sim)
    few = env.reset_batch(keys.starts, trainer.cfg.trials, exp.sim_params, exp.sim)

    def cost(policy, params, starts):
        ev.evaluate(policy, params, starts, exp.sim_params, exp.sim, key=keys.eval)
        per = []
        for _ in range(5):
            c = ev.EvalCounters()
            t0 = time.perf_counter()
            jax.block_until_ready(ev.evaluate(policy, params, starts, exp.sim_params, exp.sim, key=keys.eval,
                                              counters=c).fitness)
            per.append((time.perf_counter() - t0) / c.live_steps * 1e9)
        return float(np.median(per))

    out["heuristic"] = cost(heuristic(exp.sim), None, many)
    for name in ("neat", "hyperneat"):
        tr = runs[name][0]
        population, _ = tr.encoding.ask(streams.learner_ask(args.seed, 0), tr.init().learner)
        out[name] = cost(tr.encoding.policy, tr.encoding.policy_params(population), few)
    return out


def _components(runs, args) -> None:
    """Where a lane-step goes, each part timed alone on one core over the 4500 lanes of generation 0
    (150 genomes x 30 trials): the world's step (:func:`kx.sim.env.transition`, with the holder holding),
    the heuristic's decision, and for each method its observation and its whole decision."""
    import jax
    import jax.numpy as jnp

    from kx.evolve import streams
    from kx.hyperneat import bev
    from kx.sim import env, observe
    from kx.sim.policies import heuristic

    trainer = runs["neat"][0]
    exp = trainer.exp
    keys = streams.training(args.seed, 0)
    starts = env.reset_batch(keys.starts, trainer.cfg.trials, exp.sim_params, exp.sim)
    sim, sp = exp.sim, exp.sim_params
    population, _ = trainer.encoding.ask(streams.learner_ask(args.seed, 0), trainer.init().learner)
    state, neat_params = _lanes(trainer, population, starts)
    zero = jnp.zeros(state.holder.shape, jnp.int32)
    def every_field(new):  # the whole next state, so that no part of the step is left out as unused
        leaves = [a.astype(jnp.float32).reshape(-1, a.shape[-1]) for a in jax.tree.leaves(new)]
        return sum(x[k] for x in leaves for k in range(x.shape[0]))

    world = _time_per_lane(lambda p, s: every_field(env.transition(s, jnp.maximum(s.holder, 0), zero, sp, sim)),
                           state, None)
    heur = heuristic(sim)
    h_dec = _time_per_lane(lambda p, s: heur.apply(None, s, None), state, None)
    neat_obs = _time_per_lane(lambda p, s: observe.fixed_obs(s, sim).sum(0), state, None)
    neat_pol = trainer.encoding.policy
    neat_dec = _time_per_lane(lambda p, s: neat_pol.apply(p, s, None), state, neat_params)
    htr = runs["hyperneat"][0]
    hpop, _ = htr.encoding.ask(streams.learner_ask(args.seed, 0), htr.init().learner)
    hstate, hparams = _lanes(htr, hpop, starts)
    image = htr.encoding.image
    h_obs = _time_per_lane(lambda p, s: bev.sparse_image(s, sim, image)[1].sum(0), hstate, None)
    h_pol = htr.encoding.policy
    h_dec2 = _time_per_lane(lambda p, s: h_pol.apply(p, s, None), hstate, hparams)
    print(f"per lane, each part alone on one core (ns): the world's step {world:.0f}; heuristic decision "
          f"{h_dec:.0f}; NEAT observation {neat_obs:.0f}, NEAT decision (observation + network + ranking) "
          f"{neat_dec:.0f}; HyperNEAT's image {h_obs:.0f}, HyperNEAT decision (image + substrate gathers and "
          f"products at the keepers' cells + ranking) {h_dec2:.0f}")
