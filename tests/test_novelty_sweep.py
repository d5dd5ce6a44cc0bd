"""The novelty hybrid's sweep (kx.experiments.novelty): its arms are Table 3's protocol with one reading
changed, bad input is refused before anything is written, the diagnostics and the report come from the
results files alone (byte for byte), and the comparisons and answers are the hand-computed ones."""

import json

import numpy as np
import pytest

from kx.evolve import trainer as trainer_lib
from kx.experiments import csvfile, novelty
from kx.experiments import table3 as t3

SMALL = ("population_size=12", "trials=2", "validation_trials=4", "sim.max_iterations=60", "checkpoint_every=1")


def test_behaviour_spread_is_the_mean_distance_to_the_mean_behaviour():
    assert trainer_lib.behaviour_spread(np.zeros((3, 5))) == 0.0
    beh = np.array([[0.0, 1.0], [0.0, 0.0], [0.0, 0.0]])  # two genomes 1 apart: each 0.5 from the mean
    assert trainer_lib.behaviour_spread(beh) == 0.5
    beh = np.array([[0.0, 0.0, 0.9], [0.0, 0.0, 1.2], [0.3, 0.3, 0.3]])  # mean (0.3, 0.4, 0.3)
    want = (2 * np.sqrt(0.3**2 + 0.4**2) + np.sqrt(0.6**2 + 0.8**2)) / 3  # (0.5 + 0.5 + 1.0) / 3
    assert trainer_lib.behaviour_spread(beh) == pytest.approx(want, abs=1e-12) == pytest.approx(2 / 3)


@pytest.mark.parametrize("method", novelty.METHODS)
def test_the_table3_arms_are_table3s_runs_and_the_weights_change_only_rho(method, tmp_path):
    base = t3.Protocol()
    for name, objective in (("fitness", "fitness"), ("rho-0.4", "hybrid")):
        arm = novelty.ARMS[name]
        spec = novelty.specs(arm, method, "source", 10, 5)[3]
        assert spec == t3.RunSpec(method, objective, "source", "3v2", 3)
        assert (t3.config(novelty.protocol(arm), spec, tmp_path).to_dict()
                == t3.config(base, spec, tmp_path).to_dict())
        assert novelty.specs(arm, method, "target", 10, 5) == []  # its transfers are Table 3's cells
    ref = t3.config(base, t3.RunSpec(method, "hybrid", "source", "3v2", 3), tmp_path).to_dict()
    for name in ("rho-0.6", "rho-0.0", "authors-archive"):
        arm = novelty.ARMS[name]
        got = t3.config(novelty.protocol(arm), novelty.specs(arm, method, "source", 10, 5)[3], tmp_path).to_dict()
        diff = {k for k in ref["novelty"] if ref["novelty"][k] != got["novelty"][k]}
        assert diff == {"rho" if name.startswith("rho") else "archive_rule"}
        assert {k: v for k, v in got.items() if k != "novelty"} == {k: v for k, v in ref.items() if k != "novelty"}
    assert len(novelty.specs(novelty.ARMS["rho-0.0"], method, "target", 10, 5)) == 5
    assert novelty.specs(novelty.ARMS["fixed"], method, "target", 10, 5) == []  # sources only


@pytest.mark.parametrize("kwargs, field", [
    ({"arms": ("rho-0.3",)}, "--arms: allowed fitness, rho-1.0"),
    ({"methods": ("cma_es",)}, "--methods: allowed neat, hyperneat"),
    ({"phases": ("transfer",)}, "--phases: allowed source, target"),
    ({"runs": 0}, "--runs: allowed an integer >= 1"),
    ({"runs": 4, "target_runs": {"neat": 5}}, "--target-runs: allowed METHOD=N"),
])
def test_bad_input_is_refused_before_anything_is_written(kwargs, field, tmp_path):
    with pytest.raises(ValueError, match=field):
        novelty.run(tmp_path / "nv", **kwargs)
    assert not (tmp_path / "nv").exists()


def _row(method, setup, phase, target, run, test, best):
    row = {f: "" for f in t3.FIELDS}
    row.update(method=method, setup=setup, phase=phase, target=target, run=run, test_fitness=test, max_fitness=best,
               best_so_far=" ".join(format(best * (g + 1) / 4, ".9g") for g in range(4)),
               best_validation=" ".join(format(test, ".9g") for _ in range(4)), generations=4)
    return row


def _folder(tmp_path):
    """A sweep folder written by hand: NEAT's fitness arm clearly above pure novelty in 3v2 (6 runs each), one
    transfer cell each, and diagnostics in which the fittest genome has no child in one generation of four."""
    out, table3 = tmp_path / "novelty", tmp_path / "table3"
    for d in (out / "fitness", out / "rho-0.0", table3):
        d.mkdir(parents=True)
    csvfile.write(out / "fitness" / "results.csv", t3.FIELDS,
                  [_row("neat", "fitness", "source", "3v2", i, 0.60 + i / 100, 0.80 + i / 100) for i in range(6)])
    csvfile.write(out / "rho-0.0" / "results.csv", t3.FIELDS,
                  [_row("neat", "hybrid", "source", "3v2", i, 0.10 + i / 100, 0.50 + i / 100) for i in range(6)]
                  + [_row("neat", "hybrid", "target", "4v3", i, 0.20 + i / 100, 0.40 + i / 100) for i in range(3)])
    csvfile.write(table3 / "results.csv", t3.FIELDS,
                  [_row("neat", "fitness", "target", "4v3", i, 0.21 + i / 100, 0.41 + i / 100) for i in range(8)])
    for arm, setup in (("fitness", "fitness"), ("rho-0.0", "hybrid")):
        rows = []
        for i in range(6):
            for g in range(4):
                kids = 0 if (arm == "rho-0.0" and g == 1) else 3
                rows.append({"method": "neat", "setup": setup, "phase": "source", "target": "3v2", "run": i,
                             "generation": g, "best_fitness": 0.5, "mean_fitness": 0.2, "behaviour_spread": 0.1 * g,
                             "n_species": 5, "fittest_offspring": kids, "fittest_elite": int(kids > 0),
                             "archive_size": "" if arm == "fitness" else 10 * (g + 1), "archive_added": "",
                             "mean_novelty": ""})
        csvfile.write(out / arm / "diagnostics.csv", novelty.DIAGNOSTICS, rows)
    (out / "novelty.json").write_text(json.dumps({"table3": "../table3", "protocol": t3.Protocol().to_json(),
                                                  "runs": 6, "target_runs": {"neat": 3}}))
    return out


@pytest.mark.slow  # moved out of the default suite to keep it under 7 minutes in a fresh clone
def test_the_report_is_the_hand_computed_comparison_and_regenerates_byte_for_byte(tmp_path):
    out = _folder(tmp_path)
    text = novelty.write_report(out).read_text()
    files = {p.name: p.read_bytes() for p in out.iterdir() if p.suffix in (".md", ".png")}
    assert set(files) == {"report.md", "sources.png", "transfers.png", "spread.png"}
    # 6 runs against 6, every fitness run above every pure-novelty run: A 0, exact p 2 / C(12, 6), one arm
    # compared so Holm's p is the p
    assert "No. No reading beats fitness alone" in text
    assert f"NEAT `rho-0.0` in 3v2 on the validated champion on the test states (A 0.00, Holm p {2 / 924:.3f})" in text
    source_line = next(line for line in text.splitlines() if line.startswith("| `rho-0.0`") and "| 6 |" in line)
    # spread: mean of 0, 0.1, 0.2, 0.3; fittest childless in 1 of 4 generations; 3 children in 3 of 4; archive 40
    assert source_line.endswith(f"| 0.15 | 25% | {9 / 4:.3g} | 40 |")
    fitness_line = next(line for line in text.splitlines() if line.startswith("| `fitness`") and "| 6 |" in line)
    assert fitness_line.endswith("| 0.15 | 0% | 3 | - |")
    # the transfer table takes the fitness arm's 4v3 runs from Table 3's folder, those below the sweep's 6 runs
    assert "| `fitness` fitness alone | 6 |" in text.split("## After transfer")[1]
    assert "Not yet: the sweep has no HyperNEAT pure-novelty transfers" in text
    assert "- NEAT, behaviour spread: 0.150 under fitness alone, 0.150 to 0.150 under the hybrid's readings" in text
    assert ("childless in 0% of generations under fitness alone, with 3.0 children on average; "
            f"25% and {9 / 4:.1f} at rho 0.0.") in text
    novelty.write_report(out)
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.suffix in (".md", ".png")} == files


def test_the_diagnostics_come_from_the_runs_metrics_and_survive_without_them(tmp_path):
    folder = tmp_path / "arm"
    spec = t3.RunSpec("neat", "hybrid", "source", "3v2", 0)
    d = t3.run_dir(folder, spec)
    d.mkdir(parents=True)
    metrics = [{"generation": g, "best_fitness": 0.1 * g, "mean_fitness": 0.05, "behaviour_spread": 0.2,
                "n_species": 4, "fittest_offspring": g, "fittest_elite": 0, "archive_size": g, "archive_added": 1,
                "mean_novelty": 0.3, "eval_seconds": 1.0} for g in range(3)]
    csvfile.write(d / "metrics.csv", tuple(metrics[0]), metrics)
    csvfile.write(folder / "results.csv", t3.FIELDS, [_row("neat", "hybrid", "source", "3v2", 0, 0.1, 0.2)
                                                      | {"generations": 3}])
    assert novelty.update_diagnostics(folder, novelty.ARMS["rho-0.0"]) == 1
    rows = novelty.read_diagnostics(folder / "diagnostics.csv")
    assert [r["fittest_offspring"] for r in rows] == ["0", "1", "2"] and rows[2]["best_fitness"] == "0.2"
    (d / "metrics.csv").unlink()  # a fresh clone: no run directory, the committed rows stay
    assert novelty.update_diagnostics(folder, novelty.ARMS["rho-0.0"]) == 1
    assert novelty.read_diagnostics(folder / "diagnostics.csv") == rows


@pytest.mark.slow  # ~80 s: tiny runs of four arms and a Table 3 folder
def test_a_tiny_sweep_reproduces_table3s_sources_and_reports(tmp_path):
    base = t3.Protocol(seed=3, test_trials=4, source_generations=2, target_generations=2, overrides=SMALL)
    out, table3 = tmp_path / "novelty", tmp_path / "table3"
    t3.run(table3, base, t3.plan(("neat",), ("4v3",), ("fitness", "hybrid"), 2), log=lambda s: None)
    novelty.run(out, ("fitness", "rho-0.0", "rho-0.4", "authors-archive"), ("neat",), runs=2,
                target_runs={"neat": 2}, table3=table3, base=base, log=lambda s: None)
    for arm, runs in (("fitness", 2), ("rho-0.0", 4), ("rho-0.4", 2), ("authors-archive", 2)):
        rows = novelty.read_diagnostics(out / arm / "diagnostics.csv")
        assert len(rows) == 2 * runs  # two generations a run
        assert all(r["behaviour_spread"] != "" and r["fittest_offspring"] != "" for r in rows)
        assert all((r["archive_size"] == "") == (arm == "fitness") for r in rows)
    text = novelty.write_report(out).read_text()
    assert "- NEAT `fitness`: 2 of 2 sources equal Table 3's rows" in text
    assert "- NEAT `rho-0.4`: 2 of 2 sources equal Table 3's rows" in text
    with pytest.raises(t3.RunError, match="base protocol"):
        novelty.run(out, ("fitness",), ("neat",), runs=2, target_runs={"neat": 2}, table3=table3, log=lambda s: None)
