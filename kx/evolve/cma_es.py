"""CMA-ES (evosax) on a fixed linear keep-away policy: the standard-optimiser anchor of ``kx.bench learning``.

Hansen's CMA-ES as evosax 0.3.2 implements it, with its default parameters, on the linear policy
:func:`kx.sim.policies.linear_policy` of the paper's 13-input / 3-output layout (42 values: 13 x 3
weights and 3 biases). The set-up is fixed so that the anchor cannot drift: population 50, initial step
size 1.0, mean starting at zero, 60 generations of 30 shared training trials (3000 evaluations of 30
trials: the budget of the paper's source run, 150 genomes x 20 generations). Each generation draws its
trials from the run's training stream (:mod:`kx.evolve.streams`), like a NEAT run of the same seed. The
champion is the distribution mean after the last generation.

evosax is an optional dependency (``pip install -e '.[bench]'``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from kx.evolve import streams
from kx.sim import env, observe, policies
from kx.sim import evaluate as ev
from kx.sim.types import KeepAwayConfig, KeepAwayParams


@dataclasses.dataclass(frozen=True)
class CMAESSetup:
    population_size: int = 50
    generations: int = 60
    trials: int = 30
    sigma: float = 1.0
    layout: str = "fixed"


def run(seed: int, sim: KeepAwayConfig, sim_params: KeepAwayParams, setup: CMAESSetup = CMAESSetup(),
        log=None) -> tuple[jax.Array, list[dict]]:
    """One CMA-ES run; returns the final distribution mean ``[n_params]`` and one row per generation
    (best and mean training fitness, step size)."""
    try:
        from evosax.algorithms import CMA_ES
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise SystemExit("CMA-ES needs evosax: pip install -e '.[bench]'") from e
    n_in, n_out = observe.n_inputs(setup.layout, sim), observe.n_outputs(setup.layout, sim)
    dim = n_in * n_out + n_out
    es = CMA_ES(population_size=setup.population_size, solution=jnp.zeros(dim))
    params = es.default_params.replace(std_init=jnp.asarray(setup.sigma))
    state = es.init(streams.learner_init(seed), jnp.zeros(dim), params)
    policy = policies.linear_policy(sim, setup.layout)
    rows = []
    for g in range(setup.generations):
        k_ask, k_tell = jax.random.split(streams.learner_step(seed, g))
        population, state = es.ask(k_ask, state, params)
        keys = streams.training(seed, g)
        starts = env.reset_batch(keys.starts, setup.trials, sim_params, sim)
        stats = ev.evaluate(policy, policies.linear_params(population, sim, setup.layout), starts, sim_params, sim,
                            key=keys.eval)
        fitness = stats.fitness.mean(axis=1)
        state, _ = es.tell(k_tell, population, -fitness, state, params)  # evosax minimises
        rows.append({"generation": g, "best_fitness": float(fitness.max()), "mean_fitness": float(fitness.mean()),
                     "sigma": float(state.std)})
        if log is not None:
            log(rows[-1])
    return state.mean, rows


def fitness_on(mean: jax.Array, starts, keys_eval: jax.Array, sim: KeepAwayConfig, sim_params: KeepAwayParams,
               layout: str = "fixed") -> np.ndarray:
    """Per-trial fitness ``[T]`` of the linear policy ``mean`` on ``starts``."""
    stats = ev.evaluate(policies.linear_policy(sim, layout), policies.linear_params(mean[None], sim, layout),
                        starts, sim_params, sim, key=keys_eval)
    return np.asarray(stats.fitness)[0]
