"""The source-to-target protocol of policy transfer (SPEC section 5; docs/transfer.md), as a library.

A *source* run of a method's shipped config trains in the source task (3v2) in a run directory; a
*target* run of the method's config for a larger task (4v3, 5v3, 6v4) starts either from the source's
final population (``transfer.source``, the default seeding, :mod:`kx.evolve.transfer`) or fresh, with
the same seed; the target's champion then plays held-out test states of the target task (the test
stream of a seed no run trains or validates on, :func:`kx.evolve.streams.test`), and both arms are
compared on the same start states, the same evaluation budget and the same stopping point.

``python -m kx.bench transfer`` runs it for one generation of each target arm
(:func:`first_generation`); a Table 3 driver can run the targets longer with the same pieces.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Callable

import ml_collections

from kx.evolve import config as cfg_lib
from kx.evolve import run as run_lib
from kx.evolve import streams
from kx.evolve.encoding import stack
from kx.sim import env

SOURCE_TASK = "3v2"
TARGET_TASKS = ("4v3", "5v3", "6v4")
#: the target arms: seeded with the source's population, or a fresh population
ARMS = ("transfer", "fresh")


def _config_file(method: str, task: str) -> pathlib.Path:
    """The shipped config of ``method`` for ``task`` (``configs/<method>_<task>.py``)."""
    return cfg_lib.CONFIG_DIR / f"{method}_{task}.py"


def source_config(method: str, seed: int, objective: str = "fitness",
                  task: str = SOURCE_TASK) -> ml_collections.ConfigDict:
    """The source run's config: the method's shipped config of ``task``, with ``objective`` and
    ``seed``, no GIF."""
    return cfg_lib.load(_config_file(method, task), ["gif=false", f"objective={objective}", f"seed={seed}"])


def target_config(method: str, task: str, seed: int, source: str | pathlib.Path | None = None,
                  objective: str = "fitness", generations: int = 1) -> ml_collections.ConfigDict:
    """A target run's config: the method's shipped config of ``task`` with ``objective``, ``seed`` and
    ``generations``, no GIF, seeded from the run directory ``source`` (``None``: a fresh population)."""
    over = ["gif=false", f"objective={objective}", f"seed={seed}", f"generations={generations}"]
    if source is not None:
        over.append(f"transfer.source={source}")
    return cfg_lib.load(_config_file(method, task), over)


def train_source(method: str, seed: int, run_dir: str | pathlib.Path, objective: str = "fitness",
                 log: Callable[[str], None] = lambda s: None) -> dict:
    """Trains the source run of ``method`` and ``seed`` in ``run_dir`` (:func:`kx.evolve.run.train`);
    returns its last metrics row."""
    return run_lib.train(source_config(method, seed, objective), run_dir, log=log)


def held_out_states(trainer: run_lib.Trainer, keys, trials: int):
    """``trials`` start states of the trainer's task from the test stream's ``keys``
    (:func:`kx.evolve.streams.test`)."""
    return env.reset_batch(keys.starts, trials, trainer.exp.sim_params, trainer.exp.sim)


def fitness_on(trainer: run_lib.Trainer, genotype, starts, key) -> float:
    """One genotype's mean fitness on ``starts`` (with the kick noise of ``key``)."""
    return float(trainer.evaluate(stack([genotype]), starts, key).fitness.mean())


@dataclasses.dataclass(frozen=True)
class FirstGeneration:
    """A target run's first generation."""

    test: float  # its champion (the fittest on the generation's training trials, the run's validated
    # champion after one generation) on the target's test states
    mean_fitness: float  # the population's mean training fitness in that generation


def first_generation(cfg: ml_collections.ConfigDict, keys, test_trials: int) -> FirstGeneration:
    """The first generation of the target run of ``cfg`` (no run directory), its champion played on
    ``test_trials`` test states of the target task from the test stream's ``keys``."""
    trainer = run_lib.Trainer(cfg)
    starts = held_out_states(trainer, keys, test_trials)
    result = trainer.step(trainer.init())
    return FirstGeneration(test=fitness_on(trainer, result.state.champion, starts, keys.eval),
                           mean_fitness=result.row["mean_fitness"])


def seeded_and_fresh(method: str, task: str, seed: int, source: str | pathlib.Path, keys, test_trials: int,
                     objective: str = "fitness") -> dict[str, FirstGeneration]:
    """Both target arms (:data:`ARMS`) of ``method`` in ``task`` with ``seed``: seeded from the source
    run directory ``source``, and fresh; each one's :func:`first_generation`."""
    return {arm: first_generation(target_config(method, task, seed, source if arm == "transfer" else None,
                                                objective), keys, test_trials)
            for arm in ARMS}


def champion_on_test(run_dir: str | pathlib.Path, test_seed: int,
                     test_trials: int) -> tuple[run_lib.Trainer, object, float]:
    """``(trainer, state, test fitness)`` of a finished run directory: its last checkpoint's validated
    champion on ``test_trials`` test states of the run's task from the test stream of ``test_seed``
    (the same states for every run given the same seed)."""
    trainer, _, state, _ = run_lib.restore(run_dir)
    keys = streams.test(test_seed)
    starts = held_out_states(trainer, keys, test_trials)
    return trainer, state, fitness_on(trainer, state.champion, starts, keys.eval)
