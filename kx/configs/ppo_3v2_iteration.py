"""PPO in 3v2 in the iteration shape (kx.evolve.encodings.ppo.PROTOCOL_SHAPE): since that shape became the shipped
one, the same config as ``configs/ppo_3v2.py``. Kept because docs/zeroshot's PPO rows were trained under this
name (``--config-of ppo=configs/ppo_3v2_iteration.py``) and ``kx.bench learning``'s PPO-iteration methods run it."""

from kx.evolve.config import base_config


def get_config():
    return base_config("ppo")
