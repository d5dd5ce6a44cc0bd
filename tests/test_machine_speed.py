"""scripts/machine_speed.py: a re-trained group's seconds against its recorded rows, by hand-computed runs."""

import csv
import pathlib
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import machine_speed  # noqa: E402

from kx.experiments import table3 as t3  # noqa: E402


def _run(folder, run, seconds, setup="fitness", method="neat"):
    d = t3.run_dir(folder, t3.RunSpec(method, setup, "source", "3v2", run))
    d.mkdir(parents=True)
    with (d / "metrics.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["generation", "best_fitness", "generation_seconds"])
        w.writerows([g, 0.5, s] for g, s in enumerate(seconds))


def _rows(path, shares, setup="fitness", method="neat", generations=2):
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=t3.FIELDS)
        w.writeheader()
        for run, share in shares.items():
            w.writerow({k: "" for k in t3.FIELDS} | {"method": method, "setup": setup, "phase": "source",
                                                     "target": "3v2", "run": run, "generations": generations,
                                                     "generation_seconds": share})


def test_groups_pair_each_batched_group_with_its_rows_and_pool_them(tmp_path, capsys):
    # two groups trained here: runs 0-2 (3 s + 1 s a group, its rows recorded 2 s each: 6 s against 4 s)
    # and run 3 alone (2 s + 2 s, recorded 2 s: 2 against 4); run 4 unfinished here (1 generation), run 5
    # never trained here: both left out
    for run in range(3):
        _run(tmp_path, run, [3.0, 1.0])
    _run(tmp_path, 3, [2.0, 2.0])
    _run(tmp_path, 4, [9.0])
    recorded = tmp_path / "recorded.csv"
    _rows(recorded, {0: 2.0, 1: 2.0, 2: 2.0, 3: 2.0, 4: 1.0, 5: 1.0})
    machine_speed.main([str(tmp_path), str(recorded)])
    out = capsys.readouterr().out.splitlines()
    assert out[2:] == ["| neat fitness source 3v2 | 0-2 | 6.0 | 4.0 | 1.50 |",
                       "| neat fitness source 3v2 | 3 | 2.0 | 4.0 | 0.50 |",
                       "machine speed: 1.00 x the recording machine (2 groups, 4 runs; 0.50-1.50 by group)"]


def test_no_run_trained_here_is_an_error_naming_both_paths(tmp_path):
    recorded = tmp_path / "recorded.csv"
    _rows(recorded, {0: 2.0})
    with pytest.raises(SystemExit) as e:
        machine_speed.main([str(tmp_path), str(recorded)])
    assert str(e.value) == f"machine_speed: no run of {recorded} has a finished run directory under {tmp_path}/runs"
