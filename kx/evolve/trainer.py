"""The objects of a run and its generation step, the one there is: R runs of one config, R >= 1.

Over 450 lines because the generation step (ask, evaluate, score, validate, tell) is one compiled piece for a run
alone and for a group; split, one program would read from two files.

A :class:`Trainer` holds one run's objects (its validated config, encoding and objective, validation
states and transfer source); no files. A :class:`RunGroup` holds R trainers whose configs are equal but for
:data:`VARYING` (the seed, and a transferred run's source). Their run states are one pytree with a leading
run axis (each carries its run key, ``RunState.key``, from which every one of its random streams derives),
and a generation of all R is::

    population, learner = over_runs(encoding.ask)(keys_ask, state.learner)               # [R, P, ...]
    stats   = evaluate(policy, params(population) [R*P], starts [.., R*T], keys [R])  # [R, P, T]
    fitness, behaviour = trial_means(stats)                                           # each run's own slice
    # (the objective may read another behaviour from the trials' statistics: objective.behaviour_of)
    score, objective = over_runs(objective.score)(fitness [R, P], behaviour [R, 3, P], state.objective)
    learner = over_runs(encoding.tell)(keys_tell, population, score, fitness, learner)
    validation = evaluate(policy, params(champions) [R], validation starts [.., R*Tv], keys [R])

then the champion bookkeeping and one metrics row per run (:func:`generation_row`). A run alone is a group
of one (:meth:`Trainer.step`): ``kx.train``, ``kx.train --seeds``, the protocol and the sweeps all step
through :meth:`RunGroup.step`. The evaluator (:func:`kx.sim.evaluate.evaluate` with R keys) plays every
run's policies on that run's own start states with that run's own noise; the lanes of different runs never
interact. So each run of a group computes, bit for bit, what it computes alone: the same fitness,
champions, checkpoints and metrics rows, but for the figures of how the generation was executed
(:data:`kx.evolve.outputs.EXECUTION_FIELDS`: the timings, and the live share of the lane-steps, which
depends on the whole batch). The tests check it for every method, the novelty hybrid and transfer.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np

from kx.evolve import checkpoint as ckpt
from kx.evolve import config as cfg_lib
from kx.evolve import outputs, streams, transfer
from kx.evolve.checkpoint import RunState
from kx.evolve.encoding import Encoding, stack
from kx.evolve.errors import ConfigError, RunError
from kx.sim import env
from kx.sim import evaluate as ev
from kx.sim.policies import BASELINES

__all__ = ["Trainer", "RunGroup", "GenerationResult", "generation_row", "check_group", "over_runs",
           "stack_states", "run_state", "trial_means", "VARYING", "CPU_TABLE_BYTES"]


@dataclasses.dataclass
class GenerationResult:
    row: dict
    state: RunState


class Trainer:
    """The objects of one experiment and its generation step (no files; :func:`train` adds them)."""

    def __init__(self, cfg: ml_collections.ConfigDict):
        self.cfg = cfg
        self.exp = cfg_lib.validate(cfg)
        self.encoding = self.exp.encoding
        self.objective = self.exp.objective
        self.fields = outputs.csv_fields(self.encoding, self.objective)
        keys = streams.validation(cfg.seed)
        self.validation_eval_key = keys.eval
        self.validation_starts = env.reset_batch(keys.starts, cfg.validation_trials, self.exp.sim_params, self.exp.sim)
        self.source = None  # the transfer source, once attach_source has restored it
        self._alone = None  # the group of this run alone, whose step is this run's (built on first use)

    def evaluate(self, population, starts, key, counters=None):
        """Every individual of ``population`` on ``starts`` (:class:`~kx.sim.types.EpisodeStats` [P, T])."""
        return ev.evaluate(self.encoding.policy, self.encoding.policy_params(population), starts,
                           self.exp.sim_params, self.exp.sim, key=key, counters=counters)

    def validate(self, genotype) -> float:
        """Mean fitness of one genotype on the validation states."""
        stats = self.evaluate(stack([genotype]), self.validation_starts, self.validation_eval_key)
        return float(stats.fitness.mean())

    def validation_baselines(self) -> dict:
        """The hand-coded policies' mean fitness on the validation states."""
        out = {}
        for name, make in BASELINES.items():
            stats = ev.evaluate(make(self.exp.sim), None, self.validation_starts, self.exp.sim_params, self.exp.sim,
                                key=self.validation_eval_key)
            out[name] = float(stats.fitness.mean())
        return out

    @property
    def transfers(self) -> bool:
        """Whether the run is seeded from another run's checkpoint (``transfer.source``)."""
        return bool(self.cfg.transfer.source)

    def attach_source(self, pinned: dict | None = None):
        """Restores and checks the transfer source (:func:`kx.evolve.transfer.load`; ``ConfigError``
        with the reason if it cannot seed this run). Returns it, or ``None`` with no transfer.
        ``pinned``: a resumed run's record of its source, which names the source instead of
        ``transfer.source`` and ``transfer.step`` (``RunError`` if the source no longer matches it)."""
        if self.transfers and self.source is None:
            self.source = transfer.load(self.cfg, self, pinned, make_trainer=Trainer)
        return self.source

    def init(self) -> RunState:
        """The run state before generation 0: a fresh learner, or one seeded from the transfer source."""
        if not self.transfers:
            return self._init()
        learner = transfer.seed(self, self.attach_source(), streams.transfer(self.cfg.seed))
        return self._init(learner)

    def _init(self, learner=None) -> RunState:
        seed = self.cfg.seed
        if learner is None:
            learner = self.encoding.init(streams.learner_init(seed))
        return RunState(learner=learner, objective=self.objective.init(self.cfg.population_size),
                        # a placeholder until generation 1
                        champion=self.encoding.placeholder(streams.learner_ask(seed, 0), learner),
                        champion_validation=jnp.asarray(-jnp.inf, jnp.float32),
                        champion_generation=jnp.asarray(-1, jnp.int32), generation=jnp.asarray(0, jnp.int32),
                        best_so_far=jnp.asarray(-jnp.inf, jnp.float32), key=streams.run_key(seed))

    def check(self, state: RunState) -> list[str]:
        """The encoding's invariants of a restored run state."""
        champion = state.champion if int(state.champion_generation) >= 0 else None
        return self.encoding.check(state.learner, champion)

    def key_problem(self, state: RunState) -> str | None:
        """What is wrong with a restored state's run key (``None``: it is this config's seed's)."""
        want = np.asarray(streams.run_key(self.cfg.seed))
        if not np.array_equal(np.asarray(state.key), want):
            return f"its run key is {np.asarray(state.key).tolist()}, seed {self.cfg.seed}'s is {want.tolist()}"
        return None

    def restore(self, run_dir, step: int | None = None):
        """``(step, state, meta)`` of a checkpoint of ``run_dir`` written with this config's method and shapes."""
        return ckpt.restore(run_dir, jax.eval_shape(self._init), self.cfg.method, step, check=self.check)

    def step(self, state: RunState) -> GenerationResult:
        """Evaluate generation ``state.generation``'s population, validate its champion, breed the next
        one: the generation step of a group of one run (:meth:`RunGroup.step`), the only one there is."""
        stacked, rows = self.alone().step(stack_states([state]))
        return GenerationResult(row=rows[0], state=run_state(stacked, 0))

    def alone(self) -> RunGroup:
        """The group of this run alone (built on first use, its programs kept for the run's life)."""
        if self._alone is None:
            self._alone = RunGroup([self])
        return self._alone

def generation_row(g: int, f: np.ndarray, s: np.ndarray, beh: np.ndarray, champ: int, validation: float,
                   state: RunState, enc_metrics: dict, obj_metrics: dict) -> dict:
    """Generation ``g``'s metrics row but its execution figures (:data:`kx.evolve.outputs.EXECUTION_FIELDS` and
    ``live_steps``): training fitness ``f [P]``, selection score ``s [P]``, behaviour ``beh [3, P]``, the
    generation champion ``champ`` and its ``validation`` score, the run ``state`` after the generation,
    the encoding's and the objective's metrics."""
    row = {
        "generation": g, "best_fitness": float(f[champ]),
        # float32 rounding can put the mean of equal values a hair above them: clip to where it lies
        "mean_fitness": float(np.clip(f.mean(), f.min(), f.max())), "median_fitness": float(np.median(f)),
        "best_so_far": float(state.best_so_far), "best_score": float(s.max()), "mean_score": float(s.mean()),
        "mean_passes": float(beh[0].mean()), "mean_dispersion": float(beh[1].mean()),
        "mean_ball_centre": float(beh[2].mean()), "behaviour_spread": behaviour_spread(beh),
        "champion_passes": float(beh[0, champ]),
        "champion_validation": validation, "best_validation": float(state.champion_validation),
        "best_validation_generation": int(state.champion_generation),
    }
    for k, v in enc_metrics.items():
        row[k] = _scalar(v)
    for k, v in obj_metrics.items():
        row[k] = _scalar(v)
    return row


def behaviour_spread(beh: np.ndarray) -> float:
    """How far apart a population's behaviours lie (``beh [3, P]``, each genome's trial means of the world's
    behaviour: passes, dispersion, ball distance from the centre, each in [0, 1]): the mean Euclidean
    distance of a genome's behaviour to the population's mean behaviour (0: every genome behaves alike)."""
    b = np.asarray(beh, np.float64)
    return float(np.sqrt(((b - b.mean(axis=1, keepdims=True)) ** 2).sum(axis=0)).mean())


def _scalar(v):
    a = np.asarray(v)
    return int(a) if np.issubdtype(a.dtype, np.integer) or a.dtype == bool else float(a)




#: the config fields in which the runs of a group may differ
VARYING = ("seed", "transfer.source")

#: On a CPU, a group plays its runs' episodes in evaluator calls whose shared policy tables together
#: hold at most this many bytes (at least one run a call; any number on other platforms). HyperNEAT's
#: substrates are 96 MB a run in 3v2 (150 x 400 x 400 float32), read at random: measured on real
#: populations of 8 runs at generation 50 of the protocol's 4v3 cell (2026-12-02, 2 cores), 8 runs a
#: call 128 s, 4 a call 117 s, one a call 84 s for the same 26M live steps; at generation 10 of 3v2
#: (short episodes) one call and eight took the same 4.5 s. The budget is this machine's L3 cache.
#: Measured again with the BEV decision that reads each lane's weights inside its chains (2026-12-03,
#: scripts/hyperneat_runs_per_call.py at 4030abb: a population replicated over R runs, each with its own start
#: states; the same episodes either way, the NEAT protocol paused): a population 5 generations
#: into 4v3, one call against one per run, R = 4 1.23x faster, R = 8 1.10x, R = 16 0.88x; a population 50
#: generations into 4v3 (longer episodes), R = 4 0.91x (samples 0.75-1.08). Kept: no setting wins at both.
CPU_TABLE_BYTES = 32 * 2**20


def check_group(cfgs: Sequence[ml_collections.ConfigDict]) -> None:
    """The configs of one group: at least one, equal in every field but :data:`VARYING`, distinct seeds
    (``ConfigError`` naming the first field that differs)."""
    if not cfgs:
        raise ConfigError("seeds: a group needs at least one run")
    first = cfg_lib.flatten(cfgs[0].to_dict())
    for c in cfgs[1:]:
        other = cfg_lib.flatten(c.to_dict())
        for field in sorted(set(first) | set(other)):
            if field not in VARYING and first.get(field) != other.get(field):
                raise ConfigError(f"{field}: the runs of a batched group share every config field but "
                                  f"{', '.join(VARYING)}; it is {first.get(field)!r} in seed {cfgs[0].seed}'s run and "
                                  f"{other.get(field)!r} in seed {c.seed}'s")
    seeds = [c.seed for c in cfgs]
    repeated = sorted({s for s in seeds if seeds.count(s) > 1})
    if repeated:
        raise ConfigError(f"seeds: each run of a group needs its own seed; {repeated} repeated in {seeds}")


def over_runs(fn: Callable, vectorised: bool = True) -> Callable:
    """``fn`` mapped over a leading run axis of every argument: ``jax.vmap``; or, where batched arithmetic
    is not bit for bit the unbatched one (``Encoding.vmap_exact``, ``Objective.vmap_exact``), ``fn``'s own
    program called on each run in turn, its outputs stacked. Measured: CMA-ES's ask and tell (vmapped, and
    even under ``jax.lax.map``, evosax's covariance update rounds differently in the last bit: the step
    size after the second generation 0.93809110 alone, 0.93809104 batched), HyperNEAT's substrate query
    (10 runs x 150) and the novelty hybrid's k-NN (10 x 50, 16 x 150); a run's trajectory then drifts."""
    def each(*args):
        n = jax.tree.leaves(args)[0].shape[0]
        if vectorised and n > 1:
            return jax.vmap(fn)(*args)
        return stack_states([fn(*run_state(args, r)) for r in range(n)])

    return each


# The host loop's operations on whole pytrees, each one compiled program rather than an eager operation
# per leaf (every eager operation of a new shape is a program of its own, and each program holds memory
# maps of the process: kx.runtime). Moving and stacking are exact, so compiled or eager they are the same.
_stack = jax.jit(lambda trees: jax.tree.map(lambda *a: jnp.stack(a), *trees))
_take = jax.jit(lambda tree, r: jax.tree.map(lambda a: a[r], tree))
_concat_lanes = jax.jit(lambda trees: jax.tree.map(lambda *a: jnp.concatenate(a, axis=-1), *trees))


def stack_states(states: Sequence[RunState]) -> RunState:
    """R run states (or any pytrees of one structure) as one with a leading run axis."""
    return _stack(list(states))


def run_state(states: RunState, r: int) -> RunState:
    """Run ``r``'s state of stacked ``states`` (host arrays stay host arrays)."""
    leaves = jax.tree.leaves(states)
    if all(isinstance(a, np.ndarray) for a in leaves):
        return jax.tree.map(lambda a: a[r], states)
    return _take(states, np.int32(r))


def _concat_states(batches):
    """Start states ``[.., T]`` of several runs side by side: ``[.., R*T]``."""
    return batches[0] if len(batches) == 1 else _concat_lanes(list(batches))


_take_runs = jax.jit(lambda tree, runs: jax.tree.map(lambda a: a[runs], tree))


@functools.partial(jax.jit, static_argnames=("trials",))
def _take_trials(starts, runs, *, trials):
    """The start states ``[.., R * trials]`` of runs ``runs``: ``[.., len(runs) * trials]``."""
    cols = (runs[:, None] * trials + jnp.arange(trials, dtype=jnp.int32)[None]).reshape(-1)
    return jax.tree.map(lambda a: jnp.take(a, cols, axis=-1), starts)


def _concat_runs(results):
    """:class:`EpisodeStats` of several calls' runs (each ``[r, P, T]``, ``behaviour`` ``[3, r, P, T]``), one
    after another."""
    run_axis = lambda f: 1 if f == "behaviour" else 0  # noqa: E731
    return type(results[0])(**{f: jnp.concatenate([getattr(p, f) for p in results], axis=run_axis(f))
                               for f in results[0].__dataclass_fields__})


@jax.jit
def _reorder_runs(stats, order):
    """:class:`EpisodeStats` ``[R, P, T]`` (``behaviour`` ``[3, R, P, T]``) with its runs in ``order``."""
    return type(stats)(**{f: jnp.take(getattr(stats, f), order, axis=1 if f == "behaviour" else 0)
                          for f in stats.__dataclass_fields__})


@functools.partial(jax.jit, static_argnames=("runs", "trials"))
def _runs_slice(params, starts, first, *, runs, trials):
    """Runs ``first .. first + runs - 1`` of a group's policy parameters ``[R, P, ...]``, as the evaluator
    takes them (``[runs * P, ...]``), and of its start states ``[.., R * trials]``."""
    def rows(a, axis, size):
        return a if a.shape[axis] == size else jax.lax.dynamic_slice_in_dim(a, first * (size // runs), size, axis)

    params = jax.tree.map(lambda a: rows(a, 0, runs), params)
    params = jax.tree.map(lambda a: a.reshape((a.shape[0] * a.shape[1],) + a.shape[2:]), params)
    return params, jax.tree.map(lambda a: rows(a, a.ndim - 1, runs * trials), starts)


def _champions(encoding, population, index):
    """Each run's genotype ``index[r]`` of its population ``[R, P, ...]``: ``[R, ...]``, and the same as
    populations of one ``[R, 1, ...]`` for the evaluator. One compiled program for the encodings that
    keep :meth:`kx.evolve.encoding.Encoding.individual` (every leaf's row)."""
    if type(encoding).individual is Encoding.individual:
        return _rows_of(population, index)
    champions = jax.vmap(encoding.individual)(population, index)
    return champions, jax.tree.map(lambda a: a[:, None], champions)


@jax.jit
def _rows_of(population, index):
    champions = jax.tree.map(lambda a: jax.vmap(lambda x, i: x[i])(a, index), population)
    return champions, jax.tree.map(lambda a: a[:, None], champions)


@jax.jit
def _bookkeeping(state: RunState, learner, objective, g, best, champions, validation, better) -> RunState:
    """The run states after generation ``g``: learner and objective state, the best training fitness so
    far (``best [R]``), and the validated champion, replaced by the generation's where its validation
    score is strictly better (``better [R]``: the earliest champion wins ties)."""
    n = better.shape[0]
    pick = lambda new, old: jnp.where(better.reshape((n,) + (1,) * (old.ndim - 1)), new, old)  # noqa: E731
    return state.replace(
        learner=learner, objective=objective, generation=jnp.full((n,), g + 1, jnp.int32),
        best_so_far=jnp.maximum(state.best_so_far, best),
        champion=jax.tree.map(pick, champions, state.champion),
        champion_validation=pick(validation, state.champion_validation),
        champion_generation=pick(jnp.full((n,), g, jnp.int32), state.champion_generation))


def trial_means(stats, behaviour=None) -> tuple[jax.Array, jax.Array]:
    """Each run's mean fitness ``[R, P]`` and behaviour ``[R, 3, P]`` over its trials, from a grouped
    evaluation's :class:`~kx.sim.types.EpisodeStats` ``[R, P, T]`` (``behaviour``: other rows ``[3, R, P,
    T]`` than its own, an objective's reading), by the run loop's own operations on
    each run's own ``[P, T]`` slice. The mean over the last axis of the whole ``[R, P, T]`` rounds
    differently in the last bit for some shapes (10 x 50 x 30, CMA-ES's population: 296 of 500 means on
    random values; none at NEAT's 150), and a run's trajectory then drifts from the run's alone."""
    n = stats.fitness.shape[0]
    behaviour = stats.behaviour if behaviour is None else behaviour
    return (jnp.stack([stats.fitness[r].mean(axis=1) for r in range(n)]),
            jnp.stack([behaviour[:, r].mean(axis=2) for r in range(n)]))


class RunGroup:
    """The objects of R runs of one config and their generation step, the one there is: a run alone is a
    group of one (:meth:`Trainer.step`). No files (:func:`kx.evolve.run.train` and
    :func:`kx.evolve.group.train_group` add them). ``trainers``: one :class:`Trainer` per run (each holds
    its run's validation states and, for a transferred run, its source)."""

    def __init__(self, trainers: Sequence[Trainer]):
        self.trainers = list(trainers)
        check_group([t.cfg for t in self.trainers])
        first = self.trainers[0]
        self.cfg, self.exp = first.cfg, first.exp
        self.encoding, self.objective = first.encoding, first.objective
        self.seeds = [t.cfg.seed for t in self.trainers]
        self.validation_starts = _concat_states([t.validation_starts for t in self.trainers])
        self.validation_keys = jnp.stack([t.validation_eval_key for t in self.trainers])
        enc = self.encoding
        self._ask = over_runs(enc.ask, "ask" in enc.vmap_exact)
        self._tell = over_runs(enc.tell, "tell" in enc.vmap_exact)
        self._score = over_runs(self.objective.score, self.objective.vmap_exact)
        self.calls_note = None  # how the last generation's episodes were dealt into evaluator calls, and why
        self._policy_params = (enc.policy_params if enc.policy_params_leading_axes
                               else over_runs(enc.policy_params, "policy_params" in enc.vmap_exact))

    @classmethod
    def from_configs(cls, cfgs: Sequence[ml_collections.ConfigDict]) -> RunGroup:
        check_group(cfgs)  # before any trainer is built
        return cls([Trainer(c) for c in cfgs])

    def __len__(self) -> int:
        return len(self.trainers)

    def init(self) -> RunState:
        """Every run's state before generation 0 (fresh, or seeded from its transfer source), stacked."""
        return stack_states([t.init() for t in self.trainers])

    def runs_per_call(self, params) -> int:
        """How many runs' episodes one evaluator call plays, for policy parameters ``params`` (``[k, P,
        ...]``, k runs): all of them, but on a CPU only as many as keep a shared table within
        :data:`CPU_TABLE_BYTES`."""
        n = jax.tree.leaves(params)[0].shape[0]
        return self._runs_per_call(n, sum(a.nbytes for a in jax.tree.leaves(params)) // n)

    def _runs_per_call(self, n: int, per_run: int) -> int:
        """:meth:`runs_per_call` of ``n`` runs whose policy parameters take ``per_run`` bytes a run."""
        if not self.encoding.policy.shared or jax.devices()[0].platform != "cpu":
            self.calls_note = f"every run's episodes in one evaluator call ({n} runs)"
            return n
        c = int(min(n, max(1, CPU_TABLE_BYTES // max(per_run, 1))))
        if c == n:
            self.calls_note = (f"every run's episodes in one evaluator call ({n} runs; their shared policy tables, "
                               f"{per_run / 2**20:.1f} MB a run, fit a CPU call's {CPU_TABLE_BYTES / 2**20:.0f} MB)")
            return c
        self.calls_note = (f"{c} of the {n} runs' episodes per evaluator call: on a CPU a call's shared policy "
                           f"tables stay within {CPU_TABLE_BYTES / 2**20:.0f} MB (this method's are "
                           f"{per_run / 2**20:.1f} MB a run; more runs a call read them at random from memory and "
                           "ran slower than one by one)")
        return c

    def _param_parts(self, population) -> list[tuple[np.ndarray, object]]:
        """The runs' policy parameters, as ``(runs, params [len(runs), P, ...])`` parts: one part of every
        run, or for an encoding whose parameters' shape follows its genotypes
        (:meth:`kx.evolve.encoding.Encoding.policy_shape`, NEAT's hidden rows) one part per shape, so that
        each run plays the shape it plays alone (a group's largest made its runs' steps dearer)."""
        n, enc = len(self), self.encoding
        everyone = np.arange(n)
        shapes = enc.policy_shape(population) if enc.policy_params_leading_axes else None
        if shapes is None or len(set(shapes.tolist())) == 1:
            return [(everyone, self._policy_params(population))]
        parts = []
        for key in sorted(set(shapes.tolist())):
            runs = np.flatnonzero(shapes == key)
            parts.append((runs, enc.policy_params(_take_runs(population, runs.astype(np.int32)))))
        return parts

    def _builds_run_by_run(self) -> bool:
        """Whether the encoding's shared table is built run by run anyway (not vmapped over runs): then a call
        that plays one run (:meth:`runs_per_call`) gets its run's table as the build left it (its rows split
        over the devices where the build did so: :func:`kx.sim.lanes.rows_split`), not first stacked with the
        others' and sliced again (two copies of 96 MB a run for HyperNEAT's 150 CPPNs)."""
        enc = self.encoding
        return enc.policy.shared and not enc.policy_params_leading_axes and "policy_params" not in enc.vmap_exact

    def evaluate(self, population, starts, keys, counters=None):
        """Run ``r``'s individuals of ``population`` (``[R, P, ...]``) on its start states ``starts[..., r*T:
        (r+1)*T]`` with its key ``keys[r]`` (:class:`EpisodeStats` [R, P, T]): every run in one evaluator
        call, or in calls of :meth:`runs_per_call` runs of one part of :meth:`_param_parts` (each run's
        episodes are the same either way: lanes never interact); a shared table built run by run
        (:meth:`_builds_run_by_run`) and played one run a call goes to its call as it was built."""
        n = len(self)
        n_trials = starts.holder.shape[-1] // n
        order, results = [], []
        parts = None
        if self._builds_run_by_run():
            enc = self.encoding
            first = enc.policy_params(_take(population, 0))
            if self._runs_per_call(n, sum(a.nbytes for a in jax.tree.leaves(first))) == 1:
                for r in range(n):
                    run_starts = starts if n == 1 else _take_trials(starts, np.array([r], np.int32), trials=n_trials)
                    params = first if r == 0 else enc.policy_params(_take(population, r))
                    results.append(ev.evaluate(enc.policy, params, run_starts, self.exp.sim_params, self.exp.sim,
                                               key=keys[r:r + 1], counters=counters))
                return results[0] if n == 1 else _concat_runs(results)
            # what over_runs gives, run 0's table not built twice
            parts = [(np.arange(n), stack_states([first] + [enc.policy_params(_take(population, r))
                                                            for r in range(1, n)]))]
        for runs, params in parts or self._param_parts(population):
            if len(runs) < n:  # the part's runs' start states and keys
                part_starts = _take_trials(starts, runs.astype(np.int32), trials=n_trials)
                part_keys = keys[runs]
            else:
                part_starts, part_keys = starts, keys
            c = self.runs_per_call(params)
            for i in range(0, len(runs), c):
                results.append(ev.evaluate(self.encoding.policy, *_runs_slice(params, part_starts, np.int32(i), runs=c,
                                                                              trials=n_trials),
                                           self.exp.sim_params, self.exp.sim, key=part_keys[i:i + c],
                                           counters=counters))
            order.extend(runs.tolist())
        if len(results) == 1:
            return results[0]
        stats = _concat_runs(results)
        if order == list(range(n)):
            return stats
        back = np.argsort(np.asarray(order)).astype(np.int32)  # the runs in their own order again
        return _reorder_runs(stats, back)

    def validate(self, champions) -> np.ndarray:
        """Each run's genotype of ``champions`` (populations of one, ``[R, 1, ...]``) on that run's validation
        states: ``[R]`` mean fitness (float64 of the float32 mean, as :meth:`Trainer.validate` gives it)."""
        note = self.calls_note  # the note tells how the generation's episodes were played, not the champions'
        stats = self.evaluate(champions, self.validation_starts, self.validation_keys)
        self.calls_note = note
        return np.array([float(stats.fitness[r].mean()) for r in range(len(self))])

    def step(self, state: RunState) -> tuple[RunState, list[dict]]:
        """Generation ``g`` of every run (``state.generation`` must be ``g`` for all): the stacked state
        after it and each run's metrics row. Each run computes, bit for bit, what it computes alone (a
        group of one): ``ask``, ``tell`` and the objective are vmapped only where that is exact
        (:func:`over_runs`), each run's means are taken on its own slice (:func:`trial_means`), and the
        evaluator plays each run on its own start states with its own keys."""
        enc, cfg, n = self.encoding, self.cfg, len(self)
        gens = np.asarray(state.generation)
        if (gens != gens[0]).any():
            raise RunError(f"a batched group steps its runs in lockstep; they are after generations {gens.tolist()}")
        g = int(gens[0])
        t0 = time.perf_counter()
        trials = [streams.training(state.key[r], g) for r in range(n)]
        starts = _concat_states([env.reset_batch(t.starts, cfg.trials, self.exp.sim_params, self.exp.sim)
                                 for t in trials])
        population, learner = self._ask(jax.vmap(lambda k: streams.learner_ask(k, g))(state.key), state.learner)
        counters = ev.EvalCounters()
        stats = self.evaluate(population, starts, jnp.stack([t.eval for t in trials]), counters)
        fitness, behaviour = trial_means(stats)  # [R, P], [R, 3, P]
        own = self.objective.behaviour_of(stats)  # the objective's reading of the behaviour (None: the world's)
        selected = behaviour if own is None else trial_means(stats, own)[1]
        score, objective, obj_metrics = self._score(fitness, selected, state.objective)
        jax.block_until_ready((fitness, score))
        t1 = time.perf_counter()
        learner, m = self._tell(jax.vmap(lambda k: streams.learner_step(k, g))(state.key), population, score,
                                fitness, learner)
        jax.block_until_ready(learner)
        t2 = time.perf_counter()
        f = np.asarray(fitness)
        champs = f.argmax(axis=1)  # the first of equals in each run
        champions, as_populations = _champions(self.encoding, population, np.asarray(champs, np.int32))
        validation = self.validate(as_populations)
        best = f[np.arange(n), champs]
        better = validation > np.asarray(state.champion_validation, np.float64)  # strictly: earliest wins ties
        state = _bookkeeping(state, learner, objective, np.int32(g), best.astype(np.float32), champions,
                             validation.astype(np.float32), better)
        t3 = time.perf_counter()
        host = jax.device_get((state.best_so_far, state.champion_validation, state.champion_generation, score,
                               behaviour, m, obj_metrics, stats.iterations))
        best_so_far, champ_val, champ_gen, s, beh, m, obj_metrics, iterations = host
        rows = []
        for r in range(n):
            view = RunState(learner=None, objective=None, champion=None, champion_validation=champ_val[r],
                            champion_generation=champ_gen[r], generation=None, best_so_far=best_so_far[r], key=None)
            row = generation_row(g, f[r], s[r], beh[r], int(champs[r]), float(validation[r]), view,
                                         {k: m[k][r] for k in enc.metric_fields},
                                         {k: v[r] for k, v in obj_metrics.items()})
            row.update(live_fraction=counters.live_steps / max(counters.executed_steps, 1),
                       live_steps=int(iterations[r].sum()), eval_seconds=t1 - t0, evolve_seconds=t2 - t1,
                       validation_seconds=t3 - t2, generation_seconds=t3 - t0)
            rows.append(row)
        return state, rows


