"""The paper image's every-entry sums (5v3, 6v4) as kx computes them (`kx.hyperneat.bev._entry_outputs`: the
weights read inside the chains, a path at a time) against the code before 2026-12-03 (every weight gathered
into a ``[K, E, lanes]`` array first, kept here): the same bits, and each one's cost alone on one core.

    python scripts/bev_every_entry.py 5v3 6v4

The substrates: the trained 4v3 HyperNEAT fixture of `kx.bench policies` (150 genomes); the states: 4500 random
starts of the task after 40 iterations of the heuristic; lane ``l`` reads genome ``l // 30``. docs/hyperneat.md
("What it costs") gives the figures.
"""

from kx import runtime

runtime.setup(1)

import argparse  # noqa: E402
import functools  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from kx.bench import policies as bench_policies  # noqa: E402
from kx.hyperneat import bev  # noqa: E402
from kx.sim import env  # noqa: E402
from kx.sim.ops import fenced  # noqa: E402
from kx.sim.policies import BASELINES  # noqa: E402
from kx.sim.types import KeepAwayConfig, KeepAwayParams  # noqa: E402


def gathered(w_flat, b_flat, index, rows, state, config, image, busy):
    """The code before 2026-12-03: every weight of the list gathered first, then the chain of products."""
    n = config.field_size**2
    cells, values = fenced(functools.partial(bev.sparse_image, config=config, image=image), state)
    values = jnp.where(busy[None], values, 0.0)

    def gather(w_flat, b_flat, index, rows, cells):
        base = (index[None] * n + rows) * n
        return w_flat[base[:, None] + cells[None]], b_flat[index[None] * n + rows]

    wv, total = fenced(gather, w_flat, b_flat, index, rows, cells)

    def products(wv, total, values):
        for e in range(values.shape[0]):
            total = total + values[e][None] * wv[:, e]
        return total

    return fenced(products, wv, total, values)


def main(tasks):
    trainer, population, _ = bench_policies.load_fixture("hyperneat")
    table = jax.block_until_ready(trainer.encoding.policy_params(population))
    w_flat, b_flat = table["w"].reshape(-1), table["b"].reshape(-1)
    params = KeepAwayParams()
    for task in tasks:
        config = KeepAwayConfig.from_task(task)
        heuristic = BASELINES["heuristic"](config)

        @jax.jit
        def play(state):
            def body(s, _):
                return env.transition(s, heuristic.apply(None, s, None), jnp.zeros_like(s.t), params, config), None
            return jax.lax.scan(body, state, None, length=40)[0]

        lanes = play(env.reset_batch(jax.random.key(7), 4500, params, config))
        index = jnp.arange(4500, dtype=jnp.int32) // 30
        kc = lanes.keeper_x + config.field_size * lanes.keeper_y
        busy = (lanes.holder >= 0) & ~lanes.done
        fns = {k: jax.jit(lambda i, r, s, b, f=f: f(w_flat, b_flat, i, r, s, config, "paper", b))
               for k, f in (("chained (kx)", bev._entry_outputs), ("gathered (before)", gathered))}
        outs = {k: np.asarray(f(index, kc, lanes, busy)) for k, f in fns.items()}
        a, b = outs.values()
        same = a.view(np.uint32) == b.view(np.uint32)
        print(f"{task}: clip needed {bev._needs_path_clip(config, 'paper')}; {same.sum()} of {same.size} sums "
              f"identical bit for bit")
        times = {}
        for _ in range(5):
            for k, f in fns.items():
                t0 = time.perf_counter()
                jax.block_until_ready(f(index, kc, lanes, busy))
                times.setdefault(k, []).append((time.perf_counter() - t0) / 4500 * 1e9)
        med = {k: float(np.median(v)) for k, v in times.items()}
        c, g = med.values()
        print(f"{task}: " + ", ".join(f"{k} {v:.0f} ns a lane" for k, v in med.items()) + f" (ratio {c / g:.2f})")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tasks", nargs="*", default=["5v3", "6v4"], help="tasks (default 5v3 6v4)")
    main(parser.parse_args().tasks)
