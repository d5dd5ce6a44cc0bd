"""The clustered test's level on null data resampled from a Table 3 transfer cell: the figures of docs/experiments.md,
"With few sources, the tails".

The cell's sources complete in every target are resampled whole (``--clusters`` of them; their targets' correlation
kept) against independent runs drawn from the same cell's runs target by target, ``--clusters`` a target: both sides
from one distribution, so every rejection is a false one. Prints the rejection rate of
kx.experiments.stats.clustered_z's test at each nominal level, per measure and number of sources.

    python scripts/cluster_level.py --method ppo --below 5      # PPO's five sources, as on 2026-12-07
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np

from kx.experiments import report, stats
from kx.experiments import table3 as t3

LEVELS = (0.05, 0.025, 0.0167, 0.01)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--results", default="docs/table3/results.csv", help="a Table 3 folder's results.csv")
    p.add_argument("--method", default="ppo", help=f"one of {sorted(t3.METHOD_NAMES)}")
    p.add_argument("--setup", default="fitness", help="a transfer setup of Table 3 (its runs share their sources)")
    p.add_argument("--below", type=int, default=None, help="keep only runs of index below this")
    p.add_argument("--clusters", default="5,6,10", help="sources a data set, comma-separated")
    p.add_argument("--sims", type=int, default=20000, help="data sets a case")
    args = p.parse_args(argv)
    if args.method not in t3.METHOD_NAMES:
        p.error(f"--method: allowed one of {sorted(t3.METHOD_NAMES)}, got {args.method!r}")
    if args.setup not in t3.SETUPS or t3.SETUPS[args.setup].source_objective is None:
        p.error(f"--setup: allowed a transfer setup, one of "
                f"{sorted(k for k, s in t3.SETUPS.items() if s.source_objective is not None)}, got {args.setup!r}")
    rows = [r for r in t3.read_results(pathlib.Path(args.results))
            if args.below is None or int(r["run"]) < args.below]
    for measure in report.MEASURES:
        runs = report._runs(rows, measure)
        real = stats.cluster_matrix([runs[(args.method, args.setup, t)] for t in t3.TARGETS], shared=True)
        real = real[np.all(~np.isnan(real), 1)]  # the sources complete in every target
        ind = stats.cluster_matrix([{i: v for i, v in enumerate(real[:, t])} for t in range(len(t3.TARGETS))],
                                   shared=False)
        print(f"{measure}: {len(real)} complete sources; rejection rate at nominal {', '.join(map(str, LEVELS))}")
        rng = np.random.default_rng(21)
        for k in (int(v) for v in args.clusters.split(",")):
            x = stats.resample_clusters(real, rng, args.sims, runs=None if k == len(real) else k)
            y = stats.resample_clusters(ind, rng, args.sims, runs=k)
            t, df = stats.clustered_z(x, y)
            pv = stats.clustered_p(t, df)
            print(f"  {k} sources: " + ", ".join(f"{float((pv < lv).mean()):.4f}" for lv in LEVELS))


if __name__ == "__main__":
    main()
