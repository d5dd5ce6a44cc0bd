"""Objectives: what the learner selects on, kept apart from the task fitness that the run reports.

An objective turns a generation's raw task fitness ``[P]`` and behaviour ``[3, P]`` into the selection
score ``[P]`` handed to the learner's ``tell``, with a state of its own carried in the run state and
checkpointed with it (the novelty archive lives there). The run loop reports raw fitness only: the
champion, the best checkpoint, metrics.csv's fitness columns, the progress line and the plots never see
the score.

* ``fitness``: the score is the fitness and the state is empty.
* ``hybrid``: the novelty search hybrid of SPEC section 4 (:mod:`kx.novelty`), configured by the
  ``novelty`` config section.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

OBJECTIVES = ("fitness", "hybrid")


class ObjectiveError(ValueError):
    """A config field of an objective out of range (the message names the field)."""


def novelty_defaults() -> dict:
    """The ``novelty`` config section at its defaults (SPEC section 4)."""
    return {"k": 15, "rho": 0.4, "archive_size": 1000, "threshold": 0.03}


class Objective:
    """Selection on raw task fitness (the base of every objective)."""

    name = "fitness"
    #: metrics.csv columns the objective adds (keys of ``score``'s metrics)
    metric_fields: tuple[str, ...] = ()

    def init(self, population_size: int) -> Any:
        return {}

    def score(self, fitness: jax.Array, behaviour: jax.Array, state: Any) -> tuple[jax.Array, Any, dict]:
        """``(score [P], next state, metrics)``."""
        del behaviour
        return jnp.asarray(fitness, jnp.float32), state, {}


Fitness = Objective


def make(cfg) -> Objective:
    """The objective of a run config (``cfg.objective``, its ``novelty`` section checked)."""
    if cfg.objective == "fitness":
        return Fitness()
    raise ObjectiveError(f"objective: allowed one of {OBJECTIVES}, got {cfg.objective!r}")
