"""scripts/cell_costs.py --versus: one method's target generation against another's, by hand-computed rows."""

import pathlib
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import cell_costs  # noqa: E402


def _row(method, setup, generations, generation_seconds, wall_seconds, phase="target", target="4v3", run=0):
    return {"method": method, "phase": phase, "target": target, "setup": setup, "generations": str(generations),
            "generation_seconds": str(generation_seconds), "wall_seconds": str(wall_seconds), "run": str(run)}


def _run_dir(folder, row, live_steps):
    """A run directory whose metrics.csv has one row per generation with these live steps."""
    spec = cell_costs.t3.RunSpec(row["method"], row["setup"], row["phase"], row["target"], int(row["run"]))
    d = cell_costs.t3.run_dir(folder, spec)
    d.mkdir(parents=True)
    lines = ["generation,live_steps,eval_seconds"] + [f"{g},{n},0.5" for g, n in enumerate(live_steps)]
    (d / "metrics.csv").write_text("\n".join(lines) + "\n")


def test_versus_divides_seconds_per_generation_cell_by_cell_and_pooled_over_setups(capsys):
    rows = [_row("hyperneat", "none", 10, 20, 25), _row("neat", "none", 10, 10, 10),
            _row("hyperneat", "fitness", 30, 30, 30), _row("neat", "fitness", 30, 15, 20),
            _row("neat", "novelty", 30, 15, 20),  # no HyperNEAT run of this cell: left out, pooled too
            _row("hyperneat", "fitness", 20, 5, 5, phase="source", target="3v2"),  # sources are not targets
            _row("neat", "fitness", 20, 50, 50, phase="source", target="3v2")]
    cell_costs._versus(cell_costs._cells(rows), "hyperneat", "neat")
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| 4v3") or "3v2" in ln]
    # none: 20/10 over 10/10 = 2.00, wall 25/10 over 10/10 = 2.50; fitness: 1.00/0.50 = 2.00, 1.00/0.667 = 1.50;
    # pooled: (20 + 30) / 40 over (10 + 15) / 40 = 2.00, (25 + 30) / 40 over (10 + 20) / 40 = 1.83
    assert lines == ["| 4v3 | fitness | 1 | 1 | 2.00 | 1.50 |", "| 4v3 | none | 1 | 1 | 2.00 | 2.50 |",
                     "| 4v3 | every setup both ran | 2 | 2 | 2.00 | 1.83 |"]


def test_versus_refuses_an_unknown_method_naming_the_allowed(tmp_path, capsys):
    with pytest.raises(SystemExit):
        cell_costs.main([str(tmp_path), "--versus", "hyperneat:nest"])
    assert "--versus: allowed METHOD:BASE with each of ['cma_es', 'hyperneat', 'neat', 'ppo']" in \
        capsys.readouterr().err


def test_versus_splits_the_ratio_into_live_steps_and_seconds_per_live_step_where_run_dirs_remain(tmp_path, capsys):
    rows = [_row("hyperneat", "none", 2, 6, 7), _row("neat", "none", 2, 1, 1),
            _row("hyperneat", "fitness", 2, 4, 4), _row("hyperneat", "fitness", 2, 4, 4, run=1),
            _row("neat", "fitness", 2, 2, 2)]
    steps = [[100, 200], [10, 20], [50, 50], [70, 30], [100, 100]]
    cells = cell_costs._cells(rows)
    cell_costs._versus_live_steps(tmp_path, cells, "hyperneat", "neat")
    assert capsys.readouterr().out == ""  # no run directories (a committed folder): nothing to split
    for row, n in zip(rows, steps):
        _run_dir(tmp_path, row, n)
    cell_costs._versus_live_steps(tmp_path, cells, "hyperneat", "neat")
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| 4v3")]
    # fitness: 200 steps / 4 generations = 50 against 200 / 2 = 100 -> 0.50; 8 s / 200 against 2 s / 200 -> 4.00;
    # the product 2.00 is the s-per-generation ratio (8 / 4 against 2 / 2).
    # none: 300 / 2 against 30 / 2 -> 10.00; 6 / 300 against 1 / 30 -> 0.60; product 6.00 (3 against 0.5).
    # pooled: 500 / 6 against 230 / 4 -> 1.45; 14 / 500 against 3 / 230 -> 2.15; product 3.11 (14/6 over 3/4)
    assert lines == ["| 4v3 | fitness | 0.50 | 4.00 | 2.00 |", "| 4v3 | none | 10.00 | 0.60 | 6.00 |",
                     "| 4v3 | every setup both ran | 1.45 | 2.15 | 3.11 |"]
