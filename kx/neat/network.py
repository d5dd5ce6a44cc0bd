"""Turning a genome into a network that evaluates fast, and evaluating it.

:func:`build` runs once per genome per generation. The genome keeps its hidden nodes in topological
order, and build lays the enabled links out as two dense matrices in that order: ``w_in`` from the
inputs and bias, ``w_hid`` from the hidden nodes, one row per hidden node then per output.
:func:`forward` then computes the hidden nodes in order, each one a dot product with the values
before it, and the outputs last: no gathers, no data-dependent control flow, the same arithmetic for
every genome of a population, so that it vectorises over genomes and over inputs.

:func:`forward` is written *batch-last*: ``x`` is ``[n_inputs, *B]`` and each network field may carry
the same trailing ``*B`` (one network per lane, as the keep-away evaluator lays out policies) or none.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from kx.neat import activations
from kx.neat.genome import links
from kx.neat.types import Genome, NEATConfig

I32 = jnp.int32


@struct.dataclass
class Network:
    """A genome's network in evaluation order (``R = n_hidden + n_outputs`` rows)."""

    w_in: jax.Array  # [R, n_inputs + 1, *B] weights from inputs and the bias (last column)
    w_hid: jax.Array  # [R, n_hidden, *B] weights from hidden nodes; row i < n_hidden uses columns < i only
    act: jax.Array  # [R, *B] int32 activation id of each row's node


def build(g: Genome, config: NEATConfig) -> Network:
    """The network of one genome (vmap over a population).

    The genome's hidden slots are already in topological order (an invariant the operators keep, see
    :mod:`kx.neat.genome`), so row ``i < n_hidden`` is hidden slot ``n_fixed + i`` (empty slots give
    rows nothing reads) and building is two scatters of the enabled links' weights.
    """
    h, f, o = config.n_hidden, config.n_fixed, config.n_outputs
    n_in1 = config.n_inputs + 1
    lk = links(g, config)
    live, src, dst = lk.enabled, lk.src, lk.dst
    # Row of each node slot (outputs after the hidden rows), and column among the hidden nodes.
    row_of = jnp.concatenate([jnp.full((n_in1,), -1, I32), jnp.arange(h, h + o, dtype=I32),
                              jnp.arange(h, dtype=I32)])
    hcol_of = jnp.concatenate([jnp.full((f,), -1, I32), jnp.arange(h, dtype=I32)])
    # Scatters (a genome has at most one link per node pair, so nothing is summed): on XLA CPU they
    # cost a tenth of the one-hot products they replaced.
    r = h + o
    row, hcol = row_of[dst], hcol_of[src]
    to_in = live & (src < n_in1)
    to_hid = live & (hcol >= 0)
    w_in = jnp.zeros((r * n_in1,), jnp.float32).at[jnp.where(to_in, row * n_in1 + src, r * n_in1)].set(
        lk.weight, mode="drop").reshape(r, n_in1)
    w_hid = jnp.zeros((r * h,), jnp.float32).at[jnp.where(to_hid, row * h + hcol, r * h)].set(
        lk.weight, mode="drop").reshape(r, h)
    act_rows = jnp.concatenate([g.node_act[f:], g.node_act[config.first_output: f]])
    return Network(w_in=w_in, w_hid=w_hid, act=act_rows.astype(I32))


def forward(net: Network, x: jax.Array, config: NEATConfig, pre_activation: bool = False) -> jax.Array:
    """Outputs ``[n_outputs, *B]`` of a network for inputs ``x`` ``[n_inputs, *B]`` (batch-last).

    ``pre_activation=True``: the output nodes' weighted sums, before their activation (hidden nodes
    are activated as always). A decision by the largest output reads these when the output activation
    is increasing (:data:`kx.neat.activations.INCREASING`): in exact arithmetic they rank the outputs
    the same, and they do not tie where a float32 sigmoid saturates to 1.0 (above a sum of about 3.4
    for NEAT's steepened sigmoid)."""
    h = net.w_hid.shape[1]  # config.n_hidden, or fewer for a network of :func:`trim`
    if net.w_in.shape[0] != h + config.n_outputs:
        raise ValueError(f"net: {net.w_in.shape[0]} rows for {h} hidden and {config.n_outputs} output nodes")
    opts = config.activation_options
    nb = x.ndim - 1
    w_in = net.w_in.reshape(net.w_in.shape[:2] + (1,) * (nb + 2 - net.w_in.ndim) + net.w_in.shape[2:])
    w_hid = net.w_hid.reshape(net.w_hid.shape[:2] + (1,) * (nb + 2 - net.w_hid.ndim) + net.w_hid.shape[2:])
    act = net.act.reshape(net.act.shape[:1] + (1,) * (nb + 1 - net.act.ndim) + net.act.shape[1:])
    # Sums written out as chains of elementwise adds: XLA CPU fuses them into one loop, where a
    # reduction over these short axes (3 to 16 terms) went to a library call that cost 10x as much.
    z = w_in[:, -1]  # the bias
    for k in range(config.n_inputs):
        z = z + w_in[:, k] * x[k][None]  # [R, *B]
    hs = []
    for i in range(h):
        zi = z[i]
        for j in range(i):
            zi = zi + w_hid[i, j] * hs[j]
        hs.append(activations.apply(act[i], zi, opts))
    out = z[h:]
    for j in range(h):
        out = out + w_hid[h:, j] * hs[j][None]
    return out if pre_activation else activations.apply(act[h:], out, opts)


def hidden_rows(n_used: int, capacity: int) -> int:
    """The hidden rows a network of :func:`trim` keeps for genomes with at most ``n_used`` hidden nodes:
    4, 8, 16, ... (the next power of two from 4), at most ``capacity``. Each count is a shape the
    evaluator compiles its rungs for (30-90 s on 2 cores, then cached), and each of its programs holds
    memory maps of the process (kx.runtime), so the counts are few: at most 3 for the shipped capacity of
    16, and a run passes through them in order. Below 4 rows cost little (4v3 generation-0 population, ns
    per live step: 0 rows 1169, 2 rows 1261, 4 rows 1369, 8 rows 1792, 16 rows 2993; noisy, with other
    work on the machine), so 0 to 4 hidden nodes share one shape."""
    return min(capacity, max(4, 1 << (max(int(n_used), 1) - 1).bit_length()))


def trim(net: Network, rows: int, config: NEATConfig) -> Network:
    """``net`` (batch-first: any leading axes, as :func:`build` vmapped gives them) with only its first ``rows``
    hidden rows: the output rows kept, the hidden columns past ``rows`` dropped. A genome keeps its hidden nodes
    in a prefix of its slots (:func:`kx.neat.genome.n_hidden` of them), so when no genome has more than ``rows``
    hidden nodes, the dropped rows are empty slots: their weights are zero and :func:`forward` of the trimmed
    network gives the same hidden values and the same output sums (each dropped term is ``0 * h``, a zero, so
    the sums are equal, at most one of them ``+0.0`` where the other is ``-0.0``, which compare equal: the
    decisions are the same). The evaluator's cost per step falls with the rows (``python -m kx.bench
    policies``)."""
    h = config.n_hidden
    if rows == h:
        return net
    keep = np.concatenate([np.arange(rows), np.arange(h, h + config.n_outputs)])
    return Network(w_in=jnp.take(net.w_in, keep, axis=-2), w_hid=jnp.take(net.w_hid, keep, axis=-2)[..., :rows],
                   act=jnp.take(net.act, keep, axis=-1))


def activate(net: Network, x: jax.Array, config: NEATConfig) -> jax.Array:
    """Outputs ``[..., n_outputs]`` for inputs ``[..., n_inputs]`` of one network (batch-first
    convenience over :func:`forward`)."""
    lead = x.shape[:-1]
    flat = x.reshape(-1, x.shape[-1]).T
    return forward(net, flat, config).T.reshape(lead + (config.n_outputs,))


def reference_activate(g, x, config: NEATConfig) -> list[float]:
    """Plain-Python evaluation of one genome straight from its genes, for the tests: each node's value
    is its activation of the weighted sum over its enabled in-links, computed by recursion."""
    g = jax.tree.map(np.asarray, g)
    nodes = {int(i): (int(k), int(a)) for i, k, a, v in zip(g.node_id, g.node_kind, g.node_act, g.node_valid) if v}
    incoming: dict[int, list[tuple[int, float]]] = {i: [] for i in nodes}
    for s, d, w, e, v in zip(g.conn_src, g.conn_dst, g.conn_weight, g.conn_enabled, g.conn_valid):
        if v and e:
            incoming[int(d)].append((int(s), float(w)))
    memo: dict[int, float] = {}

    def value(i: int) -> float:
        if i in memo:
            return memo[i]
        if i < config.n_inputs:
            v = float(x[i])
        elif i == config.n_inputs:
            v = 1.0
        else:
            total = math.fsum(w * value(s) for s, w in incoming[i])
            v = activations.PY_ACTIVATIONS[config.activation_options[nodes[i][1]]](total)
        memo[i] = v
        return v

    return [value(config.first_output + k) for k in range(config.n_outputs)]
