"""HyperNEAT in the paper's literal reading (SPEC §1 and §3): the paper's Bird's Eye View image (keepers
1.0, takers -1.0, paths +-0.3, clipped) and a CPPN queried with the four coordinates alone (no distance
input); otherwise ``configs/hyperneat_3v2.py`` (3v2, 150 CPPNs, 20 generations of 30 trials).

Kept as a preset: over 5 seeds its validated champions hold the ball for 0.003 of the episode on test
states, like always-hold, where the default (the authors' image with the distance input) reaches 0.47
(docs/hyperneat.md, "Defaults over seeds")."""

from kx.evolve.config import base_config


def get_config():
    c = base_config("hyperneat")
    c.hyperneat.image = "paper"
    c.hyperneat.distance_input = False
    return c
