"""NEAT networks as keep-away policies."""

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
    state = alg.init(jax.random.key(0), nparams.replace(weight_init_range=5.0, target_species=4), config)
    nets = alg.build_networks(state.population, config)  # [8, ...]
    starts = env.reset_batch(jax.random.key(1), 8, params, sim)
    policy = neat_policy(sim, config)
    batch_last = jax.tree.map(lambda x: jnp.moveaxis(x, 0, -1), nets)
    actions = np.asarray(policy.apply(batch_last, starts, None))
    for i in range(8):
        s_i = jax.tree.map(lambda x: x[..., i], starts)
        out = nw.activate(jax.tree.map(lambda x: x[i], nets), observe.fixed_obs(s_i, sim), config)
        assert actions[i] == int(observe.decode_ranked(out, s_i, sim))
    assert len(set(actions.tolist())) > 1  # different networks, different choices


def test_neat_population_evaluates_through_the_simulator():
    sim, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    config, nparams = presets.keepaway(population_size=6, species_capacity=4)
    state = alg.init(jax.random.key(2), nparams.replace(target_species=4), config)
    nets = alg.build_networks(state.population, config)
    starts = env.reset_batch(jax.random.key(3), 5, params, sim)
    stats = ev.evaluate(neat_policy(sim, config), nets, starts, params, sim, key=jax.random.key(4))
    assert stats.fitness.shape == (6, 5)
    assert np.all((np.asarray(stats.fitness) > 0) & (np.asarray(stats.fitness) <= 1))


def test_layout_mismatch_is_refused():
    sim = KeepAwayConfig.from_task("4v3")
    config, _ = presets.keepaway()
    with pytest.raises(ValueError, match="19 and 4"):
        neat_policy(sim, config, "full")
