"""Many runs as one program, on disk: R runs of one config, differing only in seed, trained in lockstep,
each in its own run directory.

The generation step is :meth:`kx.evolve.trainer.RunGroup.step` (the one step there is; a run alone is a
group of one), driven by :func:`kx.evolve.run.advance` (the one host loop). :func:`train_group` writes each
run's own complete run directory, as :func:`kx.evolve.run.train` writes it for that seed alone, resumable one
by one or as a group (``python -m kx.train --seeds 0-15``), and prints one progress line per generation for
the group.
"""

from __future__ import annotations

import contextlib
import pathlib
import time
from typing import Callable, Sequence

import ml_collections
import numpy as np

from kx.evolve import outputs
from kx.evolve import run as run_lib
from kx.evolve.checkpoint import RunLock
from kx.evolve.errors import RunError
from kx.evolve.trainer import RunGroup, check_group


def progress_line(rows: list[dict], total: int, eta: float | None, seconds: float) -> str:
    """One line for a generation of a group: its runs' best, mean and validated figures (best and median
    over the runs), the live share and the time."""
    g = max(int(r["generation"]) for r in rows)
    col = lambda k: np.array([float(r[k]) for r in rows])  # noqa: E731
    best, mean, val = col("best_fitness"), col("mean_fitness"), col("best_validation")
    eta_text = "" if eta is None else f"  ETA {outputs.format_seconds(eta)}"
    return (f"gen {g + 1:3d}/{total}  {len(rows)} runs  best {best.max():.4f} (median {np.median(best):.4f})"
            f"  mean {np.median(mean):.4f}  validated {val.max():.4f} (median {np.median(val):.4f})"
            f"  live {float(rows[0]['live_fraction']):.0%}  {seconds:.2f} s/gen (eval "
            f"{float(rows[0]['eval_seconds']):.2f}, evolve {float(rows[0]['evolve_seconds']):.3f}){eta_text}")


def train_group(cfgs: Sequence[ml_collections.ConfigDict], run_dirs: Sequence[str | pathlib.Path], *,
                resume: bool | Sequence[bool] = False, overwrite: bool = False,
                log: Callable[[str], None] = print) -> list[dict | None]:
    """Trains (or resumes) the runs of ``cfgs`` (one config per run, equal but in :data:`VARYING`) in
    ``run_dirs`` as one batched group; returns each run's final metrics row. ``resume``: for every run,
    or one flag per run (a protocol resumes the runs a kill interrupted and starts the others).

    Each run directory is what :func:`kx.evolve.run.train` writes for that config alone, and can be
    resumed alone; a group whose runs were cut at different generations (a kill between two runs'
    checkpoints) is resumed in lockstep again: the runs behind advance first, as a smaller group.
    Every run directory is checked (and locked) before any compute."""
    cfgs, run_dirs = list(cfgs), [pathlib.Path(d).absolute() for d in run_dirs]
    if len(cfgs) != len(run_dirs):
        raise RunError(f"{len(cfgs)} configs and {len(run_dirs)} run directories")
    if len(set(run_dirs)) != len(run_dirs):
        raise RunError("--workdir: two runs of the group would share a run directory")
    check_group(cfgs)
    resumes = [bool(resume)] * len(cfgs) if isinstance(resume, bool) else [bool(r) for r in resume]
    if len(resumes) != len(cfgs):
        raise RunError(f"resume: {len(resumes)} flags for {len(cfgs)} runs")
    for d, res in zip(run_dirs, resumes):
        if d.exists() and not d.is_dir():
            raise RunError(f"--workdir: {d} is a file, not a run directory")
        if not overwrite:
            run_lib.prepare_run_dir(d, res, False)  # refuses now, before any run is written
    with contextlib.ExitStack() as stack:
        for d in run_dirs:
            stack.enter_context(RunLock(d, log))
        group = RunGroup.from_configs(cfgs)
        runs = [run_lib.open_run(t, d, resume=res, overwrite=overwrite, step=None,
                                 log=lambda s, seed=t.cfg.seed: log(f"[seed {seed}] {s}"))
                for t, d, res in zip(group.trainers, run_dirs, resumes)]
        for run in runs:
            run.quiet = True
        total, clock = cfgs[0].generations, outputs.GenerationClock()

        def each(rows: list[dict], g: int, seconds: float) -> None:
            per_gen = clock.tick(time.perf_counter())
            log(progress_line(rows, total, None if per_gen is None else per_gen * (total - g - 1), seconds))

        run_lib.advance(runs, group, total, notice=log, log=log, each=each)
        return [run.rows[-1] if run.done else run.close() for run in runs]
