"""Writes tests/fixtures/run_dirs.json: what small runs of each method write to their run directories
(metrics rows but the execution columns, and a digest of every checkpoint's run state), for
tests/test_run_dir_fixture.py to compare the current code's run directories against.

The committed fixture was written by the code before the one generation step (commit 7cb4502, when
``Trainer.step`` and ``RunGroup.step`` were two implementations), with the test suite's XLA flags
(tests/conftest.py: they change what some programs compute in the last bit, e.g. the novelty k-NN and
HyperNEAT's substrate, so the fixture is the suite's), on a CPU with AVX-512::

    git worktree add /tmp/kx_before 7cb4502
    XLA_FLAGS="--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false \
        --xla_llvm_disable_expensive_passes=true" \
    PYTHONPATH=/tmp/kx_before python scripts/run_dir_fixture.py tests/fixtures/run_dirs.json

Floats rounded by vector instructions can differ on a CPU with other vector extensions: a fixture
records the CPU's (:func:`cpu_features`) and the XLA flags, and the test takes the fixture whose XLA flags
and extensions that decide the rounding (:data:`ROUNDING`: the vector width and fused multiply-add) are
this machine's. tests/fixtures/run_dirs_avx2.json was written by the same command, from the same commit,
on an AMD EPYC with AVX2 and FMA but no AVX-512 (2026-12-07): NEAT's and HyperNEAT's runs as on AVX-512,
CMA-ES's not (its eigendecomposition's OpenBLAS kernels: the Zen set OpenBLAS picks there and the Haswell set
an Intel CPU with AVX2 gets both reproduce it; ``OPENBLAS_CORETYPE=Sandybridge`` does not, and the test then
fails). Where neither fixture matches, the test skips,
saying why (write one there as above, to a new tests/fixtures/run_dirs_*.json).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import pathlib
import tempfile

REPO = pathlib.Path(__file__).resolve().parents[1]
#: the columns that describe how a generation was executed, not what it computed
EXECUTION = ("live_fraction", "eval_seconds", "evolve_seconds", "validation_seconds", "generation_seconds")
SMALL = ["trials=3", "validation_trials=6", "generations=3", "gif=false", "checkpoint_every=1", "keep_checkpoints=5",
         "sim.max_iterations=120"]
#: name -> (config file, overrides): tests/test_group.py's sizes, so that the test reuses their programs
RUNS = {
    "neat_hybrid": ("neat_3v2.py", ["population_size=12", "objective=hybrid", "seed=3", "neat.add_node_prob=0.3"]),
    "hyperneat": ("hyperneat_3v2.py", ["population_size=12", "seed=7"]),
    "cma_es_hybrid": ("cma_es_3v2.py", ["population_size=6", "objective=hybrid", "seed=0"]),
}


def cpu_features() -> list[str]:
    """The CPU's vector extensions that XLA CPU may use (from /proc/cpuinfo; empty where it is missing).

    Read here, not through ``kx.runtime.cpu_flags``: the fixture is written with an older ``kx`` on the path."""
    try:
        with open("/proc/cpuinfo") as f:
            flags = next(line for line in f if line.startswith("flags")).split()
    except (OSError, StopIteration):
        flags = []
    return sorted({f for f in flags if f.startswith(("avx", "fma", "sse4"))})


#: the extensions that decide how XLA CPU rounds float32 (vector width, fused multiply-add); the others
#: (sse4a, avx512_fp16, avx_vnni, ...) do not: the fixture written on an Intel CPU with AVX-512 (avx512_fp16,
#: avx_vnni) is reproduced bit for bit on this project's AMD CPU with AVX-512 (sse4a), 2026-12-04
ROUNDING = ("avx2", "avx512f", "fma")


def rounding_features(cpu: list[str]) -> list[str]:
    """Of a CPU's extensions (:func:`cpu_features`), those that decide how XLA CPU rounds float32."""
    return [f for f in ROUNDING if f in cpu]


def xla_flags() -> list[str]:
    import os

    return sorted(f for f in os.environ.get("XLA_FLAGS", "").split() if "device_count" not in f)


def digest(tree) -> str:
    import jax
    import numpy as np

    h = hashlib.sha256()
    for leaf in jax.tree.leaves(tree):
        a = np.asarray(jax.random.key_data(leaf) if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key) else leaf)
        h.update(str((a.shape, a.dtype.name)).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def record(run_dir: pathlib.Path) -> dict:
    """A run directory's metrics rows (execution columns aside, as written) and checkpoint digests."""
    from kx.evolve import checkpoint as ckpt
    from kx.evolve import run as run_lib

    with open(run_dir / "metrics.csv", newline="") as f:
        rows = [{k: v for k, v in r.items() if k not in EXECUTION} for r in csv.DictReader(f)]
    checkpoints = {str(s): digest(run_lib.restore(run_dir, s)[2]) for s in ckpt.steps(run_dir)}
    return {"rows": rows, "checkpoints": checkpoints}


def write_run(name: str, run_dir: pathlib.Path) -> dict:
    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib

    config, overrides = RUNS[name]
    cfg = cfg_lib.load(REPO / "configs" / config, [*SMALL, *overrides])
    run_lib.train(cfg, run_dir, log=lambda _: None)
    return record(run_dir)


def main(out: str) -> None:
    from kx import runtime

    runtime.setup()
    with tempfile.TemporaryDirectory() as tmp:
        got = {name: {"config": RUNS[name][0], "overrides": [*SMALL, *RUNS[name][1]],
                      **write_run(name, pathlib.Path(tmp) / name)} for name in RUNS}
    got = {"cpu": cpu_features(), "xla_flags": xla_flags(), "runs": got}
    pathlib.Path(out).write_text(json.dumps(got, indent=1) + "\n")
    print(f"wrote {out}: {', '.join(got)}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="?", default=str(REPO / "tests" / "fixtures" / "run_dirs.json"),
                        help="the fixture to write (default: tests/fixtures/run_dirs.json)")
    main(parser.parse_args().out)
