"""The Bird's Eye View policy of HyperNEAT (Verbancsics & Stanley 2010; Didi & Nitschke 2016, section 3.2).

Over 450 lines because the policy, its two ways of computing the sums (the compiled XLA code and the native kernel's
binding) and the rule for which one runs belong together: the two must give the same bits.

A substrate is a ``W x W`` input layer fully connected to a ``W x W`` output layer (SPEC §3). A
generation's substrates arrive as one shared table (:class:`kx.sim.policies.Shared`)::

    {"w": float32 [G, N, N], "b": float32 [G, N]}     N = W * W, cell index x + W * y

with ``w[g, o, i]`` the weight from input cell ``i`` to output cell ``o`` (one row per output cell, so
the few output cells a decision reads are a few contiguous rows) and ``b[g, o]`` the output's bias.
Output cell ``o`` is ``act(b[o] + sum_i image[i] * w[o, i])``.

The image (:func:`kx.sim.observe.bev_obs`) has only a few dozen non-zero cells: the ``K + T`` agents'
cells and the cells on the paths from the holder to every other agent. The policy never forms the
dense image or the ``N x N`` product. It lists the image as a fixed number of *entries* per lane
(:func:`sparse_image`), ``K + T`` agent entries and ``(K - 1 + T) x (W - 2)`` path entries (path ``p``,
step ``i``; the holder's own path is empty, so only its ``K - 1`` teammates and the ``T`` takers have
one), and reads only the weights ``w[g, o, cell]`` of those entries for the output cells ``o`` the
decision reads. A path of ``n`` cells' Chebyshev distance has ``n - 1`` steps, the rest of its ``W - 2``
slots are padding (value 0): :func:`sparse_outputs` lists each lane's path steps one after another and
takes them a chunk at a time for as long as some lane of the batch has steps left, so that a batch pays
for its longest list rather than for every slot.

The product is linear in the image, so entries that share a cell need not be merged to be summed:
only the paper's clip needs each distinct cell's total once. The cell's first occurrence, its
*owner*, carries ``clip(total) - total``. The geometry of the digital line keeps this cheap: step ``i``
of any path lies at Chebyshev distance exactly ``i`` from the holder, so two paths can share a cell
only at the same step, and an agent at Chebyshev distance ``d`` from the holder can lie only on step
``d`` of a path (computed directly, not searched). An agent cell is owned by its lowest agent entry,
whose total sums the agents on it and the path steps through it; a path cell with no agent on it can
leave [-1, 1] only where four paths of one sign meet (5v3 and 6v4), and there the lowest path through
it owns it.

Speed (``python -m kx.bench policies``: a trained 4v3 population in the evaluator, 2-core CPU): the
reads of the weights dominate. Until 2026-12-03 every lane gathered all ``K x E`` weights (460 in 4v3)
into an array, one entry of every lane at a time; measured alone, those reads cost 8 times as much from
the whole 96 MB table as from one genome's 640 KB, and HyperNEAT's whole step cost 11-13 times the
heuristic's. Reading each lane's weights of a row one after another inside the chains of multiply-adds,
and leaving the padding out, halved it (5.6-6.9 times, the machine's load moving the figure); the sums
are the same bit for bit. Since 2026-12-05 the authors' image's sums run by default on a native kernel
(:mod:`kx.hyperneat.native`, ``impl``): each lane computes its own image and reads only its own entries, where the
compiled code runs a batch's lanes in lockstep up to its longest list; the same sums bit for bit, with
the multiply-adds rounded as this code's are under the process's flags (:func:`chain_is_fused`). See
docs/hyperneat.md, "What it costs" and "A native decision".
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from kx.hyperneat import native
from kx.neat.activations import ACTIVATIONS, INCREASING
from kx.sim import observe
from kx.sim.ops import col, fenced, pick
from kx.sim.policies import Policy, Shared
from kx.sim.types import KeepAwayConfig, State

#: the decisions the policy makes from its output cells (the images: kx.sim.observe.BEV_IMAGES)
DECISIONS = ("cells", "literal")
#: how :func:`sparse_outputs` computes the sums: ``"auto"`` the native kernel where it runs
#: (:func:`native_runs`), else the compiled XLA code; ``"xla"`` and ``"native"`` force one (the same bits)
IMPLS = ("auto", "xla", "native")
# floor(i * r + ROUND_OFFSET) with r = fl(d / n) is exactly floor((2 i d + n) / (2 n)) (the digital
# line's "halves rounded up") for |i|, |d|, n < 64: the computed i * r is within 1e-5 of i * d / n, an
# exact half lands 1e-3 above its integer, and any other value keeps at least 1 / (2 n) > 1e-3 + 1e-5
# from the next integer.
ROUND_OFFSET = 0.501


def _check(config: KeepAwayConfig, image: str, decision: str, activation: str, impl: str = "auto") -> None:
    if impl not in IMPLS:
        raise ValueError(f"impl: allowed {IMPLS}, got {impl!r}")
    if image not in observe.BEV_IMAGES:
        raise ValueError(f"image: allowed {observe.BEV_IMAGES}, got {image!r}")
    if decision not in DECISIONS:
        raise ValueError(f"decision: allowed {DECISIONS}, got {decision!r}")
    if activation not in ACTIVATIONS:
        raise ValueError(f"activation: allowed {tuple(ACTIVATIONS)}, got {activation!r}")
    if config.field_size >= 64:
        raise ValueError(f"field_size: the BEV policy's exact line arithmetic allows < 64, got {config.field_size}")


def n_entries(config: KeepAwayConfig) -> int:
    """Entries per lane of :func:`sparse_image`: ``K + T`` agents and ``(K - 1 + T) x (W - 2)`` path steps."""
    k, t, w = config.n_keepers, config.n_takers, config.field_size
    return k + t + (k - 1 + t) * (w - 2)


def _needs_path_clip(config: KeepAwayConfig, image: str) -> bool:
    """Whether a cell with no agent on it can leave [-1, 1]: only in the paper's image, when more than
    1 / 0.3 paths of one sign can meet (4 teammates or 4 takers: 5v3's and 6v4's keepers, 6v4's takers)."""
    if image != "paper":
        return False
    most = max(config.n_keepers - 1, config.n_takers)
    return most * max(observe.BEV_PATH_KEEPER, -observe.BEV_PATH_TAKER) > 1.0


def _image_parts(state: State, config: KeepAwayConfig, image: str):
    """The image's parts, batch-last: the holder's cell ``hc [*B]``; the ``K + T`` agent entries (cells and
    values, the paper image's owner corrections included); and the ``K - 1 + T`` paths (the holder's
    teammates in keeper order, then the takers), each ``(n, major, minor, slope, value)``: ``n`` the
    Chebyshev distance from the holder (steps ``1 .. n - 1`` are on the path), the step along the major
    and the minor axis, the slope and the value of each of its cells (before the paper image's clip of
    cells where paths meet, :func:`_needs_path_clip`)."""
    k_n, t_n, w = config.n_keepers, config.n_takers, config.field_size
    authors = image == "authors"
    h = jnp.maximum(state.holder, 0)
    kx, ky, tx, ty = state.keeper_x, state.keeper_y, state.taker_x, state.taker_y
    sx, sy = pick(kx, h), pick(ky, h)
    hc = sx + w * sy  # [*B] the holder's cell

    # --- agents: cell, value, Chebyshev distance from the holder
    ax = [kx[i] for i in range(k_n)] + [tx[j] for j in range(t_n)]
    ay = [ky[i] for i in range(k_n)] + [ty[j] for j in range(t_n)]
    a_cell = [x + w * y for x, y in zip(ax, ay)]
    if authors:
        a_val = [jnp.where(h == i, observe.BEV_AUTHORS_HOLDER, observe.BEV_AUTHORS_TEAMMATE) for i in range(k_n)]
        a_val += [jnp.full(h.shape, observe.BEV_AUTHORS_TAKER, jnp.float32)] * t_n
    else:
        a_val = [jnp.full(h.shape, observe.BEV_KEEPER, jnp.float32)] * k_n
        a_val += [jnp.full(h.shape, observe.BEV_TAKER, jnp.float32)] * t_n

    # --- paths to the holder's teammates (keeper order, skipping the holder) and to every taker
    rows = col(k_n - 1, h.ndim)
    mate = rows + (rows >= h).astype(jnp.int32)  # [K-1, *B]
    px = [pick(kx, mate[r]) for r in range(k_n - 1)] + [tx[j] for j in range(t_n)]
    py = [pick(ky, mate[r]) for r in range(k_n - 1)] + [ty[j] for j in range(t_n)]
    sign = [1.0] * (k_n - 1) + [-1.0] * t_n
    paths = []  # per path: (n, step along the major axis, step along the minor axis, slope, value)
    for x, y, sg in zip(px, py, sign):
        dx, dy = x - sx, y - sy
        adx, ady = jnp.abs(dx), jnp.abs(dy)
        n = jnp.maximum(adx, ady)
        x_major = adx >= ady
        major = jnp.where(x_major, jnp.sign(dx), w * jnp.sign(dy))
        minor = jnp.where(x_major, w, 1)
        slope = jnp.where(x_major, dy, dx).astype(jnp.float32) / jnp.maximum(n, 1).astype(jnp.float32)
        if authors:
            value = sg / (1.0 + jnp.sqrt((dx * dx + dy * dy).astype(jnp.float32)))
        else:
            value = jnp.full(h.shape, observe.BEV_PATH_KEEPER if sg > 0 else observe.BEV_PATH_TAKER, jnp.float32)
        paths.append((n, major, minor, slope, value))

    if not authors:
        # --- agent cells: the lowest agent entry on a cell owns it
        raw = list(a_val)
        for a in range(len(ax)):
            owner = jnp.ones(h.shape, bool)
            total = raw[a]
            for b in range(len(ax)):
                if b == a:
                    continue
                same = a_cell[b] == a_cell[a]
                if b < a:
                    owner = owner & ~same
                total = total + jnp.where(same, raw[b], 0.0)
            d = jnp.maximum(jnp.abs(ax[a] - sx), jnp.abs(ay[a] - sy))
            for n, major, minor, slope, value in paths:  # the agent can only be on step d of a path
                on = (d >= 1) & (d < n) & (_step_cell(hc, major, minor, slope, d) == a_cell[a])
                total = total + jnp.where(on, value, 0.0)
            a_val[a] = raw[a] + jnp.where(owner, jnp.clip(total, -1.0, 1.0) - total, 0.0)
    return hc, a_cell, a_val, paths


def _step_cell(hc, major, minor, slope, i):
    """The cell of step ``i`` of a path from the holder's cell ``hc`` (the digital line), any ``i``."""
    return hc + i * major + minor * jnp.floor(i * slope + ROUND_OFFSET).astype(jnp.int32)


def sparse_image(state: State, config: KeepAwayConfig, image: str = "paper") -> tuple[jax.Array, jax.Array]:
    """The BEV image as ``(cells, values)``, both ``[E, *B]`` with ``E = n_entries(config)``, such that
    ``image[cells[e]] += values[e]`` over all ``e`` rebuilds :func:`kx.sim.observe.bev_obs` exactly.

    Entries: the ``K`` keepers, the ``T`` takers, then path by path (the holder's teammates in keeper
    order, then the takers) steps ``1 .. W-2``; a step past a path's end has value 0 and the holder's
    cell (a valid index to gather from).

    The image is linear in its entries except for the paper's clip, so entries that share a cell need
    no deduplication to be summed; only the clip needs each distinct cell's total, once. The cell's
    *owner* carries the correction ``clip(total) - total``: an agent cell is owned by its lowest agent
    entry (the total sums the agents on it and the path steps through it); a path cell with no agent
    on it, by the lowest path through it (only where such a cell can leave [-1, 1], see
    :func:`_needs_path_clip`). The authors' image is not clipped and needs no owners.
    """
    _check(config, image, "cells", "identity")
    hc, a_cell, a_val, paths = _image_parts(state, config, image)
    n_p, n_s, n_a = len(paths), config.field_size - 2, len(a_cell)
    h = hc
    # the paths as arrays [P, 1, *B] against the steps [1, S, 1..]: the step loop becomes a broadcast
    pn, pmajor, pminor, pslope, pval = (jnp.stack(f)[:, None] for f in zip(*paths))
    step = col(n_s, h.ndim)[None] + 1  # [1, S, 1..] steps 1 .. W-2
    on_path = step < pn  # [P, S, *B]
    p_cell = jnp.where(on_path, _step_cell(hc, pmajor, pminor, pslope, step), hc)
    p_val = jnp.where(on_path, pval, 0.0)
    if _needs_path_clip(config, image):
        # --- path cells with no agent: the lowest path through the cell owns it (paths meet only at
        # the same step, so the comparison runs step by step)
        owner = on_path
        for a in range(n_a):
            owner = owner & (p_cell != a_cell[a])
        total = p_val
        p_index = col(n_p, h.ndim + 1)  # [P, 1, 1..]
        for q in range(n_p):
            same = (p_cell == p_cell[q][None]) & on_path[q][None]  # [P, S, *B]
            owner = owner & ~(same & (q < p_index))
            total = total + jnp.where(same & (q != p_index), p_val[q][None], 0.0)
        p_val = p_val + jnp.where(owner, jnp.clip(total, -1.0, 1.0) - total, 0.0)
    shape = (n_p * n_s,) + h.shape
    return (jnp.concatenate([jnp.stack(a_cell), p_cell.reshape(shape)]),
            jnp.concatenate([jnp.stack(a_val), p_val.reshape(shape)]))


def _genome_rows(index: jax.Array, rows: jax.Array, n: int) -> jax.Array:
    """Flat offsets ``(index * N + rows) * N`` of rows ``rows [R, *B]`` of each lane's genome."""
    return (index[None] * n + rows) * n


#: path steps per pass of :func:`sparse_outputs`' loop. In the evaluator on the trained 4v3 population of
#: ``kx.bench policies``, sampled in turn in one process, 8, 16, 24, 32 and 48 came within the noise of
#: each other (16 and 32 over 8 rounds: 6.3-6.6 and 6.4-6.9 times the heuristic's whole step); alone,
#: 16 was cheaper on 128 lanes (710 against 776 ns a lane) and 32 on 1125 (941 against 1174)
CHUNK = 32


def _compact_parts(state: State, config: KeepAwayConfig, image: str):
    """:func:`_image_parts` as arrays for :func:`sparse_outputs`: ``hc [*B]``, the agents' cells and values
    ``[A, *B]``, the paths' fields ``[P, *B]`` each, each path's first position in the lane's list of
    path steps ``[P, *B]`` (the steps of the paths one after another, padding left out) and the list's
    length ``[*B]``."""
    hc, a_cell, a_val, paths = _image_parts(state, config, image)
    starts, length = [], jnp.zeros_like(hc)
    for n, *_ in paths:
        starts.append(length)
        length = length + jnp.maximum(n - 1, 0)
    fields = tuple(jnp.stack(f) for f in zip(*paths))  # n, major, minor, slope, value
    return hc, jnp.stack(a_cell), jnp.stack(a_val), fields[1:], jnp.stack(starts), length


def _path_steps(j0, hc, fields, starts, length, size: int):
    """Cells and values ``[size, *B]`` of positions ``j0 .. j0 + size - 1`` of each lane's list of path
    steps (:func:`_compact_parts`): position ``j`` is step ``j - starts[p] + 1`` of the last path ``p``
    that starts at or before it; past the list's end, value 0 at the holder's cell."""
    j = j0 + col(size, hc.ndim)  # [S, 1..]
    sel = [f[0][None] for f in fields + (starts,)]
    for p in range(1, starts.shape[0]):  # the starts never decrease: the last path starting at or before j
        take = j >= starts[p][None]
        sel = [jnp.where(take, f[p][None], s) for f, s in zip(fields + (starts,), sel)]
    major, minor, slope, value, start = sel
    on = j < length[None]
    return (jnp.where(on, _step_cell(hc[None], major, minor, slope, j - start + 1), hc[None]),
            jnp.where(on, value, 0.0))


def _chain(w_flat: jax.Array, base: jax.Array, total: jax.Array, cells: jax.Array, values: jax.Array) -> jax.Array:
    """``total + values[e] * w[base + cells[e]]`` for each entry ``e`` in turn, unrolled: an elementwise chain
    of multiply-adds over the batch that reads each lane's weights of a row one after another."""
    for e in range(values.shape[0]):
        total = total + values[e][None] * w_flat.at[base + cells[e][None]].get(mode="promise_in_bounds")
    return total


def _agent_sums(w_flat, b_flat, n: int, index, rows, a_cell, a_val):
    """The rows' biases plus the agents' entries (:func:`_chain`), and the rows' flat offsets ``[R, *B]``."""
    base = _genome_rows(index, rows, n)  # [R, *B]
    bias = b_flat.at[index[None] * n + rows].get(mode="promise_in_bounds")
    return _chain(w_flat, base, bias, a_cell, a_val), base


def native_runs(image: str) -> str:
    """Why :func:`sparse_outputs` cannot run the native kernel (``kx.hyperneat.native``'s ``kx_bev_sums``) for this
    image in this process, or "" where it can: it computes the authors' image (the default; the paper image's
    clip stays with the XLA code) on the CPU backend, where the library could be built."""
    if image != "authors":
        return f"image {image!r}: the kernel computes the authors' image"
    return native.unavailable()


@functools.cache
def chain_is_fused() -> bool:
    """Whether XLA, under this process's flags, compiles :func:`_chain`'s ``total + value * weight`` into one
    fused multiply-add (one rounding: its default flags) or a product and a sum (two: backend optimisation
    level 0, as the test suite compiles). Probed once on values whose two roundings differ: ``-1 + (1 +
    2^-12)^2`` is ``2^-11 + 2^-24`` fused and ``2^-11`` with the product rounded first."""
    v = np.full((1,), 1 + 2.0**-12, np.float32)
    zero = np.zeros((1, 1), np.int32)
    with jax.ensure_compile_time_eval():  # run now, also when first asked while a policy is being traced
        out = jax.jit(_chain)(v, zero, np.full((1, 1), -1.0, np.float32), zero, v[:, None])
        return bool(np.asarray(out)[0, 0] != 2.0**-11)


def sparse_outputs(table: dict, index: jax.Array, rows: jax.Array, state: State, config: KeepAwayConfig,
                   image: str = "paper", activation: str | None = "bipolar_sigmoid",
                   busy: jax.Array | None = None, impl: str = "auto") -> jax.Array:
    """``act(b[o] + sum_i image[i] * w[o, i])`` of each lane's genome ``index [*B]`` at output cells
    ``rows [R, *B]``, from the sparse image: ``[R, *B]`` float32 (``activation=None``: the sums,
    before any activation). ``busy [*B]`` (optional): where false, the lane's image is left out and its
    outputs are ``act(b[o])`` (:func:`bev_policy`'s ``skip_idle``).

    Each output is the chain ``b[o]``, then ``+ value * w[o, cell]`` (one fused multiply-add each) over
    the image's entries in :func:`sparse_image`'s order, its padding left out: a padding entry adds
    ``0 * w``, which changes no sum, so the outputs are those of the whole list bit for bit. The agents'
    entries come first, then the path steps, listed one after another per lane (:func:`_compact_parts`)
    and taken ``CHUNK`` at a time for as long as any lane of the batch has some left: a lane pays for
    the batch's longest list (rounded up to a chunk), not for every path's ``W - 2`` slots (in trained
    4v3 play 34 steps on average and about 90 at most in a batch, of 108 slots). Where the paper image's
    clip changes path cells (:func:`_needs_path_clip`: 5v3 and 6v4), every entry of
    :func:`sparse_image` is taken.

    ``impl`` (:data:`IMPLS`): ``"auto"`` runs the native kernel (``kx.hyperneat.native``, :func:`native_runs`) where
    it can, one lane at a time over its own list, with multiply-adds rounded as the XLA code's are under the
    process's flags (:func:`chain_is_fused`): the same sums bit for bit, a lane that is not busy included
    (its agents add ``0 * w``). ``"native"`` refuses to run without it."""
    _check(config, image, "cells", activation or "identity", impl)
    if impl != "xla":
        why = native_runs(image)
        if not why:
            return _act(activation, native.bev_sums(table, index, rows, state, config, busy, chain_is_fused(),
                                                        ROUND_OFFSET))
        if impl == "native":
            raise ValueError(f"impl: 'native' is not available here ({why}); allowed {IMPLS}")
    n = config.field_size**2
    w_flat = table["w"].reshape(-1)
    if w_flat.shape[0] >= 2**31:
        raise ValueError(f"table: {table['w'].shape[0]} substrates of {n} x {n} exceed int32 indexing")
    b_flat = table["b"].reshape(-1)
    if _needs_path_clip(config, image):
        return _act(activation, _entry_outputs(w_flat, b_flat, index, rows, state, config, image, busy))

    # Fusion fences (kx.sim.ops.fenced), each measured: XLA CPU fuses a producer into every consumer, so
    # without them the lists would be recomputed per gathered weight. The gathers sit inside the chains
    # of multiply-adds: a lane's weights of one row are read one after another (its genome's row, a few
    # pages), not one entry for every lane at a time, which cost a page walk per weight on a 96 MB table.
    hc, a_cell, a_val, fields, starts, length = fenced(
        functools.partial(_compact_parts, config=config, image=image), state)
    if busy is not None:  # an idle lane: no path steps, and its agents add 0 (at a cell the lane reads anyway)
        length = jnp.where(busy, length, 0)
        a_cell, a_val = jnp.where(busy[None], a_cell, hc[None]), jnp.where(busy[None], a_val, 0.0)

    chain = functools.partial(_chain, w_flat)
    agents = functools.partial(_agent_sums, w_flat, b_flat, n)
    total, base = fenced(agents, index, rows, a_cell, a_val)
    longest = jnp.max(length)

    def more(carry):
        return carry[0] < longest

    def steps(carry):
        j0, total = carry
        cells, values = fenced(functools.partial(_path_steps, size=CHUNK), j0, hc, fields, starts, length)
        return j0 + CHUNK, fenced(chain, base, total, cells, values)

    total = jax.lax.while_loop(more, steps, (jnp.int32(0), total))[1]
    return _act(activation, total)


def _entry_outputs(w_flat, b_flat, index, rows, state, config, image, busy=None):
    """The sums at ``rows`` over every entry of :func:`sparse_image`, padding included, in its order: the
    agents' entries, then the paths' steps a path at a time (a loop over the paths, each path's ``W - 2``
    steps an unrolled chain of multiply-adds reading each lane's weights as :func:`sparse_outputs` does).
    Until 2026-12-03 every weight of the list was gathered into a ``[R, E, *B]`` array first; the chains
    give the same sums bit for bit (``tests/test_bev.py``) at 0.45-0.57 times the cost of a decision
    (``scripts/bev_every_entry.py`` at c848d7e: the trained 4v3 fixture's substrates on 4500 5v3 and 6v4 states,
    one core)."""
    n = config.field_size**2
    n_a, n_s = config.n_keepers + config.n_takers, config.field_size - 2
    cells, values = fenced(functools.partial(sparse_image, config=config, image=image), state)  # [E, *B]
    if busy is not None:
        values = jnp.where(busy[None], values, 0.0)
    n_p = (cells.shape[0] - n_a) // n_s
    path_cells = cells[n_a:].reshape((n_p, n_s) + cells.shape[1:])  # [P, S, *B]
    path_values = values[n_a:].reshape((n_p, n_s) + values.shape[1:])

    chain = functools.partial(_chain, w_flat)
    agents = functools.partial(_agent_sums, w_flat, b_flat, n)
    total, base = fenced(agents, index, rows, cells[:n_a], values[:n_a])

    def path(p, total):
        return fenced(chain, base, total, path_cells[p], path_values[p])

    return jax.lax.fori_loop(0, n_p, path, total)


def dense_outputs(w: jax.Array, b: jax.Array, state: State, config: KeepAwayConfig, image: str = "paper",
                  activation: str = "bipolar_sigmoid") -> jax.Array:
    """The plain reference: ``act(b + w @ bev_obs(state))`` for one substrate ``w [N, N]``, ``b [N]``
    and a batch of states: ``[N, *B]``."""
    _check(config, image, "cells", activation)
    img = observe.bev_obs(state, config, image)  # [N, *B]
    out = jnp.tensordot(w, img, axes=(1, 0), precision=jax.lax.Precision.HIGHEST)
    return ACTIVATIONS[activation](b.reshape(b.shape + (1,) * (img.ndim - 1)) + out)


def _ranked_on(activation: str) -> str | None:
    """What a decision compares for a substrate activation: the pre-activation sums (``None``) when the
    activation is increasing, so that outputs a float32 activation saturates (a bipolar sigmoid is
    exactly 1.0 above a sum of about 3.4) do not tie; the activations themselves otherwise."""
    return None if activation in INCREASING else activation


def _act(activation: str | None, x: jax.Array) -> jax.Array:
    return x if activation is None else ACTIVATIONS[activation](x)


@functools.lru_cache(maxsize=None)
def bev_policy(config: KeepAwayConfig, image: str = "paper", decision: str = "cells",
               activation: str = "bipolar_sigmoid", skip_idle: bool = False, impl: str = "auto") -> Policy:
    """The HyperNEAT policy on the Bird's Eye View, reading a shared table of substrates.

    Args:
      config: the task.
      image: ``"paper"`` (SPEC §1) or ``"authors"`` (the authors' code); see
        :func:`kx.sim.observe.bev_obs`.
      decision: ``"cells"`` (SPEC §3): the outputs at the holder's cell (hold) and at each teammate's
        cell (pass to it), the largest wins, ties go to hold, then to the lower keeper index. Each lane
        reads the weights of its image's entries (:func:`sparse_outputs`) from the ``K`` rows of its
        genome. ``"literal"``: the paper's wording, the largest output anywhere on the
        layer, passing to the keeper nearest that cell (:func:`kx.sim.observe.decode_bev` with
        ``literal=True``). It needs all ``N`` outputs, ``N / K`` times the weights of ``"cells"`` per
        lane and iteration, and is slow.
      activation: the substrate's output activation, a name of :data:`kx.neat.activations.ACTIVATIONS`.
        An increasing one (:data:`kx.neat.activations.INCREASING`) is never computed: the decision
        compares the outputs' sums before it, which rank the same in exact arithmetic and do not tie
        where the float32 activation saturates; other activations are compared after it.
      skip_idle: decide only where the world reads the decision: in a lane where nobody holds the ball
        or the episode is over (:func:`kx.sim.env.transition` ignores the action there), hold (keeper
        0, the stand-in holder, or the holder) without reading the image's weights. Every episode is
        the same bit for bit, and so is every decision of a lane whose holder has the ball; only the
        answers nobody reads change. Off by default here (the policy then decides on every state as
        the dense reference does); the run loop's HyperNEAT encoding turns it on. On the trained 4v3
        population of ``kx.bench policies`` a quarter less per live step (about a third of live steps
        have the ball in flight, and a quarter of the steps the evaluator executes are of finished
        episodes).
      impl: how the sums are computed (:func:`sparse_outputs`, :data:`IMPLS`): the same decisions bit for
        bit whichever runs.

    ``apply(Shared({"w": [G, N, N], "b": [G, N]}, index [*B]), state, key)`` returns a keeper index per
    lane (the holder's own index holds), also when nobody holds the ball (then keeper 0 stands in for the
    holder, as in :mod:`kx.sim.observe`).
    """
    _check(config, image, decision, activation, impl)
    if not isinstance(skip_idle, bool):
        raise ValueError(f"skip_idle: allowed true or false, got {skip_idle!r}")
    n = config.field_size**2
    ranked = _ranked_on(activation)

    def apply(params: Shared, state: State, key) -> jax.Array:
        h = jnp.maximum(state.holder, 0)
        busy = (state.holder >= 0) & ~state.done if skip_idle else None
        if decision == "cells":
            kc = state.keeper_x + config.field_size * state.keeper_y  # [K, *B]
            vals = sparse_outputs(params.table, params.index, kc, state, config, image, ranked, busy, impl)
            action = observe.decide_on_cells(vals, h, config.n_keepers)
        else:
            rows = jnp.broadcast_to(col(n, h.ndim), (n,) + h.shape)
            outs = sparse_outputs(params.table, params.index, rows, state, config, image, ranked, busy, impl)
            action = observe.decode_bev(outs, state, config, literal=True)
        return action if busy is None else jnp.where(busy, action, h)

    name = f"bev-{image}-{decision}-{activation}" + ("-skip-idle" if skip_idle else "") + (
        "" if impl == "auto" else f"-{impl}")
    return Policy(name, apply, shared=True)


@functools.lru_cache(maxsize=None)
def dense_policy(config: KeepAwayConfig, image: str = "paper", decision: str = "cells",
                 activation: str = "bipolar_sigmoid") -> Policy:
    """:func:`bev_policy` the plain way, for tests and benchmarks: the dense image and, per lane, its
    product with whole rows of the genome's weights (the ``K`` keeper cells' rows for ``"cells"``, all
    ``N x N`` weights for ``"literal"``: only for small batches)."""
    _check(config, image, decision, activation)
    w_cells = config.field_size
    ranked = _ranked_on(activation)

    def apply(params: Shared, state: State, key) -> jax.Array:
        h = jnp.maximum(state.holder, 0)
        img = observe.bev_obs(state, config, image)  # [N, *B]
        img_lm = jnp.moveaxis(img, 0, -1)  # [*B, N]
        w, b = params.table["w"], params.table["b"]
        if decision == "cells":
            kc = state.keeper_x + w_cells * state.keeper_y  # [K, *B]
            rows = w[params.index[None], kc]  # [K, *B, N]
            out = b[params.index[None], kc] + jnp.sum(rows * img_lm[None], axis=-1)
            return observe.decide_on_cells(_act(ranked, out), h, config.n_keepers)
        out = jnp.einsum("...oi,...i->...o", w[params.index], img_lm, precision=jax.lax.Precision.HIGHEST)
        out = _act(ranked, jnp.moveaxis(out + b[params.index], -1, 0))  # [N, *B]
        return observe.decode_bev(out, state, config, literal=True)

    return Policy(f"bev-dense-{image}-{decision}-{activation}", apply, shared=True)
