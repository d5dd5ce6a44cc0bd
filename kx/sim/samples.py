"""Batches of states that exercise the policies' corner cases: for tests and for checks of bit-identity
across a change of code (``scripts/bev_identity.py`` at b84bd55), which must feed both sides the same states."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from kx.sim import env
from kx.sim.types import KeepAwayConfig, KeepAwayParams, State


def varied_states(key: jax.Array, config: KeepAwayConfig, n: int) -> State:
    """``6 n`` states, batch-last: ``n`` fresh resets, the same stepped 1 and 6 iterations with random
    actions, and ``2 n`` adversarial states (every agent inside a 3 x 3 or a 5 x 5 square, so that agents
    stack and sit on each other's paths; in every fourth nobody holds the ball). Integer arithmetic only:
    jitted or not, the same states."""
    params, w = KeepAwayParams(), config.field_size
    k_reset, k_step, k_adv = jax.random.split(key, 3)
    fresh = env.reset_batch(k_reset, n, params, config)

    def one(s, k):
        ka, kn = jax.random.split(k)
        s = env.step(kn, s, jax.random.randint(ka, (n,), 0, config.n_keepers), params, config)
        return s, s

    _, stepped = jax.lax.scan(one, fresh, jax.random.split(k_step, 6))  # leaves [6, ..., n]
    stepped = [jax.tree.map(lambda a: a[i], stepped) for i in (0, 5)]
    adv = []
    for i, size in enumerate((3, 5)):
        kk = jax.random.split(jax.random.fold_in(k_adv, i), 5)
        lo = jax.random.randint(kk[0], (n,), 0, w - size + 1)
        r = lambda k, m: lo + jax.random.randint(k, (m, n), 0, size)  # noqa: E731
        holder = jnp.where(jnp.arange(n) % 4 == 0, -1, jax.random.randint(kk[4], (n,), 0, config.n_keepers))
        adv.append(fresh.replace(keeper_x=r(kk[0], config.n_keepers), keeper_y=r(kk[1], config.n_keepers),
                                 taker_x=r(kk[2], config.n_takers), taker_y=r(kk[3], config.n_takers),
                                 holder=holder))
    return jax.tree.map(lambda *a: jnp.concatenate(a, axis=-1), fresh, *stepped, *adv)
