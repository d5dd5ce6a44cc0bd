"""Novelty search on behaviour vectors: the archive, k-nearest-neighbour novelty and the hybrid score
of SPEC section 4. Generic: it knows behaviour vectors ``[P, D]``, not keep-away (the run loop's
objective, :class:`kx.evolve.objective.Hybrid`, hands it the soccer behaviour)."""

from kx.novelty.archive import AUTHORS_PER_GENERATION, Archive, init_archive, update_archive, update_archive_authors
from kx.novelty.score import ARCHIVE_RULES, NORMALISATIONS, NoveltyParams, hybrid, minmax, novelty, step

__all__ = ["ARCHIVE_RULES", "AUTHORS_PER_GENERATION", "Archive", "NORMALISATIONS", "NoveltyParams", "hybrid",
           "init_archive", "minmax", "novelty", "step", "update_archive", "update_archive_authors"]
