"""The evaluator's lanes (kx.sim.lanes): packing into one int32 array and back bit for bit, the rungs'
scalars (params by their declared field types, the run groups' keys), the live-first compaction order."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from kx.sim import lanes
from kx.sim.types import KeepAwayParams


def test_live_first_order_is_the_stable_sort_of_done():
    """The rungs' compaction order (prefix counts and a scatter) is ``argsort(done, stable=True)``: live
    lanes first, then finished ones, each in lane order; all live, all finished and mixed batches."""
    rng = np.random.default_rng(0)
    for n, p in [(1, 0.5), (7, 0.0), (7, 1.0), (64, 0.3), (257, 0.9), (1000, 0.5)]:
        done = jnp.asarray(rng.random(n) < p)
        want = np.argsort(np.asarray(done), kind="stable")
        for k in {1, n // 2 or 1, n}:
            np.testing.assert_array_equal(np.asarray(lanes.live_first(done, k)), want[:k])


def _same_bits(a, b):
    assert a.dtype == b.dtype and a.shape == b.shape
    np.testing.assert_array_equal(np.asarray(a).view(np.uint8), np.asarray(b).view(np.uint8))


def test_lanes_pack_and_unpack_losslessly():
    """The packed lanes (one int32 array) give back every leaf bit for bit: int32, uint32 (full range),
    float32 (negative zero, infinities, NaN payloads), booleans and narrower integers; the layout is
    static and hashable, the same for any lane count."""
    n = 5
    bits = np.array([0x7FC00001, 0xFF800000, 0x80000000, 0x3F800000, 0x00000001], np.uint32)
    tree = {"i": jnp.arange(3 * n, dtype=jnp.int32).reshape(3, n) - 7,
            "u": jnp.asarray(np.array([0, 1, 2**31, 2**32 - 1, 12345], np.uint32)),
            "f": jnp.asarray(bits.view(np.float32)).reshape(1, n),
            "b": jnp.asarray([True, False, True, True, False]),
            "s": jnp.asarray(np.array([[-128, 127, 0, -1, 5]], np.int8))}
    rows = lanes.pack(tree)
    layout = lanes.Layout.of(tree)
    assert rows.dtype == jnp.int32 and rows.shape == (3 + 1 + 1 + 1 + 1, n) and layout.n_rows() == 7
    assert hash(layout) == hash(lanes.Layout.of(jax.tree.map(lambda a: a[..., :2], tree)))
    back = lanes.unpack(rows, layout)
    for k, a in tree.items():
        _same_bits(back[k], a)
    with pytest.raises(TypeError, match="starts: .* got float16"):
        lanes.pack({"h": jnp.zeros((2, n), jnp.float16)})


@struct.dataclass
class _Mixed:
    """A state of every packable kind: int32, float32, bool, uint32 and narrower integers, per agent and
    per episode."""

    xy: jax.Array  # [2, 3, n] int32
    speed: jax.Array  # [n] float32
    done: jax.Array  # [n] bool
    word: jax.Array  # [n] uint32
    small: jax.Array  # [4, n] int8
    wide: jax.Array  # [n] uint16
    half: jax.Array  # [n] int16


def test_an_evaluations_lanes_of_mixed_dtypes_round_trip():
    """An evaluation's lanes (state, a shared policy's row index, noise word, lane id) of a state of mixed
    dtypes come back bit for bit from one int32 array, the state's rows first (:meth:`Layout.first_rows`:
    what a rung repacks)."""
    n, rng = 6, np.random.default_rng(1)
    state = _Mixed(xy=jnp.asarray(rng.integers(-2**31, 2**31, (2, 3, n)), jnp.int32),
                   speed=jnp.asarray(np.array([0.0, -0.0, 1.5, -np.inf, np.nan, 3e-45], np.float32)),
                   done=jnp.asarray(rng.random(n) < 0.5),
                   word=jnp.asarray(rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)),
                   small=jnp.asarray(rng.integers(-128, 128, (4, n)), jnp.int8),
                   wide=jnp.asarray(rng.integers(0, 2**16, n), jnp.uint16),
                   half=jnp.asarray(rng.integers(-2**15, 2**15, n), jnp.int16))
    index = jnp.arange(n, dtype=jnp.int32) // 2
    word = jnp.asarray(rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32))
    lane_id = jnp.arange(n, dtype=jnp.int32)
    for shared in (True, False):
        tree = (state, index if shared else None, word, lane_id)
        layout = lanes.lane_layout(state, shared)
        assert layout == lanes.Layout.of(tree) and layout.first_rows() == 6 + 1 + 1 + 1 + 4 + 1 + 1
        rows = lanes.pack(tree)
        assert rows.dtype == jnp.int32 and rows.shape == (layout.n_rows(), n)
        for got, want in zip(jax.tree.leaves(lanes.unpack(rows, layout)), jax.tree.leaves(tree), strict=True):
            _same_bits(got, want)
        back_state = lanes.unpack(rows, layout)[0]
        assert isinstance(back_state, _Mixed)


def test_rung_scalars_carry_the_params_and_keys_exactly():
    """The params (every field, a float field by its bits), the group size and the run groups' keys travel
    to the rungs as one int32 array and come back equal."""
    params = KeepAwayParams(max_iterations=1234, start_clearance=3, kick_noise_deg=7.25, taker_reaction_delay=0,
                            tackle_iterations=2)
    keys = jax.random.split(jax.random.key(11), 3)
    back, group_size, back_keys = lanes.unpack_scalars(jnp.asarray(lanes.pack_scalars(params, 4500, keys)), 3,
                                                       str(jax.random.key_impl(keys)))
    assert int(group_size) == 4500
    fields = lanes.scalar_fields(KeepAwayParams)
    assert [f for f, _ in fields] == [f.name for f in dataclasses.fields(KeepAwayParams)]
    assert [f for f, is_float in fields if is_float] == ["kick_noise_deg"]
    for f, is_float in fields:
        got = getattr(back, f)
        assert got.dtype == (jnp.float32 if is_float else jnp.int32), f
        assert got.item() == getattr(params, f), f
    np.testing.assert_array_equal(np.asarray(jax.random.key_data(back_keys)), np.asarray(jax.random.key_data(keys)))
    # a value float32 cannot hold comes back as its float32
    back = lanes.unpack_scalars(jnp.asarray(lanes.pack_scalars(params.replace(kick_noise_deg=7.3), 1, keys[:1])),
                                1, str(jax.random.key_impl(keys)))[0]
    assert np.float32(back.kick_noise_deg) == np.float32(7.3)


@struct.dataclass
class _IntDefault:
    """A float field whose default is an int: packed by its declared type, not its default's."""

    n: int = 2
    scale: float | jax.Array = 1


def test_scalars_follow_the_declared_field_types_not_the_defaults():
    assert lanes.scalar_fields(_IntDefault) == (("n", False), ("scale", True))
    keys = jax.random.key(0)[None]
    p = _IntDefault(n=7, scale=1.5)
    back, _, _ = lanes.unpack_scalars(jnp.asarray(lanes.pack_scalars(p, 10, keys)), 1, "threefry2x32", _IntDefault)
    assert isinstance(back, _IntDefault) and back.n.item() == 7 and back.scale.item() == 1.5


@pytest.mark.parametrize("hint", ["bool", "str", "int | float", "tuple[int, int]", "jax.Array"])
def test_a_field_that_cannot_be_packed_is_refused(hint):
    cls = struct.dataclass(type("_Bad", (), {"__annotations__": {"ok": "int", "bad": hint}, "ok": 1, "bad": 0}))
    with pytest.raises(TypeError, match=r"_Bad\.bad: .* declare the field int or float"):
        lanes.scalar_fields(cls)
