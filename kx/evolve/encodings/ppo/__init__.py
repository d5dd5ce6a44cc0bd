"""PPO as a method of the run loop: ``method = "ppo"``, a gradient-based baseline in the same world and
with the same budget of episodes as NEAT.

The learner is :mod:`.algorithm` (flax actor-critic on NEAT's fixed layout, optax, the clipped objective with
GAE over SMDP steps of the keep-away environment, :mod:`kx.sim.gym`). The run loop sees a *population of
one*: each generation ``ask`` trains the network on ``ppo.episodes_per_generation`` new episodes of the
sampled policy (4500 by default: NEAT's 150 genomes x 30 trials, so that metrics rows of the two line up
generation by generation) and hands the run loop its new weights, which play the generation's ``trials``
training start states greedily (the argmax of the actor's logits, as NEAT's networks decide) for the
generation's training fitness, and, as every method's generation champion, the validation states
(``tell`` has nothing to select). Generation ``g`` plays the weights after ``g + 1`` blocks: the last
block is measured, the untrained network is not. The learning rate falls linearly to 0 over
``ppo.anneal_episodes`` episodes (the configs set it to ``generations x episodes_per_generation``; a
field of its own, so that a run resumed for more generations computes what it computed). The greedy
episodes on training and validation states are not learned from (NEAT's validation episodes are not
either); :meth:`PPOEncoding.episodes_per_generation` counts the training episodes. The run's champion
is, as for every method, the generation's weights that validated best.

A transferred run starts from the source's weights (``transfer.seeding = "population"``: the network the
source's training ended with; ``"champion"``: its validated champion), with a fresh optimiser and new
episodes: the 13/3 layout is the same in every task.

Config section ``ppo``: the :class:`.algorithm.PPOConfig` fields (but ``updates``, which the budget in
episodes decides, and ``anneal_lr``), ``episodes_per_generation`` and ``anneal_episodes``.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np

from kx.evolve.encoding import Encoding
from kx.evolve.encodings.ppo import algorithm as ppo
from kx.evolve.errors import ConfigError, is_int, is_number, need
from kx.sim import entities, observe
from kx.sim.policies import Policy
from kx.sim.types import KeepAwayConfig, KeepAwayError, KeepAwayParams

#: the config fields of ``ppo``: PPOConfig's but ``updates`` and ``anneal_lr`` (the encoding's own fields beside), and
#: but the entity network's (this method trains the fixed layout's MLP)
FIELDS = tuple(f.name for f in dataclasses.fields(ppo.PPOConfig)
               if f.name not in ("updates", "anneal_lr", "network", "heads", "blocks", "mix"))  # the MLP's


@functools.lru_cache(maxsize=None)
def greedy_policy(sim: KeepAwayConfig, hidden: int) -> Policy:
    """The actor's greedy decision as a shared-table policy of the evaluator: ``params.table`` the flax
    parameters of G networks (leading axis G), ``params.index [*B]`` each lane's. With one network (a run's
    generation, its champion) every lane applies it; with several (a batched group's runs) each lane
    gathers its own. Either way a lane's logits are the same elementwise sums
    (:func:`.algorithm.actor_logits_batch_last`), so that a run's evaluation in a group is bit for bit its
    evaluation alone."""

    def apply(params, state, key):
        x = observe.fixed_obs(state, sim)  # [13, *B]
        g = jax.tree.leaves(params.table)[0].shape[0]
        if g == 1:
            net = jax.tree.map(lambda a: a[0], params.table)
        else:
            nd = params.index.ndim
            net = jax.tree.map(lambda a: jnp.moveaxis(a[params.index], tuple(range(nd)), tuple(range(-nd, 0))),
                               params.table)
        return observe.decode_ranked(ppo.actor_logits_batch_last(net, x), state, sim)

    return Policy(f"ppo-h{hidden}", apply, shared=True)


@functools.lru_cache(maxsize=None)
def entity_policy(sim: KeepAwayConfig, cfg: ppo.PPOConfig) -> Policy:
    """The entity network's greedy decision (:class:`.algorithm.EntityActorCritic`) as a shared-table policy of the
    evaluator: ``params.table`` the flax parameters of G networks (leading axis G), ``params.index [*B]`` each
    lane's. Every lane applies its own row of the table to its own tokens, alone (the network vmapped over the
    lanes), so that a run's evaluation in a batched group is bit for bit its evaluation alone; the argmax of its
    logits is hold or a pass to a teammate (:func:`kx.sim.entities.keeper_of`)."""
    net = ppo.network(cfg)

    def apply(params, state, key):
        lanes = state.holder.shape
        n = math.prod(lanes)
        tok = entities.tokens(state, sim)
        flat = {k: jnp.moveaxis(v.reshape(v.shape[:v.ndim - len(lanes)] + (n,)), -1, 0) for k, v in tok.items()}
        own = jax.tree.map(lambda a: a[params.index.reshape(n)], params.table)
        logits, _ = jax.vmap(net.apply)(own, flat)
        return entities.keeper_of(jnp.argmax(logits, axis=-1).reshape(lanes), state, sim)

    return Policy(f"ppo-entity-h{cfg.hidden}-a{cfg.heads}x{cfg.blocks}", apply, shared=True)


@functools.lru_cache(maxsize=None)
def _block_program(cfg: ppo.PPOConfig, sim: KeepAwayConfig, sim_params: KeepAwayParams, block: int, anneal: int):
    """The jitted block of updates of one shape, shared by the runs of a process."""
    return jax.jit(ppo.make_block(cfg, ppo.environment(cfg, sim), sim_params, block, anneal))


@functools.lru_cache(maxsize=None)
def _init_program(cfg: ppo.PPOConfig, sim: KeepAwayConfig, sim_params: KeepAwayParams):
    return jax.jit(lambda key, params: ppo.init(key, cfg, ppo.environment(cfg, sim), sim_params, params))


def _steps(c: ppo.PPOConfig) -> str:
    """What a rollout's ``num_steps`` count (:data:`.algorithm.ROLLOUTS`)."""
    return "world iterations" if c.rollout == "iteration" else "SMDP steps"


#: the shape of the shipped PPO configs (``ppo`` and ``ppo_entity``, every task): 512 episodes stepped one world
#: iteration at a time, 16 a rollout, the episodes at a decision acting and learned from, 2 epochs of 16 minibatches,
#: 2 x 32 units. Over 10 seeds of 3v2 its validated champions score 0.778 on Table 3's test states (docs/zeroshot)
#: at about half the wall time of the SMDP shape of PPOConfig's defaults (64 episodes x 64 SMDP steps, 4 epochs of 4
#: minibatches, 2 x 64 units; ``configs/ppo_3v2_smdp.py``): docs/benchmarks.md, "Levers for PPO's wall time"
PROTOCOL_SHAPE = {"rollout": "iteration", "num_envs": 512, "num_steps": 16, "resets": 32, "hidden": 32,
                  "update_epochs": 2, "num_minibatches": 16}

_as_population = jax.jit(lambda params: jax.tree.map(lambda a: a[None], params))


class PPOEncoding(Encoding):
    name = "ppo"
    section = "ppo"
    layouts = ("fixed",)
    population_sizes = (1, 1)
    # tell and the policy's parameters are copies; a batched group runs each run's block of updates (ask) alone
    vmap_exact = frozenset({"tell", "policy_params"})
    metric_fields = ("train_episodes", "train_return", "updates", "policy_loss", "value_loss", "entropy",
                     "shared_starts")
    plot_field = "train_return"

    @classmethod
    def default_config(cls) -> ml_collections.ConfigDict:
        d = ppo.PPOConfig()
        c = {f: getattr(d, f) for f in FIELDS}
        c.update(PROTOCOL_SHAPE)
        c["episodes_per_generation"] = 4500  # NEAT's 150 genomes x 30 trials
        c["anneal_episodes"] = 20 * 4500  # the learning rate falls to 0 over these (0: constant); set it with
        # generations (a field of its own, so that a run resumed for more generations computes what it did)
        return ml_collections.ConfigDict(c)

    @classmethod
    def defaults(cls) -> dict:
        return {"population_size": 1}

    #: the fields of the config section, and the network they build (``PPOConfig.network``)
    fields: tuple[str, ...] = FIELDS
    network = "mlp"

    def __init__(self, cfg, sim, sim_params):
        super().__init__(cfg, sim, sim_params)
        c = cfg[self.section]
        s = self.section
        need(cfg.objective == "fitness", "objective", f"'fitness' for method '{self.name}' (it learns from the "
             "episodes' rewards; a novelty score needs a population)", cfg.objective)
        for f in ("num_envs", "num_steps", "update_epochs", "num_minibatches", "hidden", "resets"):
            need(is_int(c[f]) and 1 <= c[f] <= 1_000_000, f"{s}.{f}", "an integer in [1, 1000000]", c[f])
        for f in ("gamma", "gae_lambda"):
            need(is_number(c[f]) and 0.0 <= c[f] <= 1.0, f"{s}.{f}", "a number in [0, 1]", c[f])
        for f in ("clip_eps", "lr", "max_grad_norm", "reward_scale"):
            need(is_number(c[f]) and c[f] > 0, f"{s}.{f}", "a number > 0", c[f])
        for f in ("ent_coef", "vf_coef"):
            need(is_number(c[f]) and c[f] >= 0, f"{s}.{f}", "a number >= 0", c[f])
        need(is_int(c.anneal_episodes) and c.anneal_episodes >= 0, f"{s}.anneal_episodes",
             "an integer >= 0 (0: a constant learning rate)", c.anneal_episodes)
        need(is_int(c.episodes_per_generation) and c.episodes_per_generation >= 1, f"{s}.episodes_per_generation",
             "an integer >= 1", c.episodes_per_generation)
        need((c.num_envs * c.num_steps) % c.num_minibatches == 0, f"{s}.num_minibatches",
             f"a divisor of num_envs x num_steps = {c.num_envs * c.num_steps}", c.num_minibatches)
        need(c.resets <= c.num_envs, f"{s}.resets", f"an integer in [1, num_envs = {c.num_envs}]", c.resets)
        for f in ("max_minibatches", "learn_per_episode"):
            need(is_int(c[f]) and 0 <= c[f] <= 1_000_000, f"{s}.{f}", "an integer in [0, 1000000] (0: no limit)", c[f])
        need(isinstance(c.rollout, str), f"{s}.rollout", f"one of {', '.join(ppo.ROLLOUTS)}", c.rollout)
        n_dev = jax.local_device_count()
        need(is_int(c.devices) and 1 <= c.devices <= n_dev, f"{s}.devices",
             f"an integer in [1, {n_dev}] (this process's devices)", c.devices)
        mix = self._mix(c, sim)
        try:
            self.ppo = ppo.PPOConfig(network=self.network, mix=mix, **{
                f: (float(c[f]) if isinstance(getattr(ppo.PPOConfig, f), float) else c[f]) for f in self.fields})
        except ValueError as e:  # the entity network's heads, blocks and mix
            raise ConfigError(f"{s}.{e}") from None
        self.block = int(c.episodes_per_generation)
        self.anneal = int(c.anneal_episodes)

    def _mix(self, c, sim) -> tuple[str, ...]:
        """The other tasks whose episodes join every batch (the entity network's ``mix``; none for the MLP)."""
        return ()

    @classmethod
    def episodes_per_generation(cls, cfg) -> int:
        """The training episodes of a generation (``ppo.episodes_per_generation``); the greedy ones on the
        generation's training and validation states are not learned from."""
        return int(cfg[cls.section].episodes_per_generation)

    def init(self, key):
        return _init_program(self.ppo, self.sim, self.sim_params)(key, None)

    def ask(self, key, state):
        """Trains a block of ``episodes_per_generation`` episodes, then hands the run loop the network's new
        weights (a population of one): generation ``g`` plays the weights after ``g + 1`` blocks, so the
        last block is measured too, and the untrained network never is."""
        state = ppo.place(state, self.ppo)  # (a no-op once placed: a block's output is laid out as its input)
        state, _ = _block_program(self.ppo, self.sim, self.sim_params, self.block, self.anneal)(state, key)
        return _as_population(state.params), state

    def placeholder(self, key, learner):
        return learner.params  # the shape of a champion, without training a block

    def tell(self, key, population, score, fitness, state):
        """Nothing to select (``ask`` trained): the metrics of the block ``ask`` trained."""
        m = state.last_block
        n = jnp.maximum(m["updates"], 1).astype(jnp.float32)
        # no episode ended in a block with no update (the previous block's last update ended its episodes)
        ret = jnp.where(m["episodes"] > 0, m["return_sum"] / jnp.maximum(m["episodes"], 1), jnp.nan)
        return state, {"train_episodes": m["episodes"], "train_return": ret, "updates": m["updates"],
                       "policy_loss": m["policy_loss"] / n, "value_loss": m["value_loss"] / n,
                       "entropy": m["entropy"] / n, "shared_starts": m["shared_starts"]}

    def policy_for(self, sim):
        return greedy_policy(sim, self.ppo.hidden)

    def transfer_problems(self, source, state, seeding):
        out = []
        if seeding == "half":
            out.append("seeding 'half': PPO carries one network, not a population; allowed 'population' (the "
                       "weights the source's training ended with) or 'champion' (its validated champion)")
        for f in ("hidden", "heads", "blocks"):
            if getattr(source.ppo, f) != getattr(self.ppo, f):
                out.append(f"the source's network has {f} {getattr(source.ppo, f)} ({self.section}.{f}), this "
                           f"run's {getattr(self.ppo, f)}: they do not fit")
        if source.ppo.network != self.ppo.network:
            out.append(f"the source trained the {source.ppo.network} network, this run the {self.ppo.network} one")
        return out

    def transfer(self, key, source, state, seeding, order):
        """A fresh learner (optimiser, episodes) whose network starts from the source's weights."""
        params = state.learner.params if seeding == "population" else state.champion
        return _init_program(self.ppo, self.sim, self.sim_params)(key, params)

    def check(self, state, champion):
        errs = []
        for name, tree in (("weights", state.params), ("optimiser state", state.opt_state)):
            if not all(np.all(np.isfinite(np.asarray(a))) for a in jax.tree.leaves(tree)):
                errs.append(f"PPO {name} hold non-finite values")
        if champion is not None and not all(np.all(np.isfinite(np.asarray(a))) for a in jax.tree.leaves(champion)):
            errs.append("champion: non-finite weights")
        return errs

    def describe(self) -> str:
        c = self.ppo
        return (f"ppo (fixed layout: 13 inputs, 3 actions; actor and critic of 2 x {c.hidden} tanh units; "
                f"{c.num_envs} episodes x {c.num_steps} {_steps(c)} an update; {self.block} training episodes a "
                f"generation)")

    def progress(self, row) -> str:
        return f"train return {float(row['train_return']):.3f}, {int(row['updates'])} updates"



class EntityEncoding(PPOEncoding):
    """``method = "ppo_entity"``: PPO on the size-invariant entity network (:class:`.algorithm.EntityActorCritic`: the
    holder's view as tokens, self-attention over them, a hold logit and one pass logit per teammate), through the
    same run loop, budget and metrics as ``ppo``. Its weights fit every task, so a run transfers to any team size
    and its champion plays any task unchanged. Config section ``ppo_entity``: ``ppo``'s fields and the network's
    ``heads`` (attention heads, a divisor of ``hidden``), ``blocks`` (attention blocks) and ``mix``: other tasks,
    comma-separated (``"4v3"``, ``"4v3,5v3"``; empty: none), whose episodes share every batch with the run's own
    task, ``num_envs`` and ``resets`` split evenly among them (:func:`.algorithm.mixed_tokens`). The run's training
    budget counts the episodes of every task; its generations are played and validated in its own task."""

    name = "ppo_entity"
    section = "ppo_entity"
    fields = FIELDS + ("heads", "blocks")
    network = "entity"

    @classmethod
    def default_config(cls) -> ml_collections.ConfigDict:
        c = PPOEncoding.default_config()
        d = ppo.PPOConfig()
        c.heads, c.blocks, c.mix = d.heads, d.blocks, ""
        return c

    def _mix(self, c, sim) -> tuple[str, ...]:
        need(isinstance(c.mix, str), f"{self.section}.mix", "task names, comma-separated ('4v3,5v3'), or ''", c.mix)
        tasks = tuple(t.strip() for t in c.mix.split(",") if t.strip())
        for t in tasks:
            try:
                other = KeepAwayConfig.from_task(t, field_size=sim.field_size, agent_speed=sim.agent_speed,
                                                 ball_speed=sim.ball_speed, n_chasers=sim.n_chasers)
            except KeepAwayError as e:
                raise ConfigError(f"{self.section}.mix: {t!r} is not a task of this world ({e})") from None
            need(other != sim and tasks.count(t) == 1, f"{self.section}.mix",
                 f"tasks other than the run's own ({sim.name}), each once", c.mix)
        return tasks

    def __init__(self, cfg, sim, sim_params):
        c = cfg[self.section]
        for f in ("heads", "blocks"):
            need(is_int(c[f]) and 1 <= c[f] <= 64, f"{self.section}.{f}", "an integer in [1, 64]", c[f])
        super().__init__(cfg, sim, sim_params)

    def policy_for(self, sim):
        return entity_policy(sim, self.ppo)

    def describe(self) -> str:
        c = self.ppo
        mix = f", with {', '.join(c.mix)} episodes in every batch" if c.mix else ""
        return (f"ppo_entity (entity tokens of the holder, {self.sim.n_keepers - 1} teammates and "
                f"{self.sim.n_takers} takers; {c.blocks} self-attention block(s) of {c.heads} heads, {c.hidden} "
                f"units; a hold logit and a pass logit per teammate; {c.num_envs} episodes x {c.num_steps} "
                f"{_steps(c)} an update{mix}; {self.block} training episodes a generation)")
