"""Objectives: what the learner selects on, kept apart from the task fitness that the run reports.

An objective turns a generation's raw task fitness ``[P]`` and behaviour ``[3, P]`` into the selection
score ``[P]`` handed to the learner's ``tell``, with a state of its own carried in the run state and
checkpointed with it (the novelty archive will live there). The run loop reports raw fitness only:
the champion, the best checkpoint, metrics.csv, the progress line and the plots never see the score.

``fitness`` is the only objective for now: the score is the fitness and the state is empty.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

OBJECTIVES = ("fitness",)


class Fitness:
    """Selection on raw task fitness."""

    name = "fitness"

    def init(self, population_size: int) -> Any:
        return {}

    def score(self, fitness: jax.Array, behaviour: jax.Array, state: Any) -> tuple[jax.Array, Any, dict]:
        """``(score [P], next state, metrics)``."""
        del behaviour
        return jnp.asarray(fitness, jnp.float32), state, {}


def make(name: str):
    return {"fitness": Fitness}[name]()
