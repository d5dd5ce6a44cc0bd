"""NEAT as an encoding of the run loop: ``method = "neat"``, its ``neat.*`` config section and its networks.

Genomes of :mod:`kx.neat` play keep-away through :func:`kx.evolve.policy.neat_policy` on the ``fixed``
layout (13 inputs, 3 outputs, any team size) or the ``full`` one (4K + 2T - 3 inputs, K outputs; only the
team size it was evolved for). The population's networks are built once per generation and handed to
the evaluator per lane (they are small: a few hundred numbers per genome).

The config section ``neat`` holds every :class:`~kx.neat.types.NEATParams` field (the rates of Table 2
in the reading chosen by :func:`default_config`, see :mod:`kx.neat.presets`), the activations, and the
genome capacity: ``max_hidden`` hidden nodes (at most :data:`MAX_HIDDEN`), ``extra_conns`` connection
columns and ``extra_genes`` genes per genome beyond the initial fully connected ones, ``species_capacity``
species slots and ``max_add_links`` (add-link mutations per generation, at most ``population_size``; 0:
``max(8, population_size // 8)``; those drawn beyond it are skipped and counted in metrics.csv's
``link_capped``).
"""

from __future__ import annotations

import dataclasses
import pathlib

import jax
import ml_collections
import numpy as np

from kx.evolve.encoding import Encoding, stack
from kx.evolve.errors import ConfigError, is_int, need
from kx.evolve.policy import neat_policy
from kx.neat import presets
from kx.neat import transfer as neat_transfer
from kx.neat.activations import ACTIVATIONS
from kx.neat.algorithm import NEAT
from kx.neat.types import MAX_CONNS, NEATError, NEATParams, capacity, initial_conns
from kx.sim import observe

NEAT_METRICS = ("n_species", "stagnant_species", "threshold", "mean_hidden", "mean_links", "champion_hidden",
                "champion_links", "node_overflow", "link_overflow", "link_exhausted", "link_capped", "species_overflow",
                "fittest_offspring", "fittest_elite")


def neat_params_fields(params: NEATParams) -> dict:
    """A :class:`NEATParams` as ``neat.*`` config values (plain Python numbers)."""
    return {f.name: getattr(params, f.name) for f in dataclasses.fields(NEATParams)}


# The most hidden-node slots a genome may have. Each lane of an evaluation carries its network's
# ``[max_hidden + outputs, inputs + 1 + max_hidden]`` weights (about 0.3 MB at 256: 1.3 GB over the
# default 150 x 30 lanes) and the network's forward pass is unrolled over hidden-node pairs (256 gives
# 33,000 terms to compile), so beyond this a run does not fit in memory or compile time; the shipped
# configs use 16.
MAX_HIDDEN = 256


def check_capacity(n: dict, section: str, population_size: int, n_initial: int) -> None:
    """The genome-capacity fields of a NEAT learner's config section ``n`` (``neat``, ``hyperneat``);
    ``n_initial`` is the initial genome's links (:func:`kx.neat.types.initial_conns`); at most
    :data:`kx.neat.types.MAX_CONNS` connection columns."""
    for f in ("species_capacity", "extra_genes", "max_add_links"):
        low = 1 if f == "species_capacity" else 0
        need(is_int(n[f]) and n[f] >= low, f"{section}.{f}", f"an integer >= {low}", n[f])
    need(is_int(n["max_hidden"]) and 0 <= n["max_hidden"] <= MAX_HIDDEN, f"{section}.max_hidden",
         f"an integer in [0, {MAX_HIDDEN}]", n["max_hidden"])
    top = MAX_CONNS - n_initial
    need(is_int(n["extra_conns"]) and 0 <= n["extra_conns"] <= top, f"{section}.extra_conns",
         f"an integer in [0, {top}] ({MAX_CONNS} connection columns less the initial genome's {n_initial})",
         n["extra_conns"])
    need(n["species_capacity"] <= population_size, f"{section}.species_capacity",
         f"at most population_size ({population_size})", n["species_capacity"])
    need(n["extra_genes"] <= n["extra_conns"], f"{section}.extra_genes",
         f"at most {section}.extra_conns ({n['extra_conns']})", n["extra_genes"])


def check_add_links(value, section: str, population_size: int, zero: str) -> None:
    """``<section>.max_add_links``: 0 (``zero``, the method's own cap) or at most the population (a
    generation carries out at most one add-link per offspring)."""
    need(is_int(value) and 0 <= value <= population_size, f"{section}.max_add_links",
         f"an integer in [0, population_size = {population_size}] (0: {zero})", value)


def learner(n: dict, config, section: str) -> tuple[NEATParams, NEAT]:
    """The rates of config section ``n`` and the NEAT learner of ``config`` with them; a value out of
    range (NEAT's own checks, :func:`kx.neat.algorithm.validate`) as a :class:`ConfigError` naming
    ``section``'s field."""
    try:
        params = NEATParams(**{f.name: n[f.name] for f in dataclasses.fields(NEATParams)})
        return params, NEAT(config, params)
    except NEATError as e:
        raise ConfigError(str(e).replace("NEATParams.", f"{section}.").replace("NEATConfig.", f"{section}.")) from None


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
                    max_hidden=ncfg.n_hidden, species_capacity=ncfg.species_capacity, extra_conns=ncfg.extra_conns,
                    extra_genes=ncfg.extra_genes, max_add_links=ncfg.max_add_links)
        return ml_collections.ConfigDict(neat)

    def __init__(self, cfg, sim, sim_params):
        super().__init__(cfg, sim, sim_params)
        n = dict(cfg.neat)
        n_in, n_out = observe.n_inputs(self.layout, sim), observe.n_outputs(self.layout, sim)
        check_capacity(n, "neat", cfg.population_size, initial_conns(n_in, n_out))
        check_add_links(n["max_add_links"], "neat", cfg.population_size, "max(8, population_size // 8)")
        for f in ("output_activation", "hidden_activation"):
            need(isinstance(n[f], str) and n[f] in ACTIVATIONS, f"neat.{f}", f"one of {sorted(ACTIVATIONS)}", n[f])
        try:
            self.neat_config, _ = presets.keepaway(
                n_inputs=n_in, n_outputs=n_out, population_size=cfg.population_size,
                **capacity(n_in, n_out, n["max_hidden"], n["extra_conns"], n["extra_genes"]),
                species_capacity=n["species_capacity"],
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

    #: policy_params takes genomes with any leading axes (a group's [R, P] in one call): the hidden rows
    #: it keeps are read from the genomes on the host, so it is never vmapped (kx.evolve.group)
    policy_params_leading_axes = True

    def policy_params(self, population):
        return self.neat.policy_networks(population)

    def policy_shape(self, population):
        return self.neat.hidden_rows_of(population)

    # ------------------------------------------------------------------------------------- transfer

    def _maps(self, source):
        """``(input_map, output_map)`` from the source's networks to this run's, or ``None`` when they
        have the same inputs and outputs (the genomes carry over unchanged)."""
        s, t = source.neat_config, self.neat_config
        if (s.n_inputs, s.n_outputs) == (t.n_inputs, t.n_outputs):
            return None
        return observe.full_layout_map(source.sim, self.sim)

    def transfer_problems(self, source, state, seeding):
        s, t, sec = source.neat_config, self.neat_config, self.section
        out = []
        p_s, p_t = s.population_size, t.population_size
        if seeding == "population" and p_s != p_t:
            out.append(f"seeding 'population' carries the source's {p_s} genomes and this run's population_size is "
                       f"{p_t} (seed with 'champion' or 'half', or use population_size {p_s})")
        if seeding == "half" and (p_s + 1) // 2 > p_t:
            out.append(f"seeding 'half' carries the source's fittest {(p_s + 1) // 2} genomes and this run's "
                       f"population_size is {p_t}")
        if s.activation_options != t.activation_options:
            out.append(f"the source's genomes index the activations {s.activation_options}, this run's "
                       f"{t.activation_options} ({sec}.hidden_activation / output_activation / activations)")
        maps = None
        try:
            maps = self._maps(source)
        except ValueError as e:
            out.append(str(e))
        if maps is None:
            if (s.n_inputs, s.n_outputs) != (t.n_inputs, t.n_outputs):
                out.append(f"the source's networks have {s.n_inputs} inputs and {s.n_outputs} outputs, this run's "
                           f"{t.n_inputs} and {t.n_outputs}, and no mapping between them exists")
            for what, a, b, field in (("hidden-node slots", s.n_hidden, t.n_hidden, "max_hidden"),
                                      ("connection columns", s.max_conns, t.max_conns, "extra_conns"),
                                      ("genes per genome", s.genes, t.genes, "extra_genes")):
                if a > b:
                    out.append(f"the source's genomes have {a} {what} and this run's config {b} ({sec}.{field}): "
                               f"its genome capacity does not fit")
        else:
            genomes = self._seed_genomes(state, seeding, None)
            out += neat_transfer.fit_problems(genomes, s, t, *maps, next_node_id=state.learner.next_node_id)
        return out

    def _seed_genomes(self, state, seeding, order):
        """The source genomes a seeding carries (``order`` None: the whole population stands in for the
        fittest half, for capacity checks)."""
        pop = state.learner.population
        if seeding == "champion":
            return stack([state.champion])
        if seeding == "half" and order is not None:
            m = (jax.tree.leaves(pop)[0].shape[0] + 1) // 2
            return jax.tree.map(lambda a: a[np.asarray(order[:m])], pop)
        return pop

    def transfer(self, key, source, state, seeding, order):
        s, t = source.neat_config, self.neat_config
        learner = state.learner
        genomes = self._seed_genomes(state, seeding, order)
        next_node, next_innov = learner.next_node_id, learner.next_innov
        k_map, k_seed = jax.random.split(key)
        maps = self._maps(source)
        if maps is None:  # the same inputs and outputs: the genomes carry over unchanged (padded to this capacity)
            genomes = neat_transfer.resize(genomes, s, t)
        else:  # Algorithm 1
            genomes, next_node, next_innov = neat_transfer.map_population(
                k_map, genomes, s, t, *maps, next_node_id=next_node, next_innov=next_innov, params=self.neat_params)
        if seeding != "population":
            genomes, next_node, next_innov = self.neat.seed_copies(k_seed, genomes, next_node, next_innov)
        return self.neat.init_from(genomes, next_node, next_innov, threshold=learner.threshold)

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
        return (f"species {int(row['n_species']):2d} ({int(row['stagnant_species'])} stagnant)"
                f"  hidden {float(row['mean_hidden']):.2f}  links {float(row['mean_links']):.1f}")

    def draw(self, genotype, path: pathlib.Path):
        from kx.neat.draw import draw_genome

        return draw_genome(jax.device_get(genotype), self.neat_config, path,
                           input_names=list(observe.input_names(self.layout, self.sim)),
                           output_names=list(observe.output_names(self.layout, self.sim)))
