"""Published parameter sets.

* :func:`xor`: Stanley & Miikkulainen (2002), section 4.1 (the XOR experiment): population 150,
  c1 = c2 = 1.0, c3 = 0.4, threshold 3.0, 80% of offspring get their weights mutated (each weight: 90%
  perturbed, 10% replaced), add node 0.03, add link 0.05, disabled genes stay disabled with p = 0.75,
  25% of offspring from mutation alone, interspecies mating 0.001, stagnation after 15 generations,
  champions of species above 5 members copied. The paper gives no perturbation size; 2.5 is the
  ``weight_mut_power`` of Stanley's own NEAT C++ parameter files.
* :func:`keepaway`: the paper's Table 2 (population 150, at most 10 species of at most 30, weight
  mutation +-0.01, weights in [-5, 5], mutation rate 0.05, survival threshold 0.2, compatibility
  threshold 3), Stanley's values for what Table 2 leaves out. Readings of the ambiguous entries are in
  docs/neat.md.
"""

from __future__ import annotations

from kx.neat.types import NEATConfig, NEATParams


def xor(**config_overrides) -> tuple[NEATConfig, NEATParams]:
    kw = dict(n_inputs=2, n_outputs=1, population_size=150, max_nodes=16, max_conns=128, max_genes=32,
              species_capacity=10)
    kw.update(config_overrides)
    return NEATConfig(**kw), NEATParams()


def keepaway(n_inputs: int = 13, n_outputs: int = 3, **config_overrides) -> tuple[NEATConfig, NEATParams]:
    kw = dict(n_inputs=n_inputs, n_outputs=n_outputs, population_size=150, max_nodes=n_inputs + 1 + n_outputs + 16,
              max_conns=(n_inputs + 1) * n_outputs + 86,
              max_genes=(n_inputs + 1) * n_outputs + 32, species_capacity=10)
    kw.update(config_overrides)
    params = NEATParams(
        target_species=10,  # Table 2: maximum number of species
        max_species_population=30,  # Table 2: maximum species population
        weight_perturb_power=0.01,  # Table 2: weight mutation +-0.01
        weight_range=5.0,  # Table 2: weight value range [-5, 5]
        weight_mutate_prob=1.0,
        weight_mutate_rate=0.05,  # Table 2: mutation rate 0.05, read as the per-weight rate
        survival_threshold=0.2,  # Table 2
        compat_threshold=3.0,  # Table 2 (the starting value; it adapts toward target_species)
        # Table 2's small weight steps keep keep-away genomes close together: the threshold has to fall
        # from 3 to about 0.2 before species form, so it moves by half each generation.
        threshold_step=0.5,
        # Species founded together stagnate together; re-speciating at once keeps the count near 10
        # (on XOR it cost evaluations, so it is off there).
        respeciate=4,
    )
    return NEATConfig(**kw), params
