"""How fast this machine trains a protocol's runs against the machine that recorded them:
``python scripts/machine_speed.py FOLDER RECORDED_RESULTS_CSV``.

When a protocol folder is continued from its results.csv alone (a fresh clone, another machine), ``kx.experiments
table3`` first trains again the sources whose targets are still to run, in the same batched groups as before,
and checks that they reproduce their rows. Those runs are then timed twice, on two machines, on the same
episodes: the run directories of FOLDER hold this machine's times (metrics.csv's ``generation_seconds``, the
time of the group the run trained in, each generation), RECORDED_RESULTS_CSV the recorded ones (each row's
``generation_seconds``, its 1/R share of its group's generations). Give it the results file as it was before
this machine added rows (``git show COMMIT:docs/results/protocol_full/results.csv > FILE``), so that only runs
trained on both machines are compared.

For each batched group (the runs of a cell whose metrics.csv have the same ``generation_seconds``): its runs,
the recorded seconds (the sum of its rows' shares) and this machine's (the group's generations), and their
ratio; then all groups pooled. A ratio above 1 means this machine is faster. Both sides count compilation
(each process compiled its programs), and both assume nothing else shared the machine.
"""

from __future__ import annotations

import argparse
import collections
import csv
import pathlib
import sys

from kx.experiments import table3 as t3


def groups(folder: pathlib.Path, recorded: list[dict]) -> list[tuple[tuple, list[int], float, float]]:
    """The batched groups of ``recorded``'s runs that ``folder`` trained again: (cell key, runs, recorded
    seconds, seconds here), in the cells' order."""
    by_cell = collections.defaultdict(dict)
    for r in recorded:
        spec = t3.RunSpec(r["method"], r["setup"], r["phase"], r["target"], int(r["run"]))
        path = t3.run_dir(folder, spec) / "metrics.csv"
        if not path.is_file():
            continue
        with path.open(newline="") as f:
            seconds = tuple(float(m["generation_seconds"]) for m in csv.DictReader(f))
        if len(seconds) != int(r["generations"]):
            continue  # not a finished run (a resumption, a kill): no whole group to time
        by_cell[spec.key[:4]].setdefault(seconds, []).append((spec.run, float(r["generation_seconds"])))
    out = []
    for cell, by_seconds in sorted(by_cell.items()):
        for seconds, runs in sorted(by_seconds.items(), key=lambda kv: min(run for run, _ in kv[1])):
            out.append((cell, sorted(run for run, _ in runs), sum(share for _, share in runs), sum(seconds)))
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=pathlib.Path, help="a protocol folder with run directories trained here")
    p.add_argument("recorded", type=pathlib.Path, help="the results.csv that recorded those runs elsewhere")
    args = p.parse_args(argv)
    if not args.recorded.is_file():
        p.error(f"recorded: no results file at {args.recorded}")
    found = groups(args.folder, t3.read_results(args.recorded))
    if not found:
        sys.exit(f"machine_speed: no run of {args.recorded} has a finished run directory under {args.folder}/runs")
    print("| cell | runs | recorded s | s here | recorded / here |")
    print("|---|---|---|---|---|")
    for cell, runs, rec, here in found:
        contiguous = len(runs) > 1 and runs == list(range(runs[0], runs[-1] + 1))
        span = f"{runs[0]}-{runs[-1]}" if contiguous else ",".join(map(str, runs))
        print(f"| {' '.join(map(str, cell))} | {span} | {rec:.1f} | {here:.1f} | {rec / here:.2f} |")
    rec, here = sum(g[2] for g in found), sum(g[3] for g in found)
    ratios = [g[2] / g[3] for g in found]
    print(f"machine speed: {rec / here:.2f} x the recording machine ({len(found)} groups, "
          f"{sum(len(g[1]) for g in found)} runs; {min(ratios):.2f}-{max(ratios):.2f} by group)")


if __name__ == "__main__":
    main()
