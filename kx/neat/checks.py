"""Host-side validity checks of NEAT genomes (for tests and for checkpoints read back from disk).

:func:`check_genome` lists every broken invariant of one genome; :func:`check_population` adds the
population-wide one (one innovation number joins one pair of nodes in one column). The invariants are
those every operator of :mod:`kx.neat.genome` and :mod:`kx.neat.innovation` keeps (listed in
:mod:`kx.neat.genome`'s docstring).
"""

from __future__ import annotations

import jax
import numpy as np

from kx.neat.types import BIAS, EMPTY, HIDDEN, INPUT, OUTPUT, NEATConfig


def check_genome(g, config: NEATConfig, weight_range: float | None = None) -> list[str]:
    """Every broken invariant of one genome (numpy or jax arrays); an empty list if it is valid."""
    g = jax.tree.map(np.asarray, g)
    errs = []
    f = config.n_fixed
    nv, kind, ids = g.node_valid, g.node_kind, g.node_id
    if not np.array_equal(ids[:f], np.arange(f)) or not nv[:f].all():
        errs.append("fixed nodes do not have id == slot")
    exp_kind = np.array([INPUT] * config.n_inputs + [BIAS] + [OUTPUT] * config.n_outputs)
    if not np.array_equal(kind[:f], exp_kind):
        errs.append("fixed node kinds wrong")
    hid = nv[f:]
    if hid.size and not np.array_equal(hid, np.sort(hid)[::-1]):
        errs.append("hidden nodes are not a prefix")
    if not np.array_equal(nv, ids >= 0) or not np.all(kind[f:][hid] == HIDDEN) or not np.all(kind[~nv] == EMPTY):
        errs.append("node masks inconsistent")
    if len(set(ids[nv].tolist())) != int(nv.sum()):
        errs.append("duplicate node ids")
    if np.any((g.node_act < 0) | (g.node_act >= len(config.activation_options))):
        errs.append("activation id out of range")
    cv = g.conn_valid
    inn = g.conn_innov[cv]
    if len(set(inn.tolist())) != inn.size or np.any(inn < 0):
        errs.append("innovation numbers not unique")
    if (np.any(g.conn_innov[~cv] != -1) or np.any(g.conn_src[~cv] != -1) or np.any(g.conn_dst[~cv] != -1)
            or np.any(g.conn_enabled[~cv]) or np.any(g.conn_weight[~cv] != 0)):
        errs.append("empty connection columns not cleared")
    id_kind = {int(i): int(k) for i, k in zip(ids[nv], kind[nv])}
    slot = {int(i): k for k, i in enumerate(ids.tolist()) if nv[k]}
    pairs = set()
    edges = []
    for s, d in zip(g.conn_src[cv].tolist(), g.conn_dst[cv].tolist()):
        if s not in id_kind or d not in id_kind:
            errs.append(f"link {s}->{d} points at a missing node")
            continue
        if id_kind[s] not in (INPUT, BIAS, HIDDEN) or id_kind[d] not in (HIDDEN, OUTPUT):
            errs.append(f"link {s}->{d} joins wrong node kinds")
        if (s, d) in pairs:
            errs.append(f"duplicate link {s}->{d}")
        pairs.add((s, d))
        edges.append((s, d))
        if id_kind[s] == HIDDEN and id_kind[d] == HIDDEN and slot[s] > slot[d]:
            errs.append(f"link {s}->{d} goes from a later hidden slot to an earlier one")
    w = g.conn_weight[cv]
    if not np.all(np.isfinite(w)) or (weight_range is not None and np.any(np.abs(w) > weight_range + 1e-6)):
        errs.append("weight out of range")
    # Acyclic (Kahn) over all links.
    indeg = {i: 0 for i in id_kind}
    out = {i: [] for i in id_kind}
    for s, d in edges:
        if s in out and d in indeg:
            out[s].append(d)
            indeg[d] += 1
    queue = [i for i, v in indeg.items() if v == 0]
    seen = 0
    while queue:
        i = queue.pop()
        seen += 1
        for j in out[i]:
            indeg[j] -= 1
            if indeg[j] == 0:
                queue.append(j)
    if seen != len(indeg):
        errs.append("the network has a cycle")
    return errs


def check_population(pop, config: NEATConfig, weight_range: float | None = None) -> list[str]:
    """:func:`check_genome` on every genome, plus across the population: one innovation number per
    structural gene (the same number always joins the same pair of nodes, in the same column)."""
    pop = jax.tree.map(np.asarray, pop)
    errs = []
    by_innov: dict[int, tuple[int, int, int]] = {}
    for i in range(pop.node_id.shape[0]):
        g = jax.tree.map(lambda x: x[i], pop)
        errs += [f"genome {i}: {e}" for e in check_genome(g, config, weight_range)]
        cols = np.flatnonzero(g.conn_valid)
        for c, inn, s, d in zip(cols.tolist(), g.conn_innov[cols].tolist(), g.conn_src[cols].tolist(),
                                g.conn_dst[cols].tolist()):
            if by_innov.setdefault(inn, (s, d, c)) != (s, d, c):
                errs.append(f"genome {i}: innovation {inn} joins {s}->{d} in column {c}, elsewhere {by_innov[inn]}")
    return errs
