"""PPO on the entity network in the 5v3 target task, from scratch (or, with ``transfer.source``, from a 3v2
run's weights, which fit every team size): 50 generations of 4500 training episodes, the budget of NEAT's 50
generations in ``configs/neat_5v3.py`` (kx.evolve.config.target_config)."""

from kx.evolve.config import target_config


def get_config():
    return target_config("ppo_entity", "5v3")
