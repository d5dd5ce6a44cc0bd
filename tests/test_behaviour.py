"""The behaviour vector's fixed bounds (kx.sim.env.behaviour_bounds) and its normalisation."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TASKS, make_state, np_tree

from kx.sim import env
from kx.sim.types import DIST_SCALE, KeepAwayConfig, KeepAwayParams, Reason

CFG = KeepAwayConfig()
PARAMS = KeepAwayParams()
_step = jax.jit(env.transition, static_argnames=("config",))


def _brute_max_pair_sum(k: int, w: int, cells) -> float:
    pts = np.array(cells, float)
    best = 0.0
    for combo in itertools.combinations_with_replacement(range(len(pts)), k):
        p = pts[list(combo)]
        d = np.sqrt(((p[:, None] - p[None]) ** 2).sum(-1))
        best = max(best, d.sum() / 2)
    return best


def test_max_pair_distance_sum_hand_computed():
    s2 = math.sqrt(2)
    # 19 (p q + sqrt2 (floor(p^2/4) + floor(q^2/4))), best p per K
    assert env.max_pair_distance_sum(3, 20) == pytest.approx(19 * (2 + s2))  # p=2, q=1
    assert env.max_pair_distance_sum(4, 20) == pytest.approx(19 * (4 + 2 * s2))  # one per corner
    assert env.max_pair_distance_sum(5, 20) == pytest.approx(19 * (6 + 3 * s2))  # p=3, q=2
    assert env.max_pair_distance_sum(6, 20) == pytest.approx(19 * (8 + 5 * s2))  # p=4, q=2
    assert env.max_pair_distance_sum(8, 20) == pytest.approx(19 * (16 + 8 * s2))  # p=q=4


def test_max_pair_distance_sum_is_the_grid_maximum():
    w = 8
    grid = [(x, y) for x in range(w) for y in range(w)]
    assert env.max_pair_distance_sum(3, w) == pytest.approx(_brute_max_pair_sum(3, w, grid))
    ring = [c for c in grid if min(c) == 0 or max(c) == w - 1]  # a maximum lies on corners, so on the ring
    for k in (4, 5):
        assert env.max_pair_distance_sum(k, w) == pytest.approx(_brute_max_pair_sum(k, w, ring))


@pytest.mark.parametrize("task", TASKS)
def test_bounds_are_static_and_of_the_task_only(task):
    cfg = KeepAwayConfig.from_task(task)
    b = env.behaviour_bounds(cfg, PARAMS)
    assert all(type(v) is float for v in b)
    assert b == env.behaviour_bounds(cfg, KeepAwayParams(max_iterations=77)) == env.behaviour_bounds(cfg)
    pairs = cfg.n_keepers * (cfg.n_keepers - 1) // 2
    diag = 19 * math.sqrt(2)
    assert b[0] == 1.0 and b[2] == pytest.approx(diag / 2)
    assert b[1] == pytest.approx(env.max_pair_distance_sum(cfg.n_keepers, 20) / pairs)
    assert b[1] < diag


def test_counts_normalised_by_hand():
    # 40 iterations, 10 passes, keepers' pair distances summing to 3 * 10 cells, ball 5 cells from the centre
    t, passes = jnp.int32(40), jnp.int32(10)
    st = env.stats_from_counts(t, jnp.int32(Reason.INTERCEPTED), passes, jnp.int32(40 * 3 * 10 * DIST_SCALE),
                               jnp.int32(40 * 5 * DIST_SCALE), jnp.int32(29), PARAMS, CFG)
    beh = np.asarray(st.behaviour)
    np.testing.assert_allclose(beh, [10 / 40, 10 / (19 * (2 + math.sqrt(2)) / 3), 5 / (9.5 * math.sqrt(2))],
                               rtol=1e-6)
    assert int(st.passes) == 10 and float(st.fitness) == float(np.float32(39) / np.float32(4500))
    assert int(st.decisions) == 29  # a count, carried as it is
    # no iteration executed: zeros, not NaN
    st0 = env.stats_from_counts(*[jnp.int32(0)] * 6, PARAMS, CFG)
    assert np.all(np.asarray(st0.behaviour) == 0.0)


def test_keepers_on_corners_reach_the_dispersion_bound():
    # two keepers on a diagonal's corners and one on a third: each pair distance rounded to 1/32 cell
    # (608, 608, 860) is a hair above the exact bound, so the statistic is clipped to exactly 1
    q = 2 * round(DIST_SCALE * 19) + round(DIST_SCALE * 19 * math.sqrt(2))
    st = env.stats_from_counts(jnp.int32(5), jnp.int32(Reason.TIME_LIMIT), jnp.int32(0), jnp.int32(5 * q),
                               jnp.int32(5 * round(DIST_SCALE * 9.5 * math.sqrt(2))), jnp.int32(5), PARAMS, CFG)
    assert float(st.behaviour[1]) == 1.0 and float(st.behaviour[2]) == 1.0


def test_scripted_passes_per_iteration():
    # a pass to a keeper two cells east completes in the iteration of its kick: one pass in one iteration
    # is the bound, 1.0; then three iterations of holding with the takers far away: 1 pass in 4
    s = make_state([(2, 2), (4, 2), (2, 10)], [(15, 15), (17, 17)], holder=0)
    s = _step(s, jnp.int32(1), jnp.int32(0), PARAMS, config=CFG)
    o = np_tree(s)
    assert o["passes"] == 1 and o["holder"] == 1 and o["t"] == 1
    assert float(env.episode_stats(s, PARAMS, CFG).behaviour[0]) == 1.0
    for _ in range(3):
        s = _step(s, jnp.int32(1), jnp.int32(0), PARAMS, config=CFG)
    o = np_tree(s)
    assert o["passes"] == 1 and o["t"] == 4 and o["reason"] == Reason.RUNNING
    assert float(env.episode_stats(s, PARAMS, CFG).behaviour[0]) == 0.25
    # a hand-off to a teammate on the holder's cell also completes at once
    h = make_state([(6, 6), (6, 6), (12, 3)], [(16, 16), (17, 17)], holder=0)
    h = _step(h, jnp.int32(1), jnp.int32(0), PARAMS, config=CFG)
    assert int(h.passes) == 1 and int(h.holder) == 1 and int(h.t) == 1


def test_behaviour_in_unit_interval_over_random_play():
    cfg = KeepAwayConfig.from_task("4v3")
    s = env.reset_batch(jax.random.key(5), 64, PARAMS, cfg)
    step = jax.jit(lambda s, a, k: env.step(k, s, a, PARAMS, cfg))
    keys = jax.random.split(jax.random.key(6), 80)
    for i in range(80):
        a = jax.random.randint(keys[i], (64,), 0, cfg.n_keepers)
        s = step(s, a, keys[i])
    o = np_tree(s)
    beh = np.asarray(env.episode_stats(s, PARAMS, cfg).behaviour)
    assert beh.shape == (3, 64) and np.all(beh >= 0) and np.all(beh <= 1)
    np.testing.assert_allclose(beh[0], o["passes"] / np.maximum(o["t"], 1), rtol=1e-6)
    assert np.all(o["passes"] <= o["t"])


def test_jitted_fitness_is_the_exact_quotient():
    # XLA may turn a division by a broadcast scalar into a multiplication by its reciprocal (one ulp
    # off); the evaluator's compiled normalisation must equal an episode's eager one exactly
    t = jnp.arange(1, 601, dtype=jnp.int32)
    z = jnp.zeros_like(t)
    params = KeepAwayParams(max_iterations=600)
    f = jax.jit(env.stats_from_counts, static_argnames="config")
    got = np.asarray(f(t, z + Reason.TIME_LIMIT, z, z, z, z, params, config=CFG).fitness)
    np.testing.assert_array_equal(got, np.arange(1, 601, dtype=np.float32) / np.float32(600))
