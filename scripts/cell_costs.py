"""What a protocol cell costs per run in one folder against others, and whether their rows agree:
``python scripts/cell_costs.py FOLDER OTHER [OTHER ...] [--scale ONE_RUN_FOLDER]``.

For each cell (method, phase, task, setup) of FOLDER's results.csv: its runs, the mean wall seconds per run
(each run's share of its batched group's time, as the report's Cost table) and per generation, and the same
for each OTHER folder's runs of that cell with the ratio OTHER / FOLDER; then how many of FOLDER's rows an
OTHER folder holds too (same method, setup, phase, target and run) and how many of those equal it in every
column but the two times (`kx.experiments.table3.REPRODUCED`).

``--scale ONE_RUN_FOLDER``: the full protocol (`kx.experiments.report.full_protocol_seconds`, 20 runs a
cell) costed from ONE_RUN_FOLDER's rows, and again with each method's sources and targets scaled by their
ratio of FOLDER's wall per run to ONE_RUN_FOLDER's over the cells both hold (the mean of FOLDER's runs of a
cell against ONE_RUN_FOLDER's runs of it, averaged over the method's cells of that phase). That assumes the
ratio measured on FOLDER's cells (batched groups of a full cell, compilation spread over its runs) holds in
the method's other cells of the phase; it is an estimate, printed as one.

``--versus METHOD:BASE``: METHOD's target generation against BASE's, cell by cell and pooled over each
task's setups (s per generation, each run's share of its group's time). Where FOLDER still holds the run
directories (a live protocol folder; committed ones hold only results.csv), that ratio is split in two:
the live steps a generation plays (how long the populations' episodes last, which is what they learned,
from each run's metrics.csv) times the seconds per live step (what the method costs per step of play).
There it also fits, per batched group, the group's seconds per generation (generations 1 on: generation 0
compiles) against the live steps its runs played, by least squares: a part each generation pays however long
its episodes last (METHOD's substrate build, ``tell``, validation, the host) and a cost per live step; and
prints what METHOD's generation would cost against BASE's if its live steps cost what BASE's do in that cell
(its own fixed part and live steps kept): the ratio left with a policy as cheap as BASE's.
"""

from __future__ import annotations

import argparse
import collections
import csv
import pathlib

import numpy as np

from kx.experiments import report
from kx.experiments import table3 as t3


def _cells(rows):
    out = collections.defaultdict(list)
    for r in rows:
        out[(r["method"], r["phase"], r["target"], r["setup"])].append(r)
    return out


def _per_run(rs):
    wall = float(np.mean([float(r["wall_seconds"]) for r in rs]))
    gens = float(np.mean([int(r["generations"]) for r in rs]))
    return wall, float(np.mean([float(r["generation_seconds"]) for r in rs])) / gens


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=pathlib.Path)
    p.add_argument("others", type=pathlib.Path, nargs="*")
    p.add_argument("--scale", type=pathlib.Path, help="a one-run-a-cell folder to scale to the full protocol")
    p.add_argument("--versus", metavar="METHOD:BASE", help="a method's target generation against another's")
    args = p.parse_args(argv)
    methods = set(t3.METHODS)
    if args.versus is not None:
        pair = args.versus.split(":")
        if len(pair) != 2 or not set(pair) <= methods:
            p.error(f"--versus: allowed METHOD:BASE with each of {sorted(methods)}, got {args.versus!r}")
    rows = t3.read_results(args.folder / "results.csv")
    others = {o: t3.read_results(o / "results.csv") for o in args.others}
    cells = _cells(rows)
    print("| cell | runs | wall s per run | s per generation | " + " | ".join(
        f"{o}: runs, wall s per run (ratio)" for o in others) + " |")
    print("|---|---|---|---|" + "---|" * len(others))
    other_cells = [_cells(orows) for orows in others.values()]
    for key, rs in sorted(cells.items()):
        wall, per_gen = _per_run(rs)
        line = f"| {' '.join(key)} | {len(rs)} | {wall:.1f} | {per_gen:.2f} |"
        for oc in other_cells:
            ors = oc.get(key)
            owall = _per_run(ors)[0] if ors else None
            line += " — |" if not ors else f" {len(ors)}, {owall:.1f} ({owall / wall:.2f}) |"
        print(line)
    for o, orows in others.items():
        index = {t3.row_key(r): r for r in orows}
        both = [(r, index[t3.row_key(r)]) for r in rows if t3.row_key(r) in index]
        same = sum(not t3.differences(b, a, t3.REPRODUCED) for a, b in both)
        print(f"{o}: {len(both)} of {len(rows)} rows held there too; {same} of them equal in every column but "
              "the times")
    if args.scale:
        one = t3.read_results(args.scale / "results.csv")
        ratios = collections.defaultdict(list)
        for key, rs in cells.items():
            ors = _cells(one).get(key)
            if ors:
                ratios[key[:2]].append(_per_run(rs)[0] / _per_run(ors)[0])
        factor = {k: float(np.mean(v)) for k, v in ratios.items()}
        base, _, _ = report.full_protocol_seconds(one)
        scaled = [dict(r, wall_seconds=float(r["wall_seconds"]) * factor.get((r["method"], r["phase"]), 1.0))
                  for r in one]
        est, _, _ = report.full_protocol_seconds(scaled)
        print(f"full protocol from {args.scale}: {base / 3600:.1f} h; each method's sources and targets scaled by "
              f"their ratio here ({', '.join(f'{m} {p} {f:.2f}' for (m, p), f in sorted(factor.items()))}; "
              f"1.0 without a cell here): {est / 3600:.1f} h (an estimate)")
    if args.versus:
        _versus(cells, *args.versus.split(":"))
        _versus_live_steps(args.folder, cells, *args.versus.split(":"))
        _versus_fit(args.folder, cells, *args.versus.split(":"))


def _compared(cells, method: str, base: str) -> list[tuple[str, str, list, list]]:
    """``(target, setup, method's rows, base's rows)`` of every target cell both methods ran, then of each
    task pooled over those setups (setup ``"every setup both ran"``)."""
    out, pooled = [], collections.defaultdict(lambda: ([], []))
    for (m, phase, target, setup), rs in sorted(cells.items()):
        other = cells.get((base, phase, target, setup))
        if m != method or phase != "target" or not other:
            continue
        pooled[target][0].extend(rs)
        pooled[target][1].extend(other)
        out.append((target, setup, rs, other))
    return out + [(target, "every setup both ran", rs, other) for target, (rs, other) in sorted(pooled.items())]


def _versus(cells, method: str, base: str) -> None:
    """Prints ``method``'s target generation against ``base``'s, cell by cell and pooled over each task."""
    def sums(rs):
        gens = sum(int(r["generations"]) for r in rs)
        return (sum(float(r["generation_seconds"]) for r in rs) / gens,
                sum(float(r["wall_seconds"]) for r in rs) / gens)
    print(f"\n| target | setup | {method} runs | {base} runs | {method} / {base}: s per generation "
          "(generations' own) | (wall) |")
    print("|---|---|---|---|---|---|")
    for target, setup, rs, other in _compared(cells, method, base):
        (g, w), (bg, bw) = sums(rs), sums(other)
        print(f"| {target} | {setup} | {len(rs)} | {len(other)} | {g / bg:.2f} | {w / bw:.2f} |")


def _live_steps(folder: pathlib.Path, row: dict) -> int | None:
    """The live steps of a row's run over all its generations (its run directory's metrics.csv), or None
    where the folder does not hold the run directory (a committed folder holds only results.csv)."""
    metrics = _metrics(folder, row)
    return None if metrics is None else sum(int(r["live_steps"]) for r in metrics)


def _metrics(folder: pathlib.Path, row: dict) -> list[dict] | None:
    spec = t3.RunSpec(row["method"], row["setup"], row["phase"], row["target"], int(row["run"]))
    path = t3.run_dir(folder, spec) / "metrics.csv"
    if not path.is_file():
        return None
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _groups(metrics: list[list[dict]]) -> list[list[list[dict]]]:
    """Runs grouped by the batched group they trained in: the runs of a group carry the same
    ``generation_seconds`` in every generation (one timer's readings, the group's), runs of different groups
    do not (two timers never read the same float for every generation)."""
    out = collections.defaultdict(list)
    for m in metrics:
        out[tuple(r["generation_seconds"] for r in m)].append(m)
    return list(out.values())


class _NoFit(Exception):
    pass


def _fit(group: list[list[dict]]) -> tuple[float, float, np.ndarray, np.ndarray]:
    """``(fixed seconds, seconds per live step, live steps, seconds)`` of a group's generations 1 on:
    least squares of the group's seconds per generation against the live steps its runs played."""
    gens = min(len(m) for m in group)
    live = np.array([sum(int(m[g]["live_steps"]) for m in group) for g in range(1, gens)], float)
    sec = np.array([float(group[0][g]["generation_seconds"]) for g in range(1, gens)])
    if len(live) < 2 or np.ptp(live) == 0:
        raise _NoFit("a fit needs two generations after the first with different live steps")
    (fixed, per_step), *_ = np.linalg.lstsq(np.stack([np.ones_like(live), live], 1), sec, rcond=None)
    return float(fixed), float(per_step), live, sec


def _totals(runs: int, fit) -> np.ndarray:
    """A fitted group's seconds, fixed seconds, seconds of its live steps (at its fitted cost per live step),
    live steps and run-generations over its generations 1 on; a sixth slot left 0 for the caller."""
    fixed, per_step, live, sec = fit
    return np.array([sec.sum(), fixed * len(live), per_step * live.sum(), live.sum(), runs * len(live), 0.0])


GOAL = 1.5  # the cost goal: a HyperNEAT 4v3 target generation at most 1.5 times a NEAT one


def _versus_fit(folder: pathlib.Path, cells, method: str, base: str) -> None:
    """Per cell and per group, METHOD's and BASE's fixed part and cost per live step (:func:`_fit`), then
    METHOD's seconds per generation against BASE's (generations 1 on) as measured and as it would be with
    BASE's cost per live step in that cell: each of METHOD's groups keeps its fixed part and its live steps.
    Then, pooled over each task's cells, both methods' fixed part and cost per live step, and the cost per
    live step METHOD would need for :data:`GOAL`, with its own fixed part and with BASE's. Prints nothing
    when some run directory of a compared cell is missing; says why when a group cannot be fitted."""
    compared = [c for c in _compared(cells, method, base) if c[1] != "every setup both ran"]
    metrics = {t3.row_key(r): _metrics(folder, r) for _, _, rs, other in compared for r in rs + other}
    if not compared or any(m is None for m in metrics.values()):
        return
    try:
        fitted = [(target, setup, {m: [(len(g), _fit(g)) for g in _groups([metrics[t3.row_key(r)] for r in runs])]
                                   for m, runs in ((method, rs), (base, other))})
                  for target, setup, rs, other in compared]
    except _NoFit as e:
        print(f"(no fit: {e})")
        return
    print(f"\n| target | setup | method | group: runs, fixed ms a run-generation, ns per live step | s per "
          f"run-generation | {method} / {base} | with {base}'s ns per live step |")
    print("|---|---|---|---|---|---|---|")
    # per (target, method): _totals, the sixth slot METHOD's seconds priced at BASE's cost per live step
    pooled = collections.defaultdict(lambda: np.zeros(6))
    for target, setup, fits in fitted:
        sums = {m: sum((_totals(n, f) for n, f in groups), np.zeros(6)) for m, groups in fits.items()}
        base_per_step = sums[base][2] / sums[base][3]
        sums[method][5] = sums[method][1] + base_per_step * sums[method][3]
        sec = {m: v[0] / v[4] for m, v in sums.items()}
        for m, groups in fits.items():
            desc = "; ".join(f"{n}, {f[0] / n * 1e3:.0f}, {f[1] * 1e9:.0f}" for n, f in groups)
            tail = (f"{sec[method] / sec[base]:.2f} | {sums[method][5] / sums[method][4] / sec[base]:.2f} |"
                    if m == method else "| |")
            print(f"| {target} | {setup} | {m} | {desc} | {sec[m]:.3f} | {tail}")
            pooled[target, m] += sums[m]
    for target in sorted({t for t, _ in pooled}):
        p, b = pooled[target, method], pooled[target, base]
        sec, b_sec = p[0] / p[4], b[0] / b[4]
        print(f"| {target} | every setup both ran | {method} | | {sec:.3f} | {sec / b_sec:.2f} | "
              f"{p[5] / p[4] / b_sec:.2f} |")
    for target in sorted({t for t, _ in pooled}):
        p, b = pooled[target, method], pooled[target, base]
        b_sec = b[0] / b[4]
        desc = {m: f"{m} {v[1] / v[4] * 1e3:.0f} ms a run-generation + {v[2] / v[3] * 1e9:.0f} ns per live step x "
                   f"{v[3] / v[4] / 1e6:.2f}M live steps" for m, v in ((method, p), (base, b))}
        need = [(GOAL * b_sec - fixed / p[4]) / (p[3] / p[4]) * 1e9 for fixed in (p[1], b[1] / b[4] * p[4])]
        print(f"{target}, pooled: {desc[method]}; {desc[base]}. For {method} / {base} = {GOAL}: {method}'s ns per "
              f"live step at most {need[0]:.0f} with its fixed part, {need[1]:.0f} with {base}'s.")


def _versus_live_steps(folder: pathlib.Path, cells, method: str, base: str) -> None:
    """:func:`_versus`'s ratio split in two, where the folder holds the run directories: the live steps a
    generation plays (how long the populations' episodes last: what they learned) times the seconds per
    live step (what the method's policy and its generation cost). The product is the s-per-generation
    ratio. Prints nothing when some run directory of a compared cell is missing."""
    compared = _compared(cells, method, base)
    steps = {t3.row_key(r): _live_steps(folder, r) for _, _, rs, other in compared for r in rs + other}
    if not compared or None in steps.values():
        return

    def sums(rs):
        gens = sum(int(r["generations"]) for r in rs)
        live = sum(steps[t3.row_key(r)] for r in rs)
        return live / gens, sum(float(r["generation_seconds"]) for r in rs) / live
    print(f"\n| target | setup | {method} / {base}: live steps per generation | s per live step | "
          "product: s per generation |")
    print("|---|---|---|---|---|")
    for target, setup, rs, other in compared:
        (live, sec), (b_live, b_sec) = sums(rs), sums(other)
        print(f"| {target} | {setup} | {live / b_live:.2f} | {sec / b_sec:.2f} | {live * sec / (b_live * b_sec):.2f} |")


if __name__ == "__main__":
    main()
