"""The confirmatory replication (``python -m kx.experiments confirm``): each target run from a source of its own, the
runs a cell fixed in advance from an earlier folder's power, its design recorded before any run, and a report that
shows no result until every planned run is in."""

import csv
import json
import pathlib
import shutil

import numpy as np
import pytest

from kx.evolve.errors import RunError
from kx.experiments import __main__ as cli
from kx.experiments import confirm, csvfile, design, report
from kx.experiments import table3 as t3

ROOT = pathlib.Path(__file__).resolve().parents[1]
SMALL = ("population_size=12", "trials=2", "validation_trials=4", "sim.max_iterations=60", "checkpoint_every=1")


def test_with_sources_per_target_every_target_run_has_a_source_of_its_own():
    specs = [t3.RunSpec(m, s, "target", t, i) for m in ("neat", "hyperneat") for s in ("fitness", "hybrid")
             for t in t3.TARGETS for i in range(30)]
    shared = {t3.source_of(s) for s in specs}
    own = [t3.source_of(s, "per_target") for s in specs]
    assert len(set(own)) == len(own) == 3 * len(shared)  # three targets: three sources where one was shared
    for spec, src in zip(specs, own):
        assert src.run == 3 * spec.run + t3.TARGETS.index(spec.target) and src.phase == "source"
        assert src.setup == t3.SETUPS[spec.setup].source_objective and src.method == spec.method
    assert t3.source_of(t3.RunSpec("neat", "none", "target", "4v3", 3), "per_target") is None
    with pytest.raises(ValueError, match="sources: allowed shared, per_target"):
        t3.Protocol(sources="each")
    with pytest.raises(ValueError, match="sources: allowed shared, per_target"):
        t3.source_of(specs[0], "each")
    # a run's config names its own source's run directory
    p = t3.Protocol(seed=1, sources="per_target")
    cfg = t3.config(p, t3.RunSpec("neat", "fitness", "target", "6v4", 2), pathlib.Path("/x"))
    assert cfg.transfer.source == "/x/runs/neat/source-fitness/3v2/run08"


def test_the_plan_runs_every_cell_to_its_own_count_run_index_by_run_index():
    runs = {f"{m}/{s}": 2 for m in confirm.METHODS for s in confirm.SETUPS} | {"hyperneat/none": 3}
    dsg = design.design(role="confirmatory", sources="per_target", runs=runs)
    got = confirm.specs(dsg, 0, 3)
    assert len(got) == 3 * (2 * 6 + 1)
    assert [s.run for s in got] == sorted(s.run for s in got)
    assert [s.key for s in got if s.run == 2] == [("hyperneat", "none", "target", t, 2) for t in t3.TARGETS]
    assert confirm.specs(dsg, 1, 2) == [s for s in got if s.run == 1]


def test_a_confirmatory_folder_is_opened_only_as_one(tmp_path, capsys):
    protocol = t3.Protocol(seed=1, sources="per_target")
    with pytest.raises(RunError, match="give --basis DIR"):
        confirm.open_folder(tmp_path / "new", protocol, None)
    with pytest.raises(RunError, match="a source of its own"):
        confirm.open_folder(tmp_path / "new", t3.Protocol(seed=1), ROOT / "docs" / "table3")
    assert not (tmp_path / "new").exists()  # nothing written
    # an exploratory folder is refused
    (tmp_path / "t3").mkdir()
    shutil.copy(ROOT / "docs" / "table3" / "protocol.json", tmp_path / "t3")
    with pytest.raises(RunError, match="not a confirmatory protocol"):
        confirm.open_folder(tmp_path / "t3", protocol, None)
    # the committed folder: its recorded design, not derived again (no basis needed)
    committed = tmp_path / "c"
    committed.mkdir()
    shutil.copy(ROOT / "docs" / "table3_confirmatory" / "protocol.json", committed)
    recorded = json.loads((committed / "protocol.json").read_text())["design"]
    assert confirm.open_folder(committed, protocol, None) == design.renamed(recorded)  # under today's setup names
    assert design.renamed(recorded) != recorded  # the committed file was written under the old ones
    with pytest.raises(RunError, match="holds another protocol"):
        confirm.open_folder(committed, t3.Protocol(seed=2, sources="per_target"), None)
    # the CLI says it before any compute
    assert cli.main(["confirm", "--out", str(tmp_path / "cli")]) == 2
    assert "give --basis DIR" in capsys.readouterr().err
    assert cli.main(["confirm", "--out", str(tmp_path / "cli"), "--batch", "0", "--basis", "x"]) == 2
    assert "--batch: allowed an integer >= 1" in capsys.readouterr().err


def test_the_committed_design_fixes_every_paper_cell_within_the_affordable_most():
    dsg = design.renamed(json.loads((ROOT / "docs" / "table3_confirmatory" / "protocol.json").read_text())["design"])
    assert dsg["role"] == "confirmatory" and dsg["sources"] == "per_target" and dsg["looks"] == "planned"
    assert dsg["test"] == design.TEST and dsg["margin"] == list(design.MARGIN)
    assert dsg["primary"] == [c.key for c in design.PRIMARY]
    assert set(dsg["runs"]) == {f"{m}/{s}" for m in ("neat", "hyperneat") for s in design.PAPER_SETUPS}
    assert all(design.RUNS_PER_CELL <= n <= design.CONFIRMATORY_MOST for n in dsg["runs"].values())
    basis = dsg["basis"]["comparisons"]
    for measure, by in basis.items():
        for key, c in by.items():
            a, b = key.split(" > ")
            if c["runs_needed"] is None:  # declared not decidable at an affordable cost
                assert f"{measure}: {key}" in dsg["basis"]["not decidable at an affordable cost"]
                assert c["power_at_most"] < design.POWER_GOAL
            else:  # both its cells hold at least what 80% needs
                assert dsg["runs"][a] >= c["runs_needed"] and dsg["runs"][b] >= c["runs_needed"]


def _table3_as_the_design_read_it(tmp_path) -> pathlib.Path:
    """docs/table3 as it stood when the confirmatory design was derived from it (2026-12-06, 56d438f), rebuilt from
    today's folder: its results.csv has changed since in three ways that leave every number of those runs as it was,
    undone here: PPO's runs were appended (e.g. d4e24db), the hybrid's target setups were renamed from novelty and
    none_novelty (e778ca8), and rows gained a platform column (17bb901)."""
    with (ROOT / "docs" / "table3" / "results.csv").open(newline="") as f:
        reader = csv.DictReader(f)
        fields, rows = reader.fieldnames, list(reader)
    old_name = {new: old for old, new in t3.OLD_SETUPS.items()}
    then = [{**r, "setup": old_name.get(r["setup"], r["setup"]) if r["phase"] == "target" else r["setup"]}
            for r in rows if r["method"] != "ppo"]
    basis = tmp_path / "table3"
    basis.mkdir()
    shutil.copy(ROOT / "docs" / "table3" / "protocol.json", basis / "protocol.json")
    with (basis / "results.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=[k for k in fields if k != "platform"], extrasaction="ignore",
                           lineterminator="\n")
        w.writeheader()
        w.writerows(then)
    return basis


# in the default suite (7 s, no compiling), so that a change to the form of docs/table3's results.csv shows at once
def test_the_committed_design_is_what_docs_table3_gives_again(tmp_path):
    """derive() from docs/table3's runs as they were when the design was derived (their results.csv then, rebuilt
    from today's: it has the digest the design records) gives the committed design."""
    dsg = design.renamed(json.loads((ROOT / "docs" / "table3_confirmatory" / "protocol.json").read_text())["design"])
    derived = confirm.derive(_table3_as_the_design_read_it(tmp_path), log=lambda s: None)
    assert derived["basis"]["results_sha256"] == dsg["basis"]["results_sha256"]
    assert derived["runs"] == dsg["runs"] and derived["basis"] == dsg["basis"]


def _rows(runs: dict, rng) -> list[dict]:
    """Made-up finished rows of a confirmatory folder: every planned target run, and its source."""
    rows = []
    for key, n in runs.items():
        m, s = key.split("/")
        for t in t3.TARGETS:
            for i in range(n):
                shift = {"none": 0.0, "fitness": 0.1, "hybrid": -0.05}[s] + (0.05 if m == "hyperneat" else 0.0)
                v = 0.5 + shift + rng.normal(0, 0.05)
                row = {f: "" for f in t3.FIELDS} | {
                    "method": m, "setup": s, "phase": "target", "target": t, "run": str(i), "seed": "1",
                    "objective": "fitness", "population": "150", "trials": "30", "generations": "3",
                    "episodes": "13500", "source_episodes": "0", "max_fitness": f"{v + 0.05:.4f}",
                    "test_fitness": f"{v:.4f}", "test_trials": "1000", "champion_generation": "2",
                    "protocol_seed": "1", "wall_seconds": "10", "generation_seconds": "9",
                    "best_so_far": f"{v - 0.1:.4f} {v:.4f} {v + 0.05:.4f}", "best_validation": "0.4 0.45 0.5"}
                rows.append(row)
    return rows


def test_the_report_shows_no_result_before_the_look_and_every_verdict_at_it(tmp_path):
    runs = {f"{m}/{s}": 5 for m in confirm.METHODS for s in confirm.SETUPS}
    dsg = design.design(role="confirmatory", sources="per_target", runs=runs)
    out = tmp_path / "c"
    out.mkdir()
    (out / "protocol.json").write_text(json.dumps({**t3.Protocol(seed=1, sources="per_target").to_json(),
                                                   "design": dsg}))
    rows = _rows(runs, np.random.default_rng(0))
    csvfile.write(out / "results.csv", t3.FIELDS, rows[:-1])  # one run short
    md = report.write(out).read_text()
    assert "runs under way" in md and "89 of 90 target runs" in md
    for hidden in ("max_fitness ours", "P(a > b) =", "supported", "contradicted", "mean (sd)"):
        assert hidden not in md.split("| cell |")[1]  # no result of any comparison or cell
    csvfile.write(out / "results.csv", t3.FIELDS, rows)
    md = report.write(out).read_text()
    assert "## The paper's claims on these runs" in md and "One look, when every cell holds its planned runs" in md
    assert "Nothing: every cell of the design holds its planned runs." in md
    assert "HyperNEAT: Fitness transfer vs No transfer (4v3, 5v3, 6v4): supported" in md


@pytest.mark.slow
def test_a_tiny_confirmatory_protocol_trains_a_source_of_its_own_for_every_transfer_run(tmp_path):
    """Tiny runs through table3.run with sources per target: every transfer run's row names its own source's seed,
    each source trained once, and a second call does nothing."""
    out = tmp_path / "c"
    p = t3.Protocol(seed=1, test_trials=4, source_generations=2, target_generations=2, overrides=SMALL,
                    sources="per_target")
    runs = {f"{m}/{s}": 1 for m in confirm.METHODS for s in confirm.SETUPS}
    dsg = design.design(role="confirmatory", sources="per_target", runs=runs)
    t3.create_folder(out, p)
    design.check_folder(out, p, (t3.SOURCE_TASK, *t3.TARGETS), lambda s: None, dsg)
    specs = [s for s in confirm.specs(dsg, 0, 1) if s.method == "neat"]
    rows = t3.run(out, p, specs, batch=16, design_record=dsg, log=lambda s: None)
    every = t3.read_results(out / "results.csv")
    sources = {(r["setup"], int(r["run"])): r["seed"] for r in every if r["phase"] == "source"}
    assert len(rows) == 9 and len(sources) == 6  # fitness and hybrid sources, one per target
    for r in every:
        if r["phase"] == "target" and r["setup"] != "none":
            objective = t3.SETUPS[r["setup"]].source_objective
            assert r["source_seed"] == sources[(objective, t3.TARGETS.index(r["target"]))]
    lines = []
    t3.run(out, p, specs, batch=16, design_record=dsg, log=lines.append)
    assert any("0 to run" in ln for ln in lines) and len(t3.read_results(out / "results.csv")) == len(every)
    with pytest.raises(RunError, match="design: the statistical design recorded before the runs differs"):
        t3.run(out, p, specs, batch=16, design_record=design.design(role="confirmatory", sources="per_target",
                                                                     runs=runs | {"neat/none": 2}))


@pytest.mark.slow  # 15-40 s cold: the default suite's 7 minutes in a fresh clone on an AVX2 CPU (make test-slow)
def test_the_committed_confirmatory_report_regenerates_byte_for_byte(tmp_path):
    committed = ROOT / "docs" / "table3_confirmatory"
    for name in ("results.csv", "protocol.json"):
        shutil.copy(committed / name, tmp_path)
    report.write(tmp_path)
    names = sorted(p.name for p in committed.iterdir() if p.suffix in (".md", ".png"))
    assert "report.md" in names
    for name in names:
        assert (tmp_path / name).read_bytes() == (committed / name).read_bytes(), name
