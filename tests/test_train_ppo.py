"""``python -m kx.train`` for PPO (``method = "ppo"``): the run tests of test_train.py (the run directory,
SIGKILL then resume bit for bit, never overwriting, a champion on another task), and a transferred run
that starts from the source's weights; in a file of their own so that `make test`'s workers run them
beside NEAT's."""

import pathlib

import jax
import numpy as np
import pytest
from test_train import (  # noqa: F401  (the tests, and the session cache of trained runs they use)
    _runs,
    resume_here,
    sigkill_then_resume,
    test_run_directory_holds_config_metrics_plot_checkpoints_and_gif,
)
from test_train import test_evaluate_plays_the_validated_champion_on_test_trials_of_another_task as _evaluate
from test_train import test_existing_run_directories_are_never_overwritten_unasked as _never_overwritten

from kx.evolve import config as cfg_lib
from kx.evolve import run as run_lib
from kx.evolve.errors import ConfigError

REPO = pathlib.Path(__file__).resolve().parents[1]
TINY = ["trials=4", "sim.max_iterations=300", "validation_trials=20", "gif=false", "ppo.episodes_per_generation=32",
        "ppo.num_envs=16", "ppo.num_steps=16", "ppo.hidden=16", "ppo.resets=4", "ppo.anneal_episodes=0"]


@pytest.fixture
def trained(_runs):  # noqa: F811
    return _runs("ppo")


def test_resuming_from_a_checkpoint_ends_bit_for_bit_where_the_uninterrupted_run_does(trained, tmp_path):
    """The learner's whole state (weights, Adam's moments, the episodes in play and their returns, the
    counters) comes back from the checkpoint: the resumed run's checkpoints and metrics are the
    uninterrupted run's, bit for bit."""
    resume_here(trained, tmp_path)


@pytest.mark.slow  # ~40 s: two kx.train processes compile every program; the default suite resumes in process
def test_sigkill_then_resume_ends_bit_for_bit_where_an_uninterrupted_run_does(trained, tmp_path):
    """The same after a SIGKILL mid-run, in `python -m kx.train` processes."""
    sigkill_then_resume(trained, tmp_path)


@pytest.mark.slow  # the run loop's own logic, which the default suite runs on NEAT's run
def test_existing_run_directories_are_never_overwritten_unasked(capsys, trained, tmp_path):
    _never_overwritten(capsys, trained, tmp_path)


@pytest.mark.slow  # kx.evaluate's own logic, which the default suite runs on NEAT's run
def test_evaluate_plays_the_validated_champion_on_test_trials_of_another_task(capsys, trained):
    _evaluate(capsys, trained)


def _same(a, b) -> bool:
    return all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b),
                                                                            strict=True))


@pytest.mark.slow  # ~10 s: the run loop's transfer is the default suite's on NEAT (test_transfer.py)
def test_a_transferred_run_starts_from_the_source_weights_with_a_fresh_optimiser(trained):
    src_dir = trained[0]
    target = lambda *extra: cfg_lib.load(REPO / "configs" / "ppo_4v3.py", [  # noqa: E731
        *TINY, "generations=1", f"transfer.source={src_dir}", *extra])
    trainer = run_lib.Trainer(target())
    state = trainer.init()
    src = trainer.source
    assert int(src.state.generation) > 0 and not _same(src.state.learner.params, trainer.encoding.init(
        jax.random.key(0)).params)
    # "population": the weights the source's training ended with; the optimiser, counters and episodes anew
    assert _same(state.learner.params, src.state.learner.params)
    assert int(state.learner.episodes) == int(state.learner.updates) == int(state.learner.blocks) == 0
    assert all(float(np.abs(np.asarray(a)).max()) == 0.0 for a in jax.tree.leaves(state.learner.opt_state))
    assert state.learner.obs.shape == (16, 13) and int(state.generation) == 0
    # "champion": the source's validated champion
    champ = run_lib.Trainer(target("transfer.seeding=champion")).init()
    assert _same(champ.learner.params, src.state.champion)
    # the target's first generation plays those weights in 4v3 and trains on
    row = trainer.step(state).row
    assert row["train_episodes"] >= 32 and np.isfinite(row["champion_validation"])
    # one network, not a population; another width does not fit
    for extra, why in ((["transfer.seeding=half"], "seeding 'half'"), (["ppo.hidden=8"], "they do not fit")):
        with pytest.raises(ConfigError, match=why):
            run_lib.Trainer(target(*extra)).init()


@pytest.mark.slow  # ~25 s: two runs as a group and alone; the default suite checks groups on NEAT
def test_a_batched_group_of_ppo_runs_writes_what_each_run_writes_alone(tmp_path):
    """``kx.train --seeds`` and the protocol's groups: each run's blocks of updates run alone, and the
    group's evaluations (one table of the runs' networks, each lane gathering its own) decide as each run's
    network does alone, so every metrics row and checkpoint is the same."""
    from test_group import assert_same_run

    from kx.evolve import group as group_lib

    cfgs = [cfg_lib.load(REPO / "configs" / "ppo_3v2.py", [*TINY, "generations=2", "checkpoint_every=1",
                                                           f"seed={s}"]) for s in (0, 5)]
    group_lib.train_group(cfgs, [tmp_path / "group" / f"seed{c.seed}" for c in cfgs], log=lambda s: None)
    for c in cfgs:
        run_lib.train(c, tmp_path / "alone" / f"seed{c.seed}", log=lambda s: None)
        assert_same_run(tmp_path / "group" / f"seed{c.seed}", tmp_path / "alone" / f"seed{c.seed}")
