"""PPO in the 6v4 target task, from scratch (or, with ``transfer.source``, from a 3v2 run's weights): 50
generations of 4500 training episodes, the budget of NEAT's 50 generations in ``configs/neat_6v4.py``
(kx.evolve.config.target_config)."""

from kx.evolve.config import target_config


def get_config():
    return target_config("ppo", "6v4")
