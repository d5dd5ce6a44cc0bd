"""Ablation sweeps: every combination of a grid of config fields x seeds, on the run loop of ``kx.train``.

``python -m kx.experiments sweep --config F --grid field=v1,v2 [--grid ...] --seeds 0-9 --out DIR`` trains
one run per (combination, seed) in ``DIR/runs/<combination>/seed<k>`` (resumed from its checkpoint if the
sweep was killed, never redone once finished: results.csv's rows are keyed by the whole combination, its
``overrides``; the folder's name is :func:`names`'), plays each run's validated champion on the same
``test_trials`` test states of its task (the test stream of ``test_seed``), and appends one row per run
to ``DIR/results.csv``; ``DIR/report.md`` and ``DIR/sweep.png`` are written from it alone. A grid
dimension ``config=FILE1,FILE2`` varies the config file itself (Table 2's two readings, say).
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import pathlib
from typing import Callable

import numpy as np

from kx.evolve import config as cfg_lib
from kx.evolve import outputs as run_outputs
from kx.evolve.errors import RunError
from kx.experiments import csvfile, measure, processes, runner, stats

FIELDS = ("combination", "overrides", "seed", "task", "method", "generations", "episodes", "max_fitness",
          "test_fitness", "test_trials", "test_seed", "champion_generation", "wall_seconds")


@dataclasses.dataclass(frozen=True)
class Sweep:
    config: str | None  # the config file, as given (None: the grid's ``config`` dimension names them)
    grid: tuple[tuple[str, tuple[str, ...]], ...]  # (field, values) in the given order
    seeds: tuple[int, ...]
    test_trials: int = 1000
    test_seed: int = 0
    overrides: tuple[str, ...] = ()  # fixed overrides applied to every run

    def to_json(self) -> dict:
        return {"config": self.config, "grid": [[f, list(v)] for f, v in self.grid], "seeds": list(self.seeds),
                "test_trials": self.test_trials, "test_seed": self.test_seed, "overrides": list(self.overrides)}

    def combinations(self) -> list[tuple[str, ...]]:
        """Every combination's overrides (``field=value`` per grid field), the first field varying slowest;
        :func:`key` names one whole."""
        return [tuple(f"{f}={v}" for f, v in zip([f for f, _ in self.grid], vs))
                for vs in itertools.product(*[v for _, v in self.grid])]


def parse_grid(items) -> tuple[tuple[str, tuple[str, ...]], ...]:
    out = []
    for item in items:
        field, sep, values = item.partition("=")
        vals = tuple(v for v in values.split(",") if v)
        if not sep or not field or not vals or any(ch.isspace() for ch in item):
            raise ValueError(f"--grid: allowed field=value1,value2,... (no spaces), got {item!r}")
        if field in [f for f, _ in out]:
            raise ValueError(f"--grid: {field} given twice")
        out.append((field, vals))
    if not out:
        raise ValueError("--grid: at least one field=value1,value2,...")
    return tuple(out)


def key(combination: tuple[str, ...]) -> str:
    """The whole combination as one text, its ``field=value`` overrides joined by spaces (results.csv's
    ``overrides``): what keys a finished run, with its seed (no grid value holds a space, :func:`parse_grid`)."""
    return " ".join(combination)


def slug(combination: tuple[str, ...]) -> str:
    """A combination's readable name: its overrides with ``=``, ``/`` and ``.`` as ``-``, joined by ``_``."""
    return "_".join(c.replace("=", "-").replace("/", "-").replace(".", "-") for c in combination)


#: the longest name of a combination's folder (:func:`names`)
NAME_LENGTH = 120


def names(combinations: list[tuple[str, ...]]) -> dict[tuple[str, ...], str]:
    """Each combination's name: its folder ``DIR/runs/<name>`` and results.csv's ``combination``. Its
    :func:`slug`, unless that is longer than :data:`NAME_LENGTH` or another combination of the sweep has the
    same slug (``x=1.5`` and ``x=1-5``): then the slug cut to ``NAME_LENGTH - 17`` characters and ``-`` and
    16 hex digits of a hash of the whole combination (:func:`key`), so that two combinations sharing their
    first 120 characters keep apart."""
    slugs = [slug(c) for c in combinations]
    out = {}
    for c, s in zip(combinations, slugs):
        if len(s) > NAME_LENGTH or slugs.count(s) > 1:
            digest = hashlib.blake2b(key(c).encode(), digest_size=8).hexdigest()
            s = f"{s[:NAME_LENGTH - 17]}-{digest}"
        out[c] = s
    return out


def _config(sweep: Sweep, combination: tuple[str, ...], seed: int):
    """The run's config: ``--config`` (or the combination's ``config=FILE``) with the fixed overrides,
    the combination's, no GIF, and the seed."""
    files = [c.partition("=")[2] for c in combination if c.startswith("config=")]
    fields = [c for c in combination if not c.startswith("config=")]
    path = files[0] if files else sweep.config
    if path is None:
        raise ValueError("--config: a config file, or a --grid config=FILE1,FILE2 dimension")
    if not pathlib.Path(path).is_file():
        raise ValueError(f"--config: {path} is not a file")
    return cfg_lib.load(path, [*sweep.overrides, *fields, "gif=false", f"seed={seed}"])


def read_results(path: pathlib.Path) -> list[dict]:
    return csvfile.read(path, FIELDS, "kx sweep results file")


def _row_key(row: dict) -> tuple:
    return (row["overrides"], int(row["seed"]))


def run(out: str | pathlib.Path, sweep: Sweep, log: Callable[[str], None] = print, batch: int = 16,
        shard: processes.Shard = processes.ALONE) -> list[dict]:
    """Runs every (combination, seed) not yet in ``out/results.csv``, the seeds of each combination in
    batched groups of up to ``batch`` (:mod:`kx.evolve.group`; 1: one by one; each run's results are the
    same either way, its ``wall_seconds`` its share of its group's); returns all rows. Under several
    processes (``shard``, :mod:`kx.experiments.processes`) each trains the runs it owns (the i-th (combination, seed)
    of the grid when i modulo the processes is its index) into its own process file, which the leader
    merges into results.csv."""
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"--batch: allowed an integer >= 1, got {batch!r}")
    out = pathlib.Path(out).absolute()
    combos = sweep.combinations()
    for c in combos:  # every config checked before any compute
        cfg_lib.validate(_config(sweep, c, sweep.seeds[0]))
    spec_path = out / "sweep.json"
    ledger = runner.Ledger(out / "results.csv", FIELDS, "kx sweep results file", _row_key, _row_key, "sweep", shard)
    if shard.leader:
        out.mkdir(parents=True, exist_ok=True)
    ledger.start()
    if spec_path.is_file():
        have = json.loads(spec_path.read_text())
        if have != sweep.to_json():
            diff = [k for k in have if have[k] != sweep.to_json().get(k)]
            raise RunError(f"{out} holds another sweep (differs in {', '.join(diff)}): use another --out")
    elif shard.leader:
        run_outputs.write_json(spec_path, sweep.to_json())
    shard.barrier("sweep sweep.json")
    rows = ledger.open()
    done = {(r["overrides"], int(r["seed"])) for r in rows}
    name = names(combos)
    total = len(combos) * len(sweep.seeds)
    place = {(key(c), s): i for i, (c, s) in enumerate((c, s) for c in combos for s in sweep.seeds)}
    todo = [(c, [s for s in sweep.seeds if (key(c), s) not in done and shard.owns(place[(key(c), s)])])
            for c in combos]
    chunks = [(c, seeds[i:i + batch]) for c, seeds in todo for i in range(0, len(seeds), batch)]
    n_done = total - sum(len(seeds) for _, seeds in todo)
    log(f"kx sweep: {total} runs, {n_done} done, {total - n_done} to run -> {out}")
    for c, seeds in chunks:
        cfgs = [_config(sweep, c, seed) for seed in seeds]
        dirs = [out / "runs" / name[c] / f"seed{seed}" for seed in seeds]
        which = f"seed{'s' if len(seeds) > 1 else ''} {','.join(map(str, seeds))}"
        prefix = f"[{n_done}/{total} runs | {' '.join(c)} {which}]"
        show = lambda s: log(f"{prefix} {' '.join(s.split()[:6])}") if s.startswith("gen ") else None  # noqa: E731
        measured = measure.train_and_measure(cfgs, dirs, sweep.test_seed, sweep.test_trials, log=show)
        for cfg, seed, finished in zip(cfgs, seeds, measured):
            row = {"combination": name[c], "overrides": key(c), "seed": seed, "task": cfg.task,
                   "method": cfg.method, "generations": cfg.generations,
                   "episodes": cfg.generations * cfg.population_size * cfg.trials,
                   "max_fitness": finished.max_fitness, "test_fitness": finished.test,
                   "test_trials": sweep.test_trials, "test_seed": sweep.test_seed,
                   "champion_generation": int(finished.state.champion_generation),
                   "wall_seconds": finished.wall_seconds}
            ledger.append(row)
            n_done += 1
            log(f"[{n_done}/{total} runs | {' '.join(c)} seed {seed}] test {finished.test:.4f}, max fitness "
                f"{finished.max_fitness:.4f}")
    return ledger.finish()


def write_report(out: str | pathlib.Path) -> pathlib.Path:
    """``out/report.md`` (one table: per combination the validated champions on the test states, mean, sd,
    IQM with its 95% bootstrap CI) and ``out/sweep.png``, from ``out/results.csv`` alone."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = pathlib.Path(out)
    rows = read_results(out / "results.csv")
    if not rows:
        raise RunError(f"{out / 'results.csv'}: no finished runs to report")
    order = list(dict.fromkeys(r["overrides"] for r in rows))  # the whole combinations, in the order they ran
    by = {c: [r for r in rows if r["overrides"] == c] for c in order}
    first = rows[0]
    md = ["# Sweep", "", f"Generated by `python -m kx.experiments report` from `results.csv` alone: {len(rows)} runs "
          f"of {first['method']} in {first['task']}; each run's validated champion played the same "
          f"{first['test_trials']} test states (test seed {first['test_seed']}).", "",
          "| overrides | runs | seeds | test mean | sd | IQM [95% CI] | max training fitness (mean) | "
          "episodes per run |",
          "|---|---|---|---|---|---|---|---|"]
    data = []
    for c in order:
        rs = sorted(by[c], key=lambda r: int(r["seed"]))
        v = np.asarray([float(r["test_fitness"]) for r in rs])
        data.append(v)
        ci = stats.iqm_interval(v)
        lo = "—" if np.isnan(ci.low) else f"{ci.low:.3f}"
        hi = "—" if np.isnan(ci.high) else f"{ci.high:.3f}"
        md.append(f"| {rs[0]['overrides']} | {len(rs)} | {','.join(r['seed'] for r in rs)} | {v.mean():.4f} | "
                  f"{v.std(ddof=1) if v.size > 1 else 0:.4f} | {ci.value:.4f} [{lo}, {hi}] | "
                  f"{np.mean([float(r['max_fitness']) for r in rs]):.4f} | {rs[0]['episodes']} |")
    fig, ax = plt.subplots(figsize=(max(4.0, 1.3 * len(order)), 3.6))
    for k, v in enumerate(data):
        ax.scatter(np.full(v.size, k) + np.linspace(-0.15, 0.15, v.size), v, s=14, color="tab:blue")
        ax.hlines(v.mean(), k - 0.3, k + 0.3, color="black")
    ax.set_xticks(range(len(order)), [by[c][0]["overrides"].replace(" ", "\n") for c in order], fontsize=6)
    ax.set_ylabel("validated champion, test fitness")
    fig.tight_layout()
    fig.savefig(out / "sweep.png", dpi=90, metadata={"Software": None})
    plt.close(fig)
    md += ["", "![sweep.png](sweep.png)", ""]
    path = out / "report.md"
    path.write_text("\n".join(md))
    return path
