"""kx's native CPU kernels: XLA FFI custom calls built from C++ source with the machine's compiler.

``kx_bev_sums`` (``bev_sums.cc``): the sums of HyperNEAT's Bird's Eye View decision
(:func:`kx.hyperneat.bev.sparse_outputs`, the authors' image) one lane at a time, each lane reading only its
own image's entries. The compiled XLA code runs every lane of a batch in lockstep up to the batch's longest
list of path steps and reads each weight with a scalar gather inside a vectorised loop; the kernel gives the
same sums bit for bit (tests/test_native.py) at a fraction of the cost (docs/hyperneat.md, "A native
decision").

The library is built by ``python -m kx.hyperneat.native`` (which ``make`` runs at set-up), or on first use, into a
per-user cache as JAX's compilation cache is (``$KX_NATIVE_CACHE``, else
``$XDG_CACHE_HOME/kx/native``, else ``~/.cache/kx/native``), named by a hash of its source, the compiler and
its flags, jaxlib's version and the CPU's model and flags, so that a change of any of them builds it again.
A build holds a lock on the cache (processes starting together build it once), and goes to a temporary file
that is then renamed, so that no process loads a half-written library. It compiles with ``-march=native``
(the machine's fused multiply-add) and ``-ffp-contract=off`` (no other operation fused), with warnings on;
XLA's FFI headers are included as system headers, so that their warnings do not hide kx's. Where it cannot
be built (no compiler: ``CXX``, default ``g++``; a cache that cannot be written), where ``KX_NATIVE=0``, or on
another backend than the CPU, kx runs the compiled XLA code, which gives the same results more slowly; a
run's config chooses (``hyperneat.impl``: auto, xla or native), and its run directory records which ran
(``runtime.json``).
"""

from __future__ import annotations

import ctypes
import fcntl
import functools
import hashlib
import os
import pathlib
import platform
import shutil
import subprocess
import sys
import tempfile

import jax
import jax.numpy as jnp
import numpy as np

SOURCE = pathlib.Path(__file__).with_name("bev_sums.cc")
FLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-std=c++17", "-shared", "-fPIC", "-Wall", "-Wextra")
TARGET = "kx_bev_sums"


def cache_dir() -> pathlib.Path:
    """The per-user folder of built libraries: ``$KX_NATIVE_CACHE``, else ``$XDG_CACHE_HOME/kx/native``, else
    ``~/.cache/kx/native`` (beside JAX's compilation cache, ``~/.cache/kx/jax``: :mod:`kx.runtime`)."""
    env = os.environ
    if env.get("KX_NATIVE_CACHE"):
        return pathlib.Path(env["KX_NATIVE_CACHE"])
    base = pathlib.Path(env["XDG_CACHE_HOME"]) if env.get("XDG_CACHE_HOME") else pathlib.Path.home() / ".cache"
    return base / "kx" / "native"


def _cpu_fingerprint() -> str:
    """The CPU's model and feature flags (what ``-march=native`` compiles for)."""
    try:
        lines = pathlib.Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.processor() or platform.machine()
    keep = [ln for ln in lines if ln.startswith(("model name", "flags", "Features"))]
    return "\n".join(sorted(set(keep))) or platform.machine()


def library_path() -> pathlib.Path:
    """Where this source, compiler, jaxlib and CPU's library is (or will be) built."""
    import jaxlib

    cxx = os.environ.get("CXX", "g++")
    key = hashlib.sha256("\0".join([SOURCE.read_text(), cxx, *FLAGS, jaxlib.__version__, _cpu_fingerprint()])
                         .encode()).hexdigest()[:16]
    return cache_dir() / f"libkx_native-{key}.so"


def build() -> pathlib.Path:
    """Builds the library if it is not there yet and returns its path; raises RuntimeError saying why where
    it cannot be built (no compiler, the compiler's message, a cache folder that cannot be written)."""
    path = library_path()
    if path.is_file():
        return path
    cxx = os.environ.get("CXX", "g++")
    if shutil.which(cxx) is None:
        raise RuntimeError(f"no C++ compiler: {cxx!r} is not on PATH (set CXX to one)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = open(path.parent / ".lock", "a")  # noqa: SIM115  (held for the build)
    except OSError as e:
        raise RuntimeError(f"the cache folder {path.parent} cannot be written ({e.strerror}; set KX_NATIVE_CACHE to "
                           "another)") from None
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # another process's build of the same library: wait, then use it
        if path.is_file():
            return path
        fd, tmp = tempfile.mkstemp(suffix=".so", dir=path.parent)
        os.close(fd)
        try:
            cmd = [cxx, *FLAGS, "-isystem", jax.ffi.include_dir(), str(SOURCE), "-o", tmp]
            done = subprocess.run(cmd, capture_output=True, text=True)
            if done.returncode != 0:
                raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stderr.strip()}")
            if done.stderr.strip():  # a warning of kx's own source: shown, never hidden
                print(f"kx.hyperneat.native: the compiler warns:\n{done.stderr.strip()}", file=sys.stderr)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    return path


@functools.cache
def _library() -> tuple[ctypes.CDLL | None, str]:
    """The loaded library with its FFI target registered, or None and why not."""
    if os.environ.get("KX_NATIVE", "1") == "0":
        return None, "KX_NATIVE=0"
    try:
        lib = ctypes.cdll.LoadLibrary(str(build()))
    except (RuntimeError, OSError) as e:
        return None, str(e)
    jax.ffi.register_ffi_target(TARGET, jax.ffi.pycapsule(lib.KxBevSums), platform="cpu")
    return lib, ""


def unavailable() -> str:
    """Why the native kernels are not used in this process, or "" where they are."""
    if jax.default_backend() != "cpu":
        return f"the backend is {jax.default_backend()}, the kernels are the CPU's"
    return _library()[1]


def bev_sums(table: dict, index: jax.Array, rows: jax.Array, state, config, busy: jax.Array | None,
             fused: bool, round_offset: float) -> jax.Array:
    """``kx_bev_sums``: the authors' image's sums ``[R, *B]`` at output rows ``rows [R, *B]`` of each lane's
    genome ``index [*B]`` (:func:`kx.hyperneat.bev.sparse_outputs` with ``activation=None``); ``fused``:
    one rounding per multiply-add or two, as XLA's compiled chain does under the process's flags;
    ``round_offset``: the digital line's (``kx.hyperneat.bev.ROUND_OFFSET``). The image's values are
    :mod:`kx.sim.observe`'s ``BEV_AUTHORS_*``."""
    from kx.sim import observe

    why = unavailable()
    if why:
        raise RuntimeError(f"kx.hyperneat.native: not available ({why})")
    if busy is None:
        busy = jnp.ones(index.shape, bool)
    i32 = functools.partial(jnp.asarray, dtype=jnp.int32)
    call = jax.ffi.ffi_call(TARGET, jax.ShapeDtypeStruct(rows.shape, jnp.float32), vmap_method="sequential")
    return call(table["w"], table["b"], i32(index), i32(rows), i32(state.keeper_x), i32(state.keeper_y),
                i32(state.taker_x), i32(state.taker_y), i32(state.holder), jnp.asarray(busy, bool),
                width=np.int64(config.field_size), fused=bool(fused),
                holder_value=np.float32(observe.BEV_AUTHORS_HOLDER),
                teammate_value=np.float32(observe.BEV_AUTHORS_TEAMMATE),
                taker_value=np.float32(observe.BEV_AUTHORS_TAKER), round_offset=np.float32(round_offset))


def main() -> int:
    """``python -m kx.hyperneat.native``: builds the library (the set-up runs it); its path, or one line saying why not
    and exit status 1."""
    try:
        print(build())
        return 0
    except RuntimeError as e:
        reason = str(e).splitlines()[0] if "failed:" not in str(e) else "the compiler failed: " + " | ".join(
            ln for ln in str(e).splitlines()[1:] if "error" in ln)[:300]
        print(f"kx.hyperneat.native: not built ({reason}); "
              "kx runs its compiled XLA code instead (the same results, slower)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
