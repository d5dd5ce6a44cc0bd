"""Types of kx's NEAT: static shapes, traced parameters, genome tensors and the run state.

Following Stanley & Miikkulainen, "Evolving Neural Networks through Augmenting Topologies" (2002), and
the split used across kx (gymnax, evosax): :class:`NEATConfig` fixes every shape (inputs, outputs,
population, genome capacity, species slots) and is a hashable static argument; :class:`NEATParams`
holds the rates and thresholds, which set no shape and may be traced or vmapped for sweeps.

Genome layout (one genome; a population adds a leading axis to every array):

* Node slots ``[max_nodes]``: slot ``i < n_inputs`` is input ``i``, slot ``n_inputs`` the bias, the
  next ``n_outputs`` slots the outputs, and the rest hidden nodes, used as a prefix (a node is never
  removed). Fixed nodes have ``id == slot``; a hidden node's id comes from the run's global node
  counter, so that the same split in one generation gives the same id in every genome.
* Connection genes ``[max_conns]`` live in *columns*: in a population, each innovation number has one
  column, the same in every genome that carries it, given when the innovation is created (a column
  no genome of the generation uses; when all are in use, the structural mutation is skipped and
  counted). Aligning two genomes by innovation number, as crossover and the compatibility distance
  do, is then a comparison column by column, with no search. ``max_conns`` therefore bounds the
  number of distinct innovations alive in the population at once, not one genome's size. ``src`` and
  ``dst`` are node *ids*.

Ids and innovation numbers are int32; empty slots hold -1 and a zero weight, never NaN.
"""

from __future__ import annotations

import dataclasses

import jax
from flax import struct

from kx.neat.activations import ACTIVATIONS

INPUT, BIAS, HIDDEN, OUTPUT = 0, 1, 2, 3
EMPTY = -1
# The most genes weight_scheme 2 picks by count (NEATParams.weight_select_count): the size of a top-k,
# a static shape, while the count itself stays a traced parameter.
MAX_SELECT_COUNT = 8
# The most connection columns a config may have (NEATConfig.max_conns).
MAX_CONNS = 65535


class NEATError(ValueError):
    """A NEAT configuration or parameter value out of its allowed range."""


def initial_conns(n_inputs: int, n_outputs: int) -> int:
    """The links of the fully connected initial genome: every input and the bias to every output."""
    return (n_inputs + 1) * n_outputs


def capacity(n_inputs: int, n_outputs: int, max_hidden: int, extra_conns: int, extra_genes: int) -> dict:
    """:class:`NEATConfig`'s ``max_nodes``, ``max_conns`` and ``max_genes`` of a genome capacity given as
    ``max_hidden`` hidden nodes and ``extra_conns`` connection columns and ``extra_genes`` genes beyond the
    initial genome's links (the inverse: :attr:`NEATConfig.n_hidden`, :attr:`NEATConfig.extra_conns`,
    :attr:`NEATConfig.extra_genes`)."""
    n_initial = initial_conns(n_inputs, n_outputs)
    return dict(max_nodes=n_inputs + 1 + n_outputs + max_hidden, max_conns=n_initial + extra_conns,
                max_genes=n_initial + extra_genes)


@dataclasses.dataclass(frozen=True)
class NEATConfig:
    """Shapes and the activation set: a static, hashable argument of every jitted NEAT function.

    Attributes:
      n_inputs, n_outputs: network inputs (a bias node is added) and outputs.
      population_size: genomes per generation.
      max_nodes: node capacity per genome, inputs, bias and outputs included.
      max_conns: connection-gene columns: the most distinct innovations alive in the population at once.
      max_genes: the most connection genes one genome may carry (0: ``max_conns``); structural
        operators and the network builder work on this many rows, so it sets their cost.
      species_capacity: species slots (at least ``NEATParams.target_species``, the most species that
        may exist at once).
      activation_options: activations a node may carry (the genome stores an index into this tuple).
      hidden_activation, output_activation: the activation of new hidden nodes and of output nodes.
      random_hidden_activation: new hidden nodes draw their activation from ``activation_options``
        (HyperNEAT's CPPNs) instead of taking ``hidden_activation``.
      max_add_links: the most genomes per generation whose add-link mutation is carried out (link
        candidates are computed for that many genomes, so it sets an array shape); 0: ``max(8,
        population_size // 8)``, about 2.5 times the expected count at Stanley's add-link rate 0.05.
        Add-link draws beyond it, in population order, are skipped and counted (``link_capped``).
        :attr:`add_link_cap` is the resolved value.
    """

    n_inputs: int
    n_outputs: int
    population_size: int = 150
    max_nodes: int = 32
    max_conns: int = 128
    max_genes: int = 0
    species_capacity: int = 20
    activation_options: tuple[str, ...] = ("sigmoid",)
    hidden_activation: str = "sigmoid"
    output_activation: str = "sigmoid"
    random_hidden_activation: bool = False
    max_add_links: int = 0

    def __post_init__(self):
        def need(ok, field, allowed):
            if not ok:
                raise NEATError(f"NEATConfig.{field} = {getattr(self, field)!r}: allowed {allowed}")

        need(isinstance(self.n_inputs, int) and 1 <= self.n_inputs <= 4096, "n_inputs", "an integer in 1..4096")
        need(isinstance(self.n_outputs, int) and 1 <= self.n_outputs <= 4096, "n_outputs",
             "an integer in 1..4096")
        need(isinstance(self.population_size, int) and 2 <= self.population_size <= 1_000_000,
             "population_size", "an integer in 2..1000000")
        need(isinstance(self.max_nodes, int) and self.max_nodes >= self.n_fixed, "max_nodes",
             f"an integer >= n_inputs + 1 + n_outputs = {self.n_fixed}")
        need(isinstance(self.max_conns, int) and self.n_initial_conns <= self.max_conns <= MAX_CONNS, "max_conns",
             f"an integer in (n_inputs + 1) * n_outputs = {self.n_initial_conns} (the initial genome)..{MAX_CONNS}")
        need(isinstance(self.max_genes, int) and (self.max_genes == 0 or self.n_initial_conns <= self.max_genes
                                                   <= self.max_conns), "max_genes",
             f"0 or an integer in {self.n_initial_conns}..max_conns ({self.max_conns})")
        need(isinstance(self.species_capacity, int) and 1 <= self.species_capacity <= self.population_size,
             "species_capacity", f"an integer in 1..population_size ({self.population_size})")
        opts = tuple(self.activation_options)
        need(len(opts) >= 1 and all(a in ACTIVATIONS for a in opts) and len(set(opts)) == len(opts),
             "activation_options", f"distinct names from {sorted(ACTIVATIONS)}")
        need(self.hidden_activation in opts, "hidden_activation", f"one of activation_options {opts}")
        need(self.output_activation in opts, "output_activation", f"one of activation_options {opts}")
        need(isinstance(self.max_add_links, int) and not isinstance(self.max_add_links, bool)
             and 0 <= self.max_add_links <= self.population_size, "max_add_links",
             f"0 (max(8, population_size // 8)) or an integer in 1..population_size ({self.population_size})")
        object.__setattr__(self, "activation_options", opts)

    @property
    def n_fixed(self) -> int:
        """Input, bias and output nodes: the slots every genome has."""
        return self.n_inputs + 1 + self.n_outputs

    @property
    def n_hidden(self) -> int:
        """Hidden-node capacity."""
        return self.max_nodes - self.n_fixed

    @property
    def genes(self) -> int:
        """Connection genes one genome may carry."""
        return self.max_genes or self.max_conns

    @property
    def add_link_cap(self) -> int:
        """Genomes per generation whose add-link mutation is carried out (``max_add_links`` resolved)."""
        return self.add_link_cap_of(self.population_size)

    def add_link_cap_of(self, p: int) -> int:
        """:attr:`add_link_cap` for a population of ``p`` genomes (operators accept any ``p``)."""
        return min(p, self.max_add_links or max(8, p // 8))

    @property
    def n_initial_conns(self) -> int:
        return initial_conns(self.n_inputs, self.n_outputs)

    @property
    def extra_conns(self) -> int:
        """Connection columns beyond the initial genome's links (:func:`capacity`'s ``extra_conns``)."""
        return self.max_conns - self.n_initial_conns

    @property
    def extra_genes(self) -> int:
        """Genes per genome beyond the initial genome's links (:func:`capacity`'s ``extra_genes``)."""
        return self.genes - self.n_initial_conns

    @property
    def first_output(self) -> int:
        return self.n_inputs + 1

    def act_id(self, name: str) -> int:
        return self.activation_options.index(name)


@struct.dataclass
class NEATParams:
    """Rates and thresholds (traced; no shape depends on them).

    Defaults are Stanley & Miikkulainen's (2002) XOR values where the paper gives them; see
    :func:`kx.neat.presets.xor` and :func:`kx.neat.presets.keepaway` and docs/neat.md for each value's source.
    """

    # Compatibility distance c1 E / N + c2 D / N + c3 mean|dw|; N = 1 while both genomes have fewer
    # than ``small_genome`` genes (as the NEAT paper allows), else the larger gene count.
    c1: float = 1.0
    c2: float = 1.0
    c3: float = 0.4
    small_genome: int = 20
    # Speciation: at most ``target_species`` species (the paper's "maximum number of species"); the
    # threshold starts at ``compat_threshold`` and each generation is multiplied by
    # ``1 - threshold_step`` while fewer species exist, or by ``1 + threshold_step`` when a genome fit
    # no species and could not found one (never below ``threshold_min``), so that the count holds.
    compat_threshold: float = 3.0
    target_species: int = 10
    threshold_step: float = 0.3
    threshold_min: float = 0.01
    # When a generation is left with fewer than ``target_species - 2`` species, speciate it again at
    # half the threshold, at most this many times (0: never; wait for the threshold to fall).
    respeciate: int = 0
    # Weights.
    weight_range: float = 5.0  # weights are clipped to [-weight_range, weight_range]
    weight_init_range: float = 1.0  # initial, new-link and (schemes 0, 1) replacement weights ~ U(-r, r)
    weight_mutate_prob: float = 0.8  # chance that an offspring without a structural mutation gets a weight mutation
    # How a weight mutation changes the weights (every scheme clips to weight_range after). weight_scheme
    # 0 (Stanley's NEAT): each connection gene, with probability weight_mutate_rate, is perturbed by
    # U(-p, p) (p = weight_perturb_power) with probability weight_perturb_prob, else replaced.
    weight_scheme: int = 0
    weight_mutate_rate: float = 1.0
    weight_perturb_prob: float = 0.9
    weight_perturb_power: float = 2.5
    # weight_scheme 1 (SharpNEAT 2's default): one of three kinds, a Gaussian step of sigma
    # weight_small_sigma (with probability weight_small_share), a Gaussian step of sigma
    # weight_large_sigma (weight_large_share) or a replacement (the rest), applied to one of four
    # selections drawn uniformly: 1, 2 or 3 random connection genes, or each gene with probability
    # weight_select_fraction.
    weight_small_sigma: float = 0.02
    weight_large_sigma: float = 1.0
    weight_small_share: float = 0.455
    weight_large_share: float = 0.454
    weight_select_fraction: float = 0.02
    # weight_scheme 2 (the authors' HyperNEAT code, Evolutions.cs): one of four kinds, drawn per weight
    # mutation: with probability weight_all_share every gene gets a Gaussian step of sigma
    # weight_step_sigma; with weight_fraction_share each gene, with probability weight_select_fraction,
    # gets that step; with weight_reset_share weight_select_count distinct random genes are reset to
    # U(-weight_range, weight_range) (the authors reset over the whole range, not weight_init_range);
    # otherwise (the rest) weight_select_count distinct random genes get U(-p, p), p =
    # weight_perturb_power. The defaults below are the authors' (0.25, 0.25, 0.1, the rest 0.4; sigma
    # 0.3; 2 genes); kx.hyperneat.presets.cppn also sets weight_select_fraction 0.25 and
    # weight_perturb_power 1.25, which mean there what they mean in schemes 1 and 0.
    weight_all_share: float = 0.25
    weight_fraction_share: float = 0.25
    weight_reset_share: float = 0.1
    weight_step_sigma: float = 0.3
    weight_select_count: int = 2  # 1..MAX_SELECT_COUNT
    # Structure: an offspring gets at most one structural mutation, add node with add_node_prob, add
    # link with add_link_prob, delete link with delete_link_prob (one draw: a roulette).
    add_node_prob: float = 0.03
    add_link_prob: float = 0.05
    delete_link_prob: float = 0.0
    # Share of the (inputs + bias) x outputs links present in an initial genome (each drawn
    # independently; a genome left with none gets one at random).
    initial_link_fraction: float = 1.0
    reenable_prob: float = 0.0  # chance per offspring to re-enable one disabled gene
    activation_mutate_prob: float = 0.0  # chance per offspring to redraw one hidden node's activation
    # Reproduction.
    disable_inherit_prob: float = 0.75
    survival_threshold: float = 0.2
    elitism_min_size: int = 5  # champions of species with more members than this are copied
    stagnation_limit: int = 15
    mutation_only_prob: float = 0.25
    interspecies_prob: float = 0.001
    max_species_population: int = 0  # cap on a species' offspring; 0: none

    def validate(self) -> None:
        """Raise :class:`NEATError` naming the first value out of range (concrete values only)."""
        probs = ("weight_mutate_prob", "weight_mutate_rate", "weight_perturb_prob", "add_node_prob",
                 "add_link_prob", "delete_link_prob", "reenable_prob", "activation_mutate_prob",
                 "disable_inherit_prob", "mutation_only_prob", "interspecies_prob", "weight_small_share",
                 "weight_large_share", "weight_select_fraction", "weight_all_share", "weight_fraction_share",
                 "weight_reset_share")
        for f in probs:
            v = float(getattr(self, f))
            if not 0.0 <= v <= 1.0:
                raise NEATError(f"NEATParams.{f} = {v}: allowed a probability in [0, 1]")
        if float(self.add_node_prob) + float(self.add_link_prob) + float(self.delete_link_prob) > 1.0:
            raise NEATError("NEATParams.add_node_prob + add_link_prob + delete_link_prob must be at most 1")
        if float(self.weight_small_share) + float(self.weight_large_share) > 1.0:
            raise NEATError("NEATParams.weight_small_share + weight_large_share must be at most 1")
        if (float(self.weight_all_share) + float(self.weight_fraction_share) + float(self.weight_reset_share)
                > 1.0 + 1e-6):
            raise NEATError("NEATParams.weight_all_share + weight_fraction_share + weight_reset_share must be at "
                            "most 1 (the rest is the share of uniform steps on weight_select_count genes)")
        if int(self.weight_scheme) != self.weight_scheme or int(self.weight_scheme) not in (0, 1, 2):
            raise NEATError(f"NEATParams.weight_scheme = {self.weight_scheme}: allowed 0 (Stanley: per-gene "
                            "uniform perturbation or replacement), 1 (SharpNEAT: Gaussian steps on a few genes) or 2 "
                            "(the authors' HyperNEAT: Gaussian steps on all or some genes, or resets or uniform steps "
                            "on weight_select_count genes)")
        c = self.weight_select_count
        if int(c) != c or not 1 <= int(c) <= MAX_SELECT_COUNT:
            raise NEATError(f"NEATParams.weight_select_count = {c}: allowed an integer in 1..{MAX_SELECT_COUNT}")
        if not 0.0 < float(self.initial_link_fraction) <= 1.0:
            raise NEATError(f"NEATParams.initial_link_fraction = {self.initial_link_fraction}: allowed (0, 1]")
        for f in ("c1", "c2", "c3", "threshold_step", "weight_perturb_power", "weight_small_sigma",
                  "weight_large_sigma", "weight_step_sigma"):
            if not float(getattr(self, f)) >= 0.0:
                raise NEATError(f"NEATParams.{f} = {getattr(self, f)}: allowed a value >= 0")
        for f in ("compat_threshold", "threshold_min", "weight_range", "weight_init_range"):
            if not float(getattr(self, f)) > 0.0:
                raise NEATError(f"NEATParams.{f} = {getattr(self, f)}: allowed a value > 0")
        if not 0.0 < float(self.survival_threshold) <= 1.0:
            raise NEATError(f"NEATParams.survival_threshold = {self.survival_threshold}: allowed (0, 1]")
        for f, lo in (("small_genome", 0), ("target_species", 1), ("elitism_min_size", 0),
                      ("stagnation_limit", 1), ("max_species_population", 0), ("respeciate", 0)):
            v = getattr(self, f)
            if int(v) != v or int(v) < lo:
                raise NEATError(f"NEATParams.{f} = {v}: allowed an integer >= {lo}")


@struct.dataclass
class Genome:
    """One genome (or, with a leading axis on every field, a population)."""

    node_id: jax.Array  # [max_nodes] int32, -1 where empty
    node_kind: jax.Array  # [max_nodes] int32: INPUT, BIAS, HIDDEN, OUTPUT, or EMPTY
    node_act: jax.Array  # [max_nodes] int32 index into NEATConfig.activation_options
    node_valid: jax.Array  # [max_nodes] bool
    conn_innov: jax.Array  # [max_conns] int32 innovation number, -1 where empty (see "columns" above)
    conn_src: jax.Array  # [max_conns] int32 source node id, -1 where empty
    conn_dst: jax.Array  # [max_conns] int32 target node id, -1 where empty
    conn_weight: jax.Array  # [max_conns] float32, 0 where empty
    conn_enabled: jax.Array  # [max_conns] bool, False where empty
    conn_valid: jax.Array  # [max_conns] bool


@struct.dataclass
class Counters:
    """Structural mutations of one generation, counted (int32)."""

    node_overflow: jax.Array  # add-node mutations skipped for lack of a hidden slot, gene room or columns
    link_overflow: jax.Array  # add-link mutations skipped for lack of gene room or a column
    link_exhausted: jax.Array  # add-link mutations with no new feed-forward link left to add
    link_capped: jax.Array  # add-link mutations skipped: more genomes drew add-link than add_link_cap
    new_nodes: jax.Array  # distinct add-node innovations this generation
    new_links: jax.Array  # distinct add-link innovations this generation


@struct.dataclass
class NEATState:
    """Everything a run carries from one generation to the next (a pytree: checkpoint it whole)."""

    population: Genome  # [P, ...]
    species: jax.Array  # [P] int32 species slot of each genome
    species_alive: jax.Array  # [S] bool
    species_uid: jax.Array  # [S] int32 id of the species in the slot (unique over the run)
    species_best: jax.Array  # [S] float32 best task fitness the species ever reached (decides stagnation)
    species_improved: jax.Array  # [S] int32 generation of its last improvement
    threshold: jax.Array  # float32 current compatibility threshold
    next_node_id: jax.Array  # int32
    next_innov: jax.Array  # int32
    next_species_uid: jax.Array  # int32
    generation: jax.Array  # int32: number of completed tell() calls
    best_genome: Genome  # the fittest genome evaluated so far (by task fitness, not score)
    best_fitness: jax.Array  # float32
