"""Drawing a genome's network as a PNG (matplotlib, no display needed)."""

from __future__ import annotations

import pathlib

import jax
import numpy as np

from kx.neat.types import BIAS, HIDDEN, INPUT, OUTPUT, NEATConfig


def _layers(g, config: NEATConfig) -> dict[int, int]:
    """Layer of each node id: inputs and bias 0, hidden nodes by longest path over all links, outputs last."""
    ids = [int(i) for i, v in zip(g.node_id, g.node_valid) if v]
    kind = {int(i): int(k) for i, k, v in zip(g.node_id, g.node_kind, g.node_valid) if v}
    links = [(int(s), int(d)) for s, d, v in zip(g.conn_src, g.conn_dst, g.conn_valid) if v]
    layer = {i: 0 for i in ids}
    for _ in range(len(ids)):
        for s, d in links:
            if kind[d] == HIDDEN:
                layer[d] = max(layer[d], layer[s] + 1)
    top = max([layer[i] for i in ids if kind[i] == HIDDEN], default=0) + 1
    for i in ids:
        if kind[i] == OUTPUT:
            layer[i] = top
    return layer


def draw_genome(genome, config: NEATConfig, path: str | pathlib.Path, input_names=None, output_names=None,
                title: str | None = None) -> pathlib.Path:
    """Write ``genome`` (one genome) as a PNG: inputs at the bottom, outputs at the top, hidden nodes by
    depth; links coloured by sign (blue positive, red negative), width by |weight|, disabled dashed.
    ``input_names``/``output_names`` (at least ``n_inputs``/``n_outputs`` of them; e.g. the keep-away
    features of :func:`kx.sim.observe.input_names`) are written beside the nodes, which then carry
    their index; without them the nodes read ``in<i>``/``out<k>``."""
    for names, n, what in ((input_names, config.n_inputs, "input_names"),
                           (output_names, config.n_outputs, "output_names")):
        if names is not None and len(names) < n:
            raise ValueError(f"draw_genome: {what} has {len(names)} names, the network {n} {what[:-6]}s")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = jax.tree.map(np.asarray, genome)
    layer = _layers(g, config)
    kind = {int(i): int(k) for i, k, v in zip(g.node_id, g.node_kind, g.node_valid) if v}
    act = {int(i): config.activation_options[int(a)] for i, a, v in zip(g.node_id, g.node_act, g.node_valid) if v}
    by_layer: dict[int, list[int]] = {}
    for i in sorted(layer):
        by_layer.setdefault(layer[i], []).append(i)
    pos = {}
    for lay, members in by_layer.items():
        for j, i in enumerate(members):
            pos[i] = ((j + 1) / (len(members) + 1), lay)
    n_layers = max(by_layer) + 1
    fig, ax = plt.subplots(figsize=(max(6, 0.45 * max(len(m) for m in by_layer.values())), 1.6 * n_layers + 1))
    w_max = max(float(np.max(np.abs(g.conn_weight))), 1e-6)
    for s, d, w, e, v in zip(g.conn_src, g.conn_dst, g.conn_weight, g.conn_enabled, g.conn_valid):
        if not v:
            continue
        (x0, y0), (x1, y1) = pos[int(s)], pos[int(d)]
        ax.plot([x0, x1], [y0, y1], color="tab:blue" if w >= 0 else "tab:red", alpha=0.8 if e else 0.35,
                linestyle="-" if e else "--", linewidth=0.5 + 2.5 * abs(float(w)) / w_max, zorder=1)
    colours = {INPUT: "#dddddd", BIAS: "#fff2a8", HIDDEN: "#cfe8cf", OUTPUT: "#cfd8f0"}
    for i, (x, y) in pos.items():
        ax.scatter([x], [y], s=380, color=colours[kind[i]], edgecolor="black", zorder=2)
        name = None  # a given input's or output's name, written beside its node (below / above)
        if kind[i] == INPUT:
            label, name = (str(i), input_names[i]) if input_names else (f"in{i}", None)
        elif kind[i] == BIAS:
            label = "bias"
        elif kind[i] == OUTPUT:
            k = i - config.first_output
            label, name = (f"o{k}", output_names[k]) if output_names else (f"out{k}", None)
        else:
            label = f"{i}\n{act[i]}" if len(config.activation_options) > 1 else str(i)
        ax.annotate(label, (x, y), ha="center", va="center", fontsize=7, zorder=3)
        if name is not None:
            below = kind[i] == INPUT
            ax.annotate(name, (x, y), xytext=(0, -12 if below else 12), textcoords="offset points",
                        ha="center", va="top" if below else "bottom", rotation=90 if below else 0, fontsize=7,
                        zorder=3)
    hidden = sum(1 for k in kind.values() if k == HIDDEN)
    enabled = int(np.sum(g.conn_valid & g.conn_enabled))
    ax.set_title(title or f"{hidden} hidden nodes, {enabled} enabled links of {int(g.conn_valid.sum())}")
    ax.set_xlim(0, 1)
    ax.set_ylim(-0.5, n_layers - 0.5)
    ax.axis("off")
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
