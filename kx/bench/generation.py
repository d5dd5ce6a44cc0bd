"""``python -m kx.bench generation``: seconds per generation of ``python -m kx.train``'s default config (or
``--config``) through the run loop, split into evaluation and evolution."""

from __future__ import annotations


def run(args) -> None:
    """Seconds per generation of ``python -m kx.train``'s default config (3v2, NEAT, population 150,
    30 trials; or ``--config``), through the run loop every method uses, split into evaluation (build the
    networks, play the trials) and evolution (``tell``), with the share of executed simulator lane-steps
    that were live. The first ``--skip`` generations compile and are left out of the medians."""
    import numpy as np

    from kx.evolve import config as cfg_lib
    from kx.evolve import outputs
    from kx.evolve import run as run_lib

    cfg = cfg_lib.load(args.config, [f"seed={args.seed}", f"generations={args.generations}"])
    trainer = run_lib.Trainer(cfg)
    print(f"config {args.config or 'configs/neat_3v2.py'}: {cfg.task} {trainer.encoding.describe()}, population "
          f"{cfg.population_size}, {cfg.trials} trials; {args.generations} generations, the first {args.skip} left out")
    rows = []

    def log(row):
        rows.append(row)
        print(outputs.progress_line(row, args.generations, None, trainer.encoding), flush=True)

    run_lib.evolve_in_memory(trainer, log=log)
    body = rows[args.skip:] or rows
    med = lambda k: float(np.median([r[k] for r in body]))  # noqa: E731
    live = sum(r["live_steps"] for r in body) / sum(r["live_steps"] / max(r["live_fraction"], 1e-9) for r in body)
    e, t, h, total = med("eval_seconds"), med("evolve_seconds"), med("validation_seconds"), med("generation_seconds")
    print(f"median over generations {min(args.skip, len(rows) - 1)}..{len(rows) - 1}: {total:.3f} s per generation "
          f"= evaluation {e:.3f} s + evolution {t:.4f} s + the champion on {cfg.validation_trials} validation states "
          f"{h:.3f} s; live lane-steps {live:.1%} of those executed")
    print(f"generation: {total:.3f} s (ratio {t / e:.4f} vs evaluation)")
