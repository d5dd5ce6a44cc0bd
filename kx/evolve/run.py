"""A training run: NEAT teams evolved on keep-away, with a run directory that survives being killed.

Each generation ``g`` draws ``trials`` start states from the run's training stream (every genome meets
the same ones), evaluates the population's networks on them with the batched evaluator, takes each
genome's mean fitness, and lets NEAT's ``tell`` breed the next population. Every key comes from
:mod:`kx.evolve.streams` (training, validation and test trials, evaluator noise, the learner), so a run
resumed from the checkpoint after generation ``g`` continues exactly as the uninterrupted run would have.

**The champion is validated.** A generation's best training fitness is the largest of
``population_size`` noisy means over ``trials`` shared start states, so it flatters the genome that
reached it. Each generation's champion by training fitness is therefore replayed on
``validation_trials`` start states that no generation trains on (the same ones every generation, from
the run's validation stream), and the run's champion is the per-generation champion with the best
validation score (the earliest on ties). It is what the run reports and hands on: the progress line,
``metrics.csv``'s ``best_validation``, ``champion.gif``, ``kx.evaluate`` (which plays it on the test
stream's states, never seen in training or validation) and the checkpoints. ``baselines.json`` gives the
hand-coded policies on the validation states.

The run directory::

    config.json        the resolved config
    metrics.csv        one row per generation (training fitness, species, genome sizes, behaviour, the
                       generation champion's validation score and the best so far, timings)
    baselines.json     the hand-coded policies (hold, random, heuristic) on the validation states
    progress.png       best / mean / median training fitness, the validated champion and species
    checkpoints/<n>/   orbax checkpoints after n generations: the run state (NEAT's state and the
                       validated champion) and the run's metadata
    champion.gif       the validated champion playing the first test state, at the end
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import pathlib
import shutil
import time
from typing import Callable

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np
from flax import struct

from kx.evolve import config as cfg_lib
from kx.evolve import streams
from kx.evolve.policy import neat_policy
from kx.neat.algorithm import NEAT
from kx.neat.network import build
from kx.neat.types import Genome, NEATState
from kx.sim import env
from kx.sim import evaluate as ev
from kx.sim.policies import BASELINES

CSV_FIELDS = ("generation", "best_fitness", "mean_fitness", "median_fitness", "best_so_far", "n_species",
              "threshold", "mean_hidden", "mean_links", "champion_hidden", "champion_links", "mean_passes",
              "mean_dispersion", "mean_ball_centre", "champion_passes", "champion_validation",
              "best_validation", "best_validation_generation", "node_overflow", "link_overflow",
              "link_exhausted", "species_overflow", "live_fraction", "live_steps", "eval_seconds",
              "evolve_seconds", "validation_seconds", "generation_seconds")


@struct.dataclass
class RunState:
    """What a run carries from one generation to the next, checkpointed whole."""

    neat: NEATState
    champion: Genome  # the validated champion: the per-generation champion with the best validation score
    champion_validation: jax.Array  # float32 its mean fitness on the validation states (-inf before any)
    champion_generation: jax.Array  # int32 the generation it was evaluated in (-1 before any)


class RunError(RuntimeError):
    """A run directory or checkpoint that cannot be used, with the reason."""


# ------------------------------------------------------------------------------------------ checkpoints


def _manager(ckpt_dir: pathlib.Path, keep: int, create: bool = True):
    import orbax.checkpoint as ocp
    from orbax.checkpoint import checkpoint_managers as cm

    policy = cm.AnyPreservationPolicy([
        cm.LatestN(n=keep),
        cm.BestN(get_metric_fn=lambda m: m["champion_validation"], reverse=False, n=1),
    ])
    options = ocp.CheckpointManagerOptions(preservation_policy=policy, create=create,
                                           enable_async_checkpointing=False)
    return ocp.CheckpointManager(ckpt_dir, options=options, item_names=("state", "meta"))


def save_checkpoint(manager, step: int, state: RunState, meta: dict) -> None:
    """Writes checkpoint ``step`` (orbax writes to a temporary directory and renames it when complete,
    so a kill leaves either the whole checkpoint or none). The last ``keep_checkpoints`` are kept, and
    the one of the generation whose champion validated best (``meta["champion_validation"]``)."""
    import orbax.checkpoint as ocp

    manager.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)),
                 metrics={"champion_validation": float(meta["champion_validation"])})
    manager.wait_until_finished()


def restore_checkpoint(run_dir: pathlib.Path, template: RunState, step: int | None = None,
                       neat_config=None):
    """``(step, state, meta)`` of checkpoint ``step`` (default: the latest) of a run directory; a
    checkpoint that is missing, unreadable or of another shape is refused with :class:`RunError`, and,
    given the run's ``neat_config`` (a :class:`~kx.neat.types.NEATConfig`), one whose genomes break an
    invariant of :func:`kx.neat.genome.check_genome` (a damaged file, or one written by a kx whose
    genome layout differed)."""
    import orbax.checkpoint as ocp

    ckpt_dir = pathlib.Path(run_dir).absolute() / "checkpoints"
    if not ckpt_dir.is_dir():
        raise RunError(f"{run_dir}: no checkpoints/ directory (not a kx run directory?)")
    manager = _manager(ckpt_dir, keep=1_000_000, create=False)
    steps = manager.all_steps()
    if not steps:
        raise RunError(f"{ckpt_dir}: holds no complete checkpoint")
    step = max(steps) if step is None else step
    if step not in steps:
        raise RunError(f"{ckpt_dir}: no checkpoint {step} (there are {sorted(steps)})")
    abstract = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), template)
    try:
        meta = manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]
    except Exception as e:  # noqa: BLE001 - orbax raises many kinds; all mean the same to the user
        raise RunError(f"checkpoint {step} in {ckpt_dir} is corrupt or unreadable (its metadata): "
                       f"{type(e).__name__}: {e}") from None
    if not isinstance(meta, dict) or "config" not in meta or "generation" not in meta:
        raise RunError(f"checkpoint {step} in {ckpt_dir} is not a kx checkpoint (metadata without config)")
    try:
        state = manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract)))["state"]
    except Exception as e:  # noqa: BLE001
        raise RunError(f"checkpoint {step} in {ckpt_dir} is corrupt or does not match this config's shapes: "
                       f"{type(e).__name__}: {str(e)[:500]}") from None
    for path, a, b in zip(jax.tree_util.tree_flatten_with_path(abstract)[0], jax.tree.leaves(abstract),
                          jax.tree.leaves(state)):
        if a.shape != b.shape or a.dtype != b.dtype:
            raise RunError(f"checkpoint {step} in {ckpt_dir}: {jax.tree_util.keystr(path[0])} is "
                           f"{b.dtype}{list(b.shape)}, this config needs {a.dtype}{list(a.shape)}")
    if neat_config is not None:
        from kx.neat.genome import check_genome, check_population

        errs = check_population(state.neat.population, neat_config)
        if np.isfinite(np.asarray(state.neat.best_fitness)):
            errs += [f"best genome: {e}" for e in check_genome(state.neat.best_genome, neat_config)]
        if int(state.champion_generation) >= 0:
            errs += [f"champion: {e}" for e in check_genome(state.champion, neat_config)]
        if errs:
            raise RunError(f"checkpoint {step} in {ckpt_dir} holds invalid genomes ({len(errs)} problems; the "
                           f"first: {errs[0]}): damaged, or written by a kx with another genome layout")
    return step, state, meta


# ---------------------------------------------------------------------------------------- the run


@dataclasses.dataclass
class GenerationResult:
    row: dict
    state: RunState


class Trainer:
    """The objects of one experiment and one generation step (no files; :func:`train` adds them)."""

    def __init__(self, cfg: ml_collections.ConfigDict):
        self.cfg = cfg
        self.exp = cfg_lib.validate(cfg)
        self.neat = NEAT(self.exp.neat, self.exp.neat_params)
        self.policy = neat_policy(self.exp.sim, self.exp.neat, self.exp.layout)
        keys = streams.validation(cfg.seed)
        self.validation_eval_key = keys.eval
        self.validation_starts = env.reset_batch(keys.starts, cfg.validation_trials, self.exp.sim_params, self.exp.sim)

    def validate(self, genome) -> float:
        """Mean fitness of one genome on the validation states."""
        net = jax.tree.map(lambda a: a[None], build(genome, self.exp.neat))
        stats = ev.evaluate(self.policy, net, self.validation_starts, self.exp.sim_params, self.exp.sim,
                            key=self.validation_eval_key)
        return float(stats.fitness.mean())

    def validation_baselines(self) -> dict:
        """The hand-coded policies' mean fitness on the validation states."""
        out = {}
        for name, make in BASELINES.items():
            stats = ev.evaluate(make(self.exp.sim), None, self.validation_starts, self.exp.sim_params, self.exp.sim,
                                key=self.validation_eval_key)
            out[name] = float(stats.fitness.mean())
        return out

    def init(self) -> RunState:
        neat = self.neat.init(streams.learner_init(self.cfg.seed))
        return RunState(neat=neat, champion=jax.tree.map(lambda a: a[0], neat.population),
                        champion_validation=jnp.asarray(-jnp.inf, jnp.float32),
                        champion_generation=jnp.asarray(-1, jnp.int32))

    def step(self, generation: int, state: RunState, best_so_far: float) -> GenerationResult:
        """Evaluate generation ``generation``'s population, validate its champion, breed the next one."""
        keys = streams.training(self.cfg.seed, generation)
        population = state.neat.population
        t0 = time.perf_counter()
        starts = env.reset_batch(keys.starts, self.cfg.trials, self.exp.sim_params, self.exp.sim)
        nets = self.neat.networks(population)
        counters = ev.EvalCounters()
        stats = ev.evaluate(self.policy, nets, starts, self.exp.sim_params, self.exp.sim, key=keys.eval,
                            counters=counters)
        fitness = stats.fitness.mean(axis=1)
        jax.block_until_ready(fitness)
        t1 = time.perf_counter()
        neat_state, m = self.neat.tell(streams.learner_step(self.cfg.seed, generation), population, fitness,
                                       state.neat)
        jax.block_until_ready(neat_state)
        t2 = time.perf_counter()
        beh = np.asarray(stats.behaviour.mean(axis=2))  # [3, G]: passes, dispersion, ball centre
        champ = int(jnp.argmax(fitness))
        champ_genome = jax.tree.map(lambda a: a[champ], population)
        validation = self.validate(champ_genome)
        if validation > float(state.champion_validation):  # strictly: the earliest champion wins ties
            state = state.replace(champion=champ_genome, champion_validation=jnp.asarray(validation, jnp.float32),
                                  champion_generation=jnp.asarray(generation, jnp.int32))
        state = state.replace(neat=neat_state)
        t3 = time.perf_counter()
        best = float(m["best_fitness"])
        row = {
            "generation": generation, "best_fitness": best, "mean_fitness": float(m["mean_fitness"]),
            "median_fitness": float(m["median_fitness"]), "best_so_far": max(best_so_far, best),
            "n_species": int(m["n_species"]), "threshold": float(m["threshold"]),
            "mean_hidden": float(m["mean_hidden"]), "mean_links": float(m["mean_links"]),
            "champion_hidden": int(m["champion_hidden"]), "champion_links": int(m["champion_links"]),
            "mean_passes": float(beh[0].mean()), "mean_dispersion": float(beh[1].mean()),
            "mean_ball_centre": float(beh[2].mean()), "champion_passes": float(beh[0, champ]),
            "champion_validation": validation, "best_validation": float(state.champion_validation),
            "best_validation_generation": int(state.champion_generation),
            **{k: int(m[k]) for k in ("node_overflow", "link_overflow", "link_exhausted", "species_overflow")},
            "live_fraction": counters.live_steps / max(counters.executed_steps, 1),
            "live_steps": counters.live_steps, "eval_seconds": t1 - t0, "evolve_seconds": t2 - t1,
            "validation_seconds": t3 - t2, "generation_seconds": t3 - t0,
        }
        return GenerationResult(row=row, state=state)


def evolve_in_memory(trainer: Trainer) -> tuple[RunState, list[dict]]:
    """All of ``trainer``'s generations with no run directory: the final run state (its validated
    champion included) and the metrics row of every generation, as :func:`train` would write them."""
    state, best, rows = trainer.init(), -np.inf, []
    for g in range(trainer.cfg.generations):
        res = trainer.step(g, state, best)
        state, best = res.state, res.row["best_so_far"]
        rows.append(res.row)
    return state, rows


def _fmt_seconds(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min"


def progress_line(row: dict, total: int, eta: float | None) -> str:
    eta_text = "" if eta is None else f"  ETA {_fmt_seconds(eta)}"
    return (f"gen {row['generation'] + 1:3d}/{total}  best {row['best_fitness']:.4f}  mean {row['mean_fitness']:.4f}"
            f"  median {row['median_fitness']:.4f}  validation {row['champion_validation']:.4f}"
            f" (best {row['best_validation']:.4f}, gen {int(row['best_validation_generation']) + 1})"
            f"  species {row['n_species']:2d}"
            f"  hidden {row['mean_hidden']:.2f}  links {row['mean_links']:.1f}  live {row['live_fraction']:.0%}"
            f"  {row['generation_seconds']:.2f} s/gen (eval {row['eval_seconds']:.2f}, evolve "
            f"{row['evolve_seconds']:.3f}){eta_text}")


def _write_json(path: pathlib.Path, obj) -> None:
    """Atomically: a kill leaves the old file or the new one, never half of one."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)


def _read_rows(path: pathlib.Path, below: int) -> list[dict]:
    if not path.is_file():
        return []
    with path.open() as f:
        return [r for r in csv.DictReader(f) if int(r["generation"]) < below]


def _write_rows(path: pathlib.Path, rows: list[dict]) -> None:
    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        w.writeheader()
        w.writerows(rows)
    os.replace(tmp, path)


def _append_row(path: pathlib.Path, row: dict) -> None:
    with path.open("a", newline="") as f:
        csv.DictWriter(f, fieldnames=CSV_FIELDS).writerow(row)
        f.flush()
        os.fsync(f.fileno())


def plot_progress(rows: list[dict], path: pathlib.Path, title: str, baselines: dict | None = None) -> None:
    """Best, mean and median training fitness, the best so far, each generation's champion on the
    validation states and the run's validated champion, the random and heuristic policies on those
    states, and the species count."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = [int(r["generation"]) + 1 for r in rows]
    col = lambda k: [float(r[k]) for r in rows]  # noqa: E731
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.plot(g, col("best_fitness"), label="best (training trials)", color="C0")
    ax.plot(g, col("best_so_far"), label="best so far (training trials)", color="C0", linestyle="--")
    ax.plot(g, col("mean_fitness"), label="mean", color="C1")
    ax.plot(g, col("median_fitness"), label="median", color="C2")
    ax.plot(g, col("champion_validation"), label="generation champion, validation states", color="C4",
            marker=".", linestyle=":")
    ax.plot(g, col("best_validation"), label="validated champion", color="C4", linewidth=2)
    for i, name in enumerate(("random", "heuristic")):
        if baselines and name in baselines:
            ax.axhline(baselines[name], color="0.5", linestyle=(0, (1, 1 + 2 * i)), linewidth=1,
                       label=f"{name} policy, validation states")
    ax.set_yscale("log")  # random play holds about 0.003, the heuristic about 0.02, a perfect team 1
    ax.set_ylabel("fitness (portion of max hold time, log scale)")
    ax.set_title(title)
    ax.legend(loc="lower right", fontsize="small")
    ax.grid(alpha=0.3)
    ax2.plot(g, col("n_species"), color="C3")
    ax2.set_ylabel("species")
    ax2.set_xlabel("generation")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    os.replace(tmp, path)


def render_champion(trainer: Trainer, genome, path: pathlib.Path, frames: int) -> pathlib.Path:
    """The champion's episode on the first test state (trial 0 of the test stream), as a GIF."""
    from kx.sim.render import render_gif

    exp = trainer.exp
    keys = streams.test(trainer.cfg.seed)
    start = jax.tree.map(lambda a: a[..., 0], env.reset_batch(keys.starts, 1, exp.sim_params, exp.sim))
    net = build(genome, exp.neat)
    states, _ = ev.rollout(trainer.policy, net, start, exp.sim_params, exp.sim, key=keys.eval, n_steps=frames)
    return render_gif(env.as_numpy(states), exp.sim, path, max_frames=frames)


def prepare_run_dir(run_dir: pathlib.Path, resume: bool, overwrite: bool) -> None:
    """Refuse to touch an existing run unless asked (before any compute)."""
    if resume and overwrite:
        raise RunError("--resume and --overwrite: choose one")
    exists = run_dir.exists() and any(run_dir.iterdir()) if run_dir.is_dir() else run_dir.exists()
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
        shutil.rmtree(run_dir) if run_dir.is_dir() else run_dir.unlink()


def train(cfg: ml_collections.ConfigDict, run_dir: str | pathlib.Path, *, resume: bool = False,
          overwrite: bool = False, log: Callable[[str], None] = print) -> dict:
    """Runs (or resumes) the experiment of ``cfg`` in ``run_dir``; returns the final metrics row."""
    run_dir = pathlib.Path(run_dir).absolute()  # orbax wants absolute paths
    trainer = Trainer(cfg)  # validates the config first
    prepare_run_dir(run_dir, resume, overwrite)
    ckpt_dir = run_dir / "checkpoints"
    metrics_path = run_dir / "metrics.csv"
    state, start, best_so_far = None, 0, -np.inf
    if resume:
        saved = json.loads((run_dir / "config.json").read_text())
        diff = cfg_lib.identity_mismatch(saved, cfg)
        if diff:
            raise RunError(f"--resume: this config differs from the run's: {diff}")
        if ckpt_dir.is_dir() and _manager(ckpt_dir, cfg.keep_checkpoints, create=False).all_steps():
            step, state, meta = restore_checkpoint(run_dir, jax.eval_shape(trainer.init),
                                                   neat_config=trainer.exp.neat)
            diff = cfg_lib.identity_mismatch(meta["config"], cfg)
            if diff:
                raise RunError(f"checkpoint {step} in {ckpt_dir} was written by another config: {diff}")
            start, best_so_far = int(meta["generation"]), float(meta["best_so_far"])
            log(f"resuming {run_dir} after generation {start} (best so far {best_so_far:.4f})")
        else:
            log(f"resuming {run_dir}: no checkpoint yet, starting again from generation 0")
        if start >= cfg.generations:
            log(f"nothing to do: {start} generations done, {cfg.generations} asked")
    run_dir.mkdir(parents=True, exist_ok=True)
    _write_json(run_dir / "config.json", cfg.to_dict())
    rows = _read_rows(metrics_path, below=start)
    _write_rows(metrics_path, rows)  # drops rows of generations after the checkpoint
    manager = _manager(ckpt_dir, cfg.keep_checkpoints)
    if state is None:
        state = trainer.init()
    exp = trainer.exp
    log(f"kx.train: {cfg.task} {cfg.method} ({exp.layout} layout: {exp.neat.n_inputs} inputs, "
        f"{exp.neat.n_outputs} outputs), population {cfg.population_size}, {cfg.trials} trials, "
        f"{cfg.generations} generations, seed {cfg.seed} -> {run_dir}")
    baselines = trainer.validation_baselines()
    _write_json(run_dir / "baselines.json", {"trials": cfg.validation_trials, "states": "validation",
                                             "mean_fitness": baselines})
    log(f"validation states ({cfg.validation_trials}): "
        + ", ".join(f"{k} policy {v:.4f}" for k, v in baselines.items()))
    t_run = time.perf_counter()
    done_here = 0
    row = rows[-1] if rows else None
    for g in range(start, cfg.generations):
        result = trainer.step(g, state, best_so_far)
        state, row = result.state, result.row
        best_so_far = row["best_so_far"]
        rows.append(row)
        _append_row(metrics_path, row)
        done_here += 1
        # ETA from the generations run in this process after the first (which compiles)
        per_gen = ((time.perf_counter() - t_run - rows[start]["generation_seconds"]) / (done_here - 1)
                   if done_here > 1 else None)
        log(progress_line(row, cfg.generations, None if per_gen is None else per_gen * (cfg.generations - g - 1)))
        last = g + 1 == cfg.generations
        if (g + 1) % cfg.checkpoint_every == 0 or last:
            meta = {"config": cfg.to_dict(), "generation": g + 1, "best_so_far": best_so_far,
                    "best_fitness": row["best_fitness"], "champion_validation": row["champion_validation"],
                    "best_validation": row["best_validation"]}
            save_checkpoint(manager, g + 1, state, meta)
            plot_progress(rows, run_dir / "progress.png", f"kx {cfg.task} {cfg.method}, seed {cfg.seed}", baselines)
    if rows:
        plot_progress(rows, run_dir / "progress.png", f"kx {cfg.task} {cfg.method}, seed {cfg.seed}", baselines)
    if cfg.gif and rows:
        gif = render_champion(trainer, state.champion, run_dir / "champion.gif", cfg.gif_frames)
        log(f"validated champion (generation {int(state.champion_generation) + 1}, "
            f"{float(state.champion_validation):.4f} on the {cfg.validation_trials} validation states): {gif}")
    log(f"done: {run_dir} (metrics.csv, baselines.json, progress.png, checkpoints/, champion.gif)")
    return row
