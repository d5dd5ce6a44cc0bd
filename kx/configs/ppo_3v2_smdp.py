"""PPO in 3v2 in the SMDP shape that was the shipped one until the iteration shape replaced it
(kx.evolve.encodings.ppo.PROTOCOL_SHAPE): 64 episodes advanced one SMDP step (a decision of every episode) at a
time, 64 a rollout, 4 epochs of 4 minibatches, 2 x 64 tanh units, with the NEAT source run's budget (90,000
episodes). Kept to compare the shapes (``python -m kx.bench learning --methods NEAT,PPO,PPO-smdp``):
docs/benchmarks.md, "Levers for PPO's wall time"."""

from kx.evolve.config import base_config


def get_config():
    c = base_config("ppo")
    c.ppo.rollout = "smdp"
    c.ppo.num_envs = 64
    c.ppo.num_steps = 64
    c.ppo.resets = 8
    c.ppo.hidden = 64
    c.ppo.update_epochs = 4
    c.ppo.num_minibatches = 4
    return c
