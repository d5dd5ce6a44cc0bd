"""``python -m kx.bench runs``: the warm ratio is the median of rounds taken in turn, bad ``--rounds`` is refused
before any compute, and (slow) a small run of the benchmark checks every round's rows and ends with its
machine-readable line."""

import re
import subprocess
import sys
import types

import pytest

from kx.bench import runs


def test_the_warm_ratio_is_the_median_of_each_rounds_own_ratio():
    # rounds of (alone, group) warm seconds: ratios 2.0, 1.5, 0.8 -> median 1.5, not the ratio of the sums
    # (9.0 / 6.5)
    ratio, ratios = runs.ratio_of_rounds([(4.0, 2.0), (3.0, 2.0), (2.0, 2.5)])
    assert ratios == [2.0, 1.5, 0.8] and ratio == 1.5
    # ratios 2.0, 0.5, 3.0 -> median 2.0, not the ratio of the medians (3.0 over 2.0) nor of the sums (8 / 5)
    assert runs.ratio_of_rounds([(4.0, 2.0), (1.0, 2.0), (3.0, 1.0)]) == (2.0, [2.0, 0.5, 3.0])
    # an even number of rounds: the mean of the middle two
    assert runs.ratio_of_rounds([(1.0, 1.0), (3.0, 1.0)]) == (2.0, [1.0, 3.0])
    # a group slower in its round than its runs alone counts below 1 whatever the other rounds' speed
    assert runs.ratio_of_rounds([(10.0, 20.0)])[0] == 0.5


def test_rounds_below_one_are_refused_before_any_run():
    args = types.SimpleNamespace(group_sizes="1", rounds=0, config=None, generations=1)
    with pytest.raises(SystemExit, match=r"--rounds: allowed an integer >= 1, got 0"):
        runs.run(args)


@pytest.mark.slow  # ~70 s: compiles a group of 2
def test_a_small_run_checks_every_round_and_ends_with_its_line():
    out = subprocess.run([sys.executable, "-m", "kx.bench", "runs", "--group-sizes", "1,2", "--generations", "2",
                          "--rounds", "2"], capture_output=True, text=True, check=True).stdout.strip().splitlines()
    assert sum(bool(re.match(r"  R = [12] round [12]: batched ", ln)) for ln in out) == 4
    summaries = [ln for ln in out if ln.startswith("R = ")]
    assert len(summaries) == 2 and all(ln.endswith("every run's rows identical to its seed alone: True")
                                       for ln in summaries)
    assert all("the median of 2 round(s)" in ln for ln in summaries)
    assert re.fullmatch(r"runs: \d+ runs/h at R = 2 \(ratio \d+\.\d\d vs one_by_one\)", out[-1]), out[-1]
