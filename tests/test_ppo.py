"""PPO's parts (kx.ppo): GAE and the clipped loss against hand computations, and the jitted training
vmapped over seeds as seed by seed, deterministic."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx import ppo
from kx.sim import gym
from kx.sim.types import KeepAwayConfig, KeepAwayParams


def test_gae_by_hand():
    rewards = jnp.array([[1.0], [1.0], [1.0]])
    values = jnp.array([[0.5], [0.5], [0.5]])
    dones = jnp.array([[False], [True], [False]])  # the episode ends after step 1: no bootstrap across it
    adv, targets = ppo.gae(rewards, values, dones, jnp.array([2.0]), gamma=0.9, lam=0.8)
    # t=2: 1 + 0.9 * 2 - 0.5 = 2.3; t=1: 1 - 0.5 = 0.5; t=0: (1 + 0.9 * 0.5 - 0.5) + 0.9 * 0.8 * 0.5 = 1.31
    np.testing.assert_allclose(adv[:, 0], [1.31, 0.5, 2.3], rtol=1e-6)
    np.testing.assert_allclose(targets[:, 0], [1.81, 1.0, 2.8], rtol=1e-6)


def test_smdp_gae_discounts_a_step_by_the_iterations_it_spanned():
    rewards = jnp.array([[1.0], [2.0]])
    values = jnp.array([[0.5], [1.0]])
    dones = jnp.array([[False], [False]])
    tau = jnp.array([[3], [1]])  # a pass of 3 iterations, then a hold
    adv, targets = ppo.gae(rewards, values, dones, jnp.array([4.0]), gamma=0.9, lam=0.5, durations=tau)
    # t=1: 2 + 0.9 * 4 - 1 = 4.6; t=0: (1 + 0.729 * 1 - 0.5) + 0.729 * 0.5 * 4.6 = 2.9057
    np.testing.assert_allclose(adv[:, 0], [2.9057, 4.6], rtol=1e-6)
    np.testing.assert_allclose(targets[:, 0], [3.4057, 5.6], rtol=1e-6)
    # one iteration a step: the plain GAE
    plain, _ = ppo.gae(rewards, values, dones, jnp.array([4.0]), gamma=0.9, lam=0.5)
    ones, _ = ppo.gae(rewards, values, dones, jnp.array([4.0]), gamma=0.9, lam=0.5, durations=jnp.ones((2, 1)))
    np.testing.assert_array_equal(plain, ones)


def test_the_clipped_loss_by_hand():
    net = ppo.ActorCritic(hidden=8)
    key = jax.random.key(0)
    obs = jax.random.normal(key, (6, 13))
    params = net.init(key, obs[0])
    logits, value = net.apply(params, obs)
    action = jnp.array([0, 1, 2, 0, 1, 2])
    old_logp = jnp.log(jnp.array([0.2, 0.5, 0.4, 0.9, 0.3, 0.34]))  # ratios in and out of the clip range
    old_value = value + jnp.array([0.5, -0.5, 0.1, 0.0, 0.3, -0.1])
    adv = jnp.array([1.0, -2.0, 0.5, 0.3, -0.7, 1.5])
    targets = jnp.array([0.3, -0.2, 1.0, 0.0, 0.5, 0.1])
    batch = ppo.Transition(obs, action, old_logp, old_value, jnp.zeros(6), jnp.zeros(6, bool), jnp.ones(6, jnp.int32))
    total, (pl, vl, ent) = ppo.loss(params, net.apply, batch, adv, targets, 0.2, 0.5, 0.01)
    # numpy, term by term
    lg, v = np.asarray(logits, np.float64), np.asarray(value, np.float64)
    p = np.exp(lg - lg.max(1, keepdims=True))
    p /= p.sum(1, keepdims=True)
    logp = np.log(p[np.arange(6), np.asarray(action)])
    ratio = np.exp(logp - np.asarray(old_logp, np.float64))
    a = np.asarray(adv, np.float64)
    a = (a - a.mean()) / (a.std() + 1e-8)
    want_pl = -np.minimum(ratio * a, np.clip(ratio, 0.8, 1.2) * a).mean()
    ov, tg = np.asarray(old_value, np.float64), np.asarray(targets, np.float64)
    vc = ov + np.clip(v - ov, -0.2, 0.2)
    want_vl = 0.5 * np.maximum((v - tg) ** 2, (vc - tg) ** 2).mean()
    want_ent = -(p * np.log(p)).sum(1).mean()
    assert ((ratio < 0.8) | (ratio > 1.2)).any() and ((ratio > 0.8) & (ratio < 1.2)).any()
    np.testing.assert_allclose([float(pl), float(vl), float(ent)], [want_pl, want_vl, want_ent], rtol=1e-5)
    assert float(total) == pytest.approx(want_pl + 0.5 * want_vl - 0.01 * want_ent, rel=1e-5)


@pytest.mark.slow  # ~40 s: compiles the whole training twice
def test_training_vmapped_over_seeds_is_seed_by_seed_and_deterministic():
    cfg = ppo.PPOConfig(num_envs=8, num_steps=8, updates=3, num_minibatches=2, update_epochs=2, hidden=16)
    train = ppo.make_train(cfg, gym.KeepAway(KeepAwayConfig()), KeepAwayParams(kick_noise_deg=10.0))
    keys = jax.random.split(jax.random.key(3), 2)
    states, metrics = jax.jit(jax.vmap(train))(keys)
    assert np.all(np.isfinite(np.asarray(metrics["policy_loss"]))) and metrics["value_loss"].shape == (2, 3)
    one = jax.jit(train)
    for i in range(2):
        s_i, m_i = one(keys[i])
        for x, y in zip(jax.tree.leaves(s_i.params), jax.tree.leaves(jax.tree.map(lambda a: a[i], states.params))):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-5, atol=1e-6)
    again, _ = one(keys[0])
    for x, y in zip(jax.tree.leaves(again.params), jax.tree.leaves(one(keys[0])[0].params)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_a_minibatch_count_that_does_not_divide_the_batch_is_refused():
    with pytest.raises(ValueError, match="num_minibatches: must divide"):
        ppo.PPOConfig(num_envs=3, num_steps=5, num_minibatches=4)
