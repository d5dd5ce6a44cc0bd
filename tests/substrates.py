"""Random shared tables of substrates for the BEV policy's tests (no side effects on import, unlike conftest:
tests/test_native.py imports it in a process of its own under XLA's default flags)."""

import functools

import jax
import jax.numpy as jnp


@functools.partial(jax.jit, static_argnums=(1, 2))
def random_table(key, g, n):
    """``g`` random substrates ``{"w": [g, n, n], "b": [g, n]}``: weights in the SPEC's range [-5, 5], half of
    them 0 (links not expressed)."""
    kw, km, kb = jax.random.split(key, 3)
    w = jax.random.uniform(kw, (g, n, n), jnp.float32, -5.0, 5.0)
    w = jnp.where(jax.random.bernoulli(km, 0.5, (g, n, n)), w, 0.0)
    return {"w": w, "b": jax.random.uniform(kb, (g, n), jnp.float32, -5.0, 5.0)}
