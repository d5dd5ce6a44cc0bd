"""PPO on the size-invariant entity network (``method = "ppo_entity"``:
kx.evolve.encodings.ppo.algorithm.EntityActorCritic, self-attention over
the holder's, teammates' and takers' tokens) in the source task 3v2, with the NEAT source run's budget: 20
generations of 4500 training episodes, 90,000 episodes in all. Its champion plays any team size unchanged."""

from kx.evolve.config import base_config


def get_config():
    return base_config("ppo_entity")
