"""Node activation functions, referred to by integer id in the genome.

The set is the paper's CPPN set (Table 2: identity, Gaussian, bipolar sigmoid, absolute value, sine)
plus NEAT's steepened sigmoid ``1 / (1 + exp(-4.9 x))`` (Stanley & Miikkulainen 2002), which hidden and
output nodes of a NEAT network use. A config names the activations its genomes may carry
(``activation_options``); a node gene stores an index into that tuple, so a population whose genomes
only ever use one function pays for that one alone.
"""

from __future__ import annotations

import math
from typing import Callable

import jax
import jax.numpy as jnp

ActivationFn = Callable[[jax.Array], jax.Array]


def sigmoid(x):
    return jax.nn.sigmoid(4.9 * x)


def bipolar_sigmoid(x):
    return 2.0 * jax.nn.sigmoid(4.9 * x) - 1.0


def gaussian(x):
    return jnp.exp(-2.5 * x * x)


ACTIVATIONS: dict[str, ActivationFn] = {
    "sigmoid": sigmoid,
    "identity": lambda x: x,
    "gaussian": gaussian,
    "bipolar_sigmoid": bipolar_sigmoid,
    "abs": jnp.abs,
    "sine": jnp.sin,
    "tanh": jnp.tanh,
}

#: the strictly increasing activations: the largest output is the output with the largest weighted sum
INCREASING = frozenset({"sigmoid", "identity", "bipolar_sigmoid", "tanh"})

# Plain-Python versions for the reference evaluation in the tests.
PY_ACTIVATIONS: dict[str, Callable[[float], float]] = {
    "sigmoid": lambda x: 1.0 / (1.0 + math.exp(-4.9 * x)) if x > -100 else 0.0,
    "identity": lambda x: x,
    "gaussian": lambda x: math.exp(-2.5 * x * x),
    "bipolar_sigmoid": lambda x: 2.0 / (1.0 + math.exp(-4.9 * x)) - 1.0 if x > -100 else -1.0,
    "abs": abs,
    "sine": math.sin,
    "tanh": math.tanh,
}


def apply(act_id: jax.Array, x: jax.Array, options: tuple[str, ...]) -> jax.Array:
    """``options[act_id](x)`` elementwise; ``act_id`` broadcasts against ``x``."""
    if len(options) == 1:
        return ACTIVATIONS[options[0]](x)
    out = ACTIVATIONS[options[0]](x)
    for i, name in enumerate(options[1:], start=1):
        out = jnp.where(act_id == i, ACTIVATIONS[name](x), out)
    return out
