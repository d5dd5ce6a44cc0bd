"""What a protocol folder still needs and what it costs: the cells short of their runs, the cells extended
past them, whether a confirmatory design is complete, the wall time of the rest, and the running protocol's
progress line with its ETA, all from the finished rows' own wall times (each run's share of its group's) on
the machine that ran them.

The report (:mod:`kx.experiments.report`) prints these; nothing here decides a result.
"""

from __future__ import annotations

import collections
import re
import time

import numpy as np

from kx.evolve import outputs as run_outputs
from kx.experiments import design, processes
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
            f"every setup, CMA-ES's and PPO's two) at these mean wall times per run: **{total / 3600:.1f} hours** "
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


def kinds(row_or_spec) -> tuple[tuple, tuple, tuple]:
    """What a run's cost depends on, finest first: its cell (method, setup, phase, task: a transferred
    population plays longer episodes from its first generation), then its method, phase and task, then its
    method and phase (another task's: its teams and episodes differ, so the cost is only a guide)."""
    if isinstance(row_or_spec, t3.RunSpec):
        m, s, p, t = row_or_spec.method, row_or_spec.setup, row_or_spec.phase, row_or_spec.target
    else:
        m, s, p, t = (row_or_spec[k] for k in ("method", "setup", "phase", "target"))
    return (m, s, p, t), (m, p, t), (m, p)


class Progress:
    """The protocol's progress line: runs done of total, the current group's generation, and an ETA.

    The ETA costs every run still to go at the mean wall time per run (``wall_seconds``: its share of its
    group's time) of the finished runs of its cell in results.csv, those of this process included, or
    where its cell has none, of its method, phase and task, or where that has none either, of its method
    and phase on the other tasks (said apart: the report's full-protocol estimate does the same); the
    current group is charged what it has left of its runs' mean (at least nothing). A run's wall time is its
    share of the machine, so where local processes share its cores (each with its own runs to go) this
    process's runs take that many times as long on the clock. A run with none of these is not costed, and
    the line says how many such runs there are and on how many finished runs the estimate rests.
    (Extrapolating this process's first generations instead underestimates: their episodes are short.)"""

    def __init__(self, log, todo: list[list[t3.RunSpec]], done: int, total: int, rows: list[dict]):
        self.log, self.todo, self.done, self.total = log, [list(c) for c in todo], done, total
        self.walls: list[float] = []  # every finished run's wall time, in the order seen
        self.runs: dict[tuple, list[int]] = {}  # each kind's finished runs (indices into walls)
        for r in rows:
            self.add(r)
        self.t0 = time.perf_counter()
        self.current = None

    def add(self, row: dict) -> None:
        self.walls.append(float(row["wall_seconds"]))
        for kind in kinds(row):
            self.runs.setdefault(kind, []).append(len(self.walls) - 1)

    def start(self, spec: t3.RunSpec, what: str | None = None):
        self.current, self.what, self.t0 = spec, what or spec.describe(), time.perf_counter()

    def finish(self, n: int = 1):
        self.todo.pop(0)
        self.done += n

    def eta(self) -> tuple[float, int, int, int]:
        """``(seconds, finished runs it rests on, runs costed at another task's runs, runs not costed)``
        for the groups still to go."""
        seconds, basis, elsewhere, unknown = 0.0, set(), 0, 0
        sharers = processes.machine_sharers()  # wall_seconds are shares of the machine; the clock runs slower
        for i, chunk in enumerate(self.todo):
            cost = 0.0
            for spec in chunk:
                kind = next((k for k in kinds(spec) if self.runs.get(k)), None)
                if kind is None:
                    unknown += 1
                    continue
                elsewhere += len(kind) == 2
                basis.update(self.runs[kind])
                cost += sharers * sum(self.walls[j] for j in self.runs[kind]) / len(self.runs[kind])
            seconds += max(cost - (time.perf_counter() - self.t0), 0.0) if i == 0 else cost
        return seconds, len(basis), elsewhere, unknown

    def eta_text(self) -> str:
        seconds, basis, elsewhere, unknown = self.eta()
        if not basis:
            return f"  protocol ETA unknown (no finished run of the kinds to go; {unknown} runs)"
        text = f"  protocol ETA {run_outputs.format_seconds(seconds)} (from {basis} finished runs"
        if elsewhere:
            text += f"; {elsewhere} runs costed at their method's runs of other tasks"
        return text + (f"; {unknown} runs of kinds with none finished not counted)" if unknown else ")")

    def line(self, text: str):
        m = re.match(r"gen\s+(\d+)/(\d+)\s+(?:\d+ runs\s+)?best\s+(\S+)", text)
        if m:
            self.log(f"[{self.done}/{self.total} runs | {self.what}] gen {m.group(1)}/{m.group(2)}  "
                     f"best {m.group(3)}{self.eta_text()}")
        elif not re.sub(r"^\[seed \d+\] ", "", text).startswith(("validation states", "kx.train:", "done:",
                                                                     "transfer:")):
            self.log(f"[{self.done}/{self.total} runs | {self.what}] {text}")
