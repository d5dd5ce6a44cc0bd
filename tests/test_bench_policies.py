"""``python -m kx.bench policies``: its committed trained populations load as the current encodings' genomes,
and (slow) the benchmark ends with its two machine-readable lines; so does ``python -m kx.bench ppo``."""

import re
import subprocess
import sys

import jax
import numpy as np
import pytest

from kx.bench import policies
from kx.evolve import streams


@pytest.mark.parametrize("method", policies.METHODS)
def test_fixture_is_a_population_of_the_encoding(method):
    trainer, population, meta = policies.load_fixture(method)
    assert meta["method"] == method and meta["population_size"] == trainer.cfg.population_size
    assert trainer.exp.sim.name == "4v3"
    # the same fields, shapes and types as a population the encoding asks for itself
    want = jax.eval_shape(lambda: trainer.encoding.ask(streams.learner_ask(0, 0), trainer.init().learner)[0])
    for f in want.__dataclass_fields__:
        got, ref = getattr(population, f), getattr(want, f)
        assert (got.shape, got.dtype) == (ref.shape, ref.dtype), f
    assert meta["source_generations"] >= 10 and meta["target_generations"] >= 1
    assert np.asarray(population.conn_valid).any(axis=1).all()


@pytest.mark.slow
def test_last_lines(tmp_path):
    out = subprocess.run([sys.executable, "-m", "kx.bench", "policies", "--repeats", "1", "--sample-seconds", "0"],
                         capture_output=True, text=True, check=True).stdout.strip().splitlines()
    assert re.fullmatch(r"neat: \d+ ns per live step \(ratio \d+\.\d\d vs heuristic\)", out[-2]), out[-2]
    assert re.fullmatch(r"policies: \d+ ns per live step hyperneat \(ratio \d+\.\d\d vs heuristic\)", out[-1]), out[-1]


@pytest.mark.slow  # ~40 s each: compiles PPO's update and NEAT's evaluator
@pytest.mark.parametrize("config", [None, "configs/ppo_entity_4v3.py"])
def test_the_ppo_benchmark_ends_with_its_machine_readable_line(config):
    extra = [] if config is None else ["--config", config]
    out = subprocess.run([sys.executable, "-m", "kx.bench", "ppo", "--ppo-warmup", "2", "--repeats", "1",
                          "--sample-seconds", "0", *extra], capture_output=True, text=True, check=True).stdout.strip()
    last = out.splitlines()[-1]
    assert re.fullmatch(r"ppo: \d+ env steps/s \(ratio \d+\.\d{3} vs neat evaluator\)", last), last
    assert "world iterations a step" in out and "neat evaluator:" in out
    assert ("ppo_entity (entity tokens" if config else "ppo (fixed layout") in out


@pytest.mark.parametrize("config, match", [
    ("configs/neat_4v3.py", r"--config: allowed a config of method 'ppo' or 'ppo_entity', got configs/neat_4v3.py "
                            r"\(method 'neat'\)"),
    ("configs/ppo_entity_3v2.py", r"--config: allowed a config of the NEAT fixture's task \(4v3\), got "
                                  r"configs/ppo_entity_3v2.py \(task 3v2\)")])
def test_the_ppo_benchmark_refuses_a_config_it_cannot_set_against_neat_before_any_compute(config, match, capsys):
    from kx.bench import __main__ as bench

    with pytest.raises(SystemExit, match=match):
        bench.main(["ppo", "--config", config])
    assert "devices:" not in capsys.readouterr().out  # refused before the first figure's work
