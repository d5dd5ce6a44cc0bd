"""A confirmatory replication of Table 3 (``python -m kx.experiments confirm``): a new protocol seed, each target
run trained from a 3v2 source of its own (the three targets independent samples), every cell's runs fixed in
advance from the corrected test's power at an earlier folder's observed effects, and the design written into
protocol.json before the first run.

The design (:func:`derive`): for each primary comparison and measure, the runs a cell at which the pooled test
(:func:`kx.experiments.stats.clustered_van_elteren`, independent runs) reaches 80% power at ``alpha / 9`` in the
direction the earlier folder observed, every cell's runs resampled within each target (so the earlier folder's
shared sources do not carry over); a comparison that needs more than :data:`kx.experiments.design.CONFIRMATORY_MOST`
is declared not decidable at an affordable cost. A cell holds the most its decidable comparisons need, and at least
the paper's 20. One look, when every cell holds its runs: the report gives no verdict before.

The runs go in rounds of ``batch`` run indices over every cell (the sources of a round first), so a folder killed
at any point holds whole groups, and the same command resumes it, on any machine that reproduces its sources
(:func:`kx.experiments.table3.run`).
"""

from __future__ import annotations

import hashlib
import json
import pathlib
from typing import Callable

import numpy as np

from kx.evolve.errors import RunError
from kx.experiments import design, stats
from kx.experiments import table3 as t3

METHODS = ("neat", "hyperneat")
SETUPS = design.PAPER_SETUPS
#: the run counts the power search tries, up to the affordable most
CANDIDATES = tuple(n for n in design.POWER_RUNS if n <= design.CONFIRMATORY_MOST)


def _cells(rows: list[dict], measure: str) -> dict:
    """``{(method, setup, target): {run: value}}`` of the target rows."""
    out: dict = {}
    for r in rows:
        if r["phase"] == "target":
            out.setdefault((r["method"], r["setup"], r["target"]), {})[int(r["run"])] = float(r[measure])
    return out


def derive(basis: pathlib.Path, log: Callable[[str], None] = print) -> dict:
    """The confirmatory design derived from the folder ``basis`` (its results.csv and the sources it recorded):
    the runs a cell, and per measure and primary comparison the observed direction and effect, the runs a cell
    for 80% (``None``: more than the affordable most) and the power at the most."""
    basis = pathlib.Path(basis)
    path = basis / "results.csv"
    rows = t3.read_results(path)
    if not rows:
        raise RunError(f"{path}: no runs to derive a confirmatory design from")
    shared = t3.Protocol.read(basis / "protocol.json").sources == "shared"
    runs = {f"{m}/{s}": design.RUNS_PER_CELL for m in METHODS for s in SETUPS}
    level = design.ALPHA / len(design.PRIMARY)
    record: dict = {}
    for measure in design.MEASURES:
        cells = _cells(rows, measure)
        record[measure] = {}
        for claim in design.PRIMARY:
            targets = [t for t in t3.TARGETS if (*claim.a, t) in cells and (*claim.b, t) in cells]
            if not targets:
                raise RunError(f"{path}: {claim.key} has no target with runs of both cells")
            # the earlier folder as its design analyses it (its direction), and as independent runs (the power)
            obs = [stats.cluster_matrix([cells[(*c, t)] for t in targets], shared and t3.SETUPS[c[1]].source_objective
                                        is not None) for c in (claim.a, claim.b)]
            ind = [stats.cluster_matrix([cells[(*c, t)] for t in targets], False) for c in (claim.a, claim.b)]
            test = stats.clustered_van_elteren(*obs)
            way = int(np.sign(test.z))
            needed = (stats.clustered_runs_needed(*ind, level, design.POWER_GOAL, CANDIDATES, direction=way)
                      if way else None)
            at_most = stats.clustered_power(*ind, level, runs=design.CONFIRMATORY_MOST, direction=way) if way else 0.0
            record[measure][claim.key] = {"direction": way, "poi": round(test.poi.value, 4), "runs_needed": needed,
                                          "power_at_most": round(at_most, 4)}
            log(f"kx confirm: {measure} {claim.key}: P = {test.poi.value:.2f}, runs a cell for 80% "
                f"{needed if needed else f'> {design.CONFIRMATORY_MOST}'} (power at {design.CONFIRMATORY_MOST}: "
                f"{at_most:.0%})")
            if needed:
                for c in (claim.a, claim.b):
                    key = f"{c[0]}/{c[1]}"
                    runs[key] = max(runs[key], needed)
    digest = "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()
    undecidable = [f"{m}: {k}" for m, by in record.items() for k, v in by.items() if v["runs_needed"] is None]
    return {"runs": runs, "basis": {"folder": basis.name, "results_sha256": digest, "level": level,
                                     "candidates": list(CANDIDATES), "comparisons": record,
                                     "not decidable at an affordable cost": undecidable}}


def specs(dsg: dict, lo: int, hi: int) -> list[t3.RunSpec]:
    """The target runs of indices ``lo <= i < hi`` of every cell the confirmatory design ``dsg`` plans, in the
    plan's order (run by run, each method's targets by target and setup)."""
    out = []
    for i in range(lo, hi):
        for m in METHODS:
            for t in t3.TARGETS:
                for s in SETUPS:
                    if i < dsg["runs"][f"{m}/{s}"]:
                        out.append(t3.RunSpec(m, s, "target", t, i))
    return out


def open_folder(out: pathlib.Path, protocol: t3.Protocol, basis: pathlib.Path | None,
                log: Callable[[str], None] = print) -> dict:
    """The folder's recorded confirmatory design; where ``out`` has no protocol.json yet, derives it from
    ``basis`` (:func:`derive`) and writes protocol.json with it, before any run. An existing folder must hold a
    confirmatory design of the same protocol."""
    out = pathlib.Path(out)
    path = out / "protocol.json"
    if path.is_file():
        have = json.loads(path.read_text())
        if have.get("design", {}).get("role") != "confirmatory":
            raise RunError(f"{path}: not a confirmatory protocol (its design's role is "
                           f"{have.get('design', {}).get('role', 'exploratory')!r}): use another --out")
        t3.same_protocol(out, protocol)
        return design.renamed(have["design"])  # a folder written under the hybrid's old setup names too
    if basis is None:
        raise RunError(f"{out}: a new confirmatory folder derives its design from an earlier one: give --basis DIR")
    if protocol.sources != "per_target":
        raise RunError("sources: a confirmatory protocol gives each target run a source of its own (per_target)")
    derived = derive(basis, log)
    dsg = design.design(role="confirmatory", sources=protocol.sources, runs=derived["runs"], basis=derived["basis"])
    t3.create_folder(out, protocol)
    design.check_folder(out, protocol, (t3.SOURCE_TASK, *t3.TARGETS), lambda s: None, dsg)
    log(f"kx confirm: {path} written with the design (runs a cell: "
        + ", ".join(f"{k} {v}" for k, v in dsg["runs"].items()) + ")")
    return dsg


def run(out, protocol: t3.Protocol, basis=None, batch: int = 16, log: Callable[[str], None] = print,
        design_only: bool = False) -> list[dict]:
    """Opens (or creates) the confirmatory folder ``out`` and trains every planned run not yet in its results.csv,
    in rounds of ``batch`` run indices; with ``design_only`` it writes protocol.json and stops."""
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"--batch: allowed an integer >= 1, got {batch!r}")
    out = pathlib.Path(out)
    dsg = open_folder(out, protocol, None if basis is None else pathlib.Path(basis), log)
    if design_only:
        return []
    most = max(dsg["runs"].values())
    rows: list[dict] = []
    for lo in range(0, most, batch):
        rows += t3.run(out, protocol, specs(dsg, lo, min(lo + batch, most)), log=log, batch=batch, design_record=dsg)
    return rows
