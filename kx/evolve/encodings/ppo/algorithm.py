"""PPO on the keep-away environment (:mod:`kx.sim.gym`), purejaxrl-style: the whole training one jitted
function of a key, vmapped over seeds at the call site.

Over 450 lines because it keeps purejaxrl's layout: the networks, the rollout, GAE, the loss and the update in one
file, so that the one jitted program reads top to bottom.

The network (``PPOConfig.network``) is either ``"mlp"``, on NEAT's fixed layout: the 13 inputs in, an actor of 3
logits (hold, pass to the nearest teammate, to the second nearest) and a critic; or ``"entity"``, the size-invariant
:class:`EntityActorCritic` on the holder's view as tokens (:mod:`kx.sim.entities`: self-attention over the holder,
its teammates and the takers; a hold logit and one pass logit per teammate, for any team size). The run loop's
method ``ppo`` trains the MLP; the entity network trains through :func:`make_train` and :func:`make_block` with
:func:`environment`'s observation. Both use flax for the network, optax for the optimiser (Adam with
gradient clipping, the learning rate annealed linearly to 0 if asked). The objective is PPO's clipped
surrogate with generalised advantage estimation (Schulman et al. 2017; GAE: Schulman et al. 2016) over
SMDP steps, a step from one decision of the holder to the next (its reward the share of the episode
survived in between, its discount ``gamma`` to the power of the iterations it spanned). Evaluated
greedily (the argmax of the logits), as NEAT's networks decide.

:func:`make_train` is the whole training as one program of a key (``cfg.updates`` updates); the run loop's
method ``ppo`` (:mod:`kx.evolve.encodings.ppo`) trains in blocks of episodes instead (:func:`make_block`),
its :class:`Learner` checkpointed between them. Both step the environment's batched functions
(:meth:`kx.sim.gym.KeepAway.step_batch`).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import optax

from kx.sim import gym
from kx.sim.types import KeepAwayParams


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    num_envs: int = 64  # episodes stepped side by side
    num_steps: int = 64  # SMDP steps of each per update
    updates: int = 100  # updates of the whole training
    update_epochs: int = 4
    num_minibatches: int = 4
    gamma: float = 0.99  # per iteration of the world: an SMDP step of tau iterations is discounted by gamma ** tau
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    lr: float = 2.5e-4
    anneal_lr: bool = True
    hidden: int = 64
    network: str = "mlp"  # "mlp": ActorCritic on the fixed 13 inputs; "entity": EntityActorCritic on entity tokens
    heads: int = 4  # the entity network's attention heads (hidden must be a multiple)
    blocks: int = 1  # the entity network's attention blocks
    mix: tuple[str, ...] = ()  # other tasks whose episodes join every batch ("4v3", ...): the entity network only
    resets: int = 8  # start states drawn per step for the episodes that end in it (kx.sim.gym.step_batch)
    max_minibatches: int = 0  # an epoch learns from at most this many of its minibatches, drawn at random (0: all):
    # the rest of the rollout's steps are played (the budget is in episodes) but not learned from in that epoch
    learn_per_episode: int = 0  # rollout "iteration": an epoch learns from about this many of the rollout's
    # decisions per episode the rollout ended (whole minibatches, at least one; 0: all of them). Early, when
    # episodes are short, every decision is learned from; late, when an episode runs to a thousand decisions and
    # more, the rollouts are still played (the budget is in episodes) but few of their decisions are learned from
    rollout: str = "smdp"  # "smdp": a rollout step is an SMDP step of every episode (the batch waits for the
    # slowest pass to land); "iteration": a world iteration, the episodes at a decision act (ROLLOUTS)
    devices: int = 1  # the host devices the episodes are split over, data-parallel (:func:`make_block`): each
    # device steps and learns from num_envs / devices episodes, the gradients of a minibatch summed over them
    reward_scale: float = 100.0  # the critic learns the return times this: a step's reward is a share of the
    # 4500 iterations, and at 1.0 the greedy policy of 50 updates only held (return 0.002); at 100: 0.30 after
    # 100 updates, 0.40 after 400, always-hold 0.002 (scripts/ppo_learns.py at 629aac9, 3v2, seed 0, 200 test starts)

    def __post_init__(self):
        if (self.num_envs * self.num_steps) % self.num_minibatches:
            raise ValueError(f"num_minibatches: must divide num_envs x num_steps ({self.num_envs * self.num_steps}), "
                             f"got {self.num_minibatches}")
        if not 1 <= self.resets <= self.num_envs:
            raise ValueError(f"resets: allowed an integer in [1, num_envs = {self.num_envs}], got {self.resets}")
        if not 0 <= self.max_minibatches:
            raise ValueError(f"max_minibatches: allowed an integer >= 0 (0: every minibatch), got "
                             f"{self.max_minibatches}")
        if self.learn_per_episode < 0 or (self.learn_per_episode and self.rollout != "iteration"):
            raise ValueError(f"learn_per_episode: allowed an integer >= 0, and > 0 only with rollout 'iteration', got "
                             f"{self.learn_per_episode} (rollout {self.rollout!r})")
        if self.devices < 1 or self.num_envs % self.devices or self.resets % self.devices or (
                (self.num_envs // self.devices * self.num_steps) % self.num_minibatches):
            raise ValueError(f"devices: allowed an integer >= 1 that divides num_envs ({self.num_envs}) and resets "
                             f"({self.resets}), leaving each device's num_envs x num_steps divisible by "
                             f"num_minibatches ({self.num_minibatches}), got {self.devices}")
        if self.rollout not in ROLLOUTS:
            raise ValueError(f"rollout: allowed {', '.join(ROLLOUTS)}, got {self.rollout!r}")
        if self.network not in NETWORKS:
            raise ValueError(f"network: allowed {', '.join(NETWORKS)}, got {self.network!r}")
        if self.network == "entity" and (self.heads < 1 or self.hidden % self.heads or self.blocks < 0):
            raise ValueError(f"heads: allowed a divisor of hidden = {self.hidden} (blocks >= 0), got heads "
                             f"{self.heads}, blocks {self.blocks}")
        if self.mix:
            tasks = 1 + len(self.mix)
            if self.network != "entity":
                raise ValueError(f"mix: allowed only with the entity network (the {self.network} network's inputs "
                                 f"are one task's), got {self.mix}")
            if self.num_envs % (tasks * self.devices) or self.resets % (tasks * self.devices):
                raise ValueError(f"mix: num_envs ({self.num_envs}) and resets ({self.resets}) must divide among the "
                                 f"{tasks} tasks on each of the {self.devices} devices, got {self.mix}")


#: how a rollout steps its episodes. ``"smdp"``: ``num_steps`` SMDP steps of every episode
#: (:meth:`kx.sim.gym.KeepAway.step_batch`), each until the episode's next decision, so the whole batch iterates
#: until the slowest pass has landed (4-7 iterations a step where an episode needs 1.1-1.5 on average). ``"iteration"``:
#: ``num_steps`` world iterations of every episode (:meth:`kx.sim.gym.KeepAway.iterate_batch`); the episodes at a
#: decision act and are learned from, the others fly (masked out: ``Transition.valid``), and the passes in flight
#: at the rollout's end land before the critic bootstraps (:meth:`kx.sim.gym.KeepAway.land_batch`). Both learn from
#: the same SMDP steps (:func:`gae` and :func:`gae_iterations` give the same advantages).
ROLLOUTS = ("smdp", "iteration")

#: the networks PPO trains, and the observation of the environment each reads (kx.sim.gym.KeepAway)
NETWORKS = {"mlp": "fixed", "entity": "entities"}


class ActorCritic(nn.Module):
    n_actions: int = gym.N_ACTIONS
    hidden: int = 64

    @nn.compact
    def __call__(self, obs):
        def mlp(x, out, scale, name):
            for i in range(2):
                x = nn.tanh(nn.Dense(self.hidden, kernel_init=nn.initializers.orthogonal(np.sqrt(2)),
                                     name=f"{name}_{i}")(x))
            return nn.Dense(out, kernel_init=nn.initializers.orthogonal(scale), name=f"{name}_{2}")(x)

        return mlp(obs, self.n_actions, 0.01, "actor"), mlp(obs, 1, 1.0, "critic")[..., 0]


class EntityActorCritic(nn.Module):
    """A size-invariant actor-critic on the holder's view as entity tokens (:mod:`kx.sim.entities`): each token
    embedded by its kind's layer (holder, teammate, taker), ``blocks`` pre-norm blocks of self-attention over
    all tokens and a tanh MLP, each with a residual (no position encoding: the tokens form a set, as in UPDeT and
    TransfQMix), then the hold logit and the critic from the holder's token and one pass logit per teammate
    from its own token. Equivariant to the order of teammates (their logits follow them), invariant to the order
    of takers, for any number of either: ``obs`` a dict ``holder [..., 4]``, ``mates [..., M, 6]``, ``takers [...,
    T, 4]``; returns logits ``[..., 1 + M]`` (hold, pass to teammate slot r) and the value ``[...]``."""

    hidden: int = 64
    heads: int = 4
    blocks: int = 1

    @nn.compact
    def __call__(self, obs):
        orth = nn.initializers.orthogonal
        embed = lambda x, name: nn.Dense(self.hidden, kernel_init=orth(np.sqrt(2)), name=name)(x)  # noqa: E731
        x = jnp.concatenate([embed(obs["holder"], "holder_in")[..., None, :], embed(obs["mates"], "mate_in"),
                             embed(obs["takers"], "taker_in")], axis=-2)
        mask = None
        if "mate_mask" in obs:  # episodes of several team sizes, padded (mixed_tokens): absent entities attend to
            # nothing and are attended by none, and no pass goes to an absent teammate
            valid = jnp.concatenate([jnp.ones(obs["holder"].shape[:-1] + (1,), bool), obs["mate_mask"],
                                     obs["taker_mask"]], axis=-1)
            mask = nn.make_attention_mask(valid, valid)
        for i in range(self.blocks):
            y = nn.LayerNorm(name=f"norm_{i}_0")(x)
            x = x + nn.MultiHeadDotProductAttention(num_heads=self.heads, name=f"attention_{i}")(y, y, mask=mask)
            y = nn.LayerNorm(name=f"norm_{i}_1")(x)
            y = nn.tanh(nn.Dense(self.hidden, kernel_init=orth(np.sqrt(2)), name=f"mlp_{i}_0")(y))
            x = x + nn.Dense(self.hidden, kernel_init=orth(1.0), name=f"mlp_{i}_1")(y)
        x = nn.LayerNorm(name="norm_out")(x)
        m = obs["mates"].shape[-2]
        hold = nn.Dense(1, kernel_init=orth(0.01), name="hold")(x[..., 0, :])
        passes = nn.Dense(1, kernel_init=orth(0.01), name="pass")(x[..., 1:1 + m, :])[..., 0]
        if "mate_mask" in obs:
            passes = jnp.where(obs["mate_mask"], passes, ABSENT)
        v = nn.tanh(nn.Dense(self.hidden, kernel_init=orth(np.sqrt(2)), name="critic_0")(x[..., 0, :]))
        value = nn.Dense(1, kernel_init=orth(1.0), name="critic_1")(v)[..., 0]
        return jnp.concatenate([hold, passes], axis=-1), value


def network(cfg: PPOConfig) -> nn.Module:
    """The actor-critic ``cfg.network`` names."""
    if cfg.network == "entity":
        return EntityActorCritic(hidden=cfg.hidden, heads=cfg.heads, blocks=cfg.blocks)
    return ActorCritic(hidden=cfg.hidden)


#: the logit of a pass to an absent teammate (a padded slot of a smaller team): never sampled, never greedy
ABSENT = -1e9


def environment(cfg: PPOConfig, config):
    """The environment of task ``config`` with the observation ``cfg.network`` reads; with ``cfg.mix``, a tuple of
    it and one of each task of the mix (the same field, speeds and chasers), whose episodes share every batch."""
    if not cfg.mix:
        return gym.KeepAway(config, NETWORKS[cfg.network])
    from kx.sim.types import KeepAwayConfig

    others = tuple(KeepAwayConfig.from_task(t, field_size=config.field_size, agent_speed=config.agent_speed,
                                            ball_speed=config.ball_speed, n_chasers=config.n_chasers)
                   for t in cfg.mix)
    return tuple(gym.KeepAway(c, NETWORKS[cfg.network]) for c in (config, *others))


def mixed_tokens(obs: list[dict]) -> dict:
    """Batch-first tokens of several team sizes (one dict a task) as one batch: teammates and takers padded with
    zeros to the largest team's, ``mate_mask`` and ``taker_mask`` saying which are there, the tasks' episodes in
    order."""
    m = max(o["mates"].shape[1] for o in obs)
    t = max(o["takers"].shape[1] for o in obs)

    def pad(a, n):
        return jnp.pad(a, ((0, 0), (0, n - a.shape[1]), (0, 0)))

    def there(a, n):
        return jnp.broadcast_to(jnp.arange(n) < a.shape[1], (a.shape[0], n))

    return {"holder": jnp.concatenate([o["holder"] for o in obs]),
            "mates": jnp.concatenate([pad(o["mates"], m) for o in obs]),
            "takers": jnp.concatenate([pad(o["takers"], t) for o in obs]),
            "mate_mask": jnp.concatenate([there(o["mates"], m) for o in obs]),
            "taker_mask": jnp.concatenate([there(o["takers"], t) for o in obs])}


def _reset(key, cfg: PPOConfig, env, env_params):
    """The first ``num_envs`` episodes: of the one task, or split evenly among the mix's (each its own key)."""
    if not isinstance(env, tuple):
        return env.reset_batch(key, cfg.num_envs, env_params)
    n = cfg.num_envs // len(env)
    out = [e.reset_batch(k, n, env_params) for e, k in zip(env, jax.random.split(key, len(env)))]
    return mixed_tokens([o for o, _ in out]), tuple(s for _, s in out)


def _step(key, cfg: PPOConfig, env, state, action, env_params, how: str = "step"):
    """``step_batch`` of the one task (``how``: ``"iterate"``, ``iterate_batch``; ``"land"``, ``land_batch``,
    ``action`` unused), or of each task of the mix on its share of the batch (``resets`` split evenly): the
    observations as one batch (:func:`mixed_tokens`), rewards, ends and iterations in the batch's order."""

    def call(e, k, s, a, resets):
        if how == "land":
            return e.land_batch(k, s, env_params, resets)
        return getattr(e, f"{how}_batch")(k, s, a, env_params, resets)

    if not isinstance(env, tuple):
        return call(env, key, state, action, cfg.resets)
    n = cfg.num_envs // len(env)
    outs = [call(e, k, s, None if action is None else action[i * n:(i + 1) * n], cfg.resets // len(env))
            for i, (e, s, k) in enumerate(zip(env, state, jax.random.split(key, len(env))))]
    info = {"iterations": jnp.concatenate([o[4]["iterations"] for o in outs]),
            "shared_starts": sum(o[4]["shared_starts"] for o in outs)}
    return (mixed_tokens([o[0] for o in outs]), tuple(o[1] for o in outs), jnp.concatenate([o[2] for o in outs]),
            jnp.concatenate([o[3] for o in outs]), info)


def _deciding(env, state) -> jax.Array:
    """``[num_envs]``: the episodes at a decision (:meth:`kx.sim.gym.KeepAway.deciding`), in the batch's order."""
    if not isinstance(env, tuple):
        return env.deciding(state)
    return jnp.concatenate([e.deciding(s) for e, s in zip(env, state)])


#: the actor's layers in ``params["params"]``, input first (:class:`ActorCritic`)
ACTOR_LAYERS = ("actor_0", "actor_1", "actor_2")


def actor_logits_batch_last(params, x):
    """The actor's logits ``[3, *B]`` of observations ``x [13, *B]`` (batch-last, as the evaluator has them),
    computed as elementwise multiply-adds in a fixed order: ``params`` holds one network (its leaves as
    :class:`ActorCritic` has them, broadcast over every lane) or one per lane (each leaf with the lanes'
    axes ``*B`` last), and a lane's logits are bit for bit the same either way, whatever the other lanes."""
    nb = x.ndim - 1
    for k, name in enumerate(ACTOR_LAYERS):
        layer = params["params"][name]
        w, b = layer["kernel"], layer["bias"]
        if w.ndim == 2:  # one network for every lane: trailing axes to broadcast over the lanes
            w, b = w.reshape(w.shape + (1,) * nb), b.reshape(b.shape + (1,) * nb)
        out = b
        for i in range(x.shape[0]):  # unrolled: the sums in a fixed order
            out = out + x[i][None] * w[i]
        x = jnp.tanh(out) if k < len(ACTOR_LAYERS) - 1 else out
    return x


def sample(logits: jax.Array, u: jax.Array) -> jax.Array:
    """Actions drawn from the softmax of ``logits [..., A]`` by inverting its CDF at uniforms ``u [...]`` in
    [0, 1): action ``a`` when ``c[a-1] <= u * c[A-1] < c[a]`` (``c`` the probabilities' running sum), the
    categorical's distribution. The rollout draws a whole rollout's uniforms in one call: drawing a key's
    Gumbel noise every step (``jax.random.categorical``) cost about 0.14 us an episode-iteration of 0.95 at 512
    episodes (2026-12-06). An action of probability zero is never drawn (an absent teammate's slot:
    :data:`ABSENT`), since its running sum equals the one before it, and ``u * c[A-1] < c[A-1]``."""
    c = jnp.cumsum(jax.nn.softmax(logits), axis=-1)
    return (c[..., :-1] <= (u * c[..., -1])[..., None]).sum(-1, dtype=jnp.int32)


class Transition(NamedTuple):
    obs: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    done: jax.Array
    iterations: jax.Array  # the world's iterations the SMDP step spanned (its discount is gamma ** iterations)
    valid: Any = None  # rollout "iteration": bool, the episode was at a decision (a step learned from); else None


def gae(rewards, values, dones, last_value, gamma: float, lam: float, durations=None):
    """Advantages and value targets ``[T, N]`` of a rollout: ``dones[t]`` ends the episode after step ``t``
    (no bootstrap across it), ``last_value [N]`` the critic after the last step. SMDP steps
    (``durations [T, N]``, the world's iterations each spanned; default 1) are discounted by ``gamma **
    durations``: ``delta_t = r_t + gamma^tau_t V(s_t+1) - V(s_t)``, ``A_t = delta_t + gamma^tau_t lam
    A_t+1`` (Bradtke and Duff 1995; Sutton, Precup and Singh 1999), so that a pass of ten iterations is
    discounted as ten iterations of holding are."""
    if durations is None:
        durations = jnp.ones_like(rewards)
    discounts = jnp.asarray(gamma, jnp.float32) ** durations.astype(jnp.float32)

    def back(carry, x):
        next_adv, next_value = carry
        r, v, d, g = x
        delta = r + g * next_value * (1.0 - d) - v
        adv = delta + g * lam * (1.0 - d) * next_adv
        return (adv, v), adv

    _, adv = jax.lax.scan(back, (jnp.zeros_like(last_value), last_value),
                          (rewards, values, dones.astype(jnp.float32), discounts), reverse=True)
    return adv, adv + values


def gae_iterations(rewards, values, dones, valid, last_value, last_reward, last_iterations, last_done,
                   gamma: float, lam: float):
    """:func:`gae` of a rollout of world iterations (``[T, N]``; :data:`ROLLOUTS`' ``"iteration"``): ``valid[t]``
    says the episode was at a decision at iteration ``t`` (a step learned from), ``rewards[t]`` is iteration
    ``t``'s reward and ``dones[t]`` ends the episode after it. An SMDP step runs from a decision to the episode's
    next one: its reward is the sum of its iterations', its discount ``gamma`` to the power of their number, so
    each valid step's advantage is :func:`gae`'s of the same steps. The passes in flight at the rollout's end
    landed after it (:meth:`kx.sim.gym.KeepAway.land_batch`): ``last_reward``, ``last_iterations`` and
    ``last_done [N]`` are what that took, ``last_value`` the critic at the decision they landed at. Returns
    advantages and value targets ``[T, N]``, zero where not valid."""
    g = jnp.asarray(gamma, jnp.float32)

    def back(carry, x):
        next_adv, next_value, acc, tau, term = carry
        r, v, d, m = x
        # iteration t joins the step that follows it; an end at t cuts off what came after (the next episode's)
        acc = jnp.where(d, r, r + acc)
        tau = jnp.where(d, 1, tau + 1)
        term = d | term
        disc = g ** tau.astype(jnp.float32)
        live = 1.0 - term.astype(jnp.float32)
        delta = acc + disc * next_value * live - v
        adv = delta + disc * lam * live * next_adv
        keep = lambda new, old: jnp.where(m, new, old)  # noqa: E731
        carry = (keep(adv, next_adv), keep(v, next_value), keep(jnp.zeros_like(acc), acc),
                 keep(jnp.zeros_like(tau), tau), m.__invert__() & term)
        return carry, jnp.where(m, adv, 0.0)

    init = (jnp.zeros_like(last_value), last_value, last_reward, last_iterations.astype(jnp.int32),
            last_done.astype(bool))
    _, adv = jax.lax.scan(back, init, (rewards, values, dones.astype(bool), valid), reverse=True)
    return adv, jnp.where(valid, adv + values, 0.0)


def _mean(x, w):
    """The mean of ``x`` (over its entries weighted ``w``: 1 where valid, 0 where not; all of them if None)."""
    return x.mean() if w is None else (x * w).sum() / jnp.maximum(w.sum(), 1.0)


def loss(params, apply_fn, batch: Transition, advantages, targets, clip_eps: float, vf_coef: float,
         ent_coef: float):
    """PPO's loss of a minibatch: the clipped surrogate on normalised advantages, the clipped value loss,
    minus the entropy bonus. Returns ``(total, (policy, value, entropy))``."""
    logits, value = apply_fn(params, batch.obs)
    logp_all = jax.nn.log_softmax(logits)
    logp = jnp.take_along_axis(logp_all, batch.action[..., None], axis=-1)[..., 0]
    v_clipped = batch.value + jnp.clip(value - batch.value, -clip_eps, clip_eps)
    ratio = jnp.exp(logp - batch.log_prob)
    entropy_each = -(jnp.exp(logp_all) * logp_all).sum(-1)
    if batch.valid is None:
        value_loss = 0.5 * jnp.maximum((value - targets) ** 2, (v_clipped - targets) ** 2).mean()
        adv = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        policy_loss = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip_eps, 1 + clip_eps) * adv).mean()
        entropy = entropy_each.mean()
    else:  # only the steps at a decision count (the iteration rollout's flying episodes are padding)
        w = batch.valid.astype(jnp.float32)
        value_loss = 0.5 * _mean(jnp.maximum((value - targets) ** 2, (v_clipped - targets) ** 2), w)
        mu = _mean(advantages, w)
        adv = (advantages - mu) / (jnp.sqrt(_mean((advantages - mu) ** 2, w)) + 1e-8)
        policy_loss = -_mean(jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip_eps, 1 + clip_eps) * adv), w)
        entropy = _mean(entropy_each, w)
    return policy_loss + vf_coef * value_loss - ent_coef * entropy, (policy_loss, value_loss, entropy)


class Learner(NamedTuple):
    """PPO's whole state between two updates (a pytree of arrays: the run loop checkpoints it whole)."""

    params: Any  # the actor-critic's flax parameters
    opt_state: Any  # optax's state of the gradient clipping and Adam's moments
    env: Any  # the num_envs episodes being played, batch-last (gym.BatchState; with a mix, one a task)
    obs: Any  # their observations: [num_envs, 13], or the entity tokens (kx.sim.entities.batch_first)
    returns: jax.Array  # [num_envs] each episode's return so far
    updates: jax.Array  # int32: updates done
    decisions: jax.Array  # int32: SMDP steps played
    episodes: jax.Array  # int32: episodes ended
    blocks: jax.Array  # int32: blocks of episodes done (kx.train's generations)
    last_block: dict  # the last block's metrics (make_block; zeros before the first)


def optimiser(cfg: PPOConfig) -> optax.GradientTransformation:
    """Gradient clipping, then Adam's scaling; the learning rate is applied by :func:`make_update` (so that
    it can follow the run's progress in episodes as well as in updates)."""
    return optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.scale_by_adam(eps=1e-5))


def init(key: jax.Array, cfg: PPOConfig, env: gym.KeepAway, env_params: KeepAwayParams, params=None) -> Learner:
    """A fresh learner: the network's initial weights (or ``params``, e.g. a transfer source's), a fresh
    optimiser, ``num_envs`` new episodes."""
    k_init, k_reset = jax.random.split(key)
    obs, env_state = _reset(k_reset, cfg, env, env_params)
    if params is None:
        params = network(cfg).init(k_init, jax.tree.map(lambda a: a[0], obs))
    zero = jnp.zeros((), jnp.int32)
    return Learner(params=params, opt_state=optimiser(cfg).init(params), env=env_state, obs=obs,
                   returns=jnp.zeros((cfg.num_envs,), jnp.float32), updates=zero, decisions=zero, episodes=zero,
                   blocks=zero, last_block=_zero_metrics())


#: the metrics of one update (:func:`make_update`), summed over a block's updates by :func:`make_block`
UPDATE_METRICS = ("policy_loss", "value_loss", "entropy", "return_sum", "episodes", "shared_starts")
_INT_METRICS = ("episodes", "shared_starts", "updates")


def _zero_metrics() -> dict:
    """A block's metrics (:data:`UPDATE_METRICS` summed, and ``updates``) at zero."""
    return {k: jnp.zeros((), jnp.int32 if k in _INT_METRICS else jnp.float32) for k in (*UPDATE_METRICS, "updates")}


def make_rollout(cfg: PPOConfig, env: gym.KeepAway, env_params: KeepAwayParams):
    """``rollout(learner, key) -> ((learner, ended, return_sum, shared, iterations), traj)``: ``num_steps``
    SMDP steps of the ``num_envs`` episodes with the sampled policy (:class:`Transition` ``[T, N]``), the
    learner's episodes advanced, and what they did: episodes ended, the sum of their returns, episodes
    that shared a start, the world's iterations played."""
    net = network(cfg)

    iterating = cfg.rollout == "iteration"

    def env_step(carry, xs):
        learner, ended, return_sum, shared, iterations = carry
        k_env, u = xs
        logits, value = net.apply(learner.params, learner.obs)
        action = sample(logits, u)
        log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[..., None], axis=-1)[..., 0]
        valid = _deciding(env, learner.env) if iterating else None
        obs2, env_state, reward, done, info = _step(k_env, cfg, env, learner.env, action, env_params,
                                                    "iterate" if iterating else "step")
        returns = learner.returns + reward
        nxt = learner._replace(env=env_state, obs=obs2, returns=jnp.where(done, 0.0, returns))
        carry = (nxt, ended + done.sum(dtype=jnp.int32), return_sum + jnp.where(done, returns, 0.0).sum(),
                 shared + info["shared_starts"].astype(jnp.int32), iterations + info["iterations"].sum(dtype=jnp.int32))
        return carry, Transition(learner.obs, action, log_prob, value, reward, done, info["iterations"], valid)

    def rollout(learner, key):
        zero = jnp.zeros((), jnp.int32)
        k_env, k_act = jax.random.split(key)  # the actions' uniforms drawn at once: one call, not one a step
        return jax.lax.scan(env_step, (learner, zero, jnp.zeros((), jnp.float32), zero, zero),
                            (jax.random.split(k_env, cfg.num_steps),
                             jax.random.uniform(k_act, (cfg.num_steps, cfg.num_envs))))

    return rollout


def make_land(cfg: PPOConfig, env: gym.KeepAway, env_params: KeepAwayParams):
    """``land(learner, key) -> ((learner, ended, return_sum, shared, iterations), (reward, done, iterations))``: the
    passes in flight land (:meth:`kx.sim.gym.KeepAway.land_batch`), so that every episode is at a decision; what
    each episode's landing took (``[N]``) and what its episodes did, as :func:`make_rollout` counts them."""

    def land(learner, key):
        obs2, env_state, reward, done, info = _step(key, cfg, env, learner.env, None, env_params, "land")
        returns = learner.returns + reward
        nxt = learner._replace(env=env_state, obs=obs2, returns=jnp.where(done, 0.0, returns))
        counts = (nxt, done.sum(dtype=jnp.int32), jnp.where(done, returns, 0.0).sum(),
                  info["shared_starts"].astype(jnp.int32), info["iterations"].sum(dtype=jnp.int32))
        return counts, (reward, done, info["iterations"])

    return land


def make_update(cfg: PPOConfig, env: gym.KeepAway, env_params: KeepAwayParams, axis: str | None = None):
    """``update(learner, key, lr) -> (learner, metrics)``: one rollout of ``num_steps`` SMDP steps (or world
    iterations: :data:`ROLLOUTS`) of the ``num_envs`` episodes with the sampled policy, then ``update_epochs``
    passes of PPO's clipped loss over its decisions in ``num_minibatches`` shuffled minibatches (fewer with
    ``max_minibatches`` or ``learn_per_episode``), at learning rate ``lr``. ``metrics``: the losses and
    entropy (means over the minibatches), and of the rollout: the episodes that ended, the sum of their
    returns, the episodes that shared a start (:meth:`kx.sim.gym.KeepAway.step_batch`) and the world's
    iterations played.

    ``axis``: the name of a device axis the episodes are split over (:func:`make_block` with ``cfg.devices`` > 1;
    ``cfg`` then holds one device's share of them): each device plays and learns from its own episodes, a
    minibatch's gradient is the mean over the decisions of every device's minibatch (the devices' sums over
    their counts), the devices learn from as many minibatches as the fullest needs, and the counts are the sums
    over the devices, so that every device holds the same parameters and counters."""
    net = network(cfg)
    tx = optimiser(cfg)
    n_batch = cfg.num_envs * cfg.num_steps

    def total(x):
        return x if axis is None else jax.lax.psum(x, axis)

    def own(key):
        return key if axis is None else jax.random.fold_in(key, jax.lax.axis_index(axis))
    rollout = make_rollout(cfg, env, env_params)
    land = make_land(cfg, env, env_params)

    def update(learner: Learner, key: jax.Array, lr: jax.Array):
        k_roll, k_epochs = (own(k) for k in jax.random.split(key))
        (learner, ended, return_sum, shared, iterations), traj = rollout(learner, k_roll)
        if cfg.rollout == "iteration":
            (learner, e2, r2, s2, i2), (last_r, last_d, last_i) = land(learner, jax.random.fold_in(k_roll, 1))
            ended, return_sum, shared, iterations = ended + e2, return_sum + r2, shared + s2, iterations + i2
            _, last_value = net.apply(learner.params, learner.obs)
            adv, targets = gae_iterations(traj.reward * cfg.reward_scale, traj.value, traj.done, traj.valid,
                                          last_value, last_r * cfg.reward_scale, last_i, last_d, cfg.gamma,
                                          cfg.gae_lambda)
            decided = total(traj.valid.sum(dtype=jnp.int32))
        else:
            _, last_value = net.apply(learner.params, learner.obs)
            adv, targets = gae(traj.reward * cfg.reward_scale, traj.value, traj.done, last_value, cfg.gamma,
                               cfg.gae_lambda, traj.iterations)
            decided = total(jnp.int32(n_batch))
        ended, return_sum, shared, iterations = (total(x) for x in (ended, return_sum, shared, iterations))

        used = min(cfg.num_minibatches, cfg.max_minibatches or cfg.num_minibatches)

        def sgd_step(params, opt_state, b):
            t, a, tg = b
            grads, aux = jax.grad(loss, has_aux=True)(params, net.apply, t, a, tg, cfg.clip_eps, cfg.vf_coef,
                                                      cfg.ent_coef)
            if axis is not None:  # the mean over every device's decisions: each device's mean times its count,
                # summed in one collective (one a leaf cost about 50 us each on a CPU, 2.5x the update's time)
                n = jnp.float32(a.size) if t.valid is None else t.valid.sum(dtype=jnp.float32)
                flat, unravel = jax.flatten_util.ravel_pytree(grads)
                sums = total(jnp.concatenate([flat * n, jnp.stack(aux) * n, n[None]]))
                whole = jnp.maximum(sums[-1], 1.0)
                grads = unravel(sums[:flat.size] / whole)
                aux = tuple(sums[flat.size:-1] / whole)
            step, opt_state = tx.update(grads, opt_state, params)
            return jax.tree.map(lambda p, u: p - lr * u, params, step), opt_state, jnp.stack(aux)

        def epoch(carry, k):
            params, opt_state = carry
            perm = jax.random.permutation(k, n_batch)
            flat = jax.tree.map(lambda a: a.reshape((n_batch,) + a.shape[2:])[perm], (traj, adv, targets))
            mb = jax.tree.map(lambda a: a.reshape((cfg.num_minibatches, -1) + a.shape[1:])[:used], flat)

            def minibatch(carry, b):
                params, opt_state, aux = sgd_step(*carry, b)
                return (params, opt_state), aux

            (params, opt_state), aux = jax.lax.scan(minibatch, (params, opt_state), mb)
            return (params, opt_state), (aux.sum(0), jnp.int32(used))

        def learn_decisions(params, opt_state, key):
            """An iteration rollout's learning: its valid steps in a random order, in as many minibatches of
            ``n_batch / num_minibatches`` entries as they fill (the last one's rest padding; fewer with
            ``max_minibatches`` or ``learn_per_episode``), the flying episodes' entries never computed; each
            epoch passes over those minibatches in an order of its own."""
            k_order, k_epochs = jax.random.split(key)
            flat_valid = traj.valid.reshape(n_batch)
            order = jnp.argsort(jnp.where(flat_valid, jax.random.uniform(k_order, (n_batch,)), 2.0))
            flat = jax.tree.map(lambda a: a.reshape((n_batch,) + a.shape[2:])[order], (traj, adv, targets))
            mb = jax.tree.map(lambda a: a.reshape((cfg.num_minibatches, -1) + a.shape[1:]), flat)
            size = n_batch // cfg.num_minibatches
            count = jnp.minimum((flat_valid.sum(dtype=jnp.int32) + size - 1) // size, used)
            if cfg.learn_per_episode:  # (ended: every device's; a device's share of it, rounded up)
                share = ended if axis is None else -(-ended // jax.lax.psum(1, axis))
                count = jnp.minimum(count, jnp.maximum((share * cfg.learn_per_episode + size - 1) // size, 1))
            if axis is not None:  # every device the same number of steps: as many as the fullest needs
                count = jax.lax.pmax(count, axis)

            def epoch(carry, k):
                params, opt_state, sums = carry
                slots = jnp.arange(cfg.num_minibatches)
                visit = jnp.argsort(jnp.where(slots < count, jax.random.uniform(k, slots.shape), 2.0))

                def body(i, c):
                    params, opt_state, sums = c
                    params, opt_state, aux = sgd_step(params, opt_state, jax.tree.map(lambda a: a[visit[i]], mb))
                    return params, opt_state, sums + aux

                return jax.lax.fori_loop(0, count, body, (params, opt_state, sums)), None

            (params, opt_state, sums), _ = jax.lax.scan(epoch, (params, opt_state, jnp.zeros(3)),
                                                        jax.random.split(k_epochs, cfg.update_epochs))
            return (params, opt_state), (sums[None], (count * cfg.update_epochs)[None])

        if cfg.rollout == "iteration":
            (params, opt_state), (sums, counts) = learn_decisions(learner.params, learner.opt_state, k_epochs)
        else:
            (params, opt_state), (sums, counts) = jax.lax.scan(epoch, (learner.params, learner.opt_state),
                                                               jax.random.split(k_epochs, cfg.update_epochs))
        aux = sums.sum(0) / jnp.maximum(counts.sum(), 1).astype(jnp.float32)
        learner = learner._replace(params=params, opt_state=opt_state, updates=learner.updates + 1,
                                   decisions=learner.decisions + decided, episodes=learner.episodes + ended)
        metrics = {"policy_loss": aux[0], "value_loss": aux[1], "entropy": aux[2],
                   "return_sum": return_sum, "episodes": ended, "shared_starts": shared, "iterations": iterations}
        return learner, metrics

    return update


def learning_rate(cfg: PPOConfig, progress) -> jax.Array:
    """The learning rate at ``progress`` (the share of the training done, in [0, 1])."""
    progress = jnp.clip(jnp.asarray(progress, jnp.float32), 0.0, 1.0)
    return jnp.float32(cfg.lr) * (1.0 - progress) if cfg.anneal_lr else jnp.float32(cfg.lr)


def make_train(cfg: PPOConfig, env: gym.KeepAway, env_params: KeepAwayParams):
    """``train(key) -> (learner, metrics)``: ``cfg.updates`` PPO updates from a fresh learner, the learning
    rate annealed over them; one program of a key: jit it, vmap it over keys (seeds)."""
    update = make_update(cfg, env, env_params)

    def train(key):
        k_init, k_run = jax.random.split(key)
        learner = init(k_init, cfg, env, env_params)

        def body(learner, xs):
            u, k = xs
            return update(learner, k, learning_rate(cfg, u / cfg.updates))

        return jax.lax.scan(body, learner, (jnp.arange(cfg.updates), jax.random.split(k_run, cfg.updates)))

    return train


def make_block(cfg: PPOConfig, env: gym.KeepAway, env_params: KeepAwayParams, block: int, anneal_episodes: int):
    """``block(learner, key) -> (learner, metrics)``: updates until the learner has ended
    ``(learner.blocks + 1) * block`` episodes in all (the last update may end a few more, which count
    toward the next block; when the previous block's last update ended this block's episodes already, the
    block runs no update). The learning rate falls linearly from ``cfg.lr`` to 0 over the first
    ``anneal_episodes`` episodes (0: constant). ``metrics`` (also the learner's ``last_block``):
    :data:`UPDATE_METRICS` summed over the block's updates, and ``updates``.

    With ``cfg.devices`` > 1 the block runs data-parallel over the process's first ``devices`` devices
    (``jax.shard_map``): the learner's episodes (its environment states, observations and returns) are split
    over them, its parameters, optimiser state and counters held whole by each, and every update is
    :func:`make_update`'s over a device axis."""
    if cfg.devices == 1:
        return _block(cfg, make_update(cfg, env, env_params), anneal_episodes, block)
    from jax.sharding import PartitionSpec

    from kx.sim import lanes

    local = dataclasses.replace(cfg, num_envs=cfg.num_envs // cfg.devices, resets=cfg.resets // cfg.devices,
                                devices=1)
    run = _block(cfg, make_update(local, env, env_params, axis="lanes"), anneal_episodes, block)
    whole = PartitionSpec()

    def sharded(learner: Learner, key: jax.Array):
        split = learner._replace(
            params=whole, opt_state=whole, updates=whole, decisions=whole, episodes=whole, blocks=whole,
            last_block=whole, returns=PartitionSpec("lanes"), env=lanes.lane_specs(learner.env),
            obs=jax.tree.map(lambda a: PartitionSpec("lanes"), learner.obs))  # obs batch-first, env batch-last
        return jax.shard_map(run, mesh=lanes.mesh(cfg.devices), in_specs=(split, whole), out_specs=(split, whole),
                             check_vma=False)(learner, key)

    return sharded


def place(learner: Learner, cfg: PPOConfig) -> Learner:
    """``learner`` laid out as :func:`make_block` runs it with ``cfg.devices`` > 1 (its episodes split over the
    devices, the rest whole on each), so that a block's program compiles for one layout; as it is with one."""
    if cfg.devices == 1:
        return learner
    from jax.sharding import NamedSharding, PartitionSpec

    from kx.sim import lanes

    mesh = lanes.mesh(cfg.devices)
    whole = NamedSharding(mesh, PartitionSpec())
    specs = jax.tree.map(lambda _: whole, learner)
    specs = specs._replace(returns=NamedSharding(mesh, PartitionSpec("lanes")),
                           env=jax.tree.map(lambda p: NamedSharding(mesh, p), lanes.lane_specs(learner.env)),
                           obs=jax.tree.map(lambda a: NamedSharding(mesh, PartitionSpec("lanes")), learner.obs))
    return jax.device_put(learner, specs)


def _block(cfg: PPOConfig, update, anneal_episodes: int, block: int):
    """:func:`make_block`'s loop of ``update``s."""

    def lr_at(episodes):
        if anneal_episodes <= 0:
            return jnp.float32(cfg.lr)
        return learning_rate(dataclasses.replace(cfg, anneal_lr=True), episodes / anneal_episodes)

    def run(learner: Learner, key: jax.Array):
        target = (learner.blocks + 1) * block
        zero = {k: v for k, v in _zero_metrics().items() if k != "updates"}

        def body(carry):
            learner, sums, n, key = carry
            key, k = jax.random.split(key)
            learner, m = update(learner, k, lr_at(learner.episodes))
            return learner, {k_: sums[k_] + m[k_] for k_ in UPDATE_METRICS}, n + 1, key

        learner, sums, n, _ = jax.lax.while_loop(lambda c: c[0].episodes < target, body,
                                                 (learner, zero, jnp.zeros((), jnp.int32), key))
        metrics = dict(sums, updates=n)
        return learner._replace(blocks=learner.blocks + 1, last_block=metrics), metrics

    return run


def greedy(params, obs, hidden: int = 64, cfg: PPOConfig | None = None):
    """The network's decision when evaluated: the argmax of its logits (``cfg``'s network; default the MLP of
    ``hidden`` units)."""
    logits, _ = (network(cfg) if cfg is not None else ActorCritic(hidden=hidden)).apply(params, obs)
    return jnp.argmax(logits, axis=-1)
