"""Exact integer geometry: rounding against float64 and against exact integer arithmetic."""

import math

import jax
import jax.numpy as jnp
import numpy as np

from kx.sim import geometry as geo


def test_round_div_sqrt_exhaustive():
    # every (a, l2) the pass geometry can produce on a 20-cell field with kick noise, and more
    a = np.arange(0, 4000, 7, dtype=np.int64)
    l2 = np.unique(np.array([x * x + y * y for x in range(0, 40) for y in range(0, 40) if x or y]))
    aa, ll = np.meshgrid(a, l2, indexing="ij")
    got = np.asarray(jax.jit(geo.round_div_sqrt)(jnp.asarray(aa, jnp.int32), jnp.asarray(ll, jnp.int32)))
    # exact: n = round(a / sqrt(l2)) is the n with (2n-1)^2 l2 <= 4a^2 < (2n+1)^2 l2 (int64 here)
    n = np.floor(aa / np.sqrt(ll) + 0.5).astype(np.int64)
    four = 4 * aa * aa
    assert np.all(((2 * n - 1) ** 2 * ll <= four) | (n == 0))
    assert np.all((2 * n + 1) ** 2 * ll > four)
    np.testing.assert_array_equal(got, n)


def test_pass_cells_hand_computed():
    # a 3-4-5 pass from (0, 0): real positions (0.6k, 0.8k)
    k = jnp.arange(1, 6)
    x, y = geo.pass_cell(jnp.int32(0), jnp.int32(0), jnp.int32(3), jnp.int32(4), k)
    assert list(zip(np.asarray(x).tolist(), np.asarray(y).tolist())) == [(1, 1), (1, 2), (2, 2), (2, 3), (3, 4)]


def test_pass_cells_are_king_connected_and_reach_receiver():
    # every direction of the field at once (one compiled call; 1560 eager calls took 30 s cold)
    d = np.array([(dx, dy) for dx in range(-19, 20) for dy in range(-19, 20) if (dx, dy) != (0, 0)], np.int32)
    k = np.arange(0, 30, dtype=np.int32)  # |d| < 27: every pass's cells up to int(|d|) + 3
    x, y = (np.asarray(v) for v in jax.jit(geo.pass_cell)(
        jnp.int32(0), jnp.int32(0), jnp.asarray(d[:, :1]), jnp.asarray(d[:, 1:]), jnp.asarray(k[None])))
    for i, (dx, dy) in enumerate(d.tolist()):
        length = math.hypot(dx, dy)
        n = int(length) + 3
        # the ball never skips a cell (at most one king move a sub-step), so it cannot pass through a taker
        assert np.all(np.maximum(np.abs(np.diff(x[i, :n])), np.abs(np.diff(y[i, :n]))) <= 1)
        r = round(length)
        assert (x[i, r], y[i, r]) == (dx, dy)


def test_pack_roundtrip():
    x = jnp.arange(-60, 100)
    y = jnp.flip(x)
    px, py = geo.unpack(geo.pack(x, y))
    np.testing.assert_array_equal(px, x)
    np.testing.assert_array_equal(py, y)


def test_round_scaled_sqrt_equals_float64_tables():
    n = jnp.arange(len(geo.dist_table()), dtype=jnp.int32)
    np.testing.assert_array_equal(jax.jit(lambda n: geo.round_scaled_sqrt(n, 32))(n), geo.dist_table())
    np.testing.assert_array_equal(jax.jit(lambda n: geo.round_scaled_sqrt(n, 16))(n), geo.half_dist_table())


def test_distance_tables():
    t = geo.dist_table()
    assert t[0] == 0 and t[1] == 32 and t[2] == round(32 * math.sqrt(2)) and t[25] == 160
    assert geo.half_dist_table()[2] == round(16 * math.sqrt(2))
