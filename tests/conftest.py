import os

from kx import runtime

# the suite's processes run with the OpenBLAS kernels kx's command-line processes pin (kx.runtime.setup), before
# scipy loads them: CMA-ES's committed rows are compared here; its kx.train subprocesses pin their own
runtime.pin_openblas_kernels(announce=False)

os.environ.setdefault("KX_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".venv", "jax-cache"))
# every program is cached, however fast it compiled: the two workers and every kx.train subprocess of
# the suite share what one of them compiled first
os.environ.setdefault("KX_CACHE_MIN_COMPILE_SECS", "0")

# The suite compiles for compilation speed rather than run speed: almost all of its time is the cold
# compilation of programs that then run for milliseconds. LLVM's optimisation level 0, XLA CPU's older
# elemental emitters and no expensive LLVM passes compile NEAT's generation step 3-4x faster (8.8 s ->
# 2.3 s) and halved the suite's time (2026-12-02, 2 cores, cold cache: 788 s -> 396 s of pytest time);
# they change how fast programs run and, in the last bit, what some compute (the novelty k-NN's scores,
# HyperNEAT's runs: tests/fixtures/run_dirs.json was written with them, and a run's trajectory under
# them can part from the same run's under XLA's defaults), never the suite's comparisons, which run
# both sides under the same flags. Every kx.train and helper process the suite
# starts inherits them (so it shares the compiled programs); a user's own XLA_FLAGS choosing the
# optimisation level wins (KX_TEST_XLA_FLAGS= runs the suite with XLA's defaults).
COMPILE_FLAGS = os.environ.get("KX_TEST_XLA_FLAGS", "--xla_backend_optimization_level=0 "
                               "--xla_cpu_use_fusion_emitters=false --xla_llvm_disable_expensive_passes=true")
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {COMPILE_FLAGS}".strip()

# No Python traceback frames in the programs' location metadata (lowering skips collecting them; the
# compiled code and the persistent cache's keys are the same, since the cache strips debug info): 3-5%
# less CPU on a cold test file. Subprocesses inherit it; a user's own setting wins.
os.environ.setdefault("JAX_TRACEBACK_IN_LOCATIONS_LIMIT", "0")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from kx.sim.types import KeepAwayConfig, KeepAwayParams, State  # noqa: E402

jax.config.update("jax_compilation_cache_dir", os.environ["KX_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", float(os.environ["KX_CACHE_MIN_COMPILE_SECS"]))

TASKS = ("3v2", "4v3", "5v3", "6v4")


def make_state(keepers, takers, holder, **kw) -> State:
    """A single-episode state from cell lists (ball on the holder)."""
    i32 = lambda v: jnp.asarray(v, jnp.int32)  # noqa: E731
    hx, hy = keepers[holder]
    fields = dict(
        keeper_x=i32([k[0] for k in keepers]), keeper_y=i32([k[1] for k in keepers]),
        taker_x=i32([t[0] for t in takers]), taker_y=i32([t[1] for t in takers]),
        holder=i32(holder), ball_x=i32(hx), ball_y=i32(hy), origin_x=i32(hx), origin_y=i32(hy),
        dir_x=i32(1), dir_y=i32(0), substep=i32(0), kicker=i32(-1), t=i32(0),
        done=jnp.asarray(False), reason=i32(0), passes=i32(0), contest=i32(0), dispersion_sum=i32(0),
        ball_centre_sum=i32(0), decisions=i32(0))
    fields.update({k: (jnp.asarray(v) if k == "done" else i32(v)) for k, v in kw.items()})
    return State(**fields)


@pytest.fixture
def cfg32() -> KeepAwayConfig:
    return KeepAwayConfig()


@pytest.fixture
def params() -> KeepAwayParams:
    return KeepAwayParams()


def np_tree(state):
    """A state's fields as a dict of numpy arrays."""
    return {f: np.asarray(getattr(state, f)) for f in state.__dataclass_fields__}


# Files that take longest come first (measured: KX_TEST_PROFILE under a cold cache, 2026-12-06, less what went to the
# slow set after it), so that `--dist loadfile` hands them out before the short ones and both workers end together;
# the order within a file is kept. xdist keeps this order only with `--no-loadscope-reorder` (the Makefile passes it):
# by default it deals files out by their number of tests, which left a long file of few tests for last. A file not
# listed goes after these: list a new file that takes more than a few seconds.
LONGEST_FIRST = ("test_neat.py", "test_gym.py", "test_entity.py", "test_group.py", "test_experiments.py",
                 "test_run_loop.py", "test_bev.py", "test_env.py", "test_transfer.py", "test_ppo.py", "test_train.py",
                 "test_shared_tables.py", "test_cppn.py", "test_reference.py", "test_evaluate.py", "test_train_ppo.py",
                 "test_config.py", "test_clustered.py", "test_neat_selection.py", "test_train_hyperneat.py",
                 "test_run_dir_fixture.py", "test_neat_mutation.py", "test_neat_readings.py", "test_confirm.py",
                 "test_evolve.py", "test_novelty.py", "test_native.py", "test_substrate.py", "test_native_build.py",
                 "test_devices.py", "test_run_dir.py", "test_bench_platform.py", "test_train_entity.py",
                 "test_processes.py", "test_render.py", "test_behaviour.py", "test_openblas.py", "test_lanes.py",
                 "test_zeroshot.py", "test_train_novelty.py", "test_runtime.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


# KX_TEST_PROFILE=FILE: per test, the seconds JAX spent tracing, lowering and compiling (cache hits apart),
# appended to FILE as JSON lines (what the suite's time goes to; see README's Tests section)
if os.environ.get("KX_TEST_PROFILE"):
    import collections
    import json

    from jax import monitoring

    _SPENT = collections.Counter()
    _NAMES = {"/jax/core/compile/jaxpr_trace_duration": "trace",
              "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
              "/jax/core/compile/backend_compile_duration": "compile",
              "/jax/compilation_cache/cache_retrieval_time_sec": "cache_read"}

    def _listen(event, duration, **_):
        if event in _NAMES:
            _SPENT[_NAMES[event]] += duration

    monitoring.register_event_duration_secs_listener(_listen)

    # and each program it compiled or read from the persistent cache, with the seconds it took: a program compiled
    # by several tests (or several times in one, for batches of other sizes) is what sharing its shapes would save
    import logging
    import re

    _PROGRAMS: list = []
    _HIT: list = [None]  # the program whose persistent-cache hit was logged last, not yet finished

    class _Programs(logging.Handler):
        def emit(self, record):
            msg = record.getMessage()
            if msg.startswith("Persistent compilation cache hit for '"):
                _HIT[0] = msg.split("'")[1]
            elif m := re.match(r"Finished XLA compilation of (.*) in ([0-9.]+) sec", msg):
                # a hit is logged inside the compilation it ends, which then logs its seconds (the cache's read);
                # the cache names a program jit_tell where the compile log says jit(tell)
                hit = re.sub(r"\W", "_", m[1]).rstrip("_") == _HIT[0]
                _HIT[0] = None
                _PROGRAMS.append([m[1], round(float(m[2]), 3), hit])

    jax.config.update("jax_log_compiles", True)
    logging.getLogger("jax").addHandler(_Programs())

    @pytest.hookimpl(wrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        _SPENT.clear()
        _PROGRAMS.clear()
        t0 = __import__("time").perf_counter()
        out = yield
        with open(os.environ["KX_TEST_PROFILE"], "a") as f:
            f.write(json.dumps({"test": item.nodeid, "worker": os.environ.get("PYTEST_XDIST_WORKER", ""),
                                "end": round(__import__("time").time(), 1),
                                "seconds": __import__("time").perf_counter() - t0,
                                **{k: round(v, 3) for k, v in _SPENT.items()},
                                "programs": [p for p in _PROGRAMS if p[1] >= 0.05],  # and the rest, summed:
                                "small_programs": [sum(p[1] < 0.05 for p in _PROGRAMS),
                                                   round(sum(p[1] for p in _PROGRAMS if p[1] < 0.05), 3)]}) + "\n")
        return out
