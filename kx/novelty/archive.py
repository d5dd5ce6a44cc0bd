"""The behaviour archive: a fixed-capacity ring of behaviour vectors (SPEC section 4).

The archive is a pytree of fixed-shape arrays whose shapes depend only on its capacity and the
behaviour dimension, so it can live in a run state that orbax checkpoints whole and that a jitted
generation step carries from one generation to the next without recompiling.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Archive:
    """Behaviour vectors admitted in earlier generations, oldest replaced first once full."""

    entries: jax.Array  # [A, D] float32; rows at and past ``size`` (before the ring first wraps) are unused
    size: jax.Array  # int32 filled entries, <= A
    head: jax.Array  # int32 the next ring slot written (once full: the oldest entry)
    added: jax.Array  # int32 admissions over the whole run (those overwritten in the same generation included)

    @property
    def capacity(self) -> int:
        return self.entries.shape[0]

    @property
    def dim(self) -> int:
        return self.entries.shape[1]


def init_archive(capacity: int, dim: int) -> Archive:
    """An empty archive of ``capacity`` behaviour vectors of ``dim`` numbers each."""
    if capacity < 1 or dim < 1:
        raise ValueError(f"init_archive: capacity and dim must be >= 1, got {capacity} and {dim}")
    zero = jnp.asarray(0, jnp.int32)
    return Archive(entries=jnp.zeros((capacity, dim), jnp.float32), size=zero, head=zero, added=zero)


def update_archive(archive: Archive, behaviour: jax.Array, novelty: jax.Array,
                   threshold: jax.Array | float) -> tuple[Archive, jax.Array]:
    """``(archive, n_admitted)``: every individual whose novelty is strictly above ``threshold``
    written into the ring in population order, as if one at a time.

    ``behaviour`` is ``[P, D]``, ``novelty`` ``[P]``. The ``r``-th admitted individual goes to slot
    ``(head + r) % A``; when more than ``A`` are admitted in one generation the earlier ones would be
    overwritten by the later within the same generation, so only the last ``A`` are written (one
    scatter, never two writes to a slot). ``n_admitted`` counts every admitted individual.
    """
    cap = archive.capacity
    admit = novelty > threshold  # [P]
    n = jnp.sum(admit, dtype=jnp.int32)
    rank = jnp.cumsum(admit, dtype=jnp.int32) - 1  # [P] order among the admitted
    write = admit & (rank >= n - cap)
    slot = jnp.where(write, (archive.head + rank) % cap, cap)  # cap: out of bounds, dropped
    entries = archive.entries.at[slot].set(behaviour.astype(jnp.float32), mode="drop")
    archive = archive.replace(entries=entries, size=jnp.minimum(archive.size + n, cap).astype(jnp.int32),
                              head=((archive.head + n) % cap).astype(jnp.int32), added=archive.added + n)
    return archive, n


#: admissions per generation under the authors' archive rule (ComputeNovelty.cs 103-112)
AUTHORS_PER_GENERATION = 10


def update_archive_authors(archive: Archive, behaviour: jax.Array, novelty: jax.Array, threshold: jax.Array | float,
                           fitness: jax.Array) -> tuple[Archive, jax.Array]:
    """The authors' HyperNEAT rule: ``(archive, n_admitted)`` with at most :data:`AUTHORS_PER_GENERATION`
    individuals a generation, the most novel of those strictly above ``threshold`` (equal novelty: the
    fitter first, then the earlier in the population), written into the ring most novel first. Their
    archive has no cap; here the ring's capacity bounds it (1000 by default: 10 a generation fill it only
    after 100 generations)."""
    p = novelty.shape[0]
    m = min(AUTHORS_PER_GENERATION, p)
    # the order: novelty descending, then fitness descending, then population index ascending
    order = jnp.lexsort((jnp.arange(p), -jnp.asarray(fitness, jnp.float32), -novelty))
    top = order[:m]
    admit = novelty[top] > threshold  # [m]; sorted, so the admitted come first
    n = jnp.sum(admit, dtype=jnp.int32)
    cap = archive.capacity
    rank = jnp.arange(m, dtype=jnp.int32)
    write = admit & (rank >= n - cap)
    slot = jnp.where(write, (archive.head + rank) % cap, cap)  # cap: out of bounds, dropped
    entries = archive.entries.at[slot].set(behaviour[top].astype(jnp.float32), mode="drop")
    archive = archive.replace(entries=entries, size=jnp.minimum(archive.size + n, cap).astype(jnp.int32),
                              head=((archive.head + n) % cap).astype(jnp.int32), added=archive.added + n)
    return archive, n
