"""Measuring runs' champions on held-out test states: a finished run's validated champion
(:func:`champion_on_test`), which :mod:`kx.experiments.table3` and :mod:`kx.experiments.sweep` measure, and a
target run's first generation, which ``python -m kx.bench transfer`` measures (:func:`first_generation`).

A run's *test states* are start states of its task from the test stream of a seed (:func:`kx.evolve.streams.test`)
that no run trains or validates on: every run measured with the same test seed and number of trials plays the
same states (of its own task). The runs' configs are the callers' (Table 3's: :func:`kx.experiments.table3.config`).
"""

from __future__ import annotations

import dataclasses
import pathlib

import ml_collections

from kx.evolve import run as run_lib
from kx.evolve import streams
from kx.evolve.encoding import stack
from kx.sim import env


def held_out_states(trainer: run_lib.Trainer, keys, trials: int):
    """``trials`` start states of the trainer's task from the test stream's ``keys``
    (:func:`kx.evolve.streams.test`)."""
    return env.reset_batch(keys.starts, trials, trainer.exp.sim_params, trainer.exp.sim)


def fitness_on(trainer: run_lib.Trainer, genotype, starts, key) -> float:
    """One genotype's mean fitness on ``starts`` (with the kick noise of ``key``)."""
    return float(trainer.evaluate(stack([genotype]), starts, key).fitness.mean())


def champion_on_test(run_dir: str | pathlib.Path, test_seed: int,
                     test_trials: int) -> tuple[run_lib.Trainer, object, float]:
    """``(trainer, state, test fitness)`` of a finished run directory: its last checkpoint's validated
    champion on ``test_trials`` test states of the run's task from the test stream of ``test_seed``
    (the same states for every run given the same seed)."""
    trainer, _, state, _ = run_lib.restore(run_dir)
    keys = streams.test(test_seed)
    starts = held_out_states(trainer, keys, test_trials)
    return trainer, state, fitness_on(trainer, state.champion, starts, keys.eval)


@dataclasses.dataclass(frozen=True)
class FirstGeneration:
    """A target run's first generation."""

    test: float  # its champion (the fittest on the generation's training trials, the run's validated
    # champion after one generation) on the target's test states
    mean_fitness: float  # the population's mean training fitness in that generation


def first_generation(cfg: ml_collections.ConfigDict, keys, test_trials: int) -> FirstGeneration:
    """The first generation of the run of ``cfg`` (no run directory; a transferred run's source is read),
    its champion played on ``test_trials`` test states of the run's task from the test stream's ``keys``."""
    trainer = run_lib.Trainer(cfg)
    starts = held_out_states(trainer, keys, test_trials)
    result = trainer.step(trainer.init())
    return FirstGeneration(test=fitness_on(trainer, result.state.champion, starts, keys.eval),
                           mean_fitness=result.row["mean_fitness"])
