"""Novelty search on behaviour vectors: the archive, k-nearest-neighbour novelty and the hybrid score
of SPEC section 4. Generic: it knows behaviour vectors ``[P, D]``, not keep-away (the run loop's
objective, :class:`kx.evolve.objective.Hybrid`, hands it the soccer behaviour)."""

from kx.novelty.archive import Archive, init_archive, update_archive
from kx.novelty.score import NoveltyParams, hybrid, minmax, novelty, step

__all__ = ["Archive", "NoveltyParams", "hybrid", "init_archive", "minmax", "novelty", "step", "update_archive"]
