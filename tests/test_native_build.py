"""Where and how kx.hyperneat.native's library is built, whether or not it can run here: a per-user cache
(KX_NATIVE_CACHE,
XDG_CACHE_HOME, ~/.cache), one build for processes that start together, warnings shown (XLA's headers as system
headers, no blanket suppression), one clear line where it cannot be built; and the run config's choice of
implementation (``hyperneat.impl``)."""

import multiprocessing
import os
import pathlib
import stat
import subprocess
import sys

import pytest

from kx.evolve import config as cfg_lib
from kx.hyperneat import native

REPO = pathlib.Path(__file__).resolve().parents[1]


def _fake_compiler(tmp_path, stderr="", status=0) -> pathlib.Path:
    """A stand-in for g++ that logs its arguments, takes a second, and writes its -o file."""
    cxx = tmp_path / "fake-cxx"
    cxx.write_text(f"""#!/bin/sh
echo "$@" >> {tmp_path}/calls
sleep 1
out=""
while [ $# -gt 0 ]; do [ "$1" = "-o" ] && out="$2"; shift; done
printf '{stderr}' >&2
[ {status} -eq 0 ] && echo library > "$out"
exit {status}
""")
    cxx.chmod(cxx.stat().st_mode | stat.S_IEXEC)
    return cxx


def test_the_cache_is_per_user_and_can_be_moved(monkeypatch, tmp_path):
    monkeypatch.delenv("KX_NATIVE_CACHE", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    assert native.cache_dir() == pathlib.Path.home() / ".cache" / "kx" / "native"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert native.cache_dir() == tmp_path / "xdg" / "kx" / "native"
    monkeypatch.setenv("KX_NATIVE_CACHE", str(tmp_path / "kx"))
    assert native.cache_dir() == tmp_path / "kx"
    assert native.library_path().parent == tmp_path / "kx"
    assert not (REPO / "kx" / "native" / "_build").exists()  # nothing is built into the package


def _build_in(env):
    os.environ.update(env)
    return str(native.build())


def test_processes_that_start_together_build_once_with_warnings_on(monkeypatch, tmp_path):
    cxx = _fake_compiler(tmp_path)
    env = {"KX_NATIVE_CACHE": str(tmp_path / "cache"), "CXX": str(cxx)}
    with multiprocessing.get_context("spawn").Pool(3) as pool:
        paths = pool.map(_build_in, [env] * 3)
    assert len(set(paths)) == 1 and pathlib.Path(paths[0]).read_text() == "library\n"
    calls = (tmp_path / "calls").read_text().splitlines()
    assert len(calls) == 1, calls  # the others waited on the lock and found the library built
    args = calls[0].split()
    assert "-isystem" in args and "-I" not in args and not [a for a in args if a.startswith("-Wno-")]
    assert {"-Wall", "-Wextra", "-march=native", "-ffp-contract=off"} <= set(args)
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == [".lock", pathlib.Path(paths[0]).name]


def test_a_compiler_warning_is_shown(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("KX_NATIVE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CXX", str(_fake_compiler(tmp_path, stderr="bev_sums.cc:1: warning: unused variable")))
    native.build()
    err = capsys.readouterr().err
    assert "kx.hyperneat.native: the compiler warns:\nbev_sums.cc:1: warning: unused variable" in err


def test_a_failed_build_says_why_and_leaves_nothing(monkeypatch, tmp_path):
    monkeypatch.setenv("KX_NATIVE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CXX", "no-such-compiler")
    with pytest.raises(RuntimeError, match="no C.. compiler: 'no-such-compiler' is not on PATH"):
        native.build()
    monkeypatch.setenv("CXX", str(_fake_compiler(tmp_path, stderr="bev_sums.cc:3: error: oops", status=1)))
    with pytest.raises(RuntimeError, match="failed:\nbev_sums.cc:3: error: oops"):
        native.build()
    assert [p.name for p in (tmp_path / "cache").iterdir()] == [".lock"]  # nothing half-written


@pytest.mark.parametrize("case", ["no compiler", "cache not writable", "compiler fails"])
def test_python_m_kx_native_fails_with_one_clear_line(case, tmp_path):
    env = {**os.environ, "KX_NATIVE_CACHE": str(tmp_path / "cache"), "JAX_PLATFORMS": "cpu"}
    if case == "no compiler":
        env["CXX"] = "no-such-compiler"
        want = "kx.hyperneat.native: not built (no C++ compiler: 'no-such-compiler' is not on PATH"
    elif case == "cache not writable":  # a folder under a file: no user, root included, can create it
        (tmp_path / "file").write_text("")
        env["KX_NATIVE_CACHE"] = str(tmp_path / "file" / "cache")
        want = "kx.hyperneat.native: not built (the cache folder "
    else:
        env["CXX"] = str(_fake_compiler(tmp_path, stderr="x.cc:3: error: oops\\nnote: more", status=1))
        want = "kx.hyperneat.native: not built (the compiler failed: x.cc:3: error: oops)"
    done = subprocess.run([sys.executable, "-m", "kx.hyperneat.native"], env=env, capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert done.returncode == 1 and done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(want), done.stderr
    assert lines[0].endswith("kx runs its compiled XLA code instead (the same results, slower)")


def test_a_runs_config_chooses_the_implementation(monkeypatch):
    path = cfg_lib.CONFIG_DIR / "hyperneat_3v2.py"
    with pytest.raises(cfg_lib.ConfigError, match=r"hyperneat.impl: allowed one of \('auto', 'xla', 'native'\), "
                                                   r"got 'fast'"):
        cfg_lib.validate(cfg_lib.load(path, ["hyperneat.impl=fast"]))
    enc = cfg_lib.validate(cfg_lib.load(path, ["hyperneat.impl=xla"])).encoding
    assert enc.implementation() == {"decision_sums": "xla", "chosen": "xla"}
    # the paper image has no native kernel: auto says why it runs the XLA code, native is refused before any run
    enc = cfg_lib.validate(cfg_lib.load(path, ["hyperneat.image=paper"])).encoding
    assert enc.implementation()["decision_sums"] == "xla"
    assert enc.implementation()["why_not_native"] == "image 'paper': the kernel computes the authors' image"
    with pytest.raises(cfg_lib.ConfigError, match=r"hyperneat.impl: 'native' cannot run here \(image 'paper'"):
        cfg_lib.validate(cfg_lib.load(path, ["hyperneat.image=paper", "hyperneat.impl=native"]))
    monkeypatch.setenv("KX_NATIVE", "0")
    native._library.cache_clear()
    try:
        with pytest.raises(cfg_lib.ConfigError, match=r"'native' cannot run here \(KX_NATIVE=0\)"):
            cfg_lib.validate(cfg_lib.load(path, ["hyperneat.impl=native"]))
    finally:
        monkeypatch.delenv("KX_NATIVE")
        native._library.cache_clear()
    # the implementations compute the same bits: a run resumes under another, and an older run's config.json
    # (without the field) reads as auto
    saved = cfg_lib.load(path, ["hyperneat.impl=native"]).to_dict()
    assert cfg_lib.identity_mismatch(saved, cfg_lib.load(path, ["hyperneat.impl=xla"])) is None
    del saved["hyperneat"]["impl"]
    assert cfg_lib.with_later_fields(saved)["hyperneat"]["impl"] == "auto"
