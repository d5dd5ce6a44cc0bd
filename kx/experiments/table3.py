"""The paper's experiment protocol (SPEC section 6): source runs in 3v2, target runs in 4v3, 5v3 and 6v4
with and without transfer and the novelty hybrid, every run measured twice, one tidy results file.

Over 450 lines because the protocol's constants, its seeding, each run's config and its resumable run all read the
same RunSpec; its planning and its results file live apart (kx.experiments.planning, kx.experiments.runner).

For each method and run index ``i``:

* *source* runs in 3v2 (``source_generations``): one with ``objective = fitness`` and one with
  ``objective = hybrid``, when a selected setup needs it;
* *target* runs in each target task (``target_generations``), one per setup (:data:`SETUPS`): no
  transfer; fitness transfer (seeded with fitness source ``i``'s whole final population); hybrid
  transfer (the paper's Fitness + NS: seeded with hybrid source ``i``, the hybrid in the target too); and, beyond the
  paper, no transfer with the hybrid. CMA-ES (:data:`METHOD_SETUPS`) has no transfer and the transfer of
  its source's mean and step size, with generations scaled so that its budget in evaluations equals
  NEAT's; PPO (on the fixed layout, ``ppo``, and on the size-invariant entity network, ``ppo_entity``) has no
  transfer and the transfer of its source's final weights, NEAT's generations of NEAT's episodes each
  (``episodes_per_generation`` = NEAT's population x trials).

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
from typing import Callable, Iterable

import ml_collections

from kx import runtime
from kx.evolve import config as cfg_lib
from kx.evolve import outputs as run_outputs
from kx.evolve.errors import RunError
from kx.experiments import csvfile, design, measure, processes, runner
from kx.experiments import progress as progress_lib

METHODS = ("neat", "hyperneat", "cma_es", "ppo", "ppo_entity")
METHOD_NAMES = {"neat": "NEAT", "hyperneat": "HyperNEAT", "cma_es": "CMA-ES", "ppo": "PPO",
                "ppo_entity": "PPO entity"}  # as reports print them
SOURCES = ("shared", "per_target")
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
    "hybrid": Setup("Hybrid transfer", "hybrid", "hybrid"),  # the paper's "Fitness + NS"
    "none_hybrid": Setup("No transfer, hybrid", None, "hybrid"),  # beyond the paper
}
#: the hybrid's setups under the names they had before (``novelty``, ``none_novelty``): a folder written then reads
#: as one written now (results.csv, protocol.json's design, the run directories), and its runs keep their seeds
OLD_SETUPS = {"novelty": "hybrid", "none_novelty": "none_hybrid"}
ALIASES = {"setup": OLD_SETUPS}
#: the setups each method runs (CMA-ES, the standard optimiser, and PPO on either network, the gradient-based learners:
#: fitness only)
METHOD_SETUPS = {"neat": tuple(SETUPS), "hyperneat": tuple(SETUPS), "cma_es": ("none", "fitness"),
                 "ppo": ("none", "fitness"), "ppo_entity": ("none", "fitness")}

#: results.csv's columns, one row per finished run (source runs too: phase "source", target "3v2")
FIELDS = ("method", "setup", "phase", "target", "run", "seed", "source_seed", "objective", "population", "trials",
          "generations", "episodes", "source_episodes", "max_fitness", "test_fitness", "test_trials",
          "champion_generation", "protocol_seed", "wall_seconds", "generation_seconds", "best_so_far",
          "best_validation", "platform")
CURVES = ("best_so_far", "best_validation")
#: the columns a run's config fixes: a recorded row is checked against them before any compute
PLANNED = ("seed", "source_seed", "objective", "population", "trials", "generations", "episodes", "source_episodes",
           "test_trials", "protocol_seed")
#: the columns a run trained again must reproduce exactly: every one but the times and where it ran
REPRODUCED = tuple(f for f in FIELDS if f not in ("wall_seconds", "generation_seconds", "platform"))


@dataclasses.dataclass(frozen=True)
class Protocol:
    """The parameters every run of one protocol shares (``DIR/protocol.json``)."""

    seed: int = 0
    test_trials: int = 1000
    source_generations: int = 20
    target_generations: int = 50
    overrides: tuple[str, ...] = ()  # config overrides applied to every run ("population_size=50", ...)
    #: "shared": run i of a transfer setup in every target is seeded by source i (the paper's design: a target's
    #: runs are correlated across the targets); "per_target": each target run by a source of its own
    sources: str = "shared"

    def __post_init__(self):
        if self.sources not in SOURCES:
            raise ValueError(f"sources: allowed {', '.join(SOURCES)}, got {self.sources!r}")

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "overrides": list(self.overrides)}

    @classmethod
    def read(cls, path: str | pathlib.Path) -> "Protocol":
        """The protocol of a ``protocol.json`` (its records beside the parameters, ``design`` and
        ``test_states``, are :mod:`kx.experiments.design`'s)."""
        have = json.loads(pathlib.Path(path).read_text())
        have = {**DEFAULTS, **have}
        fields = [f.name for f in dataclasses.fields(cls)]
        missing = [f for f in fields if f not in have]
        if missing:
            raise RunError(f"{path}: not a kx table3 protocol.json (missing {', '.join(missing)})")
        return cls(**{k: tuple(have[k]) if k == "overrides" else have[k] for k in fields})


#: the parameters a protocol.json written before they existed is read with
DEFAULTS = {"sources": "shared"}


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
    if phase == "target":  # the hybrid's setups keep the seeds of their old names
        setup = {new: old for old, new in OLD_SETUPS.items()}.get(setup, setup)
    text = f"kx-table3/{protocol_seed}/{method}/{setup}/{phase}/{target}/{run}".encode()
    return int.from_bytes(hashlib.blake2b(text, digest_size=8).digest(), "little") % (2**31 - 1)


def check_choice(field: str, got: Iterable[str], allowed: Iterable[str]) -> tuple[str, ...]:
    got, allowed = tuple(got), tuple(allowed)
    bad = [g for g in got if g not in allowed]
    if bad or not got:
        raise ValueError(f"{field}: allowed {', '.join(allowed)} (one or more), got {', '.join(got) or 'nothing'}")
    return got


def plan(methods=METHODS, targets=TARGETS, setups=tuple(SETUPS), runs: int = 20) -> list[RunSpec]:
    """The runs of the selected part of the protocol, in the order they run: run index by run index
    (so that every cell grows together), per method its sources first, then its target runs."""
    methods = check_choice("--methods", methods, METHODS)
    targets = check_choice("--targets", targets, TARGETS)
    setups = check_choice("--setups", [OLD_SETUPS.get(s, s) for s in setups], SETUPS)
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


def source_of(spec: RunSpec, sources: str = "shared") -> RunSpec | None:
    """The source run a target run is seeded from, or ``None``: with ``sources`` ``shared`` run ``i`` of every
    target from source ``i``; with ``per_target`` run ``i`` of target ``k`` (its index in :data:`TARGETS`) from source
    ``3 i + k``, a source of its own."""
    objective = SETUPS[spec.setup].source_objective if spec.phase == "target" else None
    if objective is None:
        return None
    if sources not in SOURCES:
        raise ValueError(f"sources: allowed {', '.join(SOURCES)}, got {sources!r}")
    index = spec.run if sources == "shared" else spec.run * len(TARGETS) + TARGETS.index(spec.target)
    return RunSpec(spec.method, objective, "source", SOURCE_TASK, index)


def run_dir(out: pathlib.Path, spec: RunSpec) -> pathlib.Path:
    """The run's directory, ``out/runs/<method>/<phase>-<setup>/<task>/run<NN>`` (a folder's directory under its
    setup's old name where it has one: :data:`OLD_SETUPS`)."""
    def under(setup: str) -> pathlib.Path:
        return pathlib.Path(out) / "runs" / spec.method / f"{spec.phase}-{setup}" / spec.target / f"run{spec.run:02d}"

    here = under(spec.setup)
    old = [under(o) for o, new in OLD_SETUPS.items() if new == spec.setup and spec.phase == "target"]
    return old[0] if old and old[0].is_dir() and not here.exists() else here


def _reference_population(protocol: Protocol) -> int:
    """NEAT's population with the protocol's overrides: the budget every method's generations match."""
    return int(cfg_lib.load(cfg_lib.CONFIG_DIR / "neat_3v2.py", list(protocol.overrides)).population_size)


def config(protocol: Protocol, spec: RunSpec, out: pathlib.Path) -> ml_collections.ConfigDict:
    """The config of one run, source or target: the method's shipped config of the run's task, the protocol's
    overrides, the run's seed (:func:`run_seed`), objective and generations (CMA-ES's scaled to NEAT's
    evaluations; PPO's NEAT's, each of NEAT's episodes), no GIF, and for a transfer run its source's run
    directory under ``out`` (:func:`run_dir`). The one config builder of the experiments' runs: ``python -m
    kx.bench transfer`` builds its sources and targets with it too."""
    generations = protocol.source_generations if spec.phase == "source" else protocol.target_generations
    objective = spec.setup if spec.phase == "source" else SETUPS[spec.setup].objective
    src = source_of(spec, protocol.sources)
    over = [*protocol.overrides, "gif=false", f"objective={objective}", f"seed={run_seed(protocol.seed, *spec.key)}"]
    if src is not None:
        over.append(f"transfer.source={run_dir(out, src)}")
    if spec.method in ONE_NETWORK:  # a population of one: NEAT's generations, each NEAT's episodes
        over = [o for o in over if not o.startswith("population_size=")]
        cfg = cfg_lib.load(cfg_lib.CONFIG_DIR / f"{spec.method}_{spec.target}.py", over)
        ref = cfg_lib.load(cfg_lib.CONFIG_DIR / "neat_3v2.py", list(protocol.overrides))
        cfg.generations = generations
        section = cfg[spec.method]
        section.episodes_per_generation = ref.population_size * ref.trials
        section.anneal_episodes = generations * section.episodes_per_generation
    else:
        cfg = cfg_lib.load(cfg_lib.CONFIG_DIR / f"{spec.method}_{spec.target}.py", over)
        budget = generations * _reference_population(protocol)
        cfg.generations = max(1, math.ceil(budget / cfg.population_size))
    cfg_lib.validate(cfg)
    return cfg


#: the methods that train one network (PPO on the fixed layout, PPO on the entity network): the protocol's
#: ``population_size`` override is not theirs
ONE_NETWORK = ("ppo", "ppo_entity")


def episodes(cfg: ml_collections.ConfigDict) -> int:
    """The episodes a run of ``cfg`` learns from: its generations x its method's episodes a generation."""
    from kx.evolve import registry

    return cfg.generations * registry.get(cfg.method).episodes_per_generation(cfg)


# ---------------------------------------------------------------------------------------------- results.csv

def read_results(path: pathlib.Path) -> list[dict]:
    """results.csv's rows (strings), in file order; [] when there is none."""
    return csvfile.read(path, FIELDS, "kx table3 results file", ALIASES)


def row_key(row: dict) -> tuple:
    return (row["method"], row["setup"], row["phase"], row["target"], int(row["run"]))


def curve(row: dict, name: str) -> list[float]:
    return [float(v) for v in row[name].split()]


# ------------------------------------------------------------------------------------------------ running

def same_protocol(out: pathlib.Path, protocol: Protocol) -> bool:
    """Whether ``out`` already has a protocol.json; ``RunError`` with the differences when it holds another
    protocol. Writes nothing."""
    path = out / "protocol.json"
    if not path.is_file():
        return False
    have, want = json.loads(path.read_text()), protocol.to_json()
    have = {**DEFAULTS, **have}
    diff = [f"{k}: {have.get(k)!r} in {path}, {want[k]!r} now" for k in want if have.get(k) != want[k]]
    if diff:
        raise RunError(f"{out} holds another protocol ({'; '.join(diff)}): use another --out, or the same "
                       "parameters to add runs to it")
    return True


def create_folder(out: pathlib.Path, protocol: Protocol) -> bool:
    """Creates ``out`` with its protocol.json, or checks that an existing one is the same protocol; whether it
    created the file."""
    if same_protocol(out, protocol):
        return False
    out.mkdir(parents=True, exist_ok=True)
    run_outputs.write_json(out / "protocol.json", protocol.to_json())
    return True


def planned(protocol: Protocol, spec: RunSpec, out: pathlib.Path) -> dict:
    """The :data:`PLANNED` columns of the run of ``spec``, from its config (:func:`config`)."""
    cfg = config(protocol, spec, out)
    src = source_of(spec, protocol.sources)
    src_evals = 0
    if src is not None:
        scfg = config(protocol, src, out)
        src_evals = episodes(scfg)
    return {"seed": cfg.seed, "source_seed": "" if src is None else run_seed(protocol.seed, *src.key),
            "objective": cfg.objective, "population": cfg.population_size, "trials": cfg.trials,
            "generations": cfg.generations, "episodes": episodes(cfg),
            "source_episodes": src_evals, "test_trials": protocol.test_trials, "protocol_seed": protocol.seed}


def curves_of(metrics: list[dict]) -> dict:
    """results.csv's :data:`CURVES` of a run from its metrics.csv rows: each generation's value, space-separated."""
    return {c: " ".join(format(float(r[c]), ".9g") for r in metrics) for c in CURVES}


def results_row(protocol: Protocol, spec: RunSpec, out: pathlib.Path, finished: measure.Finished) -> dict:
    """The results row of the finished run of ``spec``, measured on the protocol's test states of its task
    (:func:`kx.experiments.measure.train_and_measure`): its metrics.csv curves, its validated champion's test
    fitness, and its share of its batched group's wall time and of the generations' times."""
    rows, share = finished.metrics, finished.share
    return {
        "method": spec.method, "setup": spec.setup, "phase": spec.phase, "target": spec.target, "run": spec.run,
        **planned(protocol, spec, out), "max_fitness": finished.max_fitness, "test_fitness": finished.test,
        "champion_generation": int(finished.state.champion_generation),
        "wall_seconds": finished.wall_seconds,
        "generation_seconds": round(sum(float(r["generation_seconds"]) for r in rows) / share, 3),
        **curves_of(rows), "platform": runtime.platform_label(),
    }


def differences(recorded: dict, row: dict, fields: Iterable[str]) -> list[str]:
    """Where ``row`` (values) differs from the ``recorded`` row (results.csv's strings) in ``fields``: one
    phrase per column, a curve by its first differing generation."""
    out = []
    for k in fields:
        have, now = recorded[k], csvfile.cell_text(row[k])
        if have == now:
            continue
        if k in CURVES:
            a, b = have.split(), now.split()
            g = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
            out.append(f"{k} from generation {g + 1} (recorded {' '.join(a[g:g + 1]) or 'nothing'}, now "
                       f"{' '.join(b[g:g + 1]) or 'nothing'})")
        else:
            out.append(f"{k} recorded {have or '(empty)'}, now {now or '(empty)'}")
    return out


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


def _set_aside(d: pathlib.Path) -> pathlib.Path:
    """Moves a run directory that did not reproduce its row out of the protocol's way (never deleted)."""
    aside = d.with_name(d.name + ".rejected")
    n = 1
    while aside.exists():
        n += 1
        aside = d.with_name(f"{d.name}.rejected{n}")
    d.rename(aside)
    return aside


class Waiting(RunError):
    """Raised by :func:`run` after every run it could run: the runs whose source did not reproduce its row here."""


#: what a re-run source that did not reproduce its row leaves in its set-aside directory: the platform, the row
#: it was checked against and how it differed (:func:`_rejected_here` reads it)
REJECTED = "rejected.json"


def _rejected_here(d: pathlib.Path, recorded: dict, here: str) -> bool:
    """Whether the source of run directory ``d`` was trained again on this platform (``here``) against this same
    ``recorded`` row and did not reproduce it: a set-aside directory says so (training it again would only repeat
    that, runs being deterministic on one platform)."""
    want = {k: recorded[k] for k in REPRODUCED}
    for aside in sorted(d.parent.glob(d.name + ".rejected*")):
        try:
            note = json.loads((aside / REJECTED).read_text())
        except (OSError, ValueError):
            continue
        if note.get("platform") == here and note.get("row") == want:
            return True
    return False


def directory_differences(d: pathlib.Path, recorded: dict) -> list[str]:
    """Where a finished run directory's metrics.csv differs from the run's recorded row: its curves and its
    maximum training fitness (read from the files, no compute)."""
    import csv

    with (pathlib.Path(d) / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    have = {**curves_of(rows), "max_fitness": max((float(r["best_fitness"]) for r in rows), default=float("nan"))}
    return differences(recorded, have, ("max_fitness", *CURVES))


def missing_sources(out: pathlib.Path, protocol: Protocol, specs: list[RunSpec], recorded: dict) -> list[RunSpec]:
    """The finished sources (a row in results.csv) of the unfinished transfer runs of ``specs`` whose run
    directory does not hold their final checkpoint (a fresh clone has only results.csv): they are trained
    again before their targets, and must reproduce their rows."""
    out_specs = []
    for spec in specs:
        src = source_of(spec, protocol.sources)
        if (src is None or spec.key in recorded or src.key not in recorded or src in out_specs
                or measure.finished(run_dir(out, src), config(protocol, src, out).generations)):
            continue
        out_specs.append(src)
    return out_specs


def _order(row: dict) -> tuple:
    """The order in which merged process files' rows join results.csv: the plan's (run by run, each method's
    sources first)."""
    return (int(row["run"]), METHODS.index(row["method"]), row["phase"] != "source", row["setup"],
            TARGETS.index(row["target"]) if row["target"] in TARGETS else -1)


def ledger(out: pathlib.Path, shard: processes.Shard = processes.ALONE) -> runner.Ledger:
    """The protocol folder's results.csv under ``shard`` (:class:`kx.experiments.runner.Ledger`): its process
    files merged in the plan's order."""
    return runner.Ledger(pathlib.Path(out) / "results.csv", FIELDS, "kx table3 results file", row_key, _order,
                         "table3", shard, ALIASES)


def run(out: str | pathlib.Path, protocol: Protocol, specs: list[RunSpec],
        log: Callable[[str], None] = print, batch: int = 16, shard: processes.Shard = processes.ALONE,
        design_record: dict | None = None) -> list[dict]:
    """Runs every run of ``specs`` not yet in ``out/results.csv`` (a transfer run's source first, even if
    not selected), in batched groups of up to ``batch`` runs of one cell (1: one by one), each run resumed
    from its checkpoint if a previous protocol was killed during it; appends each finished run's row.
    Returns the rows of ``specs``.

    A folder holding only results.csv and protocol.json (a fresh clone) extends: a finished source that an
    unfinished target needs and whose run directory is missing is trained again first (runs are
    deterministic on one platform) and must reproduce its row in every column but the times and the platform;
    one that differs is set aside as ``<run>.rejected`` (with :data:`REJECTED`, so that it is not trained again on
    the same platform), its targets wait, every other run runs, and then :class:`RunError` names the runs that
    wait and the platforms. Before
    any compute, every config is checked, the protocol.json is the same protocol with the same test states
    (:func:`kx.experiments.design.check_folder`), each such source's row is what its config gives now
    (:data:`PLANNED`), and a recorded source's finished run directory is the run of its row (its
    metrics.csv curves: a re-run killed before its check is not taken as checked).

    Under several processes (``shard``: :mod:`kx.experiments.processes`) each trains the runs it owns (a run index
    modulo
    the processes: a target and its source together) and writes their rows to its own process file; the
    leader merges the files of a killed run at the start and everyone's at the end, and alone writes
    protocol.json. The results are those of one process, bit for bit.

    ``design_record``: the statistical design the folder must record (:func:`kx.experiments.design.check_folder`;
    default the exploratory design of the protocol's sources)."""
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"--batch: allowed an integer >= 1, got {batch!r}")
    out = pathlib.Path(out).absolute()
    for spec in specs:  # every config checked before any compute
        config(protocol, spec, out)
    results_path = out / "results.csv"
    results = ledger(out, shard)
    results.start()
    rows = results.open()
    recorded = {row_key(r): r for r in rows}
    same_protocol(out, protocol)
    rebuild = missing_sources(out, protocol, specs, recorded)
    for src in rebuild:  # a recorded source must be the run its config gives now, before anything trains
        diff = differences(recorded[src.key], planned(protocol, src, out), PLANNED)
        if diff:
            raise RunError(f"{src.describe()}: its run directory {run_dir(out, src)} is missing, and its row in "
                           f"{results_path} is not the run the protocol's config gives now ({'; '.join(diff)}), so "
                           "it cannot be trained again to seed its targets: nothing was run")
    for spec in specs:  # a recorded source's finished directory must be the run of its row (a re-run killed
        src = source_of(spec, protocol.sources)  # before its check, a directory from elsewhere): read, not computed
        if (src is None or spec.key in recorded or src.key not in recorded or src in rebuild
                or not measure.started(run_dir(out, src))):
            continue
        diff = directory_differences(run_dir(out, src), recorded[src.key])
        if diff:
            raise RunError(f"{src.describe()}: its run directory {run_dir(out, src)} is not the run of its row in "
                           f"{results_path} ({'; '.join(diff)}): move it away to have it trained again and "
                           "checked; nothing was run")
    created = create_folder(out, protocol) if shard.leader else False
    if shard.leader:
        design.check_folder(out, protocol, (SOURCE_TASK, *TARGETS), (lambda s: None) if created else log,
                            design_record)
    shard.barrier("table3 protocol.json")
    if not shard.leader:
        design.check_folder(out, protocol, (SOURCE_TASK, *TARGETS), lambda s: None, design_record)
    rebuild = [s for s in rebuild if shard.owns(s.run)]
    here = runtime.platform_label()
    waiting = {s for s in rebuild if _rejected_here(run_dir(out, s), recorded[s.key], here)}
    for src in waiting:
        log(f"{src.describe()}: did not reproduce its row on this platform ({here}) when trained again before (set "
            f"aside in {run_dir(out, src).name}.rejected...): not trained again; its targets wait")
    rebuild = [s for s in rebuild if s not in waiting]
    needed: list[RunSpec] = []
    for spec in specs:
        src = source_of(spec, protocol.sources)
        for s in ((src,) if src is not None else ()) + (spec,):
            if s.key not in recorded and s not in needed and shard.owns(s.run):
                needed.append(s)
    total = len({s.key for s in specs} | {s.key for s in needed})
    # runs whose source was set aside here before are neither grouped nor costed: they will not run
    held = sum(1 for s in needed if source_of(s, protocol.sources) in waiting)
    again = groups(rebuild, batch)
    chunks = groups([s for s in needed if source_of(s, protocol.sources) not in waiting], batch)
    progress = progress_lib.Progress(log, again + chunks, total - len(needed), total, rows)
    grouped = f" in {len(chunks)} groups of up to {batch}" if batch > 1 and chunks else ""
    redo = f"; {len(rebuild)} finished sources without a run directory trained again first" if rebuild else ""
    done = sum(1 for k in {s.key for s in specs} | {s.key for s in needed} if k in recorded)
    mine = ""
    if shard.count > 1:
        mine = (f"; {total - done - len(needed)} by the other processes ({shard.describe()} runs the runs of index "
                f"{shard.index} mod {shard.count})")
    held = f" ({held} of them waiting for a source not reproduced here)" if held else ""
    log(f"kx table3: {total} runs, {done} done, {len(needed)} to run{grouped}{held}{redo}{mine} -> {out}")
    for chunk in again + chunks:
        reproduce = chunk[0] in rebuild
        if not reproduce:
            chunk = [s for s in chunk if source_of(s, protocol.sources) not in waiting]
            if not chunk:
                progress.finish(0)
                continue
        cfgs = [config(protocol, spec, out) for spec in chunk]
        dirs = [run_dir(out, spec) for spec in chunk]
        resumed = sum(measure.started(d) for d in dirs)
        progress.start(chunk[0], _span(chunk) + (" (again)" if reproduce else ""))
        log(f"[{progress.done}/{total} runs] {_span(chunk)}{' again, to seed its targets' if reproduce else ''}: "
            f"seeds {', '.join(str(c.seed) for c in cfgs)}, {cfgs[0].generations} generations"
            + (f" ({resumed} resumed)" if resumed else ""))
        measured = measure.train_and_measure(cfgs, dirs, protocol.seed, protocol.test_trials, log=progress.line)
        rejected = []
        for spec, finished in zip(chunk, measured):
            row = results_row(protocol, spec, out, finished)
            if reproduce:  # every run of the group compared, every one that differs set aside
                diff = differences(recorded[spec.key], row, REPRODUCED)
                if diff:
                    aside = _set_aside(run_dir(out, spec))
                    run_outputs.write_text(aside / REJECTED, json.dumps(
                        {"platform": here, "recorded_platform": recorded[spec.key]["platform"],
                         "row": {k: recorded[spec.key][k] for k in REPRODUCED}, "differences": diff}, indent=1) + "\n")
                    rejected.append(f"{spec.describe()} ({'; '.join(diff)}; set aside in {aside})")
                    waiting.add(spec)
                else:
                    log(f"[{progress.done}/{total} runs] {spec.describe()}: trained again, its row reproduced "
                        "(every column but the times)")
                continue
            results.append(row)
            progress.add(row)
            log(f"[{progress.done + 1}/{total} runs] {spec.describe()}: max fitness {row['max_fitness']:.4f}, test "
                f"{row['test_fitness']:.4f}")
            progress.done += 1
        if rejected:
            log(f"trained again to seed their targets, {len(rejected)} of {len(chunk)} sources do not reproduce "
                f"their rows of {results_path} on this platform ({here}): {'; '.join(rejected)}; their targets wait, "
                "the other runs go on")
        progress.finish(0)
    rows = results.finish()
    want = {s.key for s in specs}
    have = {row_key(r) for r in rows}
    stuck = [s for s in specs if s.key not in have and source_of(s, protocol.sources) in waiting]
    if stuck:
        made = sorted({recorded[s.key]["platform"] or "not recorded (before 2026-12-07)" for s in waiting})
        raise Waiting(f"{len(stuck)} runs wait, their sources' rows not reproduced on this platform ({here}; the rows "
                       f"were made on: {', '.join(made)}): {'; '.join(s.describe() for s in stuck)}. Every other run "
                       "ran. Run them where their sources were made (docs/experiments.md, \"Extendable anywhere\"), "
                       "or the whole protocol again in a new folder")
    return [r for r in rows if row_key(r) in want]
