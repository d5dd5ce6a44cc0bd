"""Policy transfer through the run loop (kx.evolve.transfer): seedings, the source's record, refusals.

Algorithm 1 itself (the full-layout genome mapping) is tested in test_neat_transfer.py; here the
source runs are tiny (a few genomes, short episodes) and built once per module.
"""

from __future__ import annotations

import json
import pathlib
import shutil

import jax
import numpy as np
import pytest

from kx.evolve import checkpoint as ckpt
from kx.evolve import config as cfg_lib
from kx.evolve import run as run_lib
from kx.evolve import streams, transfer
from kx.evolve.checkpoint import RunError
from kx.evolve.config import ConfigError
from kx.evolve.trainer import RunGroup
from kx.neat.checks import check_population
from kx.sim import env

REPO = pathlib.Path(__file__).resolve().parents[1]
COMMON = ["trials=2", "sim.max_iterations=60", "validation_trials=4", "gif=false", "checkpoint_every=1",
          "keep_checkpoints=5"]
SIZES = {"neat": 12, "hyperneat": 12, "cma_es": 6}
SOURCE_GENERATIONS = 2


def _config(method: str, task: str = "3v2", *extra: str):
    return cfg_lib.load(REPO / "configs" / f"{method}_{task}.py",
                        [f"population_size={SIZES[method]}", *COMMON, *extra])


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """Each method's tiny 3v2 source run, trained once when first asked for."""
    built = {}

    def get(method):
        if method not in built:
            run_dir = tmp_path_factory.mktemp("sources") / method
            run_lib.train(_config(method, "3v2", f"generations={SOURCE_GENERATIONS}"), run_dir, log=lambda s: None)
            built[method] = run_dir
        return built[method]
    return get


def _target(method, source_dir, task="4v3", *extra):
    return _config(method, task, "generations=1", f"transfer.source={source_dir}", *extra)


def _leaves_equal(a, b) -> bool:
    return all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


# HyperNEAT's CPPNs carry over unchanged (no map of inputs): its variant in the slow set (~12 s)
@pytest.mark.parametrize("method", ["neat", pytest.param("hyperneat", marks=pytest.mark.slow)])
def test_population_carries_over_and_keeps_its_source_fitness(sources, method):
    """Fixed-layout genomes and CPPNs carry over unchanged: the target's first population is the source
    checkpoint's, and on the source's own start states it scores exactly what the source run gives it
    in its next generation."""
    src_dir = sources(method)
    trainer = run_lib.Trainer(_target(method, src_dir))
    state = trainer.init()
    src_trainer, step, src_state, _ = run_lib.restore(src_dir)
    assert step == SOURCE_GENERATIONS
    assert _leaves_equal(state.learner.population, src_state.learner.population)
    assert int(state.generation) == 0 and int(state.champion_generation) == -1
    assert check_population(state.learner.population, trainer.encoding.neat_config) == []
    # the innovation counters carry on (new innovations never reuse a source number)
    assert int(state.learner.next_innov) == int(src_state.learner.next_innov)
    assert int(state.learner.next_node_id) == int(src_state.learner.next_node_id)

    # the source run's generation SOURCE_GENERATIONS, evaluated by the source run itself
    src_row = src_trainer.step(src_state).row
    keys = streams.training(src_trainer.cfg.seed, SOURCE_GENERATIONS)
    starts = env.reset_batch(keys.starts, src_trainer.cfg.trials, src_trainer.exp.sim_params, src_trainer.exp.sim)
    f = np.asarray(src_trainer.evaluate(state.learner.population, starts, keys.eval).fitness.mean(axis=1))
    assert f.max() == np.float32(src_row["best_fitness"])
    assert np.float32(np.clip(f.mean(), f.min(), f.max())) == np.float32(src_row["mean_fitness"])


@pytest.mark.slow  # a full-layout run compiles its own programs (about 60 s); Algorithm 1 itself: test_neat_transfer.py
def test_full_layout_population_mapped_by_algorithm_1(tmp_path):
    """A full-layout 3v2 population (13 inputs, 3 outputs) seeds a 4v3 run (19 inputs, 4 outputs) through
    Algorithm 1 (kx.neat.transfer, tested on its own in test_neat_transfer.py), and the target plays on."""
    from kx.neat.algorithm import build_networks
    from kx.neat.network import forward
    from kx.sim import observe

    full = REPO / "configs" / "neat_full_3v2.py"
    src_dir = tmp_path / "src"
    run_lib.train(cfg_lib.load(full, ["population_size=12", *COMMON, "generations=1"]), src_dir, log=lambda s: None)
    cfg = cfg_lib.load(full, ["population_size=12", *COMMON, "generations=1", "task=4v3",
                              f"transfer.source={src_dir}"])
    trainer = run_lib.Trainer(cfg)
    state = trainer.init()
    t_cfg, s_state = trainer.encoding.neat_config, trainer.source.state
    s_cfg = trainer.source.encoding.neat_config
    assert (s_cfg.n_inputs, s_cfg.n_outputs, t_cfg.n_inputs, t_cfg.n_outputs) == (13, 3, 19, 4)
    assert check_population(state.learner.population, t_cfg) == []
    # with the new agents' inputs at 0, the old outputs are the source network's
    in_map, out_map = observe.full_layout_map(trainer.source.encoding.sim, trainer.encoding.sim)
    x = np.random.default_rng(0).uniform(0, 1, (13, 5)).astype(np.float32)
    xt = np.zeros((19, 5), np.float32)
    xt[list(in_map)] = x
    src_out = jax.vmap(lambda n: forward(n, x, s_cfg))(build_networks(s_state.learner.population, s_cfg))
    tgt_out = jax.vmap(lambda n: forward(n, xt, t_cfg))(build_networks(state.learner.population, t_cfg))
    np.testing.assert_allclose(np.asarray(tgt_out)[:, list(out_map)], np.asarray(src_out), atol=1e-5)
    result = trainer.step(state)
    assert result.row["generation"] == 0 and np.isfinite(result.row["best_fitness"])
    assert check_population(result.state.learner.population, t_cfg) == []


# "half" (~8 s cold: its own seeding program) in the slow set; the champion's mutated copies stay in the default suite
@pytest.mark.parametrize("seeding", ["champion", pytest.param("half", marks=pytest.mark.slow)])
def test_seedings_with_mutated_copies(sources, seeding):
    src_dir = sources("neat")
    trainer = run_lib.Trainer(_target("neat", src_dir, "4v3", f"transfer.seeding={seeding}"))
    state = trainer.init()
    pop = state.learner.population
    src = trainer.source
    p = trainer.cfg.population_size
    assert check_population(pop, trainer.encoding.neat_config) == []
    if seeding == "champion":
        seeds = jax.tree.map(lambda a: a[None], src.state.champion)
    else:
        order = src.ranking()
        seeds = jax.tree.map(lambda a: a[order[: (p + 1) // 2]], src.state.learner.population)
        # the ranking is by fitness on the source's validation states, fittest first
        t = src.trainer
        fv = np.asarray(t.evaluate(src.state.learner.population, t.validation_starts,
                                   t.validation_eval_key).fitness.mean(axis=1))
        assert np.all(np.diff(fv[order]) <= 0)
    m = jax.tree.leaves(seeds)[0].shape[0]
    assert _leaves_equal(jax.tree.map(lambda a: a[:m], pop), seeds)
    # the copies are mutated once, as offspring are (a weight mutation that selects no gene, or an
    # add-link with no link left, leaves a copy as it was: most copies still differ from their seed)
    changed = [not _leaves_equal(jax.tree.map(lambda a: np.asarray(a[i]), pop),
                                 jax.tree.map(lambda a: np.asarray(a[i % m]), seeds)) for i in range(m, p)]
    assert sum(changed) >= len(changed) / 2, changed


@pytest.mark.slow  # CMA-ES compiles its own programs (about 20 s); the default suite transfers NEAT and HyperNEAT
def test_cma_es_starts_at_the_source_distribution(sources, tmp_path):
    src_dir = sources("cma_es")
    trainer = run_lib.Trainer(_target("cma_es", src_dir))
    state = trainer.init()
    src = trainer.source
    np.testing.assert_array_equal(np.asarray(state.learner.mean), np.asarray(src.state.learner.mean))
    assert float(state.learner.std) == float(src.state.learner.std)
    champ = run_lib.Trainer(_target("cma_es", src_dir, "4v3", "transfer.seeding=champion")).init()
    np.testing.assert_array_equal(np.asarray(champ.learner.mean), np.asarray(src.state.champion))
    # CMA-ES carries a distribution: no fittest half
    _refused(_target("cma_es", src_dir, "4v3", "transfer.seeding=half"), tmp_path, "transfer.seeding", "'half'")


@pytest.mark.slow  # 15-40 s cold: the default suite's 7 minutes in a fresh clone on an AVX2 CPU (make test-slow)
def test_target_run_records_its_source_and_resumes(sources, tmp_path):
    src_dir = sources("neat")
    run_dir = tmp_path / "target"
    run_lib.train(_target("neat", src_dir, "4v3", "generations=1"), run_dir, log=lambda s: None)
    record = json.loads((run_dir / "config.json").read_text())[cfg_lib.SOURCE_RECORD]
    _, step, src_state, _ = run_lib.restore(src_dir)
    assert record["path"] == str(src_dir.resolve()) and record["step"] == step == SOURCE_GENERATIONS
    assert record["source_objective"] == record["target_objective"] == "fitness"
    assert record["generation"] == SOURCE_GENERATIONS and record["task"] == "3v2" and record["seeding"] == "population"
    assert record["config"] == cfg_lib.read_run_config(src_dir / "config.json").to_dict()
    assert record["digest"] == transfer.digest(src_state) and record["digest"].startswith("sha256:")
    # the record does not stop the run from being read or resumed; a resumed run keeps it
    cfg = cfg_lib.read_run_config(run_dir / "config.json")
    assert cfg.transfer.source == str(src_dir)
    cfg.generations = 2
    row = run_lib.train(cfg, run_dir, resume=True, log=lambda s: None)
    assert row["generation"] == 1
    assert json.loads((run_dir / "config.json").read_text())[cfg_lib.SOURCE_RECORD] == record
    # the target's own checkpoints restore through the fresh-run template
    _, got, _, _ = run_lib.restore(run_dir)
    assert got == 2


class _Killed(Exception):
    """The process killed (a stand-in for SIGKILL)."""


def _start_and_kill(cfg, run_dir, monkeypatch, at: str) -> None:
    """Starts the run of ``cfg`` and kills it before its first checkpoint: as its first generation
    starts (``at="step"``) or as that generation's checkpoint is written (``at="save"``)."""
    def killed(*args, **kwargs):
        raise _Killed(at)
    with monkeypatch.context() as m:
        if at == "step":
            m.setattr(RunGroup, "step", killed)  # the generation step there is, for a run alone too
        else:
            m.setattr(ckpt, "save", killed)
        with pytest.raises(_Killed):
            run_lib.train(cfg, run_dir, log=lambda s: None)
    assert (run_dir / "config.json").is_file() and ckpt.steps(run_dir) == []


def _files(run_dir: pathlib.Path) -> dict:
    """Every file of a run directory and its bytes (the run's lock file aside: it is not the run's)."""
    return {str(f.relative_to(run_dir)): f.read_bytes() for f in sorted(run_dir.rglob("*"))
            if f.is_file() and f.name != "run.lock"}


def _record(run_dir: pathlib.Path) -> dict:
    return json.loads((run_dir / "config.json").read_text())[cfg_lib.SOURCE_RECORD]


def _resume_source(src_dir: pathlib.Path, generations: int) -> None:
    cfg = cfg_lib.read_run_config(src_dir / "config.json")
    cfg.generations = generations
    run_lib.train(cfg, src_dir, resume=True, log=lambda s: None)


def test_record_pins_the_source_before_the_first_generation(tmp_path, monkeypatch):
    """config.json holds the source's resolved absolute path, its concrete checkpoint step (not -1), the
    digest of that checkpoint's state and both runs' objectives before the target's first generation runs."""
    monkeypatch.chdir(tmp_path)
    run_lib.train(_config("neat", "3v2", "generations=1", "objective=hybrid"), tmp_path / "src", log=lambda s: None)
    cfg = _target("neat", "src", "4v3")  # relative, the latest checkpoint
    assert cfg.transfer.step == -1 and cfg.objective == "fitness"
    run_dir = tmp_path / "target"
    _start_and_kill(cfg, run_dir, monkeypatch, at="step")
    record = _record(run_dir)
    _, step, src_state, _ = run_lib.restore(tmp_path / "src")
    assert set(record) == set(transfer.RECORD_KEYS)
    assert record["path"] == str((tmp_path / "src").resolve()) and pathlib.Path(record["path"]).is_absolute()
    assert record["step"] == step == 1 and record["generation"] == 1
    assert record["digest"] == transfer.digest(src_state)
    assert record["source_objective"] == "hybrid" and record["target_objective"] == "fitness"
    assert record["config"]["objective"] == "hybrid"
    # the config itself keeps what was asked
    assert cfg_lib.read_run_config(run_dir / "config.json").transfer.to_dict() == cfg.transfer.to_dict()


def test_resume_before_first_checkpoint_refused_after_source_gained_a_checkpoint(tmp_path, monkeypatch):
    """A target (relative transfer.source, transfer.step=-1) killed before its first checkpoint, resumed
    after its source gained a checkpoint: the source's owner continued it from checkpoint 1 with a
    checkpoint every 3 generations, so checkpoint 2, which seeded the target, is set aside and the latest
    is 3. Resuming the target is refused with the reason, before anything is written; -1 is not resolved
    again to checkpoint 3."""
    monkeypatch.chdir(tmp_path)
    src_dir = tmp_path / "src"
    run_lib.train(_config("neat", "3v2", "generations=2"), src_dir, log=lambda s: None)
    cfg = _target("neat", "src", "4v3")
    run_dir = tmp_path / "target"
    _start_and_kill(cfg, run_dir, monkeypatch, at="save")  # generation 0 ran, its checkpoint never written
    record = _record(run_dir)
    assert record["step"] == 2 and record["path"] == str(src_dir.resolve())
    scfg = cfg_lib.read_run_config(src_dir / "config.json")
    scfg.generations, scfg.checkpoint_every = 3, 3
    run_lib.train(scfg, src_dir, resume=True, step=1, log=lambda s: None)
    assert ckpt.steps(src_dir) == [1, 3]
    before = _files(run_dir)
    with pytest.raises(RunError) as e:
        run_lib.train(cfg, run_dir, resume=True, log=lambda s: None)
    msg = str(e.value)
    for needle in ("--resume", "no checkpoint yet", "transfer_source.step", "recorded checkpoint 2",
                   str(src_dir.resolve()), "found checkpoints [1, 3]"):
        assert needle in msg, msg
    assert _files(run_dir) == before, "refused after writing"
    assert _record(run_dir) == record


def test_resume_before_first_checkpoint_reseeds_from_the_recorded_checkpoint(tmp_path, monkeypatch):
    """The record is the authority: a target resumed before its first checkpoint reseeds from the recorded
    absolute path and step (not from a relative transfer.source resolved in another working directory,
    nor from the newer checkpoint the source has gained) and keeps the record; a source retrained in
    place (another digest) or gone is refused with the field, what was recorded and what was found."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    src_dir = work / "src"
    run_lib.train(_config("neat", "3v2", "generations=1"), src_dir, log=lambda s: None)
    cfg = _target("neat", "src", "4v3")
    run_dir, spare = tmp_path / "target", tmp_path / "spare"
    _start_and_kill(cfg, run_dir, monkeypatch, at="save")
    shutil.copytree(run_dir, spare)
    record = _record(run_dir)
    _resume_source(src_dir, 2)
    assert ckpt.steps(src_dir) == [1, 2]

    elsewhere = tmp_path / "elsewhere"  # where "src" names nothing
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    logged = []
    run_lib.train(cfg, run_dir, resume=True, log=logged.append)
    assert _record(run_dir) == record
    assert any(f"from {src_dir.resolve()} checkpoint 1 " in line for line in logged), logged
    # generation 0 of the resumed target is the one seeded from checkpoint 1, named explicitly
    explicit = run_lib.Trainer(_target("neat", src_dir.resolve(), "4v3", "transfer.step=1"))
    want = explicit.step(explicit.init()).state
    _, got, state, _ = run_lib.restore(run_dir)
    assert got == 1 and transfer.digest(state) == transfer.digest(want)

    # the source retrained in place (another seed): checkpoint 1 is there, with another state
    run_lib.train(_config("neat", "3v2", "generations=1", "seed=1"), src_dir, overwrite=True, log=lambda s: None)
    before = _files(spare)
    with pytest.raises(RunError) as e:
        run_lib.train(cfg, spare, resume=True, log=lambda s: None)
    msg = str(e.value)
    for needle in ("transfer_source.digest", f"recorded {record['digest']}", "found sha256:",
                   "seed = 0 recorded, 1 now"):
        assert needle in msg, msg
    # the source gone
    shutil.rmtree(src_dir)
    with pytest.raises(RunError) as e:
        run_lib.train(cfg, spare, resume=True, log=lambda s: None)
    assert "transfer_source.path" in str(e.value) and f"recorded {src_dir.resolve()}" in str(e.value), str(e.value)
    assert _files(spare) == before, "refused after writing"


def test_novelty_archive_starts_empty_in_the_target(tmp_path):
    """Behaviours of two tasks are not comparable: a hybrid source's archive stays behind."""
    src_dir = tmp_path / "src"
    run_lib.train(_config("neat", "3v2", "generations=1", "objective=hybrid"), src_dir, log=lambda s: None)
    _, _, src_state, _ = run_lib.restore(src_dir)
    assert int(src_state.objective.size) > 0  # so a carried-over archive would show
    trainer = run_lib.Trainer(_target("neat", src_dir, "4v3", "objective=hybrid"))
    state = trainer.init()
    assert int(state.objective.size) == 0 and not np.any(np.asarray(state.objective.entries))
    assert _leaves_equal(state.learner.population, src_state.learner.population)
    # the first generation measures novelty against that empty archive: afterwards it holds only the
    # target's own admissions
    row = trainer.step(state).row
    assert row["archive_size"] == row["archive_added"] > 0


def _refused(cfg, tmp_path, *needles):
    run_dir = tmp_path / "refused"
    with pytest.raises(ConfigError) as e:
        run_lib.train(cfg, run_dir, log=lambda s: None)
    assert not run_dir.exists(), "refused after writing"
    for n in needles:
        assert n in str(e.value), str(e.value)
    return str(e.value)


def test_refusals(sources, tmp_path):
    neat_src = sources("neat")
    # one method into another, both ways (a HyperNEAT source as its config.json says, which is all that is read
    # before the refusal: no HyperNEAT run is trained for it)
    hn_src = tmp_path / "hn"
    shutil.copytree(neat_src, hn_src)
    (hn_src / "config.json").write_text(json.dumps(_config("hyperneat", "3v2").to_dict()))
    _refused(_target("neat", hn_src), tmp_path, "transfer.source", "'hyperneat' run", "'neat'")
    _refused(_target("hyperneat", neat_src), tmp_path, "transfer.source", "'neat' run", "'hyperneat'")
    # a source larger than the target
    big = tmp_path / "big"
    shutil.copytree(neat_src, big)
    d = json.loads((big / "config.json").read_text())
    d["task"] = "5v3"
    (big / "config.json").write_text(json.dumps(d))
    _refused(_target("neat", big, "4v3"), tmp_path, "transfer.source", "larger", "5v3", "4v3")
    # genome capacity that does not fit
    _refused(_target("neat", neat_src, "4v3", "neat.max_hidden=1"), tmp_path, "transfer.source", "neat.max_hidden",
             "does not fit")
    # the population seeding needs the source's population size
    _refused(_target("neat", neat_src, "4v3", "population_size=10"), tmp_path, "12 genomes", "population_size")
    # missing, not a run, corrupt config, damaged checkpoint, absent step
    _refused(_target("neat", tmp_path / "nowhere"), tmp_path, "transfer.source", "not a directory")
    empty = tmp_path / "empty"
    empty.mkdir()
    _refused(_target("neat", empty), tmp_path, "transfer.source", "config.json")
    corrupt = tmp_path / "corrupt"
    shutil.copytree(neat_src, corrupt)
    (corrupt / "config.json").write_text("{not json")
    _refused(_target("neat", corrupt), tmp_path, "transfer.source", "corrupt")
    damaged = tmp_path / "damaged"
    shutil.copytree(neat_src, damaged)
    for f in (damaged / "checkpoints" / str(SOURCE_GENERATIONS) / "state").rglob("*"):
        if f.is_file() and f.stat().st_size > 0:
            f.write_bytes(b"\0" * f.stat().st_size)
    _refused(_target("neat", damaged), tmp_path, "transfer.source", "checkpoint")
    _refused(_target("neat", neat_src, "4v3", "transfer.step=7"), tmp_path, "transfer.step", "no checkpoint 7")


def test_unknown_seeding_and_step_refused_by_validate():
    for field, value, needle in (("seeding", "'best'", "transfer.seeding: allowed one of"),
                                 ("step", "0", "transfer.step: allowed -1")):
        cfg = cfg_lib.load(None, [f"transfer.{field}={value}"])
        with pytest.raises(ConfigError, match=needle):
            cfg_lib.validate(cfg)
