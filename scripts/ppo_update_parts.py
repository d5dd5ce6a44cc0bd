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
"""

import argparse
import dataclasses
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from kx.evolve import config as cfg_lib
from kx.evolve import run as run_lib
from kx.evolve.encodings.ppo import algorithm as ppo


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", help="a 3v2 ppo run directory (its validated champion plays)")
    p.add_argument("base", help="the base setting: PPOConfig fields, e.g. \"rollout='iteration',num_envs=512\"")
    p.add_argument("variants", nargs="*", help="settings, each changing the base")
    args = p.parse_args(argv)
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


if __name__ == "__main__":
    main()
