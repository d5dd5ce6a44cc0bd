"""HyperNEAT evolved from scratch in the 5v3 target task (the paper's no-transfer setup), with the CPPNs and
20 x 20 Bird's Eye View substrate of ``configs/hyperneat_3v2.py``: 50 generations of 150 x 30 episodes, the
protocol's budget (kx.evolve.config.target_config)."""

from kx.evolve.config import target_config


def get_config():
    return target_config("hyperneat", "5v3")
