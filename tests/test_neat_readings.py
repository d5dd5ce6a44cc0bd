"""The NEAT operators behind the SharpNEAT reading of Table 2: partial initial connectivity, delete link,
SharpNEAT's weight mutation, and the presets that use them."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from test_neat import CFG, evolve

from kx.neat import checks as ck
from kx.neat import genome as gn
from kx.neat import presets
from kx.neat.types import NEATParams

SHARP = NEATParams(weight_scheme=1, weight_mutate_prob=1.0, add_node_prob=0.2, add_link_prob=0.3,
                   delete_link_prob=0.2, initial_link_fraction=0.3, target_species=4, mutation_only_prob=0.5,
                   interspecies_prob=0.2)


def test_initial_link_fraction():
    m = CFG.n_initial_conns
    full = jax.vmap(lambda k: gn.initial_genome(k, CFG, NEATParams()))(jax.random.split(jax.random.key(0), 200))
    assert np.all(np.asarray(full.conn_valid[:, :m])) and not np.any(np.asarray(full.conn_valid[:, m:]))
    part = jax.vmap(lambda k: gn.initial_genome(k, CFG, NEATParams(initial_link_fraction=0.05)))(
        jax.random.split(jax.random.key(0), 2000))
    n = np.asarray(part.conn_valid).sum(axis=1)
    assert n.min() >= 1 and not np.any(np.asarray(part.conn_valid[:, m:]))  # a genome keeps at least one link
    # each of the 8 links with p = 0.05, and one more when none was drawn (p = 0.95^8 = 0.66)
    np.testing.assert_allclose(n.mean(), 8 * 0.05 + 0.95 ** 8, atol=0.05)
    for i in range(0, 2000, 97):
        assert ck.check_genome(jax.tree.map(lambda a: a[i], part), CFG) == []
    # a present link keeps its innovation number and column s * n_outputs + o
    cols = np.flatnonzero(np.asarray(part.conn_valid[3]))
    assert np.array_equal(np.asarray(part.conn_innov[3])[cols], cols)


def test_delete_link_clears_the_column_and_never_takes_the_last_gene():
    g = gn.initial_genome(jax.random.key(1), CFG, NEATParams())
    out = gn.apply_structure(jax.random.key(2), g, gn.DELETE_LINK, jnp.int32(5), jnp.int32(-1), jnp.int32(-1),
                             jnp.int32(-1), jnp.int32(-1), jnp.int32(-1), jnp.int32(-1), NEATParams(), CFG)
    o = jax.tree.map(np.asarray, out)
    assert not o.conn_valid[5] and o.conn_innov[5] == -1 and o.conn_src[5] == -1 and o.conn_weight[5] == 0
    assert o.conn_valid.sum() == CFG.n_initial_conns - 1 and ck.check_genome(out, CFG) == []
    keep = np.asarray(g.conn_valid).copy()
    assert np.array_equal(np.delete(o.conn_weight, 5), np.delete(np.asarray(g.conn_weight), 5))
    # a genome with one gene left draws delete link but keeps it
    one = g.replace(conn_valid=jnp.asarray(keep & (np.arange(keep.size) == 0)))
    one = one.replace(conn_innov=jnp.where(one.conn_valid, one.conn_innov, -1),
                      conn_src=jnp.where(one.conn_valid, one.conn_src, -1),
                      conn_dst=jnp.where(one.conn_valid, one.conn_dst, -1),
                      conn_enabled=one.conn_enabled & one.conn_valid,
                      conn_weight=jnp.where(one.conn_valid, one.conn_weight, 0.0))
    for s in range(20):
        kind, key1, _, _ = gn.propose_structure(jax.random.key(s), g, NEATParams(add_node_prob=0.0, add_link_prob=0.0,
                                                                                  delete_link_prob=1.0), CFG)
        assert int(kind) == gn.DELETE_LINK and bool(g.conn_valid[int(key1)])
        kind, _, _, _ = gn.propose_structure(jax.random.key(s), one, NEATParams(add_node_prob=0.0, add_link_prob=0.0,
                                                                                 delete_link_prob=1.0), CFG)
        assert int(kind) == gn.NONE


def test_sharpneat_weight_mutation_selections_and_step_sizes():
    g = gn.initial_genome(jax.random.key(3), CFG, NEATParams())
    params = NEATParams(weight_scheme=1, weight_small_share=1.0, weight_large_share=0.0, weight_select_fraction=0.5)
    keys = jax.random.split(jax.random.key(4), 4000)
    out = jax.vmap(lambda k: gn.mutate_weights(k, g, params))(keys)
    dw = np.asarray(out.conn_weight) - np.asarray(g.conn_weight)[None]
    changed = (dw != 0).sum(axis=1)
    # the four selections are equally likely: exactly 1, 2 or 3 genes, or each of the 8 with p = 0.5
    for k in (1, 2, 3):
        frac = np.mean(changed == k)
        expect = 0.25 + 0.25 * {1: 8, 2: 28, 3: 56}[k] / 256
        assert abs(frac - expect) < 0.03, (k, frac, expect)
    assert abs(np.mean(changed >= 4) - 0.25 * (1 - (1 + 8 + 28 + 56) / 256)) < 0.03
    assert np.all(changed <= CFG.n_initial_conns) and not np.any(dw[:, CFG.n_initial_conns:])
    np.testing.assert_allclose(dw[dw != 0].std(), 0.02, rtol=0.05)  # small Gaussian steps only
    big = jax.vmap(lambda k: gn.mutate_weights(k, g, params.replace(weight_small_share=0.0,
                                                                    weight_large_share=1.0)))(keys)
    dbig = np.asarray(big.conn_weight) - np.asarray(g.conn_weight)[None]
    # sigma 1, a little less once clipped to [-5, 5]
    assert 0.9 < dbig[dbig != 0].std() < 1.02
    reset = jax.vmap(lambda k: gn.mutate_weights(k, g, params.replace(weight_small_share=0.0)))(keys)
    w = np.asarray(reset.conn_weight)[np.asarray(reset.conn_weight) != np.asarray(g.conn_weight)[None]]
    assert np.abs(w).max() <= 1.0 and abs(w.mean()) < 0.05  # replacements ~ U(-1, 1)


@functools.lru_cache(maxsize=None)
def _sharp_run():
    return evolve(CFG, SHARP, 80, seed=3)


def test_sharpneat_operators_keep_every_genome_valid():
    states, metrics = _sharp_run()
    for s in states[::8] + [states[-1]]:
        assert ck.check_population(s.population, CFG, weight_range=5.0) == []
    n = np.stack([np.asarray(s.population.conn_valid).sum(axis=1) for s in states])
    assert n[0].mean() < 0.5 * CFG.n_initial_conns  # the partial start
    # genes are deleted as well as added: some genome lost a gene between two generations
    lost = any(np.any(~np.asarray(b.population.conn_valid) & np.asarray(a.population.conn_valid).any(axis=0)[None]
                      & (np.asarray(b.population.conn_innov) == -1)) for a, b in zip(states, states[1:]))
    assert lost and max(int(m["new_nodes"]) for m in metrics) > 0


def test_presets_record_their_readings():
    _, literal = presets.keepaway_literal()
    assert float(literal.weight_perturb_power) == 0.01 and float(literal.weight_mutate_rate) == 0.05
    _, sharp = presets.keepaway_sharpneat()
    assert int(sharp.weight_scheme) == 1 and float(sharp.add_link_prob) == 0.01
    assert float(sharp.initial_link_fraction) == 0.05 and float(sharp.delete_link_prob) == 0.001
    for p in (literal, sharp, presets.keepaway()[1]):
        p.validate()
