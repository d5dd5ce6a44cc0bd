"""``python -m kx.bench platform``: does this machine play the reference's keep-away episodes bit for bit, and
how fast does it compute them?

Over 450 lines because the digest's nine stages, their comparison and the backends' subprocesses are one check:
apart, a stage's checksum would sit away from the comparison that names where two platforms part.

**What it measures.** Everything the world computes is integer or exactly rounded (:mod:`kx.sim.geometry`),
and the heuristic counts margins within :data:`kx.sim.policies.MARGIN_TOL` as equal, so the same start
states and kick-noise words give the same episodes on every platform, bit for bit, unless a platform (a GPU
backend, another JAX or jaxlib version) computes something differently; then the episodes part, and every
figure built on them (fitness, a run's trajectory, the committed results) moves with them. The digest
records checksums of the world's integer state along the heuristic's episodes of 3v2 (``--episodes`` start
states of ``--seed``, the kick noise of ``kx.bench sim``'s evaluation key), one entry per stage, in the
order computed:

* ``starts``: the start states (:func:`kx.sim.env.reset_batch`), a checksum per state field;
* ``noise_words``: each episode's kick-noise word (``jax.random``'s bits);
* ``s_max``: the kick-noise limit (a float tangent, rounded down);
* ``reset``: :func:`kx.sim.env.reset`'s operations written out, to name the one where start states part:
  the random bits behind the keepers' and takers' scores, the cells forbidden to takers, the cells that
  ``jax.lax.top_k`` picks for each episode (and, for the takers, what a stable integer sort picks);
* ``first_decision``: the heuristic's first decision; ``kick_noise_t0_3``: the kick noise of iterations 0-3;
* ``lockstep``: the episodes stepped by :func:`kx.sim.env.transition` alone, every episode in lockstep (no
  evaluator), a checksum of every state field after each block of :data:`BLOCK` iterations;
* ``evaluator``: :func:`kx.sim.evaluate.evaluate`'s results on the same episodes (rungs, packing, compaction);
* ``heuristic_min_margin``: the same with margins of exactly zero counted unsafe (a margin-sensitive variant).

Each backend computes the digest in a process of its own (``JAX_PLATFORMS`` chooses the backend at start-up),
twice: the first call compiles (or loads from kx's compilation cache, ``KX_CACHE_DIR``), the second is warm;
the two must be identical. The warm seconds of a backend against those of the host CPU backend, measured in
the same run, give the platform's speed on this work: a small one (a few seconds on a CPU) that waits on the
host after every block of the lockstep episodes, so it measures latency as much as throughput (``kx.bench
sim`` measures the simulator's throughput). ``python -m kx.bench.platform`` is that per-backend process.

**How to run it**::

    python -m kx.bench platform                     # the default backend, and the host CPU's too where the
                                                    # default is an accelerator
    python -m kx.bench platform --backends cpu      # one backend (default, cpu, gpu or tpu; comma-separated)
    python -m kx.bench platform --out here.json     # also write this platform's digest
    python -m kx.bench platform --reference there.json   # compare with a digest written elsewhere

The reference is the digest shipped with kx (``kx/bench/data/platform_digest_cpu.json``: 4500 episodes, seed
0, recorded on a CPU with the JAX version kx pins). With ``--out FILE`` the first backend's digest goes to
FILE and each other backend's to FILE with ``-BACKEND`` before its suffix. On a 2-core CPU with JAX 0.10.2 the
default run takes about 80 s with an empty compilation cache and 25 s with a warm one: the digest itself
is under 2 s warm, the rest is compilation.

**How to read it.** For each backend, one line per stage: ``match``, ``DIFFERS`` with the first entry that
differs (its field, and the episode, block or iteration where that applies), or ``not compared`` (a digest of
other episodes or another seed: checksums over every episode cannot be compared, but ``reset``'s cells are
compared episode by episode on the episodes both hold). The first stage that differs is where the platforms
part; the stages after it differ in consequence. Then:

* every backend matches: this machine plays the reference's episodes bit for bit;
* the host CPU backend matches and the accelerator does not: the accelerator's backend computes differently;
* neither matches: the JAX (or jaxlib) version differs from the reference's (the digest records it), or,
  with the same version, the machine's CPU or kx's code does;
* against a reference recorded on an accelerator (``--reference``), a stage that differs may be the backend's
  or the JAX version's: the shipped CPU digest tells them apart.

The backends run accelerators first, then the host CPU (a ``gpu`` or ``tpu`` that JAX does not find here stops
the run before the CPU's turn). **The last line** is the first backend's (the accelerator's where there is one)::

    platform: M of N stages match on BACKEND[, K not compared] (ratio M/N vs REF digest)

N is the number of stages (9), M those that match the reference, K those that could not be compared (absent
when none); the ratio is M/N to two decimals, and REF the reference's platform (``CPU`` for the shipped one).
``platform: 9 of 9 stages match on cpu (ratio 1.00 vs CPU digest)`` is a platform that computes as the
reference did. The speed is on the line before it: ``speed: ... (ratio X vs cpu backend)``, the CPU
backend's warm seconds over the backend's, where both ran.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

BLOCK = 10  # iterations between two checksums of the lockstep episodes
TASK = "3v2"
REFERENCE = pathlib.Path(__file__).resolve().parent / "data" / "platform_digest_cpu.json"
#: what ``--backends`` takes: JAX's default backend, the host CPU, or the accelerator JAX picks by itself
BACKENDS = ("default", "cpu", "gpu", "tpu")
#: the digest's stages, in the order computed
STAGES = ("starts", "noise_words", "s_max", "reset", "first_decision", "kick_noise_t0_3", "lockstep", "evaluator",
          "heuristic_min_margin")
RESET_CELLS = ("keeper_cells", "taker_cells", "taker_cells_by_sort")  # one entry per episode, ';'-separated
RESET_FIELDS = ("keeper_bits", "taker_bits", "forbidden", *RESET_CELLS, "takers_on_forbidden_cells",
                "taker_score_ties", "parts_give_the_starts")
#: what a file must hold to be taken for a digest (``reset`` and ``heuristic_min_margin`` may be absent)
REQUIRED = ("platform", "jax", "episodes", "seed", "starts", "noise_words", "s_max", "first_decision",
            "kick_noise_t0_3", "lockstep", "evaluator")
MATCH, DIFFER, NOT_COMPARED = "match", "DIFFERS", "not compared"


# ------------------------------------------------------------------------------------------------ the digest


def _checksum(a) -> int:
    """A lane-order-sensitive 32-bit checksum of an integer or boolean array ``[..., n]``."""
    import numpy as np

    v = np.asarray(a).astype(np.int64).reshape(-1, np.asarray(a).shape[-1])
    n = v.shape[-1]
    weights = (np.arange(1, n + 1, dtype=np.uint64) * np.uint64(2654435761)) % np.uint64(2**32)
    rows = (v.astype(np.uint64) % np.uint64(2**32)) * weights[None, :] % np.uint64(2**32)
    return int((rows.sum(dtype=np.uint64) + np.uint64(v.shape[0])) % np.uint64(2**32))


def _state_sums(state) -> dict[str, int]:
    return {f: _checksum(getattr(state, f)) for f in state.__dataclass_fields__}


def _cells(a) -> str:
    """One string, an episode's cells per ';'-separated entry (``a``: ``[episodes, n]``)."""
    import numpy as np

    return ";".join(",".join(map(str, r)) for r in np.asarray(a).tolist())


@functools.lru_cache(maxsize=None)
def _programs(task: str):
    """The digest's compiled programs for ``task`` (built once a process, so that a second digest is warm):
    the task, its parameters, the heuristic, the kick-noise limit, a block of lockstep iterations, the first
    decision and reset's stages."""
    import jax
    import jax.numpy as jnp

    from kx.sim import env, policies
    from kx.sim import geometry as geo
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig.from_task(task), KeepAwayParams()
    policy = policies.heuristic(config)
    s_max = env.noise_limit(params.kick_noise_deg)
    w, k, t = config.field_size, config.n_keepers, config.n_takers

    @jax.jit
    def block(state, words):
        def one(_, s):
            return env.transition(s, policy.apply(None, s, None), env.kick_noise(words, s.t, s_max), params, config)
        return jax.lax.fori_loop(0, BLOCK, one, state)

    def parts(kk):
        """:func:`kx.sim.env.reset`'s stages for one episode, with ``jax.lax.top_k`` (the platform's) for the
        selections, and the takers' selection again by a stable sort of integer keys (no top-k, no float
        comparison; the scores hold no ties here, -1 for the forbidden cells)."""
        k_hold, k_keep, k_take = jax.random.split(kk, 3)
        cells = jnp.arange(w * w, dtype=jnp.int32)
        keep_scores = jax.random.uniform(k_keep, (w * w,))
        keeper_cells = jax.lax.top_k(keep_scores, k)[1].astype(jnp.int32)
        holder = jax.random.randint(k_hold, (), 0, k, dtype=jnp.int32)
        hx, hy = keeper_cells[holder] % w, keeper_cells[holder] // w
        forbidden = (jnp.zeros(w * w, bool).at[keeper_cells].set(True)
                     | (geo.cheb(cells % w, cells // w, hx, hy) <= params.start_clearance))
        take_scores = jnp.where(forbidden, -1.0, jax.random.uniform(k_take, (w * w,)))
        taker_cells = jax.lax.top_k(take_scores, t)[1].astype(jnp.int32)
        int_keys = jnp.where(forbidden, -1, (jax.random.bits(k_take, (w * w,)) >> 9).astype(jnp.int32))
        by_sort = jnp.argsort(-int_keys, stable=True)[:t].astype(jnp.int32)
        return (jax.random.bits(k_keep, (w * w,)), jax.random.bits(k_take, (w * w,)), forbidden,
                keeper_cells, taker_cells, by_sort, take_scores)

    first_decision = jax.jit(lambda s: policy.apply(None, s, None))
    return config, params, policy, s_max, block, first_decision, jax.jit(jax.vmap(parts))


def _reset_parts(key, episodes: int) -> dict:
    """``reset``'s stages for every episode, to name the operation where two platforms' start states part:
    the random bits behind the scores, the cells forbidden to takers, the two top-k selections, one row of
    cells per episode, and how many episodes hold tied top taker scores (top-k's order among equals is then
    the platform's)."""
    import jax
    import numpy as np

    config, *_, parts = _programs(TASK)
    t = config.n_takers
    kb, tb, forb, kc, tc, by_sort, ts = parts(jax.random.split(key, episodes))
    ts, tc = np.asarray(ts), np.asarray(tc)
    return {"keeper_bits": _checksum(np.asarray(kb).T.view(np.int32)),
            "taker_bits": _checksum(np.asarray(tb).T.view(np.int32)),
            "forbidden": _checksum(np.asarray(forb).T), "keeper_cells": _cells(kc),
            "taker_cells": _cells(tc), "taker_cells_by_sort": _cells(by_sort),
            "takers_on_forbidden_cells": int((np.take_along_axis(ts, tc, 1) < 0).sum()),
            "taker_score_ties": int((np.diff(-np.sort(-ts, axis=1)[:, :t + 1], axis=1) == 0).any(axis=1).sum())}


def digest(episodes: int, seed: int) -> dict:
    """The digest of ``episodes`` start states of 3v2 drawn with ``seed`` on JAX's default backend (a dict
    that JSON writes as it is; its stages are :data:`STAGES`)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.sim import env, policies
    from kx.sim import evaluate as ev

    config, params, policy, s_max, block, first_decision, _ = _programs(TASK)
    starts = env.reset_batch(jax.random.key(seed), episodes, params, config)
    key = jax.random.key(1)  # kx.bench sim's evaluation key
    words = env.noise_words(ev.stream_keys(key)[0], jnp.arange(episodes))
    out = {"platform": jax.devices()[0].platform, "jax": jax.__version__, "episodes": episodes, "seed": seed,
           "starts": _state_sums(starts), "noise_words": _checksum(np.asarray(words)), "s_max": int(s_max)}
    out["reset"] = _reset_parts(jax.random.key(seed), episodes)
    # the stages are env.reset's, written out: whether they give its start states on this platform (on a CPU
    # they must: else _reset_parts no longer follows kx.sim.env.reset)
    w = config.field_size
    out["reset"]["parts_give_the_starts"] = all(
        out["reset"][f"{who}_cells"] == _cells(np.asarray(y * w + x).T)
        for who, x, y in (("keeper", starts.keeper_x, starts.keeper_y), ("taker", starts.taker_x, starts.taker_y)))
    if out["platform"] == "cpu" and not out["reset"]["parts_give_the_starts"]:
        raise SystemExit("kx.bench platform: its reset stages no longer follow kx.sim.env.reset")
    out["first_decision"] = _checksum(first_decision(starts))
    out["kick_noise_t0_3"] = [_checksum(env.kick_noise(words, jnp.full(episodes, t, jnp.int32), s_max))
                              for t in range(4)]

    state, blocks = starts, []
    for i in range(int(params.max_iterations) // BLOCK + 1):
        state = block(state, words)
        done = np.asarray(state.done)
        blocks.append({"after": (i + 1) * BLOCK, "live": int((~done).sum()), **_state_sums(state)})
        if done.all():
            break
    stats = env.episode_stats(state, params, config)
    out["lockstep"] = {"blocks": blocks, "mean_fitness": float(np.asarray(stats.fitness).mean()),
                       "live_steps": int(np.asarray(state.t).sum())}
    counters = ev.EvalCounters()
    got = ev.evaluate(policy, None, starts, params, config, key=key, counters=counters)
    out["evaluator"] = {"mean_fitness": float(np.asarray(got.fitness).mean()), "live_steps": int(counters.live_steps),
                        "iterations": _checksum(np.asarray(got.iterations)),
                        "passes": _checksum(np.asarray(got.passes))}
    # the heuristic passes at margins of exactly zero (min_margin 0.0, within MARGIN_TOL): the same evaluation
    # with those margins counted unsafe, a variant whose episodes hang on margins near zero
    out["heuristic_min_margin"] = {}
    for mm in (2 * policies.MARGIN_TOL,):
        c = ev.EvalCounters()
        got = ev.evaluate(policies.heuristic(config, min_margin=mm), None, starts, params, config, key=key, counters=c)
        out["heuristic_min_margin"][str(mm)] = {"mean_fitness": float(np.asarray(got.fitness).mean()),
                                                "live_steps": int(c.live_steps)}
    return out


# ----------------------------------------------------------------------------------------------- the compare


@dataclasses.dataclass(frozen=True)
class Stage:
    """One stage of a comparison: ``status`` (:data:`MATCH`, :data:`DIFFER` or :data:`NOT_COMPARED`), and
    where it differs, the first entry that does: its ``field`` and ``where`` in it (an episode, a block of the
    lockstep episodes, an iteration, a ``min_margin``; empty for a checksum over every episode); ``detail``
    says what differs there and what else does, or why the stage was not compared."""

    name: str
    status: str
    field: str = ""
    where: str = ""
    detail: str = ""

    def line(self) -> str:
        if self.status == DIFFER:
            at = f"{self.field}" + (f" at {self.where}" if self.where else "")
            return f"{self.name:<21} {DIFFER}: first {at}; {self.detail}"
        return f"{self.name:<21} {self.status}" + (f" ({self.detail})" if self.detail else "")


def _fields(name: str, got: dict, want: dict, where: str = "", note: str = "") -> Stage:
    """A stage of named entries: the first of ``want``'s entries that ``got`` does not hold alike."""
    diff = [f for f in want if got.get(f) != want[f]]
    if not diff:
        return Stage(name, MATCH, detail=note)
    f = diff[0]
    also = f"; also {', '.join(diff[1:])}" if diff[1:] else ""
    return Stage(name, DIFFER, f, where, f"{got.get(f)} here, {want[f]} there{also}" + (f"; {note}" if note else ""))


def _fitness(got: dict, want: dict) -> str:
    return (f"mean fitness {got['mean_fitness']:.4f} here, {want['mean_fitness']:.4f} there; live steps "
            f"{got['live_steps']} here, {want['live_steps']} there")


def _reset(got: dict, want: dict, same_episodes: bool) -> Stage:
    r, q = got["reset"], want["reset"]
    n = min(got["episodes"], want["episodes"])
    first, bad_fields = None, []
    for f in RESET_FIELDS if same_episodes else RESET_CELLS:
        if f not in q:
            continue
        if f in RESET_CELLS:
            a, b = r[f].split(";")[:n], q[f].split(";")[:n]
            bad = [i for i, (x, y) in enumerate(zip(a, b)) if x != y]
            if bad:
                bad_fields.append(f"{f} in {len(bad)} of {n} episodes")
                first = first or (f, f"episode {bad[0]}", f"cells {a[bad[0]]} here, {b[bad[0]]} there")
        elif r.get(f) != q[f]:
            bad_fields.append(f)
            first = first or (f, "", f"{r.get(f)} here, {q[f]} there")
    scope = "" if same_episodes else (f"the cells of the first {n} episodes; the checksums over every episode "
                                      "are not compared")
    if first is None:
        return Stage("reset", MATCH, detail=scope)
    own = sum(x != y for x, y in zip(r["taker_cells"].split(";"), r["taker_cells_by_sort"].split(";")))
    return Stage("reset", DIFFER, first[0], first[1],
                 f"{first[2]}; differ: {', '.join(bad_fields)}; here top-k and the integer sort disagree on the "
                 f"takers of {own} episodes, {r.get('taker_score_ties', '?')} episodes hold tied top taker scores, "
                 f"the stages give reset's start states: {r.get('parts_give_the_starts', '?')}"
                 + (f"; {scope}" if scope else ""))


def _lockstep(got: dict, want: dict) -> Stage:
    a, b = got["blocks"], want["blocks"]
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            diff = [f for f in y if f not in ("after", "live") and x.get(f) != y[f]]  # the state's fields first
            diff += ["live"] * (x["live"] != y["live"])
            return Stage("lockstep", DIFFER, diff[0], f"block {i} (after iteration {y['after']})",
                         f"differ there: {', '.join(diff)}; live episodes {x['live']} here, {y['live']} there; "
                         f"in the end {_fitness(got, want)}")
    if len(a) != len(b):
        return Stage("lockstep", DIFFER, "blocks", f"block {min(len(a), len(b))}",
                     f"the same as far as both go, but {len(a)} blocks here, {len(b)} there")
    return _fields("lockstep", got, {k: v for k, v in want.items() if k != "blocks"})


def compare(got: dict, want: dict) -> list[Stage]:
    """Stage by stage (:data:`STAGES`), whether the digest ``got`` matches ``want``, and where it does not, its
    first entry that differs. Digests of different episode counts compare ``s_max`` and ``reset``'s cells on
    the episodes both hold (start states are drawn per episode from one split of the seed's key); other seeds
    compare only ``s_max``."""
    same_seed = got["seed"] == want["seed"]
    same_episodes = same_seed and got["episodes"] == want["episodes"]
    why = (f"the reference is of seed {want['seed']}, this digest of seed {got['seed']}" if not same_seed else
           f"checksums over every episode: the reference has {want['episodes']}, this digest {got['episodes']}")
    out = []
    for name in STAGES:
        if name not in want or name not in got:
            out.append(Stage(name, NOT_COMPARED, detail=f"not in the {'reference' if name not in want else 'digest'}"))
        elif name == "s_max":
            out.append(_fields(name, {name: got[name]}, {name: want[name]}))
        elif name == "reset":
            out.append(_reset(got, want, same_episodes) if same_seed else Stage(name, NOT_COMPARED, detail=why))
        elif not same_episodes:
            out.append(Stage(name, NOT_COMPARED, detail=why))
        elif name == "starts":
            out.append(_fields(name, got[name], want[name], note="" if got[name] == want[name] else
                               "checksums over every episode: reset names the episodes"))
        elif name == "kick_noise_t0_3":
            diff = [i for i, (x, y) in enumerate(zip(got[name], want[name])) if x != y]
            out.append(Stage(name, DIFFER, "kick_noise", f"iteration {diff[0]}",
                             f"{got[name][diff[0]]} here, {want[name][diff[0]]} there; differ at iterations {diff}")
                       if diff else Stage(name, MATCH))
        elif name == "lockstep":
            out.append(_lockstep(got[name], want[name]))
        elif name == "evaluator":
            s = _fields(name, got[name], want[name])
            out.append(dataclasses.replace(s, detail=f"{s.detail}; {_fitness(got[name], want[name])}")
                       if s.status == DIFFER else s)
        elif name == "heuristic_min_margin":
            parts = [_fields(name, got[name].get(mm, {}), w, where=f"min_margin {mm}")
                     for mm, w in want[name].items()]
            out.append(next((s for s in parts if s.status == DIFFER), Stage(name, MATCH)))
        else:  # a single checksum
            out.append(_fields(name, {name: got[name]}, {name: want[name]}))
    return out


def summary_line(backend: str, stages: list[Stage], reference_platform: str) -> str:
    """The benchmark's last line: ``platform: M of N stages match on BACKEND[, K not compared] (ratio M/N vs
    REF digest)``."""
    n, m = len(stages), sum(s.status == MATCH for s in stages)
    k = sum(s.status == NOT_COMPARED for s in stages)
    return (f"platform: {m} of {n} stages match on {backend}" + (f", {k} not compared" if k else "")
            + f" (ratio {m / n:.2f} vs {reference_platform.upper()} digest)")


def verdict(results: dict[str, list[Stage]], got_jax: str, want_jax: str, want_platform: str = "cpu") -> str:
    """What the stages of each backend (``results``: backend name, its stages, the host CPU's as ``cpu``) say
    together, against a reference of ``want_platform`` with JAX ``want_jax`` (``got_jax`` here)."""
    ok = {b: all(s.status != DIFFER for s in st) for b, st in results.items()}
    first = {b: next((s.name for s in st if s.status == DIFFER), None) for b, st in results.items()}
    bad = [b for b in results if not ok[b]]
    parted = ", ".join(f"{b} from the stage {first[b]}" for b in bad)
    version = (f"the JAX version differs (jax {got_jax} here, {want_jax} there)" if got_jax != want_jax else
               f"with the same JAX version ({got_jax}), the machine's CPU, jaxlib or kx's code computes differently")
    if not bad:
        if any(s.status == NOT_COMPARED for st in results.values() for s in st):
            return ("the stages compared match; the others were not compared (other episodes, another seed, or a "
                    "reference without them): compare digests of the same --episodes and --seed to check them all")
        return "every backend run here plays the reference's episodes bit for bit"
    if want_platform != "cpu":
        return (f"{parted} parts from the reference, recorded on {want_platform} with jax {want_jax} (jax {got_jax} "
                "here): the backend or the JAX version computes differently; the shipped CPU digest (no --reference) "
                "tells the two apart")
    if "cpu" not in results:
        return (f"{parted} parts from the reference; the host CPU backend was not run (--backends default,cpu "
                "runs both): if it agrees, this backend computes differently; if not, " + version)
    if ok["cpu"]:
        return (f"the host CPU backend agrees with the reference and {parted} does not: that backend computes "
                "differently")
    if len(bad) == 1 and len(results) > 1:
        return (f"the host CPU backend parts from the reference ({parted}) and {', '.join(b for b in results if ok[b])}"
                " agrees: the host CPU backend computes differently")
    return f"no backend run here agrees with the reference ({parted}): " + version


# ---------------------------------------------------------------------------------------------------- the run


def load_digest(path, option: str = "--reference") -> dict:
    """A digest from a JSON file, refused (naming ``option``) when missing or not a digest."""
    p = pathlib.Path(path)
    if not p.is_file():
        raise SystemExit(f"{option}: no file {path} (allowed: a digest written by "
                         "`python -m kx.bench platform --out FILE`)")
    try:
        d = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SystemExit(f"{option}: {path} is not a platform digest (not JSON: {e})") from None
    missing = [k for k in REQUIRED if not isinstance(d, dict) or k not in d]
    if missing or not isinstance(d.get("lockstep"), dict) or "blocks" not in d["lockstep"]:
        raise SystemExit(f"{option}: {path} is not a platform digest (missing {', '.join(missing) or 'lockstep blocks'}"
                         "; allowed: a digest written by `python -m kx.bench platform --out FILE`)")
    if not isinstance(d["episodes"], int) or d["episodes"] < 1:
        raise SystemExit(f"{option}: {path} is not a platform digest (episodes {d['episodes']!r})")
    return d


def check(args) -> tuple[list[str] | None, dict, str]:
    """``args`` checked before any compute: the backends asked for (``None``: the default and, where it is an
    accelerator, the host CPU), the reference digest and its path."""
    if not isinstance(args.episodes, int) or args.episodes < 1:
        raise SystemExit(f"--episodes: allowed an integer >= 1, got {args.episodes}")
    backends = None
    if getattr(args, "backends", None):
        backends = [b.strip() for b in args.backends.split(",") if b.strip()]
        bad = [b for b in backends if b not in BACKENDS]
        if bad or not backends:
            raise SystemExit(f"--backends: allowed a comma-separated list of {', '.join(BACKENDS)}, got "
                             f"{args.backends!r}")
        backends = list(dict.fromkeys(backends))
    ref = getattr(args, "reference", None) or str(REFERENCE)
    want = load_digest(ref)
    out = getattr(args, "out", None)
    if out and not pathlib.Path(out).resolve().parent.is_dir():
        raise SystemExit(f"--out: the folder of {out} does not exist")
    return backends, want, ref


def _on_backend(backend: str, episodes: int, seed: int) -> dict:
    """One backend's digest, computed twice in a process of its own (``JAX_PLATFORMS=cpu`` for ``cpu``; unset
    for ``gpu`` and ``tpu``, whose process checks that JAX picked that kind; as set for ``default``): the
    worker's JSON (:func:`worker`)."""
    import kx

    env = dict(os.environ)
    if backend == "cpu":
        env["JAX_PLATFORMS"] = "cpu"
    elif backend in ("gpu", "tpu"):
        env.pop("JAX_PLATFORMS", None)
    root = str(pathlib.Path(kx.__file__).resolve().parents[1])  # the same kx in the worker
    env["PYTHONPATH"] = os.pathsep.join([root] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    with tempfile.TemporaryDirectory(prefix="kx-platform-") as tmp:
        path = os.path.join(tmp, "digest.json")
        cmd = [sys.executable, "-m", "kx.bench.platform", "--episodes", str(episodes), "--seed", str(seed),
               "--json", path] + (["--expect", backend] if backend != "default" else [])
        rc = subprocess.run(cmd, env=env).returncode
        if rc:
            raise SystemExit(f"kx.bench platform: the {backend} backend's digest failed (exit {rc}; its message is "
                             "above)")
        with open(path) as f:
            return json.load(f)


def _out_path(out: str, i: int, platform: str) -> pathlib.Path:
    p = pathlib.Path(out)
    return p if i == 0 else p.with_name(f"{p.stem}-{platform}{p.suffix}")


def run(args) -> None:
    backends, want, ref = check(args)
    ref_name = "the shipped CPU digest" if ref == str(REFERENCE) else ref
    print(f"platform digest: {args.episodes} episodes of {TASK} (seed {args.seed}), the heuristic's; reference: "
          f"{ref_name} ({want['platform']}, jax {want['jax']}, {want['episodes']} episodes, seed {want['seed']})")
    queue = ([b for b in backends if b != "cpu"] + (["cpu"] if "cpu" in backends else [])) if backends else ["default"]
    runs: dict[str, dict] = {}
    while queue:
        b = queue.pop(0)
        if b == "cpu" and "cpu" in runs:
            continue  # the default backend was the CPU
        print(f"{b} backend: computing the digest twice in a process of its own (with compilation, then warm)...",
              flush=True)
        res = _on_backend(b, args.episodes, args.seed)
        runs.setdefault(res["digest"]["platform"], res)
        if backends is None and res["digest"]["platform"] != "cpu":
            queue.append("cpu")

    results = {}
    for i, (plat, res) in enumerate(runs.items()):
        d = res["digest"]
        print(f"{plat} backend ({res['devices']} x {res['device_kind']}; jax {d['jax']}, jaxlib {res['jaxlib']}): "
              f"digest {res['seconds_first']:.1f} s with compilation, {res['seconds_warm']:.1f} s warm; the warm "
              f"repeat identical: {res['repeat_identical']}")
        print(f"  lockstep: mean fitness {d['lockstep']['mean_fitness']:.4f}, {d['lockstep']['live_steps']:,} live "
              f"steps; evaluator: {d['evaluator']['mean_fitness']:.4f}, {d['evaluator']['live_steps']:,} live steps")
        results[plat] = compare(d, want)
        for s in results[plat]:
            print(f"  {s.line()}")
        if args.out:
            path = _out_path(args.out, i, plat)
            path.write_text(json.dumps(d, indent=1))
            print(f"  its digest: {path}")
    print("how to read: the world's state is integer or exactly rounded, so a platform that computes as the "
          "reference's did\n  matches every stage bit for bit; the first stage that differs is where the platforms "
          "part (later stages differ\n  in consequence). The host CPU backend agrees and the GPU does not: the GPU "
          "backend computes differently.\n  Neither agrees: the JAX version differs from the reference's (or, with "
          "the same version, the machine or kx's code).")
    first = next(iter(runs))
    print(f"verdict: {verdict(results, runs[first]['digest']['jax'], want['jax'], want['platform'])}")
    warm = {p: r["seconds_warm"] for p, r in runs.items()}
    if "cpu" in warm and first != "cpu":
        print(f"speed: warm digest {warm[first]:.1f} s on {first}, {warm['cpu']:.1f} s on the host CPU backend "
              f"(ratio {warm['cpu'] / warm[first]:.2f} vs cpu backend)")
    else:
        print(f"speed: warm digest {warm[first]:.1f} s on {first}, {runs[first]['seconds_first']:.1f} s with "
              f"compilation (no other backend run to compare with)")
    print(summary_line(first, results[first], want["platform"]))


def worker(argv=None) -> int:
    """One backend's digest in this process (JAX's default backend), twice: what ``python -m kx.bench platform``
    runs per backend. Writes ``--json``: the digest, the seconds of the first call and of the warm one, and
    whether the two were identical."""
    p = argparse.ArgumentParser(prog="python -m kx.bench.platform", description=worker.__doc__)
    p.add_argument("--episodes", type=int, default=4500)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", required=True, help="where to write the result")
    p.add_argument("--expect", choices=[b for b in BACKENDS if b != "default"],
                   help="refuse unless JAX's default backend is of this kind")
    args = p.parse_args(argv)
    from kx import runtime

    runtime.setup()
    import jax
    import jaxlib

    dev = jax.devices()
    if args.expect and dev[0].platform != args.expect:
        print(f"--backends: {args.expect} asked for, but JAX's backend here is {dev[0].platform} ({dev})",
              file=sys.stderr)
        return 3
    t0 = time.perf_counter()
    first = digest(args.episodes, args.seed)
    t1 = time.perf_counter()
    again = digest(args.episodes, args.seed)
    t2 = time.perf_counter()
    with open(args.json, "w") as f:
        json.dump({"digest": first, "seconds_first": t1 - t0, "seconds_warm": t2 - t1,
                   "repeat_identical": first == again, "jaxlib": jaxlib.__version__, "devices": len(dev),
                   "device_kind": dev[0].device_kind}, f)
    return 0


if __name__ == "__main__":
    sys.exit(worker())
