"""The rates and effects of the non-structural mutations (weights, re-enabling, activations) as
:func:`kx.neat.innovation.mutate_population` applies them: measured on thousands of genomes against the
parameters, with elites (``frozen``) untouched."""

import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np

from kx.neat import genome as gn
from kx.neat import innovation as inn
from kx.neat.types import HIDDEN, NEATConfig, NEATParams

CFG = NEATConfig(n_inputs=3, n_outputs=2, population_size=24, max_nodes=12, max_conns=40, species_capacity=6)
ACT = NEATConfig(n_inputs=3, n_outputs=2, population_size=24, max_nodes=12, max_conns=40, species_capacity=6,
                 activation_options=("sigmoid", "identity", "gaussian", "bipolar_sigmoid", "abs", "sine"),
                 output_activation="identity")
N = 4000  # genomes per measurement
# Only the mutation under test is on (structural mutations off).
OFF = NEATParams(add_node_prob=0.0, add_link_prob=0.0, weight_mutate_prob=0.0, reenable_prob=0.0,
                 activation_mutate_prob=0.0)


@functools.lru_cache(maxsize=None)
def _mutate(config):
    return jax.jit(functools.partial(inn.mutate_population, config=config))


def mutate(pop, params, config=CFG, seed=0, frozen_share=0.1):
    frozen = jax.random.bernoulli(jax.random.key(1000 + seed), frozen_share, (pop.node_id.shape[0],))
    new, _, _, _ = _mutate(config)(jax.random.key(seed), pop, frozen, jnp.int32(config.n_fixed + 10),
                                   jnp.int32(config.n_initial_conns + 10), params)
    return jax.tree.map(np.asarray, new), np.asarray(frozen)


def population(weight=3.0, config=CFG):
    """N fully connected initial genomes, every weight set to ``weight``."""
    pop = jax.vmap(lambda k: gn.initial_genome(k, config, NEATParams()))(jax.random.split(jax.random.key(7), N))
    return pop.replace(conn_weight=jnp.where(pop.conn_valid, weight, 0.0))


def assert_untouched(new, old, rows):
    chex.assert_trees_all_equal(jax.tree.map(lambda x: x[rows], new), jax.tree.map(lambda x: np.asarray(x)[rows], old))


def near(measured, expected, n, z=5.0):
    """A binomial share within ``z`` standard errors."""
    se = np.sqrt(expected * (1 - expected) / n)
    assert abs(measured - expected) <= z * se + 1e-9, (measured, expected, n)


def test_stanley_weight_mutation_rates_steps_and_bounds():
    pop = population(3.0)
    params = OFF.replace(weight_scheme=0, weight_mutate_prob=0.7, weight_mutate_rate=0.6, weight_perturb_prob=0.8,
                         weight_perturb_power=0.5, weight_init_range=1.0, weight_range=5.0)
    new, frozen = mutate(pop, params)
    assert_untouched(new, pop, frozen)
    assert_untouched(new.replace(conn_weight=np.asarray(pop.conn_weight)), pop, ~frozen)  # only weights change
    valid = np.asarray(pop.conn_valid)[~frozen]
    w = new.conn_weight[~frozen][valid].reshape(-1, CFG.n_initial_conns)  # [genomes, 8]
    changed = w != 3.0
    hit = changed.any(axis=1)
    # An offspring gets a weight mutation with weight_mutate_prob; then each gene with weight_mutate_rate.
    near(hit.mean(), 0.7 * (1 - 0.4 ** 8), hit.size)
    near(changed[hit].mean(), 0.6 / (1 - 0.4 ** 8), changed[hit].size)
    # Perturbed genes stay within 0.5 of 3; replaced ones are U(-1, 1): the two are told apart.
    d = w[changed] - 3.0
    perturbed, replaced = np.abs(d) <= 0.5, np.abs(w[changed]) <= 1.0
    assert np.all(perturbed ^ replaced)
    near(perturbed.mean(), 0.8, d.size)
    np.testing.assert_allclose(d[perturbed].std(), 0.5 / np.sqrt(3), rtol=0.04)  # U(-0.5, 0.5)
    assert abs(d[perturbed].mean()) < 0.02
    np.testing.assert_allclose(w[changed][replaced].std(), 1 / np.sqrt(3), rtol=0.06)  # U(-1, 1)
    # Clipped to weight_range: at 3.2 every perturbation beyond +0.2 (a share of 0.3) lands on the bound.
    new, frozen = mutate(pop, params.replace(weight_range=3.2), seed=1)
    w = new.conn_weight[~frozen]
    assert np.abs(w).max() == np.float32(3.2)
    perturbed = w[(w != 3.0) & (w > 1.0)]
    near(np.mean(perturbed == np.float32(3.2)), 0.3, perturbed.size)


def test_sharpneat_weight_mutation_kinds_selections_steps_and_bounds():
    pop = population(3.0)
    # A large step of sigma 0 changes nothing; every gene is selected in the fraction selection: each
    # offspring's kind can be read off its weights.
    params = OFF.replace(weight_scheme=1, weight_mutate_prob=1.0, weight_small_sigma=0.02, weight_large_sigma=0.0,
                         weight_select_fraction=1.0, weight_init_range=1.0)
    new, frozen = mutate(pop, params)
    assert_untouched(new, pop, frozen)
    valid = np.asarray(pop.conn_valid)[~frozen]
    w = new.conn_weight[~frozen][valid].reshape(-1, CFG.n_initial_conns)
    changed = w != 3.0
    n_changed = changed.sum(axis=1)
    small = (n_changed > 0) & np.all(np.where(changed, np.abs(w - 3.0) < 0.2, True), axis=1)
    reset = (n_changed > 0) & np.all(np.where(changed, np.abs(w) <= 1.0, True), axis=1)
    large = n_changed == 0
    assert np.all(small.astype(int) + reset + large == 1)
    g = w.shape[0]
    near(small.mean(), 0.455, g)
    near(large.mean(), 0.454, g)
    near(reset.mean(), 0.091, g)
    # The selections: 1, 2 or 3 genes, or every gene (fraction 1), equally likely.
    for k in (1, 2, 3, 8):
        near(np.mean(n_changed[~large] == k), 0.25, int(np.sum(~large)))
    np.testing.assert_allclose((w - 3.0)[changed & small[:, None]].std(), 0.02, rtol=0.05)
    # A large step: sigma 1; clipped to weight_range.
    new, frozen = mutate(pop, params.replace(weight_small_share=0.0, weight_large_share=1.0, weight_large_sigma=1.0),
                         seed=1)
    w = new.conn_weight[~frozen][np.asarray(pop.conn_valid)[~frozen]]
    d = w[w != 3.0] - 3.0
    near(np.mean(np.abs(d) < 1.0), 0.6827, d.size)  # P(|z| < 1) of a unit Gaussian
    assert np.abs(w).max() == np.float32(5.0) and np.all(np.abs(w) <= 5.0)
    # clipped at 5: P(3 + z > 5) = P(z > 2)
    near(np.mean(d == np.float32(2.0)), 0.02275, d.size)


def test_weight_mutation_prob_is_per_offspring_for_both_schemes():
    pop = population(3.0)
    for scheme in (0, 1):
        params = OFF.replace(weight_scheme=scheme, weight_mutate_prob=0.35, weight_select_fraction=1.0)
        new, frozen = mutate(pop, params, seed=2 + scheme)
        hit = np.any(new.conn_weight[~frozen] != np.asarray(pop.conn_weight)[~frozen], axis=1)
        # scheme 0 at rate 1 changes every gene; scheme 1 always selects at least one gene (fraction 1)
        near(hit.mean(), 0.35, hit.size)


def with_disabled(seed=3):
    """N initial genomes with each gene disabled with p = 0.4."""
    pop = population(0.5)
    off = jax.random.bernoulli(jax.random.key(seed), 0.4, pop.conn_valid.shape) & pop.conn_valid
    return pop.replace(conn_enabled=pop.conn_enabled & ~off)


def test_reenable_rate_and_effect():
    pop = with_disabled()
    new, frozen = mutate(pop, OFF.replace(reenable_prob=0.35))
    assert_untouched(new, pop, frozen)
    old_en, new_en = np.asarray(pop.conn_enabled), new.conn_enabled
    assert not np.any(old_en & ~new_en)  # an enabled gene is never disabled
    assert_untouched(new.replace(conn_enabled=old_en), pop, slice(None))  # nothing but the flags changes
    gained = (new_en & ~old_en).sum(axis=1)
    assert gained.max() == 1  # one gene at a time
    has_off = (np.asarray(pop.conn_valid) & ~old_en).any(axis=1) & ~frozen
    assert np.all(gained[~has_off] == 0)
    near(gained[has_off].mean(), 0.35, int(has_off.sum()))
    # The gene is uniform among the disabled ones: its rank among them, scaled to (0, 1), averages 1/2.
    rows = np.flatnonzero(gained == 1)
    off = np.asarray(pop.conn_valid) & ~old_en
    pos = [(np.cumsum(off[r])[np.argmax(new_en[r] & ~old_en[r])] - 0.5) / off[r].sum() for r in rows]
    assert abs(np.mean(pos) - 0.5) < 5 * 0.29 / np.sqrt(len(rows))


def hidden_population():
    """N copies of a genome with 3 hidden nodes (splits of links 0, 1, 2), their activations drawn at random."""
    g = gn.initial_genome(jax.random.key(0), ACT, NEATParams())
    i32 = lambda v: jnp.asarray(v, jnp.int32)
    structure = jax.jit(functools.partial(gn.apply_structure, config=ACT))  # one program, not op by op
    for j, col in enumerate((0, 1, 2)):
        nid, c = ACT.n_fixed + j, ACT.n_initial_conns + 2 * j
        g = structure(jax.random.key(j), g, gn.ADD_NODE, i32(col), i32(-1), i32(nid), i32(c), i32(c + 1), i32(c),
                      i32(c + 1), NEATParams())
    hid = np.asarray(g.node_kind) == HIDDEN
    assert hid.sum() == 3
    pop = jax.tree.map(lambda x: jnp.broadcast_to(x, (N,) + x.shape), g)
    acts = jax.random.randint(jax.random.key(5), (N, ACT.max_nodes), 0, len(ACT.activation_options), jnp.int32)
    return pop.replace(node_act=jnp.where(hid, acts, pop.node_act)), hid


def test_activation_mutation_rate_and_effect():
    pop, hid = hidden_population()
    k = len(ACT.activation_options)
    new, frozen = mutate(pop, OFF.replace(activation_mutate_prob=0.4), config=ACT)
    assert_untouched(new, pop, frozen)
    assert_untouched(new.replace(node_act=np.asarray(pop.node_act)), pop, slice(None))  # nothing else changes
    old_act = np.asarray(pop.node_act)
    diff = new.node_act != old_act
    assert not np.any(diff[:, ~hid])  # only hidden nodes change (the outputs keep identity)
    assert diff.sum(axis=1).max() == 1
    assert np.all((new.node_act >= 0) & (new.node_act < k))
    # redrawn with activation_mutate_prob, uniformly from the k options: a change in (k - 1) / k of them
    near(diff[~frozen].any(axis=1).mean(), 0.4 * (k - 1) / k, int(np.sum(~frozen)))
    # each hidden node equally likely; each new value equally likely
    node_share = diff[:, hid].sum(axis=0) / diff.sum()
    assert np.all(np.abs(node_share - 1 / 3) < 0.05), node_share
    counts = np.bincount(new.node_act[diff], minlength=k) / diff.sum()
    assert np.all(np.abs(counts - 1 / k) < 0.04), counts
    # with one activation option there is nothing to redraw
    new, _ = mutate(population(1.0), OFF.replace(activation_mutate_prob=1.0))
    assert np.all(new.node_act == np.asarray(population(1.0).node_act))
