"""``Encoding.vmap_exact`` and ``Objective.vmap_exact`` at real sizes: what a batched group vmaps over its
runs (kx.evolve.trainer.over_runs) must be, bit for bit, each run's own call. Rounding differences showed
only at real sizes (10 runs x 150, 50 x 30), never at the 3 runs x 12 genomes of the other tests, so these
run 16 runs of the shipped configs' populations (150 genomes; CMA-ES 50): slow tests."""

import jax
import numpy as np
import pytest

from kx.evolve import config as cfg_lib
from kx.evolve import streams
from kx.evolve.trainer import RunGroup, run_state, stack_states

RUNS = 16


def _group(config: str, *extra) -> RunGroup:
    return RunGroup.from_configs([cfg_lib.load(f"configs/{config}", ["gif=false", f"seed={s}", *extra])
                                  for s in range(RUNS)])


def _equal(a, b, what):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        x, y = np.asarray(jax.random.key_data(x) if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key) else x), \
            np.asarray(jax.random.key_data(y) if jax.dtypes.issubdtype(y.dtype, jax.dtypes.prng_key) else y)
        np.testing.assert_array_equal(x, y, err_msg=what)


def _each(fn, *args):
    return stack_states([fn(*run_state(args, r)) for r in range(RUNS)])


@pytest.mark.slow
@pytest.mark.parametrize("config", ["neat_3v2.py", "hyperneat_3v2.py", "cma_es_3v2.py"])
def test_what_an_encoding_declares_exact_under_vmap_is_at_16_runs_of_its_real_population(config):
    group = _group(config)
    enc = group.encoding
    assert enc.vmap_exact <= {"ask", "tell", "policy_params"}
    state = group.init()
    g = 3  # a generation whose keys are not the first
    ask_keys = jax.vmap(lambda k: streams.learner_ask(k, g))(state.key)
    tell_keys = jax.vmap(lambda k: streams.learner_step(k, g))(state.key)
    population, learner = _each(enc.ask, ask_keys, state.learner)
    if "ask" in enc.vmap_exact:
        _equal(jax.vmap(enc.ask)(ask_keys, state.learner), (population, learner), f"{config}: ask")
    p = jax.tree.leaves(population)[0].shape[1]
    # fitness and scores as a generation gives them: many ties at 0 and a spread of values
    draw = jax.random.uniform(jax.random.key(7), (2, RUNS, p))
    fitness = np.where(np.asarray(draw[0]) < 0.3, 0.0, np.asarray(draw[0] * draw[1])).astype(np.float32)
    score = (fitness + 0.25 * np.asarray(draw[1])).astype(np.float32)
    if "tell" in enc.vmap_exact:
        alone = _each(enc.tell, tell_keys, population, score, fitness, learner)
        _equal(jax.vmap(enc.tell)(tell_keys, population, score, fitness, learner), alone, f"{config}: tell")
    if "policy_params" in enc.vmap_exact and not enc.policy_params_leading_axes:
        _equal(jax.vmap(enc.policy_params)(population), _each(enc.policy_params, population),
               f"{config}: policy_params")
    if enc.policy_params_leading_axes:  # one call for all runs: each run's networks are its own call's
        both = enc.policy_params(population)
        for r in range(RUNS):
            alone = enc.policy_params(run_state(population, r))
            got = run_state(both, r)
            # (a group's networks keep the hidden rows of its run with the most; at generation 0 none has any)
            _equal(got, alone, f"{config}: policy_params of run {r} in one call for all runs")


@pytest.mark.slow
def test_the_fitness_objective_is_exact_under_vmap_at_16_runs_of_150():
    group = _group("neat_3v2.py")
    state = group.init()
    assert group.objective.vmap_exact
    fitness = jax.random.uniform(jax.random.key(1), (RUNS, 150))
    behaviour = jax.random.uniform(jax.random.key(2), (RUNS, 3, 150))
    _equal(jax.vmap(group.objective.score)(fitness, behaviour, state.objective),
           _each(group.objective.score, fitness, behaviour, state.objective), "fitness objective")
