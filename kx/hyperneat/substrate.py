"""The HyperNEAT substrate of the Bird's Eye View, built from a whole population of CPPNs at once.

The substrate (SPEC §3; the paper, section 3.2 and its Fig. 1) has a ``W x W`` input layer and a ``W x
W`` output layer, one node per field cell (``W`` = 20, the field), fully connected from inputs to
outputs: ``N^2`` = 160,000 links for ``N = W^2`` cells. Cell ``c = x + W y`` (the index of
:func:`kx.sim.observe.bev_obs`) sits at substrate coordinates ``((2x + 1) / W - 1, (2y + 1) / W - 1)``,
the cell centres from -0.95 to 0.95 in steps of 0.1 for W = 20 (as the authors' substrate,
authors-code.md §1e).

**The query.** The weight of the link from input cell ``i`` at ``(x1, y1)`` to output cell ``o`` at
``(x2, y2)`` comes from the CPPN's outputs on the inputs ``(x1, y1, x2, y2)`` (plus NEAT's bias node;
with ``distance_input``, a fifth input ``|(x2, y2) - (x1, y1)|``, the distance in substrate
coordinates: 0.1 per cell, at most 1.9 sqrt 2):

* output 0, the weight: ``weight_range * clip(out_0, -1, 1)`` (the CPPN's outputs are bipolar sigmoids,
  so the clip only matters for other output activations): weights in [-5, 5];
* output 1, the expression (the paper: "a value indicating whether that connection can be expressed",
  Verbancsics & Stanley's link expression output): the link exists only where ``out_1 > 0``; elsewhere
  its weight is 0;
* output 2, the bias of output node ``o``: ``weight_range * clip(out_2, -1, 1)`` read from the query at
  the node's own coordinates ``(x2, y2, x2, y2)``. That is the query of the link from input cell ``o``
  to output cell ``o``, so the biases cost no query of their own. (The authors' code reads a bias from a
  query with the source coordinates replaced by the target's, the same point, on another output.)

**One batched query per generation.** :func:`build` evaluates every CPPN of a population over all
``N^2`` link coordinates: per genome, the outputs' part from the inputs (a ``[3, n_in] x [n_in, N^2]``
product), then the genome's own hidden nodes in topological order (as many as it has, not the
capacity), each from the inputs and the hidden values before it (only the hidden rows it can read:
:func:`cppn_outputs`), through its own activation function (selected per genome, so only that function is
computed), added into the outputs; the bias output only at the 400 links it is read at (the diagonal, see
output 2 above). Genomes go one after another
(``lax.map``): each is a wide, fully vectorised computation over 160,000 links, and the activation of a
hidden node is a real branch rather than every function of the set computed and masked. The result
is the generation's table ``{"w": [P, N, N], "b": [P, N]}`` (``w[g, o, i]``: genome ``g``'s weight from
input cell ``i`` to output cell ``o``; a row per output cell, so the few output cells a decision reads
are contiguous), handed to the evaluator once as the shared table of :mod:`kx.sim.evaluate` and never
copied per lane: 96 MB for 150 genomes.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from kx.neat import genome as gn
from kx.neat import network
from kx.neat.activations import ACTIVATIONS
from kx.neat.types import Genome, NEATConfig

WEIGHT, EXPRESSION, BIAS = 0, 1, 2
CPPN_OUTPUTS = 3
CPPN_INPUTS = ("x1", "y1", "x2", "y2")


@dataclasses.dataclass(frozen=True)
class Substrate:
    """The substrate's geometry and how CPPN outputs become weights (static and hashable).

    ``resolution``: cells per side (the field size); ``distance_input``: the CPPN has a fifth input, the
    distance between a link's endpoints; ``weight_range``: weights and biases lie in [-range, range].
    """

    resolution: int = 20
    distance_input: bool = False
    weight_range: float = 5.0

    def __post_init__(self):
        r = self.resolution
        if not (isinstance(r, int) and not isinstance(r, bool) and 2 <= r <= 64):
            raise ValueError(f"Substrate.resolution: allowed an integer in [2, 64], got {self.resolution!r}")
        if not isinstance(self.distance_input, bool):
            raise ValueError(f"Substrate.distance_input: allowed true or false, got {self.distance_input!r}")
        if not (isinstance(self.weight_range, float) and 0.0 < self.weight_range <= 1e3):
            raise ValueError(f"Substrate.weight_range: allowed a number in (0, 1000], got {self.weight_range!r}")

    @property
    def n_cells(self) -> int:
        return self.resolution**2

    @property
    def n_inputs(self) -> int:
        """The CPPN's inputs (NEAT adds the bias node)."""
        return len(CPPN_INPUTS) + int(self.distance_input)

    @property
    def input_names(self) -> tuple[str, ...]:
        return CPPN_INPUTS + (("d",) if self.distance_input else ())

    def coordinates(self) -> np.ndarray:
        """``[N, 2]`` substrate coordinates ``(x, y)`` of each cell ``c = x + W y``."""
        w = self.resolution
        c = np.arange(w * w)
        return np.stack([(2 * (c % w) + 1) / w - 1.0, (2 * (c // w) + 1) / w - 1.0], axis=1).astype(np.float32)

    def queries(self) -> np.ndarray:
        """``[n_inputs, N * N]`` CPPN inputs of every link; link ``o * N + i`` goes from input cell ``i``
        to output cell ``o``."""
        xy = self.coordinates()
        n = self.n_cells
        src = np.tile(xy, (n, 1))  # link o * N + i: input cell i
        dst = np.repeat(xy, n, axis=0)  # output cell o
        rows = [src[:, 0], src[:, 1], dst[:, 0], dst[:, 1]]
        if self.distance_input:
            rows.append(np.sqrt(((dst - src) ** 2).sum(axis=1)))
        return np.stack(rows).astype(np.float32)

    def check_cppn(self, config: NEATConfig) -> None:
        if (config.n_inputs, config.n_outputs) != (self.n_inputs, CPPN_OUTPUTS):
            raise ValueError(f"CPPN config: {config.n_inputs} inputs and {config.n_outputs} outputs; this substrate "
                             f"queries {self.n_inputs} inputs {self.input_names} and {CPPN_OUTPUTS} outputs "
                             "(weight, expression, bias)")


def _switch(act: jax.Array, x: jax.Array, options: tuple[str, ...]) -> jax.Array:
    if len(options) == 1:
        return ACTIVATIONS[options[0]](x)
    return jax.lax.switch(act, [ACTIVATIONS[name] for name in options], x)


def _dot_widths(rows: int) -> tuple[int, ...]:
    """The widths of the sums over earlier hidden nodes :func:`cppn_outputs` takes (see there): 2, 4, 8, ...
    below ``rows``, then ``rows``. None of 1: XLA rewrites a dot over one row as a product, which it may
    then fuse with the addition after it into one multiply-add, a rounding fewer than the dot's sum."""
    return tuple(k for k in (2, 4, 8, 16, 32, 64) if k < rows) + (rows,)


def cppn_outputs(net: network.Network, n_hidden: jax.Array, x: jax.Array, config: NEATConfig,
                 rows: int | None = None, last_at: np.ndarray | None = None, narrow: bool = True):
    """Outputs ``[n_outputs, L]`` of one CPPN's network (not vmapped) for inputs ``x [n_inputs, L]``,
    computing only its first ``n_hidden`` hidden rows (the genome's hidden nodes, a prefix of its slots).

    ``rows`` (at least ``n_hidden``; default the capacity): the hidden values kept, and so the longest of
    the hidden nodes' sums over the hidden nodes before them. The slots past the genome's hidden nodes add
    ``0 * 0`` terms, so fewer rows give the same values as reals (at most a zero's sign differs, as in
    :func:`kx.neat.network.trim`), for less work: 150 trained 4v3 CPPNs of 3-4 hidden nodes at 4 rows
    (and split over 2 CPU devices) build in 152 ms against 209 ms with all 16 on one device
    (``scripts/hyperneat_table_placement.py`` at 4a07c62).

    The same holds within a query: hidden node ``i``'s sum over the hidden rows reads only the first
    ``k >= i`` of them, ``k`` the narrowest of :func:`_dot_widths` (rows ``i`` and later are still 0).
    XLA CPU computes each of these ``jnp.dot``s as one fused multiply-add after another from +0, row by
    row, so the rows left out changed nothing, not even a zero's sign (tests/test_substrate.py checks it
    against the sum over every row: ``narrow=False``, the query as it was until 2026-12-05).

    ``last_at`` (indices of ``x``'s columns): the last output only at those columns; returns ``(first
    outputs [n_outputs - 1, L], last output [len(last_at)])`` (the substrate's biases are read at 400 of
    the 160,000 links: the other 159,600 values of that output, their activations and their share of
    each hidden node's update were computed for nothing). Each value is the same as without it."""
    h, o, n_in = config.n_hidden, config.n_outputs, config.n_inputs
    rows = h if rows is None else rows
    opts = config.activation_options
    hp = jax.lax.Precision.HIGHEST

    def from_inputs(rows):  # the inputs' and the bias's part of rows [r, n_in + 1] -> [r, L]
        return jnp.dot(rows[:, :n_in], x, precision=hp) + rows[:, n_in:]

    out = from_inputs(net.w_in[h:])
    split = o if last_at is None else o - 1
    out, last = out[:split], (None if last_at is None else out[split][last_at])
    if h:
        def body(width, i, carry):  # hidden node i: from the inputs and the hidden nodes before it; into the outputs
            hid, out, last = carry
            row = jax.lax.dynamic_slice_in_dim(net.w_in, i, 1)
            hi = _switch(net.act[i], from_inputs(row)[0] + jnp.dot(net.w_hid[i, :width], hid[:width], precision=hp),
                         opts)
            out = out + net.w_hid[h:h + split, i][:, None] * hi[None]
            if last_at is not None:
                last = last + net.w_hid[h + split, i] * hi[last_at]
            return hid.at[i].set(hi), out, last

        carry = (jnp.zeros((rows, x.shape[1]), jnp.float32), out, last)
        first = 0  # nodes first..width read `width` rows (hidden node i needs i of them)
        for width in (_dot_widths(rows) if narrow else (rows,)):
            end = rows if width == rows else width + 1
            carry = jax.lax.fori_loop(first, jnp.minimum(n_hidden, end), functools.partial(body, width), carry)
            first = end
        _, out, last = carry
    outs = jnp.stack([_switch(net.act[h + k], out[k], opts) for k in range(split)])
    if last_at is None:
        return outs
    return outs, _switch(net.act[h + split], last, opts)


@functools.partial(jax.jit, static_argnames=("config", "substrate", "devices", "rows", "reference"))
def build(population: Genome, config: NEATConfig, substrate: Substrate, devices: int = 1,
          rows: int | None = None, reference: bool = False) -> dict:
    """The substrates of a population of CPPNs (leading axis P): ``{"w": [P, N, N], "b": [P, N]}``
    (see the module docstring). ``rows``: the hidden rows each CPPN's query keeps (:func:`cppn_outputs`),
    at least the population's most hidden nodes (:func:`hidden_rows`); default the capacity.

    ``devices`` > 1 (P a multiple of it): each of the first ``devices`` local devices builds its share of
    the genomes, and the table comes with its rows split over them (:func:`kx.sim.lanes.put_rows`), where
    the evaluator's lanes that play them run: it reads them there instead of copying the whole table onto
    every device. Every genome's substrate is the same bit for bit either way.

    ``reference``: the query as it was until 2026-12-05 (every hidden row in each sum, every output on
    every link: :func:`cppn_outputs` with ``narrow=False`` and no ``last_at``), the same bits for more work;
    tests/test_substrate.py and ``scripts/substrate_build.py`` at 4a07c62 check and time the two."""
    substrate.check_cppn(config)
    if devices == 1:
        return _build(population, config, substrate, rows, reference)
    if population.node_id.shape[0] % devices:
        raise ValueError(f"devices: {population.node_id.shape[0]} CPPNs do not split evenly over {devices} devices")
    from kx.sim import lanes

    return jax.shard_map(functools.partial(_build, config=config, substrate=substrate, rows=rows, reference=reference),
                         mesh=lanes.mesh(devices), in_specs=(lanes.TABLE_ROWS,), out_specs=lanes.TABLE_ROWS,
                         check_vma=False)(population)


def hidden_rows(population: Genome, config: NEATConfig) -> int:
    """The hidden rows :func:`build` needs for ``population`` (any leading axes): the genomes' most hidden
    nodes rounded up as :func:`kx.neat.network.hidden_rows` does (4, 8, 16: few shapes to compile), read
    on the host, so not traceable."""
    kinds = np.asarray(population.node_kind)
    used = int((kinds == gn.HIDDEN).sum(axis=-1).max()) if kinds.size else 0
    return network.hidden_rows(used, config.n_hidden)


def _build(population: Genome, config: NEATConfig, substrate: Substrate, rows: int | None = None,
           reference: bool = False) -> dict:
    n, r = substrate.n_cells, substrate.weight_range
    x = jnp.asarray(substrate.queries())
    nets = jax.vmap(lambda g: network.build(g, config))(population)
    hidden = jax.vmap(gn.n_hidden)(population)

    def one(args):
        net, nh = args
        if reference:
            out = cppn_outputs(net, nh, x, config, rows, narrow=False)  # [3, N * N]
            bias = jnp.diagonal(out[BIAS].reshape(n, n))
        else:  # the bias of output node o is read at link o * N + o (its own coordinates): the diagonal
            out, bias = cppn_outputs(net, nh, x, config, rows, last_at=np.arange(n) * (n + 1))
        w = jnp.where(out[EXPRESSION] > 0.0, r * jnp.clip(out[WEIGHT], -1.0, 1.0), 0.0).reshape(n, n)
        return w, r * jnp.clip(bias, -1.0, 1.0)

    w, b = jax.lax.map(one, (nets, hidden))
    return {"w": w, "b": b}
