"""XOR, NEAT's validation task (Stanley & Miikkulainen 2002, section 4.1), as an example of the API.

Fitness, what selection sees, is Stanley's ``(4 - sum |output - target|)^2`` over the four input
pairs. A network solves XOR when its score ``4 - sum (output - target)^2`` reaches
:data:`SOLVED_SCORE` = 3.9: neat-python's fitness and threshold in its standard XOR example, so that
``python -m kx.bench neat_xor`` judges both tools by one criterion. It is stricter than Stanley's
(every output on the right side of 0.5, which any score above 3.75 implies); :func:`run` also
records the generation at which that looser criterion was first met. :func:`run` evolves many
independent populations at once: the whole run (up to ``max_generations`` generations, stopping once
every population has a solution) is one jitted ``lax.while_loop`` over a generation step vmapped over
seeds.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from kx.neat import algorithm
from kx.neat.network import forward
from kx.neat.types import HIDDEN, NEATConfig, NEATParams

XOR_INPUTS = jnp.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 1.0]], jnp.float32)
XOR_TARGETS = jnp.array([0.0, 1.0, 1.0, 0.0], jnp.float32)
SOLVED_SCORE = 3.9  # solved: 4 - sum of squared errors >= 3.9 (neat-python's examples/xor threshold)


def outputs(population, config: NEATConfig) -> jax.Array:
    """Outputs ``[P, 4]`` of a population's networks on the four XOR input pairs."""
    nets = algorithm.build_networks(population, config)
    return jax.vmap(lambda n: forward(n, XOR_INPUTS.T, config)[0])(nets)


def criteria(out: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(fitness, score, right_side)`` of outputs ``[..., 4]``: Stanley's fitness
    ``(4 - sum |error|)^2``, the score ``4 - sum error^2`` (solved when ``>= SOLVED_SCORE``) and
    Stanley's criterion (every output on the right side of 0.5)."""
    err = out - XOR_TARGETS
    return ((4.0 - jnp.sum(jnp.abs(err), axis=-1)) ** 2, 4.0 - jnp.sum(err * err, axis=-1),
            jnp.all(jnp.abs(err) < 0.5, axis=-1))


def evaluate(population, config: NEATConfig) -> tuple[jax.Array, jax.Array]:
    """``(fitness [P], solved [P])`` of a population on XOR: Stanley's fitness, and whether the score
    ``4 - sum of squared errors`` reaches :data:`SOLVED_SCORE`."""
    fitness, score, _ = criteria(outputs(population, config))
    return fitness, score >= SOLVED_SCORE


@functools.partial(jax.jit, static_argnames=("config", "max_generations", "width", "devices"))
def run(keys: jax.Array, params: NEATParams, config: NEATConfig, max_generations: int = 300,
        width: int | None = None, devices: int = 1) -> dict:
    """Independent XOR runs, one per key (``[R]`` keys), ``width`` populations evolving side by side
    on each of ``devices`` devices.

    A run stops at its first solution or after ``max_generations`` generations, and its slot starts the
    next run at once, so the batch stays full until the queue is empty. With ``devices > 1`` the runs
    are dealt out in turn (run ``i`` to device ``i % devices``) and each device works through its own
    queue with no communication: on a CPU each XLA host device (``kx.runtime.setup`` makes one per
    core) runs its step on its own thread, where one device's small step leaves the second core mostly
    idle. Each run draws its random numbers from its own key only; the floating-point rounding may
    still depend on ``width`` (XLA picks other kernels for other batch shapes), so compare runs at one
    width. On a 2-core CPU, 2 devices of width 1 are fastest (docs/benchmarks.md).

    Returns per run: ``solved`` (bool: some genome's score ``4 - SSE`` reached :data:`SOLVED_SCORE`),
    ``generations`` (generations evaluated up to and including the one with the first solution;
    ``max_generations`` if none), ``evaluations`` (``generations * population_size``), ``score`` (the
    best score of the last generation evaluated: the solution's if solved), ``hidden`` and ``links``
    (enabled) of that generation's best-scoring genome (the solution that neat-python returns too),
    ``right_side_generations`` and ``right_side_evaluations`` (the same counts for Stanley's looser
    criterion, every output on the right side of 0.5: the generation it was first met in, 0 if never;
    the run up to there is the run that would have stopped there), and ``n_species``
    ``[R, max_generations]`` (species per evaluated generation, -1 after the run ended).
    """
    if devices > 1:
        r = keys.shape[0]
        per = -(-r // devices)
        idx = jnp.arange(per * devices).reshape(per, devices).T  # device d: runs d, d + devices, ...
        mesh = jax.sharding.Mesh(np.array(jax.devices()[:devices]), ("runs",))
        spec = jax.sharding.PartitionSpec("runs")
        local = lambda k, n: jax.tree.map(lambda a: a[None], _run(k[0], n[0], params, config, max_generations,
                                                                   width))
        n_real = jnp.sum(idx < r, axis=1)  # a device's padding runs (past r) are not run
        out = jax.shard_map(local, mesh=mesh, in_specs=(spec, spec), out_specs=spec, check_vma=False)(
            keys[jnp.minimum(idx, r - 1)], n_real)
        flat = jax.tree.map(lambda a: a.reshape((per * devices,) + a.shape[2:]), out)
        order = jnp.argsort(idx.reshape(-1))  # back to the keys' order
        return jax.tree.map(lambda a: a[order][:r], flat)
    return _run(keys, keys.shape[0], params, config, max_generations, width)


def _run(keys, n_runs, params, config, max_generations, width) -> dict:
    """:func:`run` on one device: the first ``n_runs`` (may be traced) of the ``[R]`` keys."""
    r_cap = keys.shape[0]
    r = n_runs
    w = min(width or r_cap, r_cap)
    split = jax.vmap(jax.random.split)(keys)  # [R, 2]: init key, loop key
    init_one = lambda run_id: algorithm.init(split[jnp.minimum(run_id, r - 1), 0], params, config)
    tell = jax.vmap(lambda k, pop, fit, st: algorithm.tell(k, pop, fit, st, params, config))
    rows = jnp.arange(w)

    def cond(c):
        return jnp.any(c["run"] < r)

    def body(c):
        states, run, age = c["states"], c["run"], c["age"]
        active = run < r
        fit, score, right_side = criteria(jax.vmap(lambda pop: outputs(pop, config))(states.population))
        solved = score >= SOLVED_SCORE
        any_solved = jnp.any(solved, axis=1)
        rs = jnp.where((c["rs"] == 0) & jnp.any(right_side, axis=1), age + 1, c["rs"])
        first = jnp.argmax(score, axis=1)  # the best genome: a solution if there is one
        pop = states.population
        sol_h = jnp.sum(pop.node_kind[rows, first] == HIDDEN, axis=-1)
        sol_l = jnp.sum(pop.conn_valid[rows, first] & pop.conn_enabled[rows, first], axis=-1)
        loop_keys = split[jnp.minimum(run, r - 1), 1]
        new_states, metrics = tell(jax.vmap(jax.random.fold_in)(loop_keys, age), pop, fit, states)
        finished = active & (any_solved | (age + 1 >= max_generations))
        idx = jnp.where(active, run, r_cap)  # out-of-range rows are dropped
        out = dict(c["out"])
        out["n_species"] = out["n_species"].at[idx, jnp.minimum(age, max_generations - 1)].set(
            metrics["n_species"], mode="drop")
        fin = jnp.where(finished, run, r_cap)
        out["solved"] = out["solved"].at[fin].set(any_solved, mode="drop")
        out["generations"] = out["generations"].at[fin].set(age + 1, mode="drop")
        out["score"] = out["score"].at[fin].set(jnp.max(score, axis=1), mode="drop")
        out["right_side_generations"] = out["right_side_generations"].at[fin].set(rs, mode="drop")
        out["hidden"] = out["hidden"].at[fin].set(sol_h, mode="drop")
        out["links"] = out["links"].at[fin].set(sol_l, mode="drop")
        # Finished slots take the next runs in the queue.
        order = jnp.cumsum(finished) - 1
        new_run = jnp.where(finished, c["next"] + order, run)
        refill = jax.lax.cond(jnp.any(finished & (new_run < r)), lambda: jax.vmap(init_one)(new_run),
                              lambda: new_states)
        sel = lambda a, b: jnp.where(finished.reshape((w,) + (1,) * (a.ndim - 1)), a, b)
        return {"states": jax.tree.map(sel, refill, new_states), "run": new_run,
                "age": jnp.where(finished, 0, age + 1), "rs": jnp.where(finished, 0, rs),
                "next": c["next"] + jnp.sum(finished), "out": out}

    z = jnp.zeros((r_cap,), jnp.int32)
    carry = {"states": jax.vmap(init_one)(jnp.arange(w)), "run": jnp.arange(w), "age": jnp.zeros((w,), jnp.int32),
             "rs": jnp.zeros((w,), jnp.int32), "next": jnp.asarray(w, jnp.int32),
             "out": {"solved": jnp.zeros((r_cap,), bool), "generations": z, "hidden": z, "links": z,
                     "score": jnp.zeros((r_cap,), jnp.float32), "right_side_generations": z,
                     "n_species": jnp.full((r_cap, max_generations), -1, jnp.int32)}}
    out = jax.lax.while_loop(cond, body, carry)["out"]
    out["evaluations"] = out["generations"] * config.population_size
    out["right_side_evaluations"] = out["right_side_generations"] * config.population_size
    return out


def summary(result: dict) -> dict:
    """Host-side figures of :func:`run`'s result, in the form the benchmark prints (it builds the same
    dict from neat-python's runs). Means and medians are over the solved runs; ``right_side_*`` are
    the figures under Stanley's criterion."""
    res = {k: np.asarray(v) for k, v in result.items()}
    solved = res["solved"]
    mean = lambda a: float(a.mean()) if a.size else float("nan")  # noqa: E731
    median = lambda a: float(np.median(a)) if a.size else float("nan")  # noqa: E731
    rs = res["right_side_generations"] > 0
    return {"runs": int(solved.size), "solved": int(solved.sum()),
            "mean_evaluations": mean(res["evaluations"][solved]),
            "median_evaluations": median(res["evaluations"][solved]),
            "mean_generations": mean(res["generations"][solved]),
            "mean_hidden": mean(res["hidden"][solved]),
            "right_side_solved": int(rs.sum()),
            "right_side_mean_evaluations": mean(res["right_side_evaluations"][rs]),
            "right_side_mean_generations": mean(res["right_side_generations"][rs])}
