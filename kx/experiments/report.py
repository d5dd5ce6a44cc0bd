"""Table 3's report, from ``DIR/results.csv`` alone: ``DIR/report.md`` and its PNGs.

Over 450 lines because it builds one document, report.md, section by section; its statistics live in
kx.experiments.stats, its design in kx.experiments.design and its costs in kx.experiments.planning.

Nothing in it depends on where the folder lies or when it is written (no paths, no dates; the bootstrap
has a fixed seed; matplotlib's PNGs carry no time), so regenerating it gives the same bytes.
"""

from __future__ import annotations

import collections
import math
import pathlib

import numpy as np

from kx.experiments import csvfile, design, planning, sequential, stats
from kx.experiments import table3 as t3

#: The paper's Table 3 (mean (sd) over 20 runs, portion of the maximum hold time; SPEC section 6).
PAPER = {
    ("neat", "none"): ("0.438 (0.037)", "0.473 (0.052)", "0.419 (0.057)"),
    ("hyperneat", "none"): ("0.587 (0.059)", "0.765 (0.050)", "0.533 (0.044)"),
    ("neat", "fitness"): ("0.482 (0.059)", "0.580 (0.069)", "0.464 (0.033)"),
    ("hyperneat", "fitness"): ("0.729 (0.089)", "0.873 (0.089)", "0.632 (0.038)"),
    ("neat", "hybrid"): ("0.545 (0.047)", "0.638 (0.0048)", "0.520 (0.036)"),
    ("hyperneat", "hybrid"): ("0.752 (0.054)", "0.943 (0.029)", "0.697 (0.032)"),
}
MEASURES = {"max_fitness": "the paper's measure: the maximum over the run of the generation's best 30-trial "
                           "training fitness",
            "test_fitness": "the run's validated champion on the protocol's test states of the target"}
METHOD_NAMES = t3.METHOD_NAMES
ALPHA = design.ALPHA
#: what could explain where kx's runs and the paper's differ (the report's last section)
DIFFERENCES = [
    "- **The simulator.** kx's world is a grid of 20 x 20 cells stepped 4500 times an episode, with its own "
    "kick noise, possession and taker rules (SPEC section 1); the paper ran RoboCup keep-away's continuous "
    "simulator with its own noise and hand-coded skills. Absolute values cannot be compared, and the "
    "difficulty of 4v3, 5v3 and 6v4 relative to 3v2 need not be the same.",
    "- **The hybrid's weight.** kx weighs fitness by rho = 0.4 and novelty by 0.6 (its reading of the "
    "paper's Equation 1). The authors' code intended 0.6 on fitness; their NEAT arm ran 0.5; their HyperNEAT "
    "arm ran pure novelty, because a misspelt XML field left the weight at 0 (the saved population has "
    "Fitness = Novelty; ../shared/reference/authors-code.md, section 1d). The paper's hybrid rows may "
    "therefore measure other algorithms than its text describes.",
    "- **Novelty's other readings.** The authors' HyperNEAT code archives the 10 most novel genomes a "
    "generation with no cap, and its behaviour counts every decision as a pass and ignores the ball's "
    "distance from the centre; kx follows the paper (archive 1000, threshold 0.03; passes, dispersion, ball "
    "distance). docs/novelty/report.md measures each reading over seeds, in the source and after transfer.",
    "- **The measure.** The paper reports the maximum over a run of the generation's best 30-trial training "
    "fitness, which rewards exploration and is biased upward by the noise of 30 trials; kx reports it and the "
    "run's validated champion on 1000 test states, which the claims are decided on as well.",
    "- **The statistics.** The paper tests each target separately with Mann-Whitney; kx decides each claim "
    "once, pooled over the targets, with Holm's correction over the paper's comparisons, and says where the "
    "runs cannot decide it.",
]


def _f(x: float, digits: int = 3) -> str:
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def _p(p: float | None) -> str:
    if p is None or (isinstance(p, float) and math.isnan(p)):
        return "—"
    return "<0.0001" if p < 1e-4 else f"{p:.4f}"


def _sd(v: np.ndarray) -> str:
    """The sample standard deviation, or a dash for a single run."""
    return f"{v.std(ddof=1):.3f}" if v.size > 1 else "—"


def comparisons(cells: dict) -> list[tuple[str, str, tuple, tuple]]:
    """The pairwise tests, ``(claim, label, cell a, cell b)`` with cells ``(method, setup, target)``, for
    the cells present: transfer vs none, hybrid vs fitness (with and without transfer), HyperNEAT vs
    NEAT, and CMA-ES's transfer vs none."""
    out = []
    targets = sorted({k[2] for k in cells}, key=t3.TARGETS.index)
    for t in targets:
        for m in t3.METHODS:
            for a, b, claim in (("fitness", "none", "transfer"), ("hybrid", "none", "transfer"),
                                ("hybrid", "fitness", "hybrid"), ("none_hybrid", "none", "hybrid")):
                if (m, a, t) in cells and (m, b, t) in cells:
                    out.append((claim, f"{METHOD_NAMES[m]} {t}: {t3.SETUPS[a].label} vs {t3.SETUPS[b].label}",
                                (m, a, t), (m, b, t)))
        for s in t3.SETUPS:
            if ("hyperneat", s, t) in cells and ("neat", s, t) in cells:
                out.append(("hyperneat", f"{t} {t3.SETUPS[s].label}: HyperNEAT vs NEAT", ("hyperneat", s, t),
                            ("neat", s, t)))
    return out


def _cells(rows: list[dict], measure: str) -> dict:
    cells = collections.defaultdict(list)
    for r in sorted(rows, key=lambda r: int(r["run"])):
        if r["phase"] == "target":
            cells[(r["method"], r["setup"], r["target"])].append(float(r[measure]))
    return {k: np.asarray(v) for k, v in cells.items()}


def _table3(cells: dict, targets: list[str], paper: bool) -> list[str]:
    head = "| setup | method | " + " | ".join(f"{t} ours" + (f" | {t} paper" if paper else "") for t in targets) + " |"
    lines = [head, "|" + "---|" * (2 + len(targets) * (2 if paper else 1))]
    for s in t3.SETUPS:
        for m in t3.METHODS:
            if not any((m, s, t) in cells for t in targets):
                continue
            row = f"| {t3.SETUPS[s].label} | {METHOD_NAMES[m]} |"
            for t in targets:
                v = cells.get((m, s, t))
                ours = "—" if v is None else f"{v.mean():.3f} ({_sd(v)}) n={v.size}"
                row += f" {ours} |"
                if paper:
                    pv = PAPER.get((m, s))
                    row += f" {pv[t3.TARGETS.index(t)] if pv else '—'} |"
            lines.append(row)
    return lines


def _per_cell_stats(cells: dict, targets: list[str]) -> list[str]:
    lines = ["| setup | method | target | n | mean | sd | IQM [95% CI] | Lilliefors p |",
             "|---|---|---|---|---|---|---|---|"]
    for s in t3.SETUPS:
        for m in t3.METHODS:
            for t in targets:
                v = cells.get((m, s, t))
                if v is None:
                    continue
                ci = stats.iqm_interval(v)
                lines.append(f"| {t3.SETUPS[s].label} | {METHOD_NAMES[m]} | {t} | {v.size} | {v.mean():.3f} | "
                             f"{_sd(v)} | {ci.value:.3f} [{_f(ci.low)}, {_f(ci.high)}] | {_p(stats.lilliefors(v))} |")
    return lines


def _tests(cells: dict) -> tuple[list[str], list[dict]]:
    comps = comparisons(cells)
    results = []
    for claim, label, a, b in comps:
        c = stats.mann_whitney(cells[a], cells[b])
        poi = stats.improvement_interval(cells[a], cells[b])
        results.append(dict(claim=claim, label=label, a=a, b=b, c=c, poi=poi,
                            diff=float(cells[a].mean() - cells[b].mean())))
    adjusted = stats.holm([r["c"].p for r in results])
    lines = ["| comparison | n | mean difference | U | p | Holm p | A (= P(improvement)) [95% CI] |",
             "|---|---|---|---|---|---|---|"]
    for r, h in zip(results, adjusted):
        r["holm"] = float(h)
        c, poi = r["c"], r["poi"]
        lines.append(f"| {r['label']} | {c.n_a}, {c.n_b} | {r['diff']:+.3f} | {c.u:g} | {_p(c.p)} | {_p(r['holm'])} | "
                     f"{c.a:.2f} [{_f(poi.low, 2)}, {_f(poi.high, 2)}] |")
    return lines, results


def efficiency(rows: list[dict]) -> list[tuple]:
    """Per (method, target, setup): the no-transfer setup's final mean best-so-far (the paper's threshold),
    the generations the setup's mean best-so-far takes to reach it and the episodes played by then, its
    source run's included (``None`` if never reached), and how many of its runs reach it on their own, of
    how many."""
    curves = collections.defaultdict(list)
    meta = {}
    for r in rows:
        if r["phase"] != "target":
            continue
        k = (r["method"], r["target"], r["setup"])
        curves[k].append(t3.curve(r, "best_so_far"))
        # a generation's episodes from the row's own count: population x trials for the evolvers, a
        # training block of NEAT's episodes for PPO (its population of one plays only its evaluation)
        meta[k] = (int(r["episodes"]) // int(r["generations"]), int(r["source_episodes"]))
    out = []
    order = lambda k: (t3.METHODS.index(k[0]), t3.TARGETS.index(k[1]), list(t3.SETUPS).index(k[2]))  # noqa: E731
    for (m, t, s), cs in sorted(curves.items(), key=lambda kv: order(kv[0])):
        base = curves.get((m, t, "none"))
        if base is None:
            continue
        n = min(len(c) for c in base)
        threshold = float(np.mean([c[n - 1] for c in base]))
        length = min(len(c) for c in cs)
        mean = np.mean([c[:length] for c in cs], axis=0)
        hit = np.flatnonzero(mean >= threshold)
        per_gen, src = meta[(m, t, s)]
        g = int(hit[0]) + 1 if hit.size else None
        alone = sum(max(c) >= threshold for c in cs)
        out.append((m, t, s, threshold, g, None if g is None else g * per_gen + src, alone, len(cs)))
    return out


def _runs(rows: list[dict], measure: str) -> dict:
    """``{(method, setup, target): {run index: value}}`` of the target rows on ``measure``."""
    out: dict = collections.defaultdict(dict)
    for r in rows:
        if r["phase"] == "target":
            out[(r["method"], r["setup"], r["target"])][int(r["run"])] = float(r[measure])
    return dict(out)


def _targets(runs: dict, claim) -> list[str]:
    """The targets where both cells of ``claim`` have runs."""
    return [t for t in t3.TARGETS if (*claim.a, t) in runs and (*claim.b, t) in runs]


def _with_runs(runs: dict, claims) -> list[tuple]:
    """The ``claims`` with runs of both their cells in some target, each with those targets."""
    return [(claim, targets) for claim in claims if (targets := _targets(runs, claim))]


def _matrix(runs: dict, cell: tuple, targets: list[str], dsg: dict, upto: int | None = None) -> np.ndarray:
    """A cell as clusters x targets (:func:`stats.cluster_matrix`): the runs of a transfer cell share their source
    across the targets where the design's sources are shared; ``upto``: only runs of index below it."""
    shared = dsg["sources"] == "shared" and t3.SETUPS[cell[1]].source_objective is not None
    return stats.cluster_matrix([{i: v for i, v in runs[(*cell, t)].items() if upto is None or i < upto}
                                 for t in targets], shared)


def looks_had(runs: dict, claim, targets: list[str], looks) -> list[int | None]:
    """The looks of the plan ``looks`` (runs a cell, ascending) that ``claim``'s comparison had, as the run count
    each reads (``None``: every run, at its last look): the first always; a later one where a cell of the
    comparison holds runs past the look before."""
    most = max(max(runs[(*c, t)]) + 1 for c in (claim.a, claim.b) for t in targets)
    had = [0] + [k for k in range(1, len(looks)) if most > looks[k - 1]]
    return [looks[k] for k in had[:-1]] + [None]


def _exploratory_sets(runs, claim, targets, dsg):
    """The data of each look ``claim`` had: ``[(a, b)]`` matrices, and the plan's information fractions."""
    looks = dsg["looks"]
    uptos = looks_had(runs, claim, targets, looks)
    return ([(_matrix(runs, claim.a, targets, dsg, u), _matrix(runs, claim.b, targets, dsg, u)) for u in uptos],
            sequential.fractions(looks))


def pooled_tests(runs: dict, dsg: dict | None = None, power: bool = True) -> list[dict]:
    """Every claim of the families the design ``dsg`` records (:func:`kx.experiments.design.families`; default: the
    exploratory design with shared sources) with runs in both its cells in some target: the pooled test at each look the
    comparison had (:func:`stats.clustered_van_elteren`, clusters the runs that share a source; a cluster alone in
    its pattern of targets waits for the next look: :func:`stats.leave_out_lone_clusters`, ``waiting``), its sequential
    p-value under the plan's looks (:func:`sequential.sequential_p`), Holm's correction over its whole family as the
    design fixes it (a claim without runs yet counts with p = 1, so a partial folder is corrected as the whole
    protocol will be), the power in the observed direction at ALPHA / the family's size with these runs and the
    runs a cell 80% would need (``power``), and the verdict: supported or contradicted where the Holm p is below
    ALPHA (the direction the sign of the last look's statistic); no meaningful difference where not, and the
    interval of the averaged probability of improvement lies inside the design's margin; not decided otherwise."""
    dsg = dsg or design.design()
    margin = dsg["margin"]
    out = []
    for claims in design.families(dsg):
        fam = []
        for claim, targets in _with_runs(runs, claims):
            if dsg["looks"] == "planned":
                sets, fracs = [(_matrix(runs, claim.a, targets, dsg), _matrix(runs, claim.b, targets, dsg))], (1.0,)
            else:
                sets, fracs = _exploratory_sets(runs, claim, targets, dsg)
            # a source not yet run in every target the others have run in waits for the next look
            kept = [stats.leave_out_lone_clusters(a, b) for a, b in sets]
            sets, waiting = [(a, b) for a, b, _ in kept], kept[-1][2]
            tests = [stats.clustered_van_elteren(a, b) for a, b in sets]
            z = [t.z_equivalent for t in tests]
            # the direction: the sign at the look nearest to (or furthest past) its boundary, which sets the
            # sequential p (the last look's, unless an earlier one decided)
            bounds = sequential.boundaries(design.ALPHA, tuple(fracs))
            decisive = max(range(len(z)), key=lambda k: (abs(z[k]) - bounds[k], k))
            fam.append(dict(claim=claim, targets=targets, sets=sets, tests=tests, test=tests[-1], waiting=waiting,
                            seq_p=sequential.sequential_p(z, fracs), way=int(np.sign(tests[decisive].z))))
        padded = [r["seq_p"] for r in fam] + [1.0] * (len(claims) - len(fam))
        level = design.ALPHA / len(claims)
        for r, h in zip(fam, stats.holm(padded)):
            way = r["way"]
            a, b = r["sets"][-1]
            r.update(holm=float(h), level=level, way=way)
            if power:
                r.update(power=stats.clustered_power(a, b, level, direction=way) if way else 0.0,
                         needed=stats.clustered_runs_needed(a, b, level, design.POWER_GOAL, design.POWER_RUNS,
                                                            direction=way) if way else None)
            poi = r["test"].poi
            inside = margin[0] <= poi.low and poi.high <= margin[1]
            r["verdict"] = ("supported" if r["holm"] < design.ALPHA and way > 0 else
                            "contradicted" if r["holm"] < design.ALPHA and way < 0 else
                            "no meaningful difference" if inside else "not decided")
        out += fam
    return out


def first_kind_verdicts(runs: dict, dsg: dict | None = None) -> dict:
    """The verdicts of the first design (van Elteren's test with independent strata, one look at every run, no
    margin) over the families of ``dsg`` (default: today's), ``{claim key: (verdict, Holm p)}``: what the report said
    before the correction."""
    out = {}
    for claims in design.families(dsg or design.design()):
        fam = []
        for claim, targets in _with_runs(runs, claims):
            vals = [[np.asarray([v for _, v in sorted(runs[(*c, t)].items())]) for t in targets]
                    for c in (claim.a, claim.b)]
            fam.append((claim, stats.van_elteren(*vals)))
        padded = [t.p for _, t in fam] + [1.0] * (len(claims) - len(fam))
        for (claim, t), h in zip(fam, stats.holm(padded)):
            out[claim.key] = ("not decided" if h >= design.ALPHA else "supported" if t.z > 0 else "contradicted",
                              float(h))
    return out


def _changes(runs: dict, results: list[dict], dsg: dict) -> list[str]:
    """The verdicts the corrected design changes against the first one's, each with the step that changes it:
    the clustered test alone (one look, no margin), then the looks paid for, then the margin."""
    old = first_kind_verdicts(runs, dsg)
    one_look = pooled_tests(runs, {**dsg, "looks": "planned", "margin": [0.5, 0.5]}, power=False)
    looks = pooled_tests(runs, {**dsg, "margin": [0.5, 0.5]}, power=False)
    steps = {r["claim"].key: r for r in one_look}, {r["claim"].key: r for r in looks}
    lines = []
    for r in results:
        key = r["claim"].key
        before = old[key][0]
        if before == r["verdict"]:
            continue
        why = []
        v1, v2 = steps[0][key]["verdict"], steps[1][key]["verdict"]
        if v1 != before:
            why.append(f"the clustered test: Holm p {_p(old[key][1])} -> {_p(steps[0][key]['holm'])}")
        if v2 != v1:
            why.append(f"the looks paid for: Holm p {_p(steps[0][key]['holm'])} -> {_p(steps[1][key]['holm'])}")
        if r["verdict"] != v2:
            why.append(f"the margin: P(a > b) [{_f(r['test'].poi.low, 2)}, {_f(r['test'].poi.high, 2)}] inside "
                       f"[{dsg['margin'][0]:.2f}, {dsg['margin'][1]:.2f}]")
        lines.append(f"| {_label(r['claim'])} | {r['claim'].family} | **{before}** | **{r['verdict']}** | "
                     f"{'; '.join(why)} |")
    return lines


def _label(claim) -> str:
    (ma, sa), (mb, sb) = claim.a, claim.b
    if ma == mb:
        return f"{METHOD_NAMES[ma]}: {t3.SETUPS[sa].label} vs {t3.SETUPS[sb].label}"
    return f"{t3.SETUPS[sa].label}: {METHOD_NAMES[ma]} vs {METHOD_NAMES[mb]}"


def _needed(r: dict) -> str:
    return f"> {design.POWER_RUNS[-1]}" if r["needed"] is None else str(r["needed"])


VERDICTS = ("supported", "contradicted", "no meaningful difference", "not decided")


def _pooled_table(results: list[dict], family: str) -> list[str]:
    rows = [r for r in results if r["claim"].family == family]
    if not rows:
        return ["No comparison of this family has runs in both its cells."]
    lines = ["| comparison (a vs b) | targets | clusters | runs a cell | mean difference | P(a > b) [95% CI] | "
             "t (df) | p | looks | sequential p | Holm p | power now | runs a cell for 80% | verdict |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        t, poi = r["test"], r["test"].poi
        counts = sorted(set(t.n_a + t.n_b))
        runs = str(counts[0]) if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
        lines.append(f"| {_label(r['claim'])} | {', '.join(r['targets'])} | {t.clusters[0]}, {t.clusters[1]}"
                     + (f" (+{r['waiting'][0]}, +{r['waiting'][1]} waiting)" if any(r["waiting"]) else "") + " | "
                     f"{runs} | {t.diff:+.3f} | {poi.value:.2f} [{_f(poi.low, 2)}, {_f(poi.high, 2)}] | "
                     + (f"— ({t.why}) | " if t.why else f"{t.z:+.2f} ({t.df:.0f}) | ")
                     + f"{_p(t.p)} | {len(r['tests'])} | {_p(r['seq_p'])} | {_p(r['holm'])} | {r['power']:.0%} | "
                     f"{_needed(r)} | **{r['verdict']}** |")
    return lines


def _verdicts(by_measure: dict) -> list[str]:
    """The paper's claims, one line per claim and measure, from the primary family."""
    lines = []
    for name, title in design.TITLES.items():
        lines.append(f"**{title}.**")
        for measure, results in by_measure.items():
            rs = [r for r in results if r["claim"].family == "primary" and r["claim"].claim == name]
            if not rs:
                lines.append(f"- {measure}: not measured in these runs.")
                continue
            counts = collections.Counter(r["verdict"] for r in rs)
            overall = next((v for v in VERDICTS if counts[v] == len(rs)), None) or (
                ", ".join(f"{v} in {counts[v]}" for v in VERDICTS if counts[v]) + f" of {len(rs)}")
            lines.append(f"- {measure}: **{overall}**.")
            for r in rs:
                t = r["test"]
                way = {1: "the paper's way", -1: "against the paper", 0: "neither way"}[r["way"]]
                lines.append(f"  - {_label(r['claim'])} ({', '.join(r['targets'])}): {r['verdict']}; P(a > b) = "
                             f"{t.poi.value:.2f} [{_f(t.poi.low, 2)}, {_f(t.poi.high, 2)}] ({way}), mean difference "
                             f"{t.diff:+.3f}, Holm p = {_p(r['holm'])}" + (f" ({t.why})" if t.why else "")
                             + ("" if r["verdict"] != "not decided" else
                                f"; power {r['power']:.0%} with these runs, {_needed(r)} runs a cell for 80%") + ".")
        lines.append("")
    return lines


def _efficiency_claim(eff: list[tuple]) -> list[str]:
    lines = ["**Transfer reaches the no-transfer level in fewer generations.**"]
    reached = [e for e in eff if e[2] != "none"]
    if not reached:
        lines.append("- not measured in these runs.")
    for m, t, s, thr, g, ev, hit, n in reached:
        base = next((e for e in eff if e[:3] == (m, t, "none")), None)
        g0 = base[4] if base else None
        if g is None:
            lines.append(f"- {METHOD_NAMES[m]} {t} {t3.SETUPS[s].label}: the mean never reaches the threshold "
                         f"{thr:.3f} ({hit} of {n} runs do on their own).")
        else:
            lines.append(f"- {METHOD_NAMES[m]} {t} {t3.SETUPS[s].label}: reaches {thr:.3f} in {g} generations "
                         f"(no transfer: {g0}); {ev:,} episodes with its source's; {hit} of {n} runs reach it on "
                         "their own.")
    return lines + [""]


def curve_panel(ax, title: str, ylabel: str | None, legend_size: int, legend_loc: str) -> None:
    """A panel of curves over generations finished: its title and axis labels, and its legend, or "no runs
    yet" where it has no curve."""
    ax.set_title(title)
    ax.set_xlabel("generation")
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    if ax.lines:
        ax.legend(fontsize=legend_size, loc=legend_loc)
    else:
        ax.text(0.5, 0.5, "no runs yet", transform=ax.transAxes, ha="center", va="center", color="grey")


def _plots(rows: list[dict], out: pathlib.Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    targets = sorted({r["target"] for r in rows if r["phase"] == "target"}, key=t3.TARGETS.index)
    methods = [m for m in t3.METHODS if any(r["method"] == m and r["phase"] == "target" for r in rows)]
    if not targets:
        return []
    names = []
    fig, axes = plt.subplots(len(methods), len(targets), figsize=(4.2 * len(targets), 3.2 * len(methods)),
                             squeeze=False, sharey=True)
    colours = dict(zip(t3.SETUPS, ("tab:grey", "tab:blue", "tab:red", "tab:orange")))
    for i, m in enumerate(methods):
        for j, t in enumerate(targets):
            ax = axes[i][j]
            for s in t3.SETUPS:
                cs = [t3.curve(r, "best_so_far") for r in rows
                      if (r["method"], r["setup"], r["target"], r["phase"]) == (m, s, t, "target")]
                if not cs:
                    continue
                mean, lo, hi = stats.mean_band(cs)
                x = np.arange(mean.size)
                ax.plot(x, mean, color=colours[s], label=f"{t3.SETUPS[s].label} (n={len(cs)})")
                ax.fill_between(x, lo, hi, color=colours[s], alpha=0.2, linewidth=0)
            curve_panel(ax, f"{METHOD_NAMES[m]} {t}", "best-so-far training fitness" if j == 0 else None, 7,
                        "lower right")
    fig.tight_layout()
    fig.savefig(out / "progression.png", dpi=90, metadata={"Software": None})
    plt.close(fig)
    names.append("progression.png")

    fig, axes = plt.subplots(1, len(targets), figsize=(5.0 * len(targets), 3.6), squeeze=False)
    for j, t in enumerate(targets):
        ax = axes[0][j]
        labels, data = [], []
        for m in methods:
            for s in t3.SETUPS:
                v = [float(r["test_fitness"]) for r in rows
                     if (r["method"], r["setup"], r["target"], r["phase"]) == (m, s, t, "target")]
                if v:
                    labels.append(f"{METHOD_NAMES[m]}\n{t3.SETUPS[s].label}")
                    data.append(v)
        for k, v in enumerate(data):
            ax.scatter(np.full(len(v), k) + np.linspace(-0.15, 0.15, len(v)), v, s=12, color="tab:blue")
            ax.hlines(np.mean(v), k - 0.3, k + 0.3, color="black")
        ax.set_xticks(range(len(labels)), labels, fontsize=6, rotation=60, ha="right")
        ax.set_title(f"{t}: validated champions on the test states")
        ax.set_ylabel("test fitness")
    fig.tight_layout()
    fig.savefig(out / "test_champions.png", dpi=90, metadata={"Software": None})
    plt.close(fig)
    names.append("test_champions.png")
    return names


def _throughput(rows: list[dict], dsg: dict | None = None) -> list[str]:
    lines = ["| method | phase | runs | mean wall s per run | mean s per generation | runs per hour | "
             "ratio to the generations alone |", "|---|---|---|---|---|---|---|"]
    for m in t3.METHODS:
        for phase in ("source", "target"):
            rs = [r for r in rows if r["method"] == m and r["phase"] == phase]
            if not rs:
                continue
            wall = float(np.mean([float(r["wall_seconds"]) for r in rs]))
            gen = float(np.mean([float(r["generation_seconds"]) for r in rs]))
            per_gen = gen / float(np.mean([int(r["generations"]) for r in rs]))
            lines.append(f"| {METHOD_NAMES[m]} | {phase} | {len(rs)} | {wall:.1f} | {per_gen:.2f} | "
                         f"{3600 / wall:.1f} | {gen / wall:.2f} |")
    total = sum(float(r["wall_seconds"]) for r in rows)
    hours = {m: sum(float(r["wall_seconds"]) for r in rows if r["method"] == m) / 3600 for m in t3.METHODS}
    parts = ", ".join(f"{METHOD_NAMES[m]} {h:.1f} h" for m, h in hours.items() if h)
    measured = (f"Measured: the {len(rows)} runs here took **{total / 3600:.1f} hours** of wall time in all "
                f"(each run's share of its group's; {parts}).")
    if dsg is not None and dsg["role"] == "confirmatory":  # its plan is its own, not the full protocol's
        return lines + ["", measured]
    return lines + ["", measured, "", planning.full_protocol_estimate(rows)]


def _extended(rows: list[dict], dsg: dict) -> list[str]:
    if dsg["looks"] == "planned":
        return []
    cells = planning.extended_cells(rows, dsg["looks"][0])
    if not cells:
        return []
    targets = [c for c in cells if c["phase"] == "target"]
    by_cell = collections.defaultdict(list)
    for c in targets:
        by_cell[c["method"], c["setup"], c["runs"]].append(c["target"])
    sources = [c for c in cells if c["phase"] == "source"]
    claims = list(dict.fromkeys(k for c in targets for k in c["claims"]))
    text = (f"**Extended cells.** Past the protocol's {dsg['looks'][0]} runs a cell (up to {dsg['looks'][-1]}, where "
            f"the power figure at {dsg['looks'][0]} runs could not decide a primary comparison): "
            + "; ".join(f"{METHOD_NAMES[m]} {t3.SETUPS[s].label} in {', '.join(ts)} ({n} runs)"
                        for (m, s, n), ts in by_cell.items()))
    if sources:
        text += ("; with the sources of their transfer runs ("
                 + ", ".join(f"{METHOD_NAMES[c['method']]} {c['setup']} {c['target']}: {c['runs']}" for c in sources)
                 + ")")
    if claims:
        labels = {c.key: _label(c) for c in design.PRIMARY}
        text += (f". They enter the primary comparisons {'; '.join(labels[k] for k in claims)}, whose tests here are "
                 f"a second look at these cells after the one at {dsg['looks'][0]} runs, paid for by the sequential "
                 "plan")
    return [text + ".", ""]


def _design_text(dsg: dict) -> str:
    """The paragraph that says how the claims are decided under the design ``dsg``."""
    text = ("Decided by the design recorded in protocol.json (`kx/experiments/design.py`): each comparison pooled over "
            "the targets that have runs of both its cells by van Elteren's stratified rank-sum statistic with a "
            "cluster-robust variance (`kx.experiments.stats.clustered_van_elteren`), ")
    text += ("whose clusters are the runs that share a source: run i of a transfer cell in every target descends from "
             "source i, so its three targets are one cluster, and a no-transfer run is a cluster of its own; "
             if dsg["sources"] == "shared" else
             "each target run trained from a source of its own, so every run is a cluster of its own; ")
    if dsg["sources"] == "shared":
        text += ("a source that has run in some targets but not yet in all the others have (a cluster alone in its "
                 "pattern of targets, whose variance has no degrees of freedom) waits for the next look, and the "
                 "clusters column counts it as waiting; ")
    text += "Holm's correction within the paper's own comparisons (the primary family) per measure. "
    if dsg["looks"] == "planned":
        text += "One look, when every cell holds its planned runs (fixed in advance). "
    else:
        text += (f"The looks are paid for by a group-sequential plan (`kx/experiments/sequential.py`): looks at "
                 f"{' and '.join(str(v) for v in dsg['looks'])} runs a cell, O'Brien-Fleming-type alpha spending "
                 f"(Lan & DeMets 1983), each comparison decided at the last look it had by its sequential p-value, "
                 f"which Holm's step-down takes (Maurer & Bretz 2013). ")
    if dsg.get("corrected_after_runs"):
        text += "This plan and the clustered test were applied after the fact to the runs already made. "
    text += (f"*Supported*: significant the paper's way; *contradicted*: significant against it; *no meaningful "
             f"difference*: not significant, and the 95% interval of P(a > b) inside the margin "
             f"[{dsg['margin'][0]:.2f}, {dsg['margin'][1]:.2f}]; *not decided*: neither, with the estimate's direction "
             f"and size, the power at the observed effect and the runs a cell 80% would need.")
    return text


def _changes_section(changes: dict) -> list[str]:
    if not any(changes.values()):
        return ["**Against the first design** (van Elteren's test with the targets as independent strata, one look "
                "at every run, no margin): no verdict differs.", ""]
    lines = ["**Against the first design.** The verdicts that differ from what van Elteren's test with the targets as "
             "independent strata, one look at every run and no margin gives on the same runs, each with the step "
             "that changes it (the clustered test at one look, then the looks paid for, then the margin):", ""]
    for measure, rows in changes.items():
        if rows:
            lines += [f"*{measure}*", "", "| comparison (a vs b) | family | first design | corrected | why |",
                      "|---|---|---|---|---|"] + rows + [""]
    return lines


def _withheld(out: pathlib.Path, rows: list[dict], dsg: dict) -> pathlib.Path:
    """The report of a confirmatory folder short of its planned runs: its design and progress, no result (the
    design's one look is when every cell holds its runs)."""
    have = collections.Counter((r["method"], r["setup"], r["target"]) for r in rows if r["phase"] == "target")
    sources = sum(r["phase"] == "source" for r in rows)
    planned = {k: v for k, v in dsg["runs"].items()}
    md = ["# Table 3, confirmatory replication (kx): runs under way", "",
          "Generated by `python -m kx.experiments report` from `results.csv` alone. The design (protocol.json, "
          "committed before the first run) has one look, when every cell holds its planned runs: until then this "
          "report shows no result, only the progress.", "",
          _design_text(dsg), "",
          "| cell | runs planned a target | " + " | ".join(t3.TARGETS) + " |", "|---|---|" + "---|" * len(t3.TARGETS)]
    for key, n in planned.items():
        m, s = key.split("/")
        md.append(f"| {METHOD_NAMES[m]} {t3.SETUPS[s].label} | {n} | "
                  + " | ".join(str(have[(m, s, t)]) for t in t3.TARGETS) + " |")
    done = sum(min(have[(*k.split("/"), t)], n) for k, n in planned.items() for t in t3.TARGETS)
    total = sum(planned.values()) * len(t3.TARGETS)
    transfer = sum(n for k, n in planned.items() if t3.SETUPS[k.split("/")[1]].source_objective) * len(t3.TARGETS)
    undecidable = dsg.get("basis", {}).get("not decidable at an affordable cost", [])
    md += ["", f"{done} of {total} target runs and {sources} of {transfer} sources finished, in "
           f"{sum(float(r['wall_seconds']) for r in rows) / 3600:.2f} hours of wall time (each run's share of its "
           "group's).", ""]
    rest, uncosted = planning.confirmatory_rest(rows, dsg)
    md += [f"The rest at the finished runs' mean wall time per method and phase: about {rest / 3600:.1f} hours one "
           "after another" + (f", {uncosted} runs of a method and phase with none finished not counted" if uncosted
                              else "") + ".", ""]
    if undecidable:
        md += ["Declared in advance not decidable at an affordable cost (80% power needs more than "
               f"{dsg['most_runs']} runs a cell at the earlier folder's effect): " + "; ".join(undecidable) + ".", ""]
    md += ["To go on (it resumes what is under way and skips what is done):", "", "```",
           f"python -m kx.experiments confirm --out <this folder> --seed {rows[0]['protocol_seed']}", "```", ""]
    path = out / "report.md"
    path.write_text("\n".join(md))
    return path


def _platforms(rows: list[dict]) -> list[str]:
    """Where the runs were made (results.csv's ``platform``, :func:`kx.runtime.platform_label`), once a row
    records one: a row reproduces bit for bit on its own platform, not necessarily on another."""
    made = collections.Counter(r["platform"] for r in rows)
    if set(made) <= {""}:
        return []
    def runs(p):
        per = collections.Counter(METHOD_NAMES[r["method"]] for r in rows if r["platform"] == p)
        return f"{made[p]} run{'s' if made[p] > 1 else ''} (" + ", ".join(f"{m} {n}" for m, n in per.items()) + ")"

    parts = [f"{runs(p)} on `{p}`" for p in sorted(made) if p]
    if made[""]:
        parts.insert(0, f"{runs('')} {csvfile.UNRECORDED}")
    return ["", "Platforms (a run reproduces bit for bit on its own platform; a CPU without AVX-512 rounds the "
            "networks' products otherwise, docs/experiments.md \"Extendable anywhere\"): " + "; ".join(parts) + "."]


def _still_to_run(rows: list[dict]) -> list[str]:
    cells = planning.still_to_run(rows)
    if not cells:
        return [f"Nothing: every cell of the full protocol has its {design.RUNS_PER_CELL} runs."]
    lines = [f"The cells of the full protocol ({design.RUNS_PER_CELL} runs a cell) short of their runs, and what "
             "the missing runs cost one after another on this machine at the Cost table's mean wall time per run "
             "(\\*: a target with no run of its method yet, costed at the method's other targets; —: no run of "
             "the method's phase to cost it by). A protocol folder holding only results.csv, protocol.json and "
             "this report extends on another machine: a missing source is trained again first and must reproduce its "
             "row, or it is set aside and its targets wait while the other runs run (docs/experiments.md, "
             "\"Extendable anywhere\", says which machines give the same runs).", "",
             "| method | phase | task | setup | runs here | missing | hours |", "|---|---|---|---|---|---|---|"]
    for c in cells:
        setup = c["setup"] if c["phase"] == "source" else t3.SETUPS[c["setup"]].label
        hours = "—" if c["seconds"] is None else f"{c['seconds'] / 3600:.2f}" + ("\\*" if c["borrowed"] else "")
        lines.append(f"| {METHOD_NAMES[c['method']]} | {c['phase']} | {c['target']} | {setup} | {c['runs']} | "
                     f"{c['missing']} | {hours} |")
    costed = [c["seconds"] for c in cells if c["seconds"] is not None]
    cost = (f"**{sum(costed) / 3600:.1f} hours** for those costed" if costed
            else "none of them costed (no run of their method's phase here)")
    lines += ["", f"In all {sum(c['missing'] for c in cells)} runs, {cost}. To run them (each command resumes "
              "what is under way and skips what is done; `--targets` and `--setups` narrow it further):", "", "```"]
    for m in dict.fromkeys(c["method"] for c in cells):
        targets = [t for t in t3.TARGETS if any(c["method"] == m and c["target"] == t for c in cells)]
        lines.append(f"python -m kx.experiments table3 --runs {design.RUNS_PER_CELL} --methods {m} "
                     f"--targets {','.join(targets or t3.TARGETS)} --out <this folder>")
    return lines + ["```"]


def write(out: str | pathlib.Path) -> pathlib.Path:
    """Writes ``out/report.md`` and its PNGs from ``out/results.csv``; returns the report's path."""
    out = pathlib.Path(out)
    rows = t3.read_results(out / "results.csv")
    if not rows:
        raise t3.RunError(f"{out / 'results.csv'}: no finished runs to report")
    rows = sorted(rows, key=lambda r: (t3.METHODS.index(r["method"]), r["phase"], r["target"], r["setup"],
                                       int(r["run"])))
    targets = sorted({r["target"] for r in rows if r["phase"] == "target"}, key=t3.TARGETS.index)
    first = rows[0]
    src = [r for r in rows if r["phase"] == "source"]
    tgt = [r for r in rows if r["phase"] == "target"]
    dsg = design.of_folder(out)
    if dsg["role"] == "confirmatory" and not planning.complete(rows, dsg):
        return _withheld(out, rows, dsg)
    md = ["# Table 3: policy transfer and novelty search in keep-away (kx)", "",
          f"Generated by `python -m kx.experiments report` from `results.csv` alone: {len(tgt)} target runs and "
          f"{len(src)} source runs, protocol seed {first['protocol_seed']}; every target run's validated champion "
          f"played the same {first['test_trials']} test states of its target.", ""]
    gens = sorted({(r["method"], r["phase"], int(r["generations"]), int(r["population"]), int(r["trials"]),
                    int(r["episodes"])) for r in rows}, key=lambda g: (t3.METHODS.index(g[0]), g[1:]))
    md += ["Runs (method, phase: generations x population x trials):", ""]
    md += [f"- {METHOD_NAMES[m]} {p}: {g} x {pop} x {tr} = {g * pop * tr:,} episodes" if g * pop * tr == ep else
           f"- {METHOD_NAMES[m]} {p}: {g} x {ep // g:,} training episodes = {ep:,} episodes"
           for m, p, g, pop, tr, ep in gens]
    md += _platforms(rows)
    eff = efficiency(rows)
    md += ["", "Fitness is the portion of the maximum episode length (4500 grid iterations) the keepers hold the ball. "
           "The paper's numbers come from another simulator (its fitness is seconds held over a cap): compare "
           "orderings and significance, not values.", ""]
    pooled, details, changes = {}, [], {}
    for measure, what in MEASURES.items():
        cells = _cells(rows, measure)
        pooled[measure] = pooled_tests(_runs(rows, measure), dsg)
        changes[measure] = _changes(_runs(rows, measure), pooled[measure], dsg)
        md += [f"## Table 3 on {measure}", "", f"Mean (sd) over runs per cell, n its runs; {what}"
               + (" (the paper's values beside ours)." if measure == "max_fitness" else "."), ""]
        md += _table3(cells, targets, paper=(measure == "max_fitness")) + [""]
        details += [f"### Per cell ({measure}): IQM with a 95% bootstrap CI, Lilliefors normality", ""]
        details += _per_cell_stats(cells, targets)
        lines, _ = _tests(cells)
        details += ["", f"### Per target: two-sided Mann-Whitney U tests ({measure}; detail)", "",
                    "A: the Vargha-Delaney effect size, the probability that a run of the first setup beats one of "
                    "the second (ties half; 0.5 no effect), which for one task is also Agarwal et al.'s probability "
                    "of improvement; its 95% CI by bootstrap. Holm's correction over this table's comparisons. The "
                    "claims are decided by the pooled tests above, not by these.", ""]
        details += lines + [""]
    md += ["## The paper's claims on these runs", "", _design_text(dsg), ""]
    md += _extended(rows, dsg) + _verdicts(pooled) + _efficiency_claim(eff)
    md += _changes_section(changes)
    for measure in MEASURES:
        md += [f"### Primary family ({measure})", "",
               f"P(a > b): the probability of improvement averaged over the targets, with its 95% CI from a bootstrap "
               f"of whole clusters ({dsg['cluster_resamples']} resamples); clusters: each cell's (runs sharing a "
               f"source count once; \"+k waiting\": clusters whose runs are in targets no other cluster of its cell "
               f"has runs in, a source not yet run where the others have, left out of this look, since alone they "
               f"leave the variance unknown); t (df) and p: the clustered test at the comparison's last look (its "
               f"sign, the direction; a dash and the reason where it has no statistic, as when nothing varies or a "
               f"lone cluster cannot wait because its cell would have no run in a target without it: p is then 1); "
               f"looks: how many of the plan's looks the comparison had (a cell short of the first look's runs is "
               f"read at that look's boundary: its verdict is an interim reading that can change as runs land); "
               f"sequential p: the smallest level "
               f"at which the plan rejects at one of them; Holm over the family the design fixes (claims without runs "
               f"count with p = 1); power: the probability of p < {design.ALPHA} / (the family's size) in the "
               f"observed direction, at the observed effect, resampling each cell's clusters "
               f"({stats.POWER_RESAMPLES} resamples), with these runs and with the runs a cell shown.", ""]
        md += _pooled_table(pooled[measure], "primary") + [""]
        md += [f"### Secondary family, exploratory ({measure})", "",
               "kx's additions: the hybrid without transfer, transfer with the hybrid on both sides (the comparison "
               "the paper's design confounds), HyperNEAT against NEAT in that fourth setup, and CMA-ES. Holm within "
               "this family.", ""]
        md += _pooled_table(pooled[measure], "secondary") + [""]
    md += ["## Detail per cell and per target", ""] + details
    md += ["## Efficiency", "", "The generations a setup's mean best-so-far training fitness takes to reach the "
           "no-transfer setup's final mean best-so-far (the paper's threshold), the episodes played by then, "
           "its source run's included, and how many runs reach the threshold on their own within the budget.", "",
           "| method | target | setup | threshold | generations | episodes | runs reaching it |",
           "|---|---|---|---|---|---|---|"]
    for m, t, s, thr, g, ev, hit, n in eff:
        md.append(f"| {METHOD_NAMES[m]} | {t} | {t3.SETUPS[s].label} | {thr:.3f} | {'never' if g is None else g} | "
                  f"{'—' if ev is None else f'{ev:,}'} | {hit} of {n} |")
    md += [""]
    names = _plots(rows, out)
    md += ["## Plots", ""]
    md += [f"![{n}]({n})" for n in names]
    md += ["", "## Cost", "", "Wall time per run (its share of its batched group's training: compilation, "
           "validation and checkpoints included, the test not; a resumed run's generations before its resumption "
           "at their recorded times) against the "
           "sum of its generations' own times, both measured in the protocol's process (and divided among the "
           "local processes that shared the machine's cores).", ""]
    md += _throughput(rows, dsg)
    md += ["", "## Still to run", ""] + (["Nothing: every cell of the design holds its planned runs."]
                                          if dsg["role"] == "confirmatory" else _still_to_run(rows))
    md += ["", "## Where kx differs from the paper", ""] + DIFFERENCES
    md += ["", "Statistics: scipy (Mann-Whitney U, bootstrap), statsmodels (Lilliefors, Holm). The `rliable` library "
           "does not install with kx's pinned stack (arch 7.2.0, which rliable 1.2.0 requires, fails to import "
           f"with pandas 3), so the IQM and probability-of-improvement intervals are scipy's percentile bootstrap "
           f"({stats.RESAMPLES} resamples, seed {stats.BOOTSTRAP_SEED}) over the runs of a cell (for one task, "
           "the stratified bootstrap).", ""]
    path = out / "report.md"
    path.write_text("\n".join(md))
    return path
