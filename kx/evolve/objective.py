"""Objectives: what the learner selects on, kept apart from the task fitness that the run reports.

An objective turns a generation's raw task fitness ``[P]`` and behaviour ``[3, P]`` into the selection
score ``[P]`` handed to the learner's ``tell``, with a state of its own carried in the run state and
checkpointed with it (the novelty archive lives there). The run loop reports raw fitness only: the
champion, the best checkpoint, metrics.csv's fitness columns, the progress line and the plots never see
the score.

* ``fitness``: the score is the fitness and the state is empty.
* ``hybrid``: the novelty search hybrid of SPEC section 4 (:mod:`kx.novelty`), configured by the
  ``novelty`` config section: ``rho`` times the population-normalised fitness plus ``1 - rho`` times
  the normalised novelty (the mean distance to the ``k`` nearest behaviours among the rest of the
  population and the archive); the state is the archive (``archive_size`` behaviour vectors, those
  with novelty above ``threshold`` admitted, the oldest replaced once full). Its readings
  (docs/novelty.md): ``normalisation`` ("population" min-max, or "fixed" bounds) and ``archive_rule``
  ("paper", or "authors": the 10 most novel above the threshold a generation) and ``behaviour`` ("paper",
  or "authors": time held, dispersion and decisions).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from kx import novelty as nv
from kx.evolve.errors import ObjectiveError, is_int, is_number, need

OBJECTIVES = ("fitness", "hybrid")


def novelty_defaults() -> dict:
    """The ``novelty`` config section at its defaults (SPEC section 4; the readings: docs/novelty.md)."""
    return {"k": 15, "rho": 0.4, "archive_size": 1000, "threshold": 0.03, "normalisation": "population",
            "archive_rule": "paper", "behaviour": "paper"}


class Objective:
    """Selection on raw task fitness (the base of every objective)."""

    name = "fitness"
    #: metrics.csv columns the objective adds (keys of ``score``'s metrics)
    metric_fields: tuple[str, ...] = ()
    #: whether ``jax.vmap`` of ``score`` over runs computes, bit for bit, each run's score alone (a
    #: batched group, kx.evolve.group, scores run by run otherwise)
    vmap_exact: bool = True

    def init(self, population_size: int) -> Any:
        return {}

    def behaviour_of(self, stats) -> jax.Array | None:
        """The behaviour ``[3, *B]`` the objective scores, from a batch of :class:`~kx.sim.types.EpisodeStats`;
        ``None``: the world's own (``stats.behaviour``: passes, dispersion, ball distance from the centre)."""
        return None

    def score(self, fitness: jax.Array, behaviour: jax.Array, state: Any) -> tuple[jax.Array, Any, dict]:
        """``(score [P], next state, metrics)``."""
        del behaviour
        return jnp.asarray(fitness, jnp.float32), state, {}


Fitness = Objective

#: the behaviour vector the run loop hands ``score``: passes, dispersion, ball distance from centre (the
#: paper's), or the authors' reading (:data:`BEHAVIOURS`)
BEHAVIOUR_DIM = 3
#: the behaviour vector's readings (docs/novelty.md): "paper", the world's passes, keeper dispersion and
#: ball distance from the centre; "authors", their HyperNEAT code's: time held, keeper dispersion and
#: decisions (every decision of the holder counted as a pass), each a share of its bound
BEHAVIOURS = ("paper", "authors")


# One compiled program per shape (and ``k``, a static field of the params), shared by every run.
_novelty_step = jax.jit(nv.step)


class Hybrid(Objective):
    """Selection on ``rho`` x normalised fitness + ``(1 - rho)`` x normalised novelty (SPEC section 4);
    the state is the behaviour archive (:class:`kx.novelty.Archive`, ``archive_size`` x 3)."""

    name = "hybrid"
    metric_fields = ("mean_novelty", "champion_novelty", "archive_size", "archive_added", "score_std")
    # vmapped over 10 or 16 runs, the k-NN novelty rounds differently in the last bit from one run's
    # (measured at 10 x 50, 16 x 150 and 10 x 150; identical at 3 x 50 and 4 x 12)
    vmap_exact = False

    def __init__(self, k: int, rho: float, archive_size: int, threshold: float, normalisation: str = "population",
                 archive_rule: str = "paper", behaviour: str = "paper", max_iterations=4500):
        self.k, self.rho, self.archive_size, self.threshold = k, rho, archive_size, threshold
        self.normalisation, self.archive_rule, self.behaviour = normalisation, archive_rule, behaviour
        self.max_iterations = max_iterations
        self.params = nv.NoveltyParams(rho=float(rho), threshold=float(threshold), k=int(k),
                                       normalisation=normalisation, archive_rule=archive_rule)
        self._step = _novelty_step  # the module's: shared by every instance

    def init(self, population_size: int) -> nv.Archive:
        del population_size  # the archive's shape is the config's alone
        return nv.init_archive(self.archive_size, BEHAVIOUR_DIM)

    def behaviour_of(self, stats) -> jax.Array | None:
        """The authors' reading: ``[time held, dispersion, decisions]``, the first the fitness (iterations
        survived over ``max_iterations``), the second the world's, the third the holders' decisions over
        ``max_iterations`` (HyperNEATKeepawayPlayer.cs 336-354 counts every decision, hold included, as a
        pass); the paper's: ``None``, the world's own."""
        if self.behaviour == "paper":
            return None
        decisions = jnp.asarray(stats.decisions, jnp.float32) / jnp.float32(self.max_iterations)
        return jnp.stack([jnp.asarray(stats.fitness, jnp.float32), jnp.asarray(stats.behaviour[1], jnp.float32),
                          jnp.minimum(decisions, 1.0)])

    def score(self, fitness: jax.Array, behaviour: jax.Array,
              state: nv.Archive) -> tuple[jax.Array, nv.Archive, dict]:
        """``behaviour`` is the run loop's ``[3, P]``."""
        return self._step(jnp.asarray(fitness, jnp.float32), jnp.asarray(behaviour, jnp.float32).T, state,
                          self.params)


def _check_novelty(section) -> dict:
    fields = {f: section[f] if f in section else None for f in novelty_defaults()}
    checks = {
        "k": (lambda v: is_int(v) and 1 <= v <= 10_000, "an integer in [1, 10000]"),
        "rho": (lambda v: is_number(v) and 0 <= v <= 1, "a number in [0, 1]"),
        "archive_size": (lambda v: is_int(v) and 1 <= v <= 1_000_000, "an integer in [1, 1000000]"),
        "threshold": (lambda v: is_number(v) and v >= 0, "a finite number >= 0"),
        "normalisation": (lambda v: v in nv.NORMALISATIONS, f"one of {nv.NORMALISATIONS}"),
        "archive_rule": (lambda v: v in nv.ARCHIVE_RULES, f"one of {nv.ARCHIVE_RULES}"),
        "behaviour": (lambda v: v in BEHAVIOURS, f"one of {BEHAVIOURS}"),
    }
    for field, (ok, allowed) in checks.items():
        need(ok(fields[field]), f"novelty.{field}", allowed, fields[field], error=ObjectiveError)
    return fields


def make(cfg) -> Objective:
    """The objective of a run config (``cfg.objective``); the ``novelty`` section is checked whatever
    the objective (it is part of every config and of its identity)."""
    novelty = _check_novelty(cfg.novelty)
    if cfg.objective == "fitness":
        return Fitness()
    if cfg.objective == "hybrid":
        return Hybrid(**novelty, max_iterations=cfg.sim.get("max_iterations"))  # checked with the sim section
    raise ObjectiveError(f"objective: allowed one of {OBJECTIVES}, got {cfg.objective!r}")
