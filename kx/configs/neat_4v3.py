"""NEAT evolved from scratch in the 4v3 target task for 50 generations (the paper's no-transfer setup),
on the fixed 13-input, 3-output layout, population 150, 30 trials per generation."""

from kx.evolve.config import base_config


def get_config():
    c = base_config()
    c.task = "4v3"
    c.generations = 50
    return c
