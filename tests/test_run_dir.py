"""The run directory's bookkeeping: the ETA after a resume, a resume with nothing to do,
one writer at a time (run.lock), orbax's temporary folders after a kill, kx.evaluate's JSON and
confidence interval, and a bare boolean override on the command line.

The generation step is stubbed (no evaluator compiles): what is tested is the run loop around it.
The template run directory holds a real checkpoint of a small NEAT run after 2 generations."""

import json
import pathlib
import re
import shutil
import subprocess
import sys
import time
import types

import jax.numpy as jnp
import numpy as np
import pytest

from kx import evaluate as evaluate_cli
from kx import train as train_cli
from kx.evolve import checkpoint as ckpt
from kx.evolve import config as cfg_lib
from kx.evolve import outputs
from kx.evolve import run as run_lib
from kx.evolve.trainer import RunGroup, run_state, stack_states

REPO = pathlib.Path(__file__).resolve().parents[1]
DONE = 2  # generations in the template's checkpoint
SMALL = ["population_size=12", "trials=2", "validation_trials=4", "sim.max_iterations=50", "gif=false",
         "checkpoint_every=1", "keep_checkpoints=3"]
BASELINES = {"hold": 0.001, "random": 0.003, "heuristic": 0.02}


def _row(trainer, g):
    row = {f: 0 for f in trainer.fields}
    row.update(generation=g, best_fitness=0.5, mean_fitness=0.25, median_fitness=0.25, best_so_far=0.5,
               best_score=0.5, mean_score=0.25, champion_validation=0.5, best_validation=0.5,
               best_validation_generation=0, live_fraction=0.5, live_steps=10, eval_seconds=0.01,
               evolve_seconds=0.01, validation_seconds=0.0, generation_seconds=0.02)
    return row


def stub_step(monkeypatch, step) -> None:
    """Stubs the generation step there is (:meth:`RunGroup.step`, which the run loop drives for a run alone too)
    with ``step(trainer, state) -> GenerationResult`` for each run of the group."""
    def group_step(self, stacked):
        results = [step(t, run_state(stacked, j)) for j, t in enumerate(self.trainers)]
        return stack_states([r.state for r in results]), [r.row for r in results]
    monkeypatch.setattr(RunGroup, "step", group_step)


def _fake_step(self, state):
    g = int(state.generation)
    time.sleep(0.02)
    return run_lib.GenerationResult(row=_row(self, g), state=state.replace(generation=jnp.asarray(g + 1, jnp.int32)))


def _no_step(self, state):
    raise AssertionError("a generation ran")


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    """A run directory after DONE generations: config.json, metrics.csv, baselines.json, a checkpoint
    (whose validated champion is genome 0 of the first population), progress.png and champion.png."""
    run_dir = tmp_path_factory.mktemp("template") / "run"
    cfg = cfg_lib.load(None, [*SMALL, f"generations={DONE}"])
    trainer = run_lib.Trainer(cfg)
    state = trainer.init().replace(generation=jnp.asarray(DONE, jnp.int32),
                                   champion_generation=jnp.asarray(0, jnp.int32),
                                   champion_validation=jnp.asarray(0.5, jnp.float32),
                                   best_so_far=jnp.asarray(0.5, jnp.float32))
    run_dir.mkdir()
    outputs.write_json(run_dir / "config.json", cfg.to_dict())
    outputs.write_json(run_dir / "baselines.json", {"trials": 4, "states": "validation", "mean_fitness": BASELINES})
    rows = [_row(trainer, g) for g in range(DONE)]
    outputs.write_rows(run_dir / "metrics.csv", rows, trainer.fields)
    meta = {"config": cfg.to_dict(), "method": cfg.method, "generation": DONE, "best_so_far": 0.5,
            "best_fitness": 0.5, "champion_validation": 0.5, "best_validation": 0.5}
    ckpt.save(ckpt.manager(run_dir / "checkpoints", cfg.keep_checkpoints), DONE, state, meta)
    outputs.plot_progress(rows, run_dir / "progress.png", "template", BASELINES, trainer.encoding.plot_field)
    trainer.encoding.draw(state.champion, run_dir / "champion.png")
    return run_dir


@pytest.fixture
def run_dir(template, tmp_path, monkeypatch):
    """A copy of the template, with the generation step and the baselines stubbed."""
    stub_step(monkeypatch, _fake_step)
    monkeypatch.setattr(run_lib.Trainer, "validation_baselines", lambda self: dict(BASELINES))
    return pathlib.Path(shutil.copytree(template, tmp_path / "run"))


def _cfg(run_dir, generations=None):
    cfg = cfg_lib.read_run_config(run_dir / "config.json")
    if generations is not None:
        cfg.generations = generations
    return cfg


def _snapshot(run_dir):
    return {str(p.relative_to(run_dir)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(run_dir.rglob("*")) if p.is_file()}


# 1. the ETA ---------------------------------------------------------------------------------------

COMPILE = 50.0  # seconds the stubbed first generation of a process takes, on the fake clock
LATER = 1.0  # and each later one


class _Clock:
    """The run loop's clock, advanced only by the stubbed generations: the ETA is exact, however busy
    the machine (a timed assertion on the real clock failed under load)."""

    def __init__(self):
        self.now = 1000.0

    def perf_counter(self):
        return self.now


def _compiling_step(self, state):
    """The stub, with a first generation as slow as a compiling one (on the fake clock)."""
    first = not getattr(self, "_stepped", False)
    self._stepped = True
    seconds = COMPILE if first else LATER
    run_lib.time.now += seconds
    res = _fake_step(self, state)
    res.row["generation_seconds"] = seconds
    return res


@pytest.mark.parametrize("metrics", ["deleted", "truncated"])
def test_eta_comes_from_this_process_even_when_metrics_csv_lacks_rows(run_dir, metrics, monkeypatch):
    stub_step(monkeypatch, _compiling_step)
    monkeypatch.setattr(run_lib, "time", _Clock())
    if metrics == "deleted":
        (run_dir / "metrics.csv").unlink()
    else:  # one row of the checkpoint's two
        lines = (run_dir / "metrics.csv").read_text().splitlines(keepends=True)
        (run_dir / "metrics.csv").write_text("".join(lines[:2]))
    logs = []
    row = run_lib.train(_cfg(run_dir, DONE + 4), run_dir, resume=True, log=logs.append)
    assert row["generation"] == DONE + 3
    gens = [line for line in logs if line.startswith("gen ")]
    assert len(gens) == 4
    # the first generation of a process compiles: no ETA until a second one has run here, and then
    # one from the generations after the first: 1 s each, 2, 1 and 0 left (the first's 50 s left out)
    assert "ETA" not in gens[0] and all("ETA" in line for line in gens[1:]), gens
    eta = [int(re.search(r"ETA (\d+) s", line).group(1)) for line in gens[1:]]
    assert eta == [2 * LATER, 1 * LATER, 0], gens
    written = (run_dir / "metrics.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in written] == ([] if metrics == "deleted" else [0]) + [2, 3, 4, 5]


# 2. nothing to do ---------------------------------------------------------------------------------

def test_a_resume_with_nothing_to_do_writes_nothing(run_dir, monkeypatch, capsys):
    stub_step(monkeypatch, _no_step)
    monkeypatch.setattr(run_lib.Trainer, "validation_baselines", lambda self: pytest.fail("baselines computed"))
    before = _snapshot(run_dir)
    time.sleep(0.01)  # any rewrite would show in the mtimes
    assert train_cli.main(["--workdir", str(run_dir), "--resume"]) == 0
    out = capsys.readouterr().out
    assert f"nothing to do: {DONE} generations done, {DONE} asked" in out
    assert _snapshot(run_dir) == before
    # the same through the function (with the checkpoint named): it returns the last metrics row
    logs = []
    row = run_lib.train(_cfg(run_dir), run_dir, resume=True, step=DONE, log=logs.append)
    assert int(row["generation"]) == DONE - 1 and any("nothing to do" in line for line in logs)
    assert _snapshot(run_dir) == before and not (run_dir / "abandoned").exists()


# 3. one writer at a time --------------------------------------------------------------------------

HOLD = """
import sys, time
from kx.evolve import run
lock = run.RunLock(sys.argv[1])
lock.acquire()
print("held", flush=True)
time.sleep(600)
"""


@pytest.fixture
def holder():
    """Another process holding a run directory's lock: ``holder(run_dir)`` -> its Popen."""
    procs = []

    def hold(d):
        proc = subprocess.Popen([sys.executable, "-c", HOLD, str(d)], cwd=REPO, stdout=subprocess.PIPE, text=True)
        procs.append(proc)
        assert proc.stdout.readline().strip() == "held"
        return proc

    yield hold
    for proc in procs:
        proc.kill()
        proc.wait()


def test_a_second_process_is_refused_before_any_compute(run_dir, holder, monkeypatch, capsys):
    proc = holder(run_dir)
    before = _snapshot(run_dir)
    cfg = _cfg(run_dir, DONE + 2)
    monkeypatch.setattr(run_lib, "Trainer", lambda *a, **k: pytest.fail("computed before taking the lock"))
    with pytest.raises(run_lib.RunError) as e:
        run_lib.train(cfg, run_dir, resume=True, log=lambda s: None)
    msg = str(e.value)
    assert f"pid {proc.pid}" in msg and "run.lock" in msg and "another process" in msg, msg
    with pytest.raises(run_lib.RunError, match=f"pid {proc.pid}"):  # nor overwritten under it
        run_lib.train(cfg, run_dir, overwrite=True, log=lambda s: None)
    # the command line refuses it too, before JAX computes anything
    assert train_cli.main(["--workdir", str(run_dir), "--resume", "--config.generations=4"]) == 2
    assert f"pid {proc.pid}" in capsys.readouterr().err
    assert _snapshot(run_dir) == before
    # once the holder is gone (killed: its lock file stays behind), the lock is taken over, with a message
    proc.kill()
    proc.wait()
    assert (run_dir / "run.lock").is_file()
    monkeypatch.undo()
    stub_step(monkeypatch, _fake_step)
    monkeypatch.setattr(run_lib.Trainer, "validation_baselines", lambda self: dict(BASELINES))
    logs = []
    run_lib.train(cfg, run_dir, resume=True, log=logs.append)
    assert any(f"pid {proc.pid}" in line and "taking it over" in line for line in logs), logs
    assert not (run_dir / "run.lock").exists()  # released at the end


def test_the_lock_is_released_when_the_run_fails(run_dir, monkeypatch):
    def boom(self, state):
        raise KeyboardInterrupt

    stub_step(monkeypatch, boom)
    with pytest.raises(KeyboardInterrupt):
        run_lib.train(_cfg(run_dir, DONE + 2), run_dir, resume=True, log=lambda s: None)
    assert not (run_dir / "run.lock").exists()
    lock = run_lib.RunLock(run_dir)  # free: this process takes it again
    lock.acquire()
    lock.release()
    # a fresh run refused (here: its config) leaves no directory behind
    fresh = run_dir.parent / "fresh"
    bad = cfg_lib.load(None, [*SMALL, "generations=2"])
    bad.trials = 0
    with pytest.raises(cfg_lib.ConfigError):
        run_lib.train(bad, fresh, log=lambda s: None)
    assert not fresh.exists()


# 4. orbax's temporary folders ---------------------------------------------------------------------

def test_orbax_temporary_folders_are_not_checkpoints_and_are_cleaned_on_resume(run_dir):
    ckpt_dir = run_dir / "checkpoints"
    # what a kill during the save of checkpoint 3 leaves: a nearly complete copy under a temporary name
    tmp = ckpt_dir / f"{DONE + 1}.orbax-checkpoint-tmp-1712345678901234"
    shutil.copytree(ckpt_dir / str(DONE), tmp)
    (ckpt_dir / "partial.orbax-checkpoint-tmp-17").mkdir()
    assert ckpt.steps(run_dir) == [DONE]
    assert ckpt.set_aside_after(run_dir, 0) is not None and tmp.is_dir()  # never moved as a checkpoint
    shutil.move(str(next((run_dir / "abandoned").glob(f"*/checkpoints/{DONE}"))), str(ckpt_dir / str(DONE)))
    shutil.rmtree(run_dir / "abandoned")
    logs = []
    run_lib.train(_cfg(run_dir, DONE + 1), run_dir, resume=True, log=logs.append)
    assert sorted(p.name for p in ckpt_dir.iterdir()) == [str(DONE), str(DONE + 1)]
    assert ckpt.steps(run_dir) == [DONE, DONE + 1]
    assert any("orbax-checkpoint-tmp" in line and "removed" in line for line in logs), logs


# 5. kx.evaluate -----------------------------------------------------------------------------------

FITNESS = np.array([0.1, 0.2, 0.3, 0.6])
# by hand: mean 0.3, sample sd sqrt(0.14 / 3) = 0.2160246899, sem sd / 2 = 0.1080123450, t(0.975, df 3) =
# 3.1824463053 (a t table's 3.182): half width 0.3437435
HALF = 0.3437435


def test_evaluate_writes_its_json_atomically_with_a_t_interval(run_dir, monkeypatch, capsys):
    from kx.sim import evaluate as ev
    from kx.sim.types import Reason

    def fake_evaluate(policy, params, starts, *a, **k):
        n = FITNESS.size
        return types.SimpleNamespace(fitness=FITNESS[None], reason=np.full((1, n), int(Reason.TACKLED)),
                                     passes=np.arange(n)[None])

    monkeypatch.setattr(ev, "evaluate", fake_evaluate)
    written = []
    real = outputs.write_json
    monkeypatch.setattr(outputs, "write_json", lambda path, obj: (written.append(pathlib.Path(path)), real(path, obj)))
    assert evaluate_cli.main([str(run_dir), "--trials", str(FITNESS.size), "--no-baselines"]) == 0
    out = run_dir / "eval" / f"3v2-{FITNESS.size}-seed0.json"
    assert written == [out]
    champ = json.loads(out.read_text())["champion"]
    assert champ["mean_fitness"] == pytest.approx(0.3)
    assert champ["sd"] == pytest.approx(0.2160246899)
    assert champ["ci95"] == pytest.approx([0.3 - HALF, 0.3 + HALF], abs=1e-6)
    assert "95% CI -0.0437..0.6437" in capsys.readouterr().out


def test_confidence_interval_edge_cases():
    assert evaluate_cli.ci95(FITNESS) == pytest.approx((0.3 - HALF, 0.3 + HALF), abs=1e-6)
    assert evaluate_cli.ci95(np.full(5, 0.25)) == (0.25, 0.25)  # no spread: the mean itself
    assert evaluate_cli.ci95(np.array([0.4])) is None  # one trial: no interval


def test_write_json_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "a.json"
    outputs.write_json(path, {"x": 1})

    def fail(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(outputs.os, "replace", fail)
    with pytest.raises(OSError):
        outputs.write_json(path, {"x": 2})
    monkeypatch.undo()
    assert json.loads(path.read_text()) == {"x": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]  # no temporary file left


# 6. a bare boolean override -----------------------------------------------------------------------

def test_a_bare_boolean_override_means_true_and_takes_no_option_as_its_value(run_dir, monkeypatch, capsys):
    got = []
    monkeypatch.setattr(run_lib, "train", lambda cfg, workdir, **kw: got.append((cfg, kw)))
    w = ["--workdir", str(run_dir)]
    assert train_cli.main([*w, "--config.gif", "--resume"]) == 0  # the saved run has gif = false
    cfg, kw = got.pop()
    assert cfg.gif is True and kw["resume"] is True
    assert train_cli.main([*w, "--resume", "--config.gif"]) == 0  # last on the line
    assert got.pop()[0].gif is True
    assert train_cli.main([*w, "--resume", "--config.gif=false", "--config.generations", "5"]) == 0
    cfg, _ = got.pop()
    assert cfg.gif is False and cfg.generations == 5
    # a field that is not true/false needs its value; the next option is never taken as it
    assert train_cli.main([*w, "--config.generations", "--resume"]) == 2
    assert "--config.generations: needs a value" in capsys.readouterr().err
    assert train_cli.main([*w, "--resume", "--config.nope"]) == 2
    assert "nope: no such config field" in capsys.readouterr().err
    # a fresh run's config file, too
    assert train_cli.main(["--workdir", str(run_dir.parent / "new"), "--config", "configs/cma_es_3v2.py",
                           "--config.gif", "--overwrite"]) == 0
    cfg, kw = got.pop()
    assert cfg.gif is True and cfg.method == "cma_es" and kw["overwrite"] is True
    assert not got


def test_the_best_checkpoint_kept_is_the_earliest_of_equal_scores(tmp_path):
    """The preservation policy keeps the checkpoint of the run's champion, which is the earliest of
    equally validated generation champions: with validations 0.3, 0.5, 0.5, 0.2 and one latest kept,
    the checkpoints left are 2 (not 3) and 4."""
    import numpy as np

    mgr = ckpt.manager(tmp_path / "checkpoints", keep=1)
    for step, v in enumerate([0.3, 0.5, 0.5, 0.2], start=1):
        ckpt.save(mgr, step, {"x": np.full((2,), step, np.float32)}, {"champion_validation": v, "generation": step})
    assert ckpt.steps(tmp_path) == [2, 4]
