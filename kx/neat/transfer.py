"""Policy transfer between NEAT layouts: the paper's Algorithm 1 for a whole population (SPEC §5).

A population evolved for a *source* :class:`~kx.neat.types.NEATConfig` is mapped onto a *target* config
with more inputs and/or outputs (in keep-away: the new agents' features and pass actions). The caller
says where each source input and output goes (``input_map``, ``output_map``, injective); the target's
inputs and outputs not named there are the *new* nodes. The bias maps to the bias. Nothing here knows
about soccer.

Algorithm 1 (section 2.4 of the paper) builds the target network with the target's inputs and outputs
and the source's hidden nodes, then visits every pair of nodes: a link that exists in the source is
copied with its weight; a pair whose nodes do not exist in the source gets a link with a random weight.
The reading implemented here:

* "the nodes do not exist in the source" is read as *at least one of the two* is new (a pair of two old
  nodes without a source link stays unlinked: the source's topology is kept as it is);
* "each pair" is each feed-forward pair the genome layout allows (from an input, the bias or a hidden
  node to a hidden node or an output). So the new links of a genome with hidden nodes ``H`` are
  ``(each new input) -> (each node of H, each output)`` and ``(each input, new ones included, the bias,
  each node of H) -> (each new output)``, no pair twice: ``n_new_in * (|H| + n_out_source) +
  (n_in_target + 1 + |H|) * n_new_out`` links, weights U(-weight_init_range, +weight_init_range),
  enabled. A new input enters no old node except through these links, so with the new inputs at 0 the
  mapped network computes the source network's outputs (on the mapped output indices) exactly;
* every source link is kept with its weight and enabled flag; disabled links stay disabled.

Node ids: fixed nodes take the target's slot ids; hidden id ``h`` becomes ``h - source.n_fixed +
target.n_fixed`` in every genome (hidden ids are population-wide historical markings: a uniform shift
keeps them so, where keeping them as they are could collide with a new input's or output's id). Hidden
slots keep their (topological) order; activations are copied, so source and target must share
``activation_options``; new outputs get the target's ``output_activation``.

Innovation numbers (one per distinct ``(src id, dst id)`` pair of the mapped population):

* a link between fixed nodes, old or new, takes the target's initial numbering ``target slot of the
  source * target.n_outputs + output index``, what :func:`~kx.neat.genome.initial_genome` gives. In kx
  an add-link of an input (or bias) -> output pair that a genome lacks gets a fresh number from the
  counter (>= ``n_initial_conns``), so in the source one such pair may carry several numbers; they are
  all mapped to this one;
* any other source link keeps its history shifted uniformly: ``i - source.n_initial_conns +
  target.n_initial_conns`` (source numbers below ``n_initial_conns`` are checked to be exactly the
  initial fixed-fixed links). Where one pair carries several numbers in the source (the same add-link
  drawn in different generations), the smallest is taken for all (a genome never carries a pair twice,
  so nothing in one genome merges);
* the new links to and from hidden node ``h`` take fresh numbers from the target counter (the source's
  ``next_innov`` shifted as above), allocated per (new node, hidden id) pair, the hidden ids in
  ascending order, for each the new inputs then the new outputs (ascending target index), so that they
  agree across genomes.

Columns are assigned anew for the whole population: the sorted distinct innovation numbers take
columns ``0..n-1``. The mapped population therefore satisfies :func:`kx.neat.checks.check_population`
and can continue evolving under the target config (:func:`kx.neat.algorithm.init_from` builds a run state for it).

Everything here runs once per transfer on the host (numpy); the result is a :class:`Genome` of jnp
arrays with the target's shapes.

Between configs of the same inputs and outputs nothing is mapped: :func:`resize` pads the genomes to
the target's (at least as large) capacity.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from kx.neat.types import BIAS, EMPTY, HIDDEN, INPUT, OUTPUT, Genome, NEATConfig, NEATError, NEATParams

__all__ = ["fit_problems", "map_population", "resize"]


@dataclasses.dataclass
class _Plan:
    """What :func:`map_population` writes, computed once (numpy)."""

    pop: Genome  # the source population as numpy arrays, [P, ...]
    single: bool  # the caller passed one genome (no leading axis)
    fixed_map: np.ndarray  # [source.n_fixed] target id of each source fixed id
    gene_g: np.ndarray  # every gene of the mapped population: genome index,
    gene_innov: np.ndarray  # target innovation number,
    gene_src: np.ndarray  # target source id, target destination id,
    gene_dst: np.ndarray
    gene_w: np.ndarray  # weight (the source's; 0 for a new link, drawn later)
    gene_en: np.ndarray  # enabled flag
    gene_new: np.ndarray  # a new link (Algorithm 1's random weight)
    innovs: np.ndarray  # sorted distinct target innovation numbers: column k holds innovs[k]
    n_hidden: np.ndarray  # [P] hidden nodes per genome
    next_node_id: int  # target counters after the mapping
    next_innov: int


def _as_population(population) -> tuple[Genome, bool]:
    pop = jax.tree.map(np.asarray, population)
    single = pop.node_id.ndim == 1
    if single:
        pop = jax.tree.map(lambda x: x[None], pop)
    return pop, single


def _check_maps(source: NEATConfig, target: NEATConfig, input_map, output_map) -> list[str]:
    errs = []
    if tuple(source.activation_options) != tuple(target.activation_options):
        errs.append(f"activation options differ: source {source.activation_options}, target "
                    f"{target.activation_options} (node genes store an index into them)")
    if target.n_inputs < source.n_inputs:
        errs.append(f"the target has fewer inputs ({target.n_inputs}) than the source ({source.n_inputs})")
    if target.n_outputs < source.n_outputs:
        errs.append(f"the target has fewer outputs ({target.n_outputs}) than the source ({source.n_outputs})")
    for name, m, n_src, n_tgt in (("input_map", input_map, source.n_inputs, target.n_inputs),
                                  ("output_map", output_map, source.n_outputs, target.n_outputs)):
        a = np.asarray(m)
        if a.shape != (n_src,) or not np.issubdtype(a.dtype, np.integer):
            errs.append(f"{name} must hold {n_src} integers (one per source {name[:-4]}), got shape {a.shape}, "
                        f"dtype {a.dtype}")
            continue
        if np.any((a < 0) | (a >= n_tgt)):
            errs.append(f"{name} {a.tolist()}: indices must lie in 0..{n_tgt - 1} (the target's {name[:-4]}s)")
        elif len(set(a.tolist())) != n_src:
            errs.append(f"{name} {a.tolist()} is not injective (two source {name[:-4]}s map to one target "
                        f"{name[:-4]})")
    return errs


def _plan(population, source: NEATConfig, target: NEATConfig, input_map, output_map, next_node_id=None,
          next_innov=None) -> tuple[list[str], _Plan | None]:
    """The reasons the population does not fit (empty if it does) and, if it does, the mapping."""
    errs = _check_maps(source, target, input_map, output_map)
    pop, single = _as_population(population)
    p = pop.node_id.shape[0]
    if pop.node_id.shape[1:] != (source.max_nodes,) or pop.conn_innov.shape[1:] != (source.max_conns,):
        errs.append(f"the population has {pop.node_id.shape[-1]} node slots and {pop.conn_innov.shape[-1]} "
                    f"connection columns; the source config has {source.max_nodes} and {source.max_conns}")
    if errs:
        return errs, None

    sf, tf = source.n_fixed, target.n_fixed
    s_in, s_out, t_in, t_out = source.n_inputs, source.n_outputs, target.n_inputs, target.n_outputs
    s_init, t_init = source.n_initial_conns, target.n_initial_conns
    im, om = np.asarray(input_map, np.int64), np.asarray(output_map, np.int64)

    # --- the source population must have the layout the mapping relies on
    kind, ids, nv = pop.node_kind, pop.node_id.astype(np.int64), pop.node_valid.astype(bool)
    exp_kind = np.array([INPUT] * s_in + [BIAS] + [OUTPUT] * s_out)
    if not (np.all(ids[:, :sf] == np.arange(sf)) and nv[:, :sf].all() and np.all(kind[:, :sf] == exp_kind)):
        errs.append("the population's fixed nodes are not the source config's (id == slot, inputs, bias, outputs)")
    hid = kind[:, sf:] == HIDDEN
    n_hidden = hid.sum(axis=1)
    if not (np.all(hid == (np.arange(source.n_hidden) < n_hidden[:, None])) and np.all(nv[:, sf:] == hid)):
        errs.append("the population's hidden nodes are not a prefix of the hidden slots")
    hid_ids = ids[:, sf:][hid]
    if hid_ids.size and hid_ids.min() < sf:
        errs.append(f"a hidden node has id {int(hid_ids.min())}, below source.n_fixed = {sf}")
    if next_node_id is not None and hid_ids.size and hid_ids.max() >= int(next_node_id):
        errs.append(f"a hidden node has id {int(hid_ids.max())}, not below next_node_id = {int(next_node_id)}")

    cv = pop.conn_valid.astype(bool)
    g_idx, c_idx = np.nonzero(cv)
    innov = pop.conn_innov[g_idx, c_idx].astype(np.int64)
    src = pop.conn_src[g_idx, c_idx].astype(np.int64)
    dst = pop.conn_dst[g_idx, c_idx].astype(np.int64)
    if innov.size and innov.min() < 0:
        errs.append("a valid connection gene has a negative innovation number")
    if next_innov is not None and innov.size and innov.max() >= int(next_innov):
        errs.append(f"a gene has innovation {int(innov.max())}, not below next_innov = {int(next_innov)}")
    low = innov < s_init
    bad_low = low & ((src != innov // s_out) | (dst != s_in + 1 + innov % s_out))
    if np.any(bad_low):
        k = int(np.flatnonzero(bad_low)[0])
        errs.append(f"innovation {int(innov[k])} (below source.n_initial_conns = {s_init}) joins {int(src[k])}->"
                    f"{int(dst[k])}, not the initial link (slot * n_outputs + output) it must be")
    # one innovation number, one pair (what check_population also asks)
    if innov.size:
        u, inv = np.unique(innov, return_inverse=True)
        s_lo, s_hi = np.full(u.size, np.iinfo(np.int64).max), np.full(u.size, -1)
        d_lo, d_hi = s_lo.copy(), s_hi.copy()
        np.minimum.at(s_lo, inv, src), np.maximum.at(s_hi, inv, src)
        np.minimum.at(d_lo, inv, dst), np.maximum.at(d_hi, inv, dst)
        bad = (s_lo != s_hi) | (d_lo != d_hi)
        if np.any(bad):
            errs.append(f"innovation {int(u[np.flatnonzero(bad)[0]])} joins different node pairs in different genomes")
    fixed_src, fixed_dst = src < sf, dst < sf
    m_id = int(max(ids.max(initial=0), src.max(initial=0), dst.max(initial=0))) + 1
    have = (np.nonzero(hid)[0] * m_id + hid_ids)  # (genome, hidden id) of every hidden node
    lost = (~fixed_src & ~np.isin(g_idx * m_id + src, have)) | (~fixed_dst & ~np.isin(g_idx * m_id + dst, have))
    if np.any(lost):
        k = int(np.flatnonzero(lost)[0])
        errs.append(f"genome {int(g_idx[k])}: link {int(src[k])}->{int(dst[k])} points at a node it lacks")
    if np.any((src < 0) | (dst < 0)):
        errs.append("a valid connection gene has a negative node id")
    elif np.any((src >= s_in + 1) & fixed_src) or np.any(dst < s_in + 1):
        errs.append("a link leaves an output or enters an input or the bias")
    if errs:
        return errs, None

    # --- node ids
    fixed_map = np.concatenate([im, [t_in], t_in + 1 + om]).astype(np.int64)  # [sf]
    shift_id = lambda x: np.where(x < sf, fixed_map[np.clip(x, 0, sf - 1)], x - sf + tf)  # noqa: E731
    t_src, t_dst = shift_id(src), shift_id(dst)

    # --- source links: target innovation numbers, one per pair
    ff = fixed_src & fixed_dst
    t_innov = np.where(ff, t_src * t_out + (t_dst - t_in - 1), innov - s_init + t_init)
    if innov.size:
        uk, kinv = np.unique(src * m_id + dst, return_inverse=True)
        lowest = np.full(uk.size, np.iinfo(np.int64).max)
        np.minimum.at(lowest, kinv, t_innov)
        t_innov = lowest[kinv]
    if innov.size:
        order = np.lexsort((t_innov, g_idx))
        gs, ts = g_idx[order], t_innov[order]
        dup = (gs[1:] == gs[:-1]) & (ts[1:] == ts[:-1])
        if np.any(dup):
            errs.append(f"genome {int(gs[1:][dup][0])} joins one pair of nodes by two links")
            return errs, None

    # --- new links
    new_in = np.setdiff1d(np.arange(t_in), im)  # target input ids (== indices) that are new
    new_out = np.setdiff1d(np.arange(t_out), om)  # target output indices that are new
    k_new = new_in.size + new_out.size
    srcs_t = np.arange(t_in + 1)  # inputs and bias (ids == slots)
    is_new_src = np.isin(srcs_t, new_in)
    is_new_out = np.isin(np.arange(t_out), new_out)
    ff_pairs = np.argwhere(is_new_src[:, None] | is_new_out[None, :])  # [(source slot, output index)]
    ff_src, ff_o = ff_pairs[:, 0], ff_pairs[:, 1]
    ff_innov = ff_src * t_out + ff_o
    next_t = (int(next_innov) if next_innov is not None else int(innov.max(initial=s_init - 1)) + 1) - s_init + t_init
    all_hid = np.unique(hid_ids)  # source hidden ids alive in the population, ascending
    hg, hslot = np.nonzero(hid)  # genome, hidden slot (after the fixed ones) of every hidden node
    h_src_id = ids[:, sf:][hg, hslot]
    rank = np.searchsorted(all_hid, h_src_id)
    h_t = h_src_id - sf + tf
    # per hidden node: new inputs -> it, then it -> new outputs
    nh = hg.size
    hn_g = np.repeat(hg, k_new)
    hn_innov = (next_t + rank[:, None] * k_new + np.arange(k_new)[None, :]).reshape(-1)
    hn_src = np.concatenate([np.broadcast_to(new_in, (nh, new_in.size)),
                             np.broadcast_to(h_t[:, None], (nh, new_out.size))], axis=1).reshape(-1)
    hn_dst = np.concatenate([np.broadcast_to(h_t[:, None], (nh, new_in.size)),
                             np.broadcast_to(tf - t_out + new_out, (nh, new_out.size))], axis=1).reshape(-1)

    gene_g = np.concatenate([g_idx, np.repeat(np.arange(p), ff_innov.size), hn_g])
    gene_innov = np.concatenate([t_innov, np.tile(ff_innov, p), hn_innov])
    gene_src = np.concatenate([t_src, np.tile(ff_src, p), hn_src])
    gene_dst = np.concatenate([t_dst, np.tile(t_in + 1 + ff_o, p), hn_dst])
    n_src_genes = g_idx.size
    gene_w = np.concatenate([pop.conn_weight[g_idx, c_idx].astype(np.float32),
                             np.zeros(gene_g.size - n_src_genes, np.float32)])
    gene_new = np.arange(gene_g.size) >= n_src_genes
    gene_en = np.concatenate([pop.conn_enabled[g_idx, c_idx].astype(bool), np.ones(gene_g.size - n_src_genes, bool)])

    # --- capacity
    if n_hidden.size and n_hidden.max() > target.n_hidden:
        g_max = int(np.argmax(n_hidden))
        errs.append(f"genome {g_max} has {int(n_hidden.max())} hidden nodes; the target has {target.n_hidden} "
                    f"hidden slots (max_nodes {target.max_nodes} - {tf} fixed nodes); "
                    f"{int(np.sum(n_hidden > target.n_hidden))} of {p} genomes have more")
    genes = np.bincount(gene_g, minlength=p)
    if genes.max(initial=0) > target.genes:
        g_max = int(np.argmax(genes))
        errs.append(f"genome {g_max} needs {int(genes[g_max])} connection genes after mapping "
                    f"({int(np.sum(cv[g_max]))} kept, {int(genes[g_max] - np.sum(cv[g_max]))} new); the target allows "
                    f"{target.genes} per genome (max_genes); {int(np.sum(genes > target.genes))} of {p} genomes "
                    "need more")
    innovs = np.unique(gene_innov)
    if innovs.size > target.max_conns:
        errs.append(f"the mapped population has {innovs.size} distinct innovations (links); the target has "
                    f"{target.max_conns} connection columns (max_conns)")
    if errs:
        return errs, None
    next_node = (int(next_node_id) if next_node_id is not None else int(hid_ids.max(initial=sf - 1)) + 1) - sf + tf
    return [], _Plan(pop=pop, single=single, fixed_map=fixed_map, gene_g=gene_g, gene_innov=gene_innov,
                     gene_src=gene_src, gene_dst=gene_dst, gene_w=gene_w, gene_en=gene_en, gene_new=gene_new,
                     innovs=innovs, n_hidden=n_hidden, next_node_id=next_node, next_innov=next_t + all_hid.size * k_new)


def fit_problems(population, source: NEATConfig, target: NEATConfig, input_map, output_map,
                 next_node_id=None, next_innov=None) -> list[str]:
    """Why ``population`` (a :class:`Genome` of ``source``'s shapes, ``[P, ...]`` or one genome) cannot be
    mapped onto ``target`` by :func:`map_population` with these maps, one sentence with the numbers per
    problem; an empty list if it can.

    Problems: differing ``activation_options``; a target with fewer inputs or outputs than the source;
    maps of the wrong length, out of range or not injective; a population not of the source's shapes
    or layout (fixed nodes, hidden prefix, initial innovation numbers, one pair per innovation, ids and
    innovations below the given counters); more hidden nodes in a genome than the target's hidden slots;
    a genome needing more connection genes than ``target.genes``; more distinct innovations than
    ``target.max_conns``. Checks after the first failing group are not run (they need it to hold).
    """
    return _plan(population, source, target, input_map, output_map, next_node_id, next_innov)[0]


def map_population(key: jax.Array, population: Genome, source: NEATConfig, target: NEATConfig, input_map,
                   output_map, next_node_id, next_innov, params: NEATParams):
    """Algorithm 1 on every genome of ``population`` (see the module docstring for the reading).

    Args:
      key: draws the new links' weights, U(-params.weight_init_range, +range).
      population: a :class:`Genome` of ``source``'s shapes, ``[P, ...]`` (or one genome, no leading axis).
      source, target: the configs; the target has at least the source's inputs and outputs and the same
        ``activation_options``.
      input_map: ``[source.n_inputs]`` ints: ``input_map[i]`` is the target input index of source input i.
      output_map: ``[source.n_outputs]`` ints: the target output index of each source output.
      next_node_id, next_innov: the source run's counters (``NEATState.next_node_id``/``next_innov``).
      params: the target run's parameters (only ``weight_init_range`` is used).

    Returns ``(mapped, next_node_id, next_innov)``: the population with the target's shapes (same
    leading axis) and the target run's counters (int32 scalars).

    Raises :class:`~kx.neat.types.NEATError` with every reason of :func:`fit_problems` if the
    population does not fit; nothing is truncated.
    """
    errs, plan = _plan(population, source, target, input_map, output_map, next_node_id, next_innov)
    if errs:
        raise NEATError("the population does not fit the target config: " + "; ".join(errs))
    pop = plan.pop
    p = pop.node_id.shape[0]
    sf, tf, t_in = source.n_fixed, target.n_fixed, target.n_inputs
    n, c = target.max_nodes, target.max_conns

    # nodes
    slots = np.arange(n)
    hid = (slots[None, :] >= tf) & (slots[None, :] < tf + plan.n_hidden[:, None])  # [P, n]
    node_id = np.where(slots < tf, slots, -1)[None].repeat(p, 0)
    node_kind = np.full((p, n), EMPTY, np.int32)
    node_kind[:, :t_in] = INPUT
    node_kind[:, t_in] = BIAS
    node_kind[:, t_in + 1: tf] = OUTPUT
    node_act = np.zeros((p, n), np.int32)
    node_act[:, t_in + 1: tf] = target.act_id(target.output_activation)  # new outputs
    node_act[:, plan.fixed_map[source.n_inputs + 1:]] = pop.node_act[:, source.n_inputs + 1: sf]
    src_hid = np.arange(source.max_nodes)[None, :] >= sf
    src_hid = src_hid & (pop.node_kind == HIDDEN)
    node_id[hid] = pop.node_id[src_hid].astype(np.int64) - sf + tf
    node_kind[hid] = HIDDEN
    node_act[hid] = pop.node_act[src_hid]

    # connection genes
    col = np.searchsorted(plan.innovs, plan.gene_innov)
    r = float(params.weight_init_range)
    draw = np.asarray(jax.random.uniform(key, (p, c), jnp.float32, -r, r))
    w = np.where(plan.gene_new, draw[plan.gene_g, col], plan.gene_w)
    conn = {name: np.full((p, c), -1, np.int32) for name in ("innov", "src", "dst")}
    weight, enabled, valid = np.zeros((p, c), np.float32), np.zeros((p, c), bool), np.zeros((p, c), bool)
    at = (plan.gene_g, col)
    conn["innov"][at], conn["src"][at], conn["dst"][at] = plan.gene_innov, plan.gene_src, plan.gene_dst
    weight[at], enabled[at], valid[at] = w, plan.gene_en, True

    out = Genome(node_id=node_id.astype(np.int32), node_kind=node_kind, node_act=node_act,
                 node_valid=node_id >= 0, conn_innov=conn["innov"], conn_src=conn["src"], conn_dst=conn["dst"],
                 conn_weight=weight, conn_enabled=enabled, conn_valid=valid)
    dtypes = dict(node_id=jnp.int32, node_kind=jnp.int32, node_act=jnp.int32, node_valid=bool,
                  conn_innov=jnp.int32, conn_src=jnp.int32, conn_dst=jnp.int32, conn_weight=jnp.float32,
                  conn_enabled=bool, conn_valid=bool)
    out = Genome(**{f: jnp.asarray(getattr(out, f)[0] if plan.single else getattr(out, f), dtypes[f])
                    for f in dtypes})
    return out, jnp.asarray(plan.next_node_id, jnp.int32), jnp.asarray(plan.next_innov, jnp.int32)


def resize(genomes, source, target):
    """Genomes of NEAT config ``source`` in the (at least as large) capacity of config ``target`` with
    the same inputs and outputs: empty node slots and connection columns appended, nothing else changed."""
    dn, dc = target.max_nodes - source.max_nodes, target.max_conns - source.max_conns
    if dn < 0 or dc < 0 or (source.n_inputs, source.n_outputs) != (target.n_inputs, target.n_outputs):
        raise ValueError("resize: the target capacity must hold the source's and have its inputs and outputs")
    fill = {"node_id": EMPTY, "node_kind": EMPTY, "node_act": 0, "node_valid": False, "conn_innov": EMPTY,
            "conn_src": EMPTY, "conn_dst": EMPTY, "conn_weight": 0.0, "conn_enabled": False, "conn_valid": False}

    def pad(name, a):
        n = dn if name.startswith("node") else dc
        if n == 0:
            return a
        widths = [(0, 0)] * (a.ndim - 1) + [(0, n)]
        return jnp.pad(a, widths, constant_values=jnp.asarray(fill[name], a.dtype))

    return genomes.replace(**{f: pad(f, getattr(genomes, f)) for f in fill})
