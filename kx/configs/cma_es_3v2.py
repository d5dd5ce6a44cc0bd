"""CMA-ES (evosax, its default parameters) on a linear network of the fixed 13-input, 3-output layout in
the source task 3v2: population 50, 60 generations of 30 trials, the evaluation budget of the NEAT source
run (150 x 20 individuals). The standard-optimiser baseline of ``kx.bench learning``."""

from kx.evolve.config import base_config


def get_config():
    return base_config("cma_es")
