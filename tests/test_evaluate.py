"""The batched evaluator: results equal single-episode runs; finished episodes are not paid for."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import make_state

from kx.sim import env, policies
from kx.sim import evaluate as ev
from kx.sim.types import KeepAwayConfig, KeepAwayParams, Reason

CFG = KeepAwayConfig()
PARAMS = KeepAwayParams(max_iterations=600)


def test_width_ladder():
    assert ev.width_ladder(4500) == [4500, 4096, 3072, 2048, 1792, 1536, 1280, 1024, 896, 768, 640, 512, 256,
                                     128, 64]
    assert ev.width_ladder(40) == [40]
    # the rungs an evaluation of 4500 lanes steps through: each the widest width at most 0.8 of the last
    assert ev.rungs(ev.width_ladder(4500)) == [4500, 3072, 2048, 1536, 1024, 768, 512, 256, 128, 64]
    assert all(w % 2 == 0 for w in ev.width_ladder(4501, multiple=2))


def test_evaluate_equals_single_episode_rollouts():
    n_pol, n_trials = 3, 8
    starts = env.reset_batch(jax.random.key(0), n_trials, PARAMS, CFG)
    mlp = policies.mlp_init(jax.random.key(1), n_pol, CFG)
    mlp["w2"] = mlp["w2"].at[:, :, 0].add(0.8)  # lean toward holding so that some episodes last
    policy = policies.mlp_policy(CFG)
    key = jax.random.key(9)
    stats = ev.evaluate(policy, mlp, starts, PARAMS, CFG, key=key)
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
    # 60 lanes: one rung, so its one call steps all 60 until the last episode ends, not 600 steps
    assert ev.rungs(ev.width_ladder(60)) == [60] and c.widths == (60,) and c.chunks == 1
    assert c.executed_steps == 60 * longest
    # live lane-steps counted independently: a plain lockstep loop counting the lanes not yet done
    # (holding never kicks, so the kick noise plays no part)
    def live_count(state, _):
        nxt = env.transition(state, jnp.maximum(state.holder, 0), jnp.zeros_like(state.holder), PARAMS, CFG)
        return nxt, jnp.sum(~state.done, dtype=jnp.int32)

    _, live = jax.jit(lambda s: jax.lax.scan(live_count, s, None, length=longest + 1))(starts)
    assert int(live[-1]) == 0 and c.live_steps == int(live.sum())


def test_eval_key_streams():
    """Evaluator noise and policy noise are ``fold_in(key, 0)`` and ``fold_in(key, 1)``, the values
    ``split(key)`` gave before they were named: results are those of a plain loop built on split."""
    for seed in range(4):
        key = jax.random.key(seed)
        got, old = ev.stream_keys(key), jax.random.split(key)
        for i in range(2):
            np.testing.assert_array_equal(jax.random.key_data(got[i]), jax.random.key_data(old[i]))
    n_pol, n_trials, params = 2, 10, KeepAwayParams(max_iterations=200)
    starts = env.reset_batch(jax.random.key(3), n_trials, params, CFG)
    key = jax.random.key(4)
    pol = policies.random_policy(CFG)
    stats = ev.evaluate(pol, {"unused": jnp.zeros((n_pol,))}, starts, params, CFG, key=key)
    noise_key, policy_key = jax.random.split(key)
    lanes = jnp.arange(n_pol * n_trials)
    state = jax.tree.map(lambda a: jnp.take(a, lanes % n_trials, axis=-1), starts)
    words = env.noise_words(noise_key, lanes % n_trials)
    s_max = env.noise_limit(params.kick_noise_deg)

    def step(state, _):
        keys = jax.vmap(lambda i, t: jax.random.fold_in(jax.random.fold_in(policy_key, i), t))(lanes, state.t)
        action = pol.apply(None, state, keys)
        return env.transition(state, action, env.kick_noise(words, state.t, s_max), params, CFG), None

    final, _ = jax.jit(lambda s: jax.lax.scan(step, s, None, length=200))(state)
    assert bool(jnp.all(final.done))
    np.testing.assert_array_equal(np.asarray(final.t).reshape(n_pol, n_trials), np.asarray(stats.iterations))
    np.testing.assert_array_equal(np.asarray(final.passes).reshape(n_pol, n_trials), np.asarray(stats.passes))
    assert int(final.passes.sum()) > 0  # the policy's draws and the kick noise mattered


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


@pytest.mark.parametrize("keepers, takers, min_margin, want", [
    # H (5,5) holds, pressed by a taker one king move away. To A (9,5) the takers at (6,6) and (7,7) reach
    # the lane exactly in time (margin 0: cheb(T, H + s u) - s/2 is 0 at s = 2 and s = 4); to B (9,9) the
    # taker at (6,6) is on the lane (margin -1/sqrt2): A gets the ball
    ([(5, 5), (9, 5), (9, 9)], [(6, 6), (7, 7)], 0.0, 1),
    # ... unless margins of 0 are not enough: hold
    ([(5, 5), (9, 5), (9, 9)], [(6, 6), (7, 7)], 2e-4, 0),
    # B (1,5), away from both takers (margin 1, at s = 0), is more open than A: B
    ([(5, 5), (9, 5), (1, 5)], [(6, 6), (7, 7)], 0.0, 2),
    # A (9,5) and B (5,9) both at margin 0: the first in keeper order, whichever it is
    ([(5, 5), (9, 5), (5, 9)], [(6, 6), (7, 7)], 0.0, 1),
    ([(5, 5), (5, 9), (9, 5)], [(6, 6), (7, 7)], 0.0, 1),
    # no taker within 2 king moves: hold
    ([(5, 5), (9, 5), (1, 5)], [(8, 8), (12, 2)], 0.0, 0),
])
def test_heuristic_decisions_hand_computed(keepers, takers, min_margin, want):
    state = make_state(keepers, takers, 0)
    got = jax.jit(policies.heuristic(CFG, min_margin=min_margin).apply)(None, state, None)
    assert int(got) == want


def test_rollout_stacks_states():
    start = env.reset(jax.random.key(7), PARAMS, CFG)
    states, actions = ev.rollout(policies.heuristic(CFG), None, start, PARAMS, CFG, n_steps=50)
    assert states.keeper_x.shape == (51, 3) and actions.shape == (50,)
    assert int(states.t[0]) == 0 and jnp.all(jnp.diff(states.t) >= 0)
