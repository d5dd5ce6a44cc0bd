"""PPO on the entity network in the 5v3 target task, from scratch (or, with ``transfer.source``, from a 3v2 run's
weights, which fit every team size): 50 generations of 4500 training episodes, the budget of the 50-generation NEAT
run of ``configs/neat_5v3.py``."""

from kx.evolve.config import base_config


def get_config():
    c = base_config("ppo_entity")
    c.task = "5v3"
    c.generations = 50
    c.ppo_entity.anneal_episodes = 50 * 4500  # the learning rate falls to 0 over the run's budget
    return c
