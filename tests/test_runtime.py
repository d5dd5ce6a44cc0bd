"""The process's memory maps (kx.runtime): each compiled XLA CPU program holds some, and the kernel's limit
(vm.max_map_count) once killed a process that trained every method. One process trains each method and
stays well below the limit; the guard reports near the limit and releases compiled programs before it."""

import json
import pathlib
import subprocess
import sys

import pytest

from kx import runtime

REPO = pathlib.Path(__file__).resolve().parents[1]

# each method once, small, in one process: the maps after each run, and after releasing the programs
SCRIPT = """
import json, sys
from kx import runtime
runtime.setup()
from kx.evolve import config as cfg_lib
from kx.evolve import run as run_lib
maps = {"start": runtime.memory_maps()[0]}
sizes = {"neat": 12, "hyperneat": 12, "cma_es": 6}
for method, size in sizes.items():
    cfg = cfg_lib.load(f"configs/{method}_3v2.py", [f"population_size={size}", "trials=3", "validation_trials=6",
                       "generations=3", "gif=false", "sim.max_iterations=120", "objective=hybrid"])
    run_lib.evolve_in_memory(run_lib.Trainer(cfg))
    maps[method] = runtime.memory_maps()[0]
runtime.release_compiled()
maps["released"] = runtime.memory_maps()[0]
maps["limit"] = runtime.memory_maps()[1]
print(json.dumps(maps))
"""


@pytest.mark.slow  # ~30 s: a run of every method in one process (a guard against a leak of compiled programs)
@pytest.mark.skipif(runtime.memory_maps() is None, reason="no /proc/self/maps on this system")
def test_one_process_trains_every_method_well_below_the_memory_map_limit():
    out = subprocess.run([sys.executable, "-c", SCRIPT], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    maps = json.loads(out.stdout.strip().splitlines()[-1])
    assert maps["start"] < maps["neat"] < maps["hyperneat"] < maps["cma_es"]  # compiling holds maps ...
    assert maps["cma_es"] < maps["limit"] / 2, maps
    assert maps["released"] < maps["cma_es"] / 2, maps  # ... and releasing the programs gives them back


def test_the_guard_reports_near_the_limit_and_releases_before_it(monkeypatch):
    released = []
    monkeypatch.setattr(runtime, "release_compiled", lambda: released.append(True))
    monkeypatch.setattr(runtime, "_reported", False)
    for count, says, release in [(1000, None, False), (33_000, "of the limit 65530", False), (34_000, None, False),
                                 (49_200, "released the process's compiled programs", True), (1000, None, False),
                                 (40_000, "of the limit 65530", False)]:
        monkeypatch.setattr(runtime, "memory_maps", lambda c=count: (c, 65530))
        released.clear()
        msg = runtime.check_maps()
        assert (msg is None) if says is None else (says in msg and "vm.max_map_count" in msg), (count, msg)
        assert bool(released) == release, count
    monkeypatch.setattr(runtime, "memory_maps", lambda: None)
    assert runtime.check_maps() is None  # a system that does not tell: nothing to say


def test_evaluate_guards_a_script_that_nears_the_limit(monkeypatch):
    """kx.sim.evaluate.evaluate outside the run loop (a script of many tasks once died in LLVM): near the limit
    it releases the compiled programs and warns, at most every MAPS_GUARD_SECONDS, and plays the same episodes."""
    import jax
    import numpy as np

    from kx.sim import env
    from kx.sim import evaluate as ev
    from kx.sim.policies import BASELINES
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig(), KeepAwayParams(max_iterations=60)
    starts = env.reset_batch(jax.random.key(3), 4, params, config)

    def play():
        return np.asarray(ev.evaluate(BASELINES["heuristic"](config), None, starts, params, config,
                                      key=jax.random.key(5)).fitness)

    released = []
    monkeypatch.setattr(runtime, "release_compiled", lambda: released.append(True))
    monkeypatch.setattr(runtime, "_reported", False)
    monkeypatch.setattr(runtime, "_guarded_at", float("-inf"))
    monkeypatch.setattr(runtime, "memory_maps", lambda: (30_000, 65530))  # below MAPS_RELEASE: quiet
    quiet = play()
    assert not released
    monkeypatch.setattr(runtime, "_guarded_at", float("-inf"))
    monkeypatch.setattr(runtime, "memory_maps", lambda: (50_000, 65530))
    with pytest.warns(RuntimeWarning, match="released the process's compiled programs"):
        near = play()
    assert released == [True]
    np.testing.assert_array_equal(near, quiet)
    play()  # within MAPS_GUARD_SECONDS of the last look: not read again
    assert released == [True]
