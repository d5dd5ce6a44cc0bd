"""Stagnation in transferred hybrid runs: species culled per generation and the fate of the fittest lineage.

A 3v2 NEAT source run on the novelty hybrid (the default config, ``objective = "hybrid"``) seeds 4v3
target runs (``configs/neat_4v3.py``: 50 generations, the hybrid objective, the whole population), one per
seed. Every generation's ``tell`` is watched from outside the learner, so the script measures any
version of kx the same way::

    PYTHONPATH=<a kx checkout> python scripts/stagnation.py --out results.jsonl [--seeds 3] [--generations 50]
    python scripts/stagnation.py --table before.jsonl after.jsonl      # the table of docs/neat.md

One JSON line per target generation: the species alive, those stagnant (culled: no offspring for
stagnation), whether the species holding the generation's fittest genome (by raw task fitness) was
culled or left without offspring, the species' sizes, and the run's raw fitness; a last line per seed
gives the validated champion on 1000 test states of the target. ``--source`` reuses a source run
directory.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import tempfile
import time

from kx import runtime


def table(paths: list[str]) -> str:
    """One row per JSONL file: species culled per generation, generations whose fittest genome's species
    was left without offspring, and the validated champions on the target's test states."""
    import numpy as np

    lines = ["| results | seeds | species alive | culled per generation | culled, generations 16-50 | "
             "fittest genome's species left without offspring | test fitness, mean (sd) |",
             "|---|---|---|---|---|---|---|"]
    for path in paths:
        recs = [json.loads(line) for line in pathlib.Path(path).read_text().splitlines()]
        gens = [r for r in recs if r["kind"] == "generation"]
        tests = np.array([r["test"] for r in recs if r["kind"] == "test"])
        late = [r["stagnant_species"] for r in gens if r["generation"] >= 15]
        lost = sum(r["fittest_species_stagnant_or_empty"] for r in gens)
        sd = tests.std(ddof=1) if tests.size > 1 else 0.0
        lines.append(f"| {pathlib.Path(path).name} | {tests.size} | {np.mean([r['n_species'] for r in gens]):.1f} | "
                     f"{np.mean([r['stagnant_species'] for r in gens]):.2f} | {np.mean(late):.2f} | "
                     f"{lost} of {len(gens)} | {tests.mean():.4f} ({sd:.4f}): "
                     f"{' '.join(f'{t:.3f}' for t in tests)} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--table", nargs="+", default=None, metavar="JSONL", help="print the table of these files")
    p.add_argument("--out", help="JSONL file (appended to; seeds already in it are skipped)")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--generations", type=int, default=50)
    p.add_argument("--source", default="", help="a 3v2 hybrid source run directory (default: train one)")
    p.add_argument("--source-generations", type=int, default=20)
    p.add_argument("--test-trials", type=int, default=1000)
    args = p.parse_args()
    if args.table:
        print(table(args.table))
        return
    if not args.out:
        p.error("--out: required (or --table)")
    runtime.setup()

    import jax
    import numpy as np

    import kx
    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib
    from kx.evolve import streams
    from kx.evolve.encoding import stack
    from kx.sim import env

    out = pathlib.Path(args.out)
    done = set()
    if out.exists():
        for line in out.read_text().splitlines():
            rec = json.loads(line)
            if rec.get("kind") == "test":
                done.add(rec["seed"])
    source = args.source
    if not source:
        source = str(pathlib.Path(tempfile.mkdtemp(prefix="kx-stag-src-")) / "source")
        cfg = cfg_lib.load(None, ["gif=false", "objective=hybrid", "seed=0",
                                  f"generations={args.source_generations}"])
        run_lib.train(cfg, source, log=lambda s: None)
    print(f"kx from {kx.__file__}; source {source}", flush=True)
    for seed in range(args.seeds):
        if seed in done:
            continue
        cfg = cfg_lib.load("configs/neat_4v3.py", ["gif=false", "objective=hybrid", f"seed={seed}",
                                                   f"generations={args.generations}", f"transfer.source={source}"])
        trainer = run_lib.Trainer(cfg)
        enc = trainer.encoding
        tell = enc.tell
        records = []

        def watched(key, population, score, fitness, state, tell=tell, records=records):
            sp = np.asarray(state.species)
            f = np.asarray(fitness)
            slot = int(sp[int(np.argmax(f))])
            new_state, m = tell(key, population, score, fitness, state)
            records.append({"slot": slot, "m": m})
            return new_state, m

        enc.tell = watched
        t0 = time.perf_counter()
        state, rows = run_lib.evolve_in_memory(trainer)
        with out.open("a") as fh:
            for row, rec in zip(rows, records):
                m = jax.tree.map(np.asarray, rec["m"])
                slot = rec["slot"]
                sizes = m["species_sizes"]
                fh.write(json.dumps({
                    "kind": "generation", "seed": seed, "generation": int(row["generation"]),
                    "n_species": int(m["n_species"]), "stagnant_species": int(m["stagnant_species"]),
                    "fittest_species_stagnant_or_empty": bool(int(m["offspring"][slot]) == 0),
                    "fittest_species_size": int(sizes[slot]), "best_fitness": float(row["best_fitness"]),
                    "mean_fitness": float(row["mean_fitness"]), "best_validation": float(row["best_validation"]),
                    "mean_novelty": float(row.get("mean_novelty", float("nan"))),
                }) + "\n")
            keys = streams.test(2026)
            starts = env.reset_batch(keys.starts, args.test_trials, trainer.exp.sim_params, trainer.exp.sim)
            test = float(trainer.evaluate(stack([state.champion]), starts, keys.eval).fitness.mean())
            fh.write(json.dumps({"kind": "test", "seed": seed, "test": test,
                                 "champion_generation": int(state.champion_generation),
                                 "seconds": time.perf_counter() - t0}) + "\n")
        n_stag = [int(np.asarray(r["m"]["stagnant_species"])) for r in records]
        lost = sum(int(np.asarray(r["m"]["offspring"])[r["slot"]]) == 0 for r in records)
        print(f"seed {seed}: culled {np.mean(n_stag):.2f} species/generation, fittest species left without "
              f"offspring in {lost}/{len(records)} generations, test {test:.4f} ({time.perf_counter() - t0:.0f} s)",
              flush=True)
        del trainer, state


if __name__ == "__main__":
    main()
