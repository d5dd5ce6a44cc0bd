"""The holder's view as entity tokens: one for the holder, one per teammate, one per taker, for any team size.

A size-invariant policy (:class:`kx.evolve.encodings.ppo.algorithm.EntityActorCritic`) reads a set of tokens instead
of a fixed vector, as
the multi-agent literature's entity encoders do (pooling over entities, DeepSets; self-attention over entity
tokens, UPDeT and TransfQMix). Every feature is one a keeper can see from the holder's place, on the scales of
the fixed layout (:mod:`kx.sim.observe`: distances over the field's diagonal, angles over pi):

* the holder: its distance to the centre, its position relative to the centre (x and y over the diagonal), its
  distance to the nearest taker;
* a teammate: its position relative to the holder (x and y over the diagonal), its distance to the holder and to
  the centre, its distance to its nearest taker, and how open the pass lane to it is (the smallest angle at the
  holder between it and a taker, :func:`kx.sim.observe.fixed_obs`'s ``min ang``);
* a taker: its position relative to the holder, its distance to the holder and to the centre.

Teammates come in keeper order with the holder left out (slot ``r`` is keeper ``r``, or ``r + 1`` from the
holder's index on: :func:`mate_keepers`), takers in taker order: no sorting, so that a policy's invariance to the
order is its own. An action is ``0`` (hold) or ``1 + r`` (pass to teammate slot ``r``). Batch-last and
rank-polymorphic, as the simulator.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from kx.sim.ops import col, pick
from kx.sim.types import KeepAwayConfig, State

HOLDER_FEATURES = ("dist(K1,C)", "x(K1)-x(C)", "y(K1)-y(C)", "min dist(K1,T)")
MATE_FEATURES = ("x(K)-x(K1)", "y(K)-y(K1)", "dist(K1,K)", "dist(K,C)", "min dist(K,T)", "min ang(K,K1,T)")
TAKER_FEATURES = ("x(T)-x(K1)", "y(T)-y(K1)", "dist(K1,T)", "dist(T,C)")


def n_actions(config: KeepAwayConfig) -> int:
    """Hold, and a pass to each teammate."""
    return config.n_keepers


def mate_keepers(state: State, config: KeepAwayConfig) -> jax.Array:
    """``[K - 1, *B]``: the keeper index of each teammate slot (the keepers other than the holder, in order)."""
    h = jnp.maximum(state.holder, 0)
    r = col(config.n_keepers - 1, h.ndim)
    return jnp.where(r < h, r, r + 1).astype(jnp.int32)


def keeper_of(action: jax.Array, state: State, config: KeepAwayConfig) -> jax.Array:
    """The keeper an action sends the ball to: the holder's own index for ``0`` (hold), teammate slot ``a - 1``'s
    keeper otherwise (actions past the last teammate are clipped to it)."""
    h = jnp.maximum(state.holder, 0)
    a = jnp.clip(action, 0, config.n_keepers - 1).astype(jnp.int32)
    return jnp.where(a == 0, h, pick(mate_keepers(state, config), jnp.maximum(a - 1, 0)))


def tokens(state: State, config: KeepAwayConfig) -> dict[str, jax.Array]:
    """The holder's view: ``holder [4, *B]``, ``mates [K - 1, 6, *B]``, ``takers [T, 4, *B]`` (features as named
    by :data:`HOLDER_FEATURES`, :data:`MATE_FEATURES`, :data:`TAKER_FEATURES`), float32."""
    w = config.field_size
    diag = (w - 1) * math.sqrt(2.0)
    c = (w - 1) / 2.0
    f32 = lambda a: a.astype(jnp.float32)  # noqa: E731
    h = jnp.maximum(state.holder, 0)
    hx, hy = f32(pick(state.keeper_x, h)), f32(pick(state.keeper_y, h))
    slots = mate_keepers(state, config)
    mx = jnp.stack([f32(pick(state.keeper_x, slots[r])) for r in range(config.n_keepers - 1)])
    my = jnp.stack([f32(pick(state.keeper_y, slots[r])) for r in range(config.n_keepers - 1)])
    tx, ty = f32(state.taker_x), f32(state.taker_y)

    def dist(ax, ay, bx, by):
        return jnp.sqrt((ax - bx) ** 2 + (ay - by) ** 2) / diag

    # every teammate against every taker: [K - 1, T, *B]
    mt = dist(mx[:, None], my[:, None], tx[None], ty[None])
    ux, uy = (mx - hx)[:, None], (my - hy)[:, None]
    vx, vy = (tx - hx)[None], (ty - hy)[None]
    lane = jnp.arctan2(jnp.abs(ux * vy - uy * vx), ux * vx + uy * vy) / math.pi
    holder = jnp.stack([dist(hx, hy, c, c), (hx - c) / diag, (hy - c) / diag, dist(hx, hy, tx, ty).min(axis=0)])
    mates = jnp.stack([(mx - hx) / diag, (my - hy) / diag, dist(mx, my, hx, hy), dist(mx, my, c, c),
                       mt.min(axis=1), lane.min(axis=1)], axis=1)
    takers = jnp.stack([(tx - hx) / diag, (ty - hy) / diag, dist(tx, ty, hx, hy), dist(tx, ty, c, c)], axis=1)
    return {"holder": holder, "mates": mates, "takers": takers}


def batch_first(obs: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """:func:`tokens` of one batch axis, batch first: ``holder [B, 4]``, ``mates [B, K - 1, 6]``, ``takers [B, T,
    4]`` (what :class:`kx.evolve.encodings.ppo.algorithm.EntityActorCritic` reads)."""
    return {"holder": jnp.moveaxis(obs["holder"], -1, 0), "mates": jnp.moveaxis(obs["mates"], -1, 0),
            "takers": jnp.moveaxis(obs["takers"], -1, 0)}
