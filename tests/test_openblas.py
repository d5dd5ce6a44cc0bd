"""kx pins OpenBLAS's kernels on AVX-512 CPUs (kx._pin_openblas_kernels), whatever the environment forces."""

import os
import subprocess
import sys

import kx


def _coretype_after_import(**env):
    base = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "KX_OPENBLAS_CORETYPE")}
    out = subprocess.run([sys.executable, "-c", "import os, kx; print(os.environ.get('OPENBLAS_CORETYPE'))"],
                         env={**base, **env}, capture_output=True, text=True, check=True)
    return out.stdout.strip()


def test_an_avx512_cpu_gets_skylakex_kernels_over_the_environments_and_other_cpus_keep_theirs():
    pinned = kx.AVX512_KERNELS <= kx._cpu_flags()
    assert _coretype_after_import(OPENBLAS_CORETYPE="Haswell") == ("SkylakeX" if pinned else "Haswell")
    assert _coretype_after_import() == ("SkylakeX" if pinned else "None")


def test_kx_openblas_coretype_chooses_or_inherits():
    assert _coretype_after_import(OPENBLAS_CORETYPE="Haswell", KX_OPENBLAS_CORETYPE="inherit") == "Haswell"
    assert _coretype_after_import(KX_OPENBLAS_CORETYPE="inherit") == "None"
    assert _coretype_after_import(OPENBLAS_CORETYPE="Haswell", KX_OPENBLAS_CORETYPE="Zen") == "Zen"
