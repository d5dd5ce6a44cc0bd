"""What a PPO update costs per decision learned from, at a trained policy's episodes, for several settings in
one process (the figures of docs/benchmarks.md, "Levers for PPO's wall time").

    python scripts/ppo_update_parts.py RUN_DIR "rollout='iteration',num_envs=512,num_steps=16" "update_epochs=1"

RUN_DIR: a 3v2 ``ppo`` run whose validated champion plays (its hidden width is the base's); the first setting is
the base (:class:`kx.evolve.encodings.ppo.algorithm.PPOConfig` fields), each further one changes it (a setting
of another ``hidden`` acts with fresh weights of that width from the same episodes, its figure per decision of
its own update). Each setting's episodes are first played 30 rollouts on from fresh starts with the champion,
so that they are as long as training's late episodes; then every setting's update (learning rate 0: the same
episodes each time) and the base's rollout alone are timed in turn, 7 rounds, and the medians printed in
milliseconds and in microseconds per decision.

    python scripts/ppo_update_parts.py RUN_DIR "rollout='iteration',num_envs=512,num_steps=16,resets=32" --parts

``--parts`` then times the base's rollout built up part by part over 64 world iterations of its episodes (the
world's transition alone; with the fixed observation; with the actor-critic's forward pass and the decision,
greedy, sampled with ``jax.random.categorical`` and sampled as the rollout samples, :func:`ppo.sample`; the rollout
itself), in microseconds per episode-iteration. ``--devices N`` times a block of updates (``--devices N`` episodes
to end, learning rate 0) on the base's episodes at ``ppo.devices`` 1 and 2, in turn, twice, in milliseconds per
update (docs/benchmarks.md, "Both cores").
"""

import argparse
import dataclasses
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from kx import runtime
from kx.evolve import config as cfg_lib
from kx.evolve import run as run_lib
from kx.evolve.encodings.ppo import algorithm as ppo


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", help="a 3v2 ppo run directory (its validated champion plays)")
    p.add_argument("base", help="the base setting: PPOConfig fields, e.g. \"rollout='iteration',num_envs=512\"")
    p.add_argument("variants", nargs="*", help="settings, each changing the base")
    p.add_argument("--parts", action="store_true", help="also time the base's rollout part by part")
    p.add_argument("--devices", type=int, default=0, metavar="EPISODES",
                   help="also time a block of updates ending this many episodes at ppo.devices 1 and 2")
    args = p.parse_args(argv)
    runtime.setup()  # one host device a core, before JAX starts
    run_dir, base, variants = args.run_dir, args.base, args.variants
    cfg_run = cfg_lib.read_run_config(pathlib.Path(run_dir) / "config.json")
    trainer = run_lib.Trainer(cfg_run)
    _, state, _ = trainer.restore(pathlib.Path(run_dir), None)
    params = state.champion
    sim, sim_params = trainer.exp.sim, trainer.exp.sim_params
    hidden = params["params"]["actor_0"]["kernel"].shape[1]
    cfg = ppo.PPOConfig(**{"hidden": hidden, **eval(f"dict({base})")})
    env = ppo.environment(cfg, sim)

    def warmed(c):
        """A learner of setting ``c`` whose episodes the champion has played 30 rollouts on (then landed)."""
        w = dataclasses.replace(c, hidden=hidden, max_minibatches=0, learn_per_episode=0)
        lrn = ppo.init(jax.random.key(0), w, env, sim_params, params)
        roll = jax.jit(ppo.make_rollout(w, env, sim_params))
        for i in range(30):
            (lrn, *_), _ = roll(lrn, jax.random.key(i))
        if w.rollout == "iteration":
            lrn = jax.jit(ppo.make_land(w, env, sim_params))(lrn, jax.random.key(99))[0][0]
        if c.hidden != hidden:  # a network of another width: fresh weights on the same episodes
            p = ppo.network(c).init(jax.random.key(0), jax.tree.map(lambda a: a[0], lrn.obs))
            lrn = lrn._replace(params=p, opt_state=ppo.optimiser(c).init(p))
        return lrn

    learner = warmed(cfg)
    roll = jax.jit(ppo.make_rollout(cfg, env, sim_params))
    fns = {base: (jax.jit(ppo.make_update(cfg, env, sim_params)), learner)}
    for v in variants:
        c = dataclasses.replace(cfg, **eval(f"dict({v})"))
        same_episodes = all(getattr(c, f) == getattr(cfg, f) for f in ("num_envs", "num_steps", "rollout", "resets",
                                                                      "hidden"))
        fns[v] = (jax.jit(ppo.make_update(c, env, sim_params)), learner if same_episodes else warmed(c))
    fns["the base's rollout alone"] = (lambda lrn, k, lr: roll(lrn, k), learner)
    for f, lrn in fns.values():
        jax.block_until_ready(f(lrn, jax.random.key(1), jnp.float32(0)))
    times = {k: [] for k in fns}
    for r in range(7):
        for k, (f, lrn) in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(f(lrn, jax.random.key(r), jnp.float32(0)))
            times[k].append(time.perf_counter() - t)
    _, traj = roll(learner, jax.random.key(5))
    decisions = cfg.num_envs * cfg.num_steps if traj.valid is None else int(traj.valid.sum())
    print(f"{decisions} decisions a rollout of the base ({cfg.num_envs} episodes x {cfg.num_steps} "
          f"{'iterations' if cfg.rollout == 'iteration' else 'SMDP steps'}), hidden {hidden}")
    for k, v in times.items():
        f, lrn = fns[k]
        if k in variants:  # its own decisions an update
            out = f(lrn, jax.random.key(0), jnp.float32(0))[0]
            n = int(out.decisions - lrn.decisions)
        else:
            n = decisions
        m = float(np.median(v))
        print(f"{m * 1e3:7.2f} ms  {m / n * 1e6:5.2f} us/decision  {k}")
    if args.parts:
        rollout_parts(cfg, env, sim, sim_params, learner)
    if args.devices:
        devices_block(cfg, env, sim_params, learner, args.devices)


def devices_block(cfg, env, sim_params, learner, episodes: int):
    """A block of updates ending ``episodes`` episodes from ``learner`` (learning rate 0: every block plays the same
    episodes), on one host device and data-parallel on two, timed warm in turn, twice."""
    start = learner._replace(episodes=jnp.zeros((), jnp.int32), blocks=jnp.zeros((), jnp.int32))
    blocks = {}
    for dev in (1, 2):
        c = dataclasses.replace(cfg, devices=dev, lr=0.0)
        blocks[dev] = (jax.jit(ppo.make_block(c, env, sim_params, episodes, 0)), ppo.place(start, c))
        jax.block_until_ready(blocks[dev][0](blocks[dev][1], jax.random.key(1)))
    for _ in range(2):
        for dev, (block, lrn) in blocks.items():
            t = time.perf_counter()
            out = jax.block_until_ready(block(lrn, jax.random.key(2)))
            dt, n = time.perf_counter() - t, int(out[1]["updates"])
            print(f"devices {dev}: {n} updates in {dt:.2f} s, {dt / n * 1e3:.2f} ms an update")


def rollout_parts(cfg, env, sim, sim_params, learner, steps: int = 64):
    """The rollout of ``cfg`` built up part by part on ``learner``'s episodes (those at a decision act, the others
    fly; an ended episode stays as it is), medians of 7 timings in microseconds per episode-iteration."""
    from kx.sim import env as world_lib
    from kx.sim import observe

    s_max = world_lib.noise_limit(sim_params.kick_noise_deg)
    net, params, word = ppo.network(cfg), learner.params, learner.env.noise_word

    def loop(decide, observe_it=True):
        def body(w, xs):
            k, u = xs
            if decide is None:
                keeper, out = jnp.where(w.holder >= 0, w.holder, -1), 0.0
            else:
                logits, value = net.apply(params, jnp.moveaxis(observe.fixed_obs(w, sim), 0, -1))
                keeper, out = env.keeper_of(type(learner.env)(world=w, noise_word=word), decide(logits, k, u)), value
            w2 = world_lib.transition(w, keeper, world_lib.kick_noise(word, w.t, s_max), sim_params, sim)
            w2 = jax.tree.map(lambda new, old, d=w.done: jnp.where(d, old, new), w2, w)
            if decide is None and observe_it:
                out = observe.fixed_obs(w2, sim).sum()
            return w2, jnp.sum(out)

        keys = jax.random.split(jax.random.key(0), steps)
        us = jax.random.uniform(jax.random.key(1), (steps, cfg.num_envs))
        return jax.jit(lambda w: jax.lax.scan(body, w, (keys, us)))

    roll = jax.jit(ppo.make_rollout(dataclasses.replace(cfg, num_steps=steps), env, sim_params))
    fns = {"the world's transition": loop(None, False), "+ the fixed observation": loop(None),
           "+ the actor-critic, greedy": loop(lambda lg, k, u: jnp.argmax(lg, -1)),
           "+ the actor-critic, jax.random.categorical": loop(lambda lg, k, u: jax.random.categorical(k, lg)),
           "+ the actor-critic, ppo.sample (the rollout's)": loop(lambda lg, k, u: ppo.sample(lg, u)),
           "the rollout (its transitions kept, resets)": lambda w: roll(learner, jax.random.key(3))}
    for f in fns.values():
        jax.block_until_ready(f(learner.env.world))
    for name, f in fns.items():
        times = []
        for _ in range(7):
            t = time.perf_counter()
            jax.block_until_ready(f(learner.env.world))
            times.append(time.perf_counter() - t)
        print(f"{float(np.median(times)) / (cfg.num_envs * steps) * 1e6:6.3f} us/episode-iteration  {name}")


if __name__ == "__main__":
    main()
