"""Play a run's validated champion on test trials, in any task: ``python -m kx.evaluate RUN_DIR``.

    python -m kx.evaluate runs/neat_3v2-s0-... --task 4v3 --trials 1000

The champion is the run's validated champion: of each generation's best genome by training fitness,
the one with the best mean on the run's validation states (``kx.evolve.run``), of any method (NEAT,
CMA-ES, any registered encoding). Here it meets
``--trials`` start states of the test stream (:mod:`kx.evolve.streams`), which neither training nor
validation ever drew, next to the hand-coded baselines on the same states and kick noise. A network
of the fixed 13/3 layout plays any team size unchanged (zero-shot transfer); a full-layout network fits
only the team size it was evolved for (refused otherwise). Prints the figures and writes them
(atomically) to ``RUN_DIR/eval/<task>-<trials>-seed<seed>.json``: for the champion and each baseline,
the mean fitness over the trials with its sample sd and 95% confidence interval (Student's t,
:func:`ci95`), the median, the mean passes and how the episodes ended.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

from kx import runtime


def ci95(f) -> tuple[float, float] | None:
    """The 95% confidence interval of the mean of the per-trial fitnesses ``f``: Student's t with
    ``n - 1`` degrees of freedom around the mean, scaled by its standard error (``scipy.stats``).
    ``(mean, mean)`` when every trial scored the same; ``None`` for one trial (no interval)."""
    from scipy import stats

    f = np.asarray(f, np.float64).reshape(-1)
    if f.size < 2:
        return None
    mean, sem = float(f.mean()), float(stats.sem(f))
    if sem == 0.0:
        return mean, mean
    lo, hi = stats.t.interval(0.95, f.size - 1, loc=mean, scale=sem)
    return float(lo), float(hi)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m kx.evaluate", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir")
    p.add_argument("--task", default=None, help="task to play (default: the run's own), e.g. 4v3")
    p.add_argument("--trials", type=int, default=1000)
    p.add_argument("--seed", type=int, default=None, help="seed of the test trials (default: the run's)")
    p.add_argument("--step", type=int, default=None, help="checkpoint to read (default: the latest)")
    p.add_argument("--no-baselines", action="store_true", help="skip the hand-coded baselines")
    args = p.parse_args(argv)

    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib
    from kx.evolve.errors import ConfigError, RunError

    runtime.setup()  # first: validating the run's config may touch JAX, whose devices are fixed then
    run_dir = pathlib.Path(args.run_dir)
    try:
        if not (run_dir / "config.json").is_file():
            raise RunError(f"{run_dir}: not a kx run directory (no config.json)")
        if not 1 <= args.trials <= 1_000_000:
            raise ConfigError(f"--trials: allowed an integer in [1, 1000000], got {args.trials}")
        cfg = cfg_lib.read_run_config(run_dir / "config.json")
        source = cfg_lib.validate(cfg)
        target_cfg = cfg_lib.from_dict(cfg.to_dict())
        if args.task:
            target_cfg.task = args.task
        target = cfg_lib.validate(target_cfg)
        policy = source.encoding.policy_for(target.sim)  # refuses networks that do not fit the task
    except (ConfigError, RunError) as e:
        print(f"kx.evaluate: error: {e}", file=sys.stderr)
        return 2

    from kx.evolve import outputs, streams
    from kx.evolve.encoding import stack
    from kx.sim import env
    from kx.sim import evaluate as ev
    from kx.sim.policies import BASELINES
    from kx.sim.types import Reason

    trainer = run_lib.Trainer(cfg)
    try:
        step, state, meta = trainer.restore(run_dir, args.step)
    except RunError as e:
        print(f"kx.evaluate: error: {e}", file=sys.stderr)
        return 2
    if int(state.champion_generation) < 0:
        print(f"kx.evaluate: error: checkpoint {step} of {run_dir} holds no validated champion yet", file=sys.stderr)
        return 2
    seed = cfg.seed if args.seed is None else args.seed
    keys = streams.test(seed)
    starts = env.reset_batch(keys.starts, args.trials, target.sim_params, target.sim)
    params = source.encoding.policy_params(stack([state.champion]))
    stats = ev.evaluate(policy, params, starts, target.sim_params, target.sim, key=keys.eval)

    def summary(s) -> dict:
        f = np.asarray(s.fitness).reshape(-1)
        reason = np.asarray(s.reason).reshape(-1)
        sd = float(f.std(ddof=1)) if f.size > 1 else 0.0
        ci = ci95(f)
        return {"mean_fitness": float(f.mean()), "sd": sd, "ci95": None if ci is None else list(ci),
                "median": float(np.median(f)),
                "mean_passes": float(np.asarray(s.passes).mean()),
                "reasons": {r.name.lower(): float(np.mean(reason == r)) for r in Reason if r != Reason.RUNNING}}

    result = {"run_dir": str(run_dir), "checkpoint": step, "generations_done": meta["generation"],
              "method": cfg.method, "source_task": cfg.task, "task": target.sim.name, "trials": args.trials,
              "seed": seed,
              "champion_generation": int(state.champion_generation) + 1,
              "champion_validation": float(state.champion_validation), "champion": summary(stats)}
    if not args.no_baselines:
        result["baselines"] = {}
        for name, make in BASELINES.items():
            pol = make(target.sim)
            result["baselines"][name] = summary(ev.evaluate(pol, None, starts, target.sim_params, target.sim,
                                                            key=keys.eval))
    c = result["champion"]
    ci = "none with one trial" if c["ci95"] is None else f"{c['ci95'][0]:.4f}..{c['ci95'][1]:.4f}"
    print(f"validated champion of {run_dir} (checkpoint {step}, trained on {cfg.task}; from generation "
          f"{result['champion_generation']}, {result['champion_validation']:.4f} on its {cfg.validation_trials} "
          f"validation states)")
    print(f"{target.sim.name}, {args.trials} test trials (seed {seed}): mean fitness {c['mean_fitness']:.4f} "
          f"(sd {c['sd']:.4f}, 95% CI {ci}), median {c['median']:.4f}, "
          f"passes {c['mean_passes']:.1f}; ended by " + ", ".join(f"{k} {v:.0%}" for k, v in c["reasons"].items()))
    for name, b in result.get("baselines", {}).items():
        print(f"  {name:9s} on the same trials: mean fitness {b['mean_fitness']:.4f} (sd {b['sd']:.4f})")
    out = run_dir / "eval" / f"{target.sim.name}-{args.trials}-seed{seed}.json"
    out.parent.mkdir(exist_ok=True)
    outputs.write_json(out, result)  # atomically: a kill leaves the old figures or the new ones
    print(f"written: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
