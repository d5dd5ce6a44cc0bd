"""Whether PPO (kx.ppo) learns keep-away: one training of the default PPOConfig (or the options'), then its
greedy policy and always-hold on the same start states, each episode's return its fitness.

    python scripts/ppo_learns.py --task 3v2 --updates 100 --reward-scale 100 --episodes 200
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="3v2", help="KvT, e.g. 3v2, 4v3")
    p.add_argument("--updates", type=int, default=100)
    p.add_argument("--reward-scale", type=float, default=100.0)
    p.add_argument("--num-steps", type=int, default=64)
    p.add_argument("--num-envs", type=int, default=64)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--episodes", type=int, default=200, help="start states the policies are compared on")
    args = p.parse_args()

    from kx import runtime

    runtime.setup()
    import jax
    import jax.numpy as jnp

    from kx import ppo
    from kx.sim import gym
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    k, t = (int(x) for x in args.task.split("v"))
    env, params = gym.KeepAway(KeepAwayConfig(n_keepers=k, n_takers=t)), KeepAwayParams()
    cfg = ppo.PPOConfig(updates=args.updates, reward_scale=args.reward_scale, num_steps=args.num_steps,
                        num_envs=args.num_envs, resets=max(1, args.num_envs // 8))
    t0 = time.perf_counter()
    state, metrics = jax.jit(ppo.make_train(cfg, env, params))(jax.random.key(args.seed))
    jax.block_until_ready(state)
    steps = cfg.updates * cfg.num_envs * cfg.num_steps
    print(f"{args.task}: {cfg.updates} updates, {steps:,} SMDP steps in {time.perf_counter() - t0:.1f} s "
          f"(compilation included); episodes ended in the first and last rollout: "
          f"{int(metrics['episodes'][0])}, {int(metrics['episodes'][-1])} of "
          f"{cfg.num_envs * cfg.num_steps} steps")

    def episode(net_params, key):
        _, s = env.reset(key, params)

        def body(c):
            s, total = c
            a = jnp.int32(0) if net_params is None else ppo.greedy(net_params, env.observation(s), cfg.hidden)
            _, s2, r, _, _ = env.step_env(key, s, a, params)
            return s2, total + r

        return jax.lax.while_loop(lambda c: ~c[0].world.done, body, (s, jnp.float32(0.0)))[1]

    keys = jax.random.split(jax.random.key(10_000 + args.seed), args.episodes)
    learned = jax.jit(jax.vmap(lambda kk: episode(state.params, kk)))(keys)
    hold = jax.jit(jax.vmap(lambda kk: episode(None, kk)))(keys)
    print(f"mean return (fitness) on {args.episodes} start states: PPO greedy {float(learned.mean()):.4f}, "
          f"always hold {float(hold.mean()):.4f}")


if __name__ == "__main__":
    main()
