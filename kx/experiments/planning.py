"""What a protocol folder still needs and what it costs: the cells short of their runs, the cells extended
past them, whether a confirmatory design is complete, and the wall time of the rest, all from the finished
rows' own wall times (each run's share of its group's) on the machine that ran them. The running protocol's
progress line and ETA are :mod:`kx.experiments.progress`'s.

The report (:mod:`kx.experiments.report`) prints these; nothing here decides a result.
"""

from __future__ import annotations

import collections

import numpy as np

from kx.experiments import design
from kx.experiments import table3 as t3


def run_seconds(rows: list[dict], spec: t3.RunSpec) -> tuple[float | None, bool]:
    """What one run of ``spec`` costs on the machine ``rows`` ran on: the mean wall time per run of its method,
    phase and target in ``rows``; with no run of that target, the mean over its method and phase's other
    targets (then the flag is true); ``None`` with no run of its method and phase at all."""
    same = [r for r in rows if r["method"] == spec.method and r["phase"] == spec.phase]
    here = [r for r in same if r["target"] == spec.target]
    if not same:
        return None, False
    return float(np.mean([float(r["wall_seconds"]) for r in here or same])), not here



def full_protocol_seconds(rows: list[dict], runs: int = 20) -> tuple[float, set, set]:
    """The whole protocol's wall time on the machine these rows ran on: every run of :func:`table3.plan`
    (``runs`` a cell, every method, target and setup) at the mean wall time per run of its method, phase
    and target in ``rows`` (:func:`run_seconds`). Returns the seconds, the target tasks with no run here
    (costed at their method's mean over the targets that have some) and the method phases with none (left
    out)."""
    total, borrowed, missing = 0.0, set(), set()
    for spec in t3.plan(runs=runs):
        seconds, other = run_seconds(rows, spec)
        if seconds is None:
            missing.add(f"{t3.METHOD_NAMES[spec.method]} {spec.phase}")
            continue
        if other:
            borrowed.add(spec.target)
        total += seconds
    return total, borrowed, missing



def full_protocol_estimate(rows: list[dict], runs: int = 20) -> str:
    """:func:`full_protocol_seconds` as the report's sentence."""
    total, borrowed, missing = full_protocol_seconds(rows, runs)
    text = (f"The full protocol ({len(t3.plan(runs=runs))} runs: {runs} a cell, targets {', '.join(t3.TARGETS)}, "
            f"every setup of NEAT and HyperNEAT, the two of CMA-ES and of PPO on each network) at these mean wall "
            f"times per run: **{total / 3600:.1f} hours** "
            "one after another on this machine")
    if borrowed:
        text += (f"; a method's targets with no runs of it here ({', '.join(sorted(borrowed, key=t3.TARGETS.index))}"
                 ") costed at its mean over the targets it has runs in (not measured: their teams and episodes "
                 "differ)")
    if missing:
        text += f"; left out, with no runs here: {', '.join(sorted(missing))}"
    return text + "."



def still_to_run(rows: list[dict], runs: int = design.RUNS_PER_CELL) -> list[dict]:
    """The cells of the full protocol (:func:`table3.plan` at ``runs`` a cell) that ``rows`` does not fill, in
    the plan's order of a run index's cells: per cell its method, phase, target, setup, the runs it has and the runs it
    lacks, and what those cost on this machine (:func:`run_seconds`; ``None`` where the method's phase has
    no run to cost them by, ``borrowed`` where its target has none)."""
    have = collections.Counter((r["method"], r["phase"], r["target"], r["setup"]) for r in rows)
    done = {t3.row_key(r) for r in rows}
    cells: dict[tuple, dict] = {}
    for spec in t3.plan(runs=runs):
        if spec.key in done:
            continue
        cell = (spec.method, spec.phase, spec.target, spec.setup)
        seconds, other = run_seconds(rows, spec)
        c = cells.setdefault(cell, {"method": spec.method, "phase": spec.phase, "target": spec.target,
                                    "setup": spec.setup, "runs": have[cell], "missing": 0, "seconds": 0.0,
                                    "borrowed": other})
        c["missing"] += 1
        c["seconds"] = None if seconds is None else c["seconds"] + seconds
    rank = {(s.method, s.phase, s.target, s.setup): i for i, s in enumerate(t3.plan(runs=1))}
    return sorted(cells.values(), key=lambda c: rank[c["method"], c["phase"], c["target"], c["setup"]])



def extended_cells(rows: list[dict], runs: int = design.RUNS_PER_CELL) -> list[dict]:
    """The cells holding more than the protocol's ``runs`` (extended where the power figure asked for more,
    up to :data:`design.EXTEND_UP_TO`), in the plan's order: per cell its method, phase, target, setup, its
    runs, and the keys of the primary claims whose comparison it enters (a source cell: none)."""
    have = collections.Counter((r["method"], r["phase"], r["target"], r["setup"]) for r in rows)
    rank = {(s.method, s.phase, s.target, s.setup): i for i, s in enumerate(t3.plan(runs=1))}
    cells = sorted((c for c, n in have.items() if n > runs), key=lambda c: rank.get(c, len(rank)))
    return [{"method": m, "phase": p, "target": t, "setup": s, "runs": have[m, p, t, s],
             "claims": [] if p == "source" else [c.key for c in design.PRIMARY if (m, s) in (c.a, c.b)]}
            for m, p, t, s in cells]



def complete(rows: list[dict], dsg: dict) -> bool:
    """Whether every cell a confirmatory design plans holds its runs in every target."""
    have = collections.Counter((r["method"], r["setup"], r["target"]) for r in rows if r["phase"] == "target")
    return all(have[(*k.split("/"), t)] >= n for k, n in dsg["runs"].items() for t in t3.TARGETS)



def confirmatory_rest(rows: list[dict], dsg: dict) -> tuple[float, int]:
    """What the runs a confirmatory design (``dsg``) still lacks cost one after another: each missing run at the
    mean wall time of the finished runs of its method and phase. Returns the seconds and the number of missing
    runs of a method and phase with none finished (not costed)."""
    have = collections.Counter((r["method"], r["setup"], r["target"]) for r in rows if r["phase"] == "target")
    left: collections.Counter = collections.Counter()
    for key, n in dsg["runs"].items():
        m, s = key.split("/")
        for t in t3.TARGETS:
            left[(m, "target")] += max(n - have[(m, s, t)], 0)
            left[(m, "source")] += n if t3.SETUPS[s].source_objective else 0
    for r in rows:
        left[(r["method"], "source")] -= r["phase"] == "source"
    rest, uncosted = 0.0, 0
    for (m, phase), k in left.items():
        walls = [float(r["wall_seconds"]) for r in rows if (r["method"], r["phase"]) == (m, phase)]
        if k > 0 and walls:
            rest += k * float(np.mean(walls))
        elif k > 0:
            uncosted += k
    return rest, uncosted
