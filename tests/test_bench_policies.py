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


@pytest.mark.slow  # ~40 s: compiles PPO's update and NEAT's evaluator
def test_the_ppo_benchmark_ends_with_its_machine_readable_line():
    out = subprocess.run([sys.executable, "-m", "kx.bench", "ppo", "--ppo-warmup", "2", "--repeats", "1",
                          "--sample-seconds", "0"], capture_output=True, text=True, check=True).stdout.strip()
    last = out.splitlines()[-1]
    assert re.fullmatch(r"ppo: \d+ env steps/s \(ratio \d+\.\d{3} vs neat evaluator\)", last), last
    assert "world iterations a step" in out and "neat evaluator:" in out
