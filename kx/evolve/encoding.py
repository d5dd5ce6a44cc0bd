"""The interface between the run loop and a method: an *encoding* turns a population into keep-away policies.

The run loop (:mod:`kx.evolve.run`), ``kx.evaluate`` and the benchmarks know only this interface; each
method is one class that implements it, registered under the config's ``method`` name
(:mod:`kx.evolve.registry`; the built-in ones live in :mod:`kx.evolve.encodings`)::

    class MyEncoding(Encoding):
        name = "mine"                      # cfg.method
        section = "mine"                   # the config section it owns: cfg.mine.*
        layouts = ("fixed", "full")        # the observation layouts it can play

        @classmethod
        def default_config(cls): ...       # its section's fields and defaults (a ConfigDict)
        def __init__(self, cfg, sim, sim_params): ...   # validate the section (ConfigError naming the field)
        def init(self, key): ...           # the learner's first state (a pytree)
        def ask(self, key, state): ...     # the population to evaluate (a pytree, leading axis P)
        def tell(self, key, population, score, fitness, state): ...   # -> (state, {field: scalar})
        def policy_for(self, sim): ...     # the kx.sim Policy its genotypes play in task ``sim``
        # optional: policy_params (the evaluator's params for that policy; default the population itself),
        # and transfer_problems and transfer, to seed a run from another run's checkpoint

    kx.evolve.registry.register(MyEncoding)

``tell`` receives two arrays ``[P]``: ``score``, what the learner selects on (the objective's
selection score, :mod:`kx.evolve.objective`), and ``fitness``, the raw task fitness. Everything the
run reports comes from ``fitness`` (the champion, the best checkpoint, metrics.csv, the progress line
and the plots); the learner may use ``fitness`` only for its own bookkeeping of the best genome.

A *genotype* is one individual of a population (``individual(population, i)``, by default the ``i``-th
slice of every leaf); the run's validated champion is a genotype, checkpointed in the run state, and
``policy_params(stack([genotype]))`` plays it. A policy whose ``shared`` flag is set gets the
population's parameters as one table that every episode lane shares (each lane carries its index only;
:mod:`kx.sim.evaluate`), so that large per-genome parameters are never copied per lane and new values
each generation never recompile the evaluator.
"""

from __future__ import annotations

import abc
import pathlib
from typing import Any, ClassVar

import jax
import ml_collections
import numpy as np

from kx.sim.policies import Policy
from kx.sim.types import KeepAwayConfig, KeepAwayParams


def stack(genotypes: list) -> Any:
    """A population of the given genotypes (a leading axis on every leaf)."""
    return jax.tree.map(lambda *a: jax.numpy.stack(a), *genotypes)


class Encoding(abc.ABC):
    """One method's population and policies (see the module docstring)."""

    name: ClassVar[str]
    section: ClassVar[str]
    layouts: ClassVar[tuple[str, ...]] = ("fixed", "full")
    #: the population sizes it takes (``population_size``), smallest and largest
    population_sizes: ClassVar[tuple[int, int]] = (2, 100_000)
    #: metrics.csv columns the encoding adds (keys of ``tell``'s metrics), after the run loop's own
    metric_fields: ClassVar[tuple[str, ...]] = ()
    #: the metric drawn in progress.png's lower panel (None: no panel)
    plot_field: ClassVar[str | None] = None
    #: which of ``ask``, ``tell`` and ``policy_params`` ``jax.vmap`` over runs computes bit for bit as each
    #: run alone (measured, at the sizes of the shipped configs and groups of up to 16); a batched group
    #: (kx.evolve.group) calls the others run by run
    vmap_exact: ClassVar[frozenset] = frozenset({"ask", "tell", "policy_params"})
    #: ``policy_params`` takes genotypes with any leading axes (a group's ``[R, P]``) itself, one call for
    #: all runs, rather than being mapped over runs (NEAT: it reads its genomes' hidden-node counts on the
    #: host to choose the networks' shape, which a vmap cannot)
    policy_params_leading_axes: ClassVar[bool] = False

    def policy_shape(self, population) -> np.ndarray | None:
        """For an encoding with :attr:`policy_params_leading_axes`: a key per run of ``population`` (``[R,
        P, ...]``, host ints) of the shape its own ``policy_params`` would take (NEAT: its hidden rows), so
        that a group plays each run in its own shape; ``None``: one shape for every run."""
        return None

    def __init__(self, cfg: ml_collections.ConfigDict, sim: KeepAwayConfig, sim_params: KeepAwayParams):
        self.cfg, self.sim, self.sim_params = cfg, sim, sim_params
        self.layout = cfg.layout
        self.population_size = cfg.population_size

    @classmethod
    @abc.abstractmethod
    def default_config(cls) -> ml_collections.ConfigDict:
        """The fields of the encoding's config section, at their defaults."""

    @classmethod
    def defaults(cls) -> dict:
        """Run-loop fields this method sets by default (e.g. ``{"population_size": 50}``)."""
        return {}

    @abc.abstractmethod
    def init(self, key: jax.Array) -> Any:
        """The learner's first state (a pytree of arrays, checkpointed whole)."""

    @abc.abstractmethod
    def ask(self, key: jax.Array, state: Any) -> Any:
        """The population to evaluate: a pytree whose leaves have a leading axis ``population_size``."""

    @abc.abstractmethod
    def tell(self, key: jax.Array, population: Any, score: jax.Array, fitness: jax.Array,
             state: Any) -> tuple[Any, dict]:
        """Breed from ``population`` selected by ``score [P]``; returns the next state and metrics (at
        least the keys of :attr:`metric_fields`, host-convertible scalars)."""

    @abc.abstractmethod
    def policy_for(self, sim: KeepAwayConfig) -> Policy:
        """The policy this encoding's genotypes play in task ``sim`` (raise ``ConfigError`` when they
        cannot: e.g. a full-layout network has as many inputs as its own task needs)."""

    def policy_params(self, population: Any) -> Any:
        """The evaluator's parameters of ``population``'s policies (leading axis P; a shared table when
        the policy is ``shared``): by default the population itself (a learner whose genotypes are the
        policy's parameters, as CMA-ES's and PPO's are)."""
        return population

    @property
    def policy(self) -> Policy:
        """The policy of the encoding's own task."""
        if not hasattr(self, "_policy"):
            self._policy = self.policy_for(self.sim)
        return self._policy

    @classmethod
    def episodes_per_generation(cls, cfg: ml_collections.ConfigDict) -> int:
        """The episodes a generation of a run of ``cfg`` learns from (its budget): by default the
        population's ``population_size x trials`` evaluations."""
        return cfg.population_size * cfg.trials

    def placeholder(self, key: jax.Array, learner: Any) -> Any:
        """A genotype of the shape of this encoding's champions: the run state's champion before the first
        generation has one (by default the first of the population ``ask`` gives)."""
        population, _ = self.ask(key, learner)
        return self.individual(population, 0)

    def individual(self, population: Any, i) -> Any:
        """Genotype ``i`` of ``population``."""
        return jax.tree.map(lambda a: a[i], population)

    def check(self, state: Any, champion: Any | None) -> list[str]:
        """Problems of a restored learner state and champion (a damaged checkpoint, or one written by a
        kx whose layout differed); empty when sound."""
        return []

    def transfer_problems(self, source: "Encoding", state: Any, seeding: str) -> list[str]:
        """Why ``state`` (a :class:`~kx.evolve.checkpoint.RunState` of a run of ``source``, an encoding of
        this method) cannot seed this run with ``seeding`` (:mod:`kx.evolve.transfer`); empty when it can.
        A problem about the seeding itself starts with ``"seeding"``."""
        return [f"method {self.name!r} does not transfer populations"]

    def transfer(self, key: jax.Array, source: "Encoding", state: Any, seeding: str, order) -> Any:
        """This run's first learner state seeded from ``state`` (checked by :meth:`transfer_problems`);
        ``order``: the source population's indices, fittest first (the ``half`` seeding only)."""
        raise NotImplementedError(f"method {self.name!r} does not transfer populations")

    def describe(self) -> str:
        """One line for the run's log: the method and the shape of its policies."""
        return self.name

    def implementation(self) -> dict:
        """Which code runs the encoding's policies in this process where it has a choice (recorded in the run
        directory's runtime.json, printed at the run's start); ``{}`` where it has none."""
        return {}

    def progress(self, metrics: dict) -> str:
        """The encoding's part of the progress line."""
        return ""

    def draw(self, genotype: Any, path: pathlib.Path) -> pathlib.Path | None:
        """A picture of one genotype (the run's champion) as a PNG; ``None`` if the encoding has none."""
        return None
