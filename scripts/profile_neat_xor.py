"""Where the time of a NEAT XOR generation goes: a profile of 25 populations (evaluation and ``tell``).

    python scripts/profile_neat_xor.py [--ops 30] [--width 25]

Runs 30 generations to warm up, traces 10 with ``jax.profiler``, and prints the XLA operations that
took the most thread time per generation (summed over threads), each with the JAX scope it came from.
"""

from __future__ import annotations

import argparse
import collections
import glob
import re
import tempfile

from kx import runtime


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ops", type=int, default=30, help="how many operations to list")
    p.add_argument("--width", type=int, default=25, help="populations evolving side by side")
    args = p.parse_args(argv)
    runtime.setup()
    import jax
    from jax._src.lib import _profile_data  # the profiler's reader of its own trace files

    from kx.neat import algorithm, presets, xor

    cfg, prm = presets.xor()
    w = args.width
    tell = jax.vmap(lambda k, pop, fit, st: algorithm.tell(k, pop, fit, st, prm, cfg))

    @jax.jit
    def generation(st, key):
        fit, _ = jax.vmap(lambda pop: xor.evaluate(pop, cfg))(st.population)
        return tell(jax.random.split(key, w), st.population, fit, st)[0]

    st = jax.vmap(lambda k: algorithm.init(k, prm, cfg))(jax.random.split(jax.random.key(0), w))
    for i in range(30):
        st = generation(st, jax.random.key(i))
    jax.block_until_ready(st)
    trace_dir = tempfile.mkdtemp(prefix="kx-trace-")
    n_gen = 10
    jax.profiler.start_trace(trace_dir)
    for i in range(n_gen):
        st = generation(st, jax.random.key(100 + i))
    jax.block_until_ready(st)
    jax.profiler.stop_trace()

    trace = _profile_data.ProfileData.from_file(glob.glob(trace_dir + "/**/*.xplane.pb", recursive=True)[0])
    per_op = collections.Counter()
    for plane in trace.planes:
        for line in plane.lines:
            if not line.name.startswith("tf_XLAEigen"):  # XLA's worker threads
                continue
            for ev in line.events:
                if not ev.name.startswith("ThunkExecutor"):
                    per_op[ev.name] += ev.duration_ns
    scope = {}
    for text in generation.lower(st, jax.random.key(0)).compile().as_text().splitlines():
        m = re.match(r'\s*(?:ROOT )?%([\w.\-]+) = .*op_name="([^"]*)"', text)
        if m and m.group(1) not in scope:
            scope[m.group(1)] = m.group(2)
    total = sum(per_op.values())
    print(f"{w} XOR populations, population {cfg.population_size}: {total / 1e6 / n_gen:.1f} ms of thread time "
          f"per generation")
    for name, ns in per_op.most_common(args.ops):
        print(f"{ns / 1e6 / n_gen:7.3f} ms  {name:30s} {scope.get(name, '')[:120]}")


if __name__ == "__main__":
    main()
