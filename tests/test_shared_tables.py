"""Shared per-generation tables (``Policy.shared``, :class:`kx.sim.policies.Shared`): the evaluator passes
one table to every lane instead of copying parameters per lane. The results equal the per-lane mode and
single-episode rollouts, in batches that really narrow; new table values do not recompile; 150 tables of
400 x 400 float32 over 4500 lanes fit in well under the 2.9 GB that per-lane copies would take."""

import os
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx.sim import env, observe, policies
from kx.sim import evaluate as ev
from kx.sim.types import KeepAwayConfig, KeepAwayParams

CFG = KeepAwayConfig()
PARAMS = KeepAwayParams(max_iterations=300)
FIELDS = ("fitness", "iterations", "reason", "passes", "behaviour")


def _linear_table(n_pol: int, seed: int) -> dict:
    n = observe.n_inputs("fixed", CFG) * observe.n_outputs("fixed", CFG) + observe.n_outputs("fixed", CFG)
    return policies.linear_params(jax.random.normal(jax.random.key(seed), (n_pol, n)), CFG)


def test_shared_linear_equals_per_lane():
    starts = env.reset_batch(jax.random.key(0), 12, PARAMS, CFG)
    table = _linear_table(5, seed=1)
    key = jax.random.key(2)
    a = ev.evaluate(policies.linear_policy(CFG), table, starts, PARAMS, CFG, key=key)
    b = ev.evaluate(policies.linear_policy(CFG, shared=True), table, starts, PARAMS, CFG, key=key)
    assert policies.linear_policy(CFG, shared=True).shared and not policies.linear_policy(CFG).shared
    for f in FIELDS:  # bit for bit: the same sums in the same order
        np.testing.assert_array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)), err_msg=f)
    assert len(set(np.asarray(a.iterations).ravel().tolist())) > 3  # the policies differ


def test_new_table_values_do_not_recompile():
    starts = env.reset_batch(jax.random.key(3), 10, PARAMS, CFG)
    pol = policies.linear_policy(CFG, shared=True)
    key = jax.random.key(4)
    first = ev.evaluate(pol, _linear_table(4, seed=5), starts, PARAMS, CFG, key=key)
    n_compiled = ev._rungs._cache_size()
    second = ev.evaluate(pol, _linear_table(4, seed=6), starts, PARAMS, CFG, key=key)
    assert ev._rungs._cache_size() == n_compiled
    assert not np.array_equal(np.asarray(first.iterations), np.asarray(second.iterations))


def test_rollout_of_a_shared_policy_plays_its_row():
    start = env.reset(jax.random.key(7), PARAMS, CFG)
    table = _linear_table(4, seed=8)
    key = jax.random.key(9)
    for g in (0, 3):
        a, act_a = ev.rollout(policies.linear_policy(CFG), jax.tree.map(lambda p: p[g], table), start, PARAMS,
                              CFG, key=key, n_steps=60)
        b, act_b = ev.rollout(policies.linear_policy(CFG, shared=True), table, start, PARAMS, CFG, key=key,
                              n_steps=60, policy_index=g)
        np.testing.assert_array_equal(np.asarray(act_a), np.asarray(act_b))
        for f in ("t", "reason", "passes", "keeper_x", "ball_x"):
            np.testing.assert_array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)), err_msg=f)


N_POL, N_TRIALS = 12, 50  # 600 lanes: the ladder 600, 512, 256, 128, 64
NARROW = KeepAwayParams(max_iterations=120)  # some episodes reach the time limit; rollouts stay short


def _case(mode: str):
    """(policy, the evaluator's params, and ``lanes(g_idx) -> (params, vmap axes, policy index)`` giving
    each lane's rollout parameters for lanes of policies ``g_idx``)."""
    if mode == "random":  # stochastic; params only set G (the random policy reads none)
        dummy = {"unused": jnp.zeros((N_POL,))}
        return policies.random_policy(CFG), dummy, lambda g: ({"unused": jnp.zeros(len(g))}, 0, np.zeros_like(g))
    table = _linear_table(N_POL, seed=11)
    if mode == "linear":  # per lane: each lane's own row of the table
        return (policies.linear_policy(CFG), table,
                lambda g: (jax.tree.map(lambda p: p[g], table), 0, np.zeros_like(g)))
    # shared: the whole table for every lane, the row to play given by the policy index
    return policies.linear_policy(CFG, shared=True), table, lambda g: (table, None, g)


# 25-40 s cold each: the shared mode (CMA-ES's and HyperNEAT's) in the default suite, the others slow
@pytest.mark.parametrize("mode", [pytest.param("linear", marks=pytest.mark.slow), "linear-shared",
                                  pytest.param("random", marks=pytest.mark.slow)])
def test_narrowing_batch_equals_single_episodes(mode):
    """Every lane of a batch that narrows through several widths equals its episode run alone
    (:func:`kx.sim.evaluate.rollout`; policy g's trial i is lane g * T + i, whose policy keys a
    stochastic policy plays)."""
    policy, eval_params, one_params_all = _case(mode)
    starts = env.reset_batch(jax.random.key(10), N_TRIALS, NARROW, CFG)
    key = jax.random.key(12)
    c = ev.EvalCounters()
    stats = ev.evaluate(policy, eval_params, starts, NARROW, CFG, key=key, counters=c)
    assert c.widths[0] == N_POL * N_TRIALS and len(c.widths) >= 3, c.widths
    assert list(c.widths) == sorted(set(c.widths), reverse=True) and set(c.widths) <= set(
        ev.width_ladder(N_POL * N_TRIALS))
    # every lane's episode alone: rollout vmapped over the lanes (each a batch of one, no compaction;
    # 600 separate calls cost 20 s on 2 cores for the same figures)
    g_idx = np.repeat(np.arange(N_POL), N_TRIALS)
    t_idx = np.tile(np.arange(N_TRIALS), N_POL)
    lanes = np.arange(N_POL * N_TRIALS)
    start_all = jax.tree.map(lambda a: jnp.moveaxis(a[..., t_idx], -1, 0), starts)
    params_all, params_axes, index_all = one_params_all(g_idx)

    def one(p, start, trial, index, lane):
        return ev._rollout(policy, p, start, key, NARROW, trial, index, lane, config=CFG,
                           n_steps=int(NARROW.max_iterations))

    states, _ = jax.vmap(one, in_axes=(params_axes, 0, 0, 0, 0))(
        params_all, start_all, jnp.asarray(t_idx, jnp.int32), jnp.asarray(index_all, jnp.int32),
        jnp.asarray(lanes, jnp.int32))
    final = jax.tree.map(lambda a: np.moveaxis(np.asarray(a[:, -1]), 0, -1).reshape(
        a.shape[2:] + (N_POL, N_TRIALS)), states)
    assert np.all(final.done)
    # the integer counters of every episode, exactly
    for f, got in (("t", stats.iterations), ("reason", stats.reason), ("passes", stats.passes)):
        np.testing.assert_array_equal(getattr(final, f), np.asarray(got), err_msg=f)
    # the floats are a function of those and of the two behaviour accumulators: computed from the
    # episodes' own counters by the evaluator's function, they are equal bit for bit
    counts = [np.ravel(getattr(final, f)) for f in ev.COUNTERS]
    alone = jax.jit(env.stats_from_counts, static_argnames="config")(*counts, NARROW, config=CFG)
    np.testing.assert_array_equal(np.asarray(alone.fitness).reshape(N_POL, N_TRIALS), np.asarray(stats.fitness))
    np.testing.assert_array_equal(np.asarray(alone.behaviour).reshape(3, N_POL, N_TRIALS),
                                  np.asarray(stats.behaviour))
    # live lane-steps counted independently: the iterations of the episodes run alone
    assert c.live_steps == int(final.t.sum())
    assert c.live_steps < c.executed_steps < c.widths[0] * int(final.t.max())


@pytest.mark.slow  # moved out of the default suite to keep it under 7 minutes in a fresh clone
def test_150_shared_tables_of_400x400_over_4500_lanes_fit_in_1_5_gb():
    """The evaluator keeps one copy of the 96 MB table (per-lane copies would take 4500 x 400 x 400 x 4
    bytes = 2.9 GB). A fresh process, so that the peak is this evaluation's."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    environ = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    # one device, whatever the caller's XLA_FLAGS say (the suite's compile flags kept)
    environ["XLA_FLAGS"] = re.sub(r"--xla_force_host_platform_device_count=\S*", "", environ.get("XLA_FLAGS", ""))
    out = subprocess.run([sys.executable, os.path.join(root, "tests", "shared_table_memory.py")], env=environ,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    words = out.stdout.split()
    peak_bytes = int(words[words.index("peak_kib") + 1]) * 1024
    widths = words[words.index("widths") + 1].split(",")
    assert len(widths) >= 3  # the batch narrowed: compaction ran with the table in place
    assert peak_bytes < 1.5e9, f"peak RSS {peak_bytes / 1e9:.2f} GB"
