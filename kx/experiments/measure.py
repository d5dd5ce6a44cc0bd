"""Training runs and measuring their champions on held-out test states: the one loop that
:mod:`kx.experiments.table3` and :mod:`kx.experiments.sweep` share (:func:`train_and_measure`), and a target
run's first generation, which ``python -m kx.bench transfer`` measures (:func:`first_generation`).

A run's *test states* are start states of its task from the test stream of a seed (:func:`kx.evolve.streams.test`)
that no run trains or validates on: every run measured with the same test seed and number of trials plays the
same states (of its own task). The runs' configs are the callers' (Table 3's: :func:`kx.experiments.table3.config`).
"""

from __future__ import annotations

import csv
import dataclasses
import pathlib
import time
from typing import Callable, Iterator

import ml_collections

from kx.evolve import checkpoint, streams
from kx.evolve import group as group_lib
from kx.evolve import run as run_lib
from kx.evolve.encoding import stack
from kx.experiments import processes
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


def started(run_dir: pathlib.Path) -> bool:
    """Whether ``run_dir`` holds a run that trains on from its checkpoint (its config.json is written)."""
    return (pathlib.Path(run_dir) / "config.json").is_file()


def finished(run_dir: pathlib.Path, generations: int) -> bool:
    """Whether ``run_dir`` holds a finished run of ``generations`` generations: its config.json and the
    checkpoint written after its last generation."""
    return started(run_dir) and generations in checkpoint.steps(pathlib.Path(run_dir))


def _seconds_before(run_dir: pathlib.Path) -> float:
    """The time a run directory's generations that its last checkpoint holds took (metrics.csv's
    ``generation_seconds``, the time of the group the run trained in): what a resumption does not train again."""
    done = max(checkpoint.steps(run_dir), default=0)
    path = run_dir / "metrics.csv"
    if not done or not path.is_file():
        return 0.0
    with path.open() as f:
        return sum(float(r["generation_seconds"]) for r in csv.DictReader(f) if int(r["generation"]) < done)


@dataclasses.dataclass(frozen=True)
class Finished:
    """A finished run, measured."""

    run_dir: pathlib.Path
    trainer: run_lib.Trainer  # of the run's own config (its config.json)
    state: object  # its last checkpoint's run state
    test: float  # its validated champion's mean fitness on the test states
    metrics: list[dict]  # its metrics.csv rows (strings), one per generation
    wall: float  # seconds the run took on the machine with its group: the group's time from the start of
    # this training to its end, plus, for a run resumed from a checkpoint, its generations before the resumption
    share: int  # the run is charged 1/share of its group's time: the group's size, times the local processes
    # sharing the machine's cores (kx.experiments.processes.machine_sharers), so that it is the run's share of the
    # machine

    @property
    def max_fitness(self) -> float:
        """The paper's measure: the maximum over the run of the generation's best training fitness."""
        return max(float(r["best_fitness"]) for r in self.metrics)

    @property
    def wall_seconds(self) -> float:
        """Its share of its group's wall time on the machine, in seconds (3 decimals)."""
        return round(self.wall / self.share, 3)


def train_and_measure(cfgs: list[ml_collections.ConfigDict], dirs: list[pathlib.Path], test_seed: int,
                      test_trials: int, log: Callable[[str], None] = print) -> Iterator[Finished]:
    """Trains the runs of ``cfgs`` in their run directories ``dirs``, each resumed from its checkpoint when its
    directory holds one (:func:`started`): one run by :func:`kx.evolve.run.train`, more as one batched group
    (:func:`kx.evolve.group.train_group`; the same results, bit for bit); ``log`` receives their progress
    lines. Then yields each run, in order, measured (:class:`Finished`): its validated champion on
    ``test_trials`` test states of its task from the test stream of ``test_seed``
    (:func:`champion_on_test`), its metrics.csv and its share of the wall time. A run resumed from a
    checkpoint is charged its generations before the resumption too (metrics.csv's ``generation_seconds`` of
    the generations its checkpoint holds): its wall time is then the training it took, not this call's part.
    What a killed call spent past its last checkpoint, and between generations, is not counted."""
    resume = [started(d) for d in dirs]
    before = [_seconds_before(pathlib.Path(d)) if r else 0.0 for d, r in zip(dirs, resume)]
    t0 = time.perf_counter()
    if len(cfgs) == 1:
        run_lib.train(cfgs[0], dirs[0], resume=resume[0], log=log)
    else:
        group_lib.train_group(cfgs, dirs, resume=resume, log=log)
    wall = time.perf_counter() - t0
    share = len(dirs) * processes.machine_sharers()
    for d, b in zip(dirs, before):
        trainer, state, test = champion_on_test(d, test_seed, test_trials)
        with (pathlib.Path(d) / "metrics.csv").open() as f:
            metrics = list(csv.DictReader(f))
        yield Finished(pathlib.Path(d), trainer, state, test, metrics, wall + b, share)


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
