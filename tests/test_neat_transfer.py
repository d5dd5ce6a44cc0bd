"""Policy transfer between NEAT layouts (kx.neat.transfer, Algorithm 1, SPEC section 5)."""

import functools
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx.neat import algorithm as alg
from kx.neat import checks as ck
from kx.neat import network as nw
from kx.neat import transfer as tr
from kx.neat.algorithm import NEAT
from kx.neat.types import BIAS, EMPTY, HIDDEN, INPUT, OUTPUT, Genome, NEATConfig, NEATError, NEATParams

# source: 3 inputs (ids 0-2), bias 3, outputs 4-5, hidden from 6; target: 5 inputs (0-4), bias 5, outputs 6-8,
# hidden from 9
S = NEATConfig(n_inputs=3, n_outputs=2, population_size=24, max_nodes=12, max_conns=64, species_capacity=6)
T = NEATConfig(n_inputs=5, n_outputs=3, population_size=24, max_nodes=15, max_conns=256, species_capacity=6)
IN_MAP, OUT_MAP = [4, 0, 2], [2, 0]  # new inputs 1 and 3, new output index 1 (id 7)
PARAMS = NEATParams(add_node_prob=0.3, add_link_prob=0.4, delete_link_prob=0.1, initial_link_fraction=0.5,
                    target_species=4, mutation_only_prob=0.5)
R = PARAMS.weight_init_range


def t_id(i):
    """The target id of source node id ``i`` under IN_MAP/OUT_MAP."""
    if i < 3:
        return IN_MAP[i]
    if i == 3:
        return 5
    if i < 6:
        return 6 + OUT_MAP[i - 4]
    return i - 6 + 9


def hand_genome(hidden, genes, config=S):
    """A genome of ``config`` with hidden ids ``hidden`` (slot order) and genes (innov, src, dst, w, enabled),
    gene k in column innov."""
    n, c, f = config.max_nodes, config.max_conns, config.n_fixed
    ids = np.full(n, -1, np.int32)
    ids[:f] = np.arange(f)
    ids[f: f + len(hidden)] = hidden
    kind = np.full(n, EMPTY, np.int32)
    kind[: config.n_inputs], kind[config.n_inputs], kind[config.first_output: f] = INPUT, BIAS, OUTPUT
    kind[f: f + len(hidden)] = HIDDEN
    g = dict(innov=np.full(c, -1, np.int32), src=np.full(c, -1, np.int32), dst=np.full(c, -1, np.int32),
             w=np.zeros(c, np.float32), en=np.zeros(c, bool))
    for inn, s, d, w, e in genes:
        g["innov"][inn], g["src"][inn], g["dst"][inn], g["w"][inn], g["en"][inn] = inn, s, d, w, e
    return Genome(node_id=ids, node_kind=kind, node_act=np.zeros(n, np.int32), node_valid=ids >= 0,
                  conn_innov=g["innov"], conn_src=g["src"], conn_dst=g["dst"], conn_weight=g["w"], conn_enabled=g["en"],
                  conn_valid=g["innov"] >= 0)


def stack(*gs):
    return jax.tree.map(lambda *x: np.stack(x), *gs)


# A: hidden 6 then 7; 2->5 added by add-link (innovation 12, not the initial 5). B: hidden 7 only, 2->5 initial.
A = hand_genome([6, 7], [(0, 0, 4, 0.5, True), (7, 3, 5, -0.25, True), (8, 1, 6, 1.0, True), (9, 6, 4, 0.75, False),
                         (10, 6, 7, -1.5, True), (11, 7, 5, 2.0, True), (12, 2, 5, 0.125, True)])
B = hand_genome([7], [(0, 0, 4, -0.5, True), (5, 2, 5, 0.3, True), (13, 1, 7, 1.0, True), (14, 7, 4, -0.7, True)])
HAND = stack(A, B)
HAND_NEXT = (8, 15)


def genes_of(pop, i):
    """{(src, dst): (innov, column, weight, enabled)} of genome i."""
    pop = jax.tree.map(np.asarray, pop)
    cols = np.flatnonzero(pop.conn_valid[i])
    return {(int(pop.conn_src[i, c]), int(pop.conn_dst[i, c])):
            (int(pop.conn_innov[i, c]), int(c), float(pop.conn_weight[i, c]), bool(pop.conn_enabled[i, c]))
            for c in cols}


def expected_new_pairs(hidden_t):
    """Algorithm 1's new links (this module's reading) for a target genome with hidden ids ``hidden_t``."""
    new_in, new_out = [1, 3], [7]
    outs = [6, 7, 8]
    pairs = {(i, d) for i in new_in for d in list(hidden_t) + outs}
    pairs |= {(s, o) for s in list(range(6)) + list(hidden_t) for o in new_out}
    return pairs


def test_hand_built_population_maps_by_hand():
    mapped, nn, ni = tr.map_population(jax.random.key(0), HAND, S, T, IN_MAP, OUT_MAP, *HAND_NEXT, PARAMS)
    assert (int(nn), int(ni)) == (11, 31)
    assert mapped.node_id.shape == (2, T.max_nodes) and mapped.conn_innov.shape == (2, T.max_conns)
    assert mapped.conn_innov.dtype == jnp.int32 and mapped.conn_weight.dtype == jnp.float32
    assert ck.check_population(mapped, T, PARAMS.weight_range) == []
    m = jax.tree.map(np.asarray, mapped)
    assert m.node_id[0, :11].tolist() == list(range(9)) + [9, 10]
    assert m.node_id[1, :10].tolist() == list(range(9)) + [10]
    a, b = genes_of(mapped, 0), genes_of(mapped, 1)
    # kept links, with the innovation numbers worked out by hand: fixed-fixed -> slot * 3 + output index,
    # others shifted by 18 - 8 = 10
    kept_a = {(4, 8): (14, 0.5, True), (5, 6): (15, -0.25, True), (0, 9): (18, 1.0, True), (9, 8): (19, 0.75, False),
              (9, 10): (20, -1.5, True), (10, 6): (21, 2.0, True), (2, 6): (6, 0.125, True)}
    kept_b = {(4, 8): (14, -0.5, True), (2, 6): (6, 0.3, True), (0, 10): (23, 1.0, True), (10, 8): (24, -0.7, True)}
    for got, kept in ((a, kept_a), (b, kept_b)):
        for pair, (inn, w, en) in kept.items():
            assert (got[pair][0], got[pair][2], got[pair][3]) == (inn, pytest.approx(w), en)
    # new links: 2 new inputs x (H hidden + 3 outputs) + (5 inputs + bias + H hidden) x 1 new output, less the
    # 2 new-input -> new-output pairs counted twice: A (H = 2) 10 + 8 - 2 = 16, B (H = 1) 8 + 7 - 2 = 13
    assert len(a) == 7 + 16 and len(b) == 4 + 13
    assert set(a) - set(kept_a) == expected_new_pairs([9, 10])
    assert set(b) - set(kept_b) == expected_new_pairs([10])
    for got, kept in ((a, kept_a), (b, kept_b)):
        for pair in set(got) - set(kept):
            inn, _, w, en = got[pair]
            assert en and -R <= w <= R and w != 0.0
            if pair[0] < 9 and pair[1] < 9:  # fixed-fixed: the target's initial numbering
                assert inn == pair[0] * 3 + (pair[1] - 6)
    # fresh numbers from 15 - 8 + 18 = 25, per hidden id (9 then 10): new input 1, new input 3, -> new output 7
    fresh = {(1, 9): 25, (3, 9): 26, (9, 7): 27, (1, 10): 28, (3, 10): 29, (10, 7): 30}
    for pair, inn in fresh.items():
        assert a[pair][0] == inn
        if 10 in pair:
            assert b[pair][0] == inn
    # one column per innovation: the 25 distinct numbers, sorted, in columns 0..24
    innovs = sorted({v[0] for v in a.values()} | {v[0] for v in b.values()})
    assert len(innovs) == 25
    for got in (a, b):
        assert all(col == innovs.index(inn) for inn, col, _, _ in got.values())


def test_one_pair_one_innovation_across_the_population():
    # A2 is A with 1->6 carrying a later number (the same add-link in another generation): both get the smaller
    genes = [(0, 0, 4, 0.5, True), (15, 1, 6, 1.0, True), (10, 6, 7, -1.5, True)]
    a2 = hand_genome([6, 7], genes)
    mapped, _, ni = tr.map_population(jax.random.key(1), stack(A, a2), S, T, IN_MAP, OUT_MAP, 8, 16, PARAMS)
    assert ck.check_population(mapped, T) == []
    a, b = genes_of(mapped, 0), genes_of(mapped, 1)
    assert a[(0, 9)][:2] == b[(0, 9)][:2] == (18, a[(0, 9)][1])
    assert all(a[p][:2] == b[p][:2] for p in set(a) & set(b))
    assert int(ni) == 16 - 8 + 18 + 2 * 3


def test_single_genome_and_determinism():
    one, nn, ni = tr.map_population(jax.random.key(2), A, S, T, IN_MAP, OUT_MAP, *HAND_NEXT, PARAMS)
    assert one.node_id.shape == (T.max_nodes,) and (int(nn), int(ni)) == (11, 31)
    assert ck.check_genome(one, T) == []
    again, _, _ = tr.map_population(jax.random.key(2), A, S, T, IN_MAP, OUT_MAP, *HAND_NEXT, PARAMS)
    assert all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(one), jax.tree.leaves(again)))


@functools.lru_cache(maxsize=None)
def evolved():
    neat = NEAT(S, PARAMS)
    state = neat.init(jax.random.key(0))
    for g in range(10):
        state, _ = neat.tell(jax.random.key(g + 1), state.population,
                             jax.random.uniform(jax.random.key(100 + g), (S.population_size,)), state)
    return state


@functools.lru_cache(maxsize=None)
def _outputs(config):
    """Jitted outputs ``[P, N, n_outputs]`` of a population for inputs ``[N, n_inputs]``."""
    return jax.jit(lambda pop, x: jax.vmap(lambda g: nw.activate(nw.build(g, config), x, config))(pop))


def _same_outputs(src_pop, mapped, n=64):
    x = np.asarray(jax.random.uniform(jax.random.key(7), (n, S.n_inputs), minval=-2.0, maxval=2.0))
    xt = np.zeros((n, T.n_inputs), np.float32)
    xt[:, IN_MAP] = x
    y_s = np.asarray(_outputs(S)(jax.tree.map(jnp.asarray, src_pop), jnp.asarray(x)))
    y_t = np.asarray(_outputs(T)(mapped, jnp.asarray(xt)))
    np.testing.assert_allclose(y_t[..., OUT_MAP], y_s, atol=1e-5)
    # the new inputs reach the outputs: with them on, some old output moves
    xt[:, [1, 3]] = 1.0
    y_on = np.asarray(_outputs(T)(mapped, jnp.asarray(xt)))
    assert np.abs(y_on[..., OUT_MAP] - y_s).max() > 1e-3


def test_same_outputs_with_new_inputs_at_zero_hand_built():
    mapped, _, _ = tr.map_population(jax.random.key(3), HAND, S, T, IN_MAP, OUT_MAP, *HAND_NEXT, PARAMS)
    _same_outputs(HAND, mapped)


@pytest.mark.slow  # two NEAT generation steps compile (about 50 s cold); the default suite: the hand-built cases
def test_evolved_population_maps_and_keeps_going():
    state = evolved()
    src = jax.tree.map(np.asarray, state.population)
    assert ck.check_population(src, S) == []
    cv = src.conn_valid
    # the run exercised what the mapping must handle
    assert (src.node_kind == HIDDEN).sum(axis=1).max() >= 3
    assert np.any(cv & (src.conn_src >= S.n_fixed) & (src.conn_dst >= S.n_fixed))  # hidden -> hidden
    assert np.any(cv & (src.conn_src < S.n_fixed) & (src.conn_dst < S.n_fixed)
                  & (src.conn_innov >= S.n_initial_conns))  # an input->output link added later
    assert tr.fit_problems(src, S, T, IN_MAP, OUT_MAP, state.next_node_id, state.next_innov) == []
    mapped, nn, ni = tr.map_population(jax.random.key(4), state.population, S, T, IN_MAP, OUT_MAP,
                                       state.next_node_id, state.next_innov, PARAMS)
    assert int(nn) == int(state.next_node_id) + 3
    assert ck.check_population(mapped, T, PARAMS.weight_range) == []
    m = jax.tree.map(np.asarray, mapped)
    by_pair = {}
    for i in range(S.population_size):
        got = genes_of(mapped, i)
        # nodes: the source's hidden ids shifted by 3, in the same slot order; kinds and activations kept
        hid_s = src.node_id[i][src.node_kind[i] == HIDDEN]
        hid_t = m.node_id[i][m.node_kind[i] == HIDDEN]
        assert hid_t.tolist() == (hid_s + 3).tolist()
        assert np.array_equal(m.node_act[i][m.node_kind[i] == HIDDEN], src.node_act[i][src.node_kind[i] == HIDDEN])
        assert len(set(m.node_id[i][m.node_valid[i]].tolist())) == int(m.node_valid[i].sum())
        assert int(hid_t.min(initial=9)) >= 9 and int(hid_t.max(initial=0)) < int(nn)
        # links: every source link kept with its weight and flag, plus exactly the new ones
        kept = set()
        for c in np.flatnonzero(cv[i]):
            pair = (t_id(int(src.conn_src[i, c])), t_id(int(src.conn_dst[i, c])))
            assert got[pair][2] == src.conn_weight[i, c] and got[pair][3] == src.conn_enabled[i, c]
            kept.add(pair)
        assert set(got) - kept == expected_new_pairs(hid_t.tolist())
        assert len(got) == len(kept) + len(expected_new_pairs(hid_t.tolist()))
        for pair, (inn, col, _, _) in got.items():
            assert by_pair.setdefault(pair, (inn, col)) == (inn, col)
            assert inn < int(ni)
    _same_outputs(state.population, mapped)

    # the mapped population evolves on under the target config
    neat_t = NEAT(T, PARAMS)
    st = alg.init_from(mapped, nn, ni, PARAMS.compat_threshold, PARAMS, T)
    for g in range(2):
        st, metrics = neat_t.tell(jax.random.key(50 + g), st.population,
                                  jax.random.uniform(jax.random.key(60 + g), (T.population_size,)), st)
    assert ck.check_population(st.population, T, PARAMS.weight_range) == []
    assert int(st.next_innov) >= int(ni) and int(st.next_node_id) >= int(nn)
    assert int(st.generation) == 2


def _refused(population, target, fragment, in_map=IN_MAP, out_map=OUT_MAP, source=S):
    problems = tr.fit_problems(population, source, target, in_map, out_map, *HAND_NEXT)
    assert any(fragment in p for p in problems), problems
    with pytest.raises(NEATError, match=re.escape(fragment)):
        tr.map_population(jax.random.key(0), population, source, target, in_map, out_map, *HAND_NEXT, PARAMS)
    return problems


def test_refusals_name_the_reason_with_numbers():
    # genome A has 2 hidden nodes; a 5/3 target with max_nodes 10 has 1 hidden slot
    _refused(HAND, NEATConfig(n_inputs=5, n_outputs=3, max_nodes=10, max_conns=256),
             "genome 0 has 2 hidden nodes; the target has 1 hidden slots (max_nodes 10 - 9 fixed nodes); 1 of 2 "
             "genomes have more")
    # the hand population needs 25 distinct innovations
    _refused(HAND, NEATConfig(n_inputs=5, n_outputs=3, max_nodes=15, max_conns=24),
             "25 distinct innovations (links); the target has 24 connection columns")
    # genome A needs 7 + 16 = 23 genes
    _refused(HAND, NEATConfig(n_inputs=5, n_outputs=3, max_nodes=15, max_conns=256, max_genes=22),
             "genome 0 needs 23 connection genes after mapping (7 kept, 16 new); the target allows 22 per genome "
             "(max_genes); 1 of 2 genomes need more")
    assert tr.fit_problems(HAND, S, NEATConfig(n_inputs=5, n_outputs=3, max_nodes=15, max_conns=256, max_genes=23),
                           IN_MAP, OUT_MAP) == []
    _refused(HAND, NEATConfig(n_inputs=5, n_outputs=3, max_nodes=15, max_conns=256,
                              activation_options=("sigmoid", "identity")), "activation options differ")
    _refused(HAND, NEATConfig(n_inputs=2, n_outputs=3, max_nodes=15), "fewer inputs (2) than the source (3)",
             in_map=[0, 1, 1])
    _refused(HAND, NEATConfig(n_inputs=5, n_outputs=1, max_nodes=15), "fewer outputs (1) than the source (2)",
             out_map=[0, 0])
    _refused(HAND, T, "input_map [4, 0, 4] is not injective", in_map=[4, 0, 4])
    _refused(HAND, T, "output_map [3, 0]: indices must lie in 0..2", out_map=[3, 0])
    _refused(HAND, T, "input_map must hold 3 integers", in_map=[4, 0])
    # a population of another config's shapes, and counters the population has passed
    _refused(HAND, T, "the population has 12 node slots and 64 connection columns; the source config has 15 and 256",
             source=T)
    problems = tr.fit_problems(HAND, S, T, IN_MAP, OUT_MAP, 7, 15)
    assert any("not below next_node_id = 7" in p for p in problems)
    assert any("not below next_innov = 14" in p for p in tr.fit_problems(HAND, S, T, IN_MAP, OUT_MAP, 8, 14))


def test_refuses_a_population_that_breaks_the_source_layout():
    bad = hand_genome([6], [(3, 0, 4, 1.0, True)])  # innovation 3 is 1 -> 5 in the initial numbering
    assert any("innovation 3 (below source.n_initial_conns = 8) joins 0->4" in p
               for p in tr.fit_problems(bad, S, T, IN_MAP, OUT_MAP))
    c1 = hand_genome([6], [(8, 1, 6, 1.0, True)])
    c2 = hand_genome([6], [(8, 2, 6, 1.0, True)])
    assert any("innovation 8 joins different node pairs" in p
               for p in tr.fit_problems(stack(c1, c2), S, T, IN_MAP, OUT_MAP))
    lost = hand_genome([], [(8, 1, 6, 1.0, True)])
    with pytest.raises(NEATError, match="genome 0: link 1->6 points at a node it lacks"):
        tr.map_population(jax.random.key(0), lost, S, T, IN_MAP, OUT_MAP, 8, 9, PARAMS)
