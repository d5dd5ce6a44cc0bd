"""Batched run groups (kx.evolve.group): R runs of one config as one program write, bit for bit, the run
directories of the same seeds trained one by one (timings and the live share aside), resume after
SIGKILL and compile nothing new across generations."""

import json
import os
import pathlib
import re
import signal
import subprocess
import sys
import time
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx import train as train_cli
from kx.evolve import checkpoint as ckpt
from kx.evolve import config as cfg_lib
from kx.evolve import group as group_lib
from kx.evolve import outputs
from kx.evolve import run as run_lib
from kx.evolve import trainer as trainer_lib
from kx.evolve.errors import ConfigError

REPO = pathlib.Path(__file__).resolve().parents[1]
SEEDS = (0, 3, 7)
SMALL = ["trials=3", "validation_trials=6", "generations=3", "gif=false", "checkpoint_every=1", "keep_checkpoints=5",
         "sim.max_iterations=120"]
SIZE = {"neat": 12, "hyperneat": 12, "cma_es": 6}  # test_run_loop.py's sizes: programs it compiled are reused


def _cfg(method, seed, *extra, task="3v2"):
    return cfg_lib.load(REPO / "configs" / f"{method}_{task}.py",
                        [*SMALL, f"population_size={SIZE[method]}", f"seed={seed}", *extra])


def _quiet(_):
    pass


def _rows(run_dir):
    return [{k: v for k, v in r.items() if k not in outputs.EXECUTION_FIELDS}
            for r in outputs.read_rows(run_dir / "metrics.csv", below=10**9)]


def _meta(meta):
    """A checkpoint's metadata but the config fields a resume may change (``generations``, ...)."""
    return {**meta, "config": {k: v for k, v in cfg_lib.flatten(meta["config"]).items() if k not in cfg_lib.RESUMABLE}}


def assert_same_run(a: pathlib.Path, b: pathlib.Path):
    """Two run directories hold the same run: config, baselines, metrics rows (execution figures aside),
    every checkpoint's run state and metadata."""
    assert json.loads((a / "config.json").read_text()) == json.loads((b / "config.json").read_text())
    assert (a / "baselines.json").read_text() == (b / "baselines.json").read_text()
    rows_a, rows_b = _rows(a), _rows(b)
    diff = [(i, k, r[k], s.get(k)) for i, (r, s) in enumerate(zip(rows_a, rows_b)) for k in r if r[k] != s.get(k)]
    assert len(rows_a) == len(rows_b) and rows_a and not diff, diff[:5]
    steps = ckpt.steps(a)
    assert steps and steps == ckpt.steps(b)
    for step in steps:
        trainer_a, _, state_a, meta_a = run_lib.restore(a, step)
        _, _, state_b, meta_b = run_lib.restore(b, step)
        assert _meta(meta_a) == _meta(meta_b)
        for x, y in zip(jax.tree.leaves(state_a), jax.tree.leaves(state_b), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _group_and_alone(tmp_path, cfgs):
    group_lib.train_group(cfgs, [tmp_path / "group" / f"seed{c.seed}" for c in cfgs], log=_quiet)
    for c in cfgs:
        run_lib.train(c, tmp_path / "alone" / f"seed{c.seed}", log=_quiet)
    for c in cfgs:
        assert_same_run(tmp_path / "group" / f"seed{c.seed}", tmp_path / "alone" / f"seed{c.seed}")


# ~35 s each: the default suite checks a group against its runs alone in memory (the recompile test below)
@pytest.mark.slow
@pytest.mark.parametrize("method, objective", [("neat", "hybrid"), ("hyperneat", "fitness"), ("cma_es", "hybrid")])
def test_a_batched_group_writes_what_its_seeds_write_one_by_one(tmp_path, method, objective):
    _group_and_alone(tmp_path, [_cfg(method, s, f"objective={objective}") for s in SEEDS])


@pytest.mark.slow
def test_a_batched_group_of_transferred_runs_writes_what_they_write_one_by_one(tmp_path):
    """R sources (trained as a group) seed R targets in 4v3: batched and one by one, the same."""
    sources = [_cfg("neat", s, "generations=2") for s in SEEDS]
    group_lib.train_group(sources, [tmp_path / "src" / f"seed{s}" for s in SEEDS], log=_quiet)
    targets = [_cfg("neat", s, f"transfer.source={tmp_path / 'src' / f'seed{s}'}", task="4v3") for s in SEEDS]
    _group_and_alone(tmp_path, targets)


@pytest.mark.slow  # ~40 s
def test_a_group_resumed_with_its_runs_apart_catches_up_in_lockstep(tmp_path):
    """Runs of one group at different generations (a kill between two runs' checkpoints) resume as a
    group: the run behind advances alone, then all together; each ends as it would alone."""
    cfgs = [_cfg("neat", s) for s in SEEDS]
    dirs = [tmp_path / "group" / f"seed{s}" for s in SEEDS]
    group_lib.train_group([_cfg("neat", s, "generations=2") for s in SEEDS[:2]], dirs[:2], log=_quiet)
    run_lib.train(_cfg("neat", SEEDS[2], "generations=1"), dirs[2], log=_quiet)
    lines = []
    group_lib.train_group(cfgs, dirs, resume=True, log=lines.append)
    progress = [ln for ln in lines if ln.startswith("gen ")]
    assert [re.search(r"\d+ runs", ln).group() for ln in progress] == ["1 runs", "3 runs"], progress
    for c, d in zip(cfgs, dirs):
        run_lib.train(c, tmp_path / "alone" / f"seed{c.seed}", log=_quiet)
        assert_same_run(d, tmp_path / "alone" / f"seed{c.seed}")


def test_a_group_refuses_configs_that_differ_beyond_the_seed_before_any_compute(tmp_path):
    a, b = _cfg("neat", 0), _cfg("neat", 1, "trials=4")
    with pytest.raises(ConfigError, match=r"^trials: the runs of a batched group share every config field but seed"):
        group_lib.train_group([a, b], [tmp_path / "a", tmp_path / "b"], log=_quiet)
    with pytest.raises(ConfigError, match=r"seeds: each run of a group needs its own seed; \[0\] repeated"):
        trainer_lib.check_group([a, _cfg("neat", 0)])
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "config.json").write_text("{}")
    with pytest.raises(run_lib.RunError, match="exists and is not empty"):
        group_lib.train_group([a, _cfg("neat", 1)], [tmp_path / "a", tmp_path / "b"], log=_quiet)
    assert not (tmp_path / "a").exists()


@pytest.mark.slow  # ~35-55 s: 10 runs of 150 CPPNs; the default suite checks the trial means at their size
def test_a_group_of_ten_builds_substrates_and_scores_novelty_as_its_runs_alone():
    """Where vmap over 10 runs of 150 rounds differently in the last bit (HyperNEAT's substrate query, the
    novelty k-NN; identical at the 3 x 12 of the tests above), a group computes each run's alone."""
    from kx.evolve import streams

    cfgs = [cfg_lib.load(REPO / "configs" / "hyperneat_3v2.py", [f"seed={s}", "objective=hybrid"]) for s in range(10)]
    group = trainer_lib.RunGroup.from_configs(cfgs)
    state = group.init()
    population, _ = group._ask(jax.vmap(lambda k: streams.learner_ask(k, 0))(state.key), state.learner)
    tables = group._policy_params(population)
    fitness = jax.random.uniform(jax.random.key(1), (10, 150))
    behaviour = jax.random.uniform(jax.random.key(2), (10, 3, 150))
    score, archive, _ = group._score(fitness, behaviour, state.objective)
    score, archive, _ = group._score(fitness[::-1], behaviour[::-1], archive)  # with an archive to search
    alone = []
    for r, trainer in enumerate(group.trainers):
        pop = jax.tree.map(lambda a: a[r], population)
        for x, y in zip(jax.tree.leaves(tables), jax.tree.leaves(trainer.encoding.policy_params(pop)), strict=True):
            np.testing.assert_array_equal(np.asarray(x[r]), np.asarray(y))
        s1, a1, _ = trainer.objective.score(fitness[r], behaviour[r], trainer_lib.run_state(state, r).objective)
        alone.append(trainer.objective.score(fitness[9 - r], behaviour[9 - r], a1)[0])
    np.testing.assert_array_equal(np.asarray(score), np.stack([np.asarray(a) for a in alone]))


@pytest.mark.parametrize("shape", [(10, 50, 30), (3, 50, 30), (16, 150, 30)])
def test_a_groups_means_over_trials_are_those_of_each_run_alone(shape):
    """Each run's means over its trials in a group of R are those of the same run's [1, P, T] alone, the
    group of one that a run alone steps (a mean over the last axis of the whole [R, P, T] differs in the
    last bit at 50 x 30, CMA-ES's shape: the protocol's CMA-ES runs drifted)."""
    k = jax.random.split(jax.random.key(sum(shape)), 2)
    fitness = jax.random.uniform(k[0], shape) * jax.random.uniform(k[1], shape)
    behaviour = jax.random.uniform(k[1], (3, *shape))
    stats = types.SimpleNamespace(fitness=fitness, behaviour=behaviour)  # the two fields it reads
    f, b = trainer_lib.trial_means(stats)
    whole = np.asarray(fitness).mean(axis=2, dtype=np.float32)  # a different summation: not bit for bit
    assert np.allclose(np.asarray(f), whole, rtol=1e-6)
    for r in range(shape[0]):  # a run alone's means: XLA's mean over the trials of its own [P, T]
        np.testing.assert_array_equal(np.asarray(f[r]), np.asarray(jnp.mean(fitness[r], axis=1)))
        np.testing.assert_array_equal(np.asarray(b[r]), np.asarray(jnp.mean(behaviour[:, r], axis=2)))
    # what the test guards against: XLA's mean over the whole group's last axis, which is not each run's
    # alone at CMA-ES's shape (290 of 500 means here)
    if shape == (10, 50, 30):
        assert (np.asarray(jnp.mean(fitness, axis=2)) != np.asarray(f)).any(), "the group's mean is each run's here"


@pytest.mark.parametrize("text, seeds", [("0-3", [0, 1, 2, 3]), ("5", [5]), ("0-1,7", [0, 1, 7])])
def test_seeds_parse(text, seeds):
    assert train_cli.parse_seeds(text) == seeds


@pytest.mark.parametrize("text", ["a", "3-1x", "", "1,1", "-2"])
def test_bad_seeds_are_refused_naming_the_flag(text):
    with pytest.raises(ConfigError, match="^--seeds: "):
        train_cli.parse_seeds(text)


@pytest.mark.slow  # 15-40 s cold: the default suite's 7 minutes in a fresh clone on an AVX2 CPU (make test-slow)
def test_a_batched_group_recompiles_nothing_across_generations_and_computes_what_its_runs_do_alone():
    """After the first two generations, a group's generation compiles only evaluator batch widths it
    reaches for the first time; and every generation of every run, its metrics row (execution figures
    aside) and its run state, is what the same run computes alone (:class:`kx.evolve.run.Trainer`)."""
    from tests.test_run_loop import _compiles_during, assert_nothing_compiles_twice

    # test_run_loop.py's shapes for NEAT: the runs alone reuse what its recompile test compiled
    cfgs = [_cfg("neat", s, "generations=5", "trials=2", "validation_trials=4", "sim.max_iterations=60")
            for s in SEEDS]
    group = trainer_lib.RunGroup.from_configs(cfgs)
    state, compiles = _compiles_during(group.init)
    per_generation, rows = [compiles], []
    for _ in range(5):
        (state, got), compiles = _compiles_during(lambda: group.step(state))
        per_generation.append(compiles)
        rows.append(got)
    _, probe = _compiles_during(lambda: jax.jit(lambda x: x * 3.0 - 1.0)(np.arange(3.0)))
    assert probe, "the log of compilations caught nothing: the test would pass vacuously"
    assert_nothing_compiles_twice(per_generation, first=2)  # init and generation 0, as one run's
    strip = lambda row: {k: v for k, v in row.items() if k not in outputs.EXECUTION_FIELDS}  # noqa: E731
    for r, c in enumerate(cfgs):
        trainer = run_lib.Trainer(c)
        alone = trainer.init()
        for g in range(5):
            result = trainer.step(alone)
            alone = result.state
            assert strip(result.row) == strip(rows[g][r]), (c.seed, g)
        for x, y in zip(jax.tree.leaves(alone), jax.tree.leaves(trainer_lib.run_state(state, r)), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def assert_first_generation_alone(cfgs, state, rows):
    """Each run's first generation in a group (its stacked ``state`` after it and its metrics ``rows``) is
    the one the run steps alone: every row but the execution figures, every leaf of the run state."""
    strip = lambda row: {k: v for k, v in row.items() if k not in outputs.EXECUTION_FIELDS}  # noqa: E731
    for r, c in enumerate(cfgs):
        trainer = run_lib.Trainer(c)
        result = trainer.step(trainer.init())
        assert strip(result.row) == strip(rows[r]), c.seed
        for x, y in zip(jax.tree.leaves(result.state), jax.tree.leaves(trainer_lib.run_state(state, r)), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.mark.slow  # ~30 s on CI: HyperNEAT's generation step compiled for the group and alone; the default suite plays
# a group's runs one a call (split, played and put back in run order) in the NEAT test below
def test_a_hyperneat_group_played_a_run_a_call_computes_what_its_runs_do_alone(monkeypatch):
    """On a CPU a group plays its runs' episodes in calls whose substrate tables fit CPU_TABLE_BYTES (one
    run a call at the paper's sizes); forced here at test sizes, every row and run state is still each
    run's alone."""
    cfgs = [_cfg("hyperneat", s, "generations=1") for s in SEEDS]
    group = trainer_lib.RunGroup.from_configs(cfgs)
    monkeypatch.setattr(trainer_lib, "CPU_TABLE_BYTES", 1)
    state = group.init()
    population, _ = group._ask(jax.vmap(lambda k: trainer_lib.streams.learner_ask(k, 0))(state.key), state.learner)
    assert group.runs_per_call(group._policy_params(population)) == 1
    monkeypatch.setattr(trainer_lib, "CPU_TABLE_BYTES", 2**40)
    assert group.runs_per_call(group._policy_params(population)) == len(SEEDS)
    monkeypatch.setattr(trainer_lib, "CPU_TABLE_BYTES", 1)
    calls = []
    evaluate = trainer_lib.ev.evaluate
    monkeypatch.setattr(trainer_lib.ev, "evaluate", lambda *a, **k: calls.append(k["key"].shape) or evaluate(*a, **k))
    state, rows = group.step(state)
    assert calls == [(1,)] * 6  # the 3 runs' episodes, one run a call, then their validation
    # what a group's log says: how the generation's episodes were played (not the champions' validation)
    assert group.calls_note.startswith("1 of the 3 runs' episodes per evaluator call"), group.calls_note
    assert_first_generation_alone(cfgs, state, rows)


def test_a_neat_group_plays_each_run_in_its_own_network_shape_and_computes_what_its_runs_do_alone(monkeypatch):
    """NEAT's networks keep the hidden rows their genomes need; a group plays its runs in one evaluator
    call per shape (kx.evolve.trainer.RunGroup._param_parts), so a run is never played in a larger shape
    than alone. Forced here (the smallest shape first: the results put back in run order), every
    row and run state is still each run's alone (each call has one run: the widths the runs alone use)."""
    # the batched group test's configs: its group's and its runs' programs, not others of their own
    cfgs = [_cfg("neat", s, "generations=1", "trials=2", "validation_trials=4", "sim.max_iterations=60")
            for s in SEEDS]
    group = trainer_lib.RunGroup.from_configs(cfgs)
    monkeypatch.setattr(type(group.encoding), "policy_shape",
                        lambda self, population: np.array([8, 4, 6][:jax.tree.leaves(population)[0].shape[0]]))
    calls = []
    evaluate = trainer_lib.ev.evaluate
    monkeypatch.setattr(trainer_lib.ev, "evaluate", lambda *a, **k: calls.append(k["key"].shape) or evaluate(*a, **k))
    state, rows = group.step(group.init())
    assert calls == [(1,)] * 3 * 2  # run 1's shape, run 2's, then run 0's; then their validation the same way
    assert_first_generation_alone(cfgs, state, rows)


@pytest.mark.slow
def test_a_batched_group_killed_with_sigkill_resumes_bit_for_bit(tmp_path):
    """``kx.train --seeds`` killed once some run has checkpoint 2, resumed as a group: every run ends as
    the same seed trained alone does."""
    args = ["--config", "configs/neat_3v2.py", *(f"--config.{o}" for o in SMALL), "--config.population_size=12"]
    group = tmp_path / "group"
    cmd = [sys.executable, "-m", "kx.train", "--seeds", "0,3,7", "--workdir", str(group), *args]
    proc = subprocess.Popen([*cmd, "--config.generations=100000"], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None:
        if any(2 in ckpt.steps(group / f"seed{s}") for s in SEEDS):
            break
        time.sleep(0.005)
    assert proc.poll() is None, "the group ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    resumed = subprocess.run([*cmd, "--resume", "--config.generations=4"], cwd=REPO, capture_output=True, text=True,
                             timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming" in resumed.stdout
    for s in SEEDS:
        alone = tmp_path / "alone" / f"seed{s}"
        run_lib.train(_cfg("neat", s, "generations=4"), alone, log=_quiet)
        assert_same_run(group / f"seed{s}", alone)


class _Killed(Exception):
    pass


@pytest.mark.slow  # ~40 s
def test_a_batched_transfer_group_killed_mid_run_resumes_each_run_from_its_own_config(tmp_path, monkeypatch):
    """``kx.train --seeds`` of targets each seeded by its own source (``transfer.source=.../seed{seed}``),
    killed as it writes its third checkpoint, resumed with ``--resume`` alone (no ``--config``): each run
    resumes from its own config.json, with its own source, and ends as the same target trained alone."""
    seeds = (0, 3)
    src = tmp_path / "src"
    group_lib.train_group([_cfg("neat", s, "generations=2") for s in seeds], [src / f"seed{s}" for s in seeds],
                          log=_quiet)
    group = tmp_path / "group"
    args = ["--config", "configs/neat_4v3.py", *(f"--config.{o}" for o in SMALL), "--config.population_size=12",
            f"--config.transfer.source={src}/seed{{seed}}"]
    saves = []
    real_save = ckpt.save

    def dying(*a, **k):
        if len(saves) == 2:  # both runs have checkpoint 1: killed as the next one is written
            raise _Killed
        saves.append(a[1])
        return real_save(*a, **k)

    with monkeypatch.context() as m:
        m.setattr(ckpt, "save", dying)
        with pytest.raises(_Killed):
            train_cli.main(["--seeds", "0,3", "--workdir", str(group), *args])
    assert [ckpt.steps(group / f"seed{s}") for s in seeds] == [[1], [1]]
    assert train_cli.main(["--seeds", "0,3", "--workdir", str(group), "--resume"]) == 0
    for s in seeds:
        record = json.loads((group / f"seed{s}" / "config.json").read_text())[cfg_lib.SOURCE_RECORD]
        assert record["path"] == str((src / f"seed{s}").resolve())
        alone = tmp_path / "alone" / f"seed{s}"
        run_lib.train(_cfg("neat", s, f"transfer.source={src / f'seed{s}'}", task="4v3"), alone, log=_quiet)
        assert_same_run(group / f"seed{s}", alone)
