"""Process set-up for kx's command-line entry points (call before JAX is first used).

* OpenBLAS's kernels pinned on CPUs with AVX-512 (:func:`pin_openblas_kernels`), before scipy loads them.
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
import time
import warnings

#: the x86 extensions OpenBLAS's SkylakeX kernels need
AVX512_KERNELS = frozenset({"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"})


def cpu_flags() -> set[str]:
    """The CPU's feature flags (/proc/cpuinfo's first ``flags`` line; empty where there is none)."""
    try:
        with open("/proc/cpuinfo") as f:
            return set(next(line for line in f if line.startswith("flags")).split())
    except (OSError, StopIteration):
        return set()


def platform_label() -> str:
    """The platform a run was made on, as results files record it (table3's ``platform`` column): JAX's version,
    the default backend and, on a CPU, its architecture and widest vector instruction set, on an accelerator its
    device kind: ``jax 0.10.2 cpu x86_64 avx512``, ``jax 0.10.2 gpu NVIDIA H100 80GB HBM3``.

    What it names is what a run's floating point rests on beyond kx's code and config: XLA compiles for the
    host's instruction set, and OpenBLAS picks its kernels by it (:func:`pin_openblas_kernels`). Seen here,
    AVX-512 CPUs (Skylake-X, Cooper Lake, Sapphire Rapids) give the same runs, and an AVX2 CPU (AMD EPYC, Zen 3)
    gives the same heuristic episodes (``kx.bench platform``) but other PPO runs, its networks' products rounded
    otherwise. Equal labels are expected to give the same rows; a row whose label differs from the machine
    extending its folder is not expected to reproduce there (docs/experiments.md, "Extendable anywhere")."""
    import platform

    import jax

    backend = jax.default_backend()
    if backend == "cpu":
        flags = cpu_flags()
        isa = next((name for name, need in (("avx512", AVX512_KERNELS), ("avx2", {"avx2", "fma"}), ("avx", {"avx"}))
                    if need <= flags), "")
        where = " ".join(p for p in (platform.machine() or "unknown", isa) if p)
    else:
        where = jax.devices()[0].device_kind
    return f"jax {jax.__version__} {backend} {where}"


def pin_openblas_kernels(announce: bool = True) -> str | None:
    """Pins the OpenBLAS kernels of JAX's CPU linear algebra on CPUs with AVX-512, before they load; returns
    the kernel set pinned (None: the environment's kept).

    jaxlib's CPU eigendecomposition (CMA-ES's covariance update, evosax) calls LAPACK through scipy's
    OpenBLAS, whose kernels round float32 differently from one kernel set to another. On AVX-512 CPUs
    OpenBLAS's own choices (SkylakeX, Cooperlake, SapphireRapids) give the same CMA-ES runs, and kx's
    committed results were made with them; but an environment may force another set: a machine of this
    project (2026-12-05) exports ``OPENBLAS_CORETYPE=Haswell``, and there every CMA-ES run parted from its
    committed row at its first update. So kx's command-line entry points (:func:`setup`) set
    ``OPENBLAS_CORETYPE=SkylakeX`` on every CPU with AVX-512, and say so in one line on stderr (``announce``)
    when that overrides a value the environment set. ``KX_OPENBLAS_CORETYPE`` chooses instead: a kernel set's
    name, or ``inherit`` to keep the environment's. ``import kx`` changes nothing; a program of your own calls
    this before it imports scipy (once scipy has loaded its OpenBLAS, the variable no longer matters, and
    this says so)."""
    import sys

    want = os.environ.get("KX_OPENBLAS_CORETYPE")
    if want is None:
        if not AVX512_KERNELS <= cpu_flags():
            return None
        want = "SkylakeX"
    if want == "inherit":
        return None
    had = os.environ.get("OPENBLAS_CORETYPE")
    os.environ["OPENBLAS_CORETYPE"] = want
    if announce and had is not None and had != want:
        print(f"kx: OPENBLAS_CORETYPE={had} overridden by {want}, the kernels kx's results were made with "
              "(KX_OPENBLAS_CORETYPE=inherit keeps yours)", file=sys.stderr)
    if announce and any(m == "scipy.linalg" or m.startswith("scipy.linalg.") for m in sys.modules) and had != want:
        print("kx: scipy's OpenBLAS had already loaded: OPENBLAS_CORETYPE no longer changes its kernels",
              file=sys.stderr)
    return want


def setup(host_devices: int | None = None) -> None:
    pin_openblas_kernels()
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


# ------------------------------------------------------------------------------------------ memory maps
#
# Every program XLA CPU compiles holds memory maps of the process: each of its kernels is loaded as an
# object of its own, a few maps each (measured on jaxlib 0.10.2, 2 cores: about 300 maps for one evaluator
# rung of the keep-away step, 20-30 for a small program). Linux refuses a process more than
# vm.max_map_count maps (65,530 by default), and LLVM then fails to load the next program ("LLVM
# compilation error: Cannot allocate memory") and the process dies. A process that trains several methods
# or tasks compiles each one's rungs for each batch width: `python -m kx.bench learning` reached the limit
# in CMA-ES after NEAT and HyperNEAT. So a long process checks its maps (check_maps) once a generation: it
# reports them from MAPS_REPORT of the limit on, and from MAPS_RELEASE on it releases its compiled
# programs (jax.clear_caches), which then compile again, or load from the compilation cache, as needed.

MAPS_REPORT = 0.5  #: share of vm.max_map_count from which a process reports its memory maps
MAPS_RELEASE = 0.75  #: share from which it releases its compiled programs

#: how often, at most, :func:`guard_maps` reads the process's maps (reading 60,000 of them takes milliseconds)
MAPS_GUARD_SECONDS = 10.0

_reported = False
_guarded_at = float("-inf")


def memory_maps() -> tuple[int, int] | None:
    """``(maps, limit)``: the process's memory maps and the kernel's limit (vm.max_map_count); ``None``
    where the system does not tell (not Linux)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            count = sum(1 for _ in f)
        with open("/proc/sys/vm/max_map_count") as f:
            limit = int(f.read())
    except (OSError, ValueError):
        return None
    return count, limit


def release_compiled() -> None:
    """Drops every compiled program of the process (and so their memory maps): what runs next compiles
    again, or loads from the persistent compilation cache. Results do not change."""
    import gc

    import jax

    jax.clear_caches()
    gc.collect()


def check_maps() -> str | None:
    """What to tell the user about the process's memory maps, or ``None`` while they are well below the
    limit: from :data:`MAPS_REPORT` of it, once, how many and what to do; from :data:`MAPS_RELEASE`, it
    releases the compiled programs (:func:`release_compiled`) and says so."""
    global _reported
    got = memory_maps()
    if got is None:
        return None
    count, limit = got
    advice = ("each compiled XLA CPU program holds memory maps (about 300 per evaluator batch width); raise the "
              "limit (sysctl -w vm.max_map_count=262144, as root) or run fewer methods or tasks per process")
    if count >= MAPS_RELEASE * limit:
        release_compiled()
        after = memory_maps()
        _reported = False
        return (f"memory maps: {count} of the limit {limit} (vm.max_map_count); released the process's compiled "
                f"programs ({after[0] if after else '?'} maps now; they compile again or load from the compilation "
                f"cache as needed). To avoid it: {advice}")
    if count >= MAPS_REPORT * limit:
        if _reported:
            return None
        _reported = True
        return (f"memory maps: {count} of the limit {limit} (vm.max_map_count, {count / limit:.0%}); at "
                f"{MAPS_RELEASE:.0%} kx releases its compiled programs rather than let the next compilation fail. "
                f"{advice[0].upper()}{advice[1:]}")
    _reported = False
    return None


def guard_maps() -> None:
    """The guard of a process that evaluates outside the run loop (a script or a notebook calling
    :func:`kx.sim.evaluate.evaluate` for many tasks or policies): at most every :data:`MAPS_GUARD_SECONDS`,
    once the maps reach :data:`MAPS_RELEASE` of the limit, :func:`check_maps` releases the compiled programs
    and its message comes as a ``RuntimeWarning``, rather than the next compilation failing in LLVM. The run
    loop's own check (once a generation, in its log) reports from :data:`MAPS_REPORT` on, before this
    acts."""
    global _guarded_at
    now = time.monotonic()
    if now - _guarded_at < MAPS_GUARD_SECONDS:
        return
    _guarded_at = now
    got = memory_maps()
    if got is None or got[0] < MAPS_RELEASE * got[1]:
        return
    msg = check_maps()
    if msg:
        warnings.warn(msg, RuntimeWarning, stacklevel=3)
