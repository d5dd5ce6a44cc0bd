"""Keep-away as a gymnax-style environment: one episode, functional, vmapped at the call site.

    env = KeepAway(KeepAwayConfig(n_keepers=4, n_takers=3))   # any task (4v3 here)
    params = env.default_params                    # optional, as in gymnax
    obs, state = env.reset(key, params)            # obs [13]
    obs, state, reward, done, info = env.step(key, state, action, params)
    env.action_space(params), env.observation_space(params)   # Discrete(3), Box(0, 1, (13,))

gymnax's interface (its ``Environment``: ``reset``, ``step`` with auto-reset, ``step_env``, ``default_params``,
``name``, ``num_actions``, ``action_space``, ``observation_space``, ``discount``; gymnax's own spaces where gymnax
is installed, objects with the same fields otherwise), so a script written for gymnax runs on it unchanged.
``step`` returns gymnax's five values ``(obs, state, reward, done, info)``; ``info["terminated"]`` (the ball
lost) and ``info["truncated"]`` (``max_iterations`` reached with the ball kept: not a loss) tell the two ends
apart, for a client that bootstraps through a time limit. **An SMDP caveat:** a step spans a variable number of
world iterations (``info["iterations"]``: one while the holder holds, the pass's flight after a kick), and
kx's learners discount a step by ``gamma ** info["iterations"]``; a generic script that discounts each step by
``gamma`` optimises another objective, which favours passing (a pass's flight is discounted as one step).

The agent is the keeper with the ball, as in RoboCup keep-away, where only the holder's choice is
learned: its actions are those of NEAT's fixed layout, ``0`` hold, ``1`` pass to the nearest teammate,
``2`` to the second nearest (:func:`kx.sim.observe.decode_ranked`'s order); the other keepers and the
takers follow the world's own behaviours. A step is an SMDP step (Stone, Sutton and Kuhlmann 2005): the
holder's decision, then the world's iterations until the next decision (a keeper holds the ball again)
or the episode's end, its reward the share of the episode's ``max_iterations`` survived in between, so
that an episode's return is its fitness (:func:`kx.sim.env.episode_stats`). The observation is the
fixed layout's 13 inputs in every task (:func:`kx.sim.observe.fixed_obs`).

The rules are the simulator's (:func:`kx.sim.env.transition`), and so is the kick noise: a hash of the
episode's noise word, drawn at reset, and the iteration (:func:`kx.sim.env.kick_noise`), as the evaluator
plays it; ``step``'s key is not read (an episode is the same however its steps are batched). ``step``
starts a new episode once one ends (gymnax's convention, with ``reset``'s key); ``step_env`` leaves a
finished episode as it is.

**Many episodes at once, fast.** vmapped, the per-episode functions put the batch first, and the world's
code, written batch-last (:mod:`kx.sim.env`), then costs far more per episode; and a vmapped SMDP step
runs every episode's iterations until the slowest one reaches its decision. :meth:`KeepAway.reset_batch`
and :meth:`KeepAway.step_batch` play ``n`` episodes batch-last with the same rules (a test steps both with
the same decisions and gets the same worlds): each episode iterates until its own next decision, the
others wait, unchanged (``python -m kx.bench ppo``: an SMDP step of 1024 4v3 episodes holding the ball,
10.1 us an episode vmapped against 0.78 us batched, 2026-12-03). A start state costs about 50-100
iterations (the k largest of uniform scores over the field's cells, :func:`kx.sim.ops.top_k_first`: 9 us with
``lax.top_k``, 15 us with the selection that orders ties alike on every backend, 4v3, 2026-12-06, a shared
2-core machine), so ``step_batch`` draws ``resets``
start states per step rather than one per episode (Craftax's "optimistic resets", Matthews et al. 2024):
the episodes that end in a step take them in order, each with a noise word of its own; should more end
in one step than there are starts, the later ones share the earlier ones' starts
(``info["shared_starts"]`` counts them).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from kx.sim import entities, env, observe
from kx.sim.ops import pick
from kx.sim.types import KeepAwayConfig, KeepAwayParams, Reason, State

N_ACTIONS = 3  # hold, pass to the nearest teammate, to the second nearest (the fixed layout's outputs)


try:  # gymnax's own spaces where gymnax is installed; otherwise objects with the same fields and methods
    from gymnax.environments.spaces import Box, Discrete
except ImportError:  # pragma: no cover - exercised where gymnax is absent (it is not a dependency of kx)

    class Discrete:
        """gymnax's ``spaces.Discrete``: the integers ``0 .. num_categories - 1``."""

        def __init__(self, num_categories: int):
            self.num_categories = self.n = int(num_categories)
            self.shape = ()
            self.dtype = jnp.int32

        def sample(self, rng: jax.Array) -> jax.Array:
            return jax.random.randint(rng, self.shape, 0, self.n).astype(self.dtype)

        def contains(self, x) -> jax.Array:
            return jnp.logical_and(x >= 0, x < self.n)

    class Box:
        """gymnax's ``spaces.Box``: arrays of ``shape`` between ``low`` and ``high``."""

        def __init__(self, low, high, shape: tuple, dtype=jnp.float32):
            self.low, self.high, self.shape, self.dtype = low, high, tuple(shape), dtype

        def sample(self, rng: jax.Array) -> jax.Array:
            return jax.random.uniform(rng, self.shape, minval=self.low, maxval=self.high).astype(self.dtype)

        def contains(self, x) -> jax.Array:
            return jnp.logical_and(jnp.all(x >= self.low), jnp.all(x <= self.high))


@struct.dataclass
class EnvState:
    world: State
    noise_word: jax.Array  # uint32: the episode's kick noise (kx.sim.env.kick_noise)


OBSERVATIONS = ("fixed", "entities")


class KeepAway:
    """The keep-away world of one task (``config``) as a gymnax-style environment.

    ``observation``: ``"fixed"``, the fixed layout's 13 inputs and its 3 actions (hold, pass to the nearest
    teammate, to the second nearest), the same in every task; or ``"entities"``, the holder's view as tokens
    (:func:`kx.sim.entities.tokens`: a dict of the holder's, each teammate's and each taker's features) and ``K``
    actions (hold, pass to teammate slot ``a - 1``: :func:`kx.sim.entities.keeper_of`), whose sizes follow the
    task."""

    def __init__(self, config: KeepAwayConfig, observation: str = "fixed"):
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation: allowed {', '.join(OBSERVATIONS)}, got {observation!r}")
        self.config = config  # at least 3 keepers (KeepAwayConfig's own check): every action has its keeper
        self.kind = observation

    @property
    def default_params(self) -> KeepAwayParams:
        return KeepAwayParams()

    @property
    def name(self) -> str:
        return f"KeepAway-{self.config.name}"

    def action_space(self, params: KeepAwayParams | None = None) -> "Discrete":
        """gymnax's ``action_space``: ``num_actions`` discrete actions."""
        return Discrete(self.num_actions)

    def observation_space(self, params: KeepAwayParams | None = None) -> "Box":
        """gymnax's ``observation_space``: the fixed layout's 13 inputs, each in [0, 1] (distances over the
        field's diagonal, angles over pi). The entity observation is a dict of tokens whose sizes follow the
        task: it has no single box."""
        if self.kind != "fixed":
            raise ValueError("observation_space: the entity observation is a dict of tokens (kx.sim.entities)")
        return Box(0.0, 1.0, (self.observation_size,), jnp.float32)

    def discount(self, state: EnvState, params: KeepAwayParams | None = None) -> jax.Array:
        """gymnax's ``discount``: 0 once the episode has ended, else 1. A step spans ``info["iterations"]``
        iterations of the world: discount it by ``gamma ** info["iterations"]`` to learn kx's objective."""
        return jnp.where(state.world.done, 0.0, 1.0)

    @property
    def num_actions(self) -> int:
        return N_ACTIONS if self.kind == "fixed" else entities.n_actions(self.config)

    @property
    def observation_size(self) -> int:
        if self.kind != "fixed":
            raise ValueError("observation_size: the entity observation is a dict of tokens (kx.sim.entities)")
        return observe.n_inputs("fixed", self.config)

    def observation(self, state: EnvState):
        if self.kind == "entities":
            return entities.tokens(state.world, self.config)
        return observe.fixed_obs(state.world, self.config)

    def reset(self, key: jax.Array, params: KeepAwayParams | None = None) -> tuple[jax.Array, EnvState]:
        params = self.default_params if params is None else params
        k_start, k_noise = jax.random.split(key)
        world = env.reset(k_start, params, self.config)
        state = EnvState(world=world, noise_word=jax.random.bits(k_noise, (), jnp.uint32))
        return self.observation(state), state

    def keeper_of(self, state: EnvState, action: jax.Array) -> jax.Array:
        """The keeper an action sends the ball to (the holder's own index: hold)."""
        return self._keeper(state.world, action)

    def _keeper(self, world: State, action: jax.Array) -> jax.Array:
        if self.kind == "entities":
            return entities.keeper_of(action, world, self.config)
        order = observe.teammate_order(world, self.config)
        return pick(order, jnp.clip(action, 0, N_ACTIONS - 1).astype(jnp.int32))

    def step_env(self, key: jax.Array, state: EnvState, action: jax.Array,
                 params: KeepAwayParams | None = None) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict]:
        """The holder's decision ``action``, then the world until the next decision or the end. ``info``:
        ``iterations`` (the world's iterations the step spanned), ``terminated`` (the ball lost),
        ``truncated`` (the episode reached ``max_iterations`` with the ball kept), ``discount``
        (:meth:`discount`), ``reason``, ``passes``."""
        del key  # the kick noise is the episode's (its noise word and the iteration)
        params = self.default_params if params is None else params
        s_max = env.noise_limit(params.kick_noise_deg)
        word = state.noise_word

        def iterate(world, keeper):
            return env.transition(world, keeper, env.kick_noise(word, world.t, s_max), params, self.config)

        world = iterate(state.world, self.keeper_of(state, action))
        world = jax.lax.while_loop(lambda w: (w.holder < 0) & ~w.done,
                                   lambda w: iterate(w, jnp.full_like(w.holder, -1)), world)
        reward = survived(world, params) - survived(state.world, params)
        nxt = state.replace(world=world)
        truncated = world.reason == Reason.TIME_LIMIT
        info = {"iterations": world.t - state.world.t, "reason": world.reason, "passes": world.passes,
                "terminated": world.done & ~truncated, "truncated": world.done & truncated,
                "discount": self.discount(nxt, params)}
        return self.observation(nxt), nxt, reward, world.done, info

    def step(self, key: jax.Array, state: EnvState, action: jax.Array,
             params: KeepAwayParams | None = None) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict]:
        """:meth:`step_env`, and a new episode (``reset(key)``) in place of a finished one: gymnax's
        ``(obs, state, reward, done, info)``, ``done`` either end (``info["terminated"]`` or
        ``info["truncated"]`` says which)."""
        params = self.default_params if params is None else params
        obs, nxt, reward, done, info = self.step_env(key, state, action, params)
        obs_reset, state_reset = self.reset(key, params)
        pick = lambda a, b: jax.lax.select(done, a, b)  # noqa: E731
        return (jax.tree.map(pick, obs_reset, obs), jax.tree.map(pick, state_reset, nxt), reward, done, info)

    # ------------------------------------------------------------------ many episodes, batch-last

    def observation_batch(self, state: "BatchState"):
        """The observations of ``n`` batch-last episodes, batch first: ``[n, 13]``, or the tokens of
        :func:`kx.sim.entities.batch_first`."""
        if self.kind == "entities":
            return entities.batch_first(entities.tokens(state.world, self.config))
        return jnp.moveaxis(observe.fixed_obs(state.world, self.config), 0, -1)

    def reset_batch(self, key: jax.Array, n: int, params: KeepAwayParams) -> tuple[jax.Array, "BatchState"]:
        """``n`` episodes' observations ``[n, 13]`` and state: episode ``i`` is ``reset(split(key, n)[i])``'s."""
        keys = jax.random.split(key, n)
        split = jax.vmap(jax.random.split)(keys)
        world = jax.vmap(lambda k: env.reset(k, params, self.config), out_axes=-1)(split[:, 0])
        words = jax.vmap(lambda k: jax.random.bits(k, (), jnp.uint32))(split[:, 1])
        state = BatchState(world=world, noise_word=words)
        return self.observation_batch(state), state

    def step_batch_env(self, state: "BatchState", action: jax.Array,
                       params: KeepAwayParams) -> tuple[jax.Array, "BatchState", jax.Array, jax.Array, dict]:
        """:meth:`step_env` of ``n`` episodes, ``action [n]``: each episode's decision, then its iterations
        until its own next decision or end (an episode at its decision waits, unchanged, for the others)."""
        s_max = env.noise_limit(params.kick_noise_deg)
        world = env.transition(state.world, self._keeper(state.world, action),
                               env.kick_noise(state.noise_word, state.world.t, s_max), params, self.config)
        world = self._fly(world, state.noise_word, params)
        reward = survived(world, params) - survived(state.world, params)
        nxt = state.replace(world=world)
        info = {"iterations": world.t - state.world.t, "reason": world.reason, "passes": world.passes}
        return self.observation_batch(nxt), nxt, reward, world.done, info

    def _fly(self, world: State, word: jax.Array, params: KeepAwayParams) -> State:
        """The episodes with a pass in flight iterate until it lands or they end; the others wait, unchanged."""
        s_max = env.noise_limit(params.kick_noise_deg)

        def flying(w):
            return (w.holder < 0) & ~w.done

        def body(w):
            moved = env.transition(w, jnp.full_like(w.holder, -1), env.kick_noise(word, w.t, s_max), params,
                                   self.config)
            fly = flying(w)
            return jax.tree.map(lambda new, old: jnp.where(fly, new, old), moved, w)

        return jax.lax.while_loop(lambda w: jnp.any(flying(w)), body, world)

    def step_batch(self, key: jax.Array, state: "BatchState", action: jax.Array, params: KeepAwayParams,
                   resets: int) -> tuple[jax.Array, "BatchState", jax.Array, jax.Array, dict]:
        """:meth:`step_batch_env`, and new episodes in place of those that ended: ``resets`` start states
        drawn from ``key`` (those of ``reset_batch(key, resets)``), taken in episode order by the episodes
        that ended, each with a noise word of its own (``info["shared_starts"]``: how many episodes had to
        share a start, when more than ``resets`` ended)."""
        _, nxt, reward, done, info = self.step_batch_env(state, action, params)
        return self._restart(key, nxt, reward, done, info, params, resets)

    def _restart(self, key, nxt: "BatchState", reward, done, info, params: KeepAwayParams, resets: int):
        """``nxt`` with the episodes that ended (``done``) replaced by new ones (:meth:`step_batch`'s rule)."""
        k_starts, k_words = jax.random.split(key)
        n = done.shape[0]

        def replaced(nxt):
            _, fresh = self.reset_batch(k_starts, resets, params)
            rank = jnp.cumsum(done.astype(jnp.int32)) - 1  # the i-th episode to end takes start i (mod resets)
            take = jnp.where(done, rank % resets, 0)
            words = jax.random.bits(k_words, (n,), jnp.uint32)
            world = jax.tree.map(lambda f, w: jnp.where(done, jnp.take(f, take, axis=-1), w), fresh.world, nxt.world)
            return BatchState(world=world, noise_word=jnp.where(done, words, nxt.noise_word))

        # only when an episode has ended are start states drawn and put in (a start costs about 50 iterations);
        # otherwise every episode goes on as it is, which is what the replacement would leave
        out = jax.lax.cond(done.any(), replaced, lambda nxt: nxt, nxt)
        info = dict(info, shared_starts=jnp.maximum(done.sum() - resets, 0))
        return self.observation_batch(out), out, reward, done, info

    # ------------------------------------------------------------------ one world iteration at a time

    @staticmethod
    def deciding(state: "BatchState") -> jax.Array:
        """``[n]``: which episodes are at a decision (a keeper holds the ball and the episode runs on)."""
        return (state.world.holder >= 0) & ~state.world.done

    def iterate_batch(self, key: jax.Array, state: "BatchState", action: jax.Array, params: KeepAwayParams,
                      resets: int) -> tuple[jax.Array, "BatchState", jax.Array, jax.Array, dict]:
        """One world iteration of ``n`` episodes: those at a decision (:meth:`deciding`) act on ``action [n]``,
        the others (a pass in flight) ignore it; the episodes that end are replaced as :meth:`step_batch`
        replaces them. The reward is the share of ``max_iterations`` the iteration survived, so that an SMDP
        step's reward is the sum of its iterations' (the same episodes as :meth:`step_batch` plays, one
        iteration a call: no episode waits for another's pass to land)."""
        s_max = env.noise_limit(params.kick_noise_deg)
        world = env.transition(state.world, self._keeper(state.world, action),
                               env.kick_noise(state.noise_word, state.world.t, s_max), params, self.config)
        return self._advanced(key, state, world, params, resets)

    def land_batch(self, key: jax.Array, state: "BatchState", params: KeepAwayParams,
                   resets: int) -> tuple[jax.Array, "BatchState", jax.Array, jax.Array, dict]:
        """The episodes with a pass in flight iterate until it lands (their next decision) or they end; those
        at a decision wait, unchanged. ``reward``, ``done`` and ``info["iterations"]`` are each episode's over
        those iterations; the ended ones are replaced as :meth:`step_batch` replaces them. Afterwards every
        episode is at a decision."""
        return self._advanced(key, state, self._fly(state.world, state.noise_word, params), params, resets)

    def _advanced(self, key: jax.Array, state: "BatchState", world, params: KeepAwayParams, resets: int):
        """The batch moved on from ``state`` to ``world``: each episode's reward over the iterations between (the
        share of ``max_iterations`` survived), its end and what it did, the ended ones replaced
        (:meth:`_restart`)."""
        reward = survived(world, params) - survived(state.world, params)
        info = {"iterations": world.t - state.world.t, "reason": world.reason, "passes": world.passes}
        return self._restart(key, state.replace(world=world), reward, world.done, info, params, resets)


@struct.dataclass
class BatchState:
    """``n`` episodes, batch-last: ``world`` ``[.., n]``, ``noise_word [n]``."""

    world: State
    noise_word: jax.Array


def survived(world: State, params: KeepAwayParams) -> jax.Array:
    """The share of ``max_iterations`` the episode has survived so far (its fitness once finished)."""
    lost = (world.reason == Reason.INTERCEPTED) | (world.reason == Reason.TACKLED) | (
        world.reason == Reason.OUT_OF_FIELD)
    return (world.t - lost.astype(jnp.int32)).astype(jnp.float32) / jnp.asarray(params.max_iterations, jnp.float32)
