"""PPO on the keep-away environment (:mod:`kx.sim.gym`), purejaxrl-style: the whole training one jitted
function of a key, vmapped over seeds at the call site.

The network has NEAT's fixed layout: the 13 inputs in, an actor of 3 logits (hold, pass to the nearest
teammate, to the second nearest) and a critic; flax for the network, optax for the optimiser (Adam with
gradient clipping, the learning rate annealed linearly to 0 if asked). The objective is PPO's clipped
surrogate with generalised advantage estimation (Schulman et al. 2017; GAE: Schulman et al. 2016) over
SMDP steps, a step from one decision of the holder to the next (its reward the share of the episode
survived in between). Evaluated greedily (the argmax of the logits), as NEAT's networks decide.

This module is the learner alone: it is not yet a method of ``python -m kx.train`` (issue 34).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax.training.train_state import TrainState

from kx.sim import gym
from kx.sim.types import KeepAwayParams


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    num_envs: int = 64  # episodes stepped side by side
    num_steps: int = 64  # SMDP steps of each per update
    updates: int = 100  # updates of the whole training
    update_epochs: int = 4
    num_minibatches: int = 4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    lr: float = 2.5e-4
    anneal_lr: bool = True
    hidden: int = 64
    reward_scale: float = 100.0  # the critic learns the return times this: a step's reward is a share of the
    # 4500 iterations, and at 1.0 the greedy policy of 50 updates only held (return 0.002); at 100, 100
    # updates: 0.33 on 200 test starts, always-hold 0.002 (scripts/ppo_learns.py, 3v2, seed 0)

    def __post_init__(self):
        if (self.num_envs * self.num_steps) % self.num_minibatches:
            raise ValueError(f"num_minibatches: must divide num_envs x num_steps ({self.num_envs * self.num_steps}), "
                             f"got {self.num_minibatches}")


class ActorCritic(nn.Module):
    n_actions: int = gym.N_ACTIONS
    hidden: int = 64

    @nn.compact
    def __call__(self, obs):
        def mlp(x, out, scale):
            for _ in range(2):
                x = nn.tanh(nn.Dense(self.hidden, kernel_init=nn.initializers.orthogonal(np.sqrt(2)))(x))
            return nn.Dense(out, kernel_init=nn.initializers.orthogonal(scale))(x)

        return mlp(obs, self.n_actions, 0.01), mlp(obs, 1, 1.0)[..., 0]


class Transition(NamedTuple):
    obs: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    done: jax.Array


def gae(rewards, values, dones, last_value, gamma: float, lam: float):
    """Advantages and value targets ``[T, N]`` of a rollout: ``dones[t]`` ends the episode after step ``t``
    (no bootstrap across it), ``last_value [N]`` the critic after the last step."""
    def back(carry, x):
        next_adv, next_value = carry
        r, v, d = x
        delta = r + gamma * next_value * (1.0 - d) - v
        adv = delta + gamma * lam * (1.0 - d) * next_adv
        return (adv, v), adv

    _, adv = jax.lax.scan(back, (jnp.zeros_like(last_value), last_value), (rewards, values, dones.astype(jnp.float32)),
                          reverse=True)
    return adv, adv + values


def loss(params, apply_fn, batch: Transition, advantages, targets, clip_eps: float, vf_coef: float,
         ent_coef: float):
    """PPO's loss of a minibatch: the clipped surrogate on normalised advantages, the clipped value loss,
    minus the entropy bonus. Returns ``(total, (policy, value, entropy))``."""
    logits, value = apply_fn(params, batch.obs)
    logp_all = jax.nn.log_softmax(logits)
    logp = jnp.take_along_axis(logp_all, batch.action[..., None], axis=-1)[..., 0]
    v_clipped = batch.value + jnp.clip(value - batch.value, -clip_eps, clip_eps)
    value_loss = 0.5 * jnp.maximum((value - targets) ** 2, (v_clipped - targets) ** 2).mean()
    ratio = jnp.exp(logp - batch.log_prob)
    adv = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    policy_loss = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip_eps, 1 + clip_eps) * adv).mean()
    entropy = -(jnp.exp(logp_all) * logp_all).sum(-1).mean()
    return policy_loss + vf_coef * value_loss - ent_coef * entropy, (policy_loss, value_loss, entropy)


def make_train(cfg: PPOConfig, env: gym.KeepAway, env_params: KeepAwayParams):
    """``train(key) -> (train_state, metrics)``: ``cfg.updates`` PPO updates; jit it, vmap it over keys."""
    net = ActorCritic(hidden=cfg.hidden)
    n_batch = cfg.num_envs * cfg.num_steps
    steps_per_update = cfg.update_epochs * cfg.num_minibatches

    def schedule(count):
        return cfg.lr * (1.0 - (count // steps_per_update) / cfg.updates) if cfg.anneal_lr else cfg.lr

    def train(key):
        k_init, k_reset, key = jax.random.split(key, 3)
        params = net.init(k_init, jnp.zeros((env.observation_size,)))
        tx = optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.adam(schedule, eps=1e-5))
        state = TrainState.create(apply_fn=net.apply, params=params, tx=tx)
        obs, env_state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(k_reset, cfg.num_envs), env_params)

        def env_step(carry, _):
            state, env_state, obs, key = carry
            key, k_act, k_env = jax.random.split(key, 3)
            logits, value = net.apply(state.params, obs)
            action = jax.random.categorical(k_act, logits)
            log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[..., None], axis=-1)[..., 0]
            obs2, env_state, reward, done, _ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(k_env, cfg.num_envs), env_state, action, env_params)
            return (state, env_state, obs2, key), Transition(obs, action, log_prob, value, reward, done)

        def update(carry, _):
            state, env_state, obs, key = carry
            (state, env_state, obs, key), traj = jax.lax.scan(env_step, (state, env_state, obs, key), None,
                                                               cfg.num_steps)
            _, last_value = net.apply(state.params, obs)
            adv, targets = gae(traj.reward * cfg.reward_scale, traj.value, traj.done, last_value, cfg.gamma,
                               cfg.gae_lambda)

            def epoch(carry, _):
                state, key = carry
                key, k_perm = jax.random.split(key)
                perm = jax.random.permutation(k_perm, n_batch)
                flat = jax.tree.map(lambda a: a.reshape((n_batch,) + a.shape[2:])[perm], (traj, adv, targets))
                mb = jax.tree.map(lambda a: a.reshape((cfg.num_minibatches, -1) + a.shape[1:]), flat)

                def minibatch(state, b):
                    t, a, tg = b
                    grads, aux = jax.grad(loss, has_aux=True)(state.params, net.apply, t, a, tg, cfg.clip_eps,
                                                              cfg.vf_coef, cfg.ent_coef)
                    return state.apply_gradients(grads=grads), aux

                state, aux = jax.lax.scan(minibatch, state, mb)
                return (state, key), aux

            (state, key), aux = jax.lax.scan(epoch, (state, key), None, cfg.update_epochs)
            metrics = {"policy_loss": aux[0].mean(), "value_loss": aux[1].mean(), "entropy": aux[2].mean(),
                       "episodes_ended": traj.done.sum(), "mean_reward": traj.reward.mean()}
            return (state, env_state, obs, key), metrics

        (state, *_), metrics = jax.lax.scan(update, (state, env_state, obs, key), None, cfg.updates)
        return state, metrics

    return train


def greedy(params, obs, hidden: int = 64):
    """The network's decision when evaluated: the argmax of its logits."""
    logits, _ = ActorCritic(hidden=hidden).apply(params, obs)
    return jnp.argmax(logits, axis=-1)
