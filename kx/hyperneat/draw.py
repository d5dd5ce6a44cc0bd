"""A picture of what a CPPN encodes: its substrate's weight maps and its outputs on one state (a PNG).

Every panel is the 20 x 20 field drawn as :mod:`kx.sim.render` draws it (x to the right, y down), so a
panel reads like a frame of the champion's GIF:

* top row, the weights from four input cells (a corner, two edges, the centre; the cell is ringed) to
  every output cell: how a mark at that cell of the Bird's Eye View raises or lowers each output;
* bottom row, the output nodes' biases, then one start state: its Bird's Eye View image (the substrate's
  input) and the outputs it gives before the activation (a saturating activation hides their
  differences), keepers ringed, takers boxed, the holder starred and the decision's pass drawn; and the
  values the decision compares.
"""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from kx.neat.activations import ACTIVATIONS
from kx.sim import env, observe


def draw_substrate(table: dict, encoding, path: str | pathlib.Path, seed: int = 0) -> pathlib.Path:
    """``table``: one genome's ``{"w": [N, N], "b": [N]}`` (numpy); ``encoding``: the run's
    :class:`~kx.evolve.encodings.hyperneat.HyperNEATEncoding` (its task, image and decision)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim = encoding.sim
    w_side = sim.field_size
    w, b = np.asarray(table["w"]), np.asarray(table["b"])
    grid = lambda v: np.asarray(v).reshape(w_side, w_side)  # noqa: E731  [y, x]
    state = jax.tree.map(lambda a: a[..., 0], env.reset_batch(jax.random.key(seed), 1, encoding.sim_params, sim))
    img = np.asarray(observe.bev_obs(state, sim, image=encoding.image))
    pre = b + w @ img
    act = np.asarray(ACTIVATIONS[encoding.substrate_activation](jnp.asarray(pre)))
    action = int(encoding.policy.apply(_shared(table), state, None))
    holder = int(np.maximum(np.asarray(state.holder), 0))
    kx_, ky_ = np.asarray(state.keeper_x), np.asarray(state.keeper_y)
    tx_, ty_ = np.asarray(state.taker_x), np.asarray(state.taker_y)

    last = w_side - 1
    probes = [(2, 2), (last - 2, 2), (2, last - 2), (w_side // 2, w_side // 2)]
    fig, axes = plt.subplots(2, 4, figsize=(16, 8.4))
    vmax = float(encoding.substrate.weight_range)
    for ax, (x, y) in zip(axes[0], probes):
        im = ax.imshow(grid(w[:, x + w_side * y]), cmap="RdBu", vmin=-vmax, vmax=vmax)
        ax.add_patch(matplotlib.patches.Circle((x, y), 0.6, fill=False, lw=2, color="k"))
        ax.set_title(f"weights from input ({x}, {y})")
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.8, label="weight")
    axes[1, 0].imshow(grid(b), cmap="RdBu", vmin=-vmax, vmax=vmax)
    axes[1, 0].set_title("output biases")
    axes[1, 1].imshow(grid(img), cmap="RdBu", vmin=-1, vmax=1)
    axes[1, 1].set_title(f"input: Bird's Eye View ({encoding.image})")
    lim = max(float(np.abs(pre).max()), 1e-6)
    im2 = axes[1, 2].imshow(grid(pre), cmap="PuOr", vmin=-lim, vmax=lim)
    axes[1, 2].set_title("outputs before activation")
    for x, y in zip(kx_, ky_):
        axes[1, 2].add_patch(matplotlib.patches.Circle((x, y), 0.55, fill=False, lw=1.5, color="k"))
    for x, y in zip(tx_, ty_):
        axes[1, 2].add_patch(matplotlib.patches.Rectangle((x - 0.5, y - 0.5), 1, 1, fill=False, lw=1.5, color="r"))
    axes[1, 2].plot([kx_[holder]], [ky_[holder]], "k*", ms=12)
    if action != holder:
        axes[1, 2].annotate("", xy=(kx_[action], ky_[action]), xytext=(kx_[holder], ky_[holder]),
                            arrowprops=dict(arrowstyle="->", lw=2, color="k"))
    fig.colorbar(im2, ax=axes[1, 2], shrink=0.8)
    decision = "hold" if action == holder else f"pass to keeper {action}"
    axes[1, 3].axis("off")
    axes[1, 3].text(0.0, 0.9, f"{sim.name}, start state of seed {seed}\n\nkeepers: circles (holder: star)\n"
                    f"takers: red squares\n\ndecision ({encoding.decision}): {decision}\n\n"
                    f"at the keepers' cells, before and after\nthe activation ({encoding.substrate_activation}):\n"
                    + "\n".join(f"  keeper {k}{' (holder)' if k == holder else ''}: {pre[c]:+9.3f} -> {act[c]:+.6f}"
                                 for k, c in enumerate(kx_ + w_side * ky_)),
                    va="top", family="monospace", fontsize=9)
    for ax in axes.ravel()[:7]:
        ax.set_xticks([0, last])
        ax.set_yticks([0, last])
    fig.suptitle("HyperNEAT champion: its substrate")
    path = pathlib.Path(path)
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return path


def _shared(table: dict):
    from kx.sim.policies import Shared

    return Shared({k: jnp.asarray(v)[None] for k, v in table.items()}, jnp.zeros((), jnp.int32))
