"""Exact integer geometry of the grid world.

Every rule of the simulator is decided in integers, so that the JAX step, the plain-Python reference
and any accelerator agree bit for bit. The one irrational quantity, the ball's real position on a pass
``origin + k * e / |e|`` (``e`` an integer direction, ``k`` unit sub-steps), is rounded to a cell with
:func:`round_div_sqrt`: a float32 first guess corrected by an exact integer comparison. There are no
rounding ties: ``k*e_x/|e| = n + 1/2`` would make ``|e|`` rational, so an integer whose square
``e_x^2 + e_y^2`` is a perfect square; then ``2 k e_x = (2n+1) |e|`` with ``|e|`` odd after removing a
common factor (Pythagorean hypotenuses are odd), an even number equal to an odd one.

All functions are elementwise over arbitrary (batch-last) shapes.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from kx.sim.types import DIST_SCALE, MAX_FIELD

# King moves in a fixed order; index 0 (stay) first so that ties favour standing still.
MOVES = np.array(
    [(0, 0), (1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1)], dtype=np.int32
)


def inv_sqrt(l2):
    """``1 / sqrt(l2)`` in float32: the first guess of :func:`round_div_sqrt` for a given ``l2``."""
    return 1.0 / jnp.sqrt(l2.astype(jnp.float32))


def round_div_sqrt(a, l2, inv=None):
    """``round(a / sqrt(l2))`` exactly, for integer ``a >= 0`` and ``l2 >= 1`` (int32 arrays).

    ``inv`` (optional) is :func:`inv_sqrt` of ``l2``, shared by callers that round many values with the
    same ``l2``; it only seeds the guess, which the integer comparison then corrects, so the result
    is exact either way. Needs ``4 a^2`` and ``(2n+1)^2 l2`` below 2^31, which the callers guarantee
    by the field bound.
    """
    inv = inv_sqrt(l2) if inv is None else inv
    n = jnp.floor(a.astype(jnp.float32) * inv + 0.5).astype(jnp.int32)
    four_a2 = 4 * a * a
    # n is right iff (2n-1)^2 l2 <= 4a^2 < (2n+1)^2 l2 (no equality can occur, see module doc).
    n = jnp.where((n > 0) & ((2 * n - 1) ** 2 * l2 > four_a2), n - 1, n)
    n = jnp.where((2 * n + 1) ** 2 * l2 < four_a2, n + 1, n)
    return n


def round_div_sqrt_signed(v, l2, inv=None):
    """``round(v / sqrt(l2))`` for any integer ``v`` (no ties, so the rounding is symmetric)."""
    return jnp.sign(v) * round_div_sqrt(jnp.abs(v), l2, inv)


def round_scaled_sqrt(n, scale: int):
    """``round(scale * sqrt(n))`` exactly for integer ``n >= 0`` (no ties: a half would make sqrt(n)
    rational, so an integer). Needs ``4 scale^2 n < 2^31``. Arithmetic, not a table: XLA CPU gathers
    do not vectorise."""
    q = jnp.floor(scale * jnp.sqrt(n.astype(jnp.float32)) + 0.5).astype(jnp.int32)
    target = 4 * scale * scale * n  # compare (2q +- 1)^2 with (2 scale sqrt n)^2
    q = jnp.where((2 * q + 1) ** 2 <= target, q + 1, q)
    q = jnp.where((q > 0) & ((2 * q - 1) ** 2 > target), q - 1, q)
    return q


def pass_cell(origin_x, origin_y, dir_x, dir_y, k, l2=None, inv=None):
    """Cell of the ball ``k`` unit sub-steps along a pass: ``origin + round(k * dir / |dir|)``.

    ``l2 = |dir|^2`` and ``inv = inv_sqrt(l2)`` may be passed when already computed."""
    l2 = dir_x * dir_x + dir_y * dir_y if l2 is None else l2
    inv = inv_sqrt(l2) if inv is None else inv
    return (origin_x + round_div_sqrt_signed(k * dir_x, l2, inv),
            origin_y + round_div_sqrt_signed(k * dir_y, l2, inv))


def projection_substep(px, py, origin_x, origin_y, dir_x, dir_y, l2=None, inv=None):
    """Sub-step of the pass nearest to point ``p``: ``round(max(0, (p - origin) . dir) / |dir|)``."""
    l2 = dir_x * dir_x + dir_y * dir_y if l2 is None else l2
    dot = (px - origin_x) * dir_x + (py - origin_y) * dir_y
    return round_div_sqrt(jnp.maximum(dot, 0), l2, inv)


# Packed cells: a heavy computation that yields a cell returns one int32 instead of an (x, y) pair,
# because XLA CPU emits a separate fusion (recomputing everything) for each output of a large one.
_PACK_OFF, _PACK_BITS = 128, 9


def pack(x, y):
    """One int32 for a cell with coordinates in [-128, 383]."""
    return (x + _PACK_OFF) | ((y + _PACK_OFF) << _PACK_BITS)


def unpack(code):
    return (code & ((1 << _PACK_BITS) - 1)) - _PACK_OFF, (code >> _PACK_BITS) - _PACK_OFF


def cheb(ax, ay, bx, by):
    """Chebyshev distance: the number of king moves from a to b."""
    return jnp.maximum(jnp.abs(ax - bx), jnp.abs(ay - by))


def toward(x, y, tx, ty, speed: int, field_size: int):
    """Up to ``speed`` king moves from (x, y) straight toward (tx, ty), staying inside the field."""
    return (jnp.clip(x + jnp.clip(tx - x, -speed, speed), 0, field_size - 1),
            jnp.clip(y + jnp.clip(ty - y, -speed, speed), 0, field_size - 1))


def inside(x, y, field_size: int):
    return (x >= 0) & (x < field_size) & (y >= 0) & (y < field_size)


@functools.lru_cache(maxsize=None)
def dist_table() -> np.ndarray:
    """``DIST_SCALE * sqrt(n)`` rounded, for every integer ``n`` a squared cell distance can take,
    computed in float64 (correctly rounded sqrt, no ties): the oracle the tests hold
    :func:`round_scaled_sqrt` to."""
    n = np.arange(2 * (2 * MAX_FIELD) ** 2 + 1, dtype=np.float64)
    return np.floor(DIST_SCALE * np.sqrt(n) + 0.5).astype(np.int32)


@functools.lru_cache(maxsize=None)
def half_dist_table() -> np.ndarray:
    """``DIST_SCALE * sqrt(n) / 2`` rounded (distance to the centre from doubled coordinates); a test
    oracle like :func:`dist_table`."""
    n = np.arange(2 * (2 * MAX_FIELD) ** 2 + 1, dtype=np.float64)
    return np.floor(DIST_SCALE * np.sqrt(n) / 2 + 0.5).astype(np.int32)
