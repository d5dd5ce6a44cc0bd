"""Bit-identity of the Bird's Eye View policy across a change of its code: save, then check.

``python scripts/bev_identity.py save DIR``   (on the code before the change)
``python scripts/bev_identity.py check DIR``  (on the code after it)

For each task (3v2, 4v3, 5v3, 6v4) and image (``authors``, ``paper``), on random states (fresh resets,
states stepped 1 and 6 iterations with random actions, adversarial states whose agents crowd a 3 x 3 or
5 x 5 square, a quarter with nobody holding the ball) and on real states (the episodes of the trained
HyperNEAT population of ``kx/bench/data/policies/hyperneat_4v3.npz`` playing that task, sampled every 7
iterations while live), with two tables (that population's substrates, built by
``encoding.policy_params``, and 8 random substrates), ``save`` writes and ``check`` compares:

* the sums at the keepers' cells, :func:`kx.hyperneat.bev.sparse_outputs` before any activation, and
  the bipolar sigmoid of them (``[K, B]`` float32, compared bit for bit; an array whose values are equal
  but where some zero has the other sign, -0.0 for 0.0, is reported apart);
* the decisions of :func:`kx.hyperneat.bev.bev_policy` with the substrate activations
  ``bipolar_sigmoid`` (compared on the sums), ``gaussian`` (after the activation) and ``identity``;
* the ``literal`` decision on 256 states of each set;
* whole episodes: the population (its real table) on 30 start states of the task through
  :func:`kx.sim.evaluate.evaluate` (the run loop's evaluator, its rungs compiled as in training), every
  field of the episodes' statistics: equal only if every decision along every episode is.

The states and the random tables are saved with the figures (the random tables from their key, the real
table by its content's hash), so that ``check`` feeds the new code exactly the inputs the old code saw.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pathlib
import sys
import zlib

from kx import runtime

TASKS = ("3v2", "4v3", "5v3", "6v4")
IMAGES = ("authors", "paper")
ACTS = ("bipolar_sigmoid", "gaussian", "identity")
FIXTURE = pathlib.Path(__file__).resolve().parent.parent / "kx" / "bench" / "data" / "policies" / "hyperneat_4v3.npz"


def real_table(task: str):
    """The fixture population's substrates through the encoding (as the run loop builds them), and the
    encoding's image."""
    import jax
    import numpy as np

    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib
    from kx.neat.types import Genome

    cfg = cfg_lib.load("configs/hyperneat_4v3.py", ["gif=false", f"task={task}"])
    trainer = run_lib.Trainer(cfg)
    data = np.load(FIXTURE)
    population = Genome(**{f: data[f] for f in Genome.__dataclass_fields__})
    # on one device, as the code before made it (the run loop's table comes with its rows split over the devices)
    return jax.device_put(trainer.encoding.policy_params(population), jax.devices()[0])


def logical(table):
    """The table as ``{"w": [G, N, N], "b": [G, N]}`` (whatever layout the code keeps it in)."""
    import numpy as np

    from kx.hyperneat import bev

    f = getattr(bev, "logical_table", None)
    t = f(table) if f is not None else table
    return {k: np.asarray(v) for k, v in t.items()}


def as_code_table(table):
    """A logical table in the layout the policy reads (the identity unless the code has a layout)."""
    from kx.hyperneat import bev

    f = getattr(bev, "layout_table", None)
    return f(table) if f is not None else table


def digest(table) -> str:
    t = logical(table)
    return hashlib.sha256(t["w"].tobytes() + t["b"].tobytes()).hexdigest()


def random_states(key, config, n):
    """:func:`kx.sim.samples.varied_states`, the states tests/test_bev.py uses too."""
    from kx.sim import samples

    return samples.varied_states(key, config, n)


def real_states(table, config, image, n_lanes=1024, iterations=350, every=7, keep=4096):
    """States of the population's episodes (lane ``l`` plays genome ``l % G`` from reset ``l``), every
    ``every`` iterations while live, at most ``keep`` of them."""
    import functools

    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.hyperneat import bev
    from kx.sim import env
    from kx.sim.policies import Shared
    from kx.sim.types import KeepAwayParams

    params = KeepAwayParams()
    starts = env.reset_batch(jax.random.key(11), n_lanes, params, config)
    g = table["b"].shape[0]
    index = jnp.arange(n_lanes, dtype=jnp.int32) % g
    words = env.noise_words(jax.random.key(12), jnp.arange(n_lanes))
    policy = bev.bev_policy(config, image)

    @functools.partial(jax.jit, static_argnums=())
    def play(table, state):
        def body(s, _):
            a = policy.apply(Shared(table, index), s, None)
            s2 = env.transition(s, a, env.kick_noise(words, s.t, env.noise_limit(params.kick_noise_deg)), params,
                                config)
            return s2, s
        return jax.lax.scan(body, state, None, length=iterations)[1]

    traj = jax.device_get(play(table, starts))  # leaves [I, .., L]
    picks = [(i, j) for i in range(0, iterations, every) for j in range(n_lanes) if not traj.done[i, j]]
    rng = np.random.default_rng(0)
    if len(picks) > keep:
        picks = [picks[j] for j in np.sort(rng.choice(len(picks), keep, replace=False))]
    it = np.array([p[0] for p in picks])
    ln = np.array([p[1] for p in picks])
    return jax.tree.map(lambda a: jnp.asarray(a[it, ..., ln].T if a.ndim > 2 else a[it, ln]), traj)


def episodes(table, config, image):
    """Every field of the statistics of the table's genomes on 30 start states of the task (``[G, 30]``)."""
    import jax
    import numpy as np

    from kx.hyperneat import bev
    from kx.sim import env
    from kx.sim import evaluate as ev
    from kx.sim.types import KeepAwayParams

    params = KeepAwayParams()
    starts = env.reset_batch(jax.random.key(21), 30, params, config)
    stats = ev.evaluate(bev.bev_policy(config, image), table, starts, params, config, key=jax.random.key(22))
    return {f"episodes/{f}": np.asarray(getattr(stats, f)) for f in stats.__dataclass_fields__}


def figures(table, index, state, config, image):
    import jax
    import numpy as np

    from kx.hyperneat import bev
    from kx.sim.policies import Shared

    @jax.jit
    def cells(table, index, state):
        kc = state.keeper_x + config.field_size * state.keeper_y
        out = {"sums": bev.sparse_outputs(table, index, kc, state, config, image, None),
               "acts": bev.sparse_outputs(table, index, kc, state, config, image, "bipolar_sigmoid")}
        for a in ACTS:
            out[f"decision_{a}"] = bev.bev_policy(config, image, "cells", a).apply(Shared(table, index), state, None)
        return out

    @jax.jit
    def literal(table, index, state):
        return bev.bev_policy(config, image, "literal").apply(Shared(table, index), state, None)

    out = {k: np.asarray(v) for k, v in cells(table, index, state).items()}
    sub = jax.tree.map(lambda a: a[..., :256], state)
    out["decision_literal"] = np.asarray(literal(table, index[:256], sub))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mode", choices=("save", "check"), help="save: before the change; check: after it")
    parser.add_argument("dir", help="the folder of the saved arrays")
    args = parser.parse_args()
    mode, root = args.mode, pathlib.Path(args.dir)
    runtime.setup()
    import jax
    import jax.numpy as jnp
    import numpy as np

    from kx.sim.types import KeepAwayConfig

    root.mkdir(parents=True, exist_ok=True)
    bad = total = zeros = 0
    for task in TASKS:
        config = KeepAwayConfig.from_task(task)
        real = real_table(task)
        kw, km, kb = jax.random.split(jax.random.key(99), 3)
        n = config.field_size**2
        w = jax.random.uniform(kw, (8, n, n), jnp.float32, -5.0, 5.0)
        rand = {"w": jnp.where(jax.random.bernoulli(km, 0.5, (8, n, n)), w, 0.0),
                "b": jax.random.uniform(kb, (8, n), jnp.float32, -5.0, 5.0)}
        rand_code = as_code_table(rand)
        for image in IMAGES:
            path = root / f"{task}_{image}.npz"
            if mode == "save":
                rs = random_states(jax.random.key(zlib.crc32(f"{task}{image}".encode())), config, 2048)
                ss = real_states(real, config, image)
                states = {"random": rs, "real": ss}
            else:
                old = np.load(path, allow_pickle=False)
                meta = json.loads(str(old["meta"]))
                if meta["real_digest"] != digest(real):
                    print(f"{task} {image}: the real table differs from the saved one's", flush=True)
                    bad += 1
                from kx.sim.types import State
                # a counter the state gained after the save (decisions) starts at 0: the policy never reads it
                states = {s: State(**{f: jnp.asarray(old[f"{s}/state/{f}"]) if f"{s}/state/{f}" in old
                                      else jnp.zeros_like(jnp.asarray(old[f"{s}/state/holder"]))
                                      for f in State.__dataclass_fields__})
                          for s in ("random", "real")}
            record = episodes(real, config, image)
            for sname, st in states.items():
                b = st.holder.shape[-1]
                rng = np.random.default_rng(b)
                for tname, table, g in (("real", real, real["b"].shape[0]), ("random", rand_code, 8)):
                    index = jnp.asarray(rng.integers(0, g, b), jnp.int32)
                    figs = figures(table, index, st, config, image)
                    for k, v in figs.items():
                        record[f"{sname}/{tname}/{k}"] = v
                if mode == "save":
                    for f in st.__dataclass_fields__:
                        record[f"{sname}/state/{f}"] = np.asarray(getattr(st, f))
            if mode == "save":
                meta = {"real_digest": digest(real), "lanes": {s: int(v.holder.shape[-1]) for s, v in states.items()}}
                np.savez_compressed(path, meta=np.asarray(json.dumps(meta)), **record)
                print(f"saved {path}: {meta['lanes']}", flush=True)
            else:
                for k, v in record.items():
                    total += 1
                    want = old[k]
                    if v.shape != want.shape or v.dtype != want.dtype:
                        bad += 1
                        print(f"{task} {image} {k}: DIFFERS in shape or type", flush=True)
                    elif not np.array_equal(v, want):
                        bad += 1
                        print(f"{task} {image} {k}: DIFFERS ({np.sum(v != want)} of {want.size})", flush=True)
                    elif v.dtype == np.float32 and not np.array_equal(v.view(np.uint32), want.view(np.uint32)):
                        zeros += 1  # equal values; only the sign of some zeros differs
                        n_signs = np.sum(v.view(np.uint32) != want.view(np.uint32))
                        print(f"{task} {image} {k}: equal, the sign of {n_signs} zeros differs", flush=True)
                print(f"checked {path}: {len(record)} arrays", flush=True)
    if mode == "check":
        print(f"bev_identity: {total - bad - zeros} of {total} arrays bit for bit identical, {zeros} equal but for the "
              f"sign of zeros, {bad} different")
        sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
