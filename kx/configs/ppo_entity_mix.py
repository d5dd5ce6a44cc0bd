"""PPO on the size-invariant entity network (``method = "ppo_entity"``) in the source task 3v2 with 4v3 episodes in
every batch (``ppo_entity.mix = "4v3"``: the batch's ``num_envs`` and ``resets`` split evenly between the two tasks),
the NEAT source run's budget: 20 generations of 4500 training episodes, 90,000 episodes of both tasks in all. Its
generations are played and validated in 3v2; its champion plays any team size unchanged (the zero-shot study's
``ppo_entity_mix``, docs/experiments.md)."""

from kx.evolve.config import base_config


def get_config():
    c = base_config("ppo_entity")
    c.ppo_entity.mix = "4v3"
    return c
