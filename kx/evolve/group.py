"""Many runs as one program: R runs of one config, differing only in seed, advanced in lockstep.

A :class:`RunGroup` holds R runs whose configs are equal but for :data:`VARYING` (the seed, and a
transferred run's source). Their run states are one pytree with a leading run axis (each carries its run
key, ``RunState.key``, from which every one of its random streams derives), and a generation of all R is::

    population, learner = vmap(encoding.ask)(keys_ask, state.learner)                  # [R, P, ...]
    stats   = evaluate(policy, params(population) [R*P], starts [.., R*T], keys [R])  # one call, [R, P, T]
    score, objective = vmap(objective.score)(fitness [R, P], behaviour [R, 3, P], state.objective)
    learner = vmap(encoding.tell)(keys_tell, population, score, fitness, learner)
    validation = evaluate(policy, params(champions) [R], validation starts [.., R*Tv], keys [R])

The evaluator (:func:`kx.sim.evaluate.evaluate` with R keys) plays every run's policies on that run's
own start states with that run's own noise, all R x P x T episodes in one batch that narrows as they
end; the lanes of different runs never interact. So each run computes, bit for bit, what it computes
alone (:class:`kx.evolve.run.Trainer`): the same fitness, champions, checkpoints and metrics rows, but
for the figures of how the generation was executed (:data:`kx.evolve.run.EXECUTION_FIELDS`: the
timings, and the live share of the lane-steps, which depends on the whole batch). The tests check it
for every method, the novelty hybrid and transfer.

:func:`train_group` writes each run's own complete run directory, as :func:`kx.evolve.run.train` writes
it for that seed alone, resumable one by one or as a group (``python -m kx.train --seeds 0-15``).
"""

from __future__ import annotations

import contextlib
import pathlib
import time
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np

from kx.evolve import config as cfg_lib
from kx.evolve import outputs, streams
from kx.evolve import run as run_lib
from kx.evolve.checkpoint import RunLock, RunState
from kx.evolve.errors import ConfigError, RunError
from kx.sim import env
from kx.sim import evaluate as ev

#: the config fields in which the runs of a group may differ
VARYING = ("seed", "transfer.source")

#: On a CPU, a group plays its runs' episodes in evaluator calls whose shared policy tables together
#: hold at most this many bytes (at least one run a call; any number on other platforms). HyperNEAT's
#: substrates are 96 MB a run in 3v2 (150 x 400 x 400 float32), read at random: measured on real
#: populations of 8 runs at generation 50 of the protocol's 4v3 cell (2026-12-02, 2 cores), 8 runs a
#: call 128 s, 4 a call 117 s, one a call 84 s for the same 26M live steps; at generation 10 of 3v2
#: (short episodes) one call and eight took the same 4.5 s. The budget is this machine's L3 cache.
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
    if vectorised:
        return jax.vmap(fn)

    def each(*args):
        n = jax.tree.leaves(args)[0].shape[0]
        outs = [fn(*jax.tree.map(lambda a: a[r], args)) for r in range(n)]
        return jax.tree.map(lambda *o: jnp.stack(o), *outs)

    return each


def stack_states(states: Sequence[RunState]) -> RunState:
    """R run states as one with a leading run axis."""
    return jax.tree.map(lambda *a: jnp.stack(a), *states)


def run_state(states: RunState, r: int) -> RunState:
    """Run ``r``'s state of stacked ``states``."""
    return jax.tree.map(lambda a: a[r], states)


def _concat_states(batches):
    """Start states ``[.., T]`` of several runs side by side: ``[.., R*T]``."""
    return jax.tree.map(lambda *a: jnp.concatenate(a, axis=-1), *batches)


def trial_means(stats) -> tuple[jax.Array, jax.Array]:
    """Each run's mean fitness ``[R, P]`` and behaviour ``[R, 3, P]`` over its trials, from a grouped
    evaluation's :class:`~kx.sim.types.EpisodeStats` ``[R, P, T]``, by the run loop's own operations on
    each run's own ``[P, T]`` slice. The mean over the last axis of the whole ``[R, P, T]`` rounds
    differently in the last bit for some shapes (10 x 50 x 30, CMA-ES's population: 296 of 500 means on
    random values; none at NEAT's 150), and a run's trajectory then drifts from the run's alone."""
    n = stats.fitness.shape[0]
    return (jnp.stack([stats.fitness[r].mean(axis=1) for r in range(n)]),
            jnp.stack([stats.behaviour[:, r].mean(axis=2) for r in range(n)]))


class RunGroup:
    """The objects of R runs of one config and their batched generation step (no files;
    :func:`train_group` adds them). ``trainers``: one :class:`~kx.evolve.run.Trainer` per run (each
    holds its run's validation states and, for a transferred run, its source)."""

    def __init__(self, trainers: Sequence[run_lib.Trainer]):
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
        self._policy_params = (enc.policy_params if enc.policy_params_leading_axes
                               else over_runs(enc.policy_params, "policy_params" in enc.vmap_exact))
        self._individual = jax.vmap(enc.individual)

    @classmethod
    def from_configs(cls, cfgs: Sequence[ml_collections.ConfigDict]) -> RunGroup:
        check_group(cfgs)  # before any trainer is built
        return cls([run_lib.Trainer(c) for c in cfgs])

    def __len__(self) -> int:
        return len(self.trainers)

    def init(self) -> RunState:
        """Every run's state before generation 0 (fresh, or seeded from its transfer source), stacked."""
        return stack_states([t.init() for t in self.trainers])

    def runs_per_call(self, params) -> int:
        """How many runs' episodes one evaluator call plays, for policy parameters ``params`` (``[R, P,
        ...]``): all of them, but on a CPU only as many as keep a shared table within
        :data:`CPU_TABLE_BYTES`."""
        n = len(self)
        if not self.encoding.policy.shared or jax.devices()[0].platform != "cpu":
            return n
        per_run = sum(a.nbytes for a in jax.tree.leaves(params)) // n
        return int(min(n, max(1, CPU_TABLE_BYTES // max(per_run, 1))))

    def evaluate(self, population, starts, keys, counters=None):
        """Run ``r``'s individuals of ``population`` (``[R, P, ...]``) on its start states ``starts[..., r*T:
        (r+1)*T]`` with its key ``keys[r]`` (:class:`EpisodeStats` [R, P, T]): every run in one evaluator
        call, or in calls of :meth:`runs_per_call` runs (each run's episodes are the same either way)."""
        params = self._policy_params(population)
        n, c = len(self), self.runs_per_call(params)
        n_trials = starts.holder.shape[-1] // n
        flat = lambda p: jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), p)  # noqa: E731 [R, P] -> [R*P]
        parts = [ev.evaluate(self.encoding.policy, flat(jax.tree.map(lambda a: a[i:i + c], params)),
                             jax.tree.map(lambda a: a[..., i * n_trials:(i + c) * n_trials], starts),
                             self.exp.sim_params, self.exp.sim, key=keys[i:i + c], counters=counters)
                 for i in range(0, n, c)]
        if len(parts) == 1:
            return parts[0]
        run_axis = lambda f: 1 if f == "behaviour" else 0  # noqa: E731 (behaviour is [3, R, P, T])
        return type(parts[0])(**{f: jnp.concatenate([getattr(p, f) for p in parts], axis=run_axis(f))
                                 for f in parts[0].__dataclass_fields__})

    def validate(self, champions) -> np.ndarray:
        """Each run's genotype of ``champions`` (``[R, ...]``) on that run's validation states: ``[R]`` mean
        fitness (float64 of the float32 mean, as :meth:`kx.evolve.run.Trainer.validate` gives it)."""
        stats = self.evaluate(jax.tree.map(lambda a: a[:, None], champions), self.validation_starts,
                              self.validation_keys)
        return np.array([float(stats.fitness[r].mean()) for r in range(len(self))])

    def step(self, state: RunState) -> tuple[RunState, list[dict]]:
        """Generation ``g`` of every run (``state.generation`` must be ``g`` for all): the stacked state
        after it and each run's metrics row (:meth:`kx.evolve.run.Trainer.step`'s)."""
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
        score, objective, obj_metrics = self._score(fitness, behaviour, state.objective)
        jax.block_until_ready((fitness, score))
        t1 = time.perf_counter()
        learner, m = self._tell(jax.vmap(lambda k: streams.learner_step(k, g))(state.key), population, score,
                                fitness, learner)
        jax.block_until_ready(learner)
        t2 = time.perf_counter()
        f = np.asarray(fitness)
        champs = f.argmax(axis=1)  # the first of equals in each run
        champions = self._individual(population, jnp.asarray(champs, jnp.int32))
        validation = self.validate(champions)
        # the champion bookkeeping of kx.evolve.run.advance, for every run at once
        best = f[np.arange(n), champs]
        better = validation > np.asarray(state.champion_validation, np.float64)  # strictly: earliest wins ties
        pick = lambda new, old: jnp.where(better.reshape((n,) + (1,) * (old.ndim - 1)), new, old)  # noqa: E731
        state = state.replace(
            learner=learner, objective=objective, generation=jnp.full((n,), g + 1, jnp.int32),
            best_so_far=jnp.maximum(state.best_so_far, jnp.asarray(best, jnp.float32)),
            champion=jax.tree.map(pick, champions, state.champion),
            champion_validation=pick(jnp.asarray(validation, jnp.float32), state.champion_validation),
            champion_generation=pick(jnp.full((n,), g, jnp.int32), state.champion_generation))
        t3 = time.perf_counter()
        host = jax.device_get((state.best_so_far, state.champion_validation, state.champion_generation, score,
                               behaviour, m, obj_metrics, stats.iterations))
        best_so_far, champ_val, champ_gen, s, beh, m, obj_metrics, iterations = host
        rows = []
        for r in range(n):
            view = RunState(learner=None, objective=None, champion=None, champion_validation=champ_val[r],
                            champion_generation=champ_gen[r], generation=None, best_so_far=best_so_far[r], key=None)
            row = run_lib.generation_row(g, f[r], s[r], beh[r], int(champs[r]), float(validation[r]), view,
                                         {k: m[k][r] for k in enc.metric_fields},
                                         {k: v[r] for k, v in obj_metrics.items()})
            row.update(live_fraction=counters.live_steps / max(counters.executed_steps, 1),
                       live_steps=int(iterations[r].sum()), eval_seconds=t1 - t0, evolve_seconds=t2 - t1,
                       validation_seconds=t3 - t2, generation_seconds=t3 - t0)
            rows.append(row)
        return state, rows


def progress_line(rows: list[dict], total: int, eta: float | None, seconds: float) -> str:
    """One line for a generation of a group: its runs' best, mean and validated figures (best and median
    over the runs), the live share and the time."""
    g = max(int(r["generation"]) for r in rows)
    col = lambda k: np.array([float(r[k]) for r in rows])  # noqa: E731
    best, mean, val = col("best_fitness"), col("mean_fitness"), col("best_validation")
    eta_text = "" if eta is None else f"  ETA {outputs.format_seconds(eta)}"
    return (f"gen {g + 1:3d}/{total}  {len(rows)} runs  best {best.max():.4f} (median {np.median(best):.4f})"
            f"  mean {np.median(mean):.4f}  validated {val.max():.4f} (median {np.median(val):.4f})"
            f"  live {float(rows[0]['live_fraction']):.0%}  {seconds:.2f} s/gen (eval "
            f"{float(rows[0]['eval_seconds']):.2f}, evolve {float(rows[0]['evolve_seconds']):.3f}){eta_text}")


def train_group(cfgs: Sequence[ml_collections.ConfigDict], run_dirs: Sequence[str | pathlib.Path], *,
                resume: bool | Sequence[bool] = False, overwrite: bool = False,
                log: Callable[[str], None] = print) -> list[dict | None]:
    """Trains (or resumes) the runs of ``cfgs`` (one config per run, equal but in :data:`VARYING`) in
    ``run_dirs`` as one batched group; returns each run's final metrics row. ``resume``: for every run,
    or one flag per run (a protocol resumes the runs a kill interrupted and starts the others).

    Each run directory is what :func:`kx.evolve.run.train` writes for that config alone, and can be
    resumed alone; a group whose runs were cut at different generations (a kill between two runs'
    checkpoints) is resumed in lockstep again: the runs behind advance first, as a smaller group.
    Every run directory is checked (and locked) before any compute."""
    cfgs, run_dirs = list(cfgs), [pathlib.Path(d).absolute() for d in run_dirs]
    if len(cfgs) != len(run_dirs):
        raise RunError(f"{len(cfgs)} configs and {len(run_dirs)} run directories")
    if len(set(run_dirs)) != len(run_dirs):
        raise RunError("--workdir: two runs of the group would share a run directory")
    check_group(cfgs)
    resumes = [bool(resume)] * len(cfgs) if isinstance(resume, bool) else [bool(r) for r in resume]
    if len(resumes) != len(cfgs):
        raise RunError(f"resume: {len(resumes)} flags for {len(cfgs)} runs")
    for d, res in zip(run_dirs, resumes):
        if d.exists() and not d.is_dir():
            raise RunError(f"--workdir: {d} is a file, not a run directory")
        if not overwrite:
            run_lib.prepare_run_dir(d, res, False)  # refuses now, before any run is written
    with contextlib.ExitStack() as stack:
        for d in run_dirs:
            stack.enter_context(RunLock(d, log))
        group = RunGroup.from_configs(cfgs)
        runs = [run_lib.open_run(t, d, resume=res, overwrite=overwrite, step=None,
                                 log=lambda s, seed=t.cfg.seed: log(f"[seed {seed}] {s}"))
                for t, d, res in zip(group.trainers, run_dirs, resumes)]
        for run in runs:
            run.quiet = True
        total = cfgs[0].generations
        stacked, members, done_here, t_first = None, None, 0, None
        while True:
            todo = [i for i, run in enumerate(runs) if not run.done and run.generation < total]
            if not todo:
                break
            g = min(runs[i].generation for i in todo)
            batch = [i for i in todo if runs[i].generation == g]
            if batch != members:  # the first generation, or after a resume that found the runs apart
                sub = group if len(batch) == len(group) else RunGroup([group.trainers[i] for i in batch])
                stacked, members = stack_states([runs[i].state for i in batch]), batch
            t_start = time.perf_counter()
            stacked, rows = sub.step(stacked)
            host = jax.device_get(stacked)  # one transfer; each run's state is a view of it
            for j, i in enumerate(batch):
                runs[i].record(run_lib.GenerationResult(row=rows[j], state=run_state(host, j)))
            done_here += 1
            t_now = time.perf_counter()
            t_first = t_now if done_here == 1 else t_first
            per_gen = (t_now - t_first) / (done_here - 1) if done_here > 1 else None
            log(progress_line(rows, total, None if per_gen is None else per_gen * (total - g - 1), t_now - t_start))
        return [run.rows[-1] if run.done else run.close() for run in runs]
