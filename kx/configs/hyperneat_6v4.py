"""HyperNEAT evolved from scratch in the 6v4 target task for 50 generations (the paper's no-transfer setup):
the same CPPNs and 20 x 20 Bird's Eye View substrate as ``configs/hyperneat_3v2.py``, population 150,
30 trials per generation."""

from kx.evolve.config import base_config


def get_config():
    c = base_config("hyperneat")
    c.task = "6v4"
    c.generations = 50
    return c
