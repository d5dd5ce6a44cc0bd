"""The entity view (``kx.sim.entities``) and the size-invariant actor-critic that reads it
(``kx.evolve.encodings.ppo.algorithm.EntityActorCritic``): features against the positions by hand, the actions'
keepers, the environment's
entity steps against its fixed steps with the same passes, the network's equivariance to teammates and invariance
to takers for every team size from 3v2 to 6v4, and PPO training it (``kx.evolve.encodings.ppo.algorithm.make_train``)
deterministically in
3v2 and 6v4."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx.evolve.encodings.ppo import algorithm as ppo
from kx.sim import entities, gym, observe
from kx.sim.types import KeepAwayConfig, KeepAwayParams

TASKS = [(3, 2), (4, 3), (5, 3), (6, 4)]


@functools.lru_cache(maxsize=None)
def _env(k: int, t: int):
    """The entity environment of a team size and its batched reset, jitted once (one program, not op by op)."""
    env = gym.KeepAway(KeepAwayConfig(n_keepers=k, n_takers=t), "entities")
    return env, jax.jit(env.reset_batch, static_argnums=1)


def _states(k: int, t: int, n: int = 16):
    env, reset = _env(k, t)
    _, state = reset(jax.random.key(k * 10 + t), n, KeepAwayParams())
    return env, state


@pytest.mark.parametrize("k,t", [(3, 2), pytest.param(4, 3, marks=pytest.mark.slow),
                                 pytest.param(5, 3, marks=pytest.mark.slow), (6, 4)])
def test_the_tokens_are_the_holders_view_by_hand(k, t):
    env, state = _states(k, t)
    tok = entities.tokens(state.world, env.config)
    w = env.config.field_size
    diag, c = (w - 1) * math.sqrt(2), (w - 1) / 2
    kx_, ky_ = np.asarray(state.world.keeper_x), np.asarray(state.world.keeper_y)
    tx_, ty_ = np.asarray(state.world.taker_x), np.asarray(state.world.taker_y)
    holder = np.maximum(np.asarray(state.world.holder), 0)
    for b in range(kx_.shape[-1]):
        h = holder[b]
        hx, hy = kx_[h, b], ky_[h, b]
        mates = [i for i in range(k) if i != h]
        d = lambda ax, ay, bx, by: math.hypot(ax - bx, ay - by) / diag  # noqa: E731
        want_h = [d(hx, hy, c, c), (hx - c) / diag, (hy - c) / diag, min(d(hx, hy, tx_[j, b], ty_[j, b])
                                                                         for j in range(t))]
        np.testing.assert_allclose(np.asarray(tok["holder"])[:, b], want_h, rtol=1e-5, atol=1e-6)
        for r, i in enumerate(mates):
            mx, my = kx_[i, b], ky_[i, b]

            def lane(j):
                ux, uy, vx, vy = mx - hx, my - hy, tx_[j, b] - hx, ty_[j, b] - hy
                return math.atan2(abs(ux * vy - uy * vx), ux * vx + uy * vy) / math.pi

            want = [(mx - hx) / diag, (my - hy) / diag, d(mx, my, hx, hy), d(mx, my, c, c),
                    min(d(mx, my, tx_[j, b], ty_[j, b]) for j in range(t)), min(lane(j) for j in range(t))]
            np.testing.assert_allclose(np.asarray(tok["mates"])[r, :, b], want, rtol=1e-5, atol=1e-6)
        for j in range(t):
            want = [(tx_[j, b] - hx) / diag, (ty_[j, b] - hy) / diag, d(tx_[j, b], ty_[j, b], hx, hy),
                    d(tx_[j, b], ty_[j, b], c, c)]
            np.testing.assert_allclose(np.asarray(tok["takers"])[j, :, b], want, rtol=1e-5, atol=1e-6)
    shapes = {n: a.shape for n, a in entities.batch_first(tok).items()}
    assert shapes == {"holder": (16, 4), "mates": (16, k - 1, 6), "takers": (16, t, 4)}


def test_an_action_is_hold_or_a_pass_to_a_teammate_slot():
    env, state = _states(5, 3)
    w = state.world
    holder = np.maximum(np.asarray(w.holder), 0)
    slots = np.asarray(entities.mate_keepers(w, env.config))
    for b in range(holder.size):
        assert sorted(slots[:, b].tolist()) == [i for i in range(5) if i != holder[b]]
    np.testing.assert_array_equal(entities.keeper_of(jnp.zeros_like(w.holder), w, env.config), holder)
    for a in range(1, 5):
        np.testing.assert_array_equal(entities.keeper_of(jnp.full_like(w.holder, a), w, env.config), slots[a - 1])
    assert env.num_actions == 5 and gym.KeepAway(env.config).num_actions == 3
    with pytest.raises(ValueError, match="observation: allowed fixed, entities"):
        gym.KeepAway(env.config, "image")


def test_the_entity_environment_steps_the_world_as_the_fixed_one_with_the_same_passes():
    """The same keeper chosen through either action space gives the same world, step after step."""
    config = KeepAwayConfig(n_keepers=4, n_takers=3)
    fixed, ent = gym.KeepAway(config), gym.KeepAway(config, "entities")
    params = KeepAwayParams()
    _, sf = jax.jit(fixed.reset_batch, static_argnums=1)(jax.random.key(1), 32, params)  # a program, not op by op
    _, se = jax.jit(ent.reset_batch, static_argnums=1)(jax.random.key(1), 32, params)
    step_f, step_e = jax.jit(fixed.step_batch_env), jax.jit(ent.step_batch_env)
    rng = np.random.default_rng(0)
    for _ in range(12):
        a = jnp.asarray(rng.integers(0, 3, 32), jnp.int32)
        keeper = np.asarray(observe.teammate_order(sf.world, config))[np.asarray(a), np.arange(32)]
        slots = np.asarray(entities.mate_keepers(se.world, config))
        holder = np.maximum(np.asarray(se.world.holder), 0)
        a_e = np.where(keeper == holder, 0, 1 + np.argmax(slots == keeper[None], axis=0))
        _, sf, rf, df, _ = step_f(sf, a, params)
        _, se, re_, de, _ = step_e(se, jnp.asarray(a_e, jnp.int32), params)
        for x, y in zip(jax.tree.leaves(sf), jax.tree.leaves(se)):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(rf, re_)


NET = ppo.EntityActorCritic(hidden=32, heads=4, blocks=2)
_apply = jax.jit(NET.apply)  # one program a shape, shared by the tests below (op by op, each op compiles apart)


def _net_and_obs(k: int, t: int):
    env, state = _states(k, t)
    obs = entities.batch_first(entities.tokens(state.world, env.config))
    return NET, jax.tree.map(lambda a: a[:8], obs)


def _params(obs):
    """The network's weights, with larger output weights than the initial 0.01 so that a wrong ordering shows."""
    params = jax.jit(NET.init)(jax.random.key(0), jax.tree.map(lambda a: a[0], obs))
    return jax.tree.map(lambda a: a * 50.0 if a.ndim == 2 and a.shape[-1] == 1 else a, params)


def test_the_entity_network_follows_its_teammates_ignores_the_takers_order_and_fits_every_team_size():
    net, obs3 = _net_and_obs(3, 2)
    params = _params(obs3)
    rng = np.random.default_rng(1)
    apply = _apply
    for k, t in TASKS:
        _, obs = _net_and_obs(k, t)
        logits, value = apply(params, obs)  # the same weights for every team size
        assert logits.shape == (8, k) and value.shape == (8,)
        assert np.all(np.isfinite(logits)) and np.ptp(np.asarray(logits)) > 1e-3
        pm, pt = rng.permutation(k - 1), rng.permutation(t)
        moved = dict(obs, mates=obs["mates"][:, pm], takers=obs["takers"][:, pt])
        l2, v2 = apply(params, moved)
        # equal up to float32 rounding at the logits' scale (tens here): the tokens summed in another order round
        # otherwise (seen 3e-5 on a logit of -1.74 beside logits of 39, on an AVX2 CPU); a wrong order moves them
        # by the spread between teammates' logits (> 1e-3 of it, asserted above)
        tol = 1e-5 * float(np.abs(np.asarray(logits)).max())
        np.testing.assert_allclose(l2[:, 0], logits[:, 0], rtol=1e-5, atol=tol)  # hold: unchanged
        np.testing.assert_allclose(l2[:, 1:], logits[:, 1:][:, pm], rtol=1e-5, atol=tol)  # passes follow
        np.testing.assert_allclose(v2, value, rtol=1e-5, atol=1e-5 * float(np.abs(np.asarray(value)).max()))


@pytest.mark.slow  # ~10 s a size: PPO's determinism is the default suite's in test_train_ppo.py (resumed bit for bit)
@pytest.mark.parametrize("k,t", [(3, 2), (6, 4)])
def test_ppo_trains_the_entity_network_the_same_way_twice(k, t):
    cfg = ppo.PPOConfig(num_envs=16, num_steps=8, updates=2, network="entity", hidden=16, heads=2)
    env = ppo.environment(cfg, KeepAwayConfig(n_keepers=k, n_takers=t))
    train = jax.jit(ppo.make_train(cfg, env, KeepAwayParams()))
    (a, ma), (b, _) = train(jax.random.key(3)), train(jax.random.key(3))
    for x, y in zip(jax.tree.leaves(a.params), jax.tree.leaves(b.params)):
        np.testing.assert_array_equal(x, y)
    assert a.params["params"]["pass"]["kernel"].shape == (16, 1)
    assert np.all(np.isfinite(np.asarray(ma["policy_loss"]))) and int(a.decisions) == 2 * 16 * 8
    # the greedy decision is an action of the task: hold or a teammate
    act = ppo.greedy(a.params, a.obs, cfg=cfg)
    assert act.shape == (16,) and int(act.max()) < k
    with pytest.raises(ValueError, match="network: allowed mlp, entity"):
        ppo.PPOConfig(network="attention")
    with pytest.raises(ValueError, match="heads: allowed a divisor of hidden"):
        ppo.PPOConfig(network="entity", hidden=30, heads=4)


def test_a_smaller_team_padded_among_a_bigger_ones_decides_as_it_does_alone():
    """3v2 tokens padded to 4v3's sizes with their masks (mixed_tokens) give the 3v2 logits on the teammates that
    are there, and a pass to an absent one is never sampled; the 4v3 episodes of the batch are untouched."""
    _, small = _net_and_obs(3, 2)
    _, big = _net_and_obs(4, 3)
    params = _params(small)
    mixed = ppo.mixed_tokens([small, big])
    assert mixed["mates"].shape == (16, 3, 6) and mixed["mate_mask"][:8].sum(axis=1).tolist() == [2] * 8
    logits, value = _apply(params, mixed)
    alone_small, v_small = _apply(params, small)
    alone_big, v_big = _apply(params, big)
    np.testing.assert_allclose(logits[:8, :3], alone_small, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(value[:8], v_small, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(logits[8:], alone_big, rtol=1e-5, atol=1e-5)
    assert np.all(np.asarray(logits[:8, 3]) == ppo.ABSENT)
    draws = jax.random.categorical(jax.random.key(1), jnp.broadcast_to(logits[:8], (500, 8, 4)))
    assert int(draws.max()) <= 2


@pytest.mark.slow  # ~25 s cold: mixed batches' tokens are the default suite's (test_a_smaller_team_padded_among_...)
def test_ppo_trains_on_a_mix_of_team_sizes_in_every_batch():
    cfg = ppo.PPOConfig(num_envs=16, num_steps=8, updates=2, network="entity", hidden=16, heads=2, mix=("4v3",),
                        resets=4)
    env = ppo.environment(cfg, KeepAwayConfig())
    assert [e.config.name for e in env] == ["3v2", "4v3"]
    train = jax.jit(ppo.make_train(cfg, env, KeepAwayParams()))
    (a, m), (b, _) = train(jax.random.key(2)), train(jax.random.key(2))
    for x, y in zip(jax.tree.leaves(a.params), jax.tree.leaves(b.params)):
        np.testing.assert_array_equal(x, y)
    assert a.obs["mates"].shape == (16, 3, 6)
    assert np.asarray(a.obs["mate_mask"]).sum(axis=1).tolist() == [2] * 8 + [3] * 8
    assert [s.world.keeper_x.shape for s in a.env] == [(3, 8), (4, 8)] and int(m["episodes"].sum()) > 0
    for bad, why in ((dict(network="mlp"), "mix: allowed only with the entity network"),
                     (dict(network="entity", num_envs=15, resets=3), "must divide among the 2 tasks")):
        with pytest.raises(ValueError, match=why):
            ppo.PPOConfig(mix=("4v3",), **bad)
