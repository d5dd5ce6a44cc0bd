"""Process set-up for kx's command-line entry points (call before JAX is first used).

* One XLA host device per CPU core, so that :func:`kx.sim.evaluate.evaluate` can split episode lanes
  over the cores (XLA runs one device's loop on one thread at a time). Has no effect on a GPU
  platform's devices, and none once JAX has initialised its backends.
* JAX's persistent compilation cache, so that the evaluator's batch widths compile once per machine
  rather than once per process (``KX_CACHE_DIR``, default ``~/.cache/kx/jax``; ``KX_CACHE_DIR=off``
  disables it; ``KX_CACHE_MIN_COMPILE_SECS``, default 0.5, the shortest compilation it keeps).
"""

from __future__ import annotations

import os
import pathlib


def setup(host_devices: int | None = None) -> None:
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        n = host_devices or os.cpu_count() or 1
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={n}".strip()
    import jax

    cache = os.environ.get("KX_CACHE_DIR", str(pathlib.Path.home() / ".cache" / "kx" / "jax"))
    if cache != "off":
        jax.config.update("jax_compilation_cache_dir", cache)
        # programs that compile faster than this are not cached (KX_CACHE_MIN_COMPILE_SECS; the test
        # suite caches every program, so that its workers and subprocesses share them)
        jax.config.update("jax_persistent_cache_min_compile_time_secs",
                          float(os.environ.get("KX_CACHE_MIN_COMPILE_SECS", "0.5")))
