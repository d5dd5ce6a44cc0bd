"""The batched evaluator: results equal single-episode runs; finished episodes are not paid for."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx.sim import env, policies
from kx.sim import evaluate as ev
from kx.sim.types import KeepAwayConfig, KeepAwayParams, Reason

CFG = KeepAwayConfig()
PARAMS = KeepAwayParams(max_iterations=600)


def test_width_ladder():
    assert ev.width_ladder(4500) == [4500, 4096, 3072, 2048, 1792, 1536, 1280, 1024, 896, 768, 640, 512, 256,
                                     128, 64]
    assert ev.width_ladder(40) == [40]
    assert all(w % 2 == 0 for w in ev.width_ladder(4501, multiple=2))


def test_evaluate_equals_single_episode_rollouts():
    n_pol, n_trials = 3, 8
    starts = env.reset_batch(jax.random.key(0), n_trials, PARAMS, CFG)
    mlp = policies.mlp_init(jax.random.key(1), n_pol, CFG)
    mlp["w2"] = mlp["w2"].at[:, :, 0].add(0.8)  # lean toward holding so that some episodes last
    policy = policies.mlp_policy(CFG)
    key = jax.random.key(9)
    stats = ev.evaluate(policy, mlp, starts, PARAMS, CFG, first_chunk=2, chunk=16, key=key)
    assert stats.fitness.shape == (n_pol, n_trials) and stats.behaviour.shape == (3, n_pol, n_trials)
    for g in range(n_pol):
        for t in range(n_trials):
            start = jax.tree.map(lambda a: a[..., t], starts)
            one = jax.tree.map(lambda a: a[g], mlp)
            states, _ = ev.rollout(policy, one, start, PARAMS, CFG, n_steps=600, key=key, trial=t)
            final = jax.tree.map(lambda a: a[-1], states)
            alone = env.episode_stats(final, PARAMS, CFG)
            assert int(alone.iterations) == int(stats.iterations[g, t])
            assert int(alone.reason) == int(stats.reason[g, t])
            assert int(alone.passes) == int(stats.passes[g, t])
            assert float(alone.fitness) == float(stats.fitness[g, t])
            # the accumulators are exact integers (checked above through the reference tests); their
            # normalisation to [0, 1] may round differently in two compiled programs, by one ulp
            np.testing.assert_allclose(np.asarray(alone.behaviour), np.asarray(stats.behaviour[:, g, t]),
                                       rtol=2.5e-7, atol=0)


def test_finished_episodes_are_not_paid_for():
    starts = env.reset_batch(jax.random.key(2), 60, PARAMS, CFG)
    c = ev.EvalCounters()
    stats = ev.evaluate(policies.always_hold(CFG), None, starts, PARAMS, CFG, counters=c, key=jax.random.key(0))
    assert np.all(np.asarray(stats.reason) == Reason.TACKLED)  # holding never survives
    longest = int(stats.iterations.max())
    assert c.live_steps == int(stats.iterations.sum())
    # lockstep runs until the longest episode ends (overshooting by less than one chunk), not 600 steps
    assert c.executed_steps <= 60 * (2 * longest + 8)
    assert c.executed_steps < 60 * PARAMS.max_iterations / 5


def test_stochastic_policy_needs_key_and_is_reproducible():
    starts = env.reset_batch(jax.random.key(3), 20, PARAMS, CFG)
    pol = policies.random_policy(CFG)
    with pytest.raises(ValueError, match="key"):
        ev.evaluate(pol, None, starts, PARAMS.replace(kick_noise_deg=0.0), CFG)
    with pytest.raises(ValueError, match="key"):  # kick noise (on by default) needs one too
        ev.evaluate(policies.always_hold(CFG), None, starts, PARAMS, CFG)
    a = ev.evaluate(pol, None, starts, PARAMS, CFG, key=jax.random.key(5))
    b = ev.evaluate(pol, None, starts, PARAMS, CFG, key=jax.random.key(5))
    c = ev.evaluate(pol, None, starts, PARAMS, CFG, key=jax.random.key(6))
    np.testing.assert_array_equal(a.iterations, b.iterations)
    assert not np.array_equal(np.asarray(a.passes), np.asarray(c.passes)) or not np.array_equal(
        np.asarray(a.iterations), np.asarray(c.iterations))


def test_heuristic_beats_hold_and_random():
    params = KeepAwayParams()
    starts = env.reset_batch(jax.random.key(4), 60, params, CFG)
    key = jax.random.key(0)
    f = {n: float(ev.evaluate(m(CFG), None, starts, params, CFG, key=key).fitness.mean())
         for n, m in policies.BASELINES.items()}
    assert f["hold"] < 0.01 and f["random"] < 0.01
    assert f["heuristic"] > 5 * max(f["hold"], f["random"]) and f["heuristic"] < 0.9


def test_rollout_stacks_states():
    start = env.reset(jax.random.key(7), PARAMS, CFG)
    states, actions = ev.rollout(policies.heuristic(CFG), None, start, PARAMS, CFG, n_steps=50)
    assert states.keeper_x.shape == (51, 3) and actions.shape == (50,)
    assert int(states.t[0]) == 0 and jnp.all(jnp.diff(states.t) >= 0)
