"""Every random stream of a run, in one place: which key feeds what, so that no two uses share keys.

A run with seed ``s`` derives everything from its *run key* ``root = jax.random.key(s)``, which the run
state carries (:func:`run_key`: its raw ``uint32[2]`` data, ``RunState.key``), so that the runs of a
batched group (:mod:`kx.evolve.group`) are one pytree with a leading run axis and derive their keys
under ``vmap``. Every function below takes the seed (an ``int``) or the run key::

    stream = fold_in(root, STREAM)                    STREAM: TRAIN 1, VALIDATION 2, TEST 3, LEARNER 4
    TRAIN:       k = fold_in(stream, generation)      the generation's shared trials
    VALIDATION:  k = fold_in(stream, 0)               the same validation states every generation
    TEST:        k = fold_in(stream, 0)               final reports only (kx.evaluate, kx.bench learning)
                 then starts = fold_in(k, 0) (start states: env.reset_batch splits it per trial)
                      eval   = fold_in(k, 1) (the evaluator's key, from which kx.sim.evaluate derives)
                           evaluator noise = fold_in(eval, 0): trial i's kick-noise word is
                                             bits(fold_in(evaluator noise, i)), hashed with the iteration
                           policy noise    = fold_in(eval, 1): lane l's key at iteration t is
                                             fold_in(fold_in(policy noise, l), t) (stochastic policies only)
    LEARNER:     init = fold_in(stream, 0)
                 generation g's tell = fold_in(fold_in(stream, 1), g), its ask = fold_in(fold_in(stream, 2), g)
                 transfer = fold_in(stream, 3) (a transferred run's seeding: mutated copies, new links'
                            weights; it replaces init)

Why ``fold_in`` and distinct indices everywhere: under JAX's default RNG ``split(k, n)[i]`` equals
``fold_in(k, i)``, so a key that is split for one use and folded for another hands the same key to
both (the first kx runs gave the evaluator ``fold_in(k, 1)`` of the key whose ``split`` made the start
states: trial 1's reset key). Here every key has one derivation path, and the start states of the
three sets of trials come from three different streams, so training, validation and test states are
disjoint draws (the tests check that no validation or test state equals a training state). Below a
key handed to its user (a learner's ``tell``, ``env.reset_batch``), that user may split it as it likes:
its keys stay in its own subtree. The same table, with the users of each key, is in docs/architecture.md.
"""

from __future__ import annotations

import jax
import numpy as np

TRAIN, VALIDATION, TEST, LEARNER = 1, 2, 3, 4


class Trials(tuple):
    """``(starts_key, eval_key)`` of one set of trials."""

    @property
    def starts(self) -> jax.Array:
        return self[0]

    @property
    def eval(self) -> jax.Array:
        return self[1]


def run_key(seed: int) -> jax.Array:
    """The run key of seed ``seed`` as the run state carries it: the raw data (``uint32[2]`` under the
    default threefry keys) of ``jax.random.key(seed)``."""
    return jax.random.key_data(jax.random.key(seed))


def _root(run) -> jax.Array:
    """The typed root key of ``run``: a seed (an int), a typed key, or a run key's raw data."""
    if isinstance(run, (int, np.integer)):
        return jax.random.key(run)
    if jax.dtypes.issubdtype(run.dtype, jax.dtypes.prng_key):
        return run
    return jax.random.wrap_key_data(run)


def _stream(seed, stream: int) -> jax.Array:
    return jax.random.fold_in(_root(seed), stream)


def _trials(k: jax.Array) -> Trials:
    return Trials((jax.random.fold_in(k, 0), jax.random.fold_in(k, 1)))


def training(seed: int, generation: int) -> Trials:
    """The keys of generation ``generation``'s training trials (every genome meets the same ones)."""
    return _trials(jax.random.fold_in(_stream(seed, TRAIN), generation))


def validation(seed: int) -> Trials:
    """The keys of the run's validation trials (the same every generation)."""
    return _trials(jax.random.fold_in(_stream(seed, VALIDATION), 0))


def test(seed: int) -> Trials:
    """The keys of the test trials of seed ``seed``: for final reports only, never for selection."""
    return _trials(jax.random.fold_in(_stream(seed, TEST), 0))


def learner_init(seed: int) -> jax.Array:
    return jax.random.fold_in(_stream(seed, LEARNER), 0)


def learner_step(seed: int, generation: int) -> jax.Array:
    return jax.random.fold_in(jax.random.fold_in(_stream(seed, LEARNER), 1), generation)


def learner_ask(seed: int, generation: int) -> jax.Array:
    """The key of generation ``generation``'s ``ask`` (CMA-ES samples its population with it)."""
    return jax.random.fold_in(jax.random.fold_in(_stream(seed, LEARNER), 2), generation)


def transfer(seed: int) -> jax.Array:
    """The key of a transferred run's seeding (kx.evolve.transfer), used in the place of ``learner_init``."""
    return jax.random.fold_in(_stream(seed, LEARNER), 3)
