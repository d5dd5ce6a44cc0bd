"""CPPN genomes on kx's NEAT: the authors' HyperNEAT weight mutation (``weight_scheme = 2``) and the
:func:`kx.hyperneat.presets.cppn` preset, measured on thousands of genomes (each rate within 5 standard
errors), and CPPN lineages that stay valid and evaluate as their genes say."""

import functools
import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_neat import _init, _tell, evolve, one

from kx.hyperneat import presets
from kx.neat import algorithm as alg
from kx.neat import checks as ck
from kx.neat import genome as gn
from kx.neat import network as nw
from kx.neat.types import HIDDEN, NEATError

CONFIG, PARAMS = presets.cppn()
G = CONFIG.n_initial_conns  # 15 links: columns 0..14 of an initial CPPN
K = len(CONFIG.activation_options)
N = 4000  # genomes per weight measurement


def near(measured, expected, n, z=5.0):
    """A binomial share within ``z`` standard errors."""
    se = math.sqrt(expected * (1 - expected) / n)
    assert abs(measured - expected) <= z * se + 1e-9, (measured, expected, n)


def near_sd(sample, sigma, z=5.0):
    """The sample sd of a normal-ish sample within ``z`` standard errors (se ~ sigma / sqrt(2 n))."""
    assert abs(sample.std() - sigma) <= z * sigma / math.sqrt(2 * sample.size), (sample.std(), sigma, sample.size)


# ----------------------------------------------------------------------------------- weight scheme 2


@functools.lru_cache(maxsize=None)
def _weights_fn():
    """One compiled ``(keys [N], genome, params) -> [N] genomes`` for every measurement (params traced)."""
    return jax.jit(jax.vmap(lambda k, g, p: gn.mutate_weights(k, g, p, CONFIG.genes), in_axes=(0, None, None)))


def mutated_weights(params, w0=0.0, seed=0):
    """``[N, 15]`` weights of N weight mutations of one initial CPPN whose 15 weights are all ``w0``."""
    g = gn.initial_genome(jax.random.key(0), CONFIG, PARAMS)
    g = g.replace(conn_weight=jnp.where(g.conn_valid, w0, 0.0))
    out = _weights_fn()(jax.random.split(jax.random.key(seed), N), g, params)
    w = np.asarray(out.conn_weight)
    assert not np.any(w[:, G:])  # empty columns stay empty
    return w[:, :G]


ONLY_ALL = dict(weight_all_share=1.0, weight_fraction_share=0.0, weight_reset_share=0.0)
ONLY_FRACTION = dict(weight_all_share=0.0, weight_fraction_share=1.0, weight_reset_share=0.0)
ONLY_RESET = dict(weight_all_share=0.0, weight_fraction_share=0.0, weight_reset_share=1.0)
ONLY_UNIFORM = dict(weight_all_share=0.0, weight_fraction_share=0.0, weight_reset_share=0.0)


def test_scheme2_shares_of_the_four_kinds():
    # Settings under which each mutation's kind can be read off its weights (the shares are the
    # preset's): the fraction kind changes nothing (fraction 0), the all kind all 15 links, the two count
    # kinds 8 links each, uniform steps within +-0.5, resets over +-5 (all 8 within 0.5: p = 1e-8).
    w = mutated_weights(PARAMS.replace(weight_select_fraction=0.0, weight_select_count=8, weight_perturb_power=0.5))
    n = (w != 0.0).sum(axis=1)
    big = np.abs(w).max(axis=1) > 0.5
    kinds = {"all": n == G, "fraction": n == 0, "reset": (n == 8) & big, "uniform": (n == 8) & ~big}
    assert np.all(sum(k.astype(int) for k in kinds.values()) == 1)
    for name, share in (("all", 0.25), ("fraction", 0.25), ("reset", 0.1), ("uniform", 0.4)):
        near(kinds[name].mean(), share, N)


def test_scheme2_links_touched_at_the_preset_values():
    # The preset itself: 15 links (all, 25%), Binomial(15, 0.25) links (fraction, 25%), 2 links (50%).
    n = (mutated_weights(PARAMS, seed=1) != 0.0).sum(axis=1)
    binom = lambda k: math.comb(G, k) * 0.25 ** k * 0.75 ** (G - k)
    near(np.mean(n == G), 0.25 + 0.25 * binom(G), N)
    near(np.mean(n == 2), 0.5 + 0.25 * binom(2), N)
    near(np.mean(n == 0), 0.25 * binom(0), N)
    near(np.mean(n == 4), 0.25 * binom(4), N)


def test_scheme2_gaussian_steps_on_every_link_or_a_fraction():
    d = mutated_weights(PARAMS.replace(**ONLY_ALL), seed=2)
    assert np.all(d != 0.0)  # every link
    near_sd(d, 0.3)
    near(np.mean(np.abs(d) < 0.3), 0.6827, d.size)  # P(|z| < 1)
    assert abs(d.mean()) < 5 * 0.3 / math.sqrt(d.size)
    d = mutated_weights(PARAMS.replace(**ONLY_FRACTION), seed=3)
    changed = d != 0.0
    near(changed.mean(), 0.25, changed.size)  # each link with p = 0.25
    near_sd(d[changed], 0.3)
    near(np.mean(np.abs(d[changed]) < 0.3), 0.6827, int(changed.sum()))


def test_scheme2_resets_and_uniform_steps_on_two_links():
    w = mutated_weights(PARAMS.replace(**ONLY_RESET), w0=0.5, seed=4)
    changed = w != 0.5
    assert np.all(changed.sum(axis=1) == 2)  # exactly 2 distinct links
    for col in range(G):  # each link equally likely
        near(changed[:, col].mean(), 2 / G, N)
    v = w[changed]
    assert np.all(np.abs(v) <= 5.0)
    for lo in (-5.0, -2.5, 0.0, 2.5):  # U(-5, 5): a quarter in each quarter of the range
        near(np.mean((v >= lo) & (v < lo + 2.5)), 0.25, v.size)
    w = mutated_weights(PARAMS.replace(**ONLY_UNIFORM), seed=5)
    changed = w != 0.0
    assert np.all(changed.sum(axis=1) == 2)
    d = w[changed]
    assert np.all(np.abs(d) <= 1.25) and np.abs(d).max() > 1.24
    near(np.mean(np.abs(d) < 0.625), 0.5, d.size)  # U(-1.25, 1.25)
    near(np.mean(d > 0), 0.5, d.size)
    np.testing.assert_allclose(d.std(), 1.25 / math.sqrt(3), rtol=0.03)


def test_scheme2_clamps_every_kind_to_the_weight_range():
    # uniform steps from 4.5: those above +0.5 (a share of 0.3) land on 5; from -4.5 on -5
    for w0, bound in ((4.5, 5.0), (-4.5, -5.0)):
        w = mutated_weights(PARAMS.replace(**ONLY_UNIFORM), w0=w0, seed=6)
        v = w[w != w0]
        assert np.all(np.abs(v) <= 5.0)
        near(np.mean(v == np.float32(bound)), 0.3, v.size)
    # Gaussian steps from 4.9: P(0.3 z > 0.1) = P(z > 1/3) = 0.3694 land on 5
    for only in (ONLY_ALL, ONLY_FRACTION):
        w = mutated_weights(PARAMS.replace(**only), w0=4.9, seed=7)
        v = w[w != np.float32(4.9)]
        assert np.all(np.abs(v) <= 5.0)
        near(np.mean(v == np.float32(5.0)), 0.36944, v.size)
    # resets span the weight range, whatever it is
    w = mutated_weights(PARAMS.replace(**ONLY_RESET, weight_range=3.0), w0=0.5, seed=8)
    v = w[w != 0.5]
    assert np.all(np.abs(v) <= 3.0) and np.abs(v).max() > 2.99
    near(np.mean(v < -1.5), 0.25, v.size)


def test_scheme2_is_deterministic_in_its_key():
    # (that mutate_weights' switch sends scheme 2 to mutate_weights_hyperneat, and schemes 0 and 1 to
    # theirs, the measurements above and tests/test_neat_mutation.py show)
    g = gn.initial_genome(jax.random.key(3), CONFIG, PARAMS)
    keys = jax.random.split(jax.random.key(4), 2)
    got = _weights_fn()(keys, g, PARAMS)
    chex.assert_trees_all_equal(got, _weights_fn()(keys, g, PARAMS))  # the same key, the same mutation
    assert not np.array_equal(np.asarray(got.conn_weight[0]), np.asarray(got.conn_weight[1]))  # keys differ


def test_bad_scheme2_values_are_refused_with_the_field_name():
    for field, value in (("weight_all_share", 1.5), ("weight_reset_share", -0.1), ("weight_step_sigma", -1.0),
                         ("weight_select_count", 0), ("weight_select_count", 9), ("weight_select_count", 2.5),
                         ("weight_scheme", 3)):
        with pytest.raises(NEATError, match=field):
            PARAMS.replace(**{field: value}).validate()
    with pytest.raises(NEATError, match="weight_all_share \\+ weight_fraction_share \\+ weight_reset_share"):
        PARAMS.replace(weight_all_share=0.5, weight_fraction_share=0.4, weight_reset_share=0.2).validate()
    PARAMS.validate()
    PARAMS.replace(**ONLY_RESET).validate()


# ------------------------------------------------------------------------------------------ the preset


def test_the_preset_records_its_values():
    c, p = CONFIG, PARAMS
    assert (c.n_inputs, c.n_outputs, c.n_initial_conns, c.population_size) == (4, 3, 15, 150)
    assert c.activation_options == ("identity", "gaussian", "bipolar_sigmoid", "abs", "sine")
    assert c.output_activation == "bipolar_sigmoid" and c.random_hidden_activation
    assert (c.n_hidden, c.genes, c.max_conns, c.add_link_cap, c.species_capacity) == (16, 63, 255, 40, 10)
    assert (float(p.add_node_prob), float(p.add_link_prob), float(p.delete_link_prob)) == (0.05, 0.15, 0.05)
    assert float(p.weight_mutate_prob) == 1.0 and int(p.weight_scheme) == 2
    assert float(p.weight_perturb_power) == 1.25 and float(p.weight_select_fraction) == 0.25
    assert float(p.weight_range) == 5.0 and float(p.initial_link_fraction) == 1.0
    assert (int(p.target_species), int(p.max_species_population), float(p.survival_threshold),
            float(p.compat_threshold)) == (10, 30, 0.2, 3.0)
    alg.validate(c, p)
    five, _ = presets.cppn(n_inputs=5)  # the distance input
    assert (five.n_initial_conns, five.n_hidden, five.genes) == (18, 16, 66)
    assert presets.cppn(population_size=40, max_add_links=0)[0].add_link_cap == 8  # overrides reach the config


# The reproduction path: one population of 150 copies of a CPPN with 3 hidden nodes (activations
# gaussian, sine, abs), each with its own weights, put through tell() many times with random fitness;
# every offspring's mutation is read off its structure.
HIDDEN_ACTS = ("gaussian", "sine", "abs")


def _cppn_with_hidden_nodes():
    g = gn.initial_genome(jax.random.key(0), CONFIG, PARAMS)
    i32 = lambda v: jnp.asarray(v, jnp.int32)
    structure = jax.jit(functools.partial(gn.apply_structure, config=CONFIG))  # one program, not op by op
    for j, col in enumerate((0, 4, 8)):
        nid, c = CONFIG.n_fixed + j, G + 2 * j
        g = structure(jax.random.key(j), g, gn.ADD_NODE, i32(col), i32(-1), i32(nid), i32(c), i32(c + 1), i32(c),
                      i32(c + 1), PARAMS)
    hid = np.asarray(g.node_kind) == HIDDEN
    acts = np.asarray(g.node_act).copy()
    acts[hid] = [CONFIG.act_id(a) for a in HIDDEN_ACTS]
    return g.replace(node_act=jnp.asarray(acts)), hid


@functools.lru_cache(maxsize=None)
def _offspring(activation_mutate_prob, tells):
    """``(parents, [tells] children populations, metrics)`` of tell() on the same parents."""
    g, hid = _cppn_with_hidden_nodes()
    pop = jax.tree.map(lambda x: jnp.broadcast_to(x, (CONFIG.population_size,) + x.shape), g)
    w = jax.random.uniform(jax.random.key(1), pop.conn_weight.shape, jnp.float32, -1.0, 1.0)
    pop = pop.replace(conn_weight=jnp.where(pop.conn_valid, w, 0.0))
    params = PARAMS.replace(activation_mutate_prob=activation_mutate_prob)
    state = _init(CONFIG)(jax.random.key(2), params)
    s = CONFIG.species_capacity
    state = state.replace(population=pop, species=jnp.zeros((CONFIG.population_size,), jnp.int32),
                          species_alive=jnp.zeros((s,), bool).at[0].set(True),
                          next_node_id=jnp.int32(CONFIG.n_fixed + 3), next_innov=jnp.int32(G + 6))
    kids, metrics = [], []
    for t in range(tells):
        k_fit, k_tell = jax.random.split(jax.random.key(100 + t))
        fit = jax.random.uniform(k_fit, (CONFIG.population_size,))
        new, m = _tell(CONFIG)(k_tell, pop, fit, state, params)
        kids.append(jax.tree.map(np.asarray, new.population))
        metrics.append(m)
    return jax.tree.map(np.asarray, pop), kids, metrics


def _classify(parents, kids):
    """Per offspring (elites, exact copies of a parent, left out): hidden and gene count changes, and
    whether an old hidden node changed its activation; the activations of new nodes; the (before,
    after) activations of changed old nodes."""
    f = CONFIG.n_fixed
    rows = []
    for k in kids:
        elite = np.array([np.any(np.all(w == parents.conn_weight, axis=1)) for w in k.conn_weight])
        dh = (k.node_kind == HIDDEN).sum(axis=1) - 3
        dg = k.conn_valid.sum(axis=1) - (G + 6)
        old = np.isin(k.node_id, np.arange(f, f + 3))  # the three original hidden nodes, wherever they sit now
        act_changed = np.zeros(len(k.node_id), bool)
        redraws = []  # (the node's activation before, after) for every changed original node
        for j, a in enumerate(HIDDEN_ACTS):
            now = np.sum(np.where(k.node_id == f + j, k.node_act, 0), axis=1)
            act_changed |= now != CONFIG.act_id(a)
            redraws += [(CONFIG.act_id(a), int(v)) for v in now[(now != CONFIG.act_id(a)) & ~elite]]
        new_node = (k.node_kind == HIDDEN) & ~old
        new_act = [int(k.node_act[i][new_node[i]][0]) for i in range(len(k.node_id)) if new_node[i].any()]
        rows.append((~elite, dh, dg, act_changed, new_act, redraws))
    keep = np.concatenate([r[0] for r in rows])
    cat = lambda j: np.concatenate([r[j] for r in rows])[keep]
    return cat(1), cat(2), cat(3), sum((r[4] for r in rows), []), sum((r[5] for r in rows), [])


@pytest.mark.slow  # moved out of the default suite to keep it under 7 minutes in a fresh clone
def test_the_presets_structural_rates_through_tell():
    parents, kids, metrics = _offspring(0.0, 150)
    for m in metrics:  # nothing capped or skipped: every drawn mutation was carried out
        assert int(m["link_capped"]) == int(m["node_overflow"]) == int(m["link_overflow"]) == 0
        assert int(m["link_exhausted"]) == 0
    dh, dg, act_changed, new_act, _ = _classify(parents, kids)
    n = dh.size
    assert n > 0.95 * 150 * CONFIG.population_size
    add_node, add_link, delete = (dh == 1) & (dg == 2), (dh == 0) & (dg == 1), (dh == 0) & (dg == -1)
    none = (dh == 0) & (dg == 0)
    assert np.all(add_node | add_link | delete | none)  # one structural mutation at most
    near(add_node.mean(), 0.05, n)
    near(add_link.mean(), 0.15, n)
    near(delete.mean(), 0.05, n)
    near(none.mean(), 0.75, n)
    assert not np.any(act_changed)  # the preset's activation mutation rate: 0 (ChangeNodeFunction 0.0)
    # a new hidden node draws its activation uniformly from the paper's five
    counts = np.bincount(new_act, minlength=K)
    for a in range(K):
        near(counts[a] / len(new_act), 1 / K, len(new_act))


@pytest.mark.slow  # ~10 s: the mutation's rate and effect are the default suite's (test_neat_mutation.py)
def test_activation_mutation_through_tell():
    # The preset's 0 raised to 0.3: an offspring without a structural mutation redraws one hidden
    # node's activation with p = 0.3, uniformly from the five (so it changes in 4/5 of the draws).
    parents, kids, _ = _offspring(0.3, 60)
    dh, dg, act_changed, _, redraws = _classify(parents, kids)
    light = (dh == 0) & (dg == 0)
    near(act_changed[light].mean(), 0.3 * (K - 1) / K, int(light.sum()))
    assert not np.any(act_changed[~light])  # structural offspring get no activation mutation
    # a changed node took each of the other four activations equally often
    before, after = np.array(redraws).T
    for v in range(K):
        near(np.mean(after == v), np.mean(before != v) / (K - 1), after.size)


# ------------------------------------------------------------------------------ lineages stay valid


@functools.lru_cache(maxsize=None)
def _run():
    # The preset with activation mutation on, so that activations change after birth too.
    return evolve(CONFIG, PARAMS.replace(activation_mutate_prob=0.2), 60, seed=11)


def _check_cppns(pop):
    pop = jax.tree.map(np.asarray, pop)
    assert ck.check_population(pop, CONFIG, weight_range=5.0) == []
    kind, act = pop.node_kind, pop.node_act
    assert np.all((act[kind == HIDDEN] >= 0) & (act[kind == HIDDEN] < K))
    assert np.all(act[kind == 3] == CONFIG.act_id("bipolar_sigmoid"))  # outputs keep theirs


@pytest.mark.slow  # ~11 s cold: the suite's 7 minutes on an AVX2 CPU
def test_cppn_lineages_under_the_preset_stay_valid():
    states, metrics = _run()
    # 60 generations x 150 offspring = 9000 mutations and crossovers
    for s in states[::10] + [states[-1]]:
        _check_cppns(s.population)
    final = jax.tree.map(np.asarray, states[-1].population)
    acts = final.node_act[final.node_kind == HIDDEN]
    assert set(acts.tolist()) == set(range(K)), np.bincount(acts, minlength=K)  # every activation in use
    assert sum(int(m["new_nodes"]) for m in metrics) > 100 and sum(int(m["new_links"]) for m in metrics) > 300
    assert sum(int(m["link_capped"]) + int(m["node_overflow"]) + int(m["link_overflow"]) for m in metrics) == 0


@jax.jit
def _outputs(pop, x):
    """``[P, n_outputs, B]``: every CPPN of ``pop`` built and evaluated on ``x`` ``[n_inputs, B]``."""
    return jax.vmap(lambda g: nw.forward(nw.build(g, CONFIG), x, CONFIG))(pop)


def assert_forward_equals_reference(pop, rows, x):
    out = np.asarray(_outputs(pop, jnp.asarray(x.T)))
    for i in rows:
        ref = np.array([nw.reference_activate(one(pop, i), xi, CONFIG) for xi in x]).T
        np.testing.assert_allclose(out[i], ref, rtol=1e-5, atol=1e-5)
    assert np.all(np.abs(out) <= 1.0)  # bipolar sigmoid outputs


@pytest.mark.slow  # ~15 s cold (150 CPPNs evolved 40 generations): the default suite checks the forward pass of
# evolved CPPNs against the reference in test_random_cppn_lineages_stay_valid below
def test_evolved_cppns_evaluate_as_their_genes_say():
    pop = _run()[0][-1].population
    hidden = np.asarray(jnp.sum(pop.node_kind == HIDDEN, axis=1))
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (6, CONFIG.n_inputs)).astype(np.float32)  # substrate coordinates
    # the largest CPPNs and a few at random
    assert_forward_equals_reference(pop, list(np.argsort(-hidden)[:6]) + list(rng.choice(150, 4, replace=False)), x)
    assert hidden.max() >= 3


probability = st.floats(0.0, 1.0)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), generations=st.integers(1, 40), structure=st.tuples(probability, probability,
       probability), activation=probability, scheme=st.sampled_from([0, 1, 2]), reenable=probability)
def test_random_cppn_lineages_stay_valid(seed, generations, structure, activation, scheme, reenable):
    """CPPN populations bred from scratch through tell() (random fitness) under drawn structural,
    activation and re-enable rates and weight scheme (structural rates up to 1 in all, so that hidden
    slots, genes and columns run out and are counted): params are traced, so one compiled step serves
    every example."""
    total = sum(structure)
    node, link, delete = (np.asarray(structure) * (0.999 / total if total > 0.999 else 1.0)).tolist()
    params = PARAMS.replace(add_node_prob=node, add_link_prob=link, delete_link_prob=delete,
                            activation_mutate_prob=activation, weight_scheme=scheme, reenable_prob=reenable)
    params.validate()
    states, _ = evolve(CONFIG, params, generations, seed=seed)
    pop = states[-1].population
    _check_cppns(pop)
    x = np.random.default_rng(seed).uniform(-1, 1, (3, CONFIG.n_inputs)).astype(np.float32)
    hidden = np.asarray(jnp.sum(pop.node_kind == HIDDEN, axis=1))
    assert_forward_equals_reference(pop, np.argsort(-hidden)[:3], x)
