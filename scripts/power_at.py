"""Power of the primary comparisons of a Table 3 folder at a chosen number of runs a cell: the figures behind
extending cells past the protocol's 20 runs (docs/experiments.md, "The whole protocol").

Each comparison of the primary family, per measure: the pooled test's p over the targets with the runs as they
are, and the probability of p < ALPHA / (the family's size) in the observed direction with every cell's clusters
resampled to ``--runs`` (kx.experiments.stats.clustered_power, the report's estimate; the folder's sources
shared or not as its protocol.json says). ``--below K`` keeps only the runs of index < K, to see the folder as it
was at K runs a cell. ``--first-design``: the first design's test instead (van Elteren's with the targets as
independent strata, kx.experiments.stats.power), which gave the figures the extension of docs/table3 was chosen
by (docs/experiments.md).

    python scripts/power_at.py --runs 35 --below 20     # the look at 20 runs a cell, projected to 35
    python scripts/power_at.py --runs 35 --below 20 --first-design
    python scripts/power_at.py --runs 50
"""

from __future__ import annotations

import argparse
import csv
import pathlib

import numpy as np

from kx.experiments import design, report, stats
from kx.experiments.table3 import TARGETS


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--results", default="docs/table3/results.csv", help="a Table 3 folder's results.csv")
    p.add_argument("--runs", type=int, default=design.EXTEND_UP_TO, help="runs a cell to project to")
    p.add_argument("--below", type=int, default=None, help="keep only runs of index below this")
    p.add_argument("--first-design", action="store_true",
                   help="van Elteren's test with independent strata (the first design's), not the clustered one")
    args = p.parse_args(argv)
    if args.runs < 2:
        p.error(f"--runs: allowed an integer >= 2, got {args.runs}")
    rows = [r for r in csv.DictReader(pathlib.Path(args.results).open())
            if r["phase"] == "target" and (args.below is None or int(r["run"]) < args.below)]
    dsg = design.of_folder(pathlib.Path(args.results).parent)
    level = design.ALPHA / len(design.PRIMARY)

    def cell(method, setup, target, measure):
        return np.array([float(r[measure]) for r in rows
                         if (r["method"], r["setup"], r["target"]) == (method, setup, target)])

    print(f"| measure | comparison | runs a cell | p | power now | power at {args.runs} |")
    print("|---|---|---|---|---|---|")
    for measure in design.MEASURES:
        for c in design.PRIMARY:
            a = [cell(*c.a, t, measure) for t in TARGETS]
            b = [cell(*c.b, t, measure) for t in TARGETS]
            if not all(x.size and y.size for x, y in zip(a, b)):
                continue
            low, high = min(x.size for x in a + b), max(x.size for x in a + b)
            if args.first_design:
                test = stats.van_elteren(a, b)
                d = int(np.sign(test.z))
                now = stats.power(a, b, level, direction=d)
                then = stats.power(a, b, level, runs=args.runs, direction=d)
            else:
                runs_by = report._runs(rows, measure)
                xa, xb = (report._matrix(runs_by, cell_, list(TARGETS), dsg) for cell_ in (c.a, c.b))
                test = stats.clustered_van_elteren(xa, xb)
                d = int(np.sign(test.z))
                now = stats.clustered_power(xa, xb, level, direction=d)
                then = stats.clustered_power(xa, xb, level, runs=args.runs, direction=d)
            runs = str(low) if low == high else f"{low}-{high}"
            print(f"| {measure} | {c.key} | {runs} | {test.p:.4f} | {now:.0%} | {then:.0%} |")


if __name__ == "__main__":
    main()
