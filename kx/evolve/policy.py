"""Keep-away policies whose parameters are NEAT networks.

The evaluator (:func:`kx.sim.evaluate.evaluate`) hands a policy its parameters batch-last, one network
per episode lane; :func:`kx.neat.network.forward` is written batch-last, so a population's networks
(built once per generation by :func:`kx.neat.algorithm.build_networks`) go to the evaluator as they are.
"""

from __future__ import annotations

import functools

from kx.neat.activations import INCREASING
from kx.neat.network import forward
from kx.neat.types import NEATConfig
from kx.sim import observe
from kx.sim.policies import Policy
from kx.sim.types import KeepAwayConfig


def neat_config_check(sim: KeepAwayConfig, neat: NEATConfig, layout: str) -> None:
    n_in, n_out = observe.n_inputs(layout, sim), observe.n_outputs(layout, sim)
    if (neat.n_inputs, neat.n_outputs) != (n_in, n_out):
        raise ValueError(f"NEATConfig has {neat.n_inputs} inputs and {neat.n_outputs} outputs; the {layout!r} "
                         f"layout of {sim.name} needs {n_in} and {n_out}")


@functools.lru_cache(maxsize=None)
def neat_policy(sim: KeepAwayConfig, neat: NEATConfig, layout: str = "fixed") -> Policy:
    """The holder acts on the largest output of its network (ties to hold): ``fixed`` is the paper's
    13-input, 3-output layout, ``full`` the 4K + 2T - 3 input, K-output one (SPEC §1).

    With increasing output activations (NEAT's sigmoid) the outputs are compared before their
    activation, on the weighted sums: the same order in exact arithmetic, without the ties of a
    float32 sigmoid saturated at 1.0 (docs/neat.md, "Decisions")."""
    neat_config_check(sim, neat, layout)
    obs_fn = {"fixed": observe.fixed_obs, "full": observe.full_obs}[layout]
    pre = neat.output_activation in INCREASING  # output nodes keep it (only hidden nodes draw theirs)

    def apply(net, state, key):
        out = forward(net, obs_fn(state, sim), neat, pre_activation=pre)
        return observe.decode_ranked(out, state, sim)

    return Policy(f"neat-{layout}", apply)
