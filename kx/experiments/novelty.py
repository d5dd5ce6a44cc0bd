"""The novelty hybrid's readings measured over seeds: ``python -m kx.experiments novelty --out docs/novelty``.

Over 450 lines because it holds one study whole, its runs and its report: apart, the arms' definitions would sit
away from the comparisons that read them.

Each *arm* is one reading of the hybrid, or fitness alone (the reference), run as a Table 3 protocol of its
own in ``OUT/<arm>/`` (:mod:`kx.experiments.table3`: the same seeding rule, test states and measures, so
an arm's run ``i`` plays the training states of Table 3's run ``i`` of its cell): its 3v2 sources of 20
generations and, for the weights, their fitness + NS transfers to 4v3 of 50 generations. The arms
(:data:`ARMS`; docs/novelty.md gives each reading's source):

* ``fitness``: fitness alone (``objective = fitness``), Table 3's fitness sources;
* ``rho-1.0``, ``rho-0.6``, ``rho-0.5``, ``rho-0.4``, ``rho-0.0``: the hybrid at that weight on fitness
  (1.0: min-max-normalised fitness alone; 0.6 the authors' intended weight; 0.5 their NEAT arm's; 0.4 the
  paper's Equation 1, kx's default, Table 3's hybrid; 0.0 pure novelty, their HyperNEAT arm's);
* ``fixed``, ``authors-archive``, ``authors-behaviour``: the paper's weight with fixed-bound
  normalisation, the authors' archive rule, the authors' behaviour vector: sources only.

The ``fitness`` and ``rho-0.4`` arms are Table 3's configs: their sources are trained here again (for the
diagnostics, which Table 3's results files do not keep) and must be Table 3's rows, and their 4v3
transfers are Table 3's own cells (``fitness`` and ``novelty``), read from its results.csv.

Besides each arm's results.csv (one row per run, :data:`kx.experiments.table3.FIELDS`) the runs' per-generation
diagnostics go to ``OUT/<arm>/diagnostics.csv`` (:data:`DIAGNOSTICS`): the population's behaviour spread,
the archive, and whether the generation's fittest genome breeds. :func:`write_report` makes
``OUT/report.md`` and its PNGs from these files alone.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import pathlib
from typing import Callable

import numpy as np

from kx.evolve import outputs as run_outputs
from kx.evolve.errors import RunError
from kx.experiments import csvfile, design, processes, report, stats
from kx.experiments import table3 as t3


@dataclasses.dataclass(frozen=True)
class Arm:
    name: str
    label: str
    overrides: tuple[str, ...]  # config overrides of every run of the arm
    objective: str  # the sources' objective: "fitness" or "hybrid"
    transfer: str | None  # its 4v3 transfers: "here" (run in its folder), "table3" (Table 3's cell), None


ARMS = {a.name: a for a in (
    Arm("fitness", "fitness alone", (), "fitness", "table3"),
    Arm("rho-1.0", "hybrid, rho 1.0 (normalised fitness alone)", ("novelty.rho=1.0",), "hybrid", "here"),
    Arm("rho-0.6", "hybrid, rho 0.6 (the authors' intended weight)", ("novelty.rho=0.6",), "hybrid", "here"),
    Arm("rho-0.5", "hybrid, rho 0.5 (the authors' NEAT arm)", ("novelty.rho=0.5",), "hybrid", "here"),
    Arm("rho-0.4", "hybrid, rho 0.4 (the paper's; Table 3's)", (), "hybrid", "table3"),
    Arm("rho-0.0", "pure novelty, rho 0 (the authors' HyperNEAT arm)", ("novelty.rho=0.0",), "hybrid", "here"),
    Arm("fixed", "rho 0.4, fixed-bound normalisation", ("novelty.normalisation=fixed",), "hybrid", None),
    Arm("authors-archive", "rho 0.4, the authors' archive rule", ("novelty.archive_rule=authors",), "hybrid", None),
    Arm("authors-behaviour", "rho 0.4, the authors' behaviour vector", ("novelty.behaviour=authors",), "hybrid",
        None),
)}
METHODS = ("neat", "hyperneat")
REFERENCE = "fitness"
#: the Table 3 setup of a "table3" arm's 4v3 transfers
TABLE3_SETUP = {"fitness": "fitness", "rho-0.4": "hybrid"}
TARGET = "4v3"
#: diagnostics.csv's columns: one row per generation of every run (empty where a column does not apply)
KEY = ("method", "setup", "phase", "target", "run")
DIAGNOSTICS = KEY + ("generation", "best_fitness", "mean_fitness", "behaviour_spread", "n_species",
                     "fittest_offspring", "fittest_elite", "archive_size", "archive_added", "mean_novelty")


#: the protocol every arm extends: Table 3's (the same generations, test states and seeds)
TABLE3 = t3.Protocol()


def protocol(arm: Arm, base: t3.Protocol = TABLE3) -> t3.Protocol:
    """The arm's protocol: ``base`` (Table 3's by default) with the arm's overrides after its own."""
    return dataclasses.replace(base, overrides=tuple(base.overrides) + arm.overrides)


def specs(arm: Arm, method: str, phase: str, runs: int, target_runs: int) -> list[t3.RunSpec]:
    """The runs of ``arm`` for ``method`` in ``phase``: ``runs`` 3v2 sources, or ``target_runs`` 4v3 transfers
    (none for an arm whose transfers are Table 3's or that has none)."""
    if phase == "source":
        return [t3.RunSpec(method, arm.objective, "source", t3.SOURCE_TASK, i) for i in range(runs)]
    if arm.transfer != "here":
        return []
    return [t3.RunSpec(method, "hybrid", "target", TARGET, i) for i in range(target_runs)]


# ------------------------------------------------------------------------------------------- diagnostics

def read_diagnostics(path: pathlib.Path) -> list[dict]:
    return csvfile.read(path, DIAGNOSTICS, "kx novelty diagnostics file", t3.ALIASES)


def diagnostics_of(spec: t3.RunSpec, metrics: list[dict]) -> list[dict]:
    """diagnostics.csv's rows of one run from its metrics.csv rows."""
    key = dict(zip(KEY, spec.key))
    return [{**key, **{c: r.get(c, "") or "" for c in DIAGNOSTICS[len(KEY):]}} for r in metrics]


def update_diagnostics(folder: pathlib.Path, arm: Arm) -> int:
    """Rewrites ``folder/diagnostics.csv``: every run of its results.csv whose finished run directory is here
    (its metrics.csv), the rows already in the file for the others (a fresh clone's). Returns the runs."""
    rows = t3.read_results(folder / "results.csv")
    kept = read_diagnostics(folder / "diagnostics.csv")
    by_run: dict[tuple, list[dict]] = {}
    for r in kept:
        by_run.setdefault(t3.row_key(r), []).append(r)
    for row in rows:
        spec = t3.RunSpec(row["method"], row["setup"], row["phase"], row["target"], int(row["run"]))
        path = t3.run_dir(folder, spec) / "metrics.csv"
        if not path.is_file():
            continue
        with path.open() as f:
            metrics = list(csv.DictReader(f))
        if len(metrics) == int(row["generations"]) and "behaviour_spread" in metrics[0]:
            by_run[spec.key] = diagnostics_of(spec, metrics)
    order = sorted(by_run, key=lambda k: (METHODS.index(k[0]) if k[0] in METHODS else 9, k[2], k[4]))
    csvfile.write(folder / "diagnostics.csv", DIAGNOSTICS, [r for k in order for r in by_run[k]])
    return len(order)


# --------------------------------------------------------------------------------------------------- running

def _record(out: pathlib.Path, runs: int, target_runs: dict, table3: pathlib.Path, base: t3.Protocol) -> dict:
    """``out/novelty.json``: the table3 folder the report reads and the base protocol (neither may change),
    and the largest run counts asked."""
    path = out / "novelty.json"
    rel = pathlib.Path(os.path.relpath(pathlib.Path(table3).absolute(), out.absolute())).as_posix()
    have = json.loads(path.read_text()) if path.is_file() else {}
    if have and have.get("table3") != rel:
        raise RunError(f"{path}: its Table 3 folder is {have.get('table3')!r}, now {rel!r}: use the same --table3")
    if have and have.get("protocol") != base.to_json():
        raise RunError(f"{path}: its base protocol is {have.get('protocol')}, now {base.to_json()}: use another --out")
    rec = {"table3": rel, "protocol": base.to_json(), "runs": max(runs, have.get("runs", 0)),
           "target_runs": {m: max(target_runs.get(m, 0), have.get("target_runs", {}).get(m, 0))
                           for m in sorted(set(target_runs) | set(have.get("target_runs", {})))}}
    out.mkdir(parents=True, exist_ok=True)
    run_outputs.write_json(path, rec)
    return rec


def run(out: str | pathlib.Path, arms=tuple(ARMS), methods=METHODS, phases=("source", "target"), runs: int = 10,
        target_runs: dict | None = None, table3: str | pathlib.Path | None = None,
        log: Callable[[str], None] = print, batch: int = 16, base: t3.Protocol = TABLE3,
        shard: processes.Shard = processes.ALONE) -> None:
    """Every run of the sweep not yet in its arm's results.csv: every arm's sources first (each method's in
    turn), then the transfers; each arm's diagnostics.csv updated after each of its calls. Resumable as
    :func:`kx.experiments.table3.run` is (the same command again)."""
    out = pathlib.Path(out)
    target_runs = {"neat": 10, "hyperneat": 5} if target_runs is None else dict(target_runs)
    bad = [a for a in arms if a not in ARMS]
    if bad or not arms:
        raise ValueError(f"--arms: allowed {', '.join(ARMS)} (one or more), got {', '.join(arms) or 'nothing'}")
    t3.check_choice("--methods", methods, METHODS)
    t3.check_choice("--phases", phases, ("source", "target"))
    if not isinstance(runs, int) or runs < 1:
        raise ValueError(f"--runs: allowed an integer >= 1, got {runs!r}")
    for m, n in target_runs.items():
        if m not in METHODS or not isinstance(n, int) or n < 0 or n > runs:
            raise ValueError(f"--target-runs: allowed METHOD=N with METHOD one of {', '.join(METHODS)} and N in "
                             f"[0, --runs], got {m}={n}")
    table3 = pathlib.Path(table3) if table3 is not None else out.parent / "table3"
    plan = [(ARMS[a], m, p) for p in ("source", "target") if p in phases for m in METHODS if m in methods
            for a in ARMS if a in arms]
    for arm, m, p in plan:  # every config checked before any compute
        for spec in specs(arm, m, p, runs, target_runs.get(m, 0)):
            t3.config(protocol(arm, base), spec, out / arm.name)
    if shard.leader:
        _record(out, runs, target_runs, table3, base)
    for arm, m, p in plan:
        todo = specs(arm, m, p, runs, target_runs.get(m, 0))
        if not todo:
            continue
        log(f"kx novelty: {arm.name} ({arm.label}), {m} {p}s")
        t3.run(out / arm.name, protocol(arm, base), todo, log=log, batch=batch, shard=shard)
        if shard.leader:  # every process's runs are merged into results.csv by now
            update_diagnostics(out / arm.name, arm)


# ---------------------------------------------------------------------------------------------------- report

METHOD_NAMES = t3.METHOD_NAMES
ALPHA = design.ALPHA  # Table 3's significance level
MEASURES = (("test_fitness", "validated champion on the test states"), ("max_fitness", "maximum training fitness"))


def _rows(out: pathlib.Path, rec: dict) -> dict:
    """``{(arm, method, phase): rows}`` of every arm, the table3 arms' transfers from Table 3's folder (its runs
    below the sweep's source count: those seeded by the sources of the arm's run indices)."""
    cells: dict[tuple, list[dict]] = {}
    for arm in ARMS.values():
        for r in t3.read_results(out / arm.name / "results.csv"):
            cells.setdefault((arm.name, r["method"], r["phase"]), []).append(r)
    table3 = t3.read_results(out / rec["table3"] / "results.csv")
    for name, setup in TABLE3_SETUP.items():
        for r in table3:
            if (r["setup"], r["phase"], r["target"]) == (setup, "target", TARGET) and int(r["run"]) < rec["runs"]:
                cells.setdefault((name, r["method"], "target"), []).append(r)
    for rs in cells.values():
        rs.sort(key=lambda r: int(r["run"]))
    return cells


def _reproduced(out: pathlib.Path, rec: dict) -> list[str]:
    """Whether the sources of the arms with Table 3's configs are Table 3's rows (every column but the times)."""
    table3 = {t3.row_key(r): r for r in t3.read_results(out / rec["table3"] / "results.csv")}
    lines = []
    for name in TABLE3_SETUP:
        for m in METHODS:
            rows = [r for r in t3.read_results(out / name / "results.csv")
                    if r["method"] == m and r["phase"] == "source"]
            there = [r for r in rows if t3.row_key(r) in table3]
            same = [r for r in there if not t3.differences(table3[t3.row_key(r)], r, t3.REPRODUCED)]
            if rows:
                lines.append(f"- {METHOD_NAMES[m]} `{name}`: {len(same)} of {len(rows)} sources equal Table 3's rows "
                             f"in every column but the times ({len(rows) - len(there)} not in Table 3's folder yet).")
    return lines


def _values(rows: list[dict], measure: str) -> np.ndarray:
    return np.array([float(r[measure]) for r in rows])


def _fmt_interval(v: np.ndarray) -> str:
    i = stats.iqm_interval(v)
    return f"{i.value:.3f} [{i.low:.3f}, {i.high:.3f}]" if np.isfinite(i.low) else f"{i.value:.3f}"


def comparisons(cells: dict, method: str, phase: str, measure: str) -> dict:
    """Every arm with runs against the reference (``fitness``) in one (method, phase, measure): Mann-Whitney
    and the Vargha-Delaney A, Holm-corrected over the arms compared. ``{arm: (Comparison, holm p)}``."""
    ref = cells.get((REFERENCE, method, phase), [])
    arms = [a for a in ARMS if a != REFERENCE and len(cells.get((a, method, phase), [])) >= 2]
    if len(ref) < 2 or not arms:
        return {}
    comps = [stats.mann_whitney(_values(cells[(a, method, phase)], measure), _values(ref, measure)) for a in arms]
    adjusted = stats.holm([c.p for c in comps])
    return {a: (c, float(p)) for a, c, p in zip(arms, comps, adjusted)}


def _diag_summary(diag: list[dict]) -> dict:
    """Per run's diagnostics rows: the mean behaviour spread over its generations, the final archive size,
    the share of generations whose fittest genome has no child, and its mean number of children."""
    spread = np.mean([float(r["behaviour_spread"]) for r in diag])
    archive = diag[-1]["archive_size"]
    kids = [int(r["fittest_offspring"]) for r in diag if r["fittest_offspring"] != ""]
    return {"spread": spread, "archive": float(archive) if archive != "" else None,
            "childless": float(np.mean([k == 0 for k in kids])) if kids else None,
            "children": float(np.mean(kids)) if kids else None}


def _diagnostics(out: pathlib.Path) -> dict:
    """``{(arm, method, phase): {run: summary}}`` and the per-generation spread curves."""
    summary, curves = {}, {}
    for arm in ARMS:
        by_run: dict[tuple, list[dict]] = {}
        for r in read_diagnostics(out / arm / "diagnostics.csv"):
            by_run.setdefault(t3.row_key(r), []).append(r)
        for k, rows in by_run.items():
            cell = (arm, k[0], k[2])
            summary.setdefault(cell, {})[k[4]] = _diag_summary(rows)
            curves.setdefault(cell, []).append([float(r["behaviour_spread"]) for r in rows])
    return {"summary": summary, "curves": curves}


def _mean_of(summaries: dict, field: str) -> str:
    v = [s[field] for s in summaries.values() if s[field] is not None]
    if not v:
        return "-"
    return f"{100 * np.mean(v):.0f}%" if field == "childless" else f"{np.mean(v):.3g}"


def _table(cells: dict, diag: dict, method: str, phase: str) -> list[str]:
    comps = {m: comparisons(cells, method, phase, m) for m, _ in MEASURES}
    head = ("| arm | runs | test fitness IQM [95% CI] | A vs fitness (Holm p) | max fitness IQM [95% CI] | "
            "A vs fitness (Holm p) |")
    lines = [head, "|---|---|---|---|---|---|"]
    if phase == "source":
        lines = [head + " behaviour spread | fittest childless | fittest's children | final archive |",
                 "|---|---|---|---|---|---|---|---|---|---|"]
    for a, arm in ARMS.items():
        rows = cells.get((a, method, phase), [])
        if not rows:
            continue
        cols = [f"`{a}` {arm.label}", str(len(rows))]
        for m, _ in MEASURES:
            cols.append(_fmt_interval(_values(rows, m)))
            c = comps[m].get(a)
            cols.append("reference" if a == REFERENCE else "-" if c is None else f"{c[0].a:.2f} ({c[1]:.3f})")
        if phase == "source":
            s = diag["summary"].get((a, method, phase), {})
            cols += [_mean_of(s, f) for f in ("spread", "childless", "children", "archive")] if s else ["-"] * 4
        lines.append("| " + " | ".join(cols) + " |")
    return lines + [""]


def answers(cells: dict) -> list[str]:
    """The report's plain answers, from the comparisons."""
    lines = ["**Does any reading make the hybrid beat fitness alone, in the source or after transfer?**", ""]
    beats, loses, open_ = [], [], []
    for method in METHODS:
        for phase in ("source", "target"):
            for measure, what in MEASURES:
                for a, (c, p) in comparisons(cells, method, phase, measure).items():
                    text = (f"{METHOD_NAMES[method]} `{a}` {'in 3v2' if phase == 'source' else 'after transfer to 4v3'}"
                            f" on the {what} (A {c.a:.2f}, Holm p {p:.3f})")
                    (beats if p < ALPHA and c.a > 0.5 else loses if p < ALPHA else open_).append(text)
    if beats:
        lines.append(f"Yes, at Holm-corrected {ALPHA}: " + "; ".join(beats) + ".")
    else:
        lines.append(f"No. No reading beats fitness alone at Holm-corrected {ALPHA} in any comparison made "
                     f"({len(loses) + len(open_)} comparisons).")
    if loses:
        lines.append(f"Fitness alone is better ({len(loses)}): " + "; ".join(loses) + ".")
    if open_:
        best = max(open_, key=lambda t: float(t.split("(A ")[1].split(",")[0]))
        lines.append(f"Not decided ({len(open_)}); the highest A among them: {best}.")
    lines += ["", "**Can the authors' pure-novelty arm explain the paper's HyperNEAT + NS numbers on the maximum "
              "training fitness?**", ""]
    pure = cells.get(("rho-0.0", "hyperneat", "target"), [])
    ref = cells.get((REFERENCE, "hyperneat", "target"), [])
    paper = cells.get(("rho-0.4", "hyperneat", "target"), [])
    if len(pure) < 2 or len(ref) < 2:
        lines.append("Not yet: the sweep has no HyperNEAT pure-novelty transfers, or Table 3 no HyperNEAT fitness "
                     "transfers, to compare.")
        return lines
    c = stats.mann_whitney(_values(pure, "max_fitness"), _values(ref, "max_fitness"))
    text = (f"In the paper HyperNEAT's fitness + NS transfer has the highest maximum training fitness of its setups "
            f"in every target. Here, after transfer to 4v3, HyperNEAT's pure-novelty arm reaches a maximum training "
            f"fitness of IQM {stats.iqm(_values(pure, 'max_fitness')):.3f} ({len(pure)} runs) against "
            f"{stats.iqm(_values(ref, 'max_fitness')):.3f} for fitness transfer ({len(ref)} runs; A {c.a:.2f}, "
            f"Mann-Whitney p {c.p:.3f})")
    if len(paper) >= 2:
        text += f" and {stats.iqm(_values(paper, 'max_fitness')):.3f} for the paper's weight ({len(paper)} runs)"
    if c.p < ALPHA and c.a > 0.5:
        lines.append(text + ": pure novelty beats fitness transfer on the paper's measure here, so the authors' "
                     "arm could explain the paper's ordering.")
    elif c.p < ALPHA:
        lines.append(text + ": pure novelty is worse than fitness transfer on the paper's measure here, so in "
                     "kx's world the authors' pure-novelty arm does not explain the paper's ordering.")
    else:
        lines.append(text + ": the runs do not separate pure novelty from fitness transfer on the paper's measure "
                     "here, so they neither show that the authors' arm explains the paper's ordering nor rule it out.")
    return lines



def _arm_mean(diag: dict, arm: str, method: str, field: str) -> float | None:
    v = [d[field] for d in diag["summary"].get((arm, method, "source"), {}).values() if d[field] is not None]
    return float(np.mean(v)) if v else None


def diagnosis(cells: dict, diag: dict) -> list[str]:
    """What the sources' diagnostics say, per method, as sentences built from the figures."""
    lines = []
    for m in METHODS:
        if _arm_mean(diag, REFERENCE, m, "spread") is None:
            continue
        name = METHOD_NAMES[m]
        ref = {f: _arm_mean(diag, REFERENCE, m, f) for f in ("spread", "childless", "children")}
        hybrid = [a for a in ARMS if a not in (REFERENCE, "rho-1.0") and _arm_mean(diag, a, m, "spread") is not None]
        if hybrid:
            spreads = [_arm_mean(diag, a, m, "spread") for a in hybrid]
            lines.append(f"- {name}, behaviour spread: {ref['spread']:.3f} under fitness alone, {min(spreads):.3f} to "
                         f"{max(spreads):.3f} under the hybrid's readings with a novelty term ({len(hybrid)} arms): "
                         f"at most {100 * (max(spreads) / ref['spread'] - 1):+.0f}% (means over generations and "
                         "runs).")
        parts = []
        for a in ("rho-0.6", "rho-0.4", "rho-0.0"):
            c, k = _arm_mean(diag, a, m, "childless"), _arm_mean(diag, a, m, "children")
            if c is not None:
                parts.append(f"{100 * c:.0f}% and {k:.1f} at rho {a[4:]}")
        if parts:
            lines.append(f"- {name}, the generation's fittest genome: childless in {100 * ref['childless']:.0f}% of "
                         f"generations under fitness alone, with {ref['children']:.1f} children on average; "
                         + "; ".join(parts) + ".")
        one, fit = cells.get(("rho-1.0", m, "source"), []), cells.get((REFERENCE, m, "source"), [])
        if len(one) >= 2 and len(fit) >= 2:
            pieces = []
            for measure, what in MEASURES:
                c = stats.mann_whitney(_values(one, measure), _values(fit, measure))
                pieces.append(f"{what} IQM {stats.iqm(_values(one, measure)):.3f} against "
                              f"{stats.iqm(_values(fit, measure)):.3f} (A {c.a:.2f}, p {c.p:.3f})")
            lines.append(f"- {name}, the hybrid's score with no novelty in it (rho 1.0: min-max-normalised fitness) "
                         "against raw fitness: " + "; ".join(pieces) + ". A monotone rescaling leaves each "
                         "species' ranking of its members, its elite and its parents as they were; what it "
                         "changes is the species' shares of the offspring (explicit fitness sharing: a species' "
                         "mean score), which on the min-max scale are shares of each genome's fitness above the "
                         "generation's worst rather than of its fitness.")
    return lines


def _plots(cells: dict, diag: dict, out: pathlib.Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = dict(zip(ARMS, ("black", "tab:blue", "tab:cyan", "tab:green", "tab:red", "tab:purple", "tab:orange",
                              "tab:brown", "tab:pink")))
    panels = [("sources.png", "best_so_far", "source", "best-so-far training fitness, 3v2"),
              ("transfers.png", "best_so_far", "target", "best-so-far training fitness, 4v3"),
              ("spread.png", "spread", "source", "behaviour spread, 3v2")]
    names = []
    for name, what, phase, ylabel in panels:
        fig, axes = plt.subplots(1, len(METHODS), figsize=(5.4 * len(METHODS), 3.6), squeeze=False, sharey=True)
        for j, m in enumerate(METHODS):
            ax = axes[0][j]
            for a in ARMS:
                if what == "spread":
                    cs = diag["curves"].get((a, m, phase), [])
                else:
                    cs = [t3.curve(r, what) for r in cells.get((a, m, phase), [])]
                if not cs:
                    continue
                mean, lo, hi = stats.mean_band(cs)
                ax.plot(np.arange(mean.size), mean, color=colours[a], label=f"{a} (n={len(cs)})", linewidth=1.2)
                ax.fill_between(np.arange(mean.size), lo, hi, color=colours[a], alpha=0.12, linewidth=0)
            report.curve_panel(ax, METHOD_NAMES[m], ylabel if j == 0 else None, 6, "best")
        fig.tight_layout()
        fig.savefig(out / name, dpi=90, metadata={"Software": None})
        plt.close(fig)
        names.append(name)
    return names


def write_report(out: str | pathlib.Path) -> pathlib.Path:
    """``out/report.md`` and its PNGs from the arms' results.csv and diagnostics.csv and Table 3's results.csv
    alone (byte for byte the same from the same files)."""
    out = pathlib.Path(out)
    path = out / "novelty.json"
    if not path.is_file():
        raise RunError(f"{path}: not a kx novelty folder (no novelty.json)")
    rec = json.loads(path.read_text())
    cells = _rows(out, rec)
    if not cells:
        raise RunError(f"{out}: no finished runs to report")
    diag = _diagnostics(out)
    base = rec["protocol"]
    md = ["# Why novelty hurts here: the hybrid's readings over seeds (kx)", "",
          "Generated by `python -m kx.experiments report " + out.as_posix() + "` from the arms' `results.csv` and "
          f"`diagnostics.csv` and Table 3's `results.csv` (`{rec['table3']}`); the runs by "
          "`python -m kx.experiments novelty --out " + out.as_posix() + "`. Each arm is a Table 3 protocol of "
          "its own (the same seeding rule, test states and measures); the readings and their sources are in "
          "docs/novelty.md.", "",
          f"Measures: the run's validated champion on the protocol's {base['test_trials']} test states of its task, "
          "and the maximum over the run of the generation's best training fitness (the paper's measure). IQM with "
          "its 95% bootstrap interval; A is the Vargha-Delaney probability that a run of the arm beats one of "
          "fitness alone (0.5: no difference); p is the two-sided Mann-Whitney test, Holm-corrected over the "
          "arms compared in the same method, phase and measure.", "",
          "Diagnostics (sources, means over runs): *behaviour spread*, the mean distance of a genome's "
          "behaviour (passes, dispersion, ball distance from the centre) to the population's mean, averaged "
          "over the generations; *fittest childless*, the share of generations in which the generation's "
          "fittest genome (by raw fitness) is the parent of no child; *fittest's children*, how many of the "
          "next generation's children it is a parent of on average; *final archive*, the novelty archive's size "
          "after the last generation.", "", "## The answers", ""]
    md += answers(cells) + [""]
    found = diagnosis(cells, diag)
    if found:
        md += ["### What the diagnostics say (sources)", ""] + found + [""]
    for phase, title in (("source", f"Sources: 3v2, {base['source_generations']} generations"),
                         ("target", f"After transfer: fitness + NS transfer to 4v3, {base['target_generations']} "
                                    "generations")):
        md += [f"## {title}", ""]
        if phase == "target":
            md += ["The `fitness` and `rho-0.4` rows are Table 3's own 4v3 cells (fitness transfer; fitness + NS "
                   "transfer), their runs seeded by the sources of the same run indices.", ""]
        for m in METHODS:
            if any(k[1:] == (m, phase) for k in cells):
                md += [f"### {METHOD_NAMES[m]}", ""] + _table(cells, diag, m, phase)
    md += ["## Curves", ""]
    for name in _plots(cells, diag, out):
        md += [f"![{name}]({name})", ""]
    md += ["## Checks", ""] + (_reproduced(out, rec) or ["- No source of the Table 3 arms has run yet."]) + [""]
    md_path = out / "report.md"
    run_outputs.write_text(md_path, "\n".join(md))
    return md_path
