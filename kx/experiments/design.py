"""Table 3's statistical design, fixed before the runs (SPEC section 6), and the identity of a protocol's
test states: both written into ``DIR/protocol.json`` and checked whenever a folder is extended.

**The families.** Every comparison is ``a`` against ``b`` in the direction the paper claims (``a`` better),
on one measure (:data:`MEASURES`), pooled over the targets the folder holds runs of:

* *primary*, the paper's own comparisons: transfer against none for each method and transfer setup;
  hybrid transfer (the paper's Fitness + NS) against fitness transfer for each method; HyperNEAT against NEAT
  for each of the paper's three setups (9 comparisons). Holm's correction over these 9, per measure;
* *secondary*, exploratory: the fourth setup (no transfer, with the hybrid) against no transfer (the hybrid
  without transfer); hybrid transfer against the fourth setup (both run the hybrid, so they differ
  in the transfer alone: the comparison the paper's design confounds); HyperNEAT against NEAT in the
  fourth setup; and CMA-ES's transfer against none. Holm's correction over these, per measure.

**The pooled test** (:func:`kx.experiments.stats.van_elteren`): van Elteren's stratified rank-sum test,
the strata the targets, two-sided at :data:`ALPHA`. Its effect size: the probability of improvement
averaged over the targets (Agarwal et al. 2021), with a stratified-bootstrap 95% interval (runs resampled
within each cell). Per-target Mann-Whitney tests are detail.

**Verdicts** (per claim and measure): *supported* where the Holm-adjusted pooled p is below ALPHA and
the estimate points the paper's way; *contradicted* where it is below ALPHA the other way; *not decided*
otherwise, with the direction and size of the estimate, the power at the observed effect and the runs a
cell that 80% would need (:func:`kx.experiments.stats.power`).

**Test states.** Every run of a task is measured on the same ``test_trials`` start states of the test
stream of the protocol seed (:func:`kx.evolve.streams.test`). protocol.json records a SHA-256 of those
states for each task (:func:`test_state_digests`); extending a folder recomputes them and refuses, before
any compute, a folder whose states this code would not reproduce.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import pathlib
import re
from typing import Callable

import numpy as np

from kx.evolve import outputs as run_outputs
from kx.evolve.errors import RunError

ALPHA = 0.05
POWER_GOAL = 0.8
#: the run counts the power search tries (runs a cell, in every cell of a comparison)
POWER_RUNS = (5, 10, 15, 20, 25, 30, 35, 40, 50, 60, 80, 100)
#: the measures, each its own families
MEASURES = ("max_fitness", "test_fitness")
#: the methods whose shipped configs (configs/<method>_<task>.py) the protocol runs
METHOD_CONFIGS = ("neat", "hyperneat", "cma_es", "ppo", "ppo_entity")
#: runs a cell the protocol aims at, and up to how many a cell may be extended where power asks for it
RUNS_PER_CELL, EXTEND_UP_TO = 20, 35


@dataclasses.dataclass(frozen=True)
class Claim:
    """``a`` better than ``b``: cells ``(method, setup)``, pooled over the targets."""

    family: str  # "primary" or "secondary"
    claim: str  # "transfer", "hybrid", "hyperneat" (the paper's); or what the secondary one asks
    a: tuple[str, str]
    b: tuple[str, str]

    @property
    def key(self) -> str:
        return f"{self.a[0]}/{self.a[1]} > {self.b[0]}/{self.b[1]}"


PAPER_SETUPS = ("none", "fitness", "hybrid")
PRIMARY = (
    *(Claim("primary", "transfer", (m, s), (m, "none")) for m in ("neat", "hyperneat") for s in ("fitness", "hybrid")),
    *(Claim("primary", "hybrid", (m, "hybrid"), (m, "fitness")) for m in ("neat", "hyperneat")),
    *(Claim("primary", "hyperneat", ("hyperneat", s), ("neat", s)) for s in PAPER_SETUPS),
)
SECONDARY = (
    *(Claim("secondary", "hybrid, no transfer", (m, "none_hybrid"), (m, "none")) for m in ("neat", "hyperneat")),
    *(Claim("secondary", "transfer, both hybrid", (m, "hybrid"), (m, "none_hybrid")) for m in ("neat", "hyperneat")),
    Claim("secondary", "hyperneat", ("hyperneat", "none_hybrid"), ("neat", "none_hybrid")),
    Claim("secondary", "transfer", ("cma_es", "fitness"), ("cma_es", "none")),
    Claim("secondary", "transfer", ("ppo", "fitness"), ("ppo", "none")),
    Claim("secondary", "transfer", ("ppo_entity", "fitness"), ("ppo_entity", "none")),
)
CLAIMS = PRIMARY + SECONDARY
def families(dsg: dict) -> tuple[tuple[Claim, ...], tuple[Claim, ...]]:
    """The primary and secondary families a recorded design fixes (its claim keys, in its order): a folder is
    decided by the claims it recorded before its runs, so that a claim this code adds later (about cells the folder
    has no runs of) changes no Holm correction of a folder that does not record it."""
    by_key = {c.key: c for c in CLAIMS}
    return tuple(tuple(by_key[k] for k in renamed(dsg[key])) for key in ("primary", SECONDARY_KEY))


#: the paper's claims, as the report words them
TITLES = {"transfer": "Policy transfer beats evolving from scratch",
          "hybrid": "Hybrid transfer (the paper's Fitness + NS) beats fitness transfer",
          "hyperneat": "HyperNEAT beats NEAT"}


#: the pooled test (:func:`kx.experiments.stats.clustered_van_elteren`), as protocol.json names it
TEST = "clustered_van_elteren"
#: the margin of "no meaningful difference": a comparison whose interval of the averaged probability of
#: improvement lies inside it, and that the test does not decide, gets that verdict
MARGIN = (0.40, 0.60)
#: an exploratory folder's looks (runs a cell): the protocol's count, then up to the extension's
LOOKS = (RUNS_PER_CELL, EXTEND_UP_TO)
#: a confirmatory design's largest affordable run count a cell
CONFIRMATORY_MOST = 40
SOURCES = ("shared", "per_target")
ROLES = ("exploratory", "confirmatory")


def design(role: str = "exploratory", sources: str = "shared", runs: dict | None = None,
           basis: dict | None = None) -> dict:
    """The design as protocol.json records it: its parameters, and under ``text`` their description (only the
    parameters are compared when a folder is extended: rewording the description locks no folder out).

    ``role`` ``exploratory`` (the default of ``python -m kx.experiments table3``): :data:`RUNS_PER_CELL` runs a
    cell, extendable up to :data:`EXTEND_UP_TO` where power asks for it, the two looks paid for by the sequential
    plan (:mod:`kx.experiments.sequential`). ``confirmatory``: every cell's runs fixed in advance (``runs``:
    ``{"method/setup": n}``), one look when all are in, and ``basis``: what the run counts were derived from.
    ``sources``: ``shared`` (run i of every target from source i: the targets' runs are clusters) or
    ``per_target`` (each target run from a source of its own: every run independent)."""
    from kx.experiments import sequential, stats

    if role not in ROLES:
        raise ValueError(f"role: allowed {', '.join(ROLES)}, got {role!r}")
    if sources not in SOURCES:
        raise ValueError(f"sources: allowed {', '.join(SOURCES)}, got {sources!r}")
    if (role == "confirmatory") != (runs is not None):
        raise ValueError("runs: a confirmatory design fixes every cell's runs, an exploratory one none")
    out = {
        "measures": list(MEASURES),
        "alpha": ALPHA,
        "primary": [c.key for c in PRIMARY],
        "secondary (exploratory)": [c.key for c in SECONDARY],
        "resamples": stats.RESAMPLES,
        "bootstrap_seed": stats.BOOTSTRAP_SEED,
        "power_resamples": stats.POWER_RESAMPLES,
        "power_runs": list(POWER_RUNS),
        "power_goal": POWER_GOAL,
        "role": role,
        "test": TEST,
        "cluster_resamples": stats.CLUSTER_RESAMPLES,
        "sources": sources,
        "spending": sequential.SPENDING,
        "margin": list(MARGIN),
    }
    if role == "exploratory":
        out.update(runs_per_cell=RUNS_PER_CELL, extend_up_to=EXTEND_UP_TO, looks=list(LOOKS))
    else:
        out.update(runs=dict(runs), looks="planned", most_runs=CONFIRMATORY_MOST)
        if basis is not None:
            out["basis"] = basis
    out["text"] = {
        "pooled_test": "van Elteren's stratified rank-sum statistic over the targets (weights 1/(n+1) per target, "
                       "midranks) with a cluster-robust variance: a cluster is the runs that share a source (run i "
                       "of a transfer cell in every target when sources are shared) or a run alone; each cell's "
                       "part from its clusters' sums of weighted rank scores, C/(C-1) times their squared deviations "
                       "per group of clusters with runs in the same targets; two-sided against Student's t with "
                       "Welch-Satterthwaite degrees of freedom; its direction the sign of the statistic",
        "effect": "probability of improvement averaged over the targets, 95% percentile interval of a bootstrap "
                  "that resamples whole clusters within each cell (within each target for independent runs)",
        "correction": "Holm within each family and measure over the comparisons' sequential p-values (claims "
                      "without runs count with p = 1)",
        "looks": ("two looks, at runs_per_cell and at up to extend_up_to runs a cell; O'Brien-Fleming-type "
                  "alpha spending (Lan & DeMets 1983) at information fraction runs / extend_up_to; a comparison "
                  "decided at the last look it had" if role == "exploratory" else
                  "one look, when every cell holds its planned runs: no verdict before"),
        "equivalence": "where the test does not decide and the interval of the averaged probability of improvement "
                       "lies inside the margin: no meaningful difference",
        "per_target": "two-sided Mann-Whitney U, Vargha-Delaney A, Holm over each table (detail)",
        "power": "the probability that the pooled test gives p < alpha / (family size) in the observed direction, "
                 "at the observed effect: every cell's clusters resampled with replacement to n runs; the runs a "
                 "cell for the goal: the smallest n of power_runs that reaches it",
    }
    return out


#: the parameters a design of the first kind (van Elteren's test with independent strata, no looks, no margin)
#: recorded, and what they mean in today's terms: such a folder is read as an exploratory one with shared sources
FIRST_DESIGN_KEYS = ("measures", "alpha", "primary", "secondary (exploratory)", "resamples", "bootstrap_seed",
                     "power_resamples", "power_runs", "power_goal", "runs_per_cell", "extend_up_to")
CORRECTED = ("the pooled test made valid for targets that share sources (clusters as the unit), the looks paid for "
             "by a sequential plan and the margin of no meaningful difference, applied after the fact to the runs "
             "already made")


def effective(recorded: dict) -> dict:
    """The design a folder is analysed by, from its recorded one: a design of the first kind (no ``test``) is read
    as today's exploratory design with shared sources and its own parameters (:data:`CORRECTED`)."""
    if "test" in recorded:
        return recorded
    missing = [k for k in FIRST_DESIGN_KEYS if k not in recorded]
    if missing:
        raise RunError(f"design: not a kx table3 design (missing {', '.join(missing)})")
    out = design()
    out.update({k: recorded[k] for k in FIRST_DESIGN_KEYS})
    out["looks"] = [recorded["runs_per_cell"], recorded["extend_up_to"]]
    return out


def renamed(recorded):
    """A recorded design (or any part of it) with the hybrid's setups under today's names: a folder written when
    they were ``novelty`` and ``none_novelty`` (:data:`kx.experiments.table3.OLD_SETUPS`) reads as one written now."""
    if isinstance(recorded, dict):
        return {renamed(k): renamed(v) for k, v in recorded.items()}
    if isinstance(recorded, list):
        return [renamed(v) for v in recorded]
    if isinstance(recorded, str):
        return re.sub(r"(?<=/)(none_)?novelty\b", lambda m: (m.group(1) or "") + "hybrid", recorded)
    return recorded


def of_folder(out: pathlib.Path) -> dict:
    """The effective design (:func:`effective`) of the folder ``out`` (its protocol.json's; today's exploratory
    design where it records none), with ``corrected_after_runs`` where the correction was applied after runs were
    made (a design of the first kind, or one whose folder keeps a ``design_history``)."""
    path = pathlib.Path(out) / "protocol.json"
    have = json.loads(path.read_text()) if path.is_file() else {}
    if "design" not in have:
        return design(sources=have.get("sources", "shared"))
    out = dict(effective(renamed(have["design"])))
    if "test" not in have["design"] or have.get("design_history"):
        out["corrected_after_runs"] = True  # read by the report, never recorded
    return out


def planned_runs(dsg: dict, method: str, setup: str) -> int | None:
    """The runs a cell ``method/setup`` is planned to hold in every target: a confirmatory design's, or ``None``."""
    return dsg["runs"].get(f"{method}/{setup}") if dsg.get("role") == "confirmatory" else None


#: what a start state draws from its key (the rest of :class:`kx.sim.types.State` starts at constants): the
#: fields the test states' digest covers, so that a counter added to the state later changes no digest
START_FIELDS = ("keeper_x", "keeper_y", "taker_x", "taker_y", "holder", "ball_x", "ball_y")


def states_digest(states) -> str:
    """The sha256 of start states' :data:`START_FIELDS` (what two folders' test states are compared by)."""
    h = hashlib.sha256()
    for name in START_FIELDS:
        a = np.ascontiguousarray(np.asarray(getattr(states, name)))
        h.update(f"{name}:{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return "sha256:" + h.hexdigest()


def test_state_digests(protocol, tasks) -> dict[str, str]:
    """``{task: digest}`` of the protocol's test states of each task (the start states every run of the task
    is measured on: :func:`kx.experiments.measure.held_out_states`, from a NEAT run's config of the task with
    the protocol's overrides; the states depend on the task and the world's parameters only)."""
    from kx.evolve import config as cfg_lib
    from kx.evolve import streams
    from kx.sim import env

    keys = streams.test(protocol.seed)
    out = {}
    for task in tasks:
        worlds = {m: cfg_lib.load(cfg_lib.CONFIG_DIR / f"{m}_{task}.py", list(protocol.overrides)).sim.to_dict()
                  for m in METHOD_CONFIGS}
        if any(w != worlds["neat"] for w in worlds.values()):
            raise RunError(f"sim: the methods' configs of {task} set other worlds ({worlds}); one digest of the "
                           "test states per task assumes they are the same")
        cfg = cfg_lib.load(cfg_lib.CONFIG_DIR / f"neat_{task}.py", list(protocol.overrides))
        exp = cfg_lib.validate(cfg)
        out[task] = states_digest(env.reset_batch(keys.starts, protocol.test_trials, exp.sim_params, exp.sim))
    return out


def check_folder(out: pathlib.Path, protocol, tasks, log: Callable[[str], None] = print,
                 want_design: dict | None = None) -> None:
    """Checks ``out/protocol.json`` (written by :func:`kx.experiments.table3.run` before this) against this
    code: its ``test_states`` must be the states this code draws for every task of ``tasks``, and its
    ``design`` ``want_design`` (default: the exploratory :func:`design` of the protocol's sources); a file from
    before either was recorded gains it, and a design of the first kind is corrected (:func:`effective`, the old
    one kept under ``design_history``), each said in ``log``. ``RunError`` naming the field otherwise, before any
    compute."""
    path = pathlib.Path(out) / "protocol.json"
    have = json.loads(path.read_text())
    if "design" in have:
        have["design"] = renamed(have["design"])
    tasks = tuple(tasks)
    states = {"stream": "kx.evolve.streams.test(seed)", "seed": protocol.seed, "trials": protocol.test_trials,
              "sha256": test_state_digests(protocol, tasks)}
    want = {"test_states": states, "design": renamed(want_design) if want_design else design(sources=protocol.sources)}
    added = []
    if "design" in have and "test" not in have["design"]:
        old = have["design"]
        have["design"] = effective(old)
        have.setdefault("design_history", []).append({"design": old, "corrected": CORRECTED})
        added.append("the corrected design (" + CORRECTED + "; the first kept under design_history)")
    for key, value in want.items():
        if key not in have:
            have[key] = value
            added.append(key)
        elif key == "test_states":
            bad = [t for t in tasks if have[key].get("sha256", {}).get(t) != value["sha256"][t]]
            if bad or {k: have[key].get(k) for k in ("seed", "trials")} != {"seed": protocol.seed,
                                                                             "trials": protocol.test_trials}:
                raise RunError(f"{path}: test_states: this code draws other test states than the folder's runs "
                               f"were measured on (tasks {', '.join(bad) or 'all'}): a run measured now could not "
                               "be compared with them; run the protocol in a new folder")
        elif {k: v for k, v in have[key].items() if k != "text"} != {k: v for k, v in value.items() if k != "text"}:
            gained = _secondary_gained(have[key], value, pathlib.Path(out))
            if gained is None:
                diff = sorted(k for k in set(have[key]) | set(value)
                              if k != "text" and have[key].get(k) != value.get(k))
                raise RunError(f"{path}: design: the statistical design recorded before the runs differs from this "
                               f"code's ({', '.join(diff)}); a design is fixed before the runs: change it in a new "
                               "folder")
            have[key] = value
            added.append(f"the exploratory claims {', '.join(gained)} (no run of theirs yet)")
    if added:
        run_outputs.write_json(path, have)
        log(f"kx table3: {path.name} gains {' and '.join(added)} (recorded from now on)")


SECONDARY_KEY = "secondary (exploratory)"


def _secondary_gained(have: dict, want: dict, out: pathlib.Path) -> list[str] | None:
    """The claims this code's design adds to a folder's recorded one, when that is its only difference: the
    same parameters and primary family, the recorded secondary claims kept in order, and the new ones about
    cells (method, setup) of which the folder has no target run yet, so that they too are fixed before their runs
    (the exploratory family's Holm correction then counts them). ``None`` otherwise."""
    same = {k: v for k, v in have.items() if k not in ("text", SECONDARY_KEY)} == {
        k: v for k, v in want.items() if k not in ("text", SECONDARY_KEY)}
    old, new = list(have.get(SECONDARY_KEY, [])), list(want.get(SECONDARY_KEY, []))
    if not same or new[:len(old)] != old or len(new) == len(old):
        return None
    gained = new[len(old):]
    results = out / "results.csv"
    cells = set()
    if results.is_file():
        with results.open(newline="") as f:
            cells = {tuple(renamed(f"{r['method']}/{r['setup']}").split("/")) for r in csv.DictReader(f)
                     if r["phase"] == "target"}
    by_key = {c.key: c for c in SECONDARY}
    for key in gained:
        claim = by_key.get(key)
        if claim is None or claim.a in cells or claim.b in cells:
            return None
    return gained
