"""``python -m kx.bench protocol --processes 1 2``: a fixed small slice of the Table 3 protocol run by one
process and by several (:mod:`kx.experiments.processes`), runs per hour for each.

The slice: NEAT, fitness transfer to 4v3, ``--protocol-runs`` runs a cell (their 3v2 sources and their targets),
``--protocol-generations`` generations a run, 100 test trials. Each process count runs the whole command
``python -m kx.experiments table3 ... --processes N`` in a fresh folder, timed from start to exit (process
start-up, joining, the runs, the merge and the report: what a user waits for), after an untimed run of
the same command on another protocol seed has filled the persistent compilation cache with its programs
(each process count batches other group sizes, so each warms its own). One process gets every core as
a host device; N processes share the cores, ``cores // N`` devices each. Every count's results.csv is
checked against one process's (every column but the times). The last line is the ratio of the largest
count to one process.
"""

from __future__ import annotations

import csv
import os
import pathlib
import subprocess
import sys
import tempfile
import time


def _slice(runs: int, generations: int, out: pathlib.Path) -> list[str]:
    return ["table3", "--runs", str(runs), "--methods", "neat", "--targets", "4v3", "--setups", "fitness",
            "--source-generations", str(generations), "--target-generations", str(generations),
            "--test-trials", "100", "--out", str(out)]


def _rows(out: pathlib.Path) -> dict:
    from kx.experiments import table3 as t3

    with (out / "results.csv").open() as f:
        return {t3.row_key(r): {k: r[k] for k in t3.REPRODUCED} for r in csv.DictReader(f)}


def run(args) -> None:
    counts = sorted(set(args.processes))
    if not counts or counts[0] < 1:
        raise SystemExit(f"--processes: allowed integers >= 1, got {args.processes}")
    runs, gens = args.protocol_runs, args.protocol_generations
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}  # each command sets its own devices
    print(f"cores: {os.cpu_count()}; slice: NEAT, fitness transfer 3v2 -> 4v3, {runs} runs a cell ({2 * runs} runs), "
          f"{gens} generations a run; process counts {counts}", flush=True)
    with tempfile.TemporaryDirectory(prefix="kx-bench-protocol-") as tmp:
        tmp = pathlib.Path(tmp)
        figures, first = {}, None
        for n in counts:
            warm = subprocess.run([sys.executable, "-m", "kx.experiments", *_slice(runs, gens, tmp / f"warm{n}"),
                                   "--seed", "1", "--processes", str(n)], env=env, capture_output=True, text=True)
            if warm.returncode:
                raise SystemExit(f"the warm-up slice of {n} processes failed: {(warm.stdout + warm.stderr)[-2000:]}")
            out = tmp / f"p{n}"
            t0 = time.perf_counter()
            res = subprocess.run([sys.executable, "-m", "kx.experiments", *_slice(runs, gens, out),
                                  "--processes", str(n)], env=env, capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if res.returncode:
                raise SystemExit(f"{n} processes failed: {(res.stdout + res.stderr)[-2000:]}")
            rows = _rows(out)
            same = "reference" if first is None else ("the same results" if rows == first else "DIFFERENT RESULTS")
            first = rows if first is None else first
            figures[n] = 3600 * len(rows) / wall
            print(f"{n} process{'es' if n > 1 else ''}: {len(rows)} runs in {wall:.1f} s, {figures[n]:.0f} runs/h "
                  f"({same})", flush=True)
    top = counts[-1]
    print("On one machine the processes share its cores, so the ratio measures what splitting the cores costs "
          "or saves; on a cluster each process brings its own cores or GPU, and the runs per hour add up to "
          "the slowest process's share (runs are dealt by run index, so the shares differ by at most one run a "
          "cell).")
    print(f"protocol: {figures[top]:.0f} runs/h at {top} processes (ratio {figures[top] / figures[counts[0]]:.2f} "
          f"vs {counts[0]} process{'es' if counts[0] > 1 else ''})")
