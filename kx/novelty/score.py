"""k-nearest-neighbour novelty and the hybrid score of fitness and novelty (SPEC section 4).

For a population of behaviour vectors ``[P, D]`` and an archive of earlier ones (:mod:`kx.novelty.archive`)::

    nov_i   = mean Euclidean distance from b_i to its k nearest neighbours among the other P - 1
              vectors of the population and the archive's filled entries
    score_i = rho * fit_i + (1 - rho) * nov_i      fit, nov min-max normalised over the population
                                                   (0 where max == min)

and every individual with novelty strictly above the threshold joins the archive (a ring of
``archive_size`` entries: the oldest is replaced once full). SPEC's defaults: k = 15, rho = 0.4,
archive 1000, threshold 0.03.

Where the authors' code differs (``HN/Sources/KeepAway``; kx follows SPEC):

* their distance is one-sided, d(x, y) = mean_i max(0, x_i - y_i), with the population term measured
  as d(other, self) and the archive term as d(self, archive) (Behavior.cs, ComputeNovelty.cs); kx
  uses the Euclidean distance, symmetric;
* their novelty adds the distance to *every* archive member, divided by k + |archive|, rather than
  taking the k nearest of population and archive together, and breaks ties by fitness (kx: the mean
  of the k smallest distances, which ties cannot change);
* their archive has no size cap and takes at most the 10 most novel genomes per generation (kx: every
  one above the threshold, into a ring of 1000; ``archive_rule="authors"`` reads theirs);
* their hybrid weight never reached the HyperNEAT arm (the config field ``scalariser`` against the XML
  element ``<Scalarizer>``), so its "hybrid" was pure novelty; and they weighted raw, not normalised,
  fitness and novelty. kx applies rho = 0.4 to the normalised values (``normalisation="fixed"``: divided by
  fixed bounds instead of the population's range).

Every function is pure and vectorised over the population; ``step`` is jitted by its caller
(:class:`kx.evolve.objective.Hybrid`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from kx.novelty.archive import Archive, update_archive, update_archive_authors

#: the readings of the hybrid (docs/novelty.md): how fitness and novelty are put on one scale, and
#: which individuals the archive admits
NORMALISATIONS = ("population", "fixed")
ARCHIVE_RULES = ("paper", "authors")


@struct.dataclass
class NoveltyParams:
    """The hybrid's settings: ``k`` and the readings are static (they choose code); ``rho`` and
    ``threshold`` are traced."""

    rho: jax.Array | float  # weight of normalised fitness in the score, in [0, 1]
    threshold: jax.Array | float  # admission to the archive: novelty strictly above it
    k: int = struct.field(pytree_node=False, default=15)  # nearest neighbours
    # "population": fitness and novelty min-max normalised over the generation's population (kx's reading
    # of the paper's "normalized"); "fixed": divided by fixed bounds, fitness by 1 (it is a share of the
    # longest episode already) and novelty by the behaviour space's diameter, sqrt(D) for D statistics
    # in [0, 1] (one genome far above the rest then leaves the others' differences as they are)
    normalisation: str = struct.field(pytree_node=False, default="population")
    # "paper": every individual with novelty above the threshold joins a ring of archive_size (SPEC section
    # 4); "authors": the 10 most novel above the threshold a generation (their HyperNEAT code)
    archive_rule: str = struct.field(pytree_node=False, default="paper")

    def __post_init__(self):
        if self.normalisation not in NORMALISATIONS:
            raise ValueError(f"normalisation: allowed {', '.join(NORMALISATIONS)}, got {self.normalisation!r}")
        if self.archive_rule not in ARCHIVE_RULES:
            raise ValueError(f"archive_rule: allowed {', '.join(ARCHIVE_RULES)}, got {self.archive_rule!r}")


def novelty(behaviour: jax.Array, archive: Archive, k: int) -> jax.Array:
    """``[P]`` the mean distance from each of ``behaviour`` ``[P, D]`` to its ``k`` nearest neighbours
    among the rest of the population (never itself) and the archive's filled entries; over all of
    them where fewer than ``k`` exist, 0 where none do."""
    b = behaviour.astype(jnp.float32)
    p, cap = b.shape[0], archive.capacity
    others = jnp.concatenate([b, archive.entries], axis=0)  # [P + A, D]
    # the differences themselves, not |x|^2 - 2xy + |y|^2: exact zeros and exact ties for equal vectors
    dist = jnp.sqrt(jnp.sum(jnp.square(b[:, None, :] - others[None, :, :]), axis=-1))  # [P, P + A]
    col = jnp.arange(p + cap)
    valid = jnp.where(col < p, col[None, :] != jnp.arange(p)[:, None], (col - p < archive.size)[None, :])
    kk = min(k, p + cap - 1)  # static: at most every other vector
    if kk <= 0:
        return jnp.zeros((p,), jnp.float32)
    # [P, kk] ascending; only the values are read, so however a backend orders equal distances, they are the same
    nearest = -jax.lax.top_k(-jnp.where(valid, dist, jnp.inf), kk)[0]
    n_valid = jnp.minimum(p - 1 + archive.size, kk)  # the same for every row
    used = jnp.arange(kk) < n_valid
    total = jnp.sum(jnp.where(used[None, :], nearest, 0.0), axis=1)
    return jnp.where(n_valid > 0, total / jnp.maximum(n_valid, 1).astype(jnp.float32), 0.0)


def minmax(x: jax.Array) -> jax.Array:
    """``x`` ``[P]`` scaled to [0, 1] over its own range; 0 everywhere where max == min."""
    lo, hi = jnp.min(x), jnp.max(x)
    spread = hi - lo
    return jnp.where(spread > 0, (x - lo) / jnp.where(spread > 0, spread, 1.0), 0.0)


def hybrid(fitness: jax.Array, novelty: jax.Array, rho: jax.Array | float, normalisation: str = "population",
           dim: int | None = None) -> jax.Array:
    """``[P]`` ``rho * fit + (1 - rho) * nov``: fitness and novelty min-max normalised over the population
    (``normalisation="population"``), or divided by fixed bounds (``"fixed"``: fitness, a share of the
    longest episode, by 1; novelty, a mean Euclidean distance between behaviours of ``dim`` statistics in
    [0, 1], by the space's diameter ``sqrt(dim)``)."""
    fitness, novelty = jnp.asarray(fitness, jnp.float32), jnp.asarray(novelty, jnp.float32)
    if normalisation == "population":
        fit, nov = minmax(fitness), minmax(novelty)
    elif normalisation == "fixed":
        if dim is None or dim < 1:
            raise ValueError(f"dim: the behaviour's dimension (>= 1) is needed for fixed bounds, got {dim!r}")
        fit, nov = fitness, novelty / jnp.sqrt(jnp.float32(dim))
    else:
        raise ValueError(f"normalisation: allowed {', '.join(NORMALISATIONS)}, got {normalisation!r}")
    return rho * fit + (1.0 - rho) * nov


def step(fitness: jax.Array, behaviour: jax.Array, archive: Archive,
         params: NoveltyParams) -> tuple[jax.Array, Archive, dict]:
    """One generation: ``(score [P], next archive, metrics)`` from raw fitness ``[P]`` and behaviour
    ``[P, D]``. Novelty is measured against the archive as it was before this generation; then the
    archive admits this generation's novel individuals.

    Metrics (scalars): ``mean_novelty``; ``champion_novelty``, the novelty of the fitness champion
    (argmax of raw fitness, the first of equals); ``archive_size`` after the update;
    ``archive_added``, individuals admitted this generation; ``score_std``, the score's spread.
    """
    fitness = jnp.asarray(fitness, jnp.float32)
    nov = novelty(behaviour, archive, params.k)
    if params.archive_rule == "authors":
        archive, n_added = update_archive_authors(archive, behaviour, nov, params.threshold, fitness)
    else:
        archive, n_added = update_archive(archive, behaviour, nov, params.threshold)
    score = hybrid(fitness, nov, params.rho, params.normalisation, behaviour.shape[-1])
    metrics = {"mean_novelty": jnp.mean(nov), "champion_novelty": nov[jnp.argmax(fitness)],
               "archive_size": archive.size, "archive_added": n_added, "score_std": jnp.std(score)}
    return score, archive, metrics
