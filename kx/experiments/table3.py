"""The paper's experiment protocol (SPEC section 6): source runs in 3v2, target runs in 4v3, 5v3 and 6v4
with and without transfer and novelty, every run measured twice, one tidy results file.

For each method and run index ``i``:

* *source* runs in 3v2 (``source_generations``): one with ``objective = fitness`` and one with
  ``objective = hybrid``, when a selected setup needs it;
* *target* runs in each target task (``target_generations``), one per setup (:data:`SETUPS`): no
  transfer; fitness transfer (seeded with fitness source ``i``'s whole final population); fitness +
  novelty transfer (seeded with hybrid source ``i``, the hybrid in the target too); and, beyond the
  paper, no transfer with the hybrid. CMA-ES (:data:`METHOD_SETUPS`) has no transfer and the transfer of
  its source's mean and step size, with generations scaled so that its budget in evaluations equals
  NEAT's.

Every run has its own seed (:func:`run_seed`), its own run directory under ``DIR/runs`` (resumed from its
checkpoint if the protocol was killed), and, once finished, one row in ``DIR/results.csv``
(:data:`FIELDS`): the paper's measure (the maximum over the run of the generation's best training
fitness), the validated champion's fitness on the protocol's test states (the same ``test_trials``
states of the target for every run: the test stream of the protocol seed), both per-generation curves,
the budget and the times. A finished run is never run again; the same ``DIR`` accumulates parts
(``--methods``, ``--targets``, ``--setups``, ``--runs``) of one protocol, whose fixed parameters are in
``DIR/protocol.json``.

The runs of one cell (method, setup, phase, task) share a config but for their seeds and sources, so
they train as batched groups of up to ``batch`` runs (:mod:`kx.evolve.group`; the sources before the
targets they seed), each run in its own run directory, bit for bit what it writes trained alone: every
column of results.csv but the times is the same whatever ``batch``. A run of a group of R is charged
1/R of the group's time (``wall_seconds``, ``generation_seconds``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import pathlib
import re
import time
from typing import Callable, Iterable

import ml_collections

from kx.evolve import config as cfg_lib
from kx.evolve import outputs as run_outputs
from kx.evolve.errors import RunError
from kx.experiments import csvfile, measure

METHODS = ("neat", "hyperneat", "cma_es")
SOURCE_TASK = "3v2"
TARGETS = ("4v3", "5v3", "6v4")


@dataclasses.dataclass(frozen=True)
class Setup:
    label: str  # as the report prints it
    source_objective: str | None  # the objective of the source run it is seeded from (None: no transfer)
    objective: str  # the target run's objective


SETUPS = {
    "none": Setup("No transfer", None, "fitness"),
    "fitness": Setup("Fitness transfer", "fitness", "fitness"),
    "novelty": Setup("Fitness + NS transfer", "hybrid", "hybrid"),
    "none_novelty": Setup("No transfer, fitness + NS", None, "hybrid"),  # beyond the paper
}
#: the setups each method runs (CMA-ES: the standard-optimiser reference, fitness only)
METHOD_SETUPS = {"neat": tuple(SETUPS), "hyperneat": tuple(SETUPS), "cma_es": ("none", "fitness")}

#: results.csv's columns, one row per finished run (source runs too: phase "source", target "3v2")
FIELDS = ("method", "setup", "phase", "target", "run", "seed", "source_seed", "objective", "population", "trials",
          "generations", "episodes", "source_episodes", "max_fitness", "test_fitness", "test_trials",
          "champion_generation", "protocol_seed", "wall_seconds", "generation_seconds", "best_so_far",
          "best_validation")
CURVES = ("best_so_far", "best_validation")


@dataclasses.dataclass(frozen=True)
class Protocol:
    """The parameters every run of one protocol shares (``DIR/protocol.json``)."""

    seed: int = 0
    test_trials: int = 1000
    source_generations: int = 20
    target_generations: int = 50
    overrides: tuple[str, ...] = ()  # config overrides applied to every run ("population_size=50", ...)

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "overrides": list(self.overrides)}


@dataclasses.dataclass(frozen=True)
class RunSpec:
    method: str
    setup: str  # a key of SETUPS for a target run; the objective ("fitness", "hybrid") for a source run
    phase: str  # "source" or "target"
    target: str  # the task: 3v2 for a source run
    run: int

    @property
    def key(self) -> tuple:
        return (self.method, self.setup, self.phase, self.target, self.run)

    def describe(self) -> str:
        what = f"source ({self.setup})" if self.phase == "source" else SETUPS[self.setup].label
        return f"{self.method} {self.target} {what} run {self.run}"


def run_seed(protocol_seed: int, method: str, setup: str, phase: str, target: str, run: int) -> int:
    """The seed of one run: a hash of the protocol seed and the run's place in the protocol (method, setup,
    phase, target, run index), so that no two runs share training or validation states."""
    text = f"kx-table3/{protocol_seed}/{method}/{setup}/{phase}/{target}/{run}".encode()
    return int.from_bytes(hashlib.blake2b(text, digest_size=8).digest(), "little") % (2**31 - 1)


def _check_choice(field: str, got: Iterable[str], allowed: Iterable[str]) -> tuple[str, ...]:
    got, allowed = tuple(got), tuple(allowed)
    bad = [g for g in got if g not in allowed]
    if bad or not got:
        raise ValueError(f"{field}: allowed {', '.join(allowed)} (one or more), got {', '.join(got) or 'nothing'}")
    return got


def plan(methods=METHODS, targets=TARGETS, setups=tuple(SETUPS), runs: int = 20) -> list[RunSpec]:
    """The runs of the selected part of the protocol, in the order they run: run index by run index
    (so that every cell grows together), per method its sources first, then its target runs."""
    methods = _check_choice("--methods", methods, METHODS)
    targets = _check_choice("--targets", targets, TARGETS)
    setups = _check_choice("--setups", setups, SETUPS)
    if not isinstance(runs, int) or runs < 1:
        raise ValueError(f"--runs: allowed an integer >= 1, got {runs!r}")
    out = []
    for i in range(runs):
        for m in methods:
            chosen = [s for s in setups if s in METHOD_SETUPS[m]]
            for objective in ("fitness", "hybrid"):
                if any(SETUPS[s].source_objective == objective for s in chosen):
                    out.append(RunSpec(m, objective, "source", SOURCE_TASK, i))
            for t in targets:
                out.extend(RunSpec(m, s, "target", t, i) for s in chosen)
    return out


def source_of(spec: RunSpec) -> RunSpec | None:
    """The source run a target run is seeded from (run ``i`` from source ``i``), or ``None``."""
    objective = SETUPS[spec.setup].source_objective if spec.phase == "target" else None
    return None if objective is None else RunSpec(spec.method, objective, "source", SOURCE_TASK, spec.run)


def run_dir(out: pathlib.Path, spec: RunSpec) -> pathlib.Path:
    return pathlib.Path(out) / "runs" / spec.method / f"{spec.phase}-{spec.setup}" / spec.target / f"run{spec.run:02d}"


def _reference_population(protocol: Protocol) -> int:
    """NEAT's population with the protocol's overrides: the budget every method's generations match."""
    return int(cfg_lib.load(cfg_lib.CONFIG_DIR / "neat_3v2.py", list(protocol.overrides)).population_size)


def config(protocol: Protocol, spec: RunSpec, out: pathlib.Path) -> ml_collections.ConfigDict:
    """The config of one run, source or target: the method's shipped config of the run's task, the protocol's
    overrides, the run's seed (:func:`run_seed`), objective and generations (CMA-ES's scaled to NEAT's
    evaluations), no GIF, and for a transfer run its source's run directory under ``out``
    (:func:`run_dir`). The one config builder of the experiments' runs: ``python -m kx.bench transfer``
    builds its sources and targets with it too."""
    generations = protocol.source_generations if spec.phase == "source" else protocol.target_generations
    objective = spec.setup if spec.phase == "source" else SETUPS[spec.setup].objective
    src = source_of(spec)
    over = [*protocol.overrides, "gif=false", f"objective={objective}", f"seed={run_seed(protocol.seed, *spec.key)}"]
    if src is not None:
        over.append(f"transfer.source={run_dir(out, src)}")
    cfg = cfg_lib.load(cfg_lib.CONFIG_DIR / f"{spec.method}_{spec.target}.py", over)
    budget = generations * _reference_population(protocol)
    cfg.generations = max(1, math.ceil(budget / cfg.population_size))
    cfg_lib.validate(cfg)
    return cfg


# ---------------------------------------------------------------------------------------------- results.csv

def read_results(path: pathlib.Path) -> list[dict]:
    """results.csv's rows (strings), in file order; [] when there is none."""
    return csvfile.read(path, FIELDS, "kx table3 results file")


def row_key(row: dict) -> tuple:
    return (row["method"], row["setup"], row["phase"], row["target"], int(row["run"]))


def curve(row: dict, name: str) -> list[float]:
    return [float(v) for v in row[name].split()]


# ------------------------------------------------------------------------------------------------ running

def _open(out: pathlib.Path, protocol: Protocol) -> None:
    """Creates ``out`` with its protocol.json, or checks that an existing one is the same protocol."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / "protocol.json"
    want = protocol.to_json()
    if path.is_file():
        have = json.loads(path.read_text())
        diff = [f"{k}: {have.get(k)!r} in {path}, {want[k]!r} now" for k in want if have.get(k) != want[k]]
        if diff:
            raise RunError(f"{out} holds another protocol ({'; '.join(diff)}): use another --out, or the same "
                           "parameters to add runs to it")
    else:
        run_outputs.write_json(path, want)


def results_row(protocol: Protocol, spec: RunSpec, out: pathlib.Path, finished: measure.Finished) -> dict:
    """The results row of the finished run of ``spec``, measured on the protocol's test states of its task
    (:func:`kx.experiments.measure.train_and_measure`): its metrics.csv curves, its validated champion's test
    fitness, and its share of its batched group's wall time and of the generations' times."""
    cfg, rows, share = finished.trainer.cfg, finished.metrics, finished.share
    src = source_of(spec)
    src_evals = 0
    if src is not None:
        scfg = config(protocol, src, out)
        src_evals = scfg.generations * scfg.population_size * scfg.trials
    return {
        "method": spec.method, "setup": spec.setup, "phase": spec.phase, "target": spec.target, "run": spec.run,
        "seed": cfg.seed, "source_seed": "" if src is None else run_seed(protocol.seed, *src.key),
        "objective": cfg.objective, "population": cfg.population_size, "trials": cfg.trials,
        "generations": cfg.generations, "episodes": cfg.generations * cfg.population_size * cfg.trials,
        "source_episodes": src_evals, "max_fitness": finished.max_fitness,
        "test_fitness": finished.test, "test_trials": protocol.test_trials,
        "champion_generation": int(finished.state.champion_generation), "protocol_seed": protocol.seed,
        "wall_seconds": finished.wall_seconds,
        "generation_seconds": round(sum(float(r["generation_seconds"]) for r in rows) / share, 3),
        "best_so_far": " ".join(format(float(r["best_so_far"]), ".9g") for r in rows),
        "best_validation": " ".join(format(float(r["best_validation"]), ".9g") for r in rows),
    }


class _Progress:
    """The protocol's progress line: runs done of total, the current run's generation, an ETA from the
    measured seconds per generation of each (method, task)."""

    def __init__(self, log, todo: list[tuple[RunSpec, int]], done: int, total: int):
        self.log, self.todo, self.done, self.total = log, list(todo), done, total
        self.per_gen: dict[tuple[str, str], list[float]] = {}
        self.last = None
        self.current = None

    def start(self, spec: RunSpec, what: str | None = None):
        self.current, self.last, self.what = spec, None, what or spec.describe()

    def finish(self, n: int = 1):
        self.todo.pop(0)
        self.done += n

    def _rate(self, method: str, task: str) -> float | None:
        if self.per_gen.get((method, task)):
            return sum(self.per_gen[(method, task)]) / len(self.per_gen[(method, task)])
        same = [v for (m, _), vs in self.per_gen.items() if m == method for v in vs]
        pooled = same or [v for vs in self.per_gen.values() for v in vs]
        return sum(pooled) / len(pooled) if pooled else None

    def eta(self, generation_done: int) -> float | None:
        total = 0.0
        for i, (spec, gens) in enumerate(self.todo):
            rate = self._rate(spec.method, spec.target)
            if rate is None:
                return None
            total += rate * (gens - generation_done if i == 0 else gens)
        return total

    def line(self, text: str):
        spec = self.current
        m = re.match(r"gen\s+(\d+)/(\d+)\s+(?:\d+ runs\s+)?best\s+(\S+)", text)
        if m:
            now = time.perf_counter()
            if self.last is not None:  # the first generation of a process compiles: not a rate
                self.per_gen.setdefault((spec.method, spec.target), []).append(now - self.last)
            self.last = now
            eta = self.eta(int(m.group(1)))
            when = "" if eta is None else f"  protocol ETA {run_outputs.format_seconds(eta)}"
            self.log(f"[{self.done}/{self.total} runs | {self.what}] gen {m.group(1)}/{m.group(2)}  "
                     f"best {m.group(3)}{when}")
        elif not re.sub(r"^\[seed \d+\] ", "", text).startswith(("validation states", "kx.train:", "done:",
                                                                     "transfer:")):
            self.log(f"[{self.done}/{self.total} runs | {self.what}] {text}")


def cell(spec: RunSpec) -> tuple:
    """The runs that can train as one batched group: those of one method, setup, phase and task."""
    return spec.key[:4]


def groups(needed: list[RunSpec], batch: int) -> list[list[RunSpec]]:
    """``needed`` dealt into batched groups of at most ``batch`` runs of one :func:`cell`: the sources'
    groups first (every target's source is then finished before it starts), each cell in the order of
    its first run. ``batch`` 1: every run alone, in ``needed``'s order (the plan's: run index by run
    index, each method's sources first)."""
    if batch == 1:
        return [[spec] for spec in needed]
    cells: dict[tuple, list[RunSpec]] = {}
    for spec in sorted(needed, key=lambda s: s.phase != "source"):  # stable: the plan's order otherwise
        cells.setdefault(cell(spec), []).append(spec)
    return [specs[i:i + batch] for specs in cells.values() for i in range(0, len(specs), batch)]


def _span(specs: list[RunSpec]) -> str:
    runs = [s.run for s in specs]
    which = f"run {runs[0]}" if len(runs) == 1 else f"runs {','.join(map(str, runs))}"
    return specs[0].describe().rsplit(" run ", 1)[0] + " " + which


def run(out: str | pathlib.Path, protocol: Protocol, specs: list[RunSpec],
        log: Callable[[str], None] = print, batch: int = 16) -> list[dict]:
    """Runs every run of ``specs`` not yet in ``out/results.csv`` (a transfer run's source first, even if
    not selected), in batched groups of up to ``batch`` runs of one cell (1: one by one), each run resumed
    from its checkpoint if a previous protocol was killed during it; appends each finished run's row.
    Returns the rows of ``specs``."""
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"--batch: allowed an integer >= 1, got {batch!r}")
    out = pathlib.Path(out).absolute()
    for spec in specs:  # every config checked before any compute
        config(protocol, spec, out)
    _open(out, protocol)
    results_path = out / "results.csv"
    rows = read_results(results_path)
    have = {row_key(r) for r in rows}
    needed: list[RunSpec] = []
    for spec in specs:
        src = source_of(spec)
        for s in ((src,) if src is not None else ()) + (spec,):
            if s.key not in have and s not in needed:
                needed.append(s)
    total = len({s.key for s in specs} | {s.key for s in needed})
    chunks = groups(needed, batch)
    progress = _Progress(log, [(c[0], config(protocol, c[0], out).generations) for c in chunks],
                         total - len(needed), total)
    grouped = f" in {len(chunks)} groups of up to {batch}" if batch > 1 and chunks else ""
    log(f"kx table3: {total} runs, {total - len(needed)} done, {len(needed)} to run{grouped} -> {out}")
    for chunk in chunks:
        cfgs = [config(protocol, spec, out) for spec in chunk]
        dirs = [run_dir(out, spec) for spec in chunk]
        resumed = sum(measure.started(d) for d in dirs)
        progress.start(chunk[0], _span(chunk))
        log(f"[{progress.done}/{total} runs] {_span(chunk)}: seeds {', '.join(str(c.seed) for c in cfgs)}, "
            f"{cfgs[0].generations} generations" + (f" ({resumed} resumed)" if resumed else ""))
        measured = measure.train_and_measure(cfgs, dirs, protocol.seed, protocol.test_trials, log=progress.line)
        for spec, finished in zip(chunk, measured):
            row = results_row(protocol, spec, out, finished)
            rows.append(row)
            csvfile.write(results_path, FIELDS, rows)
            log(f"[{progress.done + 1}/{total} runs] {spec.describe()}: max fitness {row['max_fitness']:.4f}, test "
                f"{row['test_fitness']:.4f}")
            progress.done += 1
        progress.finish(0)
    want = {s.key for s in specs}
    return [r for r in rows if row_key(r) in want]
