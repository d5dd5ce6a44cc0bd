"""The run loop's public interface: an encoding defined here, outside kx, trains end to end; no method
recompiles the evaluator or its generation step from one generation to the next."""

import csv
import json
import logging
import re

import jax
import jax.extend.core.primitives as jax_primitives
import jax.numpy as jnp
import ml_collections
import numpy as np
import pytest

from kx import evaluate as evaluate_cli
from kx.evolve import checkpoint as ckpt
from kx.evolve import config as cfg_lib
from kx.evolve import encoding as encodings
from kx.evolve import registry, streams
from kx.evolve import run as run_lib
from kx.sim import env, observe, policies


class HillClimber(encodings.Encoding):
    """A (1, P) hill climber on the linear policy: the population is the parent and P - 1 Gaussian
    perturbations of it; the best by score becomes the parent. Uses only kx's public interfaces."""

    name = "toy_hill_climber"
    section = "toy"
    metric_fields = ("step_size", "parent_norm")
    plot_field = "step_size"

    @classmethod
    def default_config(cls):
        return ml_collections.ConfigDict({"step_size": 0.5})

    def __init__(self, cfg, sim, sim_params):
        super().__init__(cfg, sim, sim_params)
        if not (isinstance(cfg.toy.step_size, float) and cfg.toy.step_size > 0):
            raise cfg_lib.ConfigError(f"toy.step_size: allowed a number > 0, got {cfg.toy.step_size!r}")
        self.dim = observe.n_inputs(self.layout, sim) * 3 + 3

    def init(self, key):
        return {"parent": jax.random.normal(key, (self.dim,)), "step": jnp.float32(self.cfg.toy.step_size)}

    def ask(self, key, state):
        noise = jax.random.normal(key, (self.population_size - 1, self.dim)) * state["step"]
        return jnp.concatenate([state["parent"][None], state["parent"] + noise]), state

    def tell(self, key, population, score, fitness, state):
        state = {"parent": population[jnp.argmax(score)], "step": state["step"]}
        return state, {"step_size": state["step"], "parent_norm": jnp.linalg.norm(state["parent"])}

    def policy_for(self, sim):
        return policies.linear_policy(sim, self.layout)

    def policy_params(self, population):
        return policies.linear_params(population, self.sim, self.layout)


@pytest.fixture(scope="module")
def toy():
    registry.register(HillClimber)
    yield HillClimber
    registry.ENCODINGS.pop(HillClimber.name)


def _cfg(**over):
    cfg = cfg_lib.base_config(HillClimber.name)
    cfg.update(dict(population_size=6, trials=2, generations=4, checkpoint_every=2, validation_trials=4,
                    gif_frames=10))
    cfg.sim.max_iterations = 60  # the trials, validation and episode length of the other run tests (SMALL)
    cfg.update(over)
    return cfg


@pytest.mark.slow  # ~22 s cold on an AVX2 CPU: the suite's 7 minutes (the encoding protocol's unit tests stay)
def test_an_encoding_defined_outside_kx_trains_end_to_end(toy, tmp_path, capsys):
    cfg = _cfg()
    assert "toy.step_size: allowed a number > 0" in str(pytest.raises(
        cfg_lib.ConfigError, cfg_lib.validate, _cfg(toy=ml_collections.ConfigDict({"step_size": -1.0}))).value)
    logs = []
    final = run_lib.train(cfg, tmp_path / "toy", log=logs.append)
    assert final["generation"] == 3
    with (tmp_path / "toy" / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [int(r["generation"]) for r in rows] == [0, 1, 2, 3]
    assert all(float(r["step_size"]) == 0.5 for r in rows)
    # the loop hands tell each member's own score: the parent the hill climber breeds from is the
    # member that plays best on the generation's start states (replayed here with the population in
    # reverse order: the same shapes, nothing new to compile), and metrics.csv reports their fitness
    trainer = run_lib.Trainer(cfg)
    state, replaced = trainer.init(), []
    for g in range(2):
        population, _ = trainer.encoding.ask(streams.learner_ask(cfg.seed, g), state.learner)
        keys = streams.training(cfg.seed, g)
        starts = env.reset_batch(keys.starts, cfg.trials, trainer.exp.sim_params, trainer.exp.sim)
        f = np.asarray(trainer.evaluate(population[::-1], starts, keys.eval).fitness.mean(axis=1))[::-1]
        state = trainer.step(state).state
        np.testing.assert_array_equal(np.asarray(state.learner["parent"]), np.asarray(population[np.argmax(f)]))
        assert float(rows[g]["best_fitness"]) == float(f.max())
        assert float(rows[g]["median_fitness"]) == float(np.median(f))
        replaced.append(int(np.argmax(f)) != 0)  # a perturbation beat the parent (index 0)
    assert any(replaced), "the parent was never replaced: the check above would hold for a loop that ignored the score"
    for name in ("config.json", "metrics.csv", "baselines.json", "progress.png", "champion.gif"):
        assert (tmp_path / "toy" / name).is_file(), name
    assert ckpt.steps(tmp_path / "toy") == [2, 4]
    assert any("toy_hill_climber" in line for line in logs) and any(line.startswith("gen   4/4") for line in logs)
    # resumed from checkpoint 2 it ends bit for bit where the uninterrupted run ended
    trainer, step, a, _ = run_lib.restore(tmp_path / "toy")
    assert step == 4
    run_lib.train(cfg, tmp_path / "toy", resume=True, step=2, log=logs.append)
    _, _, b, _ = run_lib.restore(tmp_path / "toy")
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    # and the same in memory, with no run directory
    c, _ = run_lib.evolve_in_memory(run_lib.Trainer(cfg))
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(c), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    # kx.evaluate plays its champion (test_train plays NEAT's and CMA-ES's in another task)
    assert evaluate_cli.main([str(tmp_path / "toy"), "--trials", "8", "--no-baselines"]) == 0
    out = json.loads((tmp_path / "toy" / "eval" / "3v2-8-seed0.json").read_text())
    assert out["method"] == HillClimber.name and 0 < out["champion"]["mean_fitness"] <= 1


PRIMITIVES = {p.name for p in vars(jax_primitives).values() if hasattr(p, "bind") and hasattr(p, "name")}


class _Compiles(logging.Handler):
    def __init__(self):
        super().__init__()
        self.seen = []

    def emit(self, record):
        m = re.match(r"Compiling (\S+) with global shapes and types (.*)\. Argument mapping", record.getMessage())
        # One primitive applied eagerly (jit(slice) of a key array, say) compiles once per static parameter
        # (its slice bounds), which the log does not show: only programs, which the log describes
        # fully by their shapes, are tracked. A weak type turned strong is a recompile with the same
        # shapes: compare without the mark.
        if m and m.group(1)[4:-1] not in PRIMITIVES:
            self.seen.append((m.group(1), m.group(2).replace("~", "").replace(", weak_type=True", "")))


def _compiles_during(fn):
    """``(result, [(program, shapes)] compiled while fn ran)``."""
    handler = _Compiles()
    logger = logging.getLogger("jax._src.interpreters.pxla")
    logger.addHandler(handler)
    old = jax.config.jax_log_compiles
    jax.config.update("jax_log_compiles", True)
    try:
        return fn(), handler.seen
    finally:
        jax.config.update("jax_log_compiles", old)
        logger.removeHandler(handler)


@pytest.mark.parametrize("method, size", [("neat", 12), ("cma_es", 6), (HillClimber.name, 7)])
def test_no_method_recompiles_the_evaluator_or_its_step_across_generations(toy, method, size):
    """After the first generations (which compile every function, and the evaluator's batch widths
    reached so far), a generation compiles nothing it compiled before: new values of the population,
    its networks or its shared table reuse the compiled programs. A batch width reached for the first
    time compiles once (each width is a program of its own)."""
    cfg = cfg_lib.base_config(method) if method != HillClimber.name else _cfg()
    cfg.update(dict(population_size=size, trials=2, validation_trials=4, generations=5))
    cfg.sim.max_iterations = 60
    trainer = run_lib.Trainer(cfg)
    state, compiled_by_init = _compiles_during(trainer.init)
    per_generation = []
    for g in range(cfg.generations):
        result, compiles = _compiles_during(lambda: trainer.step(state))
        state = result.state
        per_generation.append((compiled_by_init if g == 0 else []) + compiles)  # init counts as generation 0's
    # the log works (a new function compiles); generation 0 itself may compile nothing when another test
    # of this worker compiled the same shapes first (test_transfer.py's), which is the point of the cache
    _, probe = _compiles_during(lambda: jax.jit(lambda x: x * 2.0 + 1.0)(jnp.arange(3.0)))
    assert probe, "the log of compilations caught nothing: the test would pass vacuously"
    # generation 0 (init and the first step) may compile one function twice with the same argument shapes:
    # a jitted helper with static arguments (jax.random.normal's shape, in the toy's eager init and ask)
    # compiles once per static value, which the log does not show; after it, nothing compiles again
    assert_nothing_compiles_twice(per_generation, first=1)


def assert_nothing_compiles_twice(per_generation, first: int):
    """``per_generation[i]``: the programs compiled during step i. After the ``first`` steps (which may
    compile one function twice, see above), no step compiles a program with shapes compiled before, and
    from step ``first + 1`` on only the evaluator's programs compile for shapes reached for the first time:
    its rungs for a new batch width, and for a new count of NEAT's hidden rows (kx.neat.network.trim) the
    networks' program of that count, the group's slice of them, the first rung's lanes and the rungs."""
    seen = set().union(*per_generation[:first])
    for g, compiles in enumerate(per_generation[first:], first):
        for c in compiles:
            assert c not in seen, f"step {g} compiled {c[0]} again with the same shapes"
            seen.add(c)
    later = [c for compiles in per_generation[first + 1:] for c in compiles]
    new_shape = ("_advance", "_compact", "_prepare", "_hidden_rows", "_runs_slice")
    assert all(any(k in name for k in new_shape) for name, _ in later), [name for name, _ in later]


# HyperNEAT's two cases (~15 s cold each) with the long tests, for the suite's 7 minutes in a fresh clone on an AVX2
# CPU; NEAT's and CMA-ES's stay in the default suite
@pytest.mark.parametrize("method,objective", [
    (m, o) if m != "hyperneat" else pytest.param(m, o, marks=pytest.mark.slow)
    for m in ("neat", "hyperneat", "cma_es") for o in ("fitness", "hybrid")])
def test_a_second_run_in_the_same_process_compiles_nothing(method, objective):
    """Programs belong to the process, keyed by the static shapes of a run, not to a Trainer: a second
    Trainer of the same method, task, shapes and objective compiles nothing at all, and a run with
    another seed (traced, like every per-run value) compiles only evaluator batch widths that its
    episodes reach for the first time."""
    # the shapes of the test above (NEAT and CMA-ES): the first run reuses what that test compiled
    cfg = cfg_lib.base_config(method)
    size = {"neat": 12, "hyperneat": 12, "cma_es": 6}[method]  # test_transfer.py's sizes
    cfg.update(dict(population_size=size, trials=2, validation_trials=4, generations=2, objective=objective))
    cfg.sim.max_iterations = 60

    def run(seed):
        c = ml_collections.ConfigDict(cfg.to_dict())
        c.seed = seed
        state, rows = run_lib.evolve_in_memory(run_lib.Trainer(c))
        return np.asarray(jax.tree.leaves(state)[0]), rows

    # the log sees a compilation (a program no test has compiled before), so an empty log means nothing
    # compiled; the first run may compile nothing itself when the test above compiled its shapes
    _, probe = _compiles_during(lambda: jax.jit(lambda x: x * 3 + 1)(jnp.arange(5, dtype=jnp.int32)))
    assert probe, "the log of compilations caught nothing: the test would pass vacuously"
    (first_leaf, rows1), _ = _compiles_during(lambda: run(0))
    (again_leaf, rows2), again = _compiles_during(lambda: run(0))
    assert again == [], f"a second {method}/{objective} run compiled {[name for name, _ in again]}"
    np.testing.assert_array_equal(first_leaf, again_leaf)  # and it is the same run
    assert [r["best_fitness"] for r in rows1] == [r["best_fitness"] for r in rows2]
    _, other = _compiles_during(lambda: run(1))
    assert all("_advance" in name or "_compact" in name for name, _ in other), other
