"""A training run: NEAT teams evolved on keep-away, with a run directory that survives being killed.

Each generation ``g`` draws ``trials`` start states from ``fold_in(key(seed), g)`` (every genome meets
the same ones), evaluates the population's networks on them with the batched evaluator, takes each
genome's mean fitness, and lets NEAT's ``tell`` breed the next population. Everything random derives
from ``(seed, g)``, so a run resumed from the checkpoint after generation ``g`` continues exactly as the
uninterrupted run would have.

A generation's best fitness is the largest of ``population_size`` noisy means over ``trials`` shared
start states, so it flatters the champion (on keep-away one 4500-iteration trial of 30 is worth 0.033).
Each generation therefore also replays its champion on ``heldout_trials`` start states that no
generation trains on (the same ones every generation, drawn from the run's held-out stream), and
``baselines.json`` gives the hand-coded policies' fitness on those same states: the ``champion_heldout``
column is the unbiased learning curve. It is measured, never used for selection.

The run directory::

    config.json        the resolved config
    metrics.csv        one row per generation (fitness, species, genome sizes, behaviour, the champion's
                       fitness on held-out start states, timings)
    baselines.json     the hand-coded policies (hold, random, heuristic) on the same held-out states
    progress.png       best / mean / median fitness, the held-out champion and species per generation
    checkpoints/<n>/   orbax checkpoints after n generations: the NEAT state and the run's metadata
    champion.gif       the champion's episode, at the end
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

from kx.evolve import config as cfg_lib
from kx.evolve.policy import neat_policy
from kx.neat.algorithm import NEAT
from kx.neat.network import build
from kx.neat.types import NEATState
from kx.sim import env
from kx.sim import evaluate as ev
from kx.sim.policies import BASELINES

CSV_FIELDS = ("generation", "best_fitness", "mean_fitness", "median_fitness", "best_so_far", "n_species",
              "threshold", "mean_hidden", "mean_links", "champion_hidden", "champion_links", "mean_passes",
              "mean_dispersion", "mean_ball_centre", "champion_passes", "champion_heldout", "live_fraction",
              "live_steps", "eval_seconds", "evolve_seconds", "heldout_seconds", "generation_seconds")
HELD_OUT = 0x7FFFFFFF  # fold_in index of held-out trials (training uses 0, 1, 2, ...)


class RunError(RuntimeError):
    """A run directory or checkpoint that cannot be used, with the reason."""


def trial_key(seed: int, generation: int) -> jax.Array:
    return jax.random.fold_in(jax.random.key(seed), generation)


def heldout_keys(seed: int) -> tuple[jax.Array, jax.Array]:
    """Start-state and policy keys of the per-generation held-out replay (not kx.evaluate's states)."""
    return tuple(jax.random.split(jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), HELD_OUT), 2)))


# ------------------------------------------------------------------------------------------ checkpoints


def _manager(ckpt_dir: pathlib.Path, keep: int, create: bool = True):
    import orbax.checkpoint as ocp
    from orbax.checkpoint import checkpoint_managers as cm

    policy = cm.AnyPreservationPolicy([
        cm.LatestN(n=keep),
        cm.BestN(get_metric_fn=lambda m: m["best_fitness"], reverse=False, n=1),
    ])
    options = ocp.CheckpointManagerOptions(preservation_policy=policy, create=create,
                                           enable_async_checkpointing=False)
    return ocp.CheckpointManager(ckpt_dir, options=options, item_names=("state", "meta"))


def save_checkpoint(manager, step: int, state: NEATState, meta: dict) -> None:
    """Writes checkpoint ``step`` (orbax writes to a temporary directory and renames it when complete,
    so a kill leaves either the whole checkpoint or none). The last ``keep_checkpoints`` are kept, and
    the one whose generation had the best fitness."""
    import orbax.checkpoint as ocp

    manager.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)),
                 metrics={"best_fitness": float(meta["best_fitness"])})
    manager.wait_until_finished()


def restore_checkpoint(run_dir: pathlib.Path, template: NEATState, step: int | None = None,
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

        errs = check_population(state.population, neat_config)
        if np.isfinite(np.asarray(state.best_fitness)):
            errs += [f"best genome: {e}" for e in check_genome(state.best_genome, neat_config)]
        if errs:
            raise RunError(f"checkpoint {step} in {ckpt_dir} holds invalid genomes ({len(errs)} problems; the "
                           f"first: {errs[0]}): damaged, or written by a kx with another genome layout")
    return step, state, meta


# ---------------------------------------------------------------------------------------- the run


@dataclasses.dataclass
class GenerationResult:
    row: dict
    state: NEATState


class Trainer:
    """The objects of one experiment and one generation step (no files; :func:`train` adds them)."""

    def __init__(self, cfg: ml_collections.ConfigDict):
        self.cfg = cfg
        self.exp = cfg_lib.validate(cfg)
        self.neat = NEAT(self.exp.neat, self.exp.neat_params)
        self.policy = neat_policy(self.exp.sim, self.exp.neat, self.exp.layout)
        self.heldout_starts = None
        if cfg.heldout_trials:
            k_start, self.heldout_policy_key = heldout_keys(cfg.seed)
            self.heldout_starts = env.reset_batch(k_start, cfg.heldout_trials, self.exp.sim_params, self.exp.sim)

    def heldout(self, genome) -> float:
        """Mean fitness of one genome on the held-out start states."""
        net = jax.tree.map(lambda a: a[None], build(genome, self.exp.neat))
        stats = ev.evaluate(self.policy, net, self.heldout_starts, self.exp.sim_params, self.exp.sim,
                            key=self.heldout_policy_key)
        return float(stats.fitness.mean())

    def heldout_baselines(self) -> dict:
        """The hand-coded policies' mean fitness on the held-out start states."""
        out = {}
        for name, make in BASELINES.items():
            stats = ev.evaluate(make(self.exp.sim), None, self.heldout_starts, self.exp.sim_params, self.exp.sim,
                                key=self.heldout_policy_key)
            out[name] = float(stats.fitness.mean())
        return out

    def init(self) -> NEATState:
        return self.neat.init(jax.random.fold_in(jax.random.key(self.cfg.seed), HELD_OUT - 1))

    def step(self, generation: int, state: NEATState, best_so_far: float) -> GenerationResult:
        """Evaluate generation ``generation``'s population and breed the next one."""
        k_trials, k_tell = jax.random.split(trial_key(self.cfg.seed, generation))
        t0 = time.perf_counter()
        starts = env.reset_batch(k_trials, self.cfg.trials, self.exp.sim_params, self.exp.sim)
        nets = self.neat.networks(state.population)
        counters = ev.EvalCounters()
        stats = ev.evaluate(self.policy, nets, starts, self.exp.sim_params, self.exp.sim,
                            key=jax.random.fold_in(k_trials, 1), counters=counters)
        fitness = stats.fitness.mean(axis=1)
        jax.block_until_ready(fitness)
        t1 = time.perf_counter()
        new_state, m = self.neat.tell(k_tell, state.population, fitness, state)
        jax.block_until_ready(new_state)
        t2 = time.perf_counter()
        beh = np.asarray(stats.behaviour.mean(axis=2))  # [3, G]: passes, dispersion, ball centre
        champ = int(jnp.argmax(fitness))
        heldout = (self.heldout(jax.tree.map(lambda a: a[champ], state.population))
                   if self.heldout_starts is not None else float("nan"))
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
            "champion_heldout": heldout,
            "live_fraction": counters.live_steps / max(counters.executed_steps, 1),
            "live_steps": counters.live_steps, "eval_seconds": t1 - t0, "evolve_seconds": t2 - t1,
            "heldout_seconds": t3 - t2, "generation_seconds": t3 - t0,
        }
        return GenerationResult(row=row, state=new_state)


def _fmt_seconds(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min"


def progress_line(row: dict, total: int, eta: float | None) -> str:
    eta_text = "" if eta is None else f"  ETA {_fmt_seconds(eta)}"
    return (f"gen {row['generation'] + 1:3d}/{total}  best {row['best_fitness']:.4f}  mean {row['mean_fitness']:.4f}"
            f"  median {row['median_fitness']:.4f}  best-so-far {row['best_so_far']:.4f}"
            f"  champion held-out {row['champion_heldout']:.4f}  species {row['n_species']:2d}"
            f"  hidden {row['mean_hidden']:.2f}  links {row['mean_links']:.1f}  live {row['live_fraction']:.0%}"
            f"  {row['generation_seconds']:.2f} s/gen (eval {row['eval_seconds']:.2f}, evolve "
            f"{row['evolve_seconds']:.3f}){eta_text}")


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
    """Best, mean and median fitness, the best so far and the champion on held-out states per generation,
    the random and heuristic policies on those states, and the species count."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = [int(r["generation"]) + 1 for r in rows]
    col = lambda k: [float(r[k]) for r in rows]  # noqa: E731
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.plot(g, col("best_fitness"), label="best", color="C0")
    ax.plot(g, col("best_so_far"), label="best so far", color="C0", linestyle="--")
    ax.plot(g, col("mean_fitness"), label="mean", color="C1")
    ax.plot(g, col("median_fitness"), label="median", color="C2")
    heldout = col("champion_heldout")
    if not all(np.isnan(heldout)):
        ax.plot(g, heldout, label="champion, held-out states", color="C4", marker=".")
    for i, name in enumerate(("random", "heuristic")):
        if baselines and name in baselines:
            ax.axhline(baselines[name], color="0.5", linestyle=(0, (1, 1 + 2 * i)), linewidth=1,
                       label=f"{name} policy, held-out states")
    ax.set_yscale("log")  # random play holds about 0.003, the heuristic about 0.17, a perfect team 1
    ax.set_ylabel("fitness (portion of max hold time, log scale)")
    ax.set_title(title)
    ax.legend(loc="upper left")
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
    """The champion's episode on a held-out start state, as a GIF."""
    from kx.sim.render import render_gif

    exp = trainer.exp
    key = jax.random.fold_in(jax.random.key(trainer.cfg.seed), HELD_OUT)
    start = env.reset(jax.random.split(key)[0], exp.sim_params, exp.sim)
    net = build(genome, exp.neat)
    states, _ = ev.rollout(trainer.policy, net, start, exp.sim_params, exp.sim, key=jax.random.split(key)[1],
                           n_steps=frames)
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
    (run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2, sort_keys=True) + "\n")
    rows = _read_rows(metrics_path, below=start)
    _write_rows(metrics_path, rows)  # drops rows of generations after the checkpoint
    manager = _manager(ckpt_dir, cfg.keep_checkpoints)
    if state is None:
        state = trainer.init()
    exp = trainer.exp
    log(f"kx.train: {cfg.task} {cfg.method} ({exp.layout} layout: {exp.neat.n_inputs} inputs, "
        f"{exp.neat.n_outputs} outputs), population {cfg.population_size}, {cfg.trials} trials, "
        f"{cfg.generations} generations, seed {cfg.seed} -> {run_dir}")
    baselines = None
    if cfg.heldout_trials:
        baselines = trainer.heldout_baselines()
        tmp = run_dir / "baselines.json.tmp"
        tmp.write_text(json.dumps({"trials": cfg.heldout_trials, "mean_fitness": baselines}, indent=2) + "\n")
        os.replace(tmp, run_dir / "baselines.json")
        log(f"held-out states ({cfg.heldout_trials}): "
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
                    "best_fitness": row["best_fitness"]}
            save_checkpoint(manager, g + 1, state, meta)
            plot_progress(rows, run_dir / "progress.png", f"kx {cfg.task} {cfg.method}, seed {cfg.seed}", baselines)
    if rows:
        plot_progress(rows, run_dir / "progress.png", f"kx {cfg.task} {cfg.method}, seed {cfg.seed}", baselines)
    if cfg.gif and rows:
        gif = render_champion(trainer, state.best_genome, run_dir / "champion.gif", cfg.gif_frames)
        log(f"champion (best fitness {float(state.best_fitness):.4f} on its generation's trials): {gif}")
    log(f"done: {run_dir} (metrics.csv, baselines.json, progress.png, checkpoints/, champion.gif)")
    return row
