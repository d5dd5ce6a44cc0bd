"""``python -m kx.train`` and ``python -m kx.evaluate`` for HyperNEAT: the run tests of test_train.py (the
run directory, SIGKILL then resume bit for bit, never overwriting, refused checkpoints, a champion on
another task), in a file of their own so that `make test`'s workers run them beside NEAT's and CMA-ES's."""

import pytest
from PIL import Image
from test_train import (  # noqa: F401  (the tests, and the session cache of trained runs they use)
    _runs,
    resume_here,
    sigkill_then_resume,
    test_corrupt_and_mismatched_checkpoints_are_refused_with_the_reason,
    test_evaluate_plays_the_validated_champion_on_test_trials_of_another_task,
    test_existing_run_directories_are_never_overwritten_unasked,
    test_run_directory_holds_config_metrics_plot_checkpoints_and_gif,
)


@pytest.fixture
def trained(_runs):  # noqa: F811
    return _runs("hyperneat")


def test_resuming_from_a_checkpoint_ends_bit_for_bit_where_the_uninterrupted_run_does(trained, tmp_path):
    """The CPPN population, the novelty archive and the metrics come back bit for bit (in this process)."""
    resume_here(trained, tmp_path)


@pytest.mark.slow  # moved out of the default suite to keep it under 7 minutes in a fresh clone
def test_sigkill_then_resume_ends_bit_for_bit_where_an_uninterrupted_run_does(trained, tmp_path):
    """HyperNEAT's run selects on the novelty hybrid, so the archive, the CPPN population and the metrics
    all come back bit for bit. The kill-and-resume tests are all in the slow set; the default suite
    resumes HyperNEAT's run in process (above), and NEAT's hybrid run in test_train_novelty.py."""
    sigkill_then_resume(trained, tmp_path)


def test_the_champion_png_is_the_substrate_and_the_cppn_is_drawn_beside_it(trained):
    run_dir, out, _ = trained
    assert "hyperneat (CPPN 5 inputs" in out and "image authors, decision cells" in out
    with Image.open(run_dir / "champion.png") as sub, Image.open(run_dir / "champion_cppn.png") as cppn:
        assert sub.format == cppn.format == "PNG"
        assert sub.size[0] > 2 * sub.size[1] * 0.8  # the eight panels of the substrate figure, two rows
