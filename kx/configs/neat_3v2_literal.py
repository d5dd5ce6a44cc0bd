"""The paper's source task (3v2, 20 generations) with Table 2 read literally: weights perturbed by
U(-0.01, 0.01), each with probability 0.05, fully connected initial genomes (the first kx default; see
docs/neat.md for what it learns next to the default SharpNEAT reading)."""

from kx.evolve.config import base_config


def get_config():
    return base_config("neat", reading="literal")
