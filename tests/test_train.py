"""``python -m kx.train`` and ``python -m kx.evaluate`` for every method (NEAT, HyperNEAT and CMA-ES): the
run directory, resuming after SIGKILL, bad input, refused checkpoints and configs."""

import contextlib
import csv
import io
import json
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
from PIL import Image

from kx import evaluate as evaluate_cli
from kx import train as train_cli
from kx.evolve import checkpoint as ckpt
from kx.evolve import config as cfg_lib
from kx.evolve import group as group_lib
from kx.evolve import outputs, streams
from kx.evolve import run as run_lib
from kx.sim import env

# `make test` deals out whole files (--dist loadfile): one worker runs this module, so each method's
# trained run directory is built once
REPO = pathlib.Path(__file__).resolve().parents[1]
GENERATIONS = 6
COMMON = ["--config.trials=4", "--config.sim.max_iterations=300", "--config.gif_frames=10",
          "--config.checkpoint_every=1", "--config.keep_checkpoints=2", "--config.validation_trials=40"]
METHODS = {
    "neat": ["--config", "configs/neat_3v2.py", "--config.population_size=20", *COMMON],
    # HyperNEAT's run selects on the novelty hybrid: its kill-and-resume test then covers the archive too
    "hyperneat": ["--config", "configs/hyperneat_3v2.py", "--config.population_size=12", "--config.objective=hybrid",
                  *COMMON],
    "cma_es": ["--config", "configs/cma_es_3v2.py", "--config.population_size=8", *COMMON],
    # PPO: a population of one network; 16 episodes side by side, 48 training episodes a generation
    "ppo": ["--config", "configs/ppo_3v2.py", "--config.ppo.episodes_per_generation=48", "--config.ppo.num_envs=16",
            "--config.ppo.num_steps=16", "--config.ppo.hidden=16", "--config.ppo.resets=4",
            "--config.ppo.anneal_episodes=288", *COMMON],
    # PPO on the entity network (size-invariant): the same budget
    "ppo_entity": ["--config", "configs/ppo_entity_3v2.py", "--config.ppo_entity.episodes_per_generation=48",
                   "--config.ppo_entity.num_envs=16", "--config.ppo_entity.num_steps=16",
                   "--config.ppo_entity.hidden=16", "--config.ppo_entity.resets=4",
                   "--config.ppo_entity.anneal_episodes=288", *COMMON],
}
NEAT_LEARNERS = ("neat", "hyperneat")  # NEAT's own metrics and genome checks


def _train_here(workdir, method, generations=GENERATIONS):
    """``kx.train``'s ``main`` in this process, on its one device: the programs it compiles then serve
    the tests' own replays of the run here."""
    argv = ["--workdir", str(workdir), *METHODS[method], f"--config.generations={generations}"]
    i = argv.index("--config") + 1
    argv[i] = str(REPO / argv[i])
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = train_cli.main(argv)
    assert rc == 0, err.getvalue()
    return out.getvalue()


_RUNS: dict = {}
# Every method's reference run trains in the test process (one device), where the tests' replays reuse
# the programs of the run itself (HyperNEAT's trained in a `python -m kx.train` process until 2026-12-04,
# for a kill-and-resume test of the default suite that has since gone to the slow set).


@pytest.fixture(scope="session")
def _runs(tmp_path_factory):
    """Each method's trained run directory, built once per worker when a test first asks for it (a
    parametrized module fixture would be torn down and built again whenever the order of the tests
    switches between methods)."""
    def get(method):
        if method not in _RUNS:
            run_dir = tmp_path_factory.mktemp("runs") / method
            _RUNS[method] = (run_dir, _train_here(run_dir, method), method)
        return _RUNS[method]
    return get


# CMA-ES's and HyperNEAT's run tests live in test_train_cma_es.py and test_train_hyperneat.py (the same
# tests, other files: `make test` deals out whole files to its workers, so they run beside these)
@pytest.fixture
def trained(_runs):
    return _runs("neat")


def _cfg(run_dir):
    return cfg_lib.read_run_config(run_dir / "config.json")


def _final_state(run_dir, step=GENERATIONS):
    trainer = run_lib.Trainer(_cfg(run_dir))
    got, state, meta = trainer.restore(run_dir, step)
    assert got == step and meta["generation"] == step and int(state.generation) == step
    return state, meta


def _rows(run_dir):
    with (run_dir / "metrics.csv").open() as f:
        return list(csv.DictReader(f))


def _assert_same_state(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_run_directory_holds_config_metrics_plot_checkpoints_and_gif(trained):
    run_dir, out, method = trained
    cfg = json.loads((run_dir / "config.json").read_text())
    assert cfg["method"] == method and cfg["task"] == "3v2" and cfg["generations"] == GENERATIONS
    rows = _rows(run_dir)
    trainer = run_lib.Trainer(_cfg(run_dir))
    assert [int(r["generation"]) for r in rows] == list(range(GENERATIONS))
    assert list(rows[0]) == list(outputs.csv_fields(trainer.encoding, trainer.objective))
    best = [float(r["best_fitness"]) for r in rows]
    so_far = [float(r["best_so_far"]) for r in rows]
    assert so_far == list(np.maximum.accumulate(np.float32(best)).astype(float))
    for r in rows:
        if cfg["objective"] == "fitness":  # the score is the fitness
            assert float(r["best_score"]) == float(r["best_fitness"])
        # (the hybrid's score columns against a plain numpy hybrid: test_train_novelty.py)
        # live lane-steps over executed ones, counted apart (executed: the batch width times the steps run)
        assert 0.0 < float(r["live_fraction"]) <= 1.0
        for k in trainer.encoding.metric_fields:
            assert r[k] != "", k
    if cfg["objective"] == "hybrid":  # the archive keeps every behaviour it admitted (far below its capacity)
        added = np.cumsum([int(r["archive_added"]) for r in rows])
        assert [int(r["archive_size"]) for r in rows] == list(added)
        assert 0 < added[-1] < cfg["novelty"]["archive_size"]
    # the encoding's columns describe its learner: NEAT's species count and mean enabled links of the
    # last generation are those of that generation's population (checkpoint GENERATIONS - 1, before its
    # tell; not the offspring it bred); CMA-ES's step size is the one its last tell left (the final checkpoint)
    if method in NEAT_LEARNERS:
        before_last, _ = _final_state(run_dir, GENERATIONS - 1)
        pop = before_last.learner.population
        assert int(rows[-1]["n_species"]) == len(np.unique(np.asarray(before_last.learner.species)))
        links = np.sum(np.asarray(pop.conn_valid) & np.asarray(pop.conn_enabled), axis=1)
        np.testing.assert_allclose(float(rows[-1]["mean_links"]), links.mean(), rtol=1e-6)
    elif method == "cma_es":
        assert float(rows[-1]["sigma"]) == float(_final_state(run_dir)[0].learner.std)
    else:  # PPO: each generation trained on at least its block of new episodes, and they add up
        learner = _final_state(run_dir)[0].learner
        ended = np.cumsum([int(r["train_episodes"]) for r in rows])
        assert int(learner.episodes) == ended[-1] and int(learner.blocks) == GENERATIONS
        assert all(e >= 48 * (g + 1) for g, e in enumerate(ended)) and ended[-1] < 48 * GENERATIONS + 16 * 16
        assert int(learner.updates) == sum(int(r["updates"]) for r in rows)
    # what ran: one session (started after generation 0), this JAX, and HyperNEAT's implementation of its sums
    runtime = json.loads((run_dir / "runtime.json").read_text())["sessions"]
    assert len(runtime) == 1 and runtime[0]["after_generation"] == 0 and runtime[0]["jax"] == jax.__version__
    if method == "hyperneat":
        from kx.hyperneat import native
        expect = "xla" if native.unavailable() else "native"
        assert runtime[0]["decision_sums"] == expect and runtime[0]["chosen"] == "auto"
        assert out.count("decision: sums by the ") == 1
        assert ("sums by the native kernel" in out) == (expect == "native")
    else:
        assert "decision_sums" not in runtime[0] and "decision: " not in out
    # each generation's champion replayed on the validation states, next to the hand-coded policies there
    base = json.loads((run_dir / "baselines.json").read_text())
    assert base["trials"] == cfg["validation_trials"] and set(base["mean_fitness"]) == {"hold", "random", "heuristic"}
    assert base["mean_fitness"]["hold"] < base["mean_fitness"]["heuristic"]
    val = [float(r["champion_validation"]) for r in rows]
    # generation 0 replayed here: its fitness columns are its population's fitness on its start states
    # (raw fitness, not the score the hybrid run selects on), and the champion it validated is the
    # member with the best of them
    seed = trainer.cfg.seed
    population, _ = trainer.encoding.ask(streams.learner_ask(seed, 0), trainer.init().learner)
    keys = streams.training(seed, 0)
    starts = env.reset_batch(keys.starts, trainer.cfg.trials, trainer.exp.sim_params, trainer.exp.sim)
    f = np.asarray(trainer.evaluate(population, starts, keys.eval).fitness.mean(axis=1))
    assert best[0] == float(f.max()) and float(rows[0]["median_fitness"]) == float(np.median(f))
    assert float(rows[0]["mean_fitness"]) == float(np.clip(f.mean(), f.min(), f.max()))
    assert trainer.validate(trainer.encoding.individual(population, int(np.argmax(f)))) == val[0]
    # the run's champion: the per-generation champion with the best validation score (earliest on ties)
    assert [float(r["best_validation"]) for r in rows] == list(np.maximum.accumulate(val))
    assert [int(r["best_validation_generation"]) for r in rows] == [
        int(np.argmax(val[: i + 1])) for i in range(len(val))]
    state, meta = _final_state(run_dir)
    assert meta["format"] == ckpt.FORMAT and meta["method"] == method
    assert float(state.champion_validation) == np.float32(max(val)) and meta["best_validation"] == max(val)
    assert trainer.validate(state.champion) == float(state.champion_validation)
    first = trainer.step(trainer.init()).row
    assert first["champion_validation"] == val[0] and first["best_fitness"] == best[0]
    with Image.open(run_dir / "progress.png") as im:
        assert im.format == "PNG" and im.size[0] > 300
    with Image.open(run_dir / "champion.gif") as im:
        assert im.format == "GIF" and im.n_frames > 1
    if method == "ppo":  # no picture of a network of 2 x 2 dense layers
        assert not (run_dir / "champion.png").exists()
    else:
        with Image.open(run_dir / "champion.png") as im:
            assert im.format == "PNG" and im.size[0] > 200
    if method == "hyperneat":  # champion.png is the substrate; the CPPN is drawn beside it
        with Image.open(run_dir / "champion_cppn.png") as im:
            assert im.format == "PNG" and im.size[0] > 200
    # the last 2 checkpoints are kept, and the one of the generation whose champion validated best
    steps = ckpt.steps(run_dir)
    assert steps == sorted({GENERATIONS - 1, GENERATIONS, int(np.argmax(val)) + 1})
    lines = [line for line in out.splitlines() if line.startswith("gen ")]
    assert len(lines) == GENERATIONS and "ETA" in lines[-1] and "s/gen" in lines[-1]
    assert {"neat": "species", "hyperneat": "species", "cma_es": "sigma", "ppo": "train return"}[method] in lines[-1]


@pytest.mark.slow  # ~85 s; the default suite resumes runs in process (resume_here, test_train_novelty.py)
def test_sigkill_then_resume_ends_bit_for_bit_where_an_uninterrupted_run_does(trained, tmp_path):
    sigkill_then_resume(trained, tmp_path)


def _assert_ends_as(run_dir, reference):
    """``run_dir`` ends where ``reference`` does: its final run state and checkpoint metadata bit for bit,
    and every metrics row but how the generations were executed (the timings, and the live share of the
    lane-steps, which depends on how the lanes were split over devices: the reference may have run in this
    process, on one)."""
    a, meta_a = _final_state(reference)
    b, meta_b = _final_state(run_dir)
    assert meta_a == meta_b
    _assert_same_state(a, b)
    strip = lambda rows: [{k: v for k, v in r.items() if k not in outputs.EXECUTION_FIELDS} for r in rows]  # noqa: E731
    got, want = strip(_rows(run_dir)), strip(_rows(reference))
    diff = [(i, k, r[k], w.get(k)) for i, (r, w) in enumerate(zip(got, want)) for k in r if r[k] != w.get(k)]
    assert len(got) == len(want) == GENERATIONS and not diff, diff[:5]


def sigkill_then_resume(trained, tmp_path):
    """A run killed mid-way and resumed from checkpoint 2 ends bit for bit where ``trained`` ends."""
    reference, _, method = trained
    run_dir = tmp_path / "killed"
    # far more generations than the reference: the run cannot end before the kill, however fast the machine
    cmd = [sys.executable, "-m", "kx.train", "--workdir", str(run_dir), *METHODS[method], "--config.generations=100000"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None:
        if any(s >= 2 for s in ckpt.steps(run_dir)):
            break
        time.sleep(0.01)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    have = ckpt.steps(run_dir)
    assert 2 in have and max(have) < 100000
    # continue from checkpoint 2, whatever was written after it, and stop where the reference stops
    resumed = subprocess.run([sys.executable, "-m", "kx.train", "--workdir", str(run_dir), "--resume", "--step", "2",
                              f"--config.generations={GENERATIONS}"], cwd=REPO, capture_output=True, text=True,
                             timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming" in resumed.stdout and "after generation 2" in resumed.stdout
    _assert_ends_as(run_dir, reference)
    # checkpoints written after 2 by the killed run were set aside, not deleted
    later = [s for s in have if s > 2]
    if later:
        moved = sorted(int(p.name) for p in (run_dir / "abandoned").glob("*/checkpoints/*"))
        assert moved == later


def resume_here(trained, tmp_path):
    """A copy of the reference run's directory resumed from its earlier kept checkpoint (``kx.train --resume
    --step 5``; it keeps two), in this process, reusing the programs the reference compiled here, ends bit
    for bit where the reference ends: what :func:`sigkill_then_resume` checks, without the kill and the
    two processes (a cold ``kx.train`` process compiles every program again)."""
    reference, _, method = trained
    run_dir = _copy(reference, tmp_path / "resumed")
    step = GENERATIONS - 1
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = train_cli.main(["--workdir", str(run_dir), "--resume", "--step", str(step)])
    assert rc == 0, err.getvalue()
    assert "resuming" in out.getvalue() and f"after generation {step}" in out.getvalue()
    _assert_ends_as(run_dir, reference)
    # the checkpoint after it was recomputed, the reference's set aside rather than deleted
    moved = sorted(int(p.name) for p in (run_dir / "abandoned").glob("*/checkpoints/*"))
    assert moved == [GENERATIONS] and ckpt.steps(run_dir) == ckpt.steps(reference)


def _err(capsys, argv, cli=train_cli):
    rc = cli.main(argv)
    err = capsys.readouterr().err
    assert rc == 2, err
    return err


def test_bad_config_fields_and_values_are_refused_before_any_compute(capsys, tmp_path, monkeypatch):
    def trained(*args, **kwargs):  # a case that has become valid fails here, instead of training a whole run
        raise AssertionError("a config this test expects refused reached training")

    monkeypatch.setattr(run_lib, "train", trained)
    monkeypatch.setattr(group_lib, "train_group", trained)
    w = ["--workdir", str(tmp_path / "x")]
    assert "foo: no such config field" in _err(capsys, w + ["--config.foo=1"])
    assert "neat.nope: no such config field" in _err(capsys, w + ["--config.neat.nope=1"])
    err = _err(capsys, w + ["--config.population_size=1"])
    assert "population_size: allowed an integer in [2, 100000] for method 'neat', got 1" in err
    ppo = ["--config", "configs/ppo_3v2.py"]
    assert "population_size: allowed 1 for method 'ppo', got 2" in _err(
        capsys, w + ppo + ["--config.population_size=2"])
    assert "objective: allowed 'fitness' for method 'ppo'" in _err(capsys, w + ppo + ["--config.objective=hybrid"])
    assert "ppo.num_minibatches: allowed a divisor of num_envs x num_steps = 8192" in _err(
        capsys, w + ppo + ["--config.ppo.num_minibatches=3"])
    assert "ppo.gamma: allowed a number in [0, 1]" in _err(capsys, w + ppo + ["--config.ppo.gamma=1.5"])
    assert "ppo.resets: allowed an integer in [1, num_envs = 512]" in _err(
        capsys, w + ppo + ["--config.ppo.resets=513"])
    assert "trials: allowed an integer, got 'many'" in _err(capsys, w + ["--config.trials=many"])
    assert "trials: allowed an integer, got '2.5'" in _err(capsys, w + ["--config.trials", "2.5"])
    assert "task:" in _err(capsys, w + ["--config.task=9v2"])
    assert "method: allowed one of ('neat', 'hyperneat', 'cma_es'" in _err(capsys, w + ["--config.method=nope"])
    assert "objective: allowed one of ('fitness', 'hybrid')" in _err(capsys, w + ["--config.objective=novelty"])
    assert "novelty.k: allowed an integer" in _err(capsys, w + ["--config.objective=hybrid", "--config.novelty.k=0"])
    assert "transfer.seeding: allowed one of" in _err(capsys, w + ["--config.transfer.seeding=best"])
    assert "layout:" in _err(capsys, w + ["--config.layout=bev"])
    assert "neat.add_node_prob" in _err(capsys, w + ["--config.neat.add_node_prob=1.5"])
    assert "neat.max_add_links: allowed an integer in [0, population_size" in _err(
        capsys, w + ["--config.neat.max_add_links=151"])
    assert "sim.max_iterations" in _err(capsys, w + ["--config.sim.max_iterations=0"])
    assert "--config: no config file" in _err(capsys, w + ["--config", "configs/nope.py"])
    # with no --workdir (the default run directory), as `make run` calls it, and as a group of seeds
    assert "population_size: allowed an integer" in _err(capsys, ["--config.population_size=1"])
    assert "population_size: allowed an integer" in _err(capsys, ["--seeds", "0-1", "--config.population_size=1"])
    assert "--seeds: allowed" in _err(capsys, w + ["--seeds", "0-x"])
    assert "--step: only with --resume" in _err(capsys, w + ["--step", "3"])
    cma = ["--config", "configs/cma_es_3v2.py"]
    assert "cma_es.sigma_init: allowed a number in (0, 10000]" in _err(
        capsys, w + cma + ["--config.cma_es.sigma_init=0"])
    assert "cma_es.hidden: allowed an integer in [0, 256]" in _err(capsys, w + cma + ["--config.cma_es.hidden=-1"])
    assert "neat.add_node_prob: no such config field" in _err(capsys, w + cma + ["--config.neat.add_node_prob=0.1"])
    hn = ["--config", "configs/hyperneat_3v2.py"]
    assert "layout: allowed one of ('bev',) for method 'hyperneat'" in _err(
        capsys, w + hn + ["--config.layout=fixed"])
    assert "hyperneat.activations: allowed distinct names from" in _err(
        capsys, w + hn + ["--config.hyperneat.activations=('gaussian', 'nope')"])
    assert "hyperneat.resolution: allowed sim.field_size (20)" in _err(
        capsys, w + hn + ["--config.hyperneat.resolution=10"])
    assert "hyperneat.image: allowed one of ('paper', 'authors')" in _err(
        capsys, w + hn + ["--config.hyperneat.image=x"])
    assert "hyperneat.decision: allowed one of ('cells', 'literal')" in _err(
        capsys, w + hn + ["--config.hyperneat.decision=argmax"])
    assert "hyperneat.substrate_activation: allowed one of" in _err(
        capsys, w + hn + ["--config.hyperneat.substrate_activation=relu"])
    assert "hyperneat.add_link_prob" in _err(capsys, w + hn + ["--config.hyperneat.add_link_prob=2.0"])
    assert not (tmp_path / "x").exists()


@pytest.mark.slow  # it trains in the test process, compiling every program there
def test_a_relative_workdir_works(capsys, trained, tmp_path, monkeypatch):
    # orbax needs absolute paths; the run resolves a relative --workdir itself (the same code for any method)
    src, _, method = trained
    if method != "neat":
        pytest.skip("the run directory's path is handled before the method matters")
    shutil.copytree(src, tmp_path / "rel")
    monkeypatch.chdir(tmp_path)
    assert train_cli.main(["--workdir", "rel", "--resume", "--config.generations=7", "--config.gif=false"]) == 0
    assert int(_rows(tmp_path / "rel")[-1]["generation"]) == 6
    assert 7 in ckpt.steps(tmp_path / "rel")


def test_existing_run_directories_are_never_overwritten_unasked(capsys, trained, tmp_path):
    run_dir, _, method = trained
    before = (run_dir / "metrics.csv").read_bytes()
    assert "exists and is not empty" in _err(capsys, ["--workdir", str(run_dir), *METHODS[method]])
    assert "holds no run to resume" in _err(capsys, ["--workdir", str(tmp_path / "none"), "--resume"])
    stranger = tmp_path / "stranger"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("mine")
    assert "not a kx run directory" in _err(capsys, ["--workdir", str(stranger), "--overwrite", *METHODS[method]])
    assert (stranger / "notes.txt").read_text() == "mine"
    # resuming with a field that changes what the run computes
    assert "trials = 4 in the checkpoint, 5 now" in _err(
        capsys, ["--workdir", str(run_dir), "--resume", "--config.trials=5"])
    assert (run_dir / "metrics.csv").read_bytes() == before


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


def _edit_config(run_dir, fn):
    d = json.loads((run_dir / "config.json").read_text())
    fn(d)
    (run_dir / "config.json").write_text(json.dumps(d))


def test_corrupt_and_mismatched_checkpoints_are_refused_with_the_reason(capsys, trained, tmp_path):
    src, _, method = trained
    resume = lambda d, *a: ["--workdir", str(d), "--resume", "--config.generations=8", *a]  # noqa: E731
    # a damaged latest checkpoint is reported as such, with the earlier ones to continue from
    damaged = _copy(src, tmp_path / "damaged")
    for f in (damaged / "checkpoints" / str(GENERATIONS) / "state").rglob("*"):
        if f.is_file():
            f.write_bytes(b"\x00garbage" * 8)
    err = _err(capsys, resume(damaged))
    assert f"checkpoint {GENERATIONS}" in err and "damaged" in err
    assert f"--resume --step {GENERATIONS - 1}" in err
    assert "no checkpoint 3 (there are" in _err(capsys, resume(damaged, "--step", "3"))
    if method == "neat":  # ... and --step continues from an earlier one, setting the damaged one aside (the
        # run loop's own logic, the same for every method; in this process it compiles the method's programs)
        assert train_cli.main(resume(damaged, "--step", str(GENERATIONS - 1), "--config.gif=false")) == 0
        capsys.readouterr()
        assert max(ckpt.steps(damaged)) == 8
        assert [p.name for p in (damaged / "abandoned").glob("*/checkpoints/*")] == [str(GENERATIONS)]
    # a checkpoint written by another config (its own metadata says so)
    other = _copy(src, tmp_path / "other")
    _edit_config(other, lambda d: d.update(seed=7))
    assert "written by another config: seed = 0 in the checkpoint, 7 now" in _err(capsys, resume(other))
    # a checkpoint of an older format (the first kx wrote no format into its metadata)
    old = _copy(src, tmp_path / "old")
    trainer = run_lib.Trainer(_cfg(src))
    step, state, meta = trainer.restore(old)
    shutil.rmtree(old / "checkpoints" / str(step))
    mgr = ckpt.manager(old / "checkpoints", 3)
    import orbax.checkpoint as ocp
    mgr.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(
        {k: v for k, v in meta.items() if k != "format"})), metrics={"champion_validation": 0.0})
    mgr.wait_until_finished()
    want = f"checkpoint format 1; this kx reads format {ckpt.FORMAT} (written by an older kx)"
    assert want in _err(capsys, resume(old))
    # a checkpoint whose run key is not its seed's (its config says seed 0, its state carries seed 7's key)
    rekeyed = _copy(src, tmp_path / "rekeyed")
    step, state, meta = trainer.restore(rekeyed)
    shutil.rmtree(rekeyed / "checkpoints" / str(step))
    ckpt.save(ckpt.manager(rekeyed / "checkpoints", 3), step, state.replace(key=streams.run_key(7)),
              {k: v for k, v in meta.items() if k != "format"})
    err = _err(capsys, resume(rekeyed))
    assert f"checkpoint {step}" in err and "is damaged: its run key is [0, 7], seed 0's is [0, 0]" in err
    # a checkpoint of another method, read with this config's method
    other_method = "cma_es" if method == "neat" else "neat"
    foreign = run_lib.Trainer(cfg_lib.load(REPO / METHODS[other_method][1], [
        METHODS[other_method][2].removeprefix("--config."), "trials=4"]))
    with pytest.raises(run_lib.RunError, match=f"holds a '{method}' run state; this config's method is "
                                               f"'{other_method}'"):
        foreign.restore(src)
    if method in NEAT_LEARNERS:  # readable, of the right shapes, but genomes broken (a link to a missing node)
        broken = _copy(src, tmp_path / "broken")
        step, state, meta = trainer.restore(broken)
        pop = state.learner.population
        col = int(np.argmax(np.asarray(pop.conn_valid[3])))  # a column genome 3 uses
        state = state.replace(learner=state.learner.replace(population=pop.replace(
            conn_src=pop.conn_src.at[3, col].set(999))))
        shutil.rmtree(broken / "checkpoints" / str(step))
        ckpt.save(ckpt.manager(broken / "checkpoints", 3), step, state, {k: v for k, v in meta.items()
                                                                         if k != "format"})
        err = _err(capsys, resume(broken))
        assert f"checkpoint {step}" in err and "invalid genotypes" in err and "genome 3: link 999->" in err


def test_corrupt_or_foreign_config_json_is_refused_with_the_reason(capsys, trained, tmp_path):
    src, _, _ = trained
    cases = {
        "not JSON": (lambda p: p.write_text('{"task": "3v2", '), "corrupt, not readable as JSON"),
        "a list": (lambda p: p.write_text("[1, 2]"), "expected a JSON object of config fields, got list"),
        "mis-nested": (lambda p: _edit_config(p.parent, lambda d: d.update(sim=3)), "sim: a section, not a value"),
        "nested wrongly": (lambda p: _edit_config(p.parent, lambda d: d.update(trials={"n": 4})),
                           "trials.n: not a field of this kx configs"),
        "older kx": (lambda p: _edit_config(p.parent, lambda d: (d.pop("validation_trials"),
                                                                 d.update(heldout_trials=50))),
                     "heldout_trials: not a field of this kx configs"),
        "missing field": (lambda p: _edit_config(p.parent, lambda d: d.pop("objective")), "objective: missing"),
        "bad type": (lambda p: _edit_config(p.parent, lambda d: d.update(trials="four")),
                     "trials: 'four' does not fit"),
        "unknown method": (lambda p: _edit_config(p.parent, lambda d: d.update(method="nope")),
                           "method: allowed one of"),
    }
    for i, (name, (damage, expected)) in enumerate(cases.items()):
        d = _copy(src, tmp_path / f"c{i}")
        damage(d / "config.json")
        err = _err(capsys, ["--workdir", str(d), "--resume"])
        assert expected in err and "config.json" in err, (name, err)
        err = _err(capsys, [str(d), "--trials", "4"], evaluate_cli)
        assert expected in err, (name, err)


def test_evaluate_plays_the_validated_champion_on_test_trials_of_another_task(capsys, trained):
    run_dir, _, method = trained
    assert evaluate_cli.main([str(run_dir), "--task", "4v3", "--trials", "12", "--no-baselines"]) == 0
    out = json.loads((run_dir / "eval" / "4v3-12-seed0.json").read_text())
    assert out["task"] == "4v3" and out["checkpoint"] == GENERATIONS and out["trials"] == 12
    assert out["method"] == method
    assert abs(sum(out["champion"]["reasons"].values()) - 1.0) < 1e-6
    state, _ = _final_state(run_dir)
    assert out["champion_validation"] == float(state.champion_validation)
    assert out["champion_generation"] == int(state.champion_generation) + 1
    # its 4v3 figure is the validated champion's, through the encoding's 4v3 policy on 4v3's test states
    from kx.evolve.encoding import stack
    from kx.sim import evaluate as ev
    trainer = run_lib.Trainer(_cfg(run_dir))
    keys = streams.test(0)
    c4 = cfg_lib.from_dict(_cfg(run_dir).to_dict())
    c4.task = "4v3"
    target = cfg_lib.validate(c4)
    starts = env.reset_batch(keys.starts, 12, target.sim_params, target.sim)
    params = trainer.encoding.policy_params(stack([state.champion]))
    stats = ev.evaluate(trainer.encoding.policy_for(target.sim), params, starts, target.sim_params, target.sim,
                        key=keys.eval)
    assert out["champion"]["mean_fitness"] == float(np.asarray(stats.fitness).mean())
    # on the run's own task, the champion's test figure is the one the trainer's evaluator gives
    assert evaluate_cli.main([str(run_dir), "--trials", "12", "--no-baselines"]) == 0
    own = json.loads((run_dir / "eval" / "3v2-12-seed0.json").read_text())
    starts = env.reset_batch(keys.starts, 12, trainer.exp.sim_params, trainer.exp.sim)
    stats = trainer.evaluate(stack([state.champion]), starts, keys.eval)
    assert own["champion"]["mean_fitness"] == float(np.asarray(stats.fitness).mean())
    capsys.readouterr()
    assert "--trials: allowed" in _err(capsys, [str(run_dir), "--trials", "0"], evaluate_cli)
    assert "task:" in _err(capsys, [str(run_dir), "--task", "2v2"], evaluate_cli)


def test_training_validation_and_test_states_are_disjoint_streams(tmp_path):
    tr = run_lib.Trainer(cfg_lib.load(None, ["population_size=20", "trials=4", "validation_trials=64"]))
    cells = lambda s: {c.tobytes() for c in np.concatenate(  # noqa: E731
        [np.asarray(a) for a in (s.keeper_x, s.keeper_y, s.taker_x, s.taker_y, s.holder[None])]).T}
    sim, params = tr.exp.sim, tr.exp.sim_params
    train = set().union(*(cells(env.reset_batch(streams.training(0, g).starts, 64, params, sim)) for g in range(20)))
    val = cells(tr.validation_starts)
    test = cells(env.reset_batch(streams.test(0).starts, 64, params, sim))
    assert len(val) == 64 and len(test) == 64 and len(train) == 20 * 64
    assert not (val & train) and not (test & train) and not (val & test)
    # no key of one use is the key of another (split(k, n)[i] == fold_in(k, i) under the default RNG):
    # every stream's keys for a few generations, the evaluator's two derived keys, and the trials' reset keys
    fold = jax.random.fold_in
    keys = [streams.learner_init(0)]
    for seed in (0, 1):
        for g in range(3):
            t = streams.training(seed, g)
            keys += [t.starts, t.eval, fold(t.eval, 0), fold(t.eval, 1), streams.learner_step(seed, g),
                     streams.learner_ask(seed, g)]
            keys += list(jax.random.split(t.starts, 8))
        for t in (streams.validation(seed), streams.test(seed)):
            keys += [t.starts, t.eval, fold(t.eval, 0), fold(t.eval, 1), *jax.random.split(t.starts, 8)]
    data = {tuple(np.asarray(jax.random.key_data(k)).ravel()) for k in keys}
    assert len(data) == len(keys)
    # the validation replay of a genome is a pure function of the genome and the run's seed
    genome = jax.tree.map(lambda a: a[0], tr.init().learner.population)
    assert tr.validate(genome) == tr.validate(genome) == run_lib.Trainer(tr.cfg).validate(genome)
    assert "validation_trials: allowed an integer in [1, 100000]" in str(
        pytest.raises(cfg_lib.ConfigError, cfg_lib.validate, cfg_lib.load(None, ["validation_trials=0"])).value)
    row = tr.step(tr.init()).row
    assert "validation" in outputs.progress_line(row, 1, None, tr.encoding)
    outputs.plot_progress([row], tmp_path / "p.png", "one", lower=tr.encoding.plot_field)
    assert (tmp_path / "p.png").stat().st_size > 1000


def test_overrides_go_through_config_flags_with_tuples_and_nested_fields():
    cfg = cfg_lib.apply_overrides(cfg_lib.base_config(), ["sim.max_iterations=123", "gif=false", "seed=5",
                                                          "neat.weight_init_range=2"])
    assert cfg.sim.max_iterations == 123 and cfg.gif is False and cfg.seed == 5
    assert isinstance(cfg.neat.weight_init_range, float) and cfg.neat.weight_init_range == 2.0
    import ml_collections
    c = ml_collections.ConfigDict({"shape": (1, 2), "inner": {"x": 1.0}})
    c = cfg_lib.apply_overrides(c, ["shape=(3, 4, 5)", "inner.x=0.5"])
    assert c.shape == (3, 4, 5) and c.inner.x == 0.5


def test_the_eta_follows_the_last_generations_not_the_first():
    clock = outputs.GenerationClock(window=3)
    assert clock.tick(0.0) is None  # the first generation compiles: no estimate from it alone
    assert clock.tick(1.0) == 1.0
    assert clock.tick(2.0) == 1.0
    assert clock.tick(4.0) == 4.0 / 3
    assert clock.tick(8.0) == (8.0 - 1.0) / 3
    # generations lengthening to 2, 4 and 8 s: the last three (14 s over 3), not all since the first (16 s over 5)
    assert clock.tick(16.0) == (16.0 - 2.0) / 3 > (16.0 - 0.0) / 5
