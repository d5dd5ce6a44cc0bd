"""NEAT as an encoding of the run loop: ``method = "neat"``, its ``neat.*`` config section and its networks.

Genomes of :mod:`kx.neat` play keep-away through :func:`kx.evolve.policy.neat_policy` on the ``fixed``
layout (13 inputs, 3 outputs, any team size) or the ``full`` one (4K + 2T - 3 inputs, K outputs; only the
team size it was evolved for). The population's networks are built once per generation and handed to
the evaluator per lane (they are small: a few hundred numbers per genome).

The config section ``neat`` holds every :class:`~kx.neat.types.NEATParams` field (the rates of Table 2
in the reading chosen by :func:`default_config`, see :mod:`kx.neat.presets`), the activations, and the
genome capacity: ``max_hidden`` hidden nodes, ``extra_conns`` connection columns and ``extra_genes``
genes per genome beyond the initial fully connected ones, ``species_capacity`` species slots and
``max_add_links`` (add-link mutations per generation; 0: ``max(8, population_size // 8)``; those
drawn beyond it are skipped and counted in metrics.csv's ``link_capped``).
"""

from __future__ import annotations

import dataclasses
import pathlib

import jax
import ml_collections
import numpy as np

from kx.evolve.config import ConfigError
from kx.evolve.encoding import Encoding, register
from kx.evolve.policy import neat_policy
from kx.neat import presets
from kx.neat.activations import ACTIVATIONS
from kx.neat.algorithm import NEAT
from kx.neat.types import NEATError, NEATParams
from kx.sim import observe

NEAT_METRICS = ("n_species", "threshold", "mean_hidden", "mean_links", "champion_hidden", "champion_links",
                "node_overflow", "link_overflow", "link_exhausted", "link_capped", "species_overflow")


def neat_params_fields(params: NEATParams) -> dict:
    """A :class:`NEATParams` as ``neat.*`` config values (plain Python numbers)."""
    return {f.name: getattr(params, f.name) for f in dataclasses.fields(NEATParams)}


def _need(ok: bool, field: str, allowed: str, value) -> None:
    if not ok:
        raise ConfigError(f"{field}: allowed {allowed}, got {value!r}")


def _int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def check_capacity(n: dict, section: str, population_size: int) -> None:
    """The genome-capacity fields of a NEAT learner's config section ``n`` (``neat``, ``hyperneat``)."""
    for f in ("max_hidden", "species_capacity", "extra_conns", "extra_genes", "max_add_links"):
        low = 1 if f == "species_capacity" else 0
        _need(_int(n[f]) and n[f] >= low, f"{section}.{f}", f"an integer >= {low}", n[f])
    _need(n["species_capacity"] <= population_size, f"{section}.species_capacity",
          f"at most population_size ({population_size})", n["species_capacity"])
    _need(n["extra_genes"] <= n["extra_conns"], f"{section}.extra_genes",
          f"at most {section}.extra_conns ({n['extra_conns']})", n["extra_genes"])


def learner(n: dict, config, section: str) -> tuple[NEATParams, NEAT]:
    """The rates of config section ``n`` and the NEAT learner of ``config`` with them; a value out of
    range (NEAT's own checks, :func:`kx.neat.algorithm.validate`) as a :class:`ConfigError` naming
    ``section``'s field."""
    try:
        params = NEATParams(**{f.name: n[f.name] for f in dataclasses.fields(NEATParams)})
        return params, NEAT(config, params)
    except NEATError as e:
        raise ConfigError(str(e).replace("NEATParams.", f"{section}.").replace("NEATConfig.", f"{section}.")) from None


@register
class NEATEncoding(Encoding):
    name = "neat"
    section = "neat"
    layouts = ("fixed", "full")
    metric_fields = NEAT_METRICS
    plot_field = "n_species"

    @classmethod
    def default_config(cls, reading: str = "sharpneat") -> ml_collections.ConfigDict:
        readings = {"sharpneat": presets.keepaway_sharpneat, "literal": presets.keepaway_literal}
        if reading not in readings:
            raise ConfigError(f"reading: allowed one of {tuple(readings)}, got {reading!r}")
        ncfg, nparams = readings[reading]()
        neat = neat_params_fields(nparams)
        neat.update(output_activation=ncfg.output_activation, hidden_activation=ncfg.hidden_activation,
                    max_hidden=ncfg.max_nodes - ncfg.n_fixed, species_capacity=ncfg.species_capacity,
                    extra_conns=ncfg.max_conns - ncfg.n_initial_conns,
                    extra_genes=ncfg.genes - ncfg.n_initial_conns, max_add_links=ncfg.max_add_links)
        return ml_collections.ConfigDict(neat)

    def __init__(self, cfg, sim, sim_params):
        super().__init__(cfg, sim, sim_params)
        n = dict(cfg.neat)
        check_capacity(n, "neat", cfg.population_size)
        _need(n["max_add_links"] <= cfg.population_size, "neat.max_add_links",
              f"an integer in [0, population_size = {cfg.population_size}] (0: max(8, population_size // 8))",
              n["max_add_links"])
        for f in ("output_activation", "hidden_activation"):
            _need(isinstance(n[f], str) and n[f] in ACTIVATIONS, f"neat.{f}", f"one of {sorted(ACTIVATIONS)}", n[f])
        n_in, n_out = observe.n_inputs(self.layout, sim), observe.n_outputs(self.layout, sim)
        try:
            self.neat_config, _ = presets.keepaway(
                n_inputs=n_in, n_outputs=n_out, population_size=cfg.population_size,
                max_nodes=n_in + 1 + n_out + n["max_hidden"], max_conns=(n_in + 1) * n_out + n["extra_conns"],
                max_genes=(n_in + 1) * n_out + n["extra_genes"], species_capacity=n["species_capacity"],
                output_activation=n["output_activation"], hidden_activation=n["hidden_activation"],
                activation_options=tuple(dict.fromkeys((n["hidden_activation"], n["output_activation"]))),
                max_add_links=n["max_add_links"])
        except NEATError as e:
            raise ConfigError(str(e).replace("NEATParams.", "neat.").replace("NEATConfig.", "neat.")) from None
        self.neat_params, self.neat = learner(n, self.neat_config, "neat")

    def init(self, key):
        return self.neat.init(key)

    def ask(self, key, state):
        return state.population, state

    def tell(self, key, population, score, fitness, state):
        return self.neat.tell(key, population, score, state, fitness=fitness)

    def policy_for(self, sim):
        n_in, n_out = observe.n_inputs(self.layout, sim), observe.n_outputs(self.layout, sim)
        if (n_in, n_out) != (self.neat_config.n_inputs, self.neat_config.n_outputs):
            raise ConfigError(
                f"task: the run's {self.layout}-layout networks have {self.neat_config.n_inputs} inputs and "
                f"{self.neat_config.n_outputs} outputs; {sim.name} needs {n_in} and {n_out} (full-layout "
                "genomes need the transfer mapping of SPEC section 5)")
        return neat_policy(sim, self.neat_config, self.layout)

    def policy_params(self, population):
        return self.neat.networks(population)

    def check(self, state, champion):
        from kx.neat.checks import check_genome, check_population

        errs = check_population(state.population, self.neat_config)
        if np.isfinite(np.asarray(state.best_fitness)):
            errs += [f"best genome: {e}" for e in check_genome(state.best_genome, self.neat_config)]
        if champion is not None:
            errs += [f"champion: {e}" for e in check_genome(champion, self.neat_config)]
        return errs

    def describe(self) -> str:
        c = self.neat_config
        return f"neat ({self.layout} layout: {c.n_inputs} inputs, {c.n_outputs} outputs)"

    def progress(self, row) -> str:
        return (f"species {int(row['n_species']):2d}  hidden {float(row['mean_hidden']):.2f}"
                f"  links {float(row['mean_links']):.1f}")

    def draw(self, genotype, path: pathlib.Path):
        from kx.neat.draw import draw_genome

        return draw_genome(jax.device_get(genotype), self.neat_config, path)
