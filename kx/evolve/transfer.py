"""Policy transfer (SPEC section 5): a run seeded with the population of another run's checkpoint.

A target run names its source in its config's ``transfer`` section::

    transfer.source   the source run's directory ("": no transfer)
    transfer.step     its checkpoint (-1: the latest)
    transfer.seeding  "population" (the whole source population, the paper's best and the default),
                      "champion" (the source's validated champion and mutated copies of it) or
                      "half" (the fittest half of the source population and mutated copies of them)

:func:`load` reads the source (its ``config.json`` and checkpoint, through the source's own
:class:`~kx.evolve.run.Trainer`) and refuses, with the reason and before any compute, a source that is
missing or damaged, of another method or layout, of a larger task than the target, whose genomes do
not fit the target's config, or a seeding the method cannot carry out. :func:`seed` then builds the
target's first learner state with the encoding's ``transfer`` (NEAT: fixed-layout genomes and CPPNs
unchanged, full-layout genomes mapped by Algorithm 1, :mod:`kx.neat.transfer`; CMA-ES: the source's
mean and step size). The objective's state (the novelty archive) starts empty: behaviours of two tasks
are not comparable.

"Fittest" (the ``half`` seeding) is the mean fitness on the source run's own validation states: a
checkpoint's population is the offspring bred after its last generation, not yet evaluated, so it is
evaluated once, in the source task, to rank it.

The target run's ``config.json`` records the source under ``transfer_source`` before its first
generation runs: the source's resolved absolute path, its concrete checkpoint step (never -1) and
generation, its config, ``source_objective`` (the source run's ``objective``) beside
``target_objective`` (this run's), and :func:`digest` of the restored run state (sha-256 over every
array of it), so that a result can be traced to the exact population it came from.

The record pins the source. A target resumed before its first checkpoint reseeds from the recorded
path and step (:func:`load` with ``pinned``), not from ``transfer.source`` and ``transfer.step``
resolved again (a relative path against another working directory, -1 against a source that has
gained checkpoints since), and refuses, with the field and what was recorded and found, a source that
no longer matches: the path gone, the recorded checkpoint gone, or another digest.
"""

from __future__ import annotations

import dataclasses
import hashlib
import pathlib
from typing import Any, Callable

import jax
import ml_collections
import numpy as np

from kx.evolve import checkpoint as ckpt
from kx.evolve import config as cfg_lib
from kx.evolve import streams
from kx.evolve.config import SOURCE_RECORD
from kx.evolve.errors import ConfigError, RunError
from kx.sim.types import KeepAwayConfig


def digest(tree: Any) -> str:
    """``sha256:<hex>`` of every array of ``tree`` (its path, dtype, shape and bytes, in tree order)."""
    h = hashlib.sha256()
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        a = np.asarray(jax.device_get(leaf))
        if a.dtype == object or jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):
            a = np.asarray(jax.random.key_data(leaf))
        h.update(jax.tree_util.keystr(path).encode())
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return "sha256:" + h.hexdigest()


@dataclasses.dataclass
class Source:
    """A source run's checkpoint, restored and checked against a target run."""

    run_dir: pathlib.Path
    step: int
    cfg: ml_collections.ConfigDict  # the source run's config
    trainer: Any  # the source's kx.evolve.run.Trainer (its encoding and task)
    state: Any  # its RunState after ``step`` generations
    digest: str
    seeding: str
    target_objective: str  # the target run's objective, recorded beside the source's


    @property
    def encoding(self):
        return self.trainer.encoding

    def population(self):
        """The checkpoint's population: what the source's next generation would evaluate."""
        population, _ = self.encoding.ask(_ask_key(self.cfg.seed, int(self.state.generation)), self.state.learner)
        return population

    def ranking(self) -> np.ndarray:
        """The population's indices, fittest first, by mean fitness on the source's validation states
        (ties: the lower index first)."""
        t = self.trainer
        stats = t.evaluate(self.population(), t.validation_starts, t.validation_eval_key)
        f = np.asarray(stats.fitness.mean(axis=1))
        return np.argsort(-f, kind="stable")

    def record(self) -> dict:
        """What the target's config.json records of its source (:data:`RECORD_KEYS`)."""
        return {"path": str(self.run_dir), "step": self.step, "generation": int(self.state.generation),
                "method": self.cfg.method, "task": self.cfg.task, "seeding": self.seeding,
                "source_objective": self.cfg.objective, "target_objective": self.target_objective,
                "config": self.cfg.to_dict(), "digest": self.digest}


# the keys of a target's record of its source (config.json's ``transfer_source``)
RECORD_KEYS = ("path", "step", "generation", "method", "task", "seeding", "source_objective", "target_objective",
               "config", "digest")
# the keys that pin the source: what a target resumed before its first checkpoint reseeds from
PINNED_KEYS = ("path", "step", "digest")


def saved_record(run_dir) -> dict | None:
    """The ``transfer_source`` record of the run in ``run_dir`` (``None``: no config.json, or no record)."""
    d = cfg_lib.read_run_json(pathlib.Path(run_dir) / "config.json")
    return d.get(SOURCE_RECORD) if isinstance(d, dict) else None


def _ask_key(seed: int, generation: int):
    return streams.learner_ask(seed, generation)


def _task_size(task: str) -> tuple[int, int]:
    c = KeepAwayConfig.from_task(task)
    return c.n_keepers, c.n_takers


def load(cfg: ml_collections.ConfigDict, trainer, pinned: dict | None = None, *,
         make_trainer: Callable[[ml_collections.ConfigDict], Any]) -> Source:
    """The source of ``cfg.transfer`` restored for the target run of ``trainer``, or :class:`ConfigError`
    (naming ``transfer.source``, ``transfer.step`` or ``transfer.seeding``) saying why it cannot seed it.
    ``make_trainer``: the trainer of the source's config (the run loop's :class:`~kx.evolve.run.Trainer`),
    which restores the source's checkpoint.

    ``pinned``: the record a resumed target run wrote when it started (config.json's
    ``transfer_source``). The source is then the recorded path's recorded checkpoint, whatever
    ``transfer.source`` and ``transfer.step`` resolve to now, and it must have the recorded digest;
    otherwise :class:`~kx.evolve.errors.RunError` names the record's field and gives what was
    recorded and what was found."""
    cfg_lib.check_transfer(cfg)
    if not cfg.transfer.source:
        raise ConfigError("transfer.source: empty (no transfer configured)")
    if pinned is None:
        return _load(cfg, trainer, make_trainer, pathlib.Path(cfg.transfer.source).expanduser().resolve(),
                     None if cfg.transfer.step == -1 else cfg.transfer.step)

    why = f"--resume: this run has no checkpoint yet and reseeds from the source recorded in its config.json " \
          f"({SOURCE_RECORD}), which"
    missing = [k for k in PINNED_KEYS if k not in pinned] if isinstance(pinned, dict) else list(PINNED_KEYS)
    if missing:
        raise RunError(f"{why} is incomplete: no {SOURCE_RECORD}.{missing[0]}")
    path, step = pinned["path"], pinned["step"]
    if not (isinstance(path, str) and pathlib.Path(path).is_absolute()):
        raise RunError(f"{why} is not a pinned source: {SOURCE_RECORD}.path: recorded {path!r}, not an absolute path")
    if not isinstance(step, int) or isinstance(step, bool) or step < 1:
        raise RunError(f"{why} is not a pinned source: {SOURCE_RECORD}.step: recorded {step!r}, not a checkpoint "
                       "step >= 1")
    run_dir = pathlib.Path(path)
    if not run_dir.is_dir():
        raise RunError(f"{why} no longer matches: {SOURCE_RECORD}.path: recorded {run_dir}, found no directory there")
    have = ckpt.steps(run_dir)
    if step not in have:
        raise RunError(f"{why} no longer matches: {SOURCE_RECORD}.step: recorded checkpoint {step} of {run_dir}, "
                       f"found checkpoints {have} (the source has changed since this run started)")
    try:
        source = _load(cfg, trainer, make_trainer, run_dir, step)
    except ConfigError as e:
        raise RunError(f"{why} no longer seeds it: {e}") from None
    if source.digest != pinned["digest"]:
        recorded_cfg = pinned.get("config")
        diff = cfg_lib.identity_mismatch(recorded_cfg, source.cfg) if isinstance(recorded_cfg, dict) else None
        diff = diff and diff.replace(" in the checkpoint, ", " recorded, ")
        raise RunError(f"{why} no longer matches: {SOURCE_RECORD}.digest: recorded {pinned['digest']}, found "
                       f"{source.digest} in checkpoint {step} of {run_dir} (the source has changed since this run "
                       f"started{'; its config: ' + diff if diff else ''})")
    return source


def _load(cfg: ml_collections.ConfigDict, trainer, make_trainer, run_dir: pathlib.Path, want: int | None) -> Source:
    """Checkpoint ``want`` (``None``: the latest) of the source run in ``run_dir`` (absolute), checked."""
    t = cfg.transfer
    if not run_dir.is_dir():
        raise ConfigError(f"transfer.source: {run_dir} is not a directory (the source must be a kx run directory)")
    try:
        scfg = cfg_lib.read_run_config(run_dir / "config.json")
    except ConfigError as e:
        raise ConfigError(f"transfer.source: {e}") from None
    if scfg.method != cfg.method:
        raise ConfigError(f"transfer.source: {run_dir} is a {scfg.method!r} run and this run's method is "
                          f"{cfg.method!r}; a population transfers only between runs of one method")
    if scfg.layout != cfg.layout:
        raise ConfigError(f"transfer.source: {run_dir} evolved {scfg.layout!r}-layout networks and this run's layout "
                          f"is {cfg.layout!r}; a population transfers only between runs of one layout")
    (sk, st), (tk, tt) = _task_size(scfg.task), _task_size(cfg.task)
    if sk > tk or st > tt:
        raise ConfigError(f"transfer.source: the source task {scfg.task} ({sk} keepers, {st} takers) is larger than "
                          f"this run's task {cfg.task} ({tk} keepers, {tt} takers); policies transfer to tasks at "
                          "least as large")
    try:
        source_trainer = make_trainer(scfg)
    except ConfigError as e:
        raise ConfigError(f"transfer.source: {run_dir}'s config is not valid for this kx ({e})") from None
    try:
        step, state, _ = source_trainer.restore(run_dir, want)
    except RunError as e:
        field = "transfer.step" if want is not None and f"--step {want}" in str(e) else "transfer.source"
        raise ConfigError(f"{field}: {e}") from None
    if t.seeding == "champion" and int(state.champion_generation) < 0:
        raise ConfigError(f"transfer.seeding: 'champion', but checkpoint {step} of {run_dir} has no validated "
                          "champion yet")
    problems = trainer.encoding.transfer_problems(source_trainer.encoding, state, t.seeding)
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        field = "transfer.seeding" if problems[0].startswith("seeding") else "transfer.source"
        raise ConfigError(f"{field}: checkpoint {step} of {run_dir} cannot seed this run: {problems[0]}{more}")
    return Source(run_dir=run_dir, step=step, cfg=scfg, trainer=source_trainer, state=state, digest=digest(state),
                  seeding=t.seeding, target_objective=cfg.objective)


def seed(trainer, source: Source, key) -> Any:
    """The target run's first learner state, seeded from ``source`` by its encoding."""
    order = source.ranking() if source.seeding == "half" else None
    return trainer.encoding.transfer(key, source.encoding, source.state, source.seeding, order)
