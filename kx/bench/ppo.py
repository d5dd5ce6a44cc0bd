"""``python -m kx.bench ppo``: environment steps per second of PPO's training against the evaluator's live
steps per second for NEAT's policy, measured in the same run, in 4v3.

**PPO's side** is what a ``method = "ppo"`` run pays: the update of
:func:`kx.evolve.encodings.ppo.algorithm.make_update` (a rollout of the sampled policy through the environment's
batched functions, then ``update_epochs`` passes of the clipped loss over its decisions) with
``configs/ppo_4v3.py``'s settings, the shipped shape (:data:`kx.evolve.encodings.ppo.PROTOCOL_SHAPE`: 512 episodes
x 16 world iterations, 2 epochs of 16 minibatches, 2 x 32 tanh units); ``--config`` names another PPO config of
4v3, such as ``configs/ppo_entity_4v3.py`` (the entity network, same shape). A fresh network loses the ball within
a few steps, and such short episodes are not what training pays for most of its budget, so the network is first
trained for ``--ppo-warmup`` updates (their time, compilation included, is reported apart); then each
sample runs updates for at least ``--sample-seconds``. An environment step is an SMDP step, from one
decision of the holder to the next: the figure counts the decisions PPO learns from, and beside it the
world's iterations they spanned. The rollout alone (the same steps, no learning) is timed too, and the
environment's two interfaces on the same 1024 episodes: the per-episode step vmapped, and the batched
step PPO trains on.

**NEAT's side** is the run loop's evaluator (:func:`kx.sim.evaluate.evaluate`) playing the committed trained
4v3 population of ``kx bench policies`` (``kx/bench/data/policies/neat_4v3.npz``: 150 genomes on 30
training start states, 4500 lanes), its figure the live steps (iterations of episodes still running; each
is a decision of the holder's network while a keeper holds the ball) per second.

The two are sampled in turn (``--repeats`` rounds); each figure is the median of its samples and the
ratio the median of the ratios of samples of the same round. They do different work: NEAT's evaluator
plays 4500 fixed networks forward, PPO steps 512 episodes and learns from every decision (a forward pass
to act, then forward and backward passes in each epoch), so the ratio is what PPO's training costs per
step of the world against what NEAT's evaluation costs, not a measure of either implementation alone.

The last line::

    ppo: <steps/s> env steps/s (ratio <x> vs neat evaluator)
"""

from __future__ import annotations

import time


def run(args) -> None:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.bench.policies import evaluation_work, load_fixture, sample
    from kx.evolve import config as cfg_lib
    from kx.evolve import streams
    from kx.evolve.encodings.ppo import algorithm as ppo
    from kx.sim import env

    path = args.config or "configs/ppo_4v3.py"
    cfg = cfg_lib.load(path, ["gif=false"])
    if cfg.method not in ("ppo", "ppo_entity"):
        raise SystemExit(f"--config: allowed a config of method 'ppo' or 'ppo_entity', got {path} (method "
                         f"{cfg.method!r})")
    enc = cfg_lib.validate(cfg).encoding
    trainer, population, meta = load_fixture("neat")
    exp = trainer.exp
    if (enc.sim, enc.sim_params) != (exp.sim, exp.sim_params):
        raise SystemExit(f"--config: allowed a config of the NEAT fixture's task ({exp.sim.name}), got {path} "
                         f"(task {cfg.task})")
    keys = streams.training(meta["seed"], meta["generation"])
    starts = env.reset_batch(keys.starts, trainer.cfg.trials, exp.sim_params, exp.sim)
    neat_work = evaluation_work(trainer.encoding.policy, trainer.encoding.policy_params(population), starts,
                      (exp.sim_params, exp.sim), keys.eval)

    pcfg = enc.ppo
    steps_per_update = pcfg.num_envs * pcfg.num_steps
    world = ppo.environment(pcfg, enc.sim)  # the environment the encoding trains on
    update = jax.jit(ppo.make_update(pcfg, world, enc.sim_params))
    learner = jax.jit(lambda k: ppo.init(k, pcfg, world, enc.sim_params))(jax.random.key(args.seed))
    lr = np.float32(pcfg.lr)
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; task {exp.sim.name}", flush=True)
    lanes = meta["population_size"] * trainer.cfg.trials
    print(f"neat: {meta['population_size']} genomes x {trainer.cfg.trials} start states ({lanes} lanes), the trained "
          "4v3 population of kx/bench/data/policies/neat_4v3.npz", flush=True)
    print(f"ppo: {path}, {enc.describe()}; {steps_per_update} steps an update, {pcfg.update_epochs} epochs of "
          f"{pcfg.num_minibatches} minibatches", flush=True)

    t0 = time.perf_counter()
    key = jax.random.key(args.seed + 1)
    learner, m = update(learner, key, lr)
    jax.block_until_ready(learner)
    t_compile = time.perf_counter() - t0
    t0 = time.perf_counter()
    returns = []
    for u in range(args.ppo_warmup):
        learner, m = update(learner, jax.random.fold_in(key, u), lr)
        if int(m["episodes"]):
            returns.append(float(m["return_sum"]) / int(m["episodes"]))
    jax.block_until_ready(learner)
    t_warm = time.perf_counter() - t0
    print(f"ppo: first update {t_compile:.1f} s (compilation included); {args.ppo_warmup} warm-up updates "
          f"{t_warm:.1f} s, the last ones' training return {np.mean(returns[-10:]) if returns else float('nan'):.3f}",
          flush=True)

    rollout = jax.jit(ppo.make_rollout(pcfg, world, enc.sim_params))
    jax.block_until_ready(rollout(learner, key))
    state = {"learner": learner, "n": 0}

    def ppo_sample(seconds: float, learn: bool):
        dt = steps = iterations = 0
        while dt < seconds or steps == 0:
            k = jax.random.fold_in(key, 10_000 + state["n"])
            state["n"] += 1
            t = time.perf_counter()
            before = int(state["learner"].decisions)
            if learn:
                state["learner"], m = update(state["learner"], k, lr)
                decided = int(state["learner"].decisions) - before
            else:
                (_, _, _, _, it), traj = rollout(state["learner"], k)
                m = {"iterations": it}
                decided = steps_per_update if traj.valid is None else int(traj.valid.sum())
            iterations += int(jax.block_until_ready(m["iterations"]))
            dt += time.perf_counter() - t
            steps += decided  # the decisions learned from (an iteration rollout's flying episodes are not)
        return dt, steps, iterations

    # the environment's two interfaces on the same episodes and decisions (holding): the per-episode step
    # vmapped (batch first) against the batched step (batch-last), median of 5 calls after one that compiles
    n_env = 1024
    keys = jax.random.split(jax.random.key(args.seed + 2), n_env)
    _, batch = world.reset_batch(jax.random.key(args.seed + 2), n_env, enc.sim_params)
    one = jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0), batch)
    hold = jnp.zeros((n_env,), jnp.int32)
    env_calls = {"vmapped": (jax.jit(jax.vmap(world.step_env, in_axes=(0, 0, 0, None))),
                             (keys, one, hold, enc.sim_params)),
                 "batched": (jax.jit(world.step_batch_env), (batch, hold, enc.sim_params))}
    env_us = {}
    for name, (fn, call_args) in env_calls.items():
        jax.block_until_ready(fn(*call_args))
        times = []
        for _ in range(5):
            t = time.perf_counter()
            jax.block_until_ready(fn(*call_args))
            times.append(time.perf_counter() - t)
        env_us[name] = float(np.median(times)) / n_env * 1e6
    print(f"environment, {n_env} episodes holding: the per-episode step vmapped {env_us['vmapped']:.2f} us an "
          f"episode, the batched step {env_us['batched']:.2f} us ({env_us['vmapped'] / env_us['batched']:.0f}x)",
          flush=True)

    neat_work()  # compiles the evaluator's widths
    samples = {"ppo": [], "rollout": [], "neat": []}
    for _ in range(args.repeats):
        samples["ppo"].append(ppo_sample(args.sample_seconds, True))
        samples["rollout"].append(ppo_sample(args.sample_seconds, False))
        dt, live, _ = sample(neat_work, args.sample_seconds)
        samples["neat"].append((dt, live, live))
    rate = {k: [s / dt for dt, s, _ in v] for k, v in samples.items()}
    med = {k: float(np.median(v)) for k, v in rate.items()}
    per_step = {k: sum(it for _, _, it in v) / sum(s for _, s, _ in v) for k, v in samples.items()}
    ratio = float(np.median([a / b for a, b in zip(rate["ppo"], rate["neat"])]))
    spread = {k: 100 * (max(v) - min(v)) / med[k] for k, v in rate.items()}
    print(f"each figure: the median of {args.repeats} samples taken in turn, each at least {args.sample_seconds} s")
    print(f"neat evaluator: {med['neat']:,.0f} live steps/s (spread {spread['neat']:.0f}%)")
    print(f"ppo rollout alone: {med['rollout']:,.0f} env steps/s (spread {spread['rollout']:.0f}%), "
          f"{per_step['rollout']:.2f} world iterations an SMDP step")
    print(f"ppo training: {med['ppo']:,.0f} env steps/s (spread {spread['ppo']:.0f}%; {per_step['ppo']:.2f} world "
          f"iterations a step: {med['ppo'] * per_step['ppo']:,.0f} iterations/s); learning takes "
          f"{100 * (1 - med['ppo'] / med['rollout']):.0f}% of its time")
    print(f"ppo: {med['ppo']:.0f} env steps/s (ratio {ratio:.3f} vs neat evaluator)")
