"""Checksums of the world's integer state along heuristic episodes, to compare two platforms (or two JAX
versions) and find where they part.

On an H200 with JAX 0.11.2 (2026-12-04, ``scripts/device_bench.sh``), ``kx.bench sim``'s heuristic played
its 4500 start states of 3v2 (seed 0) to a mean fitness of 0.0150 in 308,665 live steps; on this project's
CPU with JAX 0.10.2, 0.0235 in 479,470 (seeds 1 and 2: 0.0224, 0.0231), before the heuristic compared its
margins within a tolerance (below). Everything the world computes is
integer or exactly rounded (``kx.sim.geometry``), so the same start states should give the same episodes
bit for bit anywhere. This script records, for the same 4500 start states and kick-noise words:

* the start states and noise words (``jax.random``: the PRNG's bits);
* the heuristic's first decision, and the kick noise of iterations 0-3 (the hash of ``env.kick_noise``);
* the episodes stepped by ``env.transition`` alone, in lockstep (no evaluator: no lanes, rungs or
  compaction), a checksum of every state field after each block of iterations;
* the evaluator's results on the same episodes (``kx.sim.evaluate``: rungs, packing, compaction);
* the heuristic's evaluation with margins of exactly zero counted unsafe (``min_margin`` 2e-4).

The heuristic was the first thing found to part: before ``kx.sim.policies.MARGIN_TOL`` it passed at
margins of exactly zero and told equal margins apart by their last bit, so a platform rounding them
otherwise played other episodes (on this CPU, zeros counted unsafe gave 0.0106 against 0.0235).

Run it on each platform and compare::

    python scripts/platform_digest.py --out here.json
    python scripts/platform_digest.py --compare docs/results/platform_digest_cpu.json

On a GPU machine, run it twice (``JAX_PLATFORMS=cpu`` and the default): if the machine's own CPU backend
agrees with the committed file and its GPU does not, the GPU backend computes something differently;
if neither agrees, the JAX version does. The first entry that differs names the stage and field.
"""

from __future__ import annotations

import argparse
import json
import sys

BLOCK = 10  # iterations between two checksums of the lockstep episodes


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


def _reset_parts(key, episodes, params, config) -> dict:
    """``kx.sim.env.reset``'s stages for every episode, to name the operation where two platforms' start states
    part (on the H200 of 2026-12-04 the takers' cells differed, the keepers' and the holder did not): the
    random bits behind the takers' scores, the cells forbidden to them, the two top-k selections (keepers by
    their scores, takers among the allowed cells), and the cells themselves, one row per episode."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.sim import geometry as geo

    w, k, t = config.field_size, config.n_keepers, config.n_takers

    def parts(kk):
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
        # the same selection by a full sort of integer keys (no top-k, no float comparison): a reference
        # for the platform's top-k (scores are ties-free here; -1 for the forbidden)
        int_keys = jnp.where(forbidden, -1, (jax.random.bits(k_take, (w * w,)) >> 9).astype(jnp.int32))
        by_sort = jnp.argsort(-int_keys, stable=True)[:t].astype(jnp.int32)
        return (jax.random.bits(k_keep, (w * w,)), jax.random.bits(k_take, (w * w,)), forbidden,
                keeper_cells, taker_cells, by_sort, take_scores)

    kb, tb, forb, kc, tc, by_sort, ts = jax.jit(jax.vmap(parts))(jax.random.split(key, episodes))
    ts = np.asarray(ts)
    tc = np.asarray(tc)
    def rows(a):  # one string, an episode's cells per ';'-separated entry (a compact file)
        return ";".join(",".join(map(str, r)) for r in np.asarray(a).tolist())

    return {"keeper_bits": _checksum(np.asarray(kb).T.view(np.int32)),
            "taker_bits": _checksum(np.asarray(tb).T.view(np.int32)),
            "forbidden": _checksum(np.asarray(forb).T), "keeper_cells": rows(kc),
            "taker_cells": rows(tc), "taker_cells_by_sort": rows(by_sort),
            "takers_on_forbidden_cells": int((np.take_along_axis(ts, tc, 1) < 0).sum()),
            # episodes whose t + 1 highest taker scores hold a tie (top-k's order among equals is then the
            # platform's): none in seed 0's 4500 states of 3v2 on this CPU
            "taker_score_ties": int((np.diff(-np.sort(-ts, axis=1)[:, :t + 1], axis=1) == 0).any(axis=1).sum())}


def digest(episodes: int, seed: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.sim import env, policies
    from kx.sim import evaluate as ev
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    starts = env.reset_batch(jax.random.key(seed), episodes, params, config)
    key = jax.random.key(1)  # kx.bench sim's evaluation key
    words = env.noise_words(ev.stream_keys(key)[0], jnp.arange(episodes))
    policy = policies.heuristic(config)
    s_max = env.noise_limit(params.kick_noise_deg)
    out = {"platform": jax.devices()[0].platform, "jax": jax.__version__, "episodes": episodes, "seed": seed,
           "starts": _state_sums(starts), "noise_words": _checksum(np.asarray(words)), "s_max": int(s_max)}
    out["reset"] = _reset_parts(jax.random.key(seed), episodes, params, config)
    # the stages are env.reset's, written out: whether they give its start states on this platform (on this
    # CPU they must: else _reset_parts no longer follows kx.sim.env.reset)
    w = config.field_size
    out["reset"]["parts_give_the_starts"] = all(
        out["reset"][f"{who}_cells"] == ";".join(",".join(map(str, r)) for r in np.asarray(y * w + x).T.tolist())
        for who, x, y in (("keeper", starts.keeper_x, starts.keeper_y), ("taker", starts.taker_x, starts.taker_y)))
    if out["platform"] == "cpu" and not out["reset"]["parts_give_the_starts"]:
        raise SystemExit("scripts/platform_digest.py: _reset_parts no longer follows kx.sim.env.reset")
    out["first_decision"] = _checksum(jax.jit(lambda s: policy.apply(None, s, None))(starts))
    out["kick_noise_t0_3"] = [_checksum(env.kick_noise(words, jnp.full(episodes, t, jnp.int32), s_max))
                              for t in range(4)]

    @jax.jit
    def block(state):
        def one(_, s):
            return env.transition(s, policy.apply(None, s, None), env.kick_noise(words, s.t, s_max), params, config)
        return jax.lax.fori_loop(0, BLOCK, one, state)

    state, blocks = starts, []
    for i in range(int(params.max_iterations) // BLOCK + 1):
        state = block(state)
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
    # the heuristic passes at margins of exactly zero (kx.sim.policies.heuristic, min_margin 0.0, within
    # MARGIN_TOL): the same evaluation with those margins counted unsafe, which on this CPU before
    # MARGIN_TOL gave what the H200 gave in between
    out["heuristic_min_margin"] = {}
    for mm in (2 * policies.MARGIN_TOL,):
        c = ev.EvalCounters()
        got = ev.evaluate(policies.heuristic(config, min_margin=mm), None, starts, params, config, key=key, counters=c)
        out["heuristic_min_margin"][str(mm)] = {"mean_fitness": float(np.asarray(got.fitness).mean()),
                                                "live_steps": int(c.live_steps)}
    return out


def compare(got: dict, want: dict) -> list[str]:
    """Where ``got`` and ``want`` part: the first difference of each stage, in the order computed."""
    lines = []
    for k in ("episodes", "seed", "s_max"):
        if got[k] != want[k]:
            lines.append(f"{k}: {got[k]} here, {want[k]} there")
    diff = [f for f in want["starts"] if got["starts"].get(f) != want["starts"][f]]
    lines.append(f"starts: {'differ in ' + ', '.join(diff) if diff else 'the same'}")
    if "reset" in got and "reset" in want:
        r, q = got["reset"], want["reset"]
        for k in ("keeper_bits", "taker_bits", "forbidden"):
            lines.append(f"reset {k}: {'the same' if r[k] == q[k] else 'differ'}")
        for k in ("keeper_cells", "taker_cells", "taker_cells_by_sort"):
            a, b = r[k].split(";"), q[k].split(";")
            bad = [i for i, (x, y) in enumerate(zip(a, b)) if x != y]
            lines.append(f"reset {k}: {len(bad)} of {len(b)} episodes differ"
                         + (f" (episodes {bad[:5]}: {[a[i] for i in bad[:3]]} here, {[b[i] for i in bad[:3]]} there)"
                            if bad else ""))
        own = sum(x != y for x, y in zip(r["taker_cells"].split(";"), r["taker_cells_by_sort"].split(";")))
        lines.append(f"reset: here top-k and the integer sort disagree on the takers of {own} episodes; "
                     f"takers on forbidden cells here {r['takers_on_forbidden_cells']}; episodes with tied top "
                     f"taker scores here {r.get('taker_score_ties', '?')}; the stages give reset's start states here: "
                     f"{r.get('parts_give_the_starts', '?')}")
    for k in ("noise_words", "first_decision", "kick_noise_t0_3"):
        lines.append(f"{k}: {'the same' if got[k] == want[k] else 'differ'}")
    first = next(((a, b) for a, b in zip(got["lockstep"]["blocks"], want["lockstep"]["blocks"]) if a != b), None)
    if first is None and len(got["lockstep"]["blocks"]) == len(want["lockstep"]["blocks"]):
        lines.append("lockstep episodes: the same at every block")
    elif first is None:
        lines.append("lockstep episodes: the same as far as both go, but one ran more blocks")
    else:
        a, b = first
        fields = [f for f in b if a.get(f) != b[f] and f != "after"]
        lines.append(f"lockstep episodes: first differ after iteration {b['after']} (live {a['live']} here, "
                     f"{b['live']} there), in {', '.join(fields)}")
    for stage in ("lockstep", "evaluator"):
        lines.append(f"{stage}: mean fitness {got[stage]['mean_fitness']:.4f} here, {want[stage]['mean_fitness']:.4f} "
                     f"there; live steps {got[stage]['live_steps']} here, {want[stage]['live_steps']} there")
    for mm, w in want.get("heuristic_min_margin", {}).items():
        g = got.get("heuristic_min_margin", {}).get(mm)
        if g:
            lines.append(f"heuristic with min_margin {mm}: mean fitness {g['mean_fitness']:.4f} here, "
                         f"{w['mean_fitness']:.4f} there; live steps {g['live_steps']} here, {w['live_steps']} there")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=4500)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="write the digest here (JSON)")
    p.add_argument("--compare", help="a digest written elsewhere: print where this platform's parts from it")
    args = p.parse_args(argv)
    from kx import runtime

    runtime.setup()
    got = digest(args.episodes, args.seed)
    print(f"{got['platform']} (jax {got['jax']}): lockstep mean fitness {got['lockstep']['mean_fitness']:.4f}, "
          f"{got['lockstep']['live_steps']} live steps; evaluator {got['evaluator']['mean_fitness']:.4f}, "
          f"{got['evaluator']['live_steps']} live steps")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(got, f, indent=1)
    if args.compare:
        with open(args.compare) as f:
            want = json.load(f)
        print(f"against {args.compare} ({want['platform']}, jax {want['jax']}):")
        for line in compare(got, want):
            print(f"  {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
