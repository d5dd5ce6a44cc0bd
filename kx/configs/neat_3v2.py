"""The paper's source task: 3 keepers vs 2 takers, NEAT on the fixed 13-input, 3-output layout,
population 150, 30 trials per generation, 20 generations (Table 2). The default of ``python -m kx.train``."""

from kx.evolve.config import base_config


def get_config():
    return base_config()
