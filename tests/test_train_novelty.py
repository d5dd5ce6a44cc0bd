"""The hybrid objective (SPEC section 4) through the run loop: metrics.csv's novelty columns, the
archive saved with every checkpoint and restored bit for bit, a resumed run ending where the
uninterrupted one does, and selection on the score while the reports stay raw fitness."""

import csv
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

from kx.evolve import checkpoint as ckpt
from kx.evolve import config as cfg_lib
from kx.evolve import outputs
from kx.evolve import run as run_lib

REPO = pathlib.Path(__file__).resolve().parents[1]
GENERATIONS = 4
POPULATION = 12
OVERRIDES = ["objective=hybrid", f"population_size={POPULATION}", "trials=2", "sim.max_iterations=60",
             "validation_trials=4", "gif=false", "checkpoint_every=1", f"keep_checkpoints={GENERATIONS}"]


def _cfg(generations=GENERATIONS):
    return cfg_lib.load(None, OVERRIDES + [f"generations={generations}"])


def _rows(run_dir):
    with (run_dir / "metrics.csv").open() as f:
        return list(csv.DictReader(f))


def _strip(rows):
    """Rows as csv writes them, timings left out (they differ from run to run)."""
    return [{k: str(v) for k, v in r.items() if k not in outputs.TIMING_FIELDS} for r in rows]


def _assert_same_tree(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(la, lb, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _ref_novelty(points, archive_rows, k):
    """Plain Python: the mean of the k smallest Euclidean distances to the others and the archive."""
    out = []
    for i, x in enumerate(points):
        d = sorted([float(np.linalg.norm(x - y)) for j, y in enumerate(points) if j != i]
                   + [float(np.linalg.norm(x - y)) for y in archive_rows])[:k]
        out.append(sum(d) / len(d) if d else 0.0)
    return np.asarray(out)


def _minmax(x):
    return (x - x.min()) / (x.max() - x.min()) if x.max() > x.min() else np.zeros_like(x)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The run directory of a 4-generation hybrid run; the same run in memory, with what its objective
    and its learner were handed each generation; and a copy of the run directory resumed from its
    checkpoint 2 (the later checkpoints and metrics rows set aside as after a kill)."""
    base = tmp_path_factory.mktemp("novelty_runs")
    cfg = _cfg()
    run_dir = base / "run"
    run_lib.train(cfg, run_dir, log=lambda s: None)

    trainer = run_lib.Trainer(cfg)
    seen = {"score": [], "tell": []}
    score, tell = trainer.objective.score, trainer.encoding.tell

    def spy_score(fitness, behaviour, state):
        out = score(fitness, behaviour, state)
        seen["score"].append((np.asarray(fitness), np.asarray(behaviour), jax.device_get(state),
                              np.asarray(out[0])))
        return out

    def spy_tell(key, population, sc, fitness, state):
        seen["tell"].append((np.asarray(sc), np.asarray(fitness)))
        return tell(key, population, sc, fitness, state)

    trainer.objective.score, trainer.encoding.tell = spy_score, spy_tell
    state, rows = run_lib.evolve_in_memory(trainer)

    resumed = base / "resumed"
    shutil.copytree(run_dir, resumed)
    logs = []
    run_lib.train(cfg, resumed, resume=True, step=2, log=logs.append)
    return dict(cfg=cfg, run_dir=run_dir, state=state, rows=rows, seen=seen, resumed=resumed, logs=logs)


def test_metrics_csv_has_the_novelty_columns_and_the_archive_grows(runs):
    trainer = run_lib.Trainer(runs["cfg"])
    fields = trainer.objective.metric_fields
    assert fields == ("mean_novelty", "champion_novelty", "archive_size", "archive_added", "score_std")
    rows = _rows(runs["run_dir"])
    assert list(rows[0]) == list(outputs.csv_fields(trainer.encoding, trainer.objective))
    assert [int(r["generation"]) for r in rows] == list(range(GENERATIONS))
    size = [int(r["archive_size"]) for r in rows]
    added = [int(r["archive_added"]) for r in rows]
    assert size == list(np.minimum(np.cumsum(added), runs["cfg"].novelty.archive_size))
    assert size[-1] > size[0] > 0  # behaviours in [0, 1]^3 of a random population: most are novel
    # each generation adds those whose novelty (plain Python, against the archive before it) is above
    # the threshold, and score_std is the spread of the score the learner was handed (the novelty and
    # score columns against plain numpy: test_selection_sees_the_score_and_the_reports_raw_fitness)
    threshold, k = runs["cfg"].novelty.threshold, runs["cfg"].novelty.k
    for r, (_, behaviour, before, score) in zip(rows, runs["seen"]["score"], strict=True):
        nov = _ref_novelty(behaviour.T, before.entries[: int(before.size)], k)
        assert int(r["archive_added"]) == int(np.sum(nov > threshold))
        np.testing.assert_allclose(float(r["score_std"]), np.std(score), rtol=1e-5)


def test_the_checkpointed_archive_is_the_in_memory_runs(runs):
    trainer, step, state, meta = run_lib.restore(runs["run_dir"])
    assert step == GENERATIONS and meta["config"]["objective"] == "hybrid"
    archive = state.objective
    assert archive.entries.shape == (runs["cfg"].novelty.archive_size, 3)
    _assert_same_tree(archive, runs["state"].objective)
    _assert_same_tree(state, runs["state"])  # and the rest of the run state
    assert _strip(runs["rows"]) == _strip(_rows(runs["run_dir"]))
    # each checkpoint holds the archive after its generation
    for g in range(1, GENERATIONS + 1):
        _, _, s, _ = run_lib.restore(runs["run_dir"], g)
        assert int(s.objective.size) == runs["rows"][g - 1]["archive_size"]
    # the archive holds the admitted behaviours, in population order, generation after generation
    threshold, k = runs["cfg"].novelty.threshold, runs["cfg"].novelty.k
    admitted = []
    for _, behaviour, before, _ in runs["seen"]["score"]:
        rows_before = before.entries[: int(before.size)]
        nov = _ref_novelty(behaviour.T, rows_before, k)
        admitted += [behaviour.T[i] for i in range(POPULATION) if nov[i] > threshold]
    n = int(archive.size)
    assert n == len(admitted) <= runs["cfg"].novelty.archive_size
    np.testing.assert_array_equal(archive.entries[:n], np.asarray(admitted, np.float32))


def test_resuming_from_checkpoint_2_ends_bit_for_bit_as_the_uninterrupted_run(runs):
    assert any("after generation 2" in line for line in runs["logs"])
    _, _, a, meta_a = run_lib.restore(runs["run_dir"])
    _, _, b, meta_b = run_lib.restore(runs["resumed"])
    assert meta_a == meta_b
    _assert_same_tree(a.objective, b.objective)
    _assert_same_tree(a, b)
    assert _strip(_rows(runs["resumed"])) == _strip(_rows(runs["run_dir"]))
    moved = sorted(int(p.name) for p in (runs["resumed"] / "abandoned").glob("*/checkpoints/*"))
    assert moved == [3, 4]


def test_selection_sees_the_score_and_the_reports_raw_fitness(runs):
    rho, k = runs["cfg"].novelty.rho, runs["cfg"].novelty.k
    assert len(runs["seen"]["tell"]) == len(runs["seen"]["score"]) == GENERATIONS
    for row, (fitness, behaviour, before, score), (told_score, told_fitness) in zip(
            runs["rows"], runs["seen"]["score"], runs["seen"]["tell"], strict=True):
        # the learner selects on the objective's score and is handed the raw fitness beside it
        np.testing.assert_array_equal(told_score, score)
        np.testing.assert_array_equal(told_fitness, fitness)
        assert not np.array_equal(score, fitness)
        nov = _ref_novelty(behaviour.T, before.entries[: int(before.size)], k)
        np.testing.assert_allclose(score, rho * _minmax(fitness) + (1 - rho) * _minmax(nov), rtol=1e-5, atol=1e-6)
        champ = int(np.argmax(fitness))
        np.testing.assert_allclose(row["champion_novelty"], nov[champ], rtol=1e-5)
        np.testing.assert_allclose(row["mean_novelty"], nov.mean(), rtol=1e-5)
        # metrics.csv's fitness columns are raw fitness; its score columns the score
        assert row["best_fitness"] == float(fitness.max())
        assert row["median_fitness"] == float(np.median(fitness))
        assert row["champion_passes"] == float(behaviour[0, champ])
        assert row["best_score"] == float(score.max())
        np.testing.assert_allclose(row["mean_score"], score.mean(), rtol=1e-6)


@pytest.mark.slow  # two kx.train processes, each compiling every program (~85 s)
def test_sigkill_then_resume_keeps_the_archive(runs, tmp_path):
    run_dir = tmp_path / "killed"
    args = [f"--config.{o}" for o in OVERRIDES]
    proc = subprocess.Popen([sys.executable, "-m", "kx.train", "--workdir", str(run_dir), *args,
                             "--config.generations=100000"], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None and not any(s >= 2 for s in ckpt.steps(run_dir)):
        time.sleep(0.01)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    resumed = subprocess.run([sys.executable, "-m", "kx.train", "--workdir", str(run_dir), "--resume", "--step", "2",
                              f"--config.generations={GENERATIONS}"], cwd=REPO, capture_output=True, text=True,
                             timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    _, _, a, _ = run_lib.restore(runs["run_dir"])
    _, _, b, _ = run_lib.restore(run_dir)
    _assert_same_tree(a, b)
    # kx.train splits the episode lanes over one XLA device per core (kx.runtime), this process over
    # one: the lane-steps executed, so live_fraction, differ; the live steps and all else do not
    got, want = _strip(_rows(run_dir)), _strip(_rows(runs["run_dir"]))
    diff = [(i, k, r[k], w[k]) for i, (r, w) in enumerate(zip(got, want, strict=True)) for k in r
            if r[k] != w[k] and k != "live_fraction"]
    assert not diff, diff[:5]


def test_the_authors_behaviour_reaches_the_objective_through_the_run_loop():
    """novelty.behaviour = authors: the objective scores each genome's mean over its trials of [time held,
    dispersion, decisions / max_iterations]: its first row is the training fitness the run reports, its
    second the world's dispersion; with threshold 0 the whole first generation enters the archive."""
    cfg = cfg_lib.load(None, OVERRIDES + ["generations=1", "novelty.behaviour=authors", "novelty.threshold=0.0"])
    trainer = run_lib.Trainer(cfg)
    seen = []
    score = trainer.objective.score

    def spy(fitness, behaviour, state):
        seen.append((np.asarray(fitness), np.asarray(behaviour)))
        return score(fitness, behaviour, state)

    trainer.objective.score = spy
    state, rows = run_lib.evolve_in_memory(trainer)
    fitness, behaviour = seen[0]
    assert behaviour.shape == (3, POPULATION)
    np.testing.assert_array_equal(behaviour[0], fitness)  # time held is the fitness, mean for mean
    assert float(rows[0]["mean_dispersion"]) == pytest.approx(float(behaviour[1].mean()), rel=1e-5)
    # a decision in at most every iteration played: the iteration that loses the ball too, which the
    # time held (iterations survived) leaves out
    assert np.all(behaviour[2] <= behaviour[0] + 1 / 60 + 1e-6) and np.all(behaviour[2] > 0)
    archive = jax.device_get(state.objective)
    assert int(archive.size) == POPULATION
    np.testing.assert_array_equal(np.asarray(archive.entries[:POPULATION]).T, behaviour)
