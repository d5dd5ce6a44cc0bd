"""``python -m kx.train`` for PPO on the entity network (``method = "ppo_entity"``): a run resumed from a checkpoint
ends bit for bit where the uninterrupted run does, the evaluator's decisions are the network's forward pass, the
champion plays every team size unchanged, a transfer to a bigger team starts from the source's weights, and a
batched group writes what each run writes alone (slow)."""

import pathlib

import jax
import numpy as np
import pytest
from test_train import _runs, resume_here  # noqa: F401  (the session cache of trained runs it uses)

from kx.evolve import config as cfg_lib
from kx.evolve import run as run_lib
from kx.evolve.encodings import ppo as ppo_enc
from kx.evolve.encodings.ppo import algorithm as ppo
from kx.evolve.errors import ConfigError
from kx.sim import entities, gym
from kx.sim.policies import Shared
from kx.sim.types import KeepAwayConfig, KeepAwayParams

REPO = pathlib.Path(__file__).resolve().parents[1]
TINY = ["trials=4", "sim.max_iterations=300", "validation_trials=20", "gif=false",
        "ppo_entity.episodes_per_generation=32", "ppo_entity.num_envs=16", "ppo_entity.num_steps=16",
        "ppo_entity.hidden=16", "ppo_entity.resets=4", "ppo_entity.anneal_episodes=0"]


@pytest.fixture
def trained(_runs):  # noqa: F811
    return _runs("ppo_entity")


@pytest.mark.slow  # ~25 s with its trained run: the run loop's resume is the default suite's on PPO's MLP
def test_resuming_from_a_checkpoint_ends_bit_for_bit_where_the_uninterrupted_run_does(trained, tmp_path):
    resume_here(trained, tmp_path)


def test_the_evaluators_decisions_are_the_networks_forward_pass_on_every_team_size():
    """Two networks' weights, as the evaluator plays them (each lane its own row of the table, alone), decide as
    the network's forward pass on the same tokens does (argmax of its logits, to a keeper), in 3v2 and,
    unchanged, in 6v4; each lane follows its own network."""
    exp = cfg_lib.validate(cfg_lib.load(cfg_lib.CONFIG_DIR / "ppo_entity_3v2.py", TINY))
    enc = exp.encoding
    net = ppo.network(enc.ppo)
    # each piece one program, not op by op (the checks are the same)
    reset = jax.jit(lambda key, sim, n: gym.KeepAway(sim).reset_batch(key, n, KeepAwayParams())[1].world,
                    static_argnums=(1, 2))
    tokens = jax.jit(lambda world, sim: entities.batch_first(entities.tokens(world, sim)), static_argnums=1)
    first = jax.tree.map(lambda a: a[0], tokens(reset(jax.random.key(0), exp.sim, 4), exp.sim))
    init, apply = jax.jit(net.init), jax.jit(net.apply)
    champion, last = (init(jax.random.key(i), first) for i in (1, 2))
    for k, t in ((3, 2), (6, 4)):  # the source's team and the largest (4v3 and 5v3: test_entity.py's tokens)
        sim = KeepAwayConfig(n_keepers=k, n_takers=t)
        world = reset(jax.random.key(k), sim, 64)
        policy = enc.policy_for(sim)
        assert policy.shared
        both = jax.tree.map(lambda a, b: np.stack([a, b]), champion, last)
        index = jax.numpy.asarray(np.arange(64) % 2, jax.numpy.int32)
        got = np.asarray(jax.jit(policy.apply)(Shared(both, index), world, None))
        obs = tokens(world, sim)
        want = []
        for params in (champion, last):
            logits, _ = apply(params, obs)
            want.append(np.asarray(entities.keeper_of(np.argmax(np.asarray(logits), -1), world, sim)))
        np.testing.assert_array_equal(got, np.where(np.arange(64) % 2 == 0, want[0], want[1]))
        assert len(np.unique(got)) > 1 and not np.array_equal(want[0], want[1])  # decisions that can disagree


@pytest.mark.slow  # ~15 s: the run loop's transfer, which the default suite checks on NEAT and PPO
def test_a_transfer_to_a_bigger_team_starts_from_the_source_weights(trained):
    src_dir = trained[0]
    target = lambda *extra: cfg_lib.load(REPO / "configs" / "ppo_entity_6v4.py", [  # noqa: E731
        *TINY, "generations=1", f"transfer.source={src_dir}", *extra])
    trainer = run_lib.Trainer(target())
    state = trainer.init()
    src = trainer.source
    for x, y in zip(jax.tree.leaves(state.learner.params), jax.tree.leaves(src.state.learner.params), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert state.learner.obs["mates"].shape == (16, 5, 6) and state.learner.obs["takers"].shape == (16, 4, 4)
    row = trainer.step(state).row
    assert row["train_episodes"] >= 32 and np.isfinite(row["champion_validation"])
    for extra, why in ((["ppo_entity.heads=2"], "they do not fit"),
                       (["ppo_entity.heads=3"], "heads: allowed a divisor"),
                       (["ppo_entity.blocks=0"], r"ppo_entity.blocks: allowed an integer in \[1, 64\]")):
        with pytest.raises(ConfigError, match=why):
            run_lib.Trainer(target(*extra)).init()
    # the fixed layout's PPO and the entity network do not fit each other
    mlp = cfg_lib.load(REPO / "configs" / "ppo_6v4.py", ["trials=4", "generations=1", f"transfer.source={src_dir}"])
    with pytest.raises(ConfigError):
        run_lib.Trainer(mlp).init()
    assert ppo_enc.EntityEncoding.episodes_per_generation(target()) == 32


@pytest.mark.slow  # ~40 s: two runs as a group and alone
def test_a_batched_group_of_entity_runs_writes_what_each_run_writes_alone(tmp_path):
    from test_group import assert_same_run

    from kx.evolve import group as group_lib

    cfgs = [cfg_lib.load(REPO / "configs" / "ppo_entity_3v2.py", [*TINY, "generations=2", "checkpoint_every=1",
                                                                  f"seed={s}"]) for s in (0, 5)]
    group_lib.train_group(cfgs, [tmp_path / "group" / f"seed{c.seed}" for c in cfgs], log=lambda s: None)
    for c in cfgs:
        run_lib.train(c, tmp_path / "alone" / f"seed{c.seed}", log=lambda s: None)
        assert_same_run(tmp_path / "group" / f"seed{c.seed}", tmp_path / "alone" / f"seed{c.seed}")


@pytest.mark.slow  # ~20 s: test_entity.py trains on a mix in the default suite
def test_a_run_on_a_mix_of_team_sizes_trains_through_the_run_loop_and_bad_mixes_are_refused():
    cfg = lambda *extra: cfg_lib.load(REPO / "configs" / "ppo_entity_3v2.py", [*TINY, "generations=1", *extra])  # noqa: E731
    trainer = run_lib.Trainer(cfg("ppo_entity.mix=4v3"))
    assert "with 4v3 episodes in every batch" in trainer.encoding.describe()
    state = trainer.init()
    assert [s.world.keeper_x.shape[0] for s in state.learner.env] == [3, 4]
    row = trainer.step(state).row
    assert row["train_episodes"] >= 32 and np.isfinite(row["champion_validation"])
    for bad, why in (("4x3", r"ppo_entity.mix: '4x3' is not a task"), ("3v2", "tasks other than the run's own"),
                     ("4v3,5v3", "ppo_entity.mix: num_envs \\(16\\) and resets \\(4\\) must divide")):
        with pytest.raises(ConfigError, match=why):
            run_lib.Trainer(cfg(f"ppo_entity.mix={bad}"))
