"""``import kx`` leaves the environment alone; kx's command-line processes pin OpenBLAS's kernels on AVX-512 CPUs
(kx.runtime.pin_openblas_kernels, called by kx.runtime.setup), say so when they override the environment's
choice, and leave it to the user who asks (KX_OPENBLAS_CORETYPE)."""

import os
import subprocess
import sys

from kx import runtime

PINNED = runtime.AVX512_KERNELS <= runtime.cpu_flags()


def _coretype_after(code: str, **env) -> tuple[str, str]:
    base = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "KX_OPENBLAS_CORETYPE")}
    out = subprocess.run([sys.executable, "-c", f"import os; {code}; print(os.environ.get('OPENBLAS_CORETYPE'))"],
                         env={**base, **env}, capture_output=True, text=True, check=True)
    return out.stdout.strip(), out.stderr.strip()


SETUP = "from kx import runtime; runtime.pin_openblas_kernels()"


def test_importing_kx_changes_nothing_in_the_environment():
    imports = "import kx, kx.evolve.encodings.ppo.algorithm, kx.evolve.run"
    assert _coretype_after(imports, OPENBLAS_CORETYPE="Haswell") == ("Haswell", "")
    assert _coretype_after(imports) == ("None", "")


def test_the_process_set_up_pins_skylakex_kernels_on_avx512_cpus_and_says_when_it_overrides():
    got, err = _coretype_after(SETUP, OPENBLAS_CORETYPE="Haswell")
    assert got == ("SkylakeX" if PINNED else "Haswell")
    if PINNED:
        assert err.count("\n") == 0 and "OPENBLAS_CORETYPE=Haswell overridden by SkylakeX" in err
    else:
        assert err == ""
    assert _coretype_after(SETUP) == ("SkylakeX" if PINNED else "None", "")  # nothing overridden: nothing said
    if PINNED:  # scipy loaded first: the pin no longer reaches its kernels, and the process is told
        _, late = _coretype_after("import scipy.linalg; " + SETUP, OPENBLAS_CORETYPE="Haswell")
        assert "had already loaded" in late


def test_kx_openblas_coretype_chooses_or_inherits():
    assert _coretype_after(SETUP, OPENBLAS_CORETYPE="Haswell", KX_OPENBLAS_CORETYPE="inherit") == ("Haswell", "")
    assert _coretype_after(SETUP, KX_OPENBLAS_CORETYPE="inherit") == ("None", "")
    got, err = _coretype_after(SETUP, OPENBLAS_CORETYPE="Haswell", KX_OPENBLAS_CORETYPE="Zen")
    assert got == "Zen" and "overridden by Zen" in err
