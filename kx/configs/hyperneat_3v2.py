"""The paper's source task with HyperNEAT: 3 keepers vs 2 takers, CPPNs (the paper's activation set, the
authors' HyperNEAT mutation rates) painting the 20 x 20 -> 20 x 20 Bird's Eye View substrate; population
150, 30 trials per generation, 20 generations (Table 2). The champion plays every task unchanged."""

from kx.evolve.config import base_config


def get_config():
    return base_config("hyperneat")
