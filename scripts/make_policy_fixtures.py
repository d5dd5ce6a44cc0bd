"""Trained 4v3 populations for ``python -m kx.bench policies``: ``kx/bench/data/policies/<method>_4v3.npz``.

``python scripts/make_policy_fixtures.py [--methods neat,hyperneat] [--target-generations 5]``

For NEAT (``configs/neat_3v2.py`` then ``configs/neat_4v3.py``; seed 0, 15 source generations) and HyperNEAT
(``configs/hyperneat_3v2.py`` then ``configs/hyperneat_4v3.py``; seed 1, 20 source generations), each with
its defaults (population 150, 30 trials): a 3v2 source run, then a 4v3 run seeded with the source's whole
final population (``transfer.source``) and trained ``--target-generations`` generations, both through
``kx.evolve.run.train`` in a temporary directory. HyperNEAT learns later than NEAT: its seed 0 validated
0.006 after 15 generations (its 4v3 population then played episodes as short as always-hold's), seed 1
about 0.67 after 20 (docs/hyperneat.md); ``--seed`` and ``--source-generations`` override both.

The fixture is the population the 4v3 run would evaluate next (its learner's ``ask`` of generation
``--target-generations``): the genomes, each field of :class:`kx.neat.types.Genome` an array of the npz with
a leading axis of 150, and ``meta`` (a JSON string) saying how it was made. HyperNEAT's genomes are CPPNs;
the benchmark builds their substrate table from them (``encoding.policy_params``), as the run loop does.
About 10 KB each.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import tempfile
import time

from kx import runtime

OUT = pathlib.Path(__file__).resolve().parent.parent / "kx" / "bench" / "data" / "policies"
CONFIGS = {"neat": ("configs/neat_3v2.py", "configs/neat_4v3.py"),
           "hyperneat": ("configs/hyperneat_3v2.py", "configs/hyperneat_4v3.py")}
DEFAULTS = {"neat": (0, 15), "hyperneat": (1, 20)}  # (seed, source generations)


def make(method: str, args, tmp: pathlib.Path) -> pathlib.Path:
    import jax
    import numpy as np

    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib
    from kx.evolve import streams

    src_path, dst_path = CONFIGS[method]
    seed, source_generations = DEFAULTS[method]
    seed = seed if args.seed is None else args.seed
    source_generations = source_generations if args.source_generations is None else args.source_generations
    common = [f"seed={seed}", "gif=false", "checkpoint_every=1000"]
    src_dir, dst_dir = tmp / f"{method}_3v2", tmp / f"{method}_4v3"
    t0 = time.perf_counter()
    src_cfg = cfg_lib.load(src_path, common + [f"generations={source_generations}"])
    src_row = run_lib.train(src_cfg, src_dir, log=lambda s: None)
    dst_cfg = cfg_lib.load(dst_path, common + [f"generations={args.target_generations}",
                                               f"transfer.source={src_dir}"])
    dst_row = run_lib.train(dst_cfg, dst_dir, log=lambda s: None)
    trainer = run_lib.Trainer(dst_cfg)
    step, state, _ = trainer.restore(dst_dir)
    population, _ = trainer.encoding.ask(streams.learner_ask(seed, step), state.learner)
    population = jax.device_get(population)
    meta = {"method": method, "source_config": src_path, "target_config": dst_path, "seed": seed,
            "source_generations": source_generations, "target_generations": args.target_generations,
            "generation": step, "population_size": int(dst_cfg.population_size),
            "source_best_validation": src_row["best_validation"],
            "target_last_mean_fitness": dst_row["mean_fitness"], "target_best_validation": dst_row["best_validation"],
            "made_by": "scripts/make_policy_fixtures.py"}
    fields = {f: np.asarray(getattr(population, f)) for f in population.__dataclass_fields__}
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / f"{method}_4v3.npz"
    np.savez_compressed(path, meta=np.asarray(json.dumps(meta)), **fields)
    print(f"{method}: {path} ({path.stat().st_size / 1e3:.0f} KB); {json.dumps(meta)}; "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default="neat,hyperneat")
    ap.add_argument("--source-generations", type=int, default=None)
    ap.add_argument("--target-generations", type=int, default=5)
    ap.add_argument("--seed", type=int, default=None)
    args = ap.parse_args()
    runtime.setup()
    with tempfile.TemporaryDirectory() as tmp:
        for method in args.methods.split(","):
            make(method, args, pathlib.Path(tmp))


if __name__ == "__main__":
    main()
