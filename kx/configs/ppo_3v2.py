"""PPO (kx.evolve.encodings.ppo.algorithm: flax, optax; the clipped objective with GAE) in the source task 3v2, in the
iteration shape (kx.evolve.encodings.ppo.PROTOCOL_SHAPE: 512 episodes stepped a world iteration at a time, 16 a
rollout, 2 epochs of 16 minibatches, 2 x 32 units; the older SMDP shape is configs/ppo_3v2_smdp.py), with
the NEAT source run's budget: 20 generations of 4500 training episodes (NEAT's 150 genomes x 30 trials),
90,000 episodes in all. Each generation's network plays the generation's 30 training start states
greedily (its training fitness) and the validation states, as every method's generation champion does."""

from kx.evolve.config import base_config


def get_config():
    return base_config("ppo")
