"""scripts/cell_costs.py --versus: one method's target generation against another's, by hand-computed rows."""

import pathlib
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import cell_costs  # noqa: E402


def _row(method, setup, generations, generation_seconds, wall_seconds, phase="target", target="4v3"):
    return {"method": method, "phase": phase, "target": target, "setup": setup, "generations": str(generations),
            "generation_seconds": str(generation_seconds), "wall_seconds": str(wall_seconds)}


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
