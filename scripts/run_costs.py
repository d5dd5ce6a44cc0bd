"""Where each run of a protocol folder spent its generations: ``python scripts/run_costs.py FOLDER [--out CSV]``.

Reads the run directories under ``FOLDER/runs`` (they stay on the machine that trained them; results.csv
alone does not hold this) and writes one row per run: its method, phase, setup and task, generations,
and the means over its generations after the first (which compiles) of the population's mean fitness, the
live episode-steps, the evaluation (policies' parameters built and every episode played), evolution and
validation seconds and the whole generation's, and the evaluation's nanoseconds per live step. A run trained
in a batched group records its group's times in metrics.csv; its seconds here are its share of them (the
group's divided by ``share``, the group's size times the local processes, read off results.csv: the sum of
the metrics' generation times over the row's ``generation_seconds``). Default output:
``FOLDER/run_costs.csv``."""

from __future__ import annotations

import argparse
import csv
import pathlib

import numpy as np

FIELDS = ("mean_fitness", "live_steps", "eval_seconds", "evolve_seconds", "validation_seconds", "generation_seconds")


def rows(folder: pathlib.Path) -> list[dict]:
    from kx.experiments import table3 as t3

    out = []
    # each run's generation_seconds as results.csv charges it (its share of its group's); none without the file
    charged = {t3.row_key(r): float(r["generation_seconds"]) for r in t3.read_results(folder / "results.csv")}
    for metrics in sorted(folder.glob("runs/*/*/*/run*/metrics.csv")):
        method, kind, task, run = metrics.parts[-5:-1]
        phase, setup = kind.split("-", 1)
        with metrics.open() as f:
            table = list(csv.DictReader(f))
        later = table[1:] or table
        key = (method, setup, phase, task, int(run[3:]))  # table3.row_key's order
        total = sum(float(r["generation_seconds"]) for r in table)
        share = max(1, round(total / charged[key])) if charged.get(key) else 1
        row = {"method": method, "phase": phase, "setup": setup, "task": task, "run": int(run[3:]),
               "generations": len(table), "share": share}
        for k in FIELDS:
            per = 1 if k in ("mean_fitness", "live_steps") else share  # seconds: the run's share of its group's
            row[k] = float(np.mean([float(r[k]) for r in later])) / per
        row["eval_ns_per_live_step"] = row["eval_seconds"] / max(row["live_steps"], 1) * 1e9
        out.append(row)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=pathlib.Path)
    p.add_argument("--out", type=pathlib.Path)
    args = p.parse_args()
    table = rows(args.folder)
    if not table:
        raise SystemExit(f"{args.folder}: no run directories with metrics.csv under runs/")
    out = args.out or args.folder / "run_costs.csv"
    with out.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(table[0]))
        w.writeheader()
        for r in table:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    print(f"{out}: {len(table)} runs")


if __name__ == "__main__":
    main()
