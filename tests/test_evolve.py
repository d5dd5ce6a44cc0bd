"""NEAT networks as keep-away policies."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx.evolve.policy import neat_policy
from kx.neat import algorithm as alg
from kx.neat import network as nw
from kx.neat import presets
from kx.sim import env, observe
from kx.sim import evaluate as ev
from kx.sim.types import KeepAwayConfig, KeepAwayParams


def test_neat_policy_acts_on_each_lanes_own_network():
    sim, params = KeepAwayConfig.from_task("4v3"), KeepAwayParams()
    config, nparams = presets.keepaway(population_size=8, species_capacity=4)
    # (jitted: op by op, their hundreds of operations each compile apart)
    state = jax.jit(functools.partial(alg.init, config=config))(
        jax.random.key(0), nparams.replace(weight_init_range=5.0, target_species=4))
    nets = alg.build_networks(state.population, config)  # [8, ...]
    starts = jax.jit(env.reset_batch, static_argnums=(1, 3))(jax.random.key(1), 8, params, sim)
    policy = neat_policy(sim, config)
    batch_last = jax.tree.map(lambda x: jnp.moveaxis(x, 0, -1), nets)
    actions = np.asarray(jax.jit(lambda n, s: policy.apply(n, s, None))(batch_last, starts))
    for i in range(8):
        s_i = jax.tree.map(lambda x: x[..., i], starts)
        x_i = observe.fixed_obs(s_i, sim)[:, None]
        out = nw.forward(jax.tree.map(lambda x: x[i], nets), x_i, config, pre_activation=True)[:, 0]
        assert actions[i] == int(observe.decode_ranked(out, s_i, sim))
    assert len(set(actions.tolist())) > 1  # different networks, different choices


def test_neat_policy_decides_on_the_output_sums_not_on_saturated_sigmoids():
    """Outputs whose sums are 4 and 5 are both exactly 1.0 after NEAT's sigmoid in float32; the policy
    compares the sums (the same order in exact arithmetic): the larger acts, exact ties go to hold."""
    sim, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    config, _ = presets.keepaway(population_size=8, species_capacity=4)
    r, n_in1 = config.n_hidden + config.n_outputs, config.n_inputs + 1
    state = env.reset(jax.random.key(5), params, sim)
    order = np.asarray(observe.teammate_order(state, sim))  # hold, nearest teammate, next

    def decide(bias):
        w_in = jnp.zeros((r, n_in1), jnp.float32).at[config.n_hidden:, -1].set(jnp.asarray(bias, jnp.float32))
        net = nw.Network(w_in=w_in, w_hid=jnp.zeros((r, config.n_hidden), jnp.float32),
                         act=jnp.full((r,), config.act_id("sigmoid"), jnp.int32))
        return int(neat_policy(sim, config).apply(net, state, None))

    sat = nw.activate(nw.Network(w_in=jnp.zeros((r, n_in1)).at[config.n_hidden:, -1].set(jnp.array([4.0, 5.0, 0.0])),
                                 w_hid=jnp.zeros((r, config.n_hidden)), act=jnp.zeros((r,), jnp.int32)),
                      jnp.zeros((config.n_inputs,)), config)
    assert float(sat[0]) == float(sat[1]) == 1.0  # saturated: a tie after the activation
    assert decide([4.0, 5.0, 0.0]) == order[1]  # pass to the nearest teammate
    assert decide([5.0, 4.0, 0.0]) == order[0]  # hold
    assert decide([5.0, 5.0, 5.0]) == order[0]  # an exact tie goes to hold
    assert decide([-1.0, -3.0, 6.0]) == order[2]


@pytest.mark.slow  # ~6 s: every run test of the default suite evaluates NEAT populations through the simulator
def test_neat_population_evaluates_through_the_simulator():
    sim, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    config, nparams = presets.keepaway(population_size=6, species_capacity=4)
    state = alg.init(jax.random.key(2), nparams.replace(target_species=4), config)
    nets = alg.build_networks(state.population, config)
    starts = env.reset_batch(jax.random.key(3), 5, params, sim)
    stats = ev.evaluate(neat_policy(sim, config), nets, starts, params, sim, key=jax.random.key(4))
    # each genome's episodes are its own network's, wherever it sits in the population: the same
    # population in another order (the same shapes: no new compilation) gives each genome the same
    # results. Every place gets a genome that plays differently from the one there before, so results
    # that stayed with the place (or came from another genome's network) would show.
    perm = np.asarray([3, 4, 5, 0, 1, 2])
    moved = ev.evaluate(neat_policy(sim, config), jax.tree.map(lambda a: a[perm], nets), starts, params, sim,
                        key=jax.random.key(4))
    for f in ("fitness", "iterations", "reason", "passes"):
        np.testing.assert_array_equal(np.asarray(getattr(moved, f)), np.asarray(getattr(stats, f))[perm], err_msg=f)
    np.testing.assert_array_equal(np.asarray(moved.behaviour), np.asarray(stats.behaviour)[:, perm])
    it = np.asarray(stats.iterations)
    assert all(not np.array_equal(it[perm[i]], it[i]) for i in range(6)), it


def test_layout_mismatch_is_refused():
    sim = KeepAwayConfig.from_task("4v3")
    config, _ = presets.keepaway()
    with pytest.raises(ValueError, match="19 and 4"):
        neat_policy(sim, config, "full")
