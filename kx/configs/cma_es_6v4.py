"""CMA-ES (evosax) on a linear network of the fixed 13-input, 3-output layout, from scratch in the 6v4
target task: population 50, 150 generations of 30 trials (the budget of the 50-generation NEAT run of
``configs/neat_6v4.py``, 150 x 50 individuals)."""

from kx.evolve.config import base_config


def get_config():
    c = base_config("cma_es")
    c.task = "6v4"
    c.generations = 150
    return c
