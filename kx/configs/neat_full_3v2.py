"""NEAT on the full layout of SPEC section 1 (4K + 2T - 3 = 13 inputs, K = 3 outputs for 3v2) in the
source task, 20 generations: the layout Algorithm 1 maps to bigger teams."""

from kx.evolve.config import base_config


def get_config():
    c = base_config()
    c.layout = "full"
    return c
