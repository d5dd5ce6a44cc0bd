"""``python -m kx.bench hyperneat``: seconds per generation of HyperNEAT and of NEAT (3v2, 150 x 30) on the
same start states in one run, split into building the policies, evaluation, evolution and validation."""

from __future__ import annotations

import time


def _timed_generations(cfg, generations: int, log_name: str):
    """``generations`` generations of ``cfg`` through the run loop, each split into building the
    policies' parameters (NEAT: the networks; HyperNEAT: the substrates), playing the trials, evolution
    (``tell``) and the champion's validation. Returns one dict per generation."""
    import jax

    from kx.evolve import report
    from kx.evolve import run as run_lib

    trainer = run_lib.Trainer(cfg)
    enc = trainer.encoding
    build, built = enc.policy_params, []

    def timed_build(population):  # the loop calls it once per evaluation: the generation's, then validation's
        t0 = time.perf_counter()
        out = jax.block_until_ready(build(population))
        built.append(time.perf_counter() - t0)
        return out

    enc.policy_params = timed_build
    state, rows = trainer.init(), []
    for _ in range(generations):
        built.clear()
        res = trainer.step(state)
        state, row = res.state, res.row
        row = dict(row, build_seconds=built[0], play_seconds=row["eval_seconds"] - built[0])
        rows.append(row)
        print(f"{log_name} " + report.progress_line(row, generations, None, enc)
              + f"  build {row['build_seconds']:.3f} s  play {row['play_seconds']:.3f} s  live steps "
              f"{row['live_steps']}", flush=True)
    return trainer, rows


def run(args) -> None:
    """Seconds per generation of HyperNEAT (``configs/hyperneat_3v2.py``) and of NEAT (the default config)
    in one run, on the same 3v2 start states (the training stream of ``--seed``: each generation's 30
    states are the same for both) and the same population (150 x 30), through the run loop, split into
    building the policies (HyperNEAT: every CPPN queried over the substrate's 160,000 links; NEAT: the
    networks), evaluation (playing the 4500 episodes), evolution (``tell``) and the champion's
    validation. The first ``--skip`` generations compile and are left out of the medians, which are
    reported with the live lane-steps (episode lengths differ between the two methods' teams) and the
    cost per live step."""
    import numpy as np

    from kx.evolve import config as cfg_lib

    runs = {}
    for name, path in (("neat", None), ("hyperneat", "configs/hyperneat_3v2.py")):
        cfg = cfg_lib.load(path, [f"seed={args.seed}", f"generations={args.generations}", "gif=false"])
        t0 = time.perf_counter()
        trainer, rows = _timed_generations(cfg, args.generations, name)
        runs[name] = (trainer, rows, time.perf_counter() - t0)
    med = {}
    for name, (trainer, rows, wall) in runs.items():
        body = rows[args.skip:] or rows
        m = {k: float(np.median([r[k] for r in body])) for k in (
            "generation_seconds", "build_seconds", "play_seconds", "evolve_seconds", "validation_seconds",
            "live_steps")}
        first = rows[0]["generation_seconds"]
        med[name] = m
        print(f"{name}: {trainer.encoding.describe()}; median over generations {min(args.skip, len(rows) - 1)}.."
              f"{len(rows) - 1}: {m['generation_seconds']:.3f} s per generation = build {m['build_seconds']:.3f} s "
              f"+ evaluation {m['play_seconds']:.3f} s + evolution {m['evolve_seconds']:.4f} s + validation "
              f"{m['validation_seconds']:.3f} s; {m['live_steps'] / 1e6:.2f}M live lane-steps per generation, "
              f"{m['play_seconds'] / max(m['live_steps'], 1) * 1e9:.0f} ns each; generation 0 (compiling) "
              f"{first:.1f} s; {wall:.0f} s in all")
    h, n = med["hyperneat"], med["neat"]
    per_step = (h["play_seconds"] / h["live_steps"]) / (n["play_seconds"] / n["live_steps"])
    print(f"per live lane-step, HyperNEAT's evaluation costs {per_step:.2f}x NEAT's")
    ratio = h["generation_seconds"] / n["generation_seconds"]
    print(f"hyperneat: {h['generation_seconds']:.3f} s/generation (ratio {ratio:.2f} vs neat)")
