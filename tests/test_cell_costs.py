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
            _row("neat", "hybrid", 30, 15, 20),  # no HyperNEAT run of this cell: left out, pooled too
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
    assert "--versus: allowed METHOD:BASE with each of ['cma_es', 'hyperneat', 'neat', 'ppo', 'ppo_entity']" in \
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


def _metrics_dir(folder, row, live_steps, seconds):
    spec = cell_costs.t3.RunSpec(row["method"], row["setup"], row["phase"], row["target"], int(row["run"]))
    d = cell_costs.t3.run_dir(folder, spec)
    d.mkdir(parents=True)
    lines = ["generation,live_steps,generation_seconds"] + [
        f"{g},{n},{s}" for g, (n, s) in enumerate(zip(live_steps, seconds))]
    (d / "metrics.csv").write_text("\n".join(lines) + "\n")


def test_versus_fits_each_group_and_prices_the_method_at_the_base_cost_per_live_step(tmp_path, capsys):
    rows = [_row("hyperneat", "fitness", 3, 0, 0, run=r) for r in range(3)] + [_row("neat", "fitness", 3, 0, 0)]
    # hyperneat runs 0 and 1 train in one group: 0.2 s + 200 ns per live step of both runs; run 2 alone:
    # 0.1 s + 300 ns; neat: 0.05 s + 100 ns. Generation 0 (compilation, 9 s) is left out of every fit.
    a = [0.2 + 2e-7 * n for n in (2e6, 5e6)]
    _metrics_dir(tmp_path, rows[0], [5, 10**6, 2 * 10**6], [9.0] + a)
    _metrics_dir(tmp_path, rows[1], [5, 10**6, 3 * 10**6], [9.0] + a)
    _metrics_dir(tmp_path, rows[2], [5, 10**6, 2 * 10**6], [9.5] + [0.1 + 3e-7 * n for n in (1e6, 2e6)])
    _metrics_dir(tmp_path, rows[3], [5, 10**6, 3 * 10**6], [40.0] + [0.05 + 1e-7 * n for n in (1e6, 3e6)])
    cell_costs._versus_fit(tmp_path, cell_costs._cells(rows), "hyperneat", "neat")
    out = capsys.readouterr().out.splitlines()
    lines = [ln for ln in out if ln.startswith("| 4v3")]
    # hyperneat: (0.6 + 1.2 + 0.4 + 0.7) s over 6 run-generations = 0.483 s; neat (0.15 + 0.35) / 2 = 0.25 s:
    # 1.93. At neat's 100 ns: (0.2 + 0.2) + (0.2 + 0.5) + (0.1 + 0.1) + (0.1 + 0.2) = 1.6 s over 6: 1.07.
    assert lines == ["| 4v3 | fitness | hyperneat | 2, 100, 200; 1, 100, 300 | 0.483 | 1.93 | 1.07 |",
                     "| 4v3 | fitness | neat | 1, 50, 100 | 0.250 | | |",
                     "| 4v3 | every setup both ran | hyperneat | | 0.483 | 1.93 | 1.07 |"]
    # pooled: hyperneat's fixed (0.2 + 0.2) + (0.1 + 0.1) = 0.6 s over 6 run-generations, its live steps 1.4 s over
    # 7M and 0.9 s over 3M: 230 ns, 10M / 6 = 1.67M a run-generation; neat 0.1 s / 2, 0.4 s / 4M, 4M / 2. For 1.5:
    # (1.5 x 0.25 - 0.1) s / 1.67M = 165 ns, with neat's fixed part (0.375 - 0.05) / 1.67M = 195 ns.
    assert out[-1] == ("4v3, pooled: hyperneat 100 ms a run-generation + 230 ns per live step x 1.67M live steps; "
                       "neat 50 ms a run-generation + 100 ns per live step x 2.00M live steps. For hyperneat / neat "
                       "= 1.5: hyperneat's ns per live step at most 165 with its fixed part, 195 with neat's.")


def test_versus_fit_says_why_when_a_group_has_too_few_generations(tmp_path, capsys):
    rows = [_row("hyperneat", "none", 2, 0, 0), _row("neat", "none", 2, 0, 0)]
    _metrics_dir(tmp_path, rows[0], [5, 10], [1.0, 0.5])
    _metrics_dir(tmp_path, rows[1], [5, 10], [1.0, 0.2])
    cell_costs._versus_fit(tmp_path, cell_costs._cells(rows), "hyperneat", "neat")
    assert "(no fit: a fit needs two generations after the first with different live steps)" in \
        capsys.readouterr().out
