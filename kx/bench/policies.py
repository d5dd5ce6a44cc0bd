"""``python -m kx.bench policies``: what each policy's decision costs per live step of the world, on trained
4v3 populations, as a ratio to the heuristic's whole step measured in the same run.

**The populations** (``kx/bench/data/policies/<method>_4v3.npz``, made by
``scripts/make_policy_fixtures.py``): for NEAT and for HyperNEAT, a 3v2 run of the default config (NEAT seed
0, 15 generations; HyperNEAT seed 1, 20 generations, as HyperNEAT learns later), then a 4v3 run seeded with
its whole population and trained 5 generations; the fixture is the population of 150 the 4v3 run evaluates
next. HyperNEAT's genomes are CPPNs; their substrate table
(150 x 400 x 400) is built from them here.

**The work.** Each policy plays the same 4500 lanes: the population's 150 parameter sets, each on the same
30 start states (the training states of the NEAT fixture's 4v3 run at that generation: random resets that
no policy here has seen) with the same kick noise, through
:func:`kx.sim.evaluate.evaluate`, the run loop's evaluator, with its parameters made as the run loop makes
them (``encoding.policy`` and ``encoding.policy_params(population)``, ``Trainer.evaluate``). The heuristic
and always-hold (:data:`kx.sim.policies.BASELINES`) are handed 150 parameter sets they ignore, so that they
play the same 4500 lanes.

**The figure: nanoseconds per live step** = the wall time of one evaluation (from the call until its
statistics are on the host) over its live steps (steps of episodes still running, the evaluator's
counters): the world's step, the policy's decision and the evaluator's own costs (its rungs, the
narrowing tail), everything a generation pays per step of play. Episodes of different policies differ in
length (a trained population keeps the ball far longer than the heuristic), and normalising per live step
makes them comparable; what it does not remove is that long episodes leave a longer tail of narrow rungs,
which costs more per step, so the heuristic's short episodes are, if anything, charged more per step than
the trained teams' long ones. The policy's own share is reported as the difference to the heuristic's
whole step (whose decision is about 5 ns a lane) and to always-hold's (a decision of no cost; its
episodes are the shortest, so the evaluator's fixed costs weigh most on it). ``hyperneat`` is what
the run loop plays: :func:`kx.hyperneat.bev.bev_policy` with ``skip_idle`` (no decision where nobody holds
the ball or the episode is over); ``hyperneat_every_state`` decides on every state as the dense reference
does (the same episodes bit for bit, and so the same mean fitness). HyperNEAT's sums run on the native kernel
(:mod:`kx.hyperneat.native`) where it can be built, and the benchmark says so; ``hyperneat_xla`` is then the same
policy on the compiled XLA code, measured in the same run (the same episodes).

**Samples.** The policies are sampled in turn (one sample of each, ``--repeats`` times, as ``kx.bench
sim`` does), each sample repeating evaluations for at least ``--sample-seconds``; each figure is the median
of its samples with their spread, and each ratio the median of the ratios of samples taken in the same
round. The first evaluation of each policy compiles its widths; its excess over the warm median is
reported as compilation. Beside them, each policy's decision timed alone on one core over the 4500 lanes
(mid-episode states: 20 iterations of the heuristic from the start states), and HyperNEAT's substrate
build (``policy_params``), which a generation pays once.

The last two lines::

    neat: <ns> ns per live step (ratio <x> vs heuristic)
    policies: <ns> ns per live step hyperneat (ratio <x> vs heuristic)
"""

from __future__ import annotations

import json
import pathlib
import time

FIXTURES = pathlib.Path(__file__).resolve().parent / "data" / "policies"
ROOT = pathlib.Path(__file__).resolve().parent.parent.parent
METHODS = ("neat", "hyperneat")


def load_fixture(method: str):
    """``(trainer, population, meta)`` of a committed trained 4v3 population (``<method>_4v3.npz``)."""
    import jax.numpy as jnp
    import numpy as np

    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib
    from kx.neat.types import Genome

    path = FIXTURES / f"{method}_4v3.npz"
    if not path.exists():
        raise SystemExit(f"{path}: missing; python scripts/make_policy_fixtures.py makes it")
    data = np.load(path)
    meta = json.loads(str(data["meta"]))
    cfg = cfg_lib.load(str(ROOT / meta["target_config"]), [f"seed={meta['seed']}", "gif=false",
                                                           f"population_size={meta['population_size']}"])
    population = Genome(**{f: jnp.asarray(data[f]) for f in Genome.__dataclass_fields__})
    return run_lib.Trainer(cfg), population, meta


def evaluation_work(policy, params, starts, world, key):
    """One evaluation as a sample's unit of work: returns ``(seconds, live steps, executed steps, mean
    fitness)``."""
    import jax

    from kx.sim import evaluate as ev

    sim_params, sim = world

    def work():
        c = ev.EvalCounters()
        t0 = time.perf_counter()
        stats = ev.evaluate(policy, params, starts, sim_params, sim, key=key, counters=c)
        fitness = float(jax.block_until_ready(stats.fitness).mean())
        return time.perf_counter() - t0, c.live_steps, c.executed_steps, fitness

    return work


def sample(work, seconds: float) -> tuple[float, int, int]:
    """Evaluations repeated for at least ``seconds``: ``(seconds, live steps, evaluations)``."""
    dt = live = n = 0
    while dt < seconds or n == 0:
        s, lv, _, _ = work()
        dt, live, n = dt + s, live + lv, n + 1
    return dt, live, n


def _decision_alone(named, lanes, reps: int = 20, rounds: int = 5) -> dict:
    """Nanoseconds per lane of each ``fn(params, state)`` (a decision), applied ``reps`` times inside one
    compiled loop on one device, whose iterations depend on each other (XLA cannot hoist the work out);
    the medians of ``rounds`` calls taken in turn."""
    import jax
    import numpy as np

    from kx.bench.common import repeated

    loops = {k: (repeated(fn, reps), params) for k, (fn, params) in named.items()}
    for loop, params in loops.values():
        jax.block_until_ready(loop(params, lanes))
    times = {k: [] for k in loops}
    for _ in range(rounds):
        for k, (loop, params) in loops.items():
            t0 = time.perf_counter()
            jax.block_until_ready(loop(params, lanes))
            times[k].append((time.perf_counter() - t0) / reps / lanes.holder.shape[-1] * 1e9)
    return {k: float(np.median(v)) for k, v in times.items()}


def _mid_episode(lanes, heuristic, world, iterations: int = 20):
    """``lanes`` after ``iterations`` iterations of the heuristic (no kick noise), on one device."""
    import jax
    import jax.numpy as jnp

    from kx.sim import env

    sim_params, sim = world

    @jax.jit
    def play(state):
        def body(s, _):
            return env.transition(s, heuristic.apply(None, s, None), jnp.zeros_like(s.t), sim_params, sim), None
        return jax.lax.scan(body, state, None, length=iterations)[0]

    return play(jax.device_put(lanes, jax.devices()[0]))


def _lane_params(trainer, population, n_trials: int):
    """Each lane's parameters on one device, lane ``g * T + i`` (policy g, trial i), as the evaluator
    hands them to the policy: a per-lane pytree, or :class:`Shared` ``(table, index)``."""
    import jax
    import jax.numpy as jnp

    from kx.sim.policies import Shared

    enc = trainer.encoding
    # on one device (HyperNEAT's table comes with its rows split over the devices, for the evaluator)
    params = jax.device_put(enc.policy_params(population), jax.devices()[0])
    n_pol = jax.tree.leaves(params)[0].shape[0]
    lane = jnp.arange(n_pol * n_trials, dtype=jnp.int32)
    if enc.policy.shared:
        return Shared(params, lane // n_trials)
    return jax.tree.map(lambda p: jnp.moveaxis(jnp.take(p, lane // n_trials, axis=0), 0, -1), params)


def run(args) -> None:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.evolve import streams
    from kx.hyperneat import bev
    from kx.sim import env
    from kx.sim.policies import BASELINES

    fixtures = {m: load_fixture(m) for m in METHODS}
    trainer, _, meta = fixtures["neat"]
    exp = trainer.exp
    for m, (tr, _, _) in fixtures.items():
        if (tr.exp.sim, tr.exp.sim_params, tr.cfg.trials) != (exp.sim, exp.sim_params, trainer.cfg.trials):
            raise SystemExit(f"{m}: its fixture's task or trials differ from neat's")
    world = (exp.sim_params, exp.sim)
    keys = streams.training(meta["seed"], meta["generation"])
    n_trials = trainer.cfg.trials
    starts = env.reset_batch(keys.starts, n_trials, exp.sim_params, exp.sim)
    n_pol = meta["population_size"]
    print(f"devices: {jax.local_device_count()} x {jax.devices()[0].platform}; task {exp.sim.name}; {n_pol} x "
          f"{n_trials} lanes (the training start states of generation {meta['generation']} of seed {meta['seed']}, "
          f"NEAT's fixture's next)")
    for m, (_, _, mt) in fixtures.items():
        print(f"{m}: {mt['population_size']} genomes of seed {mt['seed']} after {mt['source_generations']} "
              f"generations of {mt['source_config']} and {mt['target_generations']} of {mt['target_config']} from them "
              f"(the 4v3 run's last mean fitness {mt['target_last_mean_fitness']:.4f})", flush=True)

    dummy = jnp.zeros((n_pol,), jnp.int32)  # parameter sets the baselines ignore: the same 4500 lanes
    policies = {"heuristic": (BASELINES["heuristic"](exp.sim), dummy), "hold": (BASELINES["hold"](exp.sim), dummy)}
    build = {}
    for m, (tr, population, _) in fixtures.items():
        enc = tr.encoding
        times = []
        for _ in range(3 if m == "hyperneat" else 1):
            t0 = time.perf_counter()
            params = jax.block_until_ready(enc.policy_params(population))
            times.append(time.perf_counter() - t0)
        build[m] = times
        policies[m] = (enc.policy, params)
    # HyperNEAT's policy deciding on every state, idle lanes included (bev_policy without skip_idle: the same
    # episodes bit for bit); the run loop's encoding skips them
    enc = fixtures["hyperneat"][0].encoding
    policies["hyperneat_every_state"] = (bev.bev_policy(exp.sim, enc.image, enc.decision, enc.substrate_activation),
                                         policies["hyperneat"][1])
    # what the run loop plays, on the compiled XLA code instead of the native kernel (the same episodes)
    why = bev.native_runs(enc.image)
    sums = "the native kernel (kx.hyperneat.native)" if not why else f"the XLA code ({why})"
    print(f"hyperneat's sums: {sums}", flush=True)
    if not why:
        policies["hyperneat_xla"] = (bev.bev_policy(exp.sim, enc.image, enc.decision, enc.substrate_activation,
                                                    skip_idle=True, impl="xla"), policies["hyperneat"][1])

    works, first = {}, {}
    for name, (policy, params) in policies.items():
        work = evaluation_work(policy, params, starts, world, keys.eval)
        t0 = time.perf_counter()
        dt, live, executed, fitness = work()  # compiles every width
        first[name] = (time.perf_counter() - t0, live, executed, fitness)
        works[name] = work
    reps, sec = args.repeats, args.sample_seconds
    print(f"each figure: the median of {reps} samples, the policies sampled in turn, each sample at least "
          f"{sec} s of evaluations", flush=True)
    samples = {k: [] for k in works}
    for _ in range(reps):
        for name, work in works.items():
            samples[name].append(sample(work, sec))
    per = {k: [dt / live * 1e9 for dt, live, _ in v] for k, v in samples.items()}
    med = {k: float(np.median(v)) for k, v in per.items()}
    ratio = {k: float(np.median([a / b for a, b in zip(v, per["heuristic"])])) for k, v in per.items()}
    for name in works:
        v, (t_first, live, executed, fitness) = per[name], first[name]
        warm = med[name] * live / 1e9
        extra = "" if name == "heuristic" else (f"; {med[name] - med['heuristic']:+.0f} ns beyond the heuristic's, "
                                                f"{med[name] - med['hold']:+.0f} beyond hold's")
        print(f"{name}: {med[name]:.0f} ns per live step (median; samples {min(v):.0f} to {max(v):.0f}, spread "
              f"{100 * (max(v) - min(v)) / med[name]:.0f}%; ratio {ratio[name]:.2f} vs heuristic){extra}; one "
              f"evaluation: {live} live steps, executed {executed} ({live / max(executed, 1):.2f} live), "
              f"{warm * 1e3:.0f} ms warm, mean fitness {fitness:.4f}; first call {t_first:.1f} s (compiling "
              f"{max(t_first - warm, 0.0):.1f} s)", flush=True)
    b = float(np.median(build["hyperneat"]))
    print(f"hyperneat: substrate build (policy_params, once a generation) {b * 1e3:.0f} ms (median of "
          f"{len(build['hyperneat'])}; the first {build['hyperneat'][0] * 1e3:.0f} ms); a generation's build and "
          f"evaluation {b + med['hyperneat'] * first['hyperneat'][1] / 1e9:.2f} s", flush=True)

    # each decision alone, on one device, over the 4500 lanes in mid-episode states
    lanes = _mid_episode(jax.tree.map(lambda a: jnp.tile(a, (1,) * (a.ndim - 1) + (n_pol,)), starts),
                         policies["heuristic"][0], world)
    named = {"heuristic": (lambda p, s: policies["heuristic"][0].apply(None, s, None), None)}
    for m, (tr, population, _) in fixtures.items():
        pol = tr.encoding.policy
        named[m] = ((lambda pol: lambda p, s: pol.apply(p, s, None))(pol), _lane_params(tr, population, n_trials))
    every = policies["hyperneat_every_state"][0]
    named["hyperneat_every_state"] = (lambda p, s: every.apply(p, s, None), named["hyperneat"][1])
    if "hyperneat_xla" in policies:
        on_xla = policies["hyperneat_xla"][0]
        named["hyperneat_xla"] = (lambda p, s: on_xla.apply(p, s, None), named["hyperneat"][1])
    alone = _decision_alone(named, lanes)
    print("each decision alone on one core (ns per lane, mid-episode states): "
          + ", ".join(f"{k} {v:.0f}" for k, v in alone.items()))
    print(f"neat: {med['neat']:.0f} ns per live step (ratio {ratio['neat']:.2f} vs heuristic)")
    print(f"policies: {med['hyperneat']:.0f} ns per live step hyperneat (ratio {ratio['hyperneat']:.2f} vs heuristic)")
