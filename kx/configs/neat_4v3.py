"""NEAT evolved from scratch in the 4v3 target task (the paper's no-transfer setup), on the fixed 13-input,
3-output layout: 50 generations of 150 x 30 episodes, the protocol's budget (kx.evolve.config.target_config)."""

from kx.evolve.config import target_config


def get_config():
    return target_config("neat", "4v3")
