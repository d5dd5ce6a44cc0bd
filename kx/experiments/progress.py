"""The running protocol's progress line and its ETA (:func:`kx.experiments.table3.run` prints it): runs done
of total, the current group's generation and best fitness, and what the groups still to go cost at the finished
runs' wall times (each run's share of its group's; :mod:`kx.experiments.planning` costs a whole folder the same
way)."""

from __future__ import annotations

import re
import time

from kx.evolve import outputs as run_outputs
from kx.experiments import processes


def kinds(row_or_spec) -> tuple[tuple, tuple, tuple]:
    """What a run's cost depends on, finest first: its cell (method, setup, phase, task: a transferred
    population plays longer episodes from its first generation), then its method, phase and task, then its
    method and phase (another task's: its teams and episodes differ, so the cost is only a guide)."""
    if not isinstance(row_or_spec, dict):
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

    def __init__(self, log, todo: list[list], done: int, total: int, rows: list[dict]):
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

    def start(self, spec, what: str | None = None):
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
