"""PPO's parts (kx.evolve.encodings.ppo.algorithm): GAE and the clipped loss against hand computations, and the jitted
training
vmapped over seeds as seed by seed, deterministic."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx.evolve.encodings.ppo import algorithm as ppo
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


def test_the_iteration_rollouts_gae_is_the_smdp_gae_of_the_same_steps():
    """:func:`kx.evolve.encodings.ppo.algorithm.gae_iterations` over world iterations (each SMDP step's reward spread
    over its iterations,
    the steps at a decision valid, the rollout cut in the middle of passes that land afterwards) gives each
    valid step :func:`kx.evolve.encodings.ppo.algorithm.gae`'s advantage of the same SMDP steps, ends included."""
    rng = np.random.default_rng(0)
    steps, n, gamma, lam = 40, 6, 0.99, 0.95
    r = rng.random((steps, n)).astype(np.float32)
    d = rng.random((steps, n)) < 0.15
    tau = rng.integers(1, 6, (steps, n))
    v = rng.random((steps, n)).astype(np.float32)
    after = rng.random(n).astype(np.float32)  # the critic after the last step
    its = []  # each episode's iterations: (reward, end, value, decision)
    for i in range(n):
        seq = []
        for k in range(steps):
            share = rng.random(tau[k, i])
            share = share / share.sum() * r[k, i]
            seq += [(share[j], bool(d[k, i]) and j == tau[k, i] - 1, v[k, i] if j == 0 else 99.0, j == 0)
                    for j in range(tau[k, i])]
        its.append(seq)
    length = min(len(s) for s in its) - 3  # the rollout cuts through some steps
    arrays = [np.zeros((length, n), t) for t in (np.float32, bool, np.float32, bool)]
    last = [np.zeros(n, t) for t in (np.float32, np.int32, bool, np.float32)]  # reward, iterations, end, value
    for i, seq in enumerate(its):
        for a, col in zip(arrays, zip(*seq[:length])):
            a[:, i] = col
        j = length
        while j < len(seq) and not seq[j][3]:  # the landing: to the next decision
            last[0][i] += seq[j][0]
            last[1][i] += 1
            last[2][i] |= seq[j][1]
            j += 1
        last[3][i] = seq[j][2] if j < len(seq) else after[i]
    rew, end, val, valid = map(jnp.asarray, arrays)
    adv, targets = ppo.gae_iterations(rew, val, end, valid, jnp.asarray(last[3]), *map(jnp.asarray, last[:3]), gamma,
                                      lam)
    valid = arrays[3]
    assert (last[1] > 0).any() and arrays[1].any() and not valid.all()
    for i in range(n):
        k = int(valid[:, i].sum())  # the SMDP steps the rollout began; the last one's value is where it landed
        want, want_t = ppo.gae(jnp.asarray(r[:k, i:i + 1]), jnp.asarray(v[:k, i:i + 1]), jnp.asarray(d[:k, i:i + 1]),
                               jnp.asarray(last[3][i:i + 1]), gamma, lam, jnp.asarray(tau[:k, i:i + 1]))
        np.testing.assert_allclose(np.asarray(adv[:, i])[valid[:, i]], np.asarray(want[:, 0]), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(np.asarray(targets[:, i])[valid[:, i]], np.asarray(want_t[:, 0]), rtol=1e-5,
                                   atol=1e-6)
        assert (np.asarray(adv[:, i])[~valid[:, i]] == 0).all()


def test_the_masked_loss_is_the_loss_of_the_valid_steps_alone():
    """With ``Transition.valid``, the loss (its normalised advantages too) is that of the valid steps alone: the
    padding (an iteration rollout's flying episodes) changes nothing, whatever it holds."""
    net = ppo.ActorCritic(hidden=8)
    key = jax.random.key(1)
    k = jax.random.split(key, 6)
    m = 10
    obs = jax.random.normal(k[0], (m, 13))
    params = net.init(key, obs[0])
    valid = jnp.array([1, 0, 1, 1, 0, 1, 1, 0, 1, 1], bool)
    batch = ppo.Transition(obs, jax.random.randint(k[1], (m,), 0, 3), jnp.log(jax.random.uniform(k[2], (m,))),
                           jax.random.normal(k[3], (m,)), jnp.zeros(m), jnp.zeros(m, bool), jnp.ones(m, jnp.int32),
                           valid)
    adv, targets = jax.random.normal(k[4], (m,)), jax.random.normal(k[5], (m,))
    total, parts = ppo.loss(params, net.apply, batch, adv, targets, 0.2, 0.5, 0.01)
    keep = np.flatnonzero(np.asarray(valid))
    alone = jax.tree.map(lambda a: a[keep], batch._replace(valid=None))
    want, want_parts = ppo.loss(params, net.apply, alone, adv[keep], targets[keep], 0.2, 0.5, 0.01)
    np.testing.assert_allclose([float(total), *map(float, parts)], [float(want), *map(float, want_parts)], rtol=2e-5)
    junk = batch._replace(obs=batch.obs.at[1].set(100.0), log_prob=batch.log_prob.at[4].set(-50.0))
    again, _ = ppo.loss(params, net.apply, junk, adv.at[7].set(1e3), targets.at[7].set(-1e3), 0.2, 0.5, 0.01)
    assert float(again) == pytest.approx(float(total), rel=2e-5)


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


def test_an_iteration_rollouts_update_learns_from_its_decisions_alone_and_limits_what_it_learns_from():
    """``rollout="iteration"``: an update counts as decisions only the steps where an episode was at one; it is
    deterministic; a limit on the minibatches (``max_minibatches``, ``learn_per_episode``) that does not bind
    gives the same update bit for bit, and one that binds gives another."""
    sim, params = KeepAwayConfig(), KeepAwayParams(kick_noise_deg=10.0)
    base = dict(num_envs=16, num_steps=24, num_minibatches=4, update_epochs=2, hidden=8, resets=4, rollout="iteration")
    env = ppo.environment(ppo.PPOConfig(**base), sim)
    # one learner for every case (the limits do not change it), one program, not op by op
    start = jax.jit(lambda k: ppo.init(k, ppo.PPOConfig(**base), env, params))(jax.random.key(0))
    programs = {}

    def updated(**kw):
        cfg = ppo.PPOConfig(**base, **kw)
        if cfg not in programs:  # each config's update compiled once: the determinism case runs it again
            programs[cfg] = jax.jit(ppo.make_update(cfg, env, params))
        return programs[cfg](start, jax.random.key(1), jnp.float32(1e-3))

    plain, m = updated()
    decided, stepped = int(plain.decisions), 16 * 24
    assert 0 < decided < stepped  # passes flew: those iterations are not decisions
    assert int(m["iterations"]) >= stepped and int(m["episodes"]) > 0
    def apart(a, b):
        return max(float(np.abs(np.asarray(x) - np.asarray(y)).max())
                   for x, y in zip(jax.tree.leaves(a.params), jax.tree.leaves(b.params)))

    assert apart(plain, updated()[0]) == 0.0  # deterministic
    # a limit that binds: fewer steps of gradient, on the same episodes (one that does not bind gives the same
    # update: test_max_minibatches_binds_or_changes_nothing, slow, since it is one more program to compile)
    other = updated(learn_per_episode=1)[0]
    assert apart(plain, other) > 1e-4 and int(other.decisions) == decided


@pytest.mark.slow  # three more programs to compile: the default suite checks learn_per_episode's limit that binds
def test_max_minibatches_binds_or_changes_nothing():
    """max_minibatches that binds gives another update on the same decisions; limits that do not bind
    (max_minibatches and learn_per_episode) give the same update (another program: its sums may round apart in
    the last bit)."""
    sim, params = KeepAwayConfig(), KeepAwayParams(kick_noise_deg=10.0)

    def updated(**kw):
        cfg = ppo.PPOConfig(num_envs=16, num_steps=24, num_minibatches=4, update_epochs=2, hidden=8, resets=4,
                            rollout="iteration", **kw)
        env = ppo.environment(cfg, sim)
        learner = ppo.init(jax.random.key(0), cfg, env, params)
        return jax.jit(ppo.make_update(cfg, env, params))(learner, jax.random.key(1), jnp.float32(1e-3))[0]

    def apart(a, b):
        return max(float(np.abs(np.asarray(x) - np.asarray(y)).max())
                   for x, y in zip(jax.tree.leaves(a.params), jax.tree.leaves(b.params)))

    a, b = updated(), updated(max_minibatches=1)
    assert apart(a, b) > 1e-4 and int(a.decisions) == int(b.decisions)
    assert apart(a, updated(learn_per_episode=10_000, max_minibatches=4)) < 1e-6


def test_bad_rollout_settings_are_refused_with_the_field_named():
    with pytest.raises(ValueError, match="rollout: allowed smdp, iteration"):
        ppo.PPOConfig(rollout="frames")
    with pytest.raises(ValueError, match="learn_per_episode: .*only with rollout 'iteration'"):
        ppo.PPOConfig(learn_per_episode=10)
    with pytest.raises(ValueError, match="max_minibatches: allowed an integer >= 0"):
        ppo.PPOConfig(max_minibatches=-1)
    # (the last: 8 minibatches divide the 4 x 2 steps of the rollout, not a device's 2 x 2)
    for bad in ({"devices": 0}, {"devices": 3}, {"devices": 16, "resets": 8},
                {"devices": 2, "num_envs": 4, "num_steps": 2, "resets": 2, "num_minibatches": 8}):
        with pytest.raises(ValueError, match=r"devices: allowed an integer >= 1 that divides num_envs"):
            ppo.PPOConfig(**bad)
    from kx.evolve import config as cfg_lib

    n_dev = jax.local_device_count()
    with pytest.raises(cfg_lib.ConfigError, match=rf"ppo.devices: allowed an integer in \[1, {n_dev}\] \(this "
                                                  r"process's devices\), got"):
        cfg_lib.validate(cfg_lib.load(cfg_lib.CONFIG_DIR / "ppo_3v2.py", [f"ppo.devices={n_dev + 1}"]))


@pytest.mark.parametrize("hidden", [16, 64])
def test_the_evaluators_greedy_decision_is_the_trained_networks(hidden):
    """The evaluator plays a PPO champion by its own forward pass
    (:func:`kx.evolve.encodings.ppo.algorithm.actor_logits_batch_last`, through
    the run loop's policy :func:`kx.evolve.encodings.ppo.greedy_policy`): on random weights and start states its
    logits are :class:`kx.evolve.encodings.ppo.algorithm.ActorCritic`'s within float tolerance and its decisions are
    the network's argmax,
    exactly, so a reported champion is the network that was trained."""
    from kx.evolve.encodings.ppo import greedy_policy
    from kx.sim import env, observe
    from kx.sim.policies import Shared

    sim, params = KeepAwayConfig(), KeepAwayParams(kick_noise_deg=10.0)
    net = ppo.ActorCritic(hidden=hidden)
    # each a program (op by op, their operations each compile apart)
    obs_of = jax.jit(observe.fixed_obs, static_argnums=1)
    decode = jax.jit(observe.decode_ranked, static_argnums=2)
    play = jax.jit(lambda table, states: greedy_policy(sim, hidden).apply(
        Shared(table, jnp.zeros(400, jnp.int32)), states, None))
    for seed in range(3):
        weights = net.init(jax.random.key(seed), jnp.zeros(13))
        # weights far from the small initial actor's, so that the logits differ clearly between actions
        weights = jax.tree.map(lambda a: a * 30.0, weights)
        states = env.reset_batch(jax.random.key(100 + seed), 400, params, sim)
        x = obs_of(states, sim)  # [13, 400]
        want, _ = net.apply(weights, x.T)
        got = ppo.actor_logits_batch_last(weights, x)
        np.testing.assert_allclose(np.asarray(got).T, np.asarray(want), rtol=1e-5, atol=1e-5)
        top = np.sort(np.asarray(want), axis=1)
        clear = (top[:, -1] - top[:, -2]) > 1e-4  # no near-tie that the float tolerance could flip
        assert clear.sum() >= 390
        table = jax.tree.map(lambda a: a[None], weights)
        acts = play(table, states)
        expect = decode(jnp.asarray(want).T, states, sim)
        np.testing.assert_array_equal(np.asarray(acts)[clear], np.asarray(expect)[clear])
        assert len(set(np.asarray(jnp.argmax(want, axis=-1)).tolist())) > 1  # more than one action taken


def test_the_rollouts_sampler_draws_the_softmaxs_actions_and_never_an_absent_teammate():
    """``sample`` inverts the softmax's CDF: hand-computed cut points, the categorical's frequencies over many
    uniforms, and a slot of probability zero (an absent teammate's :data:`ppo.ABSENT` logit) never drawn, even
    at the largest uniform below 1."""
    third = jnp.zeros(3)  # three equal actions: cuts at 1/3 and 2/3
    u = jnp.array([0.0, 0.33, 0.34, 0.66, 0.67, np.nextafter(np.float32(1), np.float32(0))], jnp.float32)
    np.testing.assert_array_equal(ppo.sample(jnp.broadcast_to(third, (6, 3)), u), [0, 0, 1, 1, 2, 2])
    logits = jnp.array([0.5, -1.0, 1.5, 0.0])
    draws = ppo.sample(jnp.broadcast_to(logits, (200_000, 4)), jax.random.uniform(jax.random.key(3), (200_000,)))
    p = np.asarray(jax.nn.softmax(logits))
    freq = np.bincount(np.asarray(draws), minlength=4) / draws.size
    assert np.all(np.abs(freq - p) < 4 * np.sqrt(p * (1 - p) / draws.size)), (freq, p)
    absent = jnp.array([[0.3, 2.0, ppo.ABSENT, ppo.ABSENT], [ppo.ABSENT, 1.0, ppo.ABSENT, 5.0]])
    top = np.nextafter(np.float32(1), np.float32(0))
    for uu in (0.0, 0.5, 0.999, top):
        a = np.asarray(ppo.sample(absent, jnp.full((2,), uu, jnp.float32)))
        assert a[0] in (0, 1) and a[1] in (1, 3), (uu, a)
