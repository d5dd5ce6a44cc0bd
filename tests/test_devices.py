"""Lanes split over two host devices give the same results as one device (a fresh process, since the
device count is fixed when JAX starts)."""

import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent("""
    import jax, numpy as np
    assert jax.local_device_count() == 2
    from kx.sim import env, policies, evaluate as ev
    from kx.sim.types import KeepAwayConfig, KeepAwayParams
    cfg, params = KeepAwayConfig.from_task("4v3"), KeepAwayParams(max_iterations=300)
    starts = env.reset_batch(jax.random.key(0), 45, params, cfg)   # 45 lanes: padded to 46 on 2 devices
    pol = policies.heuristic(cfg)
    one = ev.evaluate(pol, None, starts, params, cfg, devices=1)
    two = ev.evaluate(pol, None, starts, params, cfg, devices=2)
    for f in ("fitness", "iterations", "reason", "passes", "behaviour"):
        np.testing.assert_array_equal(np.asarray(getattr(one, f)), np.asarray(getattr(two, f)), err_msg=f)
    print("ok", float(one.fitness.mean()))
""")


def test_two_devices_equal_one(tmp_path):
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.startswith("ok")


@pytest.mark.slow
def test_bench_sim_last_line(tmp_path):
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, PYTHONPATH=root)
    out = subprocess.run([sys.executable, "-m", "kx.bench", "sim", "--episodes", "300", "--repeats", "1",
                          "--reference-seconds", "0.5"], env=env, capture_output=True, text=True, timeout=1200)
    assert out.returncode == 0, out.stderr[-3000:]
    last = out.stdout.strip().splitlines()[-1]
    name, rest = last.split(": ", 1)
    value, unit, _, ratio, _, baseline = rest.replace("(", "").replace(")", "").split()
    assert name == "sim" and unit == "live-steps/s" and baseline == "reference"
    assert float(value) > 0 and float(ratio) > 1
