"""kx: keep-away soccer teams evolved with NEAT and HyperNEAT, in JAX.

Reproduces Didi & Nitschke, "Multi-Agent Behavior-Based Policy Transfer" (EvoApplications 2016).
"""

import os as _os

__version__ = "0.1.0"

#: the x86 extensions OpenBLAS's SkylakeX kernels need
AVX512_KERNELS = frozenset({"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"})


def _cpu_flags() -> set[str]:
    """The CPU's feature flags (/proc/cpuinfo's first ``flags`` line; empty where there is none)."""
    try:
        with open("/proc/cpuinfo") as f:
            return set(next(line for line in f if line.startswith("flags")).split())
    except (OSError, StopIteration):
        return set()


def _pin_openblas_kernels() -> None:
    """Pins the OpenBLAS kernels of JAX's CPU linear algebra, before they load, on CPUs with AVX-512.

    jaxlib's CPU eigendecomposition (CMA-ES's covariance update, evosax) calls LAPACK through scipy's
    OpenBLAS, whose kernels round float32 differently from one kernel set to another. On AVX-512 CPUs
    OpenBLAS's own choices (SkylakeX, Cooperlake, SapphireRapids) give the same CMA-ES runs, and kx's
    committed results were made with them; but an environment may force another set: a machine of this
    project (2026-12-05) exports ``OPENBLAS_CORETYPE=Haswell``, and there every CMA-ES run parted from its
    committed row at its first update. So kx sets ``OPENBLAS_CORETYPE=SkylakeX`` on every CPU with
    AVX-512, whatever the environment says. ``KX_OPENBLAS_CORETYPE`` chooses instead: a kernel set's name,
    or ``inherit`` to keep the environment's. A scipy loaded before kx keeps the kernels it loaded with."""
    want = _os.environ.get("KX_OPENBLAS_CORETYPE")
    if want is None:
        if not AVX512_KERNELS <= _cpu_flags():
            return
        want = "SkylakeX"
    if want != "inherit":
        _os.environ["OPENBLAS_CORETYPE"] = want


_pin_openblas_kernels()
