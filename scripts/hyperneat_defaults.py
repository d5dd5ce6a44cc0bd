"""HyperNEAT's defaults measured over seeds: image (paper, authors) x distance input (off, on).

Each cell trains ``configs/hyperneat_3v2.py`` (3v2, 150 CPPNs x 20 generations of 30 trials) with
``hyperneat.image`` and ``hyperneat.distance_input`` set, over seeds ``0..N-1``, through the run loop
of ``python -m kx.train`` (no run directory), and plays each run's validated champion on the same 1000
test states as ``python -m kx.bench learning`` (the test stream of seed 2026, which no run trains or
validates on) and, unchanged, on the test states of 4v3, 5v3 and 6v4::

    python scripts/hyperneat_defaults.py --out docs/results/hyperneat_defaults.jsonl [--seeds 5]
    python scripts/hyperneat_defaults.py --out docs/results/hyperneat_defaults.jsonl --table

One JSON line per run, appended as it ends (a cell and seed already in the file is skipped, so an
interrupted sweep resumes). ``--table`` prints the Markdown table of docs/hyperneat.md from the file:
the mean, standard deviation and standard error of each cell's test fitness, and each cell against
the best one by Welch's t-test (scipy).
"""

from __future__ import annotations

import argparse
import itertools
import json
import pathlib
import time

from kx import runtime

CELLS = tuple(itertools.product(("paper", "authors"), (False, True)))
TEST_SEED = 2026


def _read(path: pathlib.Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def table(records: list[dict]) -> str:
    import numpy as np
    from scipy import stats

    by = {c: np.array([r["test"] for r in records if (r["image"], r["distance_input"]) == c]) for c in CELLS}
    by = {c: v for c, v in by.items() if v.size}
    best = max(by, key=lambda c: by[c].mean())
    lines = ["| image | distance input | seeds | test fitness, mean (sd) | s.e. | 4v3 | 5v3 | 6v4 "
             "| vs best (Welch p) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c, v in by.items():
        rs = [r for r in records if (r["image"], r["distance_input"]) == c]
        zs = {t: np.mean([r["zero_shot"][t] for r in rs]) for t in ("4v3", "5v3", "6v4")}
        p = "best" if c == best else f"{stats.ttest_ind(v, by[best], equal_var=False).pvalue:.3f}"
        sd = v.std(ddof=1) if v.size > 1 else 0.0
        lines.append(f"| {c[0]} | {'on' if c[1] else 'off'} | {v.size} | {v.mean():.4f} ({sd:.4f}) | "
                     f"{sd / np.sqrt(v.size):.4f} | {zs['4v3']:.4f} | {zs['5v3']:.4f} | {zs['6v4']:.4f} | {p} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="JSONL file, appended to (runs already in it are skipped)")
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--test-trials", type=int, default=1000)
    p.add_argument("--table", action="store_true", help="print the table of --out and stop")
    args = p.parse_args()
    out = pathlib.Path(args.out)
    if args.table:
        print(table(_read(out)))
        return
    runtime.setup()


    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib
    from kx.evolve import streams
    from kx.evolve.encoding import stack
    from kx.sim import env
    from kx.sim import evaluate as ev
    from kx.sim.types import KeepAwayConfig

    done = {(r["image"], r["distance_input"], r["seed"]) for r in _read(out)}
    keys = streams.test(TEST_SEED)
    out.parent.mkdir(parents=True, exist_ok=True)
    tests = {}
    for seed in range(args.seeds):  # seed-major: every cell gets its first seeds before any gets its last
        for image, dist in CELLS:
            if (image, dist, seed) in done:
                continue
            t0 = time.perf_counter()
            cfg = cfg_lib.load("configs/hyperneat_3v2.py", ["gif=false", f"seed={seed}", f"hyperneat.image={image}",
                                                            f"hyperneat.distance_input={dist}"])
            trainer = run_lib.Trainer(cfg)
            state, _ = run_lib.evolve_in_memory(trainer)
            enc, params = trainer.encoding, trainer.exp.sim_params
            if not tests:
                for task in ("3v2", "4v3", "5v3", "6v4"):
                    sim = KeepAwayConfig.from_task(task, field_size=trainer.exp.sim.field_size,
                                                   agent_speed=trainer.exp.sim.agent_speed,
                                                   ball_speed=trainer.exp.sim.ball_speed,
                                                   n_chasers=trainer.exp.sim.n_chasers)
                    tests[task] = (sim, env.reset_batch(keys.starts, args.test_trials, params, sim))
            champ = enc.policy_params(stack([state.champion]))
            fit = {t: float(ev.evaluate(enc.policy_for(sim), champ, starts, params, sim, key=keys.eval).fitness.mean())
                   for t, (sim, starts) in tests.items()}
            rec = {"image": image, "distance_input": dist, "seed": seed, "test": fit["3v2"],
                   "zero_shot": {t: fit[t] for t in ("4v3", "5v3", "6v4")},
                   "champion_generation": int(state.champion_generation),
                   "validation": float(state.champion_validation), "seconds": time.perf_counter() - t0,
                   "test_trials": args.test_trials}
            with out.open("a") as fh:
                fh.write(json.dumps(rec) + "\n")
            print(f"image {image}, distance input {dist}, seed {seed}: test {fit['3v2']:.4f} "
                  f"(4v3 {fit['4v3']:.4f}, 5v3 {fit['5v3']:.4f}, 6v4 {fit['6v4']:.4f}; {rec['seconds']:.0f} s)",
                  flush=True)
            del trainer, state
    print(table(_read(out)))


if __name__ == "__main__":
    main()
