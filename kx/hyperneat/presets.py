"""The CPPN preset: kx's generic NEAT (:mod:`kx.neat`) set up for HyperNEAT's CPPNs.

Verbancsics & Stanley (2010) evolve the CPPN with the authors' own C# NEAT (SPEC §3;
``../shared/reference/authors-code.md`` §1a, "HyperNEAT arm", files in ``HN/Executables/`` and
``HN/Sources/KeepAway/NEAT/Evolutions.cs``). :func:`cppn` returns ``(NEATConfig, NEATParams)``; every
value and its source:

Shapes (:class:`~kx.neat.types.NEATConfig`):

* Inputs x1, y1, x2, y2 (``n_inputs = 4``; 5 with the distance input, SPEC §3) and NEAT's bias node (the
  CPPN's bias input); outputs weight, expression and bias (``n_outputs = 3``, SPEC §3 and
  :mod:`kx.hyperneat.substrate`).
* ``activation_options``: the paper's set (SPEC §3): identity, Gaussian ``e^(-2.5 x^2)``, bipolar
  sigmoid ``2 / (1 + e^(-4.9 x)) - 1``, absolute value, sine (:mod:`kx.neat.activations`).
  ``random_hidden_activation``: a new hidden node draws its activation from that set, **uniformly**
  (:func:`kx.neat.genome.apply_structure` draws ``randint`` over the options). The authors draw with
  weights (Mutation.xml: Gaussian 0.39, bipolar sigmoid 0.3, step 0.1, abs 0.1, sine 0.1, reciprocal and
  ramp 0.005 each, identity 0), over a set that is not the paper's; kx follows the paper's set and draws
  it uniformly (identity included). ``hidden_activation`` "gaussian" is required by the config but unused
  while ``random_hidden_activation`` is on. ``output_activation``: bipolar sigmoid (the shipped seed's
  outputs are BipolarSigmoid; a weight in [-1, 1], scaled to the weight range by the substrate).
* Capacity, for 20 to 100 generations of 150 genomes (Initialization.xml: 100 generations, 150
  genomes). ``max_nodes``: 16 hidden nodes; at add node 0.05 a lineage gains a node every 20
  generations, about 5 in 100. ``max_genes``: the 15 initial links (18 with the distance input) plus
  48 (63). Per mutated offspring the gene count grows by 2 x 0.05 + 0.15 - 0.05 = 0.2 on average (sd
  0.6), so a lineage left to drift carries about 35 genes after 100 generations, sd 6; 63 is more than
  4 sd above. ``max_conns``: the 15 initial links plus 240 (255 columns), the most distinct
  innovations alive in the population at once: 150 offspring make about 7.5 splits (2 columns each)
  and 22.5 new links a generation, about 30 new columns, some 4 times XOR's rate at Stanley's values.
  ``max_add_links``: 40 add-links carried out per generation: at 0.15, 150 offspring draw 22.5 on
  average (sd 4.4); kx's default cap, 18, would skip a fifth of them (each counted in ``link_capped``,
  and given a weight mutation instead); 40 is 4 sd above the mean. ``species_capacity``: 10, the
  target. A larger capacity costs compilation and time: ``tell`` at 400 columns compiled in 17 s and
  ran in 5 ms, at 255 in 11 s and 3 ms (2-core CPU).
  Measured (2026-12-01, the preset on random fitness, 100 generations, seeds 0-4): at most 120 to 144
  columns alive, 30 to 37 genes and 6 to 9 hidden nodes in one genome (means 24 to 28 genes and 1.9 to
  4.6 hidden nodes at generation 100); no add-link capped, no mutation skipped for want of room. The
  authors' own generation-29 population has a mean complexity of 22.2. A fitness that rewards size
  alone grows about a gene a generation and reaches ``max_genes`` near generation 50 (from then on
  mutations that need room are skipped and counted, never written).

Rates (:class:`~kx.neat.types.NEATParams`):

* Structure: add node 0.05, add link 0.15, delete link 0.05 (Mutation.xml AddNode, AddConnection,
  DeleteConnection; SPEC §2 revised), in kx's roulette (at most one structural mutation per offspring).
  The authors give each asexual offspring exactly one operator, by a roulette over {delete 0.05,
  change function 0.0, add node 0.05, add connection 0.15, weights 0.8}, and a weight mutation when a
  structural operator fails (Evolutions.cs 213-274). ``weight_mutate_prob = 1`` gives that in kx, as
  :func:`kx.neat.presets.keepaway_sharpneat` does: an offspring whose structural draw misses (0.75) or
  fails gets a weight mutation.
* Weights: ``weight_scheme = 2``, the authors' four kinds (Mutation.xml WeightProbabilities,
  Evolutions.cs 298-367): 25% every link + N(0, 0.3); 25% each link with p = 0.25 + N(0, 0.3)
  (``weight_select_fraction = 0.25``); 10% 2 random links reset to U(-5, 5); 40% 2 random links +
  U(-1.25, 1.25) (``weight_perturb_power = 1.25``, WeightRange / 8); clamped to +-5 (``weight_range = 5``,
  WeightRange 10 read as +-5, also Table 2). The two links of a count kind are distinct in kx.
* Activation mutation: ``activation_mutate_prob = 0.0``, the authors' ChangeNodeFunction 0.0. The
  operator is there (SPEC §3: hidden nodes carry an activation gene) and a run may turn it on
  (``hyperneat.activation_mutate_prob``); 0 is kept because the preset is the authors' arm, and in kx
  the operator sits outside the roulette (an offspring without a structural mutation gets it on top of
  its weight mutation), so a nonzero value would match no rate of theirs. A hidden node's function is
  then drawn at its birth and mixed by crossover.
* Fully connected initial CPPNs: ``initial_link_fraction = 1`` (Initialization.xml
  InitalConnectionPercentage 1). Initial and new-link weights U(-1, 1) (``weight_init_range``, kx's
  default): sd 0.58, near the authors' new-link N(0, 0.5). Their initial population is a seed CPPN and
  149 clones with weights U(-5, 5), which kx does not reproduce here.
* Table 2 (``kx.neat.presets.TABLE2``, shared with the keep-away NEAT presets): population 150, at most
  10 species of at most 30 offspring, weights in [-5, 5], survival threshold 0.2, compatibility
  threshold 3 (the start; ``threshold_step`` 0.5 and ``respeciate`` 4 as for keep-away).
* Kept from Stanley's NEAT (kx's defaults), where the authors differ: the compatibility distance c1 = c2
  = 1, c3 = 0.4 (the authors': un-normalised, plus 2 per activation mismatch, toward 8 species); add
  node gives the in-link weight 1 and the out-link the old weight (theirs: the old weight in, N(0, 1)
  out, the old link removed with p = 0.8); 25% mutation-only offspring and every crossover child mutated
  (theirs: asexual 0.75, children of crossover not mutated); champion elitism of species above 5
  (theirs: 10% of each species); stagnation 15 (theirs: a penalty after 10); interspecies mating 0.001.
"""

from __future__ import annotations

from kx.neat.presets import TABLE2
from kx.neat.types import NEATConfig, NEATParams, capacity

CPPN_ACTIVATIONS = ("identity", "gaussian", "bipolar_sigmoid", "abs", "sine")  # SPEC §3, the paper's set
MAX_HIDDEN = 16
EXTRA_GENES = 48  # beyond the initial (n_inputs + 1) * n_outputs links
EXTRA_CONNS = 240  # columns beyond the initial links
MAX_ADD_LINKS = 40


def cppn(n_inputs: int = 4, n_outputs: int = 3, **config_overrides) -> tuple[NEATConfig, NEATParams]:
    """The CPPN preset: ``(NEATConfig, NEATParams)`` for CPPNs with ``n_inputs`` coordinates (x1, y1, x2,
    y2; 5 with a distance input) and ``n_outputs`` outputs (weight, expression, bias). Every value and
    its source: the module docstring. ``config_overrides`` replace :class:`NEATConfig` fields."""
    kw = dict(n_inputs=n_inputs, n_outputs=n_outputs, population_size=150,
              **capacity(n_inputs, n_outputs, MAX_HIDDEN, EXTRA_CONNS, EXTRA_GENES),
              species_capacity=10, activation_options=CPPN_ACTIVATIONS,
              hidden_activation="gaussian", output_activation="bipolar_sigmoid", random_hidden_activation=True,
              max_add_links=MAX_ADD_LINKS)
    kw.update(config_overrides)
    params = NEATParams(
        **TABLE2,
        add_node_prob=0.05,  # Mutation.xml AddNode
        add_link_prob=0.15,  # AddConnection
        delete_link_prob=0.05,  # DeleteConnection
        weight_mutate_prob=1.0,  # with the roulette above: weights 0.75 (+ failed structural draws)
        weight_scheme=2,  # WeightProbabilities: the four kinds
        weight_all_share=0.25, weight_fraction_share=0.25, weight_reset_share=0.1,  # the rest, 0.4: uniform steps
        weight_step_sigma=0.3,  # NextGuassian(0, 0.3) * WeightRange / 10
        weight_select_fraction=0.25,  # (T,T,T,0.25,0.25)
        weight_select_count=2,  # (F,F,F,2,0.1) and (F,T,F,2,0.4)
        weight_perturb_power=1.25,  # WeightRange / 8
        activation_mutate_prob=0.0,  # ChangeNodeFunction 0.0
        initial_link_fraction=1.0,  # InitalConnectionPercentage 1
    )
    return NEATConfig(**kw), params
