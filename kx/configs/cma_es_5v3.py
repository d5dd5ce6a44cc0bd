"""CMA-ES (evosax) on a linear network of the fixed 13-input, 3-output layout, from scratch in the 5v3
target task: population 50, 150 generations of 30 trials, the budget of NEAT's 50 generations in
``configs/neat_5v3.py`` (kx.evolve.config.target_config)."""

from kx.evolve.config import target_config


def get_config():
    return target_config("cma_es", "5v3")
