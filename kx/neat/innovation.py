"""Population-level structural bookkeeping of NEAT (Stanley & Miikkulainen 2002): innovation numbers
shared across a generation.

The same structural innovation arising in several genomes of one generation gets one innovation number
(and one node id for a split), as in the paper's Section 3.1. Structural mutation is split in three
steps so that the per-genome parts stay single-genome operators of :mod:`kx.neat.genome`:

1. :func:`~kx.neat.genome.propose_structure` (per genome) picks the link to split or the link to add;
   :func:`pick_links` computes the add-link candidates for the few genomes that draw add-link, at most
   ``NEATConfig.add_link_cap`` of them per generation (the rest are skipped and counted, ``link_capped``);
2. :func:`assign_innovations` (over the population) numbers the distinct proposals and gives each new
   connection gene a column no genome of the generation uses;
3. :func:`~kx.neat.genome.apply_structure` (per genome) writes the genes with those numbers.

:func:`mutate_population` composes them with the weight, re-enable and activation mutations: it is the
mutation step of :func:`kx.neat.algorithm.tell`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from kx.neat import genome as gn
from kx.neat.types import Counters, Genome, NEATConfig, NEATParams

I32 = jnp.int32


def pick_links(keys: jax.Array, pop: Genome, frozen: jax.Array, params: NEATParams, config: NEATConfig):
    """The new link of every genome that draws add-link (``[P]`` keys as given to
    :func:`~kx.neat.genome.propose_structure`), computing candidate links only for those genomes: the
    first ``NEATConfig.add_link_cap_of(P)`` of them in population order (by default ``max(8, P // 8)``;
    at Stanley's add-link rate about 5% draw it); any beyond are skipped and returned as ``capped``.
    Returns ``((pair, has_pair, order), capped)``: ``[P]`` each but ``order`` ``[P, max_nodes]``, the
    :func:`~kx.neat.genome.link_order` that adding the picked link needs (the identity for the others)."""
    p = frozen.shape[0]
    m = config.add_link_cap_of(p)  # sets the shape of the candidate computation: static
    _, want, _, _, k_link = jax.vmap(lambda k: gn.structure_draw(k, params))(keys)
    want = want & ~frozen
    idx = jnp.searchsorted(jnp.cumsum(want.astype(I32)), jnp.arange(1, m + 1, dtype=I32)).astype(I32)
    sel = jnp.minimum(idx, p - 1)
    n = config.max_nodes

    def pick_one(k, g):
        cand, reach = gn.candidates_and_reach(g, config)
        pair, has = gn.pick_where(k, cand)
        return pair, has, gn.link_order(reach, pair // n, pair % n, config)

    pair, has, order = jax.vmap(pick_one)(k_link[sel], jax.tree.map(lambda x: x[sel], pop))
    pair_all = jnp.zeros((p,), I32).at[idx].set(pair, mode="drop")
    has_all = jnp.zeros((p,), bool).at[idx].set(has & (idx < p), mode="drop")
    order_all = jnp.broadcast_to(jnp.arange(n, dtype=I32), (p, n)).at[idx].set(order, mode="drop")
    chosen = jnp.zeros((p,), bool).at[idx].set(True, mode="drop")
    return (pair_all, has_all, order_all), want & ~chosen


def assign_innovations(kind: jax.Array, key1: jax.Array, key2: jax.Array, split_innov: jax.Array,
                       used_columns: jax.Array, next_node_id: jax.Array, next_innov: jax.Array):
    """Number the distinct structural proposals of a generation (``[P]`` arrays) and give each new
    connection gene a column.

    Proposals to split the same link (same innovation ``split_innov``) share one new node id and the
    two innovation numbers of its links; proposals of the same new link (same source and target ids)
    share one innovation number. Distinct innovations take the columns no genome uses
    (``~used_columns``), in order: add-node pairs first, then new links; a proposal left without a
    column is dropped (``kind`` becomes ``NONE``) and counted.

    Returns ``(kind, node_id, innov_a, innov_b, col_a, col_b, next_node_id, next_innov, n_new_nodes,
    n_new_links, n_dropped)``; ``innov_b``/``col_b`` are used by add-node only.
    """
    k1 = jnp.where(kind == gn.ADD_NODE, split_innov, jnp.where(kind == gn.ADD_LINK, key1, -1))
    k2 = jnp.where(kind == gn.ADD_LINK, key2, -1)
    order = jnp.lexsort((k2, k1, kind))
    sk, s1, s2 = kind[order], k1[order], k2[order]
    first = jnp.concatenate([jnp.ones((1,), bool),
                             (sk[1:] != sk[:-1]) | (s1[1:] != s1[:-1]) | (s2[1:] != s2[:-1])])
    node_rank = jnp.cumsum(first & (sk == gn.ADD_NODE)) - 1
    link_rank = jnp.cumsum(first & (sk == gn.ADD_LINK)) - 1
    n_node_groups = jnp.sum(first & (sk == gn.ADD_NODE), dtype=I32)
    # Column ranks: add node g takes free columns 2g and 2g + 1, new link l takes 2 n_node_groups + l.
    rank_a = jnp.where(sk == gn.ADD_NODE, 2 * node_rank, 2 * n_node_groups + link_rank)
    rank_last = jnp.where(sk == gn.ADD_NODE, rank_a + 1, rank_a)
    n_free = jnp.sum(~used_columns, dtype=I32)
    fits = (sk != gn.NONE) & (rank_last < n_free)
    free_cols = jnp.argsort(used_columns, stable=True).astype(I32)  # free columns first, ascending
    c = used_columns.shape[0]
    col_a = free_cols[jnp.clip(rank_a, 0, c - 1)]
    col_b = free_cols[jnp.clip(rank_a + 1, 0, c - 1)]
    # Groups that fit form a prefix of the ranks, so their numbers stay contiguous.
    n_nodes = jnp.sum(first & fits & (sk == gn.ADD_NODE), dtype=I32)
    n_links = jnp.sum(first & fits & (sk == gn.ADD_LINK), dtype=I32)
    s_node = next_node_id + node_rank
    s_ia = jnp.where(sk == gn.ADD_NODE, next_innov + 2 * node_rank, next_innov + 2 * n_nodes + link_rank)
    dropped = (sk != gn.NONE) & ~fits
    unsort = lambda x: jnp.zeros_like(x).at[order].set(x)
    new_kind = unsort(jnp.where(fits, sk, gn.NONE).astype(I32))
    return (new_kind, unsort(s_node.astype(I32)), unsort(s_ia.astype(I32)), unsort((s_ia + 1).astype(I32)),
            unsort(col_a), unsort(col_b), next_node_id + n_nodes, next_innov + 2 * n_nodes + n_links,
            n_nodes, n_links, jnp.sum(dropped, dtype=I32))


def mutate_population(key: jax.Array, pop: Genome, frozen: jax.Array, next_node_id: jax.Array,
                      next_innov: jax.Array, params: NEATParams, config: NEATConfig):
    """Mutate every genome of ``pop`` (``[P, ...]``) not ``frozen`` (elites), with innovation numbers
    and columns shared across the population. Returns ``(pop, next_node_id, next_innov, counters)``.

    Per genome (the order of Stanley's NEAT C++): one structural mutation if drawn; otherwise, with
    ``weight_mutate_prob``, weight mutation, and re-enabling and activation mutation at their rates.
    """
    p = frozen.shape[0]
    keys = jax.random.split(key, (p, 5))
    link_pick, link_capped = pick_links(keys[:, 0], pop, frozen, params, config)
    kind, key1, key2, (node_full, link_full, l_exh) = jax.vmap(
        lambda k, g, lp: gn.propose_structure(k, g, params, config, lp))(keys[:, 0], pop, link_pick)
    l_exh = l_exh & ~link_capped  # a capped genome never looked for a link
    proposed = jnp.where(frozen, gn.NONE, kind)
    split_innov = jnp.take_along_axis(pop.conn_innov, jnp.clip(key1, 0, config.max_conns - 1)[:, None], 1)[:, 0]
    used = jnp.any(pop.conn_valid, axis=0)
    deleting = proposed == gn.DELETE_LINK  # needs no innovation number or column
    kind, node_id, ia, ib, ca, cb, next_node_id, next_innov, n_nodes, n_links, _ = assign_innovations(
        jnp.where(deleting, gn.NONE, proposed), key1, key2, split_innov, used, next_node_id, next_innov)
    kind = jnp.where(deleting, gn.DELETE_LINK, kind)
    no_column = kind != proposed  # dropped: no free column left

    def one(k, g, kd, a, b, nid, i1, i2, c1, c2, frz, order):
        g2 = gn.apply_structure(k[1], g, kd, a, b, nid, i1, i2, c1, c2, params, config, order)
        light = (kd == gn.NONE) & ~frz
        ku = jax.random.uniform(k[2], (3,))
        gw = gn.mutate_weights(k[3], g2, params, config.genes)
        g2 = jax.tree.map(lambda x, y: jnp.where(light & (ku[0] < params.weight_mutate_prob), y, x), g2, gw)
        gr = gn.mutate_reenable(k[4], g2)
        g2 = jax.tree.map(lambda x, y: jnp.where(light & (ku[1] < params.reenable_prob), y, x), g2, gr)
        if len(config.activation_options) > 1:
            ga = gn.mutate_activation(jax.random.fold_in(k[4], 1), g2, config)
            g2 = jax.tree.map(lambda x, y: jnp.where(light & (ku[2] < params.activation_mutate_prob), y, x),
                              g2, ga)
        return g2

    pop = jax.vmap(one)(keys, pop, kind, key1, key2, node_id, ia, ib, ca, cb, frozen, link_pick[2])
    nf = ~frozen
    counters = Counters(node_overflow=jnp.sum((node_full | no_column & (proposed == gn.ADD_NODE)) & nf, dtype=I32),
                        link_overflow=jnp.sum((link_full | no_column & (proposed == gn.ADD_LINK)) & nf, dtype=I32),
                        link_exhausted=jnp.sum(l_exh & nf, dtype=I32),
                        link_capped=jnp.sum(link_capped & nf, dtype=I32),
                        new_nodes=n_nodes, new_links=n_links)
    return pop, next_node_id, next_innov, counters
