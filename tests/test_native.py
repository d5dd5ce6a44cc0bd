"""kx.hyperneat.native's ``kx_bev_sums`` against the compiled XLA code of kx.hyperneat.bev.sparse_outputs: the same
sums bit
for bit, under the suite's flags (multiply-adds rounded twice) and, in a process of its own, under XLA's default
flags (fused, as the run loop compiles); the same episodes in the evaluator; the choice of implementation and
its errors."""

import functools
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from substrates import random_table

from kx.hyperneat import bev, native
from kx.sim import env, samples
from kx.sim.types import KeepAwayConfig, KeepAwayParams

W = 20

pytestmark = pytest.mark.skipif(bool(native.unavailable()), reason=f"kx.hyperneat.native: {native.unavailable()}")


def _table(key, g):
    return random_table(key, g, W * W)


@functools.partial(jax.jit, static_argnames=("config", "impl", "n_rows"))
def _sums(table, index, state, busy, config, impl, n_rows=None):
    """The sums at the keepers' cells, or at ``n_rows`` rows of the lane's genome (cells 7, 14, ...)."""
    if n_rows is None:
        rows = state.keeper_x + W * state.keeper_y
    else:
        rows = (jnp.arange(n_rows, dtype=jnp.int32)[:, None] * 7 + index[None]) % (W * W)
    return bev.sparse_outputs(table, index, rows, state, config, "authors", None, busy, impl)


def _varied(task, key):
    """Resets, stepped and adversarial states (agents stacked on one cell, nobody holding the ball), a fifth of
    them finished, and which lanes are busy (a holder in a running episode)."""
    config = KeepAwayConfig.from_task(task)
    state = jax.jit(samples.varied_states, static_argnums=(1, 2))(key, config, 48)
    n = state.holder.shape[0]
    state = state.replace(done=jnp.arange(n) % 5 == 1)
    busy = (state.holder >= 0) & ~state.done
    return config, state, busy


def _same_bits(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype == np.float32
    np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))


def check_native_against_xla(tasks, extra_rows=True):
    """Every sum of the native kernel against the XLA code, for each task: at the keepers' cells with and
    without the busy mask (idle lanes included: they add ``0 * w`` as the XLA code does), and at other counts
    of rows (1, 2, 7, 9: the kernel's other path)."""
    table = _table(jax.random.key(21), 5)
    for i, task in enumerate(tasks):
        config, state, busy = _varied(task, jax.random.key(30 + i))
        n = state.holder.shape[0]
        assert 0.2 < float(busy.mean()) < 0.8
        index = jnp.arange(n, dtype=jnp.int32) % 5
        for mask in (busy, None):
            _same_bits(_sums(table, index, state, mask, config, "native"), _sums(table, index, state, mask, config,
                                                                                  "xla"))
        for r in (1, 2, 7, 9) if extra_rows else ():
            _same_bits(_sums(table, index, state, busy, config, "native", r),
                       _sums(table, index, state, busy, config, "xla", r))


def check_episodes_alike(task="4v3"):
    """The evaluator's statistics of every lane, native against XLA: the same episodes."""
    from kx.sim import evaluate as ev

    config = KeepAwayConfig.from_task(task)
    params = KeepAwayParams(max_iterations=120)
    starts = env.reset_batch(jax.random.key(41), 6, params, config)
    table = _table(jax.random.key(42), 3)
    table = jax.tree.map(lambda a: a * 0.2, table)  # outputs that do not all saturate: decisions that differ
    stats = [jax.tree.map(np.asarray, ev.evaluate(bev.bev_policy(config, "authors", skip_idle=True, impl=impl),
                                                  table, starts, params, config, key=jax.random.key(43)))
             for impl in ("native", "xla")]
    for f in stats[0].__dataclass_fields__:
        np.testing.assert_array_equal(getattr(stats[0], f), getattr(stats[1], f), err_msg=f)
    assert stats[0].passes.sum() > 0


# the default suite: the same sums under the run loop's flags (test_native_under_xla_default_flags) and the
# same episodes under the suite's (test_native_plays_the_same_episodes_in_the_evaluator)
@pytest.mark.parametrize("task", [pytest.param(t, marks=pytest.mark.slow) for t in ("3v2", "4v3", "5v3", "6v4")])
def test_native_sums_are_the_xla_sums_bit_for_bit(task):
    """Under the suite's flags XLA rounds each product before its sum (:func:`bev.chain_is_fused` is False)
    and the kernel does the same, for every task (the slow set)."""
    assert not bev.chain_is_fused()
    check_native_against_xla([task])


def test_native_plays_the_same_episodes_in_the_evaluator():
    check_episodes_alike()


# Both in the slow set (a process of its own compiling at XLA's default level: ~20 s on CI without the episodes);
# the default suite checks the kernel's sums and episodes against the XLA code's under the suite's flags (above)
@pytest.mark.slow
@pytest.mark.parametrize("episodes", [False, True])
def test_native_under_xla_default_flags(episodes):
    """In a process of its own under XLA's default flags, which the run loop compiles with: the chain is fused
    there (one rounding per multiply-add), and the kernel's sums (and, in the slow set, the evaluator's episodes)
    are still the XLA code's."""
    environ = {**os.environ, "XLA_FLAGS": ""}
    done = subprocess.run([sys.executable, __file__, *(["--episodes"] if episodes else [])], env=environ,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and "the same bits, fused" in done.stdout, done.stdout + done.stderr


def test_impl_is_checked_and_native_refused_where_it_cannot_run(monkeypatch):
    config, state, busy = _varied("3v2", jax.random.key(50))
    table = _table(jax.random.key(51), 2)
    index = jnp.zeros(state.holder.shape, jnp.int32)
    kc = state.keeper_x + W * state.keeper_y
    with pytest.raises(ValueError, match=r"impl: allowed \('auto', 'xla', 'native'\), got 'c'"):
        bev.sparse_outputs(table, index, kc, state, config, "authors", None, busy, "c")
    with pytest.raises(ValueError, match="impl: allowed"):
        bev.bev_policy(config, "authors", impl="fast")
    # the paper image is the XLA code's: auto runs it, native is refused with the reason
    with pytest.raises(ValueError, match="'native' is not available here .image 'paper'"):
        bev.sparse_outputs(table, index, kc, state, config, "paper", None, busy, "native")
    monkeypatch.setenv("KX_NATIVE", "0")
    native._library.cache_clear()
    try:
        assert native.unavailable() == "KX_NATIVE=0"
        with pytest.raises(ValueError, match=r"'native' is not available here \(KX_NATIVE=0\)"):
            bev.sparse_outputs(table, index, kc, state, config, "authors", None, busy, "native")
        # auto falls back to the XLA code
        _same_bits(bev.sparse_outputs(table, index, kc, state, config, "authors", None, busy),
                   bev.sparse_outputs(table, index, kc, state, config, "authors", None, busy, "xla"))
    finally:
        monkeypatch.delenv("KX_NATIVE")
        native._library.cache_clear()
    assert native.unavailable() == ""


if __name__ == "__main__":  # the checks under XLA's default flags (test_native_under_xla_default_flags runs them)
    from kx import runtime

    runtime.setup(1)
    assert bev.chain_is_fused()
    check_native_against_xla(["6v4"], extra_rows=False)  # the most keepers' rows and path steps
    if "--episodes" in sys.argv:  # the same sums decide the same: the evaluator's episodes (slow set)
        check_episodes_alike()
    print("the same bits, fused")
