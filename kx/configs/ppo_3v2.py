"""PPO (kx.evolve.encodings.ppo.algorithm: flax, optax; the clipped objective with GAE over SMDP steps) in the source
task 3v2, with
the NEAT source run's budget: 20 generations of 4500 training episodes (NEAT's 150 genomes x 30 trials),
90,000 episodes in all. Each generation's network plays the generation's 30 training start states
greedily (its training fitness) and the validation states, as every method's generation champion does."""

from kx.evolve.config import base_config


def get_config():
    return base_config("ppo")
