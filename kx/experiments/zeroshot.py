"""The zero-shot study: every learner trained on 3v2 alone, its validated champion played unchanged
on the test states of 3v2, 4v3, 5v3 and 6v4, beside the hand-coded policies, and set against the same learner
trained in the target (Table 3's no-transfer runs) and against NEAT evolved 50 generations in the target (the goal).

``python -m kx.experiments zeroshot --out DIR [--learners neat,...] [--seeds 0-9] [--config-of LEARNER=FILE]`` trains
each (learner, seed) not yet in ``DIR/results.csv`` in ``DIR/runs/<learner>/seed<k>`` (resumed from its checkpoint
after a kill, never redone once its row is written: :func:`kx.experiments.measure.train_and_measure`, as a sweep's),
and appends one row per run: the champion's mean fitness on ``test_trials`` test states of each task, the test stream
of ``test_seed`` (:func:`kx.evolve.streams.test`). The defaults are Table 3's (protocol seed 0, 1000 states a task),
so that a zero-shot score and a trained-in-target score are measured on the same states (their digests are recorded
in ``DIR/zeroshot.json`` beside each learner's config file and its whole resolved config; the report compares them
with docs/table3's). The hand-coded policies (:data:`kx.sim.policies.BASELINES`) play the same states once
(``DIR/baselines.csv``). ``DIR/report.md`` and ``DIR/zeroshot.png`` are written from the folder's files and
docs/table3's results alone (:func:`write_report`).

A champion plays another task as ``kx.bench learning`` plays it: its encoding's policy for that task's world
(``encoding.policy_for(sim)``): the fixed 13-input layout, HyperNEAT's substrate and the entity network fit every
team size.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import time
from typing import Callable

import numpy as np

from kx import runtime
from kx.evolve import config as cfg_lib
from kx.evolve import outputs as run_outputs
from kx.evolve.checkpoint import RunLock
from kx.evolve.errors import ConfigError, RunError
from kx.experiments import csvfile, design, measure, runner, stats
from kx.experiments import table3 as t3

#: the learners and the shipped config each trains with (``--config-of`` swaps one)
LEARNERS = {"neat": "configs/neat_3v2.py", "hyperneat": "configs/hyperneat_3v2.py", "cma_es": "configs/cma_es_3v2.py",
            "ppo": "configs/ppo_3v2.py", "ppo_entity": "configs/ppo_entity_3v2.py",
            "ppo_entity_mix": "configs/ppo_entity_mix.py"}
SOURCE = t3.SOURCE_TASK
TASKS = (SOURCE, *t3.TARGETS)
#: the seeds a learner the issue asks for
SEEDS_ASKED = 10
#: Table 3's test states (docs/table3/protocol.json: the test stream of its protocol seed, 1000 states a task)
TEST_SEED, TEST_TRIALS = 0, 1000
TABLE3 = "docs/table3"
ROOT = pathlib.Path(__file__).resolve().parents[2]
SCORES = tuple(f"test_{t}" for t in TASKS)
FIELDS = ("learner", "config", "seed", "method", "trained", "generations", "episodes", "max_fitness",
          "champion_generation", *SCORES, "test_trials", "test_seed", "wall_seconds", "test_seconds",
          "platform")  # where the run was made (kx.runtime.platform_label; empty before 2026-12-07: csvfile.ADDED)
WHAT = "kx zeroshot results file"
BASELINE_FIELDS = ("policy", "task", "test_fitness", "test_trials", "test_seed")


@dataclasses.dataclass(frozen=True)
class Study:
    learners: tuple[str, ...] = tuple(LEARNERS)
    seeds: tuple[int, ...] = tuple(range(SEEDS_ASKED))
    test_trials: int = TEST_TRIALS
    test_seed: int = TEST_SEED
    configs: tuple[tuple[str, str], ...] = ()  # (learner, config file): what replaces LEARNERS' file
    overrides: tuple[str, ...] = ()  # config overrides for every learner ("population_size=10", ...)
    table3: str = TABLE3  # the Table 3 folder whose no-transfer cells the report divides by (relative: to the checkout)

    def config_file(self, learner: str) -> str:
        return dict(self.configs).get(learner, LEARNERS[learner])

    def config(self, learner: str, seed: int):
        """The run's config: the learner's file, the study's overrides, no GIF, the seed."""
        return cfg_lib.load(self.config_file(learner), [*self.overrides, "gif=false", f"seed={seed}"])


def parse_config_of(items) -> tuple[tuple[str, str], ...]:
    """``--config-of LEARNER=FILE`` items as (learner, file) pairs."""
    out = []
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or name not in LEARNERS or not path or name in dict(out):
            raise ValueError(f"--config-of: allowed LEARNER=FILE, each learner once, with LEARNER one of "
                             f"{', '.join(LEARNERS)}; got {item!r}")
        out.append((name, path))
    return tuple(out)


def trained_on(cfg) -> str:
    """The tasks a run of ``cfg`` learns from: its task, and the entity network's mix (``3v2+4v3``)."""
    mix = cfg[cfg.method].get("mix", "") if cfg.method in cfg else ""
    return "+".join([cfg.task, *[t.strip() for t in mix.split(",") if t.strip()]])


def _resolved(cfg) -> dict:
    """The whole config but its seed, as JSON holds it."""
    d = json.loads(json.dumps(cfg.to_dict()))
    d.pop("seed")
    return d


def check(study: Study) -> dict:
    """Every input checked before any compute, each error naming its field and what it allows; returns the learners'
    configs (of the first seed)."""
    t3.check_choice("--learners", study.learners, LEARNERS)
    if len(set(study.learners)) != len(study.learners):
        raise ValueError(f"--learners: allowed {', '.join(LEARNERS)}, each once, got {', '.join(study.learners)}")
    seeds = study.seeds
    if not seeds or len(set(seeds)) != len(seeds) or any(not isinstance(s, int) or not 0 <= s < 2**31 for s in seeds):
        raise ValueError(f"--seeds: allowed distinct integers in [0, 2**31), got {seeds!r}")
    for name, v, low in (("--test-trials", study.test_trials, 1), ("--test-seed", study.test_seed, 0)):
        if not isinstance(v, int) or not low <= v < 2**31:
            raise ValueError(f"{name}: allowed an integer in [{low}, 2**31), got {v!r}")
    parse_config_of(f"{n}={p}" for n, p in study.configs)
    cfgs = {}
    for learner in study.learners:
        try:
            cfg = study.config(learner, seeds[0])
            cfg_lib.validate(cfg)
        except ConfigError as e:
            raise ConfigError(f"{learner} ({study.config_file(learner)}): {e}") from None
        if cfg.task != SOURCE:
            raise ValueError(f"--config-of: {learner}'s config {study.config_file(learner)} trains in {cfg.task}; the "
                             f"study trains every learner in {SOURCE}")
        cfgs[learner] = cfg
    worlds = {n: c.sim.to_dict() for n, c in cfgs.items()}
    first = next(iter(worlds))
    other = [n for n, w in worlds.items() if w != worlds[first]]
    if other:
        raise ValueError(f"sim: {', '.join(other)} set another world than {first}: the study plays every champion and "
                         "the hand-coded policies in one world")
    return cfgs


def world(sim_section, task: str):
    """``(sim, sim_params)`` of ``task`` in the world of a config's ``sim`` section."""
    c = cfg_lib.base_config()
    c.task = task
    c.sim.update(sim_section.to_dict())
    exp = cfg_lib.validate(c)
    return exp.sim, exp.sim_params


def test_states(sim_section, test_seed: int, test_trials: int) -> dict:
    """``{task: (sim, sim_params, starts)}``: each task's test states, as every run of the task is measured on
    (:func:`kx.experiments.measure.held_out_states`), and the key of their kick noise (``"key"``)."""
    from kx.evolve import streams
    from kx.sim import env

    keys = streams.test(test_seed)
    out = {"key": keys.eval}
    for task in TASKS:
        sim, params = world(sim_section, task)
        out[task] = (sim, params, env.reset_batch(keys.starts, test_trials, params, sim))
    return out


def play(encoding, champion, sim, params, starts, key) -> float:
    """A champion's mean fitness on ``starts`` of the world ``sim``, unchanged (``encoding.policy_for(sim)``)."""
    from kx.evolve.encoding import stack
    from kx.sim import evaluate as ev

    return float(ev.evaluate(encoding.policy_for(sim), encoding.policy_params(stack([champion])), starts, params, sim,
                             key=key).fitness.mean())


def baselines(states: dict) -> list[dict]:
    """The hand-coded policies (:data:`kx.sim.policies.BASELINES`) on each task's test states."""
    from kx.sim import evaluate as ev
    from kx.sim.policies import BASELINES

    return [{"policy": name, "task": task, "test_fitness": float(ev.evaluate(
        make(states[task][0]), None, states[task][2], states[task][1], states[task][0], key=states["key"]
    ).fitness.mean())} for name, make in BASELINES.items() for task in TASKS]


def record(study: Study, cfgs: dict) -> dict:
    """What ``DIR/zeroshot.json`` fixes (test states, overrides, the Table 3 folder, each learner's config)."""
    return {"test_seed": study.test_seed, "test_trials": study.test_trials, "overrides": list(study.overrides),
            "table3": study.table3,
            "learners": {n: {"config": study.config_file(n), "method": c.method, "trained": trained_on(c),
                             "resolved": _resolved(c)} for n, c in cfgs.items()}}


def _differences(have: dict, want: dict) -> list[str]:
    """What in the record ``want`` differs from ``have``: a field of the study, or a learner both record with
    other configs (a config read from another file but resolving to the same fields is the same learner)."""
    diff = [f"{k}: {have.get(k)!r} there, {want[k]!r} now" for k in want if k != "learners" and have.get(k) != want[k]]
    for n, w in want["learners"].items():
        h = have["learners"].get(n)
        if h is not None and {**h, "config": w["config"]} != w:
            fields = sorted(k for k in set(cfg_lib.flatten(h["resolved"])) | set(cfg_lib.flatten(w["resolved"]))
                            if cfg_lib.flatten(h["resolved"]).get(k) != cfg_lib.flatten(w["resolved"]).get(k))
            diff.append(f"learners.{n}: config {h['config']} there, {w['config']} now"
                        + (f" (fields {', '.join(fields)})" if fields else ""))
    return diff


def _agree(out: pathlib.Path, have: dict, want: dict) -> dict:
    """The folder's record with ``want``'s new learners added; ``RunError`` naming what differs
    (:func:`_differences`). A learner's config from another file that resolves to the same fields keeps the
    folder's record, and the file it names."""
    diff = _differences(have, want)
    if diff:
        raise RunError(f"{out} holds another zero-shot study ({'; '.join(diff)}): use another --out, or the same test "
                       "states, overrides and configs to add runs to it; nothing was run")
    return _joined(have, want)


def _joined(have: dict, want: dict) -> dict:
    """The record ``have`` with the learners only ``want`` records added after its own."""
    return {**have, "learners": {**have["learners"], **{n: w for n, w in want["learners"].items()
                                                        if n not in have["learners"]}}}


def _row_key(row: dict) -> tuple:
    return (row["learner"], int(row["seed"]))


def _order(row: dict) -> tuple:
    return (list(LEARNERS).index(row["learner"]), int(row["seed"]))


def read_results(out: pathlib.Path) -> list[dict]:
    return csvfile.read(pathlib.Path(out) / "results.csv", FIELDS, WHAT)


def _finish(ledger: runner.Ledger, out: pathlib.Path) -> list[dict]:
    """results.csv's rows in the study's order (learner, seed: a resumed run's row joins its place), as strings."""
    ledger.finish()
    rows = read_results(out)
    ordered = sorted(rows, key=_order)
    if ordered != rows:
        csvfile.write(out / "results.csv", FIELDS, ordered)
    return ordered


def run(out: str | pathlib.Path, study: Study, log: Callable[[str], None] = print, batch: int = 16) -> list[dict]:
    """Trains and measures every (learner, seed) of ``study`` not yet in ``out/results.csv``, the seeds of a learner in
    batched groups of up to ``batch`` (1: one by one; the rows are the same but for the times); returns every row of
    ``out/results.csv``.
    Every input, config and the folder's record are checked before any compute. One process at a time writes a
    folder: it holds ``out/run.lock`` (:class:`kx.evolve.checkpoint.RunLock`) while it runs."""
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"--batch: allowed an integer >= 1, got {batch!r}")
    out = pathlib.Path(out).absolute()
    cfgs = check(study)
    with RunLock(out, log):
        return _run(out, study, cfgs, log, batch)


def _run(out: pathlib.Path, study: Study, cfgs: dict, log: Callable[[str], None], batch: int) -> list[dict]:
    spec_path = out / "zeroshot.json"
    want = record(study, cfgs)
    have = json.loads(spec_path.read_text()) if spec_path.is_file() else None
    merged = want if have is None else _agree(out, have, want)
    ledger = runner.Ledger(out / "results.csv", FIELDS, WHAT, _row_key, _order, "zeroshot")
    out.mkdir(parents=True, exist_ok=True)
    ledger.start()
    rows = ledger.open()
    done = {_row_key(r) for r in rows}
    todo = {n: [s for s in study.seeds if (n, s) not in done] for n in study.learners}
    total, left = len(study.learners) * len(study.seeds), sum(map(len, todo.values()))
    log(f"kx zeroshot: {total} runs, {total - left} done, {left} to run -> {out}")
    if not left and have is not None and (out / "baselines.csv").is_file():
        return _finish(ledger, out)
    states = test_states(next(iter(cfgs.values())).sim, study.test_seed, study.test_trials)
    digests = {t: design.states_digest(states[t][2]) for t in TASKS}
    if have is not None and have.get("test_states", {}).get("sha256") != digests:
        raise RunError(f"{spec_path}: test_states: this code draws other test states than the folder's runs were "
                       "measured on: use another --out; nothing was run")
    merged["test_states"] = {"stream": "kx.evolve.streams.test(seed)", "sha256": digests}
    run_outputs.write_json(spec_path, merged)
    if not (out / "baselines.csv").is_file():
        base = baselines(states)
        csvfile.write(out / "baselines.csv", BASELINE_FIELDS,
                      [{**b, "test_trials": study.test_trials, "test_seed": study.test_seed} for b in base])
        log("hand-coded policies: " + "; ".join(f"{b['policy']} {b['task']} {b['test_fitness']:.4f}" for b in base))
    n_done = total - left
    for learner in study.learners:
        for i in range(0, len(todo[learner]), batch):
            seeds = todo[learner][i:i + batch]
            group = [study.config(learner, s) for s in seeds]
            dirs = [out / "runs" / learner / f"seed{s}" for s in seeds]
            show = lambda s: log(f"[{n_done}/{total} runs | {learner}] {' '.join(s.split()[:6])}") \
                if s.startswith("gen ") else None  # noqa: E731
            for cfg, seed, finished in zip(group, seeds, measure.train_and_measure(
                    group, dirs, study.test_seed, study.test_trials, log=show)):
                t0 = time.perf_counter()
                enc, champion = finished.trainer.encoding, finished.state.champion
                scores = {f"test_{t}": play(enc, champion, *states[t], states["key"]) for t in t3.TARGETS}
                row = {"learner": learner, "config": merged["learners"][learner]["config"], "seed": seed,
                       "method": cfg.method,
                       "trained": trained_on(cfg), "generations": cfg.generations, "episodes": t3.episodes(cfg),
                       "max_fitness": finished.max_fitness,
                       "champion_generation": int(finished.state.champion_generation),
                       f"test_{SOURCE}": finished.test, **scores, "test_trials": study.test_trials,
                       "test_seed": study.test_seed, "wall_seconds": finished.wall_seconds,
                       "test_seconds": round(time.perf_counter() - t0, 3), "platform": runtime.platform_label()}
                ledger.append(row)
                n_done += 1
                log(f"[{n_done}/{total} runs | {learner} seed {seed}] " + ", ".join(
                    f"{t} {row[f'test_{t}']:.4f}" for t in TASKS) + f" ({row['wall_seconds']:.1f} s training, "
                    f"{row['test_seconds']:.1f} s zero-shot tests)")
    return _finish(ledger, out)


def merge(out: str | pathlib.Path, other: str | pathlib.Path, log: Callable[[str], None] = print) -> list[dict]:
    """The rows of the study folder ``other`` joined to ``out``'s, with the records of its learners: the same study
    run elsewhere (another machine, or another process training other learners into a folder of its own). Refused
    before anything is written, naming what differs, unless both folders record the same test states (their
    digests), overrides and Table 3 folder, the learners both record the same configs, and a (learner, seed) both
    hold the same row but for its times; the hand-coded policies' rows must agree too (``out`` takes ``other``'s if
    it has none). Run directories are not copied (a run of ``other`` resumes only there). Both folders are locked
    while they are read and written; returns ``out``'s rows."""
    out, other = pathlib.Path(out).absolute(), pathlib.Path(other).absolute()
    if out == other:
        raise ValueError(f"--merge: allowed another study folder than --out, got {other}")
    with RunLock(out, log), RunLock(other, log):
        recs = {}
        for d in (out, other):
            if not (d / "zeroshot.json").is_file():
                raise RunError(f"{d}: no zeroshot.json: not a zero-shot study's folder; nothing was merged")
            recs[d] = json.loads((d / "zeroshot.json").read_text())
        if "test_states" not in recs[other] or "test_states" not in recs[out]:
            raise RunError(f"{other if 'test_states' not in recs[other] else out}: no test states recorded (a study "
                           "that never ran); nothing was merged")
        diff = _differences(recs[out], recs[other])
        if diff:
            raise RunError(f"{other} holds another zero-shot study than {out} ({'; '.join(diff)}); nothing was merged")
        mine, theirs = read_results(out), read_results(other)
        fixed = [f for f in FIELDS if f not in ("config", "wall_seconds", "test_seconds", "platform")]
        have = {_row_key(r): r for r in mine}
        clash = [k for r in theirs if (k := _row_key(r)) in have and any(have[k][f] != r[f] for f in fixed)]
        if clash:
            raise RunError(f"{other}: the rows of {', '.join(f'{n} seed {s}' for n, s in clash)} differ from {out}'s "
                           "in more than their times; nothing was merged")
        base = {d: csvfile.read(d / "baselines.csv", BASELINE_FIELDS, "kx zeroshot baselines file")
                if (d / "baselines.csv").is_file() else None for d in (out, other)}
        if base[out] is not None and base[other] is not None and base[out] != base[other]:
            raise RunError(f"{other}/baselines.csv: the hand-coded policies' rows differ from {out}'s; nothing was "
                           "merged")
        new = [r for r in theirs if _row_key(r) not in have]
        # the records first: a row never lacks its learner's
        run_outputs.write_json(out / "zeroshot.json", _joined(recs[out], recs[other]))
        if base[out] is None and base[other] is not None:
            csvfile.write(out / "baselines.csv", BASELINE_FIELDS, base[other])
        rows = sorted([*mine, *new], key=_order)
        csvfile.write(out / "results.csv", FIELDS, rows)
        log(f"kx zeroshot: {len(new)} rows of {other} joined {out} ("
            + (", ".join(f"{r['learner']} seed {r['seed']}" for r in new) or "none new") + f"); {len(rows)} rows")
        return rows


# ------------------------------------------------------------------------------------------------ the report

def _table3_folder(rec: dict) -> pathlib.Path:
    path = pathlib.Path(rec["table3"])
    return path if path.is_absolute() else ROOT / path


def trained_in_target(rec: dict) -> tuple[dict, dict]:
    """From the recorded Table 3 folder: ``{method: {target: test_fitness of its no-transfer runs}}`` and its test
    states' digests (``{}`` where the folder has none)."""
    folder = _table3_folder(rec)
    rows = t3.read_results(folder / "results.csv")
    cells: dict = {}
    for r in rows:
        if r["phase"] == "target" and r["setup"] == "none":
            cells.setdefault(r["method"], {}).setdefault(r["target"], []).append(float(r["test_fitness"]))
    protocol = folder / "protocol.json"
    digests = json.loads(protocol.read_text()).get("test_states", {}) if protocol.is_file() else {}
    return {m: {t: np.asarray(v) for t, v in by.items()} for m, by in cells.items()}, digests


def _ci(i: stats.Interval) -> str:
    return "[—]" if np.isnan(i.low) else f"[{i.low:.3f}, {i.high:.3f}]"


def _poi(a: np.ndarray, b: np.ndarray) -> tuple[str, stats.Interval]:
    i = stats.improvement_permutation_interval(a, b)
    return f"{i.value:.2f} {_ci(i)}", i


def _command(rec: dict, by: dict) -> str:
    parts = ["python -m kx.experiments zeroshot --out DIR", f"--learners {','.join(by)}"]
    seeds = sorted({s for v in by.values() for s in v["seeds"]})
    parts.append(f"--seeds {','.join(map(str, seeds))}")
    parts += [f"--test-trials {rec['test_trials']}", f"--test-seed {rec['test_seed']}"]
    parts += [f"--config-of {n}={v['config']}" for n, v in rec["learners"].items()
              if n in by and v["config"] != LEARNERS[n]]
    parts += [f"--set {o}" for o in rec["overrides"]]
    if rec["table3"] != TABLE3:
        parts.append(f"--table3 {rec['table3']}")
    return " ".join(parts)


def write_report(out: str | pathlib.Path) -> pathlib.Path:
    """``out/report.md`` and ``out/zeroshot.png`` from ``out``'s zeroshot.json, results.csv and baselines.csv and the
    recorded Table 3 folder's results.csv and protocol.json alone (fixed bootstrap and permutation seeds: byte for byte
    the same)."""
    out = pathlib.Path(out)
    if not (out / "zeroshot.json").is_file():
        raise RunError(f"{out}: no zeroshot.json: not a zero-shot study's folder (python -m kx.experiments zeroshot)")
    rec = json.loads((out / "zeroshot.json").read_text())
    rows = read_results(out)
    if not rows:
        raise RunError(f"{out / 'results.csv'}: no finished runs to report")
    base = csvfile.read(out / "baselines.csv", BASELINE_FIELDS, "kx zeroshot baselines file")
    names = [n for n in LEARNERS if n in rec["learners"]]
    by = {}
    for n in names:
        rs = sorted((r for r in rows if r["learner"] == n), key=lambda r: int(r["seed"]))
        if rs:
            by[n] = {"seeds": [int(r["seed"]) for r in rs], "rows": rs,
                     **{t: np.asarray([float(r[f"test_{t}"]) for r in rs]) for t in TASKS}}
    reference, digests = trained_in_target(rec)
    t3_name = rec["table3"]
    same = [t for t in TASKS if digests.get("sha256", {}).get(t) == rec["test_states"]["sha256"][t]
            and digests.get("trials") == rec["test_trials"]]
    states = (f"the same states as {t3_name}'s test_fitness (their sha256 digests equal, every task)"
              if len(same) == len(TASKS) else
              f"NOT the states of {t3_name}'s test_fitness in {', '.join(t for t in TASKS if t not in same)} (other "
              "digests, or the folder records none): a fraction of trained-in-target there compares unlike states")
    md = ["# Zero-shot study", "",
          f"Generated by `python -m kx.experiments report` from this folder's `zeroshot.json`, `results.csv` and "
          f"`baselines.csv` and {t3_name}'s `results.csv` and `protocol.json` alone. Every learner trained on {SOURCE} "
          f"(the entity mix on {SOURCE} with 4v3 episodes in every batch); each run's validated champion played, "
          f"unchanged, {rec['test_trials']} test states of each task (the test stream of seed {rec['test_seed']}): "
          f"{states}. {SEEDS_ASKED} seeds a learner are asked for; n says how many ran.", "",
          "## Zero-shot scores", "", f"IQM [95% bootstrap CI] and mean of the runs' champions; {SOURCE} is the "
          "training task, the others zero-shot.", "",
          "| learner | n | " + " | ".join(TASKS) + " |", "|---|---|" + "---|" * len(TASKS)]
    for n in LEARNERS:
        if n not in by:
            md.append(f"| {n} | 0 | " + " | ".join("not yet run" for _ in TASKS) + " |")
            continue
        cells = [f"{i.value:.3f} {_ci(i)}; mean {by[n][t].mean():.3f}" for t in TASKS
                 for i in [stats.iqm_interval(by[n][t])]]
        flag = "" if len(by[n]["seeds"]) >= SEEDS_ASKED else f" (of {SEEDS_ASKED})"
        md.append(f"| {n} | {len(by[n]['seeds'])}{flag} | " + " | ".join(cells) + " |")
    policies = list(dict.fromkeys(b["policy"] for b in base))
    for p in policies:
        vals = {b["task"]: float(b["test_fitness"]) for b in base if b["policy"] == p}
        md.append(f"| {p} (hand-coded) | — | " + " | ".join(f"{vals[t]:.3f}" for t in TASKS) + " |")
    md += ["", "![zeroshot.png](zeroshot.png)", "",
           "## As a fraction of the same learner trained in the target", "",
           f"The zero-shot IQM divided by the IQM of the same method's no-transfer runs in {t3_name} (phase target, "
           "setup none, test_fitness: 50 generations-equivalent from scratch in the target).", "",
           "| learner | method | " + " | ".join(t3.TARGETS) + " |", "|---|---|" + "---|" * len(t3.TARGETS)]
    for n in by:
        method = by[n]["rows"][0]["method"]
        cells = []
        for t in t3.TARGETS:
            ref = reference.get(method, {}).get(t)
            if ref is None:
                cells.append(f"not yet run ({t3_name} has no {method} none cell)")
                continue
            z, r = stats.iqm(by[n][t]), stats.iqm(ref)
            cells.append(f"{z / r:.2f} ({z:.3f} / {r:.3f}, n = {ref.size})")
        md.append(f"| {n} | {method} | " + " | ".join(cells) + " |")
    goal = reference.get("neat", {})
    md += ["", "## The goal to beat", ""]
    if not all(t in goal for t in t3.TARGETS):
        md.append(f"{t3_name} holds no NEAT no-transfer cell of every target: the goal is unknown.")
    else:
        short = {n: len(by[n]["seeds"]) if n in by else 0 for n in rec["learners"]}
        short = {n: k for n, k in short.items() if k < SEEDS_ASKED}
        md += [f"A policy trained on {SOURCE} alone that, zero-shot, matches NEAT evolved 50 generations in the target "
               f"({t3_name}'s neat none cells, IQM: " + ", ".join(
                   f"{t} {stats.iqm(goal[t]):.3f} (mean {goal[t].mean():.3f}, n = {goal[t].size})" for t in t3.TARGETS)
               + "), and beats every other learner's zero-shot score with the interval of the probability of "
               "improvement above 0.5 (in a task another learner trained on, such as the mix in 4v3, that "
               "learner's score is not zero-shot and is left out). Reached: its zero-shot IQM at least the goal's, and "
               "every such interval above "
               "0.5. Beside it, the probability that one of its runs beats one of NEAT's in the target.", "",
               f"The verdict is read once, when every learner has its {SEEDS_ASKED} seeds (a fixed sample: a verdict "
               "at each look as the seeds come in would be a sequential test at an unadjusted level); before that a "
               "cell says *interim* and gives what it would read now. A learner trained on more than "
               f"{SOURCE} (the mix) is not eligible; its cells say what it would read. An interval above 0.5 is a "
               "one-sided test at 2.5%. The interval is the studentised permutation interval of Brunner and Munzel's "
               "statistic (its distribution over 9,999 seeded splits of the two learners' pooled runs): exact when the "
               "two learners are alike, ties and 10 runs included (on every split of pools drawn from this folder's "
               "runs it is above 0.5 for at most 2.5% of them; on null data resampled from them, 10 against 10, NEAT, "
               "PPO and CMA-ES in 4v3 and 6v4, 2000 data sets each, it rejects 1.8-2.9%, 2.5% on average; "
               "`tests/test_zeroshot.py`), where the percentile bootstrap of Table 3's reports rejects 2.75-3.7%. The "
               "goal needs every interval above 0.5 (an intersection-union test), so its level is at most the largest "
               "of theirs.", ""]
        if short:
            md += ["**Interim**: no verdict yet; seeds still to run: " + ", ".join(
                f"{n} {k} of {SEEDS_ASKED}" for n, k in short.items()) + ".", ""]
        md += ["| learner | n | " + " | ".join(t3.TARGETS) + " |", "|---|---|" + "---|" * len(t3.TARGETS)]
        for n in by:
            eligible = rec["learners"][n]["trained"] == SOURCE
            cells = []
            for t in t3.TARGETS:
                z, g = stats.iqm(by[n][t]), stats.iqm(goal[t])
                # against every other learner's zero-shot score: not the mix's in a task it trained on
                weak = [m for m in by if m != n and t not in rec["learners"][m]["trained"].split("+")
                        and not stats.improvement_permutation_interval(by[n][t], by[m][t]).low > 0.5]
                passes = z >= g and not weak
                digits = next(d for d in (3, 4, 5, 6, 9) if f"{z:.{d}f}" != f"{g:.{d}f}" or d == 9)  # 0.3990 < 0.3993
                reasons = "; ".join(([f"IQM {z:.{digits}f} {'<' if z < g else '>='} {g:.{digits}f}"])
                                    + ([f"P(improvement) interval not above 0.5 over {', '.join(weak)}"] if weak
                                       else ["every P(improvement) interval above 0.5"]))
                if not eligible:
                    verdict = (f"not eligible (trained on {rec['learners'][n]['trained']}); would read "
                               f"{'reached' if passes else 'not reached'}: {reasons}")
                elif short:
                    verdict = f"interim, would read {'reached' if passes else 'not reached'}: {reasons}"
                else:
                    verdict = "**reached**: " + reasons if passes else "not reached: " + reasons
                cells.append(f"{verdict} (P(improvement) over NEAT in the target {_poi(by[n][t], goal[t])[0]})")
            md.append(f"| {n} | {len(by[n]['seeds'])} | " + " | ".join(cells) + " |")
    md += ["", "## Probability of improvement", "",
           "Of the row's learner over the column's, zero-shot, per task: the probability that a run of the first beats "
           "one of the second (ties half), with its 95% studentised permutation interval (as in the goal above; one "
           "direction is the other's mirror).", ""]
    for t in TASKS:
        md += [f"**{t}**", "", "| over | " + " | ".join(by) + " |", "|---|" + "---|" * len(by)]
        md += [f"| {a} | " + " | ".join("—" if a == b else _poi(by[a][t], by[b][t])[0] for b in by) + " |" for a in by]
        md.append("")
    md += ["## What was run", "", "```", _command(rec, by), "```", "",
           "| learner | config | method | trained on | episodes a run | seeds | training s (sum, mean a run) | "
           "zero-shot test s (sum) |", "|---|---|---|---|---|---|---|---|"]
    for n, v in by.items():
        rs, learner = v["rows"], rec["learners"][n]
        wall = np.asarray([float(r["wall_seconds"]) for r in rs])
        md.append(f"| {n} | `{learner['config']}` | {learner['method']} | {learner['trained']} | {rs[0]['episodes']} | "
                  f"{','.join(map(str, v['seeds']))} | {wall.sum():.0f}, {wall.mean():.1f} | "
                  f"{sum(float(r['test_seconds']) for r in rs):.0f} |")
    md += ["", "Each learner's whole resolved config (but the seed) is in `zeroshot.json` "
           "(`learners.<name>.resolved`); a run's seed is its seed; "
           "its training seconds are its share of its batched group's on the machine; a learner's zero-shot test "
           "seconds include the compilation of its first run's evaluations.", ""]
    made = sorted({r["platform"] for v in by.values() for r in v["rows"]})
    if made != [""]:  # once a row records where it was made (kx.runtime.platform_label)
        parts = []
        for p in made:
            runs = [f"{n} seeds {','.join(str(r['seed']) for r in v['rows'] if r['platform'] == p)}"
                    for n, v in by.items() if any(r["platform"] == p for r in v["rows"])]
            where = f"on `{p}`" if p else csvfile.UNRECORDED
            parts.append(f"{', '.join(runs)} {where}")
        md += ["Platforms (a run reproduces bit for bit on its own platform): " + "; ".join(parts) + ".", ""]
    _plot(out, by, base, goal)
    path = out / "report.md"
    path.write_text("\n".join(md))
    return path


def _plot(out: pathlib.Path, by: dict, base: list[dict], goal: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(TASKS), figsize=(3.2 * len(TASKS), 3.4), sharey=True)
    for ax, t in zip(axes, TASKS):
        for k, n in enumerate(by):
            i = stats.iqm_interval(by[n][t])
            err = [[0.0], [0.0]] if np.isnan(i.low) else [[i.value - i.low], [i.high - i.value]]
            ax.errorbar([k], [i.value], yerr=err, fmt="o", capsize=3, color=f"C{k}")
        heur = [float(b["test_fitness"]) for b in base if b["policy"] == "heuristic" and b["task"] == t]
        if heur:
            ax.axhline(heur[0], color="grey", linestyle="--", linewidth=1, label="heuristic")
        if t in goal:
            ax.axhline(stats.iqm(goal[t]), color="black", linewidth=1, label="NEAT trained in target")
        ax.set_xticks(range(len(by)), list(by), rotation=45, ha="right", fontsize=7)
        ax.set_title(t + (" (trained)" if t == SOURCE else " (zero-shot)"), fontsize=9)
    axes[0].set_ylabel("test fitness, IQM [95% CI]")
    axes[-1].legend(fontsize=6, loc="upper right")
    fig.tight_layout()
    fig.savefig(out / "zeroshot.png", dpi=90, metadata={"Software": None})
    plt.close(fig)
