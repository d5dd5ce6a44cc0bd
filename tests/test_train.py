"""``python -m kx.train`` and ``python -m kx.evaluate``: the run directory, resuming after SIGKILL, bad input."""

import csv
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
from kx.evolve import config as cfg_lib
from kx.evolve import run as run_lib
from kx.evolve import streams
from kx.sim import env

REPO = pathlib.Path(__file__).resolve().parents[1]
GENERATIONS = 6
SMALL = ["--config.population_size=20", "--config.trials=4", "--config.sim.max_iterations=300",
         "--config.gif_frames=30", "--config.checkpoint_every=1", "--config.keep_checkpoints=2"]


def _train(workdir, *extra, generations=GENERATIONS):
    return subprocess.run([sys.executable, "-m", "kx.train", "--workdir", str(workdir), *SMALL,
                           f"--config.generations={generations}", *extra],
                          cwd=REPO, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("runs") / "a"
    proc = _train(run_dir)
    assert proc.returncode == 0, proc.stderr
    return run_dir, proc.stdout


def _cfg(run_dir):
    return cfg_lib.from_dict(json.loads((run_dir / "config.json").read_text()))


def _final_state(run_dir, step=GENERATIONS):
    trainer = run_lib.Trainer(_cfg(run_dir))
    got, state, meta = run_lib.restore_checkpoint(run_dir, jax.eval_shape(trainer.init), step)
    assert got == step and meta["generation"] == step
    return state, meta


def _rows(run_dir):
    with (run_dir / "metrics.csv").open() as f:
        return list(csv.DictReader(f))


def test_run_directory_holds_config_metrics_plot_checkpoints_and_gif(trained):
    run_dir, out = trained
    cfg = json.loads((run_dir / "config.json").read_text())
    assert cfg["population_size"] == 20 and cfg["task"] == "3v2" and cfg["generations"] == GENERATIONS
    rows = _rows(run_dir)
    assert [int(r["generation"]) for r in rows] == list(range(GENERATIONS))
    assert set(rows[0]) == set(run_lib.CSV_FIELDS)
    best = [float(r["best_fitness"]) for r in rows]
    so_far = [float(r["best_so_far"]) for r in rows]
    assert so_far == list(np.maximum.accumulate(best))
    for r in rows:
        assert 0.0 <= float(r["mean_fitness"]) <= float(r["best_fitness"]) <= 1.0
        assert 1 <= int(r["n_species"]) <= 10 and 0.0 < float(r["live_fraction"]) <= 1.0
    # each generation's champion replayed on the validation states, next to the hand-coded policies there
    base = json.loads((run_dir / "baselines.json").read_text())
    assert base["trials"] == cfg["validation_trials"] and set(base["mean_fitness"]) == {"hold", "random", "heuristic"}
    assert base["mean_fitness"]["hold"] < base["mean_fitness"]["heuristic"]
    val = [float(r["champion_validation"]) for r in rows]
    assert all(0.0 < v <= 1.0 for v in val)
    # the run's champion: the per-generation champion with the best validation score (earliest on ties)
    assert [float(r["best_validation"]) for r in rows] == list(np.maximum.accumulate(val))
    assert [int(r["best_validation_generation"]) for r in rows] == [
        int(np.argmax(val[: i + 1])) for i in range(len(val))]
    state, meta = _final_state(run_dir)
    assert float(state.champion_validation) == np.float32(max(val)) and meta["best_validation"] == max(val)
    trainer = run_lib.Trainer(_cfg(run_dir))
    assert trainer.validate(state.champion) == float(state.champion_validation)
    first = trainer.step(0, trainer.init(), -np.inf).row
    assert first["champion_validation"] == val[0] and first["best_fitness"] == best[0]
    for k in ("node_overflow", "link_overflow", "link_exhausted", "species_overflow"):
        assert all(int(r[k]) >= 0 for r in rows), k
    with Image.open(run_dir / "progress.png") as im:
        assert im.format == "PNG" and im.size[0] > 300
    with Image.open(run_dir / "champion.gif") as im:
        assert im.format == "GIF" and im.n_frames > 1
    # the last 2 checkpoints are kept, and the one of the generation whose champion validated best
    steps = sorted(int(p.name) for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit())
    best_step = int(np.argmax(val)) + 1
    assert steps == sorted({GENERATIONS - 1, GENERATIONS, best_step})
    lines = [line for line in out.splitlines() if line.startswith("gen ")]
    assert len(lines) == GENERATIONS and "ETA" in lines[-1] and "species" in lines[-1] and "s/gen" in lines[-1]


def test_sigkill_then_resume_ends_bit_for_bit_where_an_uninterrupted_run_does(trained, tmp_path):
    reference, _ = trained
    run_dir = tmp_path / "killed"
    cmd = [sys.executable, "-m", "kx.train", "--workdir", str(run_dir), *SMALL, f"--config.generations={GENERATIONS}"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ckpts = run_dir / "checkpoints"
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None:
        if ckpts.is_dir() and any(p.name.isdigit() and int(p.name) >= 2 for p in ckpts.iterdir()):
            break
        time.sleep(0.01)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (ckpts / str(GENERATIONS)).exists()
    resumed = subprocess.run([sys.executable, "-m", "kx.train", "--workdir", str(run_dir), "--resume"],
                             cwd=REPO, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming" in resumed.stdout
    a, meta_a = _final_state(reference)
    b, meta_b = _final_state(run_dir)
    assert meta_a == meta_b
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    drop = ("eval_seconds", "evolve_seconds", "validation_seconds", "generation_seconds")
    strip = lambda rows: [{k: v for k, v in r.items() if k not in drop} for r in rows]  # noqa: E731
    assert strip(_rows(run_dir)) == strip(_rows(reference))


def _err(capsys, argv, cli=train_cli):
    rc = cli.main(argv)
    err = capsys.readouterr().err
    assert rc == 2, err
    return err


def test_bad_config_fields_and_values_are_refused_before_any_compute(capsys, tmp_path):
    w = ["--workdir", str(tmp_path / "x")]
    assert "foo: no such config field" in _err(capsys, w + ["--config.foo=1"])
    assert "neat.nope: no such config field" in _err(capsys, w + ["--config.neat.nope=1"])
    err = _err(capsys, w + ["--config.population_size=1"])
    assert "population_size: allowed an integer in [2, 100000], got 1" in err
    assert "trials: allowed an integer" in _err(capsys, w + ["--config.trials=many"])
    assert "task:" in _err(capsys, w + ["--config.task=9v2"])
    assert "method: allowed one of ('neat',)" in _err(capsys, w + ["--config.method=hyperneat"])
    assert "layout:" in _err(capsys, w + ["--config.layout=bev"])
    assert "neat.add_node_prob" in _err(capsys, w + ["--config.neat.add_node_prob=1.5"])
    assert "sim.max_iterations" in _err(capsys, w + ["--config.sim.max_iterations=0"])
    assert "--config: no config file" in _err(capsys, w + ["--config", "configs/nope.py"])
    assert not (tmp_path / "x").exists()


def test_a_relative_workdir_works(capsys, trained, tmp_path, monkeypatch):
    # orbax needs absolute paths; the run resolves a relative --workdir itself
    src, _ = trained
    shutil.copytree(src, tmp_path / "rel")
    monkeypatch.chdir(tmp_path)
    assert train_cli.main(["--workdir", "rel", "--resume", "--config.generations=7", "--config.gif=false"]) == 0
    assert int(_rows(tmp_path / "rel")[-1]["generation"]) == 6
    assert (tmp_path / "rel" / "checkpoints" / "7").is_dir()


def test_existing_run_directories_are_never_overwritten_unasked(capsys, trained, tmp_path):
    run_dir, _ = trained
    before = (run_dir / "metrics.csv").read_bytes()
    assert "exists and is not empty" in _err(capsys, ["--workdir", str(run_dir), *SMALL])
    assert "holds no run to resume" in _err(capsys, ["--workdir", str(tmp_path / "none"), "--resume"])
    stranger = tmp_path / "stranger"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("mine")
    assert "not a kx run directory" in _err(capsys, ["--workdir", str(stranger), "--overwrite", *SMALL])
    assert (stranger / "notes.txt").read_text() == "mine"
    # resuming with a field that changes what the run computes
    assert "population_size = 20 in the checkpoint, 30 now" in _err(
        capsys, ["--workdir", str(run_dir), "--resume", "--config.population_size=30"])
    assert (run_dir / "metrics.csv").read_bytes() == before


def test_corrupt_and_mismatched_checkpoints_are_refused_with_the_reason(capsys, trained, tmp_path):
    src, _ = trained
    corrupt = tmp_path / "corrupt"
    shutil.copytree(src, corrupt)
    for f in (corrupt / "checkpoints" / str(GENERATIONS) / "state").rglob("*"):
        if f.is_file():
            f.write_bytes(b"\x00garbage" * 8)
    err = _err(capsys, ["--workdir", str(corrupt), "--resume", "--config.generations=8"])
    assert f"checkpoint {GENERATIONS}" in err and "corrupt" in err
    # a checkpoint written by another config (its own metadata says so)
    other = tmp_path / "other"
    shutil.copytree(src, other)
    cfg = json.loads((other / "config.json").read_text())
    cfg["seed"] = 7
    (other / "config.json").write_text(json.dumps(cfg))
    err = _err(capsys, ["--workdir", str(other), "--resume", "--config.generations=8"])
    assert "written by another config: seed = 0 in the checkpoint, 7 now" in err
    # a readable checkpoint of the right shapes whose genomes are broken (a link to a missing node)
    broken = tmp_path / "broken"
    shutil.copytree(src, broken)
    step, state, meta = run_lib.restore_checkpoint(broken, jax.eval_shape(run_lib.Trainer(
        cfg_lib.from_dict(json.loads((src / "config.json").read_text()))).init))
    col = int(np.argmax(np.asarray(state.neat.population.conn_valid[3])))  # a column genome 3 uses
    state = state.replace(neat=state.neat.replace(population=state.neat.population.replace(
        conn_src=state.neat.population.conn_src.at[3, col].set(999))))
    shutil.rmtree(broken / "checkpoints" / str(step))
    run_lib.save_checkpoint(run_lib._manager(broken / "checkpoints", 3), step, state, meta)
    err = _err(capsys, ["--workdir", str(broken), "--resume", "--config.generations=8"])
    assert f"checkpoint {step}" in err and "invalid genomes" in err and "genome 3: link 999->" in err


def test_evaluate_plays_the_validated_champion_on_test_trials_of_another_task(capsys, trained):
    run_dir, _ = trained
    assert evaluate_cli.main([str(run_dir), "--task", "4v3", "--trials", "12", "--no-baselines"]) == 0
    out = json.loads((run_dir / "eval" / "4v3-12-seed0.json").read_text())
    assert out["task"] == "4v3" and out["checkpoint"] == GENERATIONS and out["trials"] == 12
    assert 0.0 < out["champion"]["mean_fitness"] <= 1.0
    assert abs(sum(out["champion"]["reasons"].values()) - 1.0) < 1e-6
    state, _ = _final_state(run_dir)
    assert out["champion_validation"] == float(state.champion_validation)
    assert out["champion_generation"] == int(state.champion_generation) + 1
    capsys.readouterr()
    assert "--trials: allowed" in _err(capsys, [str(run_dir), "--trials", "0"], evaluate_cli)
    assert "task:" in _err(capsys, [str(run_dir), "--task", "2v2"], evaluate_cli)


def test_training_validation_and_test_states_are_disjoint_streams(tmp_path):
    overrides = [s.removeprefix("--config.") for s in SMALL]
    tr = run_lib.Trainer(cfg_lib.load(None, overrides + ["validation_trials=64"]))
    cells = lambda s: {c.tobytes() for c in np.concatenate(  # noqa: E731
        [np.asarray(a) for a in (s.keeper_x, s.keeper_y, s.taker_x, s.taker_y, s.holder[None])]).T}
    sim, params = tr.exp.sim, tr.exp.sim_params
    train = set().union(*(cells(env.reset_batch(streams.training(0, g).starts, 64, params, sim)) for g in range(20)))
    val = cells(tr.validation_starts)
    test = cells(env.reset_batch(streams.test(0).starts, 64, params, sim))
    assert len(val) == 64 and len(test) == 64 and len(train) == 20 * 64
    assert not (val & train) and not (test & train) and not (val & test)
    # no key of one use is the key of another (split(k, n)[i] == fold_in(k, i) under the default RNG)
    keys = [streams.training(0, 0).starts, streams.training(0, 0).eval, streams.validation(0).starts,
            streams.validation(0).eval, streams.test(0).starts, streams.test(0).eval, streams.learner_init(0),
            streams.learner_step(0, 0)]
    trial_keys = [jax.random.split(streams.training(0, 0).starts, 64)[i] for i in range(64)]
    data = {tuple(np.asarray(jax.random.key_data(k)).ravel()) for k in keys + trial_keys}
    assert len(data) == len(keys) + len(trial_keys)
    # the validation replay of a genome is a pure function of the genome and the run's seed
    genome = jax.tree.map(lambda a: a[0], tr.init().neat.population)
    assert tr.validate(genome) == tr.validate(genome) == run_lib.Trainer(tr.cfg).validate(genome)
    assert "validation_trials: allowed an integer in [1, 100000]" in str(
        pytest.raises(cfg_lib.ConfigError, cfg_lib.validate, cfg_lib.load(None, ["validation_trials=0"])).value)
    row = tr.step(0, tr.init(), -np.inf).row
    assert "validation" in run_lib.progress_line(row, 1, None)
    run_lib.plot_progress([row], tmp_path / "p.png", "one")
    assert (tmp_path / "p.png").stat().st_size > 1000
