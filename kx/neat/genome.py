"""Genome operators of NEAT (Stanley & Miikkulainen 2002) on fixed-capacity tensors.

Over 450 lines because every operator on one genome's tensors shares the layout's invariants (kx.neat.types); split,
each part would restate them.

Every operator here is a pure function of *one* genome (see :mod:`kx.neat.types` for the layout),
vmapped over the population by the caller. Structural mutation is split in two so that the same
structural innovation arising in several genomes of one generation gets one innovation number:

1. :func:`propose_structure` (per genome) picks the link to split or the link to add;
2. :func:`kx.neat.innovation.assign_innovations` (over the population) numbers the distinct proposals;
3. :func:`apply_structure` (per genome) writes the genes with those numbers.

The population-level steps (:func:`~kx.neat.innovation.pick_links`, ``assign_innovations`` and
:func:`~kx.neat.innovation.mutate_population`, the mutation step of a generation) live in
:mod:`kx.neat.innovation`; the host-side validity checks in :mod:`kx.neat.checks`.

Connection genes live in *columns*: within a population, a column holds one innovation number, and a
new innovation is given a column that no genome of the generation uses (see :mod:`kx.neat.types`), so
that aligning two genomes by innovation number is a comparison column by column. A mutation that needs
a node slot or a column when none is left is skipped and counted.

Every operator keeps the invariants checked by :func:`kx.neat.checks.check_genome`: innovation numbers
are unique within a genome, hidden nodes are a prefix, every link leaves an input, the bias or a hidden
node and enters a hidden or output node, no two links join the same pair, and the graph of all links
(enabled or not, so that re-enabling never closes a cycle) is acyclic. More than acyclic: the hidden
slots are in topological order (a link between hidden nodes goes from a lower slot to a higher one), so
that :func:`kx.neat.network.build` needs no sort. Add node inserts its node just before the split
link's target; add link, when its source sits after its target, moves the target and what it reaches
past the source (the stable partition of an incremental topological sort, as in Pearce and Kelly 2006).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from kx.neat.types import BIAS, EMPTY, HIDDEN, INPUT, MAX_SELECT_COUNT, OUTPUT, Genome, NEATConfig, NEATParams
from kx.sim.ops import top_k_first

I32 = jnp.int32


# --------------------------------------------------------------------------------------------------
# Construction


def initial_genome(key: jax.Array, config: NEATConfig, params: NEATParams) -> Genome:
    """Inputs and bias connected to the outputs, weights ~ U(-weight_init_range, +range): every link,
    or each with probability ``initial_link_fraction`` (at least one).

    Link ``(source slot s, output o)`` has innovation number ``s * n_outputs + o`` (and that column) in
    every genome that carries it.
    """
    n, c, f = config.max_nodes, config.max_conns, config.n_fixed
    slots = jnp.arange(n, dtype=I32)
    kind = jnp.full((n,), EMPTY, I32)
    kind = kind.at[: config.n_inputs].set(INPUT).at[config.n_inputs].set(BIAS)
    kind = kind.at[config.first_output: f].set(OUTPUT)
    act = jnp.where(kind == OUTPUT, config.act_id(config.output_activation), 0).astype(I32)
    m = config.n_initial_conns
    idx = jnp.arange(c, dtype=I32)
    # the weights draw from ``key`` itself, as before the fraction existed (a fraction of 1 keeps every
    # link, since uniform() < 1 always holds, so those genomes are unchanged)
    k_w, k_keep, k_one = key, jax.random.fold_in(key, 1), jax.random.fold_in(key, 2)
    keep = jax.random.uniform(k_keep, (c,)) < params.initial_link_fraction
    keep = keep | (~jnp.any(keep[:m]) & (idx == jax.random.randint(k_one, (), 0, m, I32)))
    used = (idx < m) & keep
    src = jnp.where(used, idx // config.n_outputs, -1)
    dst = jnp.where(used, config.first_output + idx % config.n_outputs, -1)
    r = params.weight_init_range
    w = jnp.where(used, jax.random.uniform(k_w, (c,), jnp.float32, -r, r), 0.0)
    return Genome(node_id=jnp.where(slots < f, slots, -1), node_kind=kind, node_act=act,
                  node_valid=slots < f, conn_innov=jnp.where(used, idx, -1), conn_src=src.astype(I32),
                  conn_dst=dst.astype(I32), conn_weight=w, conn_enabled=used, conn_valid=used)


def n_conns(g: Genome) -> jax.Array:
    """Connection genes of a genome (enabled or not)."""
    return jnp.sum(g.conn_valid, dtype=I32)


def n_hidden(g: Genome) -> jax.Array:
    return jnp.sum(g.node_kind == HIDDEN, dtype=I32)


def slot_of(g: Genome, ids: jax.Array) -> jax.Array:
    """Node slot of each node id in ``ids`` (0 for ids the genome lacks; mask those yourself).

    A sum rather than an ``argmax`` (each id is in at most one slot): XLA CPU's argmax is a scalar
    loop, the sum vectorises (a tenth of the time on a population's links)."""
    slots = jnp.arange(g.node_id.shape[-1], dtype=I32)
    match = (g.node_id == ids[..., None]) & g.node_valid
    return jnp.sum(jnp.where(match, slots, 0), axis=-1, dtype=I32)


# --------------------------------------------------------------------------------------------------
# Alignment, distance, crossover


def _align(a: Genome, b: Genome) -> jax.Array:
    """Per column: both genomes carry the same innovation there (genomes of one lineage keep each
    innovation in the column it was created in)."""
    return a.conn_valid & b.conn_valid & (a.conn_innov == b.conn_innov)


def distance_stats(g: Genome) -> tuple[jax.Array, jax.Array]:
    """What :func:`distance` needs of one genome alone: its gene count and largest innovation number
    (computed once per genome when distances to many genomes are wanted)."""
    return n_conns(g), jnp.max(jnp.where(g.conn_valid, g.conn_innov, -1))


def distance(a: Genome, b: Genome, params: NEATParams, stats_a=None, stats_b=None) -> jax.Array:
    """Compatibility distance ``c1 E / N + c2 D / N + c3 W`` over connection genes (NEAT eq. 1).

    E counts excess genes (beyond the other genome's largest innovation number), D disjoint genes, W
    is the mean absolute weight difference of matching genes; N is the larger genome's gene count, or 1
    while both have fewer than ``params.small_genome`` genes. ``stats_a``/``stats_b`` are
    :func:`distance_stats` of the genomes, if already computed.
    """
    na, max_a = distance_stats(a) if stats_a is None else stats_a
    nb, max_b = distance_stats(b) if stats_b is None else stats_b
    match = _align(a, b)
    # A gene beyond the other genome's largest innovation matches nothing; a column holds at most one
    # such gene (of a or of b). Matching and excess genes are counted in one integer reduction (each
    # reduction of its own is a separate pass over the columns on CPU): matches in the low 16 bits.
    excess_col = (a.conn_valid & (a.conn_innov > max_b)) | (b.conn_valid & (b.conn_innov > max_a))
    counts = jnp.sum(match.astype(I32) | (excess_col.astype(I32) << 16))
    n_match, excess = counts & 0xFFFF, counts >> 16
    disjoint = na + nb - 2 * n_match - excess
    dw = jnp.sum(jnp.where(match, jnp.abs(a.conn_weight - b.conn_weight), 0.0))
    w = jnp.where(n_match > 0, dw / jnp.maximum(n_match, 1), 0.0)
    big_n = jnp.maximum(na, nb)
    norm = jnp.where(big_n < params.small_genome, 1, jnp.maximum(big_n, 1)).astype(jnp.float32)
    return (params.c1 * excess + params.c2 * disjoint) / norm + params.c3 * w


def crossover(key: jax.Array, fitter: Genome, other: Genome, params: NEATParams,
              genes: int | None = None) -> Genome:
    """Offspring of two parents aligned by innovation number.

    Matching genes take weight and enabled flag from either parent at random; disjoint and excess
    genes come from the fitter parent, so the offspring has exactly the fitter parent's structure
    (nodes and links) and stays valid. A matching gene disabled in either parent is disabled with
    probability ``disable_inherit_prob`` (otherwise it keeps the flag of the parent it came from). A
    matching hidden node takes its activation from either parent at random.
    """
    k_bits, k_act = jax.random.split(key)
    match = _align(fitter, other)
    pick_other, dis = _two_flags(_gene_bits(k_bits, fitter.conn_valid, 1, genes)[0], 0.5,
                                 params.disable_inherit_prob)
    take_other = match & pick_other
    w = jnp.where(take_other, other.conn_weight, fitter.conn_weight)
    en = jnp.where(take_other, other.conn_enabled, fitter.conn_enabled)
    either_off = match & ~(fitter.conn_enabled & other.conn_enabled)
    force_off = either_off & dis
    en = en & ~force_off
    # Node activations (matter for CPPNs only): matching hidden nodes from either parent.
    node_match = (fitter.node_id[:, None] == other.node_id[None, :]) & fitter.node_valid[:, None] \
        & other.node_valid[None, :]
    has = jnp.any(node_match, axis=1) & (fitter.node_kind == HIDDEN)
    other_act = other.node_act[jnp.argmax(node_match, axis=1)]
    pick_act = has & jax.random.bernoulli(k_act, 0.5, has.shape)
    act = jnp.where(pick_act, other_act, fitter.node_act)
    return fitter.replace(conn_weight=w, conn_enabled=en, node_act=act)


# --------------------------------------------------------------------------------------------------
# Weight and flag mutations


def _gene_bits(key: jax.Array, valid: jax.Array, n: int, genes: int | None = None) -> jax.Array:
    """``[n, max_conns]`` random uint32 words, independent across a genome's ``valid`` columns (other
    columns get copies). With ``genes`` (the most genes a genome carries, ``NEATConfig.genes``) they are
    drawn for the genes, not for every column: threefry's cost is in the words drawn."""
    c = valid.shape[0]
    if genes is None or genes >= c:
        return jax.random.bits(key, (n, c), jnp.uint32)
    bits = jax.random.bits(key, (n, genes), jnp.uint32)
    return bits[:, jnp.minimum(mask_rank(valid), genes - 1)]


def _two_flags(bits: jax.Array, p_low, p_high) -> tuple[jax.Array, jax.Array]:
    """Two independent coin flips per uint32 word, with probabilities ``p_low`` and ``p_high`` (16 bits
    each: a probability is honoured to within 2^-16)."""
    scale = jnp.float32(1 << 16)
    low = (bits & 0xFFFF).astype(jnp.float32) < p_low * scale
    high = (bits >> 16).astype(jnp.float32) < p_high * scale
    return low, high


def _symmetric_unit(bits: jax.Array) -> jax.Array:
    """U(-1, 1) from uint32 words (23 bits of mantissa, as ``jax.random.uniform``)."""
    one_two = jax.lax.bitcast_convert_type((bits >> 9) | jnp.uint32(0x3F800000), jnp.float32)  # [1, 2)
    return 2.0 * one_two - 3.0


def mutate_weights(key: jax.Array, g: Genome, params: NEATParams, genes: int | None = None) -> Genome:
    """A weight mutation by ``params.weight_scheme``: 0, :func:`mutate_weights_stanley`; 1,
    :func:`mutate_weights_sharpneat`; 2, :func:`mutate_weights_hyperneat`. ``genes``: see
    :func:`_gene_bits`. One ``lax.switch``: with the scheme unbatched (the population's vmap), only the
    chosen branch runs."""
    branches = (lambda: mutate_weights_stanley(key, g, params, genes),
                lambda: mutate_weights_sharpneat(key, g, params, genes),
                lambda: mutate_weights_hyperneat(key, g, params, genes))
    return jax.lax.switch(jnp.clip(jnp.asarray(params.weight_scheme, I32), 0, 2), branches)


def _gene_normal(key: jax.Array, valid: jax.Array, genes: int | None) -> jax.Array:
    """``[max_conns]`` N(0, 1) values, independent across ``valid`` columns (drawn per gene, as
    :func:`_gene_bits`)."""
    c = valid.shape[0]
    if genes is None or genes >= c:
        return jax.random.normal(key, (c,))
    return jax.random.normal(key, (genes,))[jnp.minimum(mask_rank(valid), genes - 1)]


def mutate_weights_hyperneat(key: jax.Array, g: Genome, params: NEATParams, genes: int | None = None) -> Genome:
    """The authors' HyperNEAT weight mutation (``HN/Sources/KeepAway/NEAT/Evolutions.cs``; SPEC §2): one
    of four kinds. With probability ``weight_all_share`` every gene gets a step N(0, ``weight_step_sigma``);
    with ``weight_fraction_share`` each gene, with probability ``weight_select_fraction``, gets that step;
    with ``weight_reset_share`` ``weight_select_count`` distinct random genes are reset to
    U(-weight_range, weight_range); otherwise ``weight_select_count`` distinct random genes get
    U(-weight_perturb_power, weight_perturb_power). Then clipped to the weight range. ``genes``: see
    :func:`_gene_bits`."""
    k_kind, k_bits, k_norm = jax.random.split(key, 3)
    u = jax.random.uniform(k_kind)
    a, f, r = params.weight_all_share, params.weight_fraction_share, params.weight_reset_share
    kind = (u >= a).astype(I32) + (u >= a + f) + (u >= a + f + r)  # 0 all, 1 fraction, 2 reset, 3 uniform step
    bits = _gene_bits(k_bits, g.conn_valid, 2, genes)
    unit = (bits[0] >> 8).astype(jnp.float32) * jnp.float32(2.0 ** -24)  # U[0, 1) per gene
    # weight_select_count genes: the smallest scores, taken by index (ties cannot pick a third)
    c = g.conn_valid.shape[0]
    k = min(MAX_SELECT_COUNT, c)
    idx = top_k_first(-jnp.where(g.conn_valid, unit, 2.0), k)  # equal scores in gene order, on every backend
    by_count = jnp.zeros((c,), bool).at[idx].set(jnp.arange(k) < params.weight_select_count)
    chosen = g.conn_valid & jnp.where(kind == 0, True, jnp.where(kind == 1, unit < params.weight_select_fraction,
                                                                   by_count))
    sym = _symmetric_unit(bits[1])  # U(-1, 1): a reset or a uniform step (a gene gets one or the other)
    gauss = g.conn_weight + params.weight_step_sigma * _gene_normal(k_norm, g.conn_valid, genes)
    new = jnp.where(kind <= 1, gauss, jnp.where(kind == 2, sym * params.weight_range,
                                                g.conn_weight + sym * params.weight_perturb_power))
    w = jnp.clip(jnp.where(chosen, new, g.conn_weight), -params.weight_range, params.weight_range)
    return g.replace(conn_weight=jnp.where(g.conn_valid, w, 0.0))


def mutate_weights_sharpneat(key: jax.Array, g: Genome, params: NEATParams, genes: int | None = None) -> Genome:
    """SharpNEAT 2's default weight mutation: a Gaussian step of sigma ``weight_small_sigma`` (with
    probability ``weight_small_share``) or ``weight_large_sigma`` (``weight_large_share``), or else a
    replacement by U(-init, init), on 1, 2 or 3 random connection genes or on each gene with probability
    ``weight_select_fraction`` (the four selections equally likely); then clipped."""
    k_kind, k_bits, k_norm = jax.random.split(key, 3)
    u = jax.random.uniform(k_kind, (2,))
    small = u[0] < params.weight_small_share
    reset = u[0] >= params.weight_small_share + params.weight_large_share
    selection = jnp.minimum(jnp.floor(u[1] * 4).astype(I32), 3)  # 0, 1, 2: that many genes + 1; 3: a fraction
    bits = _gene_bits(k_bits, g.conn_valid, 2, genes)
    unit = (bits[0] >> 8).astype(jnp.float32) * jnp.float32(2.0 ** -24)  # U[0, 1) per gene
    score = jnp.where(g.conn_valid, unit, 2.0)
    kth = -jax.lax.top_k(-score, 3)[0][jnp.minimum(selection, 2)]  # the (selection+1)-th smallest score
    chosen = g.conn_valid & jnp.where(selection == 3, unit < params.weight_select_fraction, score <= kth)
    z = _gene_normal(k_norm, g.conn_valid, genes)
    sigma = jnp.where(small, params.weight_small_sigma, params.weight_large_sigma)
    fresh = _symmetric_unit(bits[1]) * params.weight_init_range
    w = jnp.where(chosen, jnp.where(reset, fresh, g.conn_weight + sigma * z), g.conn_weight)
    w = jnp.clip(w, -params.weight_range, params.weight_range)
    return g.replace(conn_weight=jnp.where(g.conn_valid, w, 0.0))


def mutate_weights_stanley(key: jax.Array, g: Genome, params: NEATParams, genes: int | None = None) -> Genome:
    """Each connection weight, with probability ``weight_mutate_rate``: perturbed by U(-p, p) with
    probability ``weight_perturb_prob``, else replaced by a fresh U(-init, init) value; then clipped.
    ``genes``: see :func:`_gene_bits`."""
    # Two random words per gene (threefry dominated this step): one for both coin flips, one for the
    # value, used as the perturbation or as the fresh weight (never both).
    bits = _gene_bits(key, g.conn_valid, 2, genes)
    mutate, perturb = _two_flags(bits[0], params.weight_mutate_rate, params.weight_perturb_prob)
    mutate = g.conn_valid & mutate
    u = _symmetric_unit(bits[1])
    p, r = params.weight_perturb_power, params.weight_init_range
    delta, fresh = u * p, u * r
    w = jnp.where(mutate, jnp.where(perturb, g.conn_weight + delta, fresh), g.conn_weight)
    w = jnp.clip(w, -params.weight_range, params.weight_range)
    return g.replace(conn_weight=jnp.where(g.conn_valid, w, 0.0))


def pick_where(key: jax.Array, mask: jax.Array) -> tuple[jax.Array, jax.Array]:
    """A uniformly random index where ``mask`` (flattened) is true, and whether there is one: the r-th
    true entry for one uniform r (one random word, not one per entry)."""
    flat = mask.reshape(-1)
    n = jnp.sum(flat, dtype=I32)
    r = jnp.minimum(jnp.floor(jax.random.uniform(key) * n).astype(I32), n - 1)
    hit = flat & (mask_rank(flat) == r)
    return jnp.sum(jnp.where(hit, jnp.arange(flat.shape[0], dtype=I32), 0), dtype=I32), n > 0


def mutate_reenable(key: jax.Array, g: Genome) -> Genome:
    """Re-enable one disabled connection gene chosen at random (if any): safe, since the graph of
    all links, disabled ones included, is kept acyclic."""
    i, ok = pick_where(key, g.conn_valid & ~g.conn_enabled)
    return g.replace(conn_enabled=g.conn_enabled.at[i].set(g.conn_enabled[i] | ok))


def mutate_activation(key: jax.Array, g: Genome, config: NEATConfig) -> Genome:
    """Redraw the activation of one hidden node at random from ``activation_options``."""
    k_i, k_a = jax.random.split(key)
    i, ok = pick_where(k_i, g.node_kind == HIDDEN)
    a = jax.random.randint(k_a, (), 0, len(config.activation_options), I32)
    return g.replace(node_act=g.node_act.at[i].set(jnp.where(ok, a, g.node_act[i])))


# --------------------------------------------------------------------------------------------------
# Structural mutations

NONE, ADD_NODE, ADD_LINK, DELETE_LINK = 0, 1, 2, 3


def _adjacency(src: jax.Array, dst: jax.Array, mask: jax.Array, n: int) -> jax.Array:
    """``[n, n]`` float 0/1 matrix with a 1 at ``(src[c], dst[c])`` for every ``c`` with ``mask[c]``.

    A scatter into the flattened matrix: on XLA CPU it costs a tenth of the one-hot product
    ``onehot(src).T @ onehot(dst)`` it replaced (batched small products are slow there)."""
    inside = mask & (src >= 0) & (src < n) & (dst >= 0) & (dst < n)  # like the one-hot: others match nothing
    flat = jnp.where(inside, src * n + dst, n * n)
    return jnp.zeros((n * n,), jnp.float32).at[flat].max(1.0, mode="drop").reshape(n, n)


def closure(adj: jax.Array) -> jax.Array:
    """Transitive closure of a 0/1 adjacency matrix by repeated squaring: ``reach[i, j]`` is 1 when a
    path of one or more links leads from ``i`` to ``j``."""
    n = adj.shape[-1]
    reach = adj
    for _ in range(max(1, int(np.ceil(np.log2(max(n, 2)))))):
        reach = jnp.minimum(reach + reach @ reach, 1.0)
    return reach


def mask_rank(mask: jax.Array) -> jax.Array:
    """``[n]`` int32: how many entries of the 1-D ``mask`` before each position are true (the exclusive
    running count). Counted with population counts of 32-bit words: XLA CPU's ``cumsum`` is a
    reduce-window that costs four times as much on a population's columns."""
    n = mask.shape[0]
    pad = -n % 32
    m = jnp.concatenate([mask, jnp.zeros((pad,), bool)]) if pad else mask
    bit = jnp.arange(32, dtype=jnp.uint32)
    words = jnp.sum(m.reshape(-1, 32).astype(jnp.uint32) << bit, axis=1, dtype=jnp.uint32)  # disjoint bits
    per_word = jax.lax.population_count(words).astype(I32)
    before = jnp.cumsum(per_word) - per_word
    within = jax.lax.population_count(words[:, None] & ((jnp.uint32(1) << bit) - jnp.uint32(1))).astype(I32)
    return (before[:, None] + within).reshape(-1)[:n]


class Links(NamedTuple):
    """A genome's connection genes gathered into ``max_genes`` rows (valid ones first), with node slots
    in place of ids: the compact view the structural operators and the network builder work on."""

    col: jax.Array  # [K] column of each row
    src: jax.Array  # [K] source node slot
    dst: jax.Array  # [K] target node slot
    valid: jax.Array  # [K] bool
    enabled: jax.Array  # [K] bool
    weight: jax.Array  # [K] float32


def links(g: Genome, config: NEATConfig) -> Links:
    # Valid column c goes to row (valid columns before c): a scatter (XLA's CPU sort costs ten times
    # as much, a binary search over the running count three times).
    c = config.max_conns
    row = jnp.where(g.conn_valid, mask_rank(g.conn_valid), config.genes)
    col = jnp.full((config.genes,), c, I32).at[row].set(jnp.arange(c, dtype=I32), mode="drop")
    valid = col < c
    col = jnp.minimum(col, c - 1)
    return Links(col=col, src=slot_of(g, g.conn_src[col]), dst=slot_of(g, g.conn_dst[col]), valid=valid,
                 enabled=g.conn_enabled[col] & valid, weight=jnp.where(valid, g.conn_weight[col], 0.0))


def hidden_reach(lk: Links, config: NEATConfig, enabled_only: bool = False) -> jax.Array:
    """``[n_hidden, n_hidden]`` bool: a path of links leads from hidden slot ``i`` to hidden slot ``j``
    (all links count unless ``enabled_only``).

    A new link src -> dst closes a cycle only if dst reaches src; inputs have no in-links and outputs no
    out-links, so only paths between hidden nodes matter.
    """
    h, f = config.n_hidden, config.n_fixed
    if h == 0:
        return jnp.zeros((0, 0), bool)
    adj = _adjacency(lk.src - f, lk.dst - f, lk.enabled if enabled_only else lk.valid, h)
    return closure(adj) > 0


def link_candidates(g: Genome, config: NEATConfig, lk: Links | None = None) -> jax.Array:
    """``[max_nodes, max_nodes]`` mask of (source slot, target slot) pairs a new link may join: from an
    input, the bias or a hidden node to a hidden or output node, not yet linked, closing no cycle."""
    return candidates_and_reach(g, config, lk)[0]


def candidates_and_reach(g: Genome, config: NEATConfig, lk: Links | None = None):
    """:func:`link_candidates` and the :func:`hidden_reach` (all links) it was computed from."""
    lk = links(g, config) if lk is None else lk
    kind = g.node_kind
    src_ok = g.node_valid & ((kind == INPUT) | (kind == BIAS) | (kind == HIDDEN))
    dst_ok = g.node_valid & ((kind == HIDDEN) | (kind == OUTPUT))
    n = config.max_nodes
    cand = src_ok[:, None] & dst_ok[None, :] & ~jnp.eye(n, dtype=bool)
    cand = cand & ~(_adjacency(lk.src, lk.dst, lk.valid, n) > 0)
    reach = hidden_reach(lk, config)
    if config.n_hidden:
        f = config.n_fixed
        cand = cand.at[f:, f:].set(cand[f:, f:] & ~reach.T)  # reach.T[i, j]: hidden j reaches hidden i
    return cand, reach


def link_order(reach: jax.Array, src_slot: jax.Array, dst_slot: jax.Array, config: NEATConfig) -> jax.Array:
    """``[max_nodes]`` slot permutation (new slot -> old slot) that keeps the hidden slots in
    topological order once a link ``src_slot -> dst_slot`` (closing no cycle) is added.

    Nothing moves unless both ends are hidden and the source sits after the target. Then, among the
    slots from the target to the source, the target and the nodes it reaches move, in their order,
    after the others (the source among them): no link inside that range goes from a moved node to one
    that stays, since the target reaches every node a moved node reaches. ``reach`` is
    :func:`hidden_reach` over all links, before the new one."""
    f, h = config.n_fixed, config.n_hidden
    if h == 0:  # no hidden slots: nothing to order
        return jnp.arange(f, dtype=I32)
    off = jnp.arange(h, dtype=I32)
    hs, hd = src_slot - f, dst_slot - f
    move = (hs >= 0) & (hd >= 0) & (hs > hd)
    region = (off >= hd) & (off <= hs)
    moved = region & ((off == hd) | reach[jnp.clip(hd, 0, h - 1)])
    stays = region & ~moved
    before = lambda m: jnp.sum(m[None, :] & (off[None, :] < off[:, None]), axis=1, dtype=I32)  # h is small
    new_off = jnp.where(stays, hd + before(stays),
                        jnp.where(moved, hd + jnp.sum(stays, dtype=I32) + before(moved), off))
    new_off = jnp.where(move, new_off, off)
    perm = jnp.zeros((h,), I32).at[new_off].set(off)
    return jnp.concatenate([jnp.arange(f, dtype=I32), f + perm])


def structure_draw(key: jax.Array, params: NEATParams):
    """One roulette draw: add node, add link, delete link or none; ``k_split`` also picks the gene a
    delete removes (the two never happen together)."""
    k_u, k_split, k_link = jax.random.split(key, 3)
    u = jax.random.uniform(k_u)
    want_node = u < params.add_node_prob
    want_link = ~want_node & (u < params.add_node_prob + params.add_link_prob)
    want_delete = ~want_node & ~want_link & (u < params.add_node_prob + params.add_link_prob + params.delete_link_prob)
    return want_node, want_link, want_delete, k_split, k_link


def propose_structure(key: jax.Array, g: Genome, params: NEATParams, config: NEATConfig, link_pick=None):
    """Draw this genome's structural mutation: add node with ``add_node_prob``, add link with
    ``add_link_prob``, delete link with ``delete_link_prob``, else none. Returns ``(kind, key1, key2,
    (node_full, link_full, link_exhausted))``: for ADD_NODE, key1 is the column of the link to split;
    for ADD_LINK, key1 and key2 are the source and target node ids; for DELETE_LINK, key1 is the column
    of the gene to remove (never a genome's last gene). ``node_full``/``link_full``: an add node/link
    skipped for lack of a hidden slot or of gene room (``max_genes``); ``link_exhausted``: no new
    feed-forward link is left to add. ``link_pick``, if given, is the ``(pair, has_pair)`` already
    drawn for this genome by :func:`pick_links`."""
    want_node, want_link, want_delete, k_split, k_link = structure_draw(key, params)
    split, has_split = pick_where(k_split, g.conn_enabled)
    genes = n_conns(g)
    node_room = (n_hidden(g) < config.n_hidden) & (genes + 2 <= config.genes)
    do_node = want_node & has_split & node_room
    pair, has_pair = pick_where(k_link, link_candidates(g, config)) if link_pick is None else link_pick[:2]
    link_room = genes + 1 <= config.genes
    do_link = want_link & has_pair & link_room
    gone, _ = pick_where(k_split, g.conn_valid)
    do_delete = want_delete & (genes >= 2)
    n = config.max_nodes
    kind = jnp.where(do_node, ADD_NODE, jnp.where(do_link, ADD_LINK, jnp.where(do_delete, DELETE_LINK, NONE)))
    kind = kind.astype(I32)
    key1 = jnp.where(do_node, split, jnp.where(do_link, g.node_id[pair // n], jnp.where(do_delete, gone, -1)))
    key1 = key1.astype(I32)
    key2 = jnp.where(do_link, g.node_id[pair % n], -1).astype(I32)
    return kind, key1, key2, (want_node & has_split & ~node_room, want_link & has_pair & ~link_room,
                              want_link & ~has_pair)


def apply_structure(key: jax.Array, g: Genome, kind, key1, key2, node_id, innov_a, innov_b, col_a, col_b,
                    params: NEATParams, config: NEATConfig, order: jax.Array | None = None) -> Genome:
    """Write a structural mutation with its assigned ids and columns.

    Add node splits the link in column ``key1``: the link is disabled, a hidden node ``node_id`` is
    inserted just before the link's target among the hidden slots (at the end if the target is an
    output), the link into it gets weight 1 (innovation ``innov_a``, column ``col_a``), the link out of
    it the old weight (``innov_b``, ``col_b``). Add link joins node ids ``key1 -> key2`` with a
    U(-init, init) weight (``innov_a``, ``col_a``) and reorders the hidden slots by ``order`` (from
    :func:`link_order`; computed here if not given). Delete link clears column ``key1`` (its nodes stay:
    a hidden node left without links computes a constant or nothing).
    """
    k_w, k_act = jax.random.split(key)
    is_node, is_link = kind == ADD_NODE, kind == ADD_LINK
    f, n = config.n_fixed, config.max_nodes
    split = jnp.clip(key1, 0, config.max_conns - 1)
    old_src, old_dst, old_w = g.conn_src[split], g.conn_dst[split], g.conn_weight[split]
    if order is None:
        sl = slot_of(g, jnp.stack([key1, key2]))
        order = link_order(hidden_reach(links(g, config), config), sl[0], sl[1], config)
    # Slot permutation: add link's reordering, or add node's shift of the hidden slots from its slot on.
    dst_slot = slot_of(g, old_dst)
    ins = jnp.where(dst_slot >= f, dst_slot, f + n_hidden(g))
    slots = jnp.arange(n, dtype=I32)
    perm = jnp.where(is_link, order, jnp.where(is_node & (slots > ins), slots - 1, slots))
    g = g.replace(node_id=g.node_id[perm], node_kind=g.node_kind[perm], node_act=g.node_act[perm],
                  node_valid=g.node_valid[perm])
    if config.random_hidden_activation:
        act = jax.random.randint(k_act, (), 0, len(config.activation_options), I32)
    else:
        act = jnp.asarray(config.act_id(config.hidden_activation), I32)
    put_node = is_node & (slots == ins)
    g = g.replace(node_id=jnp.where(put_node, node_id, g.node_id),
                  node_kind=jnp.where(put_node, HIDDEN, g.node_kind),
                  node_act=jnp.where(put_node, act, g.node_act),
                  node_valid=g.node_valid | put_node)
    cols = jnp.arange(config.max_conns)
    r = params.weight_init_range
    link_w = jax.random.uniform(k_w, (), jnp.float32, -r, r)
    put_a = (is_node | is_link) & (cols == col_a)
    put_b = is_node & (cols == col_b)
    src = jnp.where(put_a, jnp.where(is_node, old_src, key1), jnp.where(put_b, node_id, g.conn_src))
    dst = jnp.where(put_a, jnp.where(is_node, node_id, key2), jnp.where(put_b, old_dst, g.conn_dst))
    w = jnp.where(put_a, jnp.where(is_node, 1.0, link_w), jnp.where(put_b, old_w, g.conn_weight))
    innov = jnp.where(put_a, innov_a, jnp.where(put_b, innov_b, g.conn_innov))
    enabled = (g.conn_enabled & ~(is_node & (cols == split))) | put_a | put_b
    gone = (kind == DELETE_LINK) & (cols == key1)
    return g.replace(conn_src=jnp.where(gone, -1, src).astype(I32), conn_dst=jnp.where(gone, -1, dst).astype(I32),
                     conn_weight=jnp.where(gone, 0.0, w), conn_innov=jnp.where(gone, -1, innov).astype(I32),
                     conn_enabled=enabled & ~gone, conn_valid=(g.conn_valid | put_a | put_b) & ~gone)
