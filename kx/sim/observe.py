"""Observations of the holder's situation and the decoding of policy outputs into actions.

Three layouts (SPEC §1, "Observations"):

* ``fixed``, 13 inputs / 3 outputs (the paper's Table 1): the holder K1, its 2 nearest teammates and
  2 nearest takers sorted by distance. The same layout for every team size, so a genome transfers.
* ``full``, ``4K + 2T - 3`` inputs / K outputs (Stone, Sutton & Kuhlmann 2005): every teammate and
  taker, sorted by distance from the holder.
* ``bev``, the ``W x W`` Bird's Eye View image of HyperNEAT (Verbancsics & Stanley 2010).

Distances are divided by the largest cell distance ``(W-1) * sqrt(2)``, angles by pi. Actions are keeper
indices (the holder's own index holds), as :func:`kx.sim.env.step` takes them. All functions are
batch-last and rank-polymorphic like the simulator; outputs of the observations are float32.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from kx.sim.ops import col, pick
from kx.sim.types import KeepAwayConfig, State

FIXED_INPUTS, FIXED_OUTPUTS = 13, 3
BEV_KEEPER, BEV_TAKER, BEV_PATH_KEEPER, BEV_PATH_TAKER = 1.0, -1.0, 0.3, -0.3


def n_inputs(layout: str, config: KeepAwayConfig) -> int:
    return {"fixed": FIXED_INPUTS, "full": 4 * config.n_keepers + 2 * config.n_takers - 3,
            "bev": config.field_size**2}[layout]


def n_outputs(layout: str, config: KeepAwayConfig) -> int:
    return {"fixed": FIXED_OUTPUTS, "full": config.n_keepers, "bev": config.field_size**2}[layout]


def _holder(state: State) -> jax.Array:
    return jnp.maximum(state.holder, 0)


def teammate_order(state: State, config: KeepAwayConfig) -> jax.Array:
    """Keeper indices sorted by squared distance from the holder (ties: lower index), holder first.

    Returns ``[K, *B]``: row 0 is the holder, row r its r-th nearest teammate.
    """
    h = _holder(state)
    kx, ky = state.keeper_x, state.keeper_y
    hx, hy = pick(kx, h), pick(ky, h)
    d2 = (kx - hx) ** 2 + (ky - hy) ** 2
    d2 = jnp.where(col(config.n_keepers, h.ndim) == h, -1, d2)
    return _argsort_small(d2)


def taker_order(state: State, config: KeepAwayConfig) -> jax.Array:
    """Taker indices sorted by squared distance from the holder (ties: lower index)."""
    h = _holder(state)
    hx, hy = pick(state.keeper_x, h), pick(state.keeper_y, h)
    d2 = (state.taker_x - hx) ** 2 + (state.taker_y - hy) ** 2
    return _argsort_small(d2)


def _argsort_small(v: jax.Array) -> jax.Array:
    """Stable argsort along axis 0 of a short axis, by counting (no sort op on the batch)."""
    n = v.shape[0]
    idx = col(n, v.ndim - 1)
    rank = jnp.zeros_like(v, dtype=jnp.int32)
    for m in range(n):
        rank = rank + ((v[m] < v) | ((v[m] == v) & (m < idx))).astype(jnp.int32)
    # invert the permutation: order[r] = i where rank[i] == r
    return jnp.sum(jnp.where(rank[None] == idx[:, None], idx[None], 0), axis=1).astype(jnp.int32)


def _features(state: State, config: KeepAwayConfig, n_mates: int, n_takers: int) -> jax.Array:
    """Stone-style features from the holder's view with ``n_mates`` teammates and ``n_takers`` takers."""
    w = config.field_size
    diag = (w - 1) * math.sqrt(2.0)
    c = (w - 1) / 2.0
    ko, to = teammate_order(state, config), taker_order(state, config)
    fx = lambda a: a.astype(jnp.float32)  # noqa: E731
    kxs = [fx(pick(state.keeper_x, ko[r])) for r in range(n_mates + 1)]
    kys = [fx(pick(state.keeper_y, ko[r])) for r in range(n_mates + 1)]
    txs = [fx(pick(state.taker_x, to[r])) for r in range(n_takers)]
    tys = [fx(pick(state.taker_y, to[r])) for r in range(n_takers)]
    dist = lambda ax, ay, bx, by: jnp.sqrt((ax - bx) ** 2 + (ay - by) ** 2) / diag  # noqa: E731

    def angle(ix, iy, jx, jy):  # angle at the holder between holder->i and holder->j, over pi
        ux, uy, vx, vy = ix - kxs[0], iy - kys[0], jx - kxs[0], jy - kys[0]
        return jnp.arctan2(jnp.abs(ux * vy - uy * vx), ux * vx + uy * vy) / math.pi

    mates = range(1, n_mates + 1)
    feats = [dist(kxs[0], kys[0], c, c)]
    feats += [dist(kxs[0], kys[0], kxs[i], kys[i]) for i in mates]
    feats += [dist(kxs[0], kys[0], txs[j], tys[j]) for j in range(n_takers)]
    feats += [dist(kxs[i], kys[i], c, c) for i in mates]
    feats += [dist(txs[j], tys[j], c, c) for j in range(n_takers)]
    feats += [_min(dist(kxs[i], kys[i], txs[j], tys[j]) for j in range(n_takers)) for i in mates]
    feats += [_min(angle(kxs[i], kys[i], txs[j], tys[j]) for j in range(n_takers)) for i in mates]
    return jnp.stack(feats)


def _feature_names(n_mates: int, n_takers: int) -> tuple[str, ...]:
    """The names of :func:`_features`' rows, in its order: K1 is the holder, K2, K3, ... its teammates
    and T1, T2, ... the takers by distance from it, C the centre; ``min dist(K2,T)`` is the distance
    from K2 to its nearest taker, ``min ang(K2,K1,T)`` the smallest angle at K1 between K2 and a taker."""
    mates, takers = range(2, n_mates + 2), range(1, n_takers + 1)
    names = ["dist(K1,C)"]
    names += [f"dist(K1,K{i})" for i in mates]
    names += [f"dist(K1,T{j})" for j in takers]
    names += [f"dist(K{i},C)" for i in mates]
    names += [f"dist(T{j},C)" for j in takers]
    names += [f"min dist(K{i},T)" for i in mates]
    names += [f"min ang(K{i},K1,T)" for i in mates]
    return tuple(names)


def full_layout_map(source: KeepAwayConfig, target: KeepAwayConfig) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Where each ``full``-layout input and output of task ``source`` lies in the layout of the larger
    task ``target``: ``(input_map, output_map)``, ``input_map[i]`` the target index of source input
    ``i``. Each feature keeps its meaning: the holder's distance to the r-th nearest teammate stays
    that, and so on for every group of :func:`full_obs`; the target's other inputs and outputs are
    those of the agents the source did not have. Output ``o`` (hold, pass to the o-th nearest
    teammate) stays ``o``."""
    ms, ts = source.n_keepers - 1, source.n_takers
    mt, tt = target.n_keepers - 1, target.n_takers
    if ms > mt or ts > tt:
        raise ValueError(f"full_layout_map: {source.name} is larger than {target.name}")
    groups = ((1, 1), (ms, mt), (ts, tt), (ms, mt), (ts, tt), (ms, mt), (ms, mt))  # (source size, target size)
    input_map, offset = [], 0
    for n_s, n_t in groups:
        input_map += [offset + r for r in range(n_s)]
        offset += n_t
    return tuple(input_map), tuple(range(ms + 1))


def _min(xs):
    xs = list(xs)
    out = xs[0]
    for x in xs[1:]:
        out = jnp.minimum(out, x)
    return out


def fixed_obs(state: State, config: KeepAwayConfig) -> jax.Array:
    """The paper's 13 inputs ``[13, *B]``: dist(K1,C), dist(K1,K2), dist(K1,K3), dist(K1,T1),
    dist(K1,T2), dist(K2,C), dist(K3,C), dist(T1,C), dist(T2,C), min_j dist(K2,Tj), min_j dist(K3,Tj),
    min_j ang(K2,K1,Tj), min_j ang(K3,K1,Tj), with j over T1, T2."""
    return _features(state, config, 2, 2)


def full_obs(state: State, config: KeepAwayConfig) -> jax.Array:
    """Stone et al.'s ``4K + 2T - 3`` inputs, in the order of :func:`fixed_obs` generalised to every
    teammate and taker (sorted by distance from the holder)."""
    return _features(state, config, config.n_keepers - 1, config.n_takers)


def fixed_names() -> tuple[str, ...]:
    """The names of :func:`fixed_obs`' 13 inputs, in its order (``dist(K1,C)``, ``dist(K1,K2)``, ...)."""
    return _feature_names(2, 2)


def full_names(config: KeepAwayConfig) -> tuple[str, ...]:
    """The names of :func:`full_obs`' ``4K + 2T - 3`` inputs for ``config``'s team sizes, in its order."""
    return _feature_names(config.n_keepers - 1, config.n_takers)


def input_names(layout: str, config: KeepAwayConfig) -> tuple[str, ...]:
    """The names of the ``fixed`` or ``full`` layout's inputs."""
    return {"fixed": fixed_names, "full": lambda: full_names(config)}[layout]()


def output_names(layout: str, config: KeepAwayConfig) -> tuple[str, ...]:
    """The names of the ``fixed`` or ``full`` layout's outputs, as :func:`decode_ranked` reads them:
    hold, then pass to K2, K3, ... (the teammates by distance from the holder)."""
    return ("hold",) + tuple(f"pass K{i}" for i in range(2, n_outputs(layout, config) + 1))


def decode_ranked(outputs: jax.Array, state: State, config: KeepAwayConfig) -> jax.Array:
    """Outputs ``[n, *B]`` (hold, pass to the 1st, 2nd, ... nearest teammate) to a keeper index.

    The largest output acts; ties go to the earlier output (hold first)."""
    choice = jnp.argmax(outputs, axis=0).astype(jnp.int32)
    return pick(teammate_order(state, config), choice)


BEV_IMAGES = ("paper", "authors")
BEV_AUTHORS_HOLDER, BEV_AUTHORS_TEAMMATE, BEV_AUTHORS_TAKER = 1.0, 0.5, -1.0


def bev_obs(state: State, config: KeepAwayConfig, image: str = "paper") -> jax.Array:
    """Bird's Eye View image ``[W*W, *B]`` (cell ``x + W*y``).

    ``image="paper"`` (SPEC §1): keepers 1.0, takers -1.0, cells strictly between the holder and each
    teammate +0.3 and each taker -0.3; values add, then clip to [-1, 1].

    ``image="authors"`` (the authors' code, ``HyperNEATKeepawayPlayer.cs`` 142-296): the holder's cell
    +1.0, each teammate's cell +0.5, each taker's cell -1.0, the path cells to a teammate
    ``+1/(1+d)`` and to a taker ``-1/(1+d)``, ``d`` the Euclidean distance in cells from the holder to
    that agent; values add and are not clipped (the source accumulates with ``+=``/``-=`` and sets the
    inputs as they are). The path cells are kx's digital line, as for ``"paper"``.

    The straight path between two cells is the digital line ``S + round(i * (A - S) / n)``, ``i = 1 ..
    n-1``, with ``n`` their Chebyshev distance and halves rounded up.
    """
    if image not in BEV_IMAGES:
        raise ValueError(f"image: allowed {BEV_IMAGES}, got {image!r}")
    authors = image == "authors"
    w = config.field_size
    bshape = state.holder.shape
    cells = jnp.arange(w * w, dtype=jnp.int32).reshape((w * w,) + (1,) * len(bshape))
    gx, gy = cells % w, cells // w
    h = _holder(state)
    sx, sy = pick(state.keeper_x, h), pick(state.keeper_y, h)
    img = jnp.zeros((w * w,) + bshape, jnp.float32)

    def on_path(ax, ay):
        dx, dy = ax - sx, ay - sy
        n = jnp.maximum(jnp.maximum(jnp.abs(dx), jnp.abs(dy)), 1)
        x_major = jnp.abs(dx) >= jnp.abs(dy)
        i = jnp.where(x_major, (gx - sx) * jnp.sign(dx), (gy - sy) * jnp.sign(dy))
        other = jnp.where(x_major, sy + jnp.floor_divide(2 * i * dy + n, 2 * n),
                          sx + jnp.floor_divide(2 * i * dx + n, 2 * n))
        hit = jnp.where(x_major, gy == other, gx == other)
        return hit & (i >= 1) & (i <= n - 1)

    def path_value(ax, ay, sign):
        if not authors:
            return BEV_PATH_KEEPER if sign > 0 else BEV_PATH_TAKER
        d = jnp.sqrt(((ax - sx) ** 2 + (ay - sy) ** 2).astype(jnp.float32))
        return sign / (1.0 + d)

    for i in range(config.n_keepers):
        ax, ay = state.keeper_x[i], state.keeper_y[i]
        v = jnp.where(h == i, BEV_AUTHORS_HOLDER, BEV_AUTHORS_TEAMMATE) if authors else BEV_KEEPER
        img = img + jnp.where((gx == ax) & (gy == ay), v, 0.0)
        img = img + jnp.where(on_path(ax, ay) & (h != i), path_value(ax, ay, 1.0), 0.0)
    for j in range(config.n_takers):
        ax, ay = state.taker_x[j], state.taker_y[j]
        img = img + jnp.where((gx == ax) & (gy == ay), BEV_AUTHORS_TAKER if authors else BEV_TAKER, 0.0)
        img = img + jnp.where(on_path(ax, ay), path_value(ax, ay, -1.0), 0.0)
    return img if authors else jnp.clip(img, -1.0, 1.0)


def decode_bev(outputs: jax.Array, state: State, config: KeepAwayConfig, literal: bool = False) -> jax.Array:
    """Substrate outputs ``[W*W, *B]`` to a keeper index.

    Default: compare the outputs at the holder's cell (hold) and at each teammate's cell; the largest
    wins, ties go to hold, then to the lower index. ``literal``: the paper's wording, the largest output
    anywhere on the layer, passing to the keeper nearest that cell (squared distance, holder first,
    then lower index), which holds if that keeper is the holder.
    """
    w = config.field_size
    h = _holder(state)
    kc = state.keeper_x + w * state.keeper_y  # [K, *B]
    if literal:
        best = jnp.argmax(outputs, axis=0).astype(jnp.int32)
        bx, by = best % w, best // w
        d2 = (state.keeper_x - bx) ** 2 + (state.keeper_y - by) ** 2
        d2 = jnp.where(col(config.n_keepers, h.ndim) == h, 2 * d2 - 1, 2 * d2)  # holder wins ties
        return jnp.argmin(d2, axis=0).astype(jnp.int32)
    return decide_on_cells(jnp.take_along_axis(outputs, kc, axis=0), h, config.n_keepers)


def decide_on_cells(vals: jax.Array, h: jax.Array, n_keepers: int) -> jax.Array:
    """The BEV decision on the values at the keepers' cells ``vals [K, *B]``, the holder ``h [*B]``: the
    holder's own value (hold) against each teammate's (pass to it); the largest wins, ties go to hold, then
    to the lower keeper index (:func:`decode_bev`, and HyperNEAT's sparse decision in kx.hyperneat.bev)."""
    best_v, best_i = pick(vals, h), h
    for i in range(n_keepers):
        better = (vals[i] > best_v) & (h != i)
        best_v, best_i = jnp.where(better, vals[i], best_v), jnp.where(better, i, best_i)
    return best_i.astype(jnp.int32)
