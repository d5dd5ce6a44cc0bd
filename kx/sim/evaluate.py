"""Batched evaluation of G policies on T shared start states, paying only for live episodes.

Every (policy, trial) pair is a *lane*; lanes are batch-last arrays stepped in lockstep by a jitted
``while_loop``. The batch narrows as episodes end, down a ladder of widths (:func:`width_ladder`,
:func:`rungs`): each *rung* steps its lanes until the live ones fit the next narrower width and then
gathers them into it, on the device. Every rung of an evaluation runs in one compiled call
(:func:`_rungs`), compiled once per (policy, task, lane count) and reused across generations; the host
reads the rungs' counters once, when the last has run, so short episodes pay no host round trips. A
batch whose episodes end early therefore costs about what its live steps cost, and the results equal
those of each episode run alone (lanes never interact; the tests check this).

Split over several devices, each device steps and compacts its own lanes down the ladder on its own
counts and meets the others only at the end of the call. Until 2026-12-04 each rung was a call of its
own, and a call ended when its slowest device did: where one device's lanes held the long episodes
(good genomes: the lanes are policy-major, so a device holds one half of the population) it ran the
whole tail in one rung while the other waited, then the other ran its tail in the next rung while the
first waited. On populations 50 generations into the protocol's 4v3 cells, one call evaluated HyperNEAT's
1.04-2.63 times and NEAT's 1.45-2.06 times as fast (the same episodes; scripts/rungs_in_one_call.py at 4a07c62); a NEAT
group of 16 runs (8 on each device) is balanced already and gained about 1.1 times.
The lanes of several independent evaluations (the runs of a batched group) can share one batch: see
``key`` in :func:`evaluate`. How the lanes are packed into the rungs' arrays and placed on the devices
is :mod:`kx.sim.lanes`; this module steps them.

Policies take their parameters in one of two ways (:class:`kx.sim.policies.Policy`, ``shared``). Per
lane, each lane carries a copy of its policy's parameter set, batch-last like the state, gathered with
the lanes when the batch narrows. Shared, the lanes carry only their policy's index (``lane // T``,
int32); the whole table of G parameter sets is one argument of the compiled loop, the same for every
lane (replicated on every device), and the policy gathers its rows itself
(:class:`kx.sim.policies.Shared`). Shared tables cost their size once instead of once per lane.

Randomness does not depend on how lanes are batched. Two streams derive from the evaluation's key:
*evaluator noise* (the kicks), ``noise_key = fold_in(key, 0)``, and *policy noise* (stochastic
policies), ``policy_key = fold_in(key, 1)`` (equal to ``split(key)[0]`` and ``[1]`` under the default
threefry keys). The kick noise of trial ``i`` at iteration ``t`` is :func:`kx.sim.env.kick_noise` of the
trial's word ``bits(fold_in(noise_key, i))`` and ``t``, the same for every policy (common random
numbers); stochastic policies get ``fold_in(fold_in(policy_key, lane), t)`` with ``lane = g * T + i``
for policy ``g`` and trial ``i``.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from kx import runtime
from kx.sim import env, lanes, ops
from kx.sim.policies import Policy, Shared
from kx.sim.types import EpisodeStats, KeepAwayConfig, KeepAwayParams, State


@dataclasses.dataclass
class EvalCounters:
    """What an evaluation executed: lane-steps stepped in lockstep and those of live episodes, the
    compiled calls (rungs) it dispatched and the widths that stepped at least once."""

    executed_steps: int = 0
    live_steps: int = 0
    chunks: int = 0
    widths: tuple[int, ...] = ()


def width_ladder(n: int, smallest: int = 64, multiple: int = 1) -> list[int]:
    """Batch widths, descending: ``n``, then powers of two below it down to ``smallest``, with 3/4 of
    each power from 1024 up, and steps of 256 between 1024 and 2048 and of 128 between 512 and 1024
    (good teams leave a long tail of full-length episodes; a close width wastes less on it).

    Each width costs one compilation (a few seconds on CPU, then cached), so the ladder stays coarse.
    Widths are rounded up to a ``multiple`` (the number of devices the lanes are split over).
    """
    sizes = {n}
    p = smallest
    while p < n:
        sizes.add(p)
        if p >= 1024 and p * 3 // 4 < n:
            sizes.add(p * 3 // 4)
        p *= 2
    sizes |= {w for w in range(1024 + 256, 2048, 256) if w < n}
    sizes |= {w for w in range(512 + 128, 1024, 128) if w < n}
    sizes = {-(-w // multiple) * multiple for w in sizes}
    return sorted(sizes, reverse=True)


def stream_keys(key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The evaluator's two streams of an evaluation key: ``(noise_key, policy_key)`` = ``(fold_in(key,
    0), fold_in(key, 1))``, kick noise and policy noise."""
    return jax.random.fold_in(key, 0), jax.random.fold_in(key, 1)


def _lane_keys(key: jax.Array, ids: jax.Array, t: jax.Array) -> jax.Array:
    """One key per lane for iteration ``t``: ``fold_in(fold_in(key, id), t)``."""
    return jax.vmap(lambda i, tt: jax.random.fold_in(jax.random.fold_in(key, i), tt))(ids, t)


def _group_lane_keys(keys: jax.Array, group_size: jax.Array, ids: jax.Array, t: jax.Array) -> jax.Array:
    """:func:`_lane_keys` of lanes from several run groups: lane ``id`` belongs to group ``id //
    group_size`` and is lane ``id % group_size`` of it; its key is that of the group's evaluation key
    ``keys[group]`` (one group: the same keys as :func:`_lane_keys`)."""
    return jax.vmap(lambda k, i, tt: jax.random.fold_in(jax.random.fold_in(k, i), tt))(
        keys[ids // group_size], ids % group_size, t)


def _advance_local(state: State, lane_params: Any, noise_word: jax.Array, lane_id: jax.Array,
                   keys: jax.Array, group_size: jax.Array, params: KeepAwayParams, chunk: jax.Array,
                   stop_at: jax.Array, table: Any = None, *, policy: Policy, config: KeepAwayConfig):
    """Up to ``chunk`` iterations of every lane (``[.., n]``), stopping early once at most ``stop_at``
    lanes are live (the next narrower batch width would hold them; 0: when all have finished).
    ``noise_word [n]``: each lane's trial's kick-noise word (:func:`kx.sim.env.noise_words`).
    ``lane_params``: each lane's parameters, or for a shared policy each lane's row of ``table``
    (``[n]`` int32). ``keys [R]``: the evaluation key of each run group (lanes ``r * group_size`` to
    ``(r + 1) * group_size - 1``), read by stochastic policies only.
    """
    policy_keys = jax.vmap(lambda k: stream_keys(k)[1])(keys)
    s_max = env.noise_limit(params.kick_noise_deg)
    policy_params = Shared(table, lane_params) if policy.shared else lane_params

    def one(state):
        pkeys = (_group_lane_keys(policy_keys, group_size, lane_id, state.t) if policy.stochastic
                 else None)
        action = ops.fenced(policy.apply, policy_params, state, pkeys)
        noise = env.kick_noise(noise_word, state.t, s_max)
        return env.transition(state, action, noise, params, config)

    def body(carry):
        state, i = carry
        return one(state), i + 1

    def cond(carry):
        state, i = carry
        return (i < chunk) & (jnp.sum(~state.done, dtype=jnp.int32) > stop_at)

    state, steps = jax.lax.while_loop(cond, body, (state, jnp.zeros((), jnp.int32)))
    # [1, 2]: iterations run and lanes still live, fetched by the host in one transfer
    return state, jnp.stack([steps, jnp.sum(~state.done, dtype=jnp.int32)])[None]


# The evaluator's loops are compiled for 512-bit vector registers where the CPU has them (AVX-512; XLA
# CPU's default prefers 256 bits): the step alone ran 14.0M -> 16.5M lane-steps/s on 2 CPU devices, and
# 20-27M -> 26-30M once the heuristic was vectorised (2026-12-02, scripts/profile_evaluator.py). Only
# these loops: set for the whole process, the same option changed evosax's CMA-ES
# (its covariance update's sums split differently over the wider registers) and so the runs of Table 3,
# whereas what a step computes is elementwise per lane (the policies' sums run along a short leading
# axis, the lanes last), which the width of the registers does not change: the protocol's NEAT and
# HyperNEAT runs came out bit for bit the same with the option set everywhere. Other backends ignore it.
LOOP_COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": 512}


@functools.partial(jax.jit, static_argnames=("policy", "config", "n_dev"), compiler_options=LOOP_COMPILER_OPTIONS)
def advance(state, lane_params, noise_word, lane_id, keys, group_size, params, chunk, stop_at, table=None, *,
            policy, config, n_dev):
    """:func:`_advance_local` on each device's share of the lanes: every device runs its own loop
    and stops when its own lanes are done or fit its share of the next narrower width (a global
    count would need a collective every iteration, which measured slower). A shared policy's
    ``table`` is replicated: every device reads the whole of it. Returns the state and, per device,
    the iterations it ran and its live lanes ``[n_dev, 2]``. The step with no rungs around it (the lanes
    unpacked, never compacted): :func:`kx.bench.sim.lockstep` times it."""
    local = functools.partial(_advance_local, policy=policy, config=config)
    if n_dev == 1:
        return local(state, lane_params, noise_word, lane_id, keys, group_size, params, chunk, stop_at, table)
    in_specs = (lanes.lane_specs((state, lane_params, noise_word, lane_id))
                + lanes.replicated_specs((keys, group_size, params, chunk, stop_at, table)))
    out_specs = (lanes.lane_specs(state), lanes.PER_DEVICE)
    # each device stops once its own live lanes fit its share of the narrower width
    return jax.shard_map(local, mesh=lanes.mesh(n_dev), in_specs=in_specs, out_specs=out_specs, check_vma=False)(
        state, lane_params, noise_word, lane_id, keys, group_size, params, chunk, stop_at // n_dev, table)


# The rungs of the ladder an evaluation steps through: from a width, the next is the widest one at most
# this share of it. Each rung steps its lanes until the live ones fit the next rung, and there compacts
# them (:func:`_rungs`). A rung whose lanes already fit the next one costs a compaction only. Measured on
# 4500 heuristic episodes of 3v2 when each rung was a call and the host still returned between calls (a
# sync, a record and a compaction, 1-2 ms each): 1.0 (every rung) 6.3M live-steps/s, 0.8 9.0M, 0.6 9.0M,
# 0.5 7.8M.
SHRINK = 0.8

COUNTERS = ("t", "reason", "passes", "dispersion_sum", "ball_centre_sum", "decisions")

# no iteration cap inside a rung: every episode ends by max_iterations, so the loop ends by itself
_NO_CAP = np.int32(2**31 - 1)


def rungs(ladder: list[int]) -> list[int]:
    """The widths an evaluation steps through, from ``ladder[0]``: each the widest width of ``ladder`` at
    most :data:`SHRINK` of the one before."""
    out = [ladder[0]]
    while True:
        nxt = [w for w in ladder if w < out[-1] and w <= SHRINK * out[-1]]
        if not nxt:
            return out
        out.append(nxt[0])


@functools.partial(jax.jit, static_argnames=("policy", "config", "n_dev", "targets", "layout", "n_groups", "impl",
                                             "table_rows"), compiler_options=LOOP_COMPILER_OPTIONS)
def _rungs(rows, lane_params, scalars, table=None, *, policy, config, n_dev, targets, layout, n_groups, impl,
           table_rows=False):
    """Rungs one after another in one compiled call: in rung ``k`` every lane is stepped until the live ones
    fit ``targets[k]`` (0: until every episode has ended), then on each device the ``targets[k] // n_dev`` of
    its lanes that come first when live lanes are put before finished ones (lanes never move between
    devices) go on to the next rung. Each device runs its own loops and compactions, stopping on its own
    counts, and waits for the other devices only at the end of the call: one device's long episodes do not
    hold the others at every rung (see ``evaluate``). The lanes (state, a shared policy's row index, noise
    word, id) come and go packed in one array ``rows`` (:class:`kx.sim.lanes.Layout`), a per-lane policy's
    parameters beside them as they are (``lane_params``, else None: packed, NEAT's networks were copied once
    more per rung and its evaluation took 15% longer); ``scalars`` holds the params, the run groups' size and
    their ``n_groups`` keys of PRNG ``impl`` (:func:`kx.sim.lanes.pack_scalars`). A shared ``table`` is whole
    on every device, or with ``table_rows`` its rows are split over the devices
    (:func:`kx.sim.lanes.rows_split`: each device holds the rows its lanes play, and a lane's row index is
    made local to them). Returns, if the last target is not 0, the lanes and parameters compacted to it;
    then every rung's record of its lanes before its compaction, side by side per device (``[7, n_dev x
    sum of the rungs' widths per device]``: :data:`COUNTERS`, then the lane id; finished lanes' values are
    final), and per device and rung the iterations run and the live lanes ``[n_dev, len(targets), 2]``."""
    def local(rows, lane_params, scalars, table):
        params, group_size, keys = lanes.unpack_scalars(scalars, n_groups, impl)
        records, progress = [], []
        for target in targets:
            state, index, noise_word, lane_id = lanes.unpack(rows, layout)
            if table_rows:  # this device's rows of the table: the lanes' rows, counted from its first
                index = index - jax.lax.axis_index("lanes") * jax.tree.leaves(table)[0].shape[0]
            state, ran = _advance_local(state, index if policy.shared else lane_params, noise_word, lane_id, keys,
                                        group_size, params, _NO_CAP, jnp.int32(target // n_dev), table,
                                        policy=policy, config=config)
            records.append(jnp.stack([getattr(state, f) for f in COUNTERS] + [lane_id]))  # [7, lanes]
            progress.append(ran)
            if not target:
                break
            # the state's rows anew, the rest (row index, noise word, id) as they came
            order = lanes.live_first(state.done, target // n_dev)
            rows = jnp.take(jnp.concatenate([lanes.pack(state), rows[layout.first_rows():]]), order, axis=-1)
            if not policy.shared:
                lane_params = jax.tree.map(lambda a: jnp.take(a, order, axis=-1), lane_params)
        out = (jnp.concatenate(records, axis=1), jnp.concatenate(progress)[None])
        if targets[-1]:
            return (rows, None if policy.shared else lane_params) + out
        return out

    if n_dev == 1:
        return local(rows, lane_params, scalars, table)
    in_specs = (lanes.lane_specs((rows, lane_params)) + (lanes.replicated_specs(scalars),)
                + ((lanes.row_specs if table_rows else lanes.replicated_specs)(table),))
    out_specs = (lanes.lane_specs(rows), lanes.PER_DEVICE_RUNGS)
    if targets[-1]:
        out_specs = lanes.lane_specs((rows, lane_params)) + out_specs
    return jax.shard_map(local, mesh=lanes.mesh(n_dev), in_specs=in_specs, out_specs=out_specs, check_vma=False)(
        rows, lane_params, scalars, table)


@functools.partial(jax.jit, static_argnames=("shared", "n_groups", "n_pol", "n_trials", "width"))
def _prepare(starts, policy_params, keys, *, shared, n_groups, n_pol, n_trials, width):
    """The first rung's lanes, packed (:func:`kx.sim.lanes.pack`, :func:`kx.sim.lanes.lane_layout`), and a
    per-lane policy's parameters for them (else None), in one compiled call (eagerly, the noise words
    and the gathers cost a fifth of an evaluation of 4500 short episodes): lane ``l`` plays run ``l //
    group_size``'s policy ``l // T`` on that run's trial ``l % T`` with the trial's kick-noise word; past
    ``n`` (padding to a multiple of the devices) lane ``l`` repeats lane ``l mod n``, the same episode
    with the same keys, so recording it twice writes the same values. (A shared table does not pass
    through here: a compiled call would copy it, 96 MB for HyperNEAT.)

    It runs where its inputs are, not split over the devices: partitioned, with the lanes' sharding
    imposed on its result, it took 2.0 ms for 4500 lanes on 2 CPU devices, against 0.5 ms on one
    followed by a copy of half the lanes to the other (:func:`evaluate`)."""
    group_size = n_pol * n_trials
    n = n_groups * group_size
    lane_id = jnp.arange(width, dtype=jnp.int32) % n
    trial_id = (lane_id // group_size) * n_trials + lane_id % n_trials
    words = jax.vmap(lambda k: env.noise_words(stream_keys(k)[0], jnp.arange(n_trials)))(keys).reshape(-1)
    noise_word = jnp.take(words, trial_id)
    state = jax.tree.map(lambda a: jnp.take(a, trial_id, axis=-1), starts)
    if shared:  # lanes carry their row of the table; the table stays whole
        return lanes.pack((state, lane_id // n_trials, noise_word, lane_id)), None
    lane_params = jax.tree.map(lambda p: jnp.moveaxis(jnp.take(p, lane_id // n_trials, axis=0), 0, -1), policy_params)
    return lanes.pack((state, None, noise_word, lane_id)), lane_params


@functools.partial(jax.jit, static_argnames=("config", "shape"))
def _finish(results: dict, params: KeepAwayParams, *, config, shape):
    # Normalised once, over all episodes, by one program: the floats do not depend on the batch
    # widths or device split the episodes ran in.
    stats = env.stats_from_counts(*(results[f] for f in COUNTERS), params, config)
    return jax.tree.map(lambda a: a.reshape(a.shape[:-1] + shape), stats)


def evaluate(policy: Policy, policy_params: Any, starts: State, params: KeepAwayParams,
             config: KeepAwayConfig, *, key: jax.Array | None = None, devices: int | None = None,
             counters: EvalCounters | None = None) -> EpisodeStats:
    """Runs every policy on every start state to the end of its episode.

    Args:
      policy: the policy (see :mod:`kx.sim.policies`).
      policy_params: a pytree with a leading axis of G parameter sets, or ``None`` (G = 1). Per lane
        (``policy.shared`` false) each set is copied into the lanes that play it; for a shared policy
        the pytree is the table every lane reads (:class:`kx.sim.policies.Shared`), never copied per
        lane: whole on every device, or, if its rows come split evenly over the devices
        (:func:`kx.sim.lanes.put_rows`), each device reads the rows its lanes play where they are. Either
        way it is an argument of the compiled calls: new values do not recompile.
      starts: T start states, batch-last (``[.., T]``), e.g. from :func:`kx.sim.env.reset_batch`.
      params, config: the world.
      key: needed for kick noise and stochastic policies: evaluator noise (the kicks) draws from
        ``fold_in(key, 0)``, policy noise from ``fold_in(key, 1)`` (:func:`stream_keys`).

        **Run groups.** ``key`` may instead be an array of R keys (shape ``[R]``): R independent
        evaluations (the runs of a batched group, :mod:`kx.evolve.group`) played as one batch. Then
        ``policy_params`` holds R x P parameter sets, run ``r``'s P at rows ``r * P`` to ``(r + 1) * P
        - 1``; ``starts`` holds R x T states, run ``r``'s at ``r * T`` to ``(r + 1) * T - 1``; run ``r``'s
        policies meet only its own states with its own key's noise; and the result is ``[R, P, T]``.
        Each run's episodes, and so its results, are those that evaluating it alone gives.
      devices: split the lanes over this many local devices (default: all). On a CPU, run with
        ``XLA_FLAGS=--xla_force_host_platform_device_count=<cores>`` to get one device per core.
      counters: if given, filled with executed and live lane-steps.

    Returns:
      :class:`EpisodeStats` with batch ``[G, T]`` (``behaviour`` is ``[3, G, T]``); with R keys
      ``[R, P, T]`` (``behaviour`` ``[3, R, P, T]``).
    """
    env.check(config, params)
    runtime.guard_maps()  # before this evaluation compiles anything: a script's guard (the run loop has its own)
    if key is None:
        if policy.stochastic or float(jnp.asarray(params.kick_noise_deg)) > 0:
            raise ValueError("key: a key is needed for kick noise and for stochastic policies")
        key = jax.random.key(0)
    grouped = key.ndim == 1
    keys = key if grouped else key[None]
    n_groups = keys.shape[0]
    n_states = starts.holder.shape[-1]
    leaves = jax.tree.leaves(policy_params)
    n_sets = leaves[0].shape[0] if leaves else 1
    if n_states % n_groups or n_sets % n_groups:
        raise ValueError(f"key: {n_groups} run groups need as many start states per group and parameter sets per "
                         f"group; got {n_states} start states and {n_sets} parameter sets")
    n_trials, n_pol = n_states // n_groups, n_sets // n_groups
    group_size = n_pol * n_trials
    n = n_groups * group_size
    n_dev = min(devices or jax.local_device_count(), jax.local_device_count())
    ladder = width_ladder(n, multiple=n_dev)
    starts, policy_params, keys = lanes.onto_mesh((starts, policy_params, keys), n_dev)
    rows, lane_params = _prepare(starts, None if policy.shared else policy_params, keys, shared=policy.shared,
                                 n_groups=n_groups, n_pol=n_pol, n_trials=n_trials, width=ladder[0])
    # split the lanes once; in any other layout every sharded call would reshard them
    rows, lane_params = lanes.put_lanes((rows, lane_params), n_dev)
    layout = lanes.lane_layout(starts, policy.shared)
    # what every rung reads besides its lanes, on the devices once rather than sent with every rung: a shared
    # table whole on each device (replicated), or, where it comes with its rows split over the devices and
    # they divide evenly (HyperNEAT's substrates, built so: kx.hyperneat.substrate.build), as it is: each
    # device's lanes play exactly its rows (the lanes are policy-major and stay on their device), and a copy
    # of the whole table onto each device (96 MB, about 48 ms on 2 CPU devices:
    # scripts/hyperneat_table_placement.py at 4a07c62) is saved
    table_rows = policy.shared and lanes.rows_split(policy_params, n_dev)
    table, scalars = lanes.put_replicated(
        (policy_params if policy.shared and not table_rows else None, lanes.pack_scalars(params, group_size, keys)),
        n_dev)
    if table_rows:
        table = policy_params
    # Every rung in one call (_rungs): each device steps and compacts its own lanes down the ladder without
    # waiting for the others, and the host reads what the rungs recorded (a few integers per lane) once, at
    # the end, in one transfer.
    chain = rungs(ladder)
    targets = tuple(chain[1:]) + (0,)
    call = functools.partial(_rungs, policy=policy, config=config, n_dev=n_dev, layout=layout, n_groups=n_groups,
                             impl=str(jax.random.key_impl(keys)), table_rows=table_rows)
    per_device = [w // n_dev for w in chain]
    packed, progress = (np.asarray(a) for a in call(rows, lane_params, scalars, table, targets=targets))
    results = {f: np.zeros(n, np.int32) for f in COUNTERS}
    for block in np.split(packed, n_dev, axis=1):  # each device's rungs, one after another
        for rec in np.split(block, np.cumsum(per_device)[:-1], axis=1):  # later rungs overwrite lanes still live
            for i, f in enumerate(COUNTERS):
                results[f][rec[-1]] = rec[i]  # padding lanes repeat a lane and write the same values
    if counters is not None:
        ran = progress[:, :, 0]  # [n_dev, rungs]
        counters.chunks += len(chain)
        counters.executed_steps += int((ran.astype(np.int64) * np.array(per_device)).sum())
        counters.widths = tuple(w for i, w in enumerate(chain) if i == 0 or ran[:, i].max() > 0)
        counters.live_steps += int(results["t"].sum(dtype=np.int64))
    shape = (n_groups, n_pol, n_trials) if grouped else (n_pol, n_trials)
    return _finish(results, params, config=config, shape=shape)


def rollout(policy: Policy, policy_params: Any, start: State, params: KeepAwayParams,
            config: KeepAwayConfig, *, key: jax.Array | None = None, n_steps: int | None = None,
            trial: int = 0, policy_index: int = 0, lane: int | None = None):
    """One episode step by step, every state kept (for rendering and inspection).

    ``policy_params`` is one parameter set (no leading axis) of a per-lane policy, or for a shared
    policy (``policy.shared``) the whole table with its leading axis G, of which row ``policy_index``
    plays (ignored for per-lane policies). Returns the stacked states ``[n_steps + 1]`` (leading axis;
    the first is ``start``) and the actions taken ``[n_steps]``. Steps after the episode ends repeat
    its final state.

    With the same ``key``, ``trial = i`` plays the kick noise of trial ``i`` of :func:`evaluate`, and a
    stochastic policy the policy keys of lane ``lane`` (default ``trial``: the first policy's lane of
    that trial; policy ``g`` of an evaluation of ``T`` trials played trial ``i`` in lane ``g * T + i``),
    so it replays that episode exactly.
    """
    n_steps = int(params.max_iterations) if n_steps is None else n_steps
    key = jax.random.key(0) if key is None else key
    lane = trial if lane is None else lane
    return _rollout(policy, policy_params, start, key, params, jnp.int32(trial), jnp.int32(policy_index),
                    jnp.int32(lane), config=config, n_steps=n_steps)


@functools.partial(jax.jit, static_argnums=(0,), static_argnames=("config", "n_steps"))
def _rollout(policy, policy_params, start, key, params, trial, policy_index, lane_id, *, config, n_steps):
    noise_key, policy_key = stream_keys(key)
    s_max = env.noise_limit(params.kick_noise_deg)
    word = env.noise_words(noise_key, jnp.full((1,), trial, jnp.int32))
    lane = jnp.full((1,), lane_id, jnp.int32)
    batched = jax.tree.map(lambda a: a[..., None], start)
    if policy.shared:
        lp = Shared(policy_params, jnp.full((1,), policy_index, jnp.int32))
    else:
        lp = jax.tree.map(lambda p: jnp.asarray(p)[..., None], policy_params)

    def body(state, _):
        pkeys = _lane_keys(policy_key, lane, state.t) if policy.stochastic else None
        action = ops.fenced(policy.apply, lp, state, pkeys)
        noise = env.kick_noise(word, state.t, s_max)
        nxt = env.transition(state, action, noise, params, config)
        return nxt, (nxt, action)

    _, (states, actions) = jax.lax.scan(body, batched, None, length=n_steps)
    states = jax.tree.map(lambda s0, s: jnp.concatenate([s0[None], s], axis=0), batched, states)
    return jax.tree.map(lambda a: a[..., 0], states), actions[..., 0]
