"""PPO in 3v2 with the NEAT source run's budget (90,000 episodes), in the iteration rollout's shape: 512 episodes
stepped one world iteration at a time (16 a rollout), the episodes at a decision acting and learned from, 2 epochs
of 16 minibatches, 2 x 32 tanh units (docs/benchmarks.md, "Levers for PPO's wall time": seeds 0 and 1 gave 0.735
and 0.782 on the test states, the old shape 0.764 and 0.790; with 8 minibatches, 0.660 and 0.704 at 10.5x a NEAT
run). ``python -m kx.bench learning --methods NEAT,PPO-iteration`` times it against NEAT in one process."""

from kx.evolve.config import base_config


def get_config():
    c = base_config("ppo")
    c.ppo.rollout = "iteration"
    c.ppo.num_envs = 512
    c.ppo.num_steps = 16
    c.ppo.resets = 32
    c.ppo.hidden = 32
    c.ppo.update_epochs = 2
    c.ppo.num_minibatches = 16
    return c
