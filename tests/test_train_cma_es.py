"""``python -m kx.train`` and ``python -m kx.evaluate`` for CMA-ES: the run tests of test_train.py (the
run directory, SIGKILL then resume bit for bit, never overwriting, refused checkpoints, a champion on
another task), in a file of their own so that `make test`'s workers run them beside NEAT's and HyperNEAT's.

They are long tests (`make test-slow`): the run loop they exercise is NEAT's and HyperNEAT's, which the
default suite runs, and CMA-ES's own state is checked by the toy encoding's and CMA-ES's recompilation
tests in test_run_loop.py."""

import pytest
from test_train import (  # noqa: F401  (the tests, and the session cache of trained runs they use)
    _runs,
    test_corrupt_and_mismatched_checkpoints_are_refused_with_the_reason,
    test_evaluate_plays_the_validated_champion_on_test_trials_of_another_task,
    test_existing_run_directories_are_never_overwritten_unasked,
    test_run_directory_holds_config_metrics_plot_checkpoints_and_gif,
    test_sigkill_then_resume_ends_bit_for_bit_where_an_uninterrupted_run_does,
)

pytestmark = pytest.mark.slow


@pytest.fixture
def trained(_runs):  # noqa: F811
    return _runs("cma_es")

