"""The run loop: any method's population evolved on keep-away, in a run directory that survives being killed.

Each generation ``g`` draws ``trials`` start states from the run's training stream (every individual
meets the same ones) and then::

    population, learner = encoding.ask(key_ask, learner)           # kx.evolve.encoding
    stats   = evaluate(encoding.policy, encoding.policy_params(population), starts, ...)
    fitness = stats.fitness.mean(axis=1)                            # raw task fitness [P]
    score, objective_state = objective.score(fitness, behaviour, objective_state)   # kx.evolve.objective
    learner = encoding.tell(key_tell, population, score, fitness, learner)

The generation step is :meth:`kx.evolve.trainer.Trainer.step`, the step of a group of one run
(:class:`kx.evolve.trainer.RunGroup`: the one generation step, for a run alone and for batched runs), and
:func:`advance` is the one host loop over it: for a run in its directory (:func:`train`), for a batched group
of runs (:func:`kx.evolve.group.train_group`) and for a run in memory (:func:`evolve_in_memory`). The
loop knows only the encoding interface (NEAT, CMA-ES and any registered encoding run through the
same code) and the objective interface (what the learner selects on). Raw task fitness drives
everything reported: the validated champion, the best checkpoint, metrics.csv, the progress line and
the plots. Every key comes from :mod:`kx.evolve.streams`, so a run resumed from the checkpoint after
generation ``g`` continues exactly as the uninterrupted run would have.

**The champion is validated.** A generation's best training fitness is the largest of
``population_size`` noisy means over ``trials`` shared start states, so it flatters the individual
that reached it. Each generation's champion by training fitness is therefore replayed on
``validation_trials`` start states that no generation trains on (the same ones every generation, from
the run's validation stream), and the run's champion is the generation champion with the best
validation score (the earliest on ties). It is what the run reports and hands on: the progress line,
``metrics.csv``'s ``best_validation``, ``champion.gif``, ``kx.evaluate`` (which plays it on the test
stream's states) and the checkpoints. ``baselines.json`` gives the hand-coded policies on the
validation states.

The run directory::

    config.json        the resolved config (written atomically); a transferred run adds its source
                       (transfer_source: absolute path, step, config, objectives, digest; written before
                       the first generation, kept on resume, what a resume before the first checkpoint
                       reseeds from; kx.evolve.transfer)
    metrics.csv        one row per generation: training fitness, the selection score, behaviour, the
                       generation champion's validation score and the best so far, timings, and the
                       encoding's own columns (NEAT: species, genome sizes, overflow counters)
    baselines.json     the hand-coded policies (hold, random, heuristic) on the validation states
    progress.png       best / mean / median training fitness, the validated champion, the encoding's figure
    checkpoints/<n>/   the run state after n generations (kx.evolve.checkpoint)
    champion.gif       the validated champion playing the first test state, at the end
    champion.png       a picture of the validated champion (its network), at the end
    abandoned/<time>/  checkpoints set aside by ``--resume --step N`` (never deleted)
    run.lock           while a process writes the run: its pid and host (kx.evolve.checkpoint.RunLock)
"""

from __future__ import annotations

import dataclasses
import pathlib
import shutil
import sys
import time
from typing import Callable

import jax
import ml_collections

from kx import runtime
from kx.evolve import checkpoint as ckpt
from kx.evolve import config as cfg_lib
from kx.evolve import outputs, streams, transfer
from kx.evolve.checkpoint import RunLock, RunState
from kx.evolve.encoding import stack
from kx.evolve.errors import RunError
from kx.evolve.trainer import GenerationResult, RunGroup, Trainer, run_state, stack_states
from kx.sim import env
from kx.sim import evaluate as ev

PLOT_EVERY_S = 10.0  # the shortest interval between two drawings of progress.png during a run

__all__ = ["RunError", "RunLock", "RunState", "Trainer", "GenerationResult", "evolve_in_memory", "train",
           "prepare_run_dir", "restore"]


#: the run directory's record of what ran each time the run was started or resumed
RUNTIME_FILE = "runtime.json"


def describe_implementation(impl: dict) -> str:
    """One line of an encoding's :meth:`~kx.evolve.encoding.Encoding.implementation`."""
    if impl.get("decision_sums") == "native":
        return (f"sums by the native kernel (kx.hyperneat.native, {impl['library']}; "
                f"hyperneat.impl = {impl['chosen']!r})")
    why = f": {impl['why_not_native']}" if impl.get("why_not_native") else ""
    return f"sums by the compiled XLA code (hyperneat.impl = {impl['chosen']!r}{why})"


def record_runtime(run_dir: pathlib.Path, start: int, impl: dict) -> None:
    """Appends this session (the generation it starts after, the JAX version, backend and devices, and the
    encoding's implementation) to ``run_dir/runtime.json``; the run's results do not depend on it (the
    implementations give the same bits), its times do."""
    import json

    import jaxlib

    path = run_dir / RUNTIME_FILE
    try:
        sessions = json.loads(path.read_text())["sessions"] if path.is_file() else []
        sessions = sessions if isinstance(sessions, list) else []
    except (OSError, ValueError, KeyError, TypeError):
        sessions = []  # a damaged record is replaced: it holds no result
    sessions.append({"after_generation": int(start), "jax": jax.__version__, "jaxlib": jaxlib.__version__,
                     "backend": jax.default_backend(), "devices": jax.local_device_count(), **impl})
    outputs.write_json(path, {"sessions": sessions})

def evolve_in_memory(trainer: Trainer, log: Callable[[dict], None] | None = None) -> tuple[RunState, list[dict]]:
    """All of ``trainer``'s generations with no run directory: the final run state (its validated
    champion included) and the metrics row of every generation, as :func:`train` would write them."""
    run = InMemoryRun(trainer.init(), log)
    advance([run], trainer.alone(), trainer.cfg.generations,
            notice=lambda m: print(m, file=sys.stderr, flush=True))
    return run.state, run.rows


class _Run:
    """What :func:`advance` reads of a run: the generation its state has reached."""

    @property
    def generation(self) -> int:
        return int(self.state.generation)


@dataclasses.dataclass
class InMemoryRun(_Run):
    """A run with no directory: its state and its metrics rows, each row passed to ``log``."""

    state: RunState
    log: Callable[[dict], None] | None = None
    rows: list = dataclasses.field(default_factory=list)
    done: bool = False

    def record(self, result: GenerationResult) -> dict:
        self.state = result.state
        self.rows.append(result.row)
        if self.log is not None:
            self.log(result.row)
        return result.row


def advance(runs: list, group: RunGroup, total: int, *, notice: Callable[[str], None],
            log: Callable[[str], None] = print,
            each: Callable[[list[dict], int, float], None] | None = None) -> None:
    """The one host loop over the generation step (:meth:`kx.evolve.trainer.RunGroup.step`): ``runs`` (an
    :class:`OpenRun` or :class:`InMemoryRun` each, ``group``'s runs in its order; a run alone is a group of one)
    to ``total`` generations in lockstep. Runs cut at different generations (a kill between two runs'
    checkpoints) are brought level first: the runs behind advance alone, as a smaller group. After each
    generation every run records its result, ``each(rows, generation, seconds)`` is told, and ``notice`` hears
    of the process's memory maps near their limit."""
    stacked, members, first = None, None, True
    while True:
        todo = [i for i, run in enumerate(runs) if not run.done and run.generation < total]
        if not todo:
            return
        g = min(runs[i].generation for i in todo)
        batch = [i for i in todo if runs[i].generation == g]
        if batch != members:  # the first generation, or after a resume that found the runs apart
            sub = group if len(batch) == len(group) else RunGroup([group.trainers[i] for i in batch])
            stacked, members = stack_states([runs[i].state for i in batch]), batch
        t_start = time.perf_counter()
        stacked, rows = sub.step(stacked)
        if first and len(batch) > 1 and sub.calls_note:
            log(f"batched group: {sub.calls_note}")
        first = False
        host = jax.device_get(stacked)  # one transfer; each run's state is a view of it
        for j, i in enumerate(batch):
            runs[i].record(GenerationResult(row=rows[j], state=run_state(host, j)))
        if each is not None:
            each(rows, g, time.perf_counter() - t_start)
        maps_notice(notice)


def render_champion(trainer: Trainer, genotype, path: pathlib.Path, frames: int) -> pathlib.Path:
    """The champion's episode on the first test state (trial 0 of the test stream), as a GIF."""
    from kx.sim.render import render_gif

    exp, enc = trainer.exp, trainer.encoding
    keys = streams.test(trainer.cfg.seed)
    start = jax.tree.map(lambda a: a[..., 0], env.reset_batch(keys.starts, 1, exp.sim_params, exp.sim))
    params = enc.policy_params(stack([genotype]))
    if not enc.policy.shared:
        params = jax.tree.map(lambda a: a[0], params)
    states, _ = ev.rollout(enc.policy, params, start, exp.sim_params, exp.sim, key=keys.eval, n_steps=frames)
    return render_gif(env.as_numpy(states), exp.sim, path, max_frames=frames)


def prepare_run_dir(run_dir: pathlib.Path, resume: bool, overwrite: bool) -> None:
    """Refuse to touch an existing run unless asked (before any compute). The lock file (``run.lock``)
    counts for nothing here: :func:`train` calls this holding it, and ``--overwrite`` keeps it."""
    run_dir = pathlib.Path(run_dir)
    if resume and overwrite:
        raise RunError("--resume and --overwrite: choose one")
    exists = (any(p.name != ckpt.LOCK_NAME for p in run_dir.iterdir()) if run_dir.is_dir()
              else run_dir.exists())
    if resume:
        if not (run_dir / "config.json").is_file():
            raise RunError(f"--resume: {run_dir} holds no run to resume (no config.json)")
        return
    if exists:
        if not overwrite:
            raise RunError(f"--workdir: {run_dir} exists and is not empty; pass --resume to continue that run, "
                           "--overwrite to replace it, or another --workdir")
        if run_dir.is_dir() and not (run_dir / "config.json").is_file():
            raise RunError(f"--overwrite: {run_dir} is not a kx run directory (no config.json); refusing to delete it")
        if not run_dir.is_dir():
            run_dir.unlink()
            return
        for p in run_dir.iterdir():
            if p.name != ckpt.LOCK_NAME:
                shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()


def restore(run_dir, step: int | None = None):
    """``(trainer, step, state, meta)`` of a run directory's checkpoint ``step`` (default: the latest),
    its config read from its own ``config.json``."""
    cfg = cfg_lib.read_run_config(pathlib.Path(run_dir) / "config.json")
    trainer = Trainer(cfg)
    got, state, meta = trainer.restore(run_dir, step)
    return trainer, got, state, meta


def train(cfg: ml_collections.ConfigDict, run_dir: str | pathlib.Path, *, resume: bool = False,
          overwrite: bool = False, step: int | None = None, log: Callable[[str], None] = print) -> dict:
    """Runs (or resumes, from checkpoint ``step`` or the latest) the experiment of ``cfg`` in
    ``run_dir``; returns the final metrics row (a resume with nothing to do: the last one, having
    written nothing).

    One process at a time: the run directory's lock (``run.lock``, :class:`RunLock`) is taken first, so
    a directory another process is writing is refused (``RunError`` naming its pid) before any compute,
    and held to the end, released also on an exception; a stale one (its process killed) is taken over."""
    run_dir = pathlib.Path(run_dir).absolute()  # orbax wants absolute paths
    if run_dir.exists() and not run_dir.is_dir():  # no lock inside a file: refused, or replaced (--overwrite)
        return _train(cfg, run_dir, resume=resume, overwrite=overwrite, step=step, log=log)
    with RunLock(run_dir, log):
        return _train(cfg, run_dir, resume=resume, overwrite=overwrite, step=step, log=log)


def _train(cfg: ml_collections.ConfigDict, run_dir: pathlib.Path, *, resume: bool, overwrite: bool,
           step: int | None, log: Callable[[str], None]) -> dict:
    """:func:`train`'s work, with the run directory's lock held."""
    run = open_run(Trainer(cfg), run_dir, resume=resume, overwrite=overwrite, step=step, log=log)  # validates first
    if run.done:
        return run.rows[-1] if run.rows else None
    advance([run], run.trainer.alone(), cfg.generations, notice=log, log=log)
    return run.close()


def maps_notice(log: Callable[[str], None]) -> None:
    """The process's memory maps, told when they near the limit (:func:`kx.runtime.check_maps`, which
    releases the compiled programs before the limit is reached)."""
    msg = runtime.check_maps()
    if msg:
        log(msg)


@dataclasses.dataclass
class OpenRun(_Run):
    """A run directory being written (:func:`open_run`): the run state, and what the files need."""

    trainer: Trainer
    run_dir: pathlib.Path
    state: RunState
    start: int  # the generation the run continues from
    rows: list
    log: Callable[[str], None]
    done: bool = False  # nothing to do: the run has its generations already (nothing was written)
    manager: object = None
    baselines: dict | None = None
    quiet: bool = False  # no progress line per generation (a batched group prints one for all its runs)
    done_here: int = 0
    clock: outputs.GenerationClock = dataclasses.field(default_factory=outputs.GenerationClock)
    last_plot: float = -float("inf")

    def record(self, result: GenerationResult) -> dict:
        """Writes one generation: its metrics row, its progress line, its checkpoint when due, progress.png."""
        cfg, enc, run_dir = self.trainer.cfg, self.trainer.encoding, self.run_dir
        t_step = time.perf_counter()
        self.state, row = result.state, result.row
        g = int(row["generation"])
        self.rows.append(row)
        outputs.append_row(run_dir / "metrics.csv", row, self.trainer.fields)
        self.done_here += 1
        # ETA from this process's own clock, over its last generations after the first (which compiles), each
        # with its checkpoint and plot: never from metrics.csv, which may hold fewer rows (deleted, cut)
        per_gen = self.clock.tick(t_step)
        if not self.quiet:
            self.log(outputs.progress_line(row, cfg.generations,
                                          None if per_gen is None else per_gen * (cfg.generations - g - 1), enc))
        last = g + 1 == cfg.generations
        if (g + 1) % cfg.checkpoint_every == 0 or last:
            meta = {"config": cfg.to_dict(), "method": cfg.method, "generation": g + 1,
                    "best_so_far": float(self.state.best_so_far), "best_fitness": row["best_fitness"],
                    "champion_validation": row["champion_validation"], "best_validation": row["best_validation"]}
            ckpt.save(self.manager, g + 1, self.state, meta)
            # progress.png follows the checkpoints, redrawn at most every PLOT_EVERY_S seconds (drawing
            # it takes about 0.25 s, a third of a small run's generation) and always after the last one
            if not last and time.perf_counter() - self.last_plot >= PLOT_EVERY_S:
                outputs.plot_progress(self.rows, run_dir / "progress.png", self._title, self.baselines,
                                     enc.plot_field)
                self.last_plot = time.perf_counter()
        return row

    @property
    def _title(self) -> str:
        cfg = self.trainer.cfg
        return f"kx {cfg.task} {cfg.method}, seed {cfg.seed}"

    def close(self) -> dict | None:
        """The run's last files (progress.png, champion.gif, champion.png); returns its last metrics row."""
        trainer, run_dir, state, rows, log = self.trainer, self.run_dir, self.state, self.rows, self.log
        cfg, enc = trainer.cfg, trainer.encoding
        if rows:
            outputs.plot_progress(rows, run_dir / "progress.png", self._title, self.baselines, enc.plot_field)
        written = ["metrics.csv", "baselines.json", "progress.png", "checkpoints/"]
        if rows and int(state.champion_generation) >= 0:
            if cfg.gif:
                gif = render_champion(trainer, state.champion, run_dir / "champion.gif", cfg.gif_frames)
                written.append(gif.name)
                log(f"validated champion (generation {int(state.champion_generation) + 1}, "
                    f"{float(state.champion_validation):.4f} on the {cfg.validation_trials} validation states): {gif}")
            pic = enc.draw(state.champion, run_dir / "champion.png")
            if pic is not None:
                written.append(pathlib.Path(pic).name)
        log(f"done: {run_dir} ({', '.join(written)})")
        return rows[-1] if rows else None


def open_run(trainer: Trainer, run_dir: pathlib.Path, *, resume: bool, overwrite: bool, step: int | None,
             log: Callable[[str], None]) -> OpenRun:
    """Prepares ``run_dir`` for ``trainer``'s run (its lock held by the caller): refuses what must be
    refused before any compute, restores the checkpoint on ``--resume``, writes config.json and
    baselines.json; returns the :class:`OpenRun` whose ``record`` writes each generation."""
    run_dir = pathlib.Path(run_dir).absolute()  # orbax wants absolute paths
    cfg = trainer.cfg
    enc = trainer.encoding
    if step is not None and not resume:
        raise RunError("--step: only with --resume")
    # a resumed transferred run's record of its source (written before its first generation) is the
    # authority: never rewritten, and what the run reseeds from if it has no checkpoint yet
    saved_record = None
    if trainer.transfers and resume and (run_dir / "config.json").is_file():
        saved_record = transfer.saved_record(run_dir)
    if trainer.transfers and not (resume and ckpt.steps(run_dir)):
        if not resume:
            trainer.attach_source()  # refused with the reason before anything is written
        elif (run_dir / "config.json").is_file():  # (without, prepare_run_dir refuses: no run to resume)
            if saved_record is None:
                raise RunError(f"--resume: {run_dir / 'config.json'} has no record of the source this run started "
                               f"from ({cfg_lib.SOURCE_RECORD}), so it cannot reseed from the same checkpoint; "
                               "start it again with --overwrite")
            trainer.attach_source(saved_record)  # the recorded path and step, or refused with the reason
    prepare_run_dir(run_dir, resume, overwrite)
    metrics_path = run_dir / "metrics.csv"
    state, start = None, 0
    if resume:
        saved = cfg_lib.read_run_config(run_dir / "config.json").to_dict()
        diff = cfg_lib.identity_mismatch(saved, cfg)
        if diff:
            raise RunError(f"--resume: this config differs from the run's: {diff}")
        have = ckpt.steps(run_dir)
        if have:
            got, state, meta = trainer.restore(run_dir, step)
            diff = cfg_lib.identity_mismatch(meta["config"], cfg)
            if diff:
                raise RunError(f"checkpoint {got} in {run_dir / 'checkpoints'} was written by another config: {diff}")
            problem = trainer.key_problem(state)
            if problem:
                raise RunError(f"checkpoint {got} in {run_dir / 'checkpoints'} is damaged: {problem}")
            start = int(meta["generation"])
            if start >= cfg.generations:  # the run stays as it is, byte for byte: nothing set aside or rewritten
                log(f"nothing to do: {start} generations done, {cfg.generations} asked (checkpoint {got} of "
                    f"{run_dir}); nothing written (--config.generations=N runs it longer)")
                return OpenRun(trainer=trainer, run_dir=run_dir, state=state, start=start, log=log, done=True,
                               rows=outputs.read_rows(metrics_path, below=start))
        elif step is not None:
            raise RunError(f"--step {step}: {run_dir} has no checkpoint yet")
        removed = ckpt.clean_tmp(run_dir)  # a checkpoint a kill interrupted: never complete, never read
        if removed:
            log(f"removed {len(removed)} unfinished checkpoint folder(s) left in {run_dir / 'checkpoints'} by a "
                f"killed run: {', '.join(removed)}")
        if have:
            if got < have[-1]:
                moved = ckpt.set_aside_after(run_dir, got)
                log(f"continuing from checkpoint {got}: the later checkpoints {[s for s in have if s > got]} "
                    f"and the metrics are set aside in {moved}")
            log(f"resuming {run_dir} after generation {start} (best so far {float(state.best_so_far):.4f})")
        else:
            log(f"resuming {run_dir}: no checkpoint yet, starting again from generation 0")
    run_dir.mkdir(parents=True, exist_ok=True)
    record = cfg.to_dict()
    if saved_record is not None:  # keep the record the run was started with
        record[cfg_lib.SOURCE_RECORD] = saved_record
    elif trainer.source is not None:  # resolved path, concrete step and digest, before the first generation
        record[cfg_lib.SOURCE_RECORD] = trainer.source.record()
    outputs.write_json(run_dir / "config.json", record)
    rows = outputs.read_rows(metrics_path, below=start)
    outputs.write_rows(metrics_path, rows, trainer.fields)  # drops rows of generations after the checkpoint
    manager = ckpt.manager(run_dir / "checkpoints", cfg.keep_checkpoints)
    if state is None:
        state = trainer.init()
    log(f"kx.train: {cfg.task} {enc.describe()}, population {cfg.population_size}, {cfg.trials} trials, "
        f"{cfg.generations} generations, objective {cfg.objective}, seed {cfg.seed} -> {run_dir}")
    if trainer.source is not None:
        src = trainer.source
        log(f"transfer: seeded ({src.seeding}) from {src.run_dir} checkpoint {src.step} ({src.cfg.task}, "
            f"{int(src.state.generation)} generations; {src.digest[:19]}...)")
    impl = enc.implementation()
    if impl:
        log(f"decision: {describe_implementation(impl)}")
    record_runtime(run_dir, start, impl)
    baselines = trainer.validation_baselines()
    outputs.write_json(run_dir / "baselines.json", {"trials": cfg.validation_trials, "states": "validation",
                                                   "mean_fitness": baselines})
    log(f"validation states ({cfg.validation_trials}): "
        + ", ".join(f"{k} policy {v:.4f}" for k, v in baselines.items()))
    return OpenRun(trainer=trainer, run_dir=run_dir, state=state, start=start, rows=rows, log=log, manager=manager,
                   baselines=baselines)
