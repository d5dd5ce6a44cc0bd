"""How the evaluator's lanes lie in arrays and on devices: packing, scalars, compaction order, placement.

:mod:`kx.sim.evaluate` steps lanes (one episode each, batch-last) through the rungs of its width
ladder; this module holds what the rungs carry and how, apart from how they step:

* the lanes of a rung travel packed in one int32 array ``[rows, lanes]`` (:class:`Layout`,
  :func:`pack`, :func:`unpack`; the lanes of an evaluation: :func:`lane_layout`);
* what every rung reads besides its lanes (the params, the run groups' size and keys) travels as one
  small int32 array (:func:`pack_scalars`, :func:`unpack_scalars`), the params by their declared
  field types (:func:`scalar_fields`);
* a rung compacts its lanes live first (:func:`live_first`);
* lanes split over the devices of one mesh, everything else replicated on them (:func:`mesh`,
  :func:`lane_specs`, :func:`put_lanes`, :func:`put_replicated`, :func:`onto_mesh`).

Packing is lossless (32-bit types reinterpreted, booleans and narrower integers widened), so the
evaluator's results do not depend on it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from kx.sim.types import KeepAwayParams


@dataclasses.dataclass(frozen=True)
class Layout:
    """How a pytree of batch-last lane arrays lies in the rows of one int32 array ``[rows, lanes]``
    (:func:`pack`): the tree's structure and, per leaf, its shape without the lane axis and its dtype.
    Static (hashable), so compiled calls take the lanes as one array.

    One array rather than one per field because every argument and result of a compiled call costs
    its own handling on every call: a rung of 25 lane arrays on 2 devices cost 0.36 ms more to call
    than one of 5, measured in a loop that did nothing else, and an evaluation makes ten such calls."""

    treedef: Any
    leaves: tuple[tuple[tuple[int, ...], str], ...]

    @staticmethod
    def of(tree) -> "Layout":
        leaves, treedef = jax.tree.flatten(tree)
        return Layout(treedef, tuple((tuple(a.shape[:-1]), jnp.dtype(a.dtype).name) for a in leaves))

    def n_rows(self, n_leaves: int | None = None) -> int:
        """Rows of the first ``n_leaves`` leaves (default: all)."""
        return sum(math.prod(shape) for shape, _ in self.leaves[:n_leaves])

    def first_rows(self) -> int:
        """Rows of the first item of a tuple tree (the state, in :func:`lane_layout`'s lanes)."""
        first = jax.tree.unflatten(self.treedef, [0] * len(self.leaves))[0]
        return self.n_rows(len(jax.tree.leaves(first)))


def int32_rows(a: jax.Array) -> jax.Array:
    """One lane array ``[..., w]`` as int32 rows ``[-1, w]``, losslessly: 32-bit types reinterpreted,
    booleans and narrower integers widened."""
    a = a.reshape(-1, a.shape[-1])
    dt = jnp.dtype(a.dtype)
    if dt == jnp.int32:
        return a
    if dt.itemsize == 4:
        return jax.lax.bitcast_convert_type(a, jnp.int32)
    if dt == jnp.bool_ or (jnp.issubdtype(dt, jnp.integer) and dt.itemsize < 4):
        return a.astype(jnp.int32)
    raise TypeError(f"starts: the evaluator packs the state's arrays into int32 lanes; they must be 32-bit, boolean "
                    f"or narrower integers, got {dt.name}")


def pack(tree) -> jax.Array:
    """Every leaf of ``tree`` (batch-last, the same lane count) in one int32 array ``[rows, lanes]``,
    leaf after leaf (:class:`Layout`)."""
    return jnp.concatenate([int32_rows(a) for a in jax.tree.leaves(tree)])


def unpack(rows: jax.Array, layout: Layout):
    """The tree :func:`pack` packed into ``rows``."""
    w, out, off = rows.shape[-1], [], 0
    for shape, name in layout.leaves:
        n, dt = math.prod(shape), jnp.dtype(name)
        r = rows[off: off + n].reshape(shape + (w,))
        off += n
        if dt == jnp.bool_:
            r = r != 0
        elif dt.itemsize == 4 and dt != jnp.int32:
            r = jax.lax.bitcast_convert_type(r, dt)
        elif dt != jnp.int32:
            r = r.astype(dt)
        out.append(r)
    return jax.tree.unflatten(layout.treedef, out)


def lane_layout(starts, shared: bool) -> Layout:
    """The :class:`Layout` of an evaluation's packed lanes ``(state, row index of a shared policy (else
    None), noise word, lane id)``."""
    leaves, treedef = jax.tree.flatten(starts)
    return _layout_of(treedef, tuple((tuple(a.shape[:-1]), jnp.dtype(a.dtype).name) for a in leaves), shared)


@functools.lru_cache(maxsize=256)
def _layout_of(treedef, leaves, shared: bool) -> Layout:
    lane = jax.ShapeDtypeStruct((1,), jnp.int32)
    state = jax.tree.unflatten(treedef, [jax.ShapeDtypeStruct(shape + (1,), dtype) for shape, dtype in leaves])
    return Layout.of((state, lane if shared else None, jax.ShapeDtypeStruct((1,), jnp.uint32), lane))


# What every rung reads besides its lanes, the params, the run groups' size and the groups' keys, travels
# as one small int32 array (a float field and the keys' words by their bits): on 2 CPU devices one
# replicated array cost 0.05 ms to put, the params and a key array apart 0.4 ms.

@functools.lru_cache(maxsize=None)
def scalar_fields(cls: type = KeepAwayParams) -> tuple[tuple[str, bool], ...]:
    """``(name, is float)`` of every field of the params dataclass ``cls``, in order, by its declared type:
    ``int`` travels as an int32, ``float`` as a float32's bits (either may also be declared ``| jax.Array``,
    a traced value). Any other declared type is refused (a TypeError naming the field): a float taken for
    an int would be truncated silently, whatever its default."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        kinds = set(typing.get_args(hint)) if isinstance(hint, types.UnionType) or typing.get_origin(
            hint) is typing.Union else {hint}
        kinds.discard(jax.Array)
        if kinds not in ({int}, {float}):
            raise TypeError(f"{cls.__name__}.{f.name}: the evaluator passes params to its compiled calls as int32 "
                            f"or float32 scalars; declare the field int or float (optionally | jax.Array), "
                            f"not {hint!r}")
        out.append((f.name, kinds == {float}))
    return tuple(out)


def pack_scalars(params, group_size: int, keys: jax.Array) -> np.ndarray:
    """``params`` (field after field, :func:`scalar_fields`), the run groups' size and the words of their
    ``keys`` in one int32 array, on the host."""
    vals = [np.float32(getattr(params, f)).view(np.int32) if is_float else np.int32(getattr(params, f))
            for f, is_float in scalar_fields(type(params))]
    words = np.asarray(jax.random.key_data(keys)).view(np.int32).reshape(-1)
    return np.concatenate([np.array(vals + [group_size], np.int32), words])


def unpack_scalars(scalars: jax.Array, n_groups: int, impl: str,
                   cls: type = KeepAwayParams) -> tuple[Any, jax.Array, jax.Array]:
    """The params (a ``cls``), the run groups' size and their keys ``[n_groups]`` of PRNG ``impl`` that
    :func:`pack_scalars` packed."""
    fields = scalar_fields(cls)
    n = len(fields)
    vals = {f: jax.lax.bitcast_convert_type(scalars[i], jnp.float32) if is_float else scalars[i]
            for i, (f, is_float) in enumerate(fields)}
    words = jax.lax.bitcast_convert_type(scalars[n + 1:], jnp.uint32).reshape(n_groups, -1)
    return cls(**vals), scalars[n], jax.random.wrap_key_data(words, impl=impl)


def live_first(done: jax.Array, k: int) -> jax.Array:
    """The first ``k`` lane indices when live lanes are put before finished ones, each in lane order:
    ``argsort(done, stable=True)[:k]``, from prefix counts and one scatter (a sort cost 2-3x more)."""
    n = done.shape[-1]
    live = ~done
    seen = jnp.cumsum(live, dtype=jnp.int32)  # live lanes up to and including each lane
    i = jnp.arange(n, dtype=jnp.int32)
    pos = jnp.where(live, seen - 1, seen[-1] + i - seen)  # finished lanes after all the live ones
    return jnp.zeros(n, jnp.int32).at[pos].set(i, unique_indices=True)[:k]


# Placement: the lanes (the last axis of every lane array) split over a mesh of the first n_dev
# devices along its one axis "lanes"; everything else replicated. Every sharding of the evaluator,
# shard_map's specs and device_put's NamedShardings alike, is built from these.
REPLICATED = jax.sharding.PartitionSpec()
# per device results stacked along a leading axis, one row per device ([n_dev, ...])
PER_DEVICE = jax.sharding.PartitionSpec("lanes", None)
# per device and rung ([n_dev, rungs, ...])
PER_DEVICE_RUNGS = jax.sharding.PartitionSpec("lanes", None, None)
# a shared table's rows (its leading axis: the parameter sets) split over the mesh, each device holding
# the rows its own lanes play (:func:`rows_split`)
TABLE_ROWS = jax.sharding.PartitionSpec("lanes")


def mesh(n_dev: int) -> jax.sharding.Mesh:
    """The first ``n_dev`` devices of this process, the lanes split over them."""
    return jax.sharding.Mesh(np.array(jax.local_devices()[:n_dev]), ("lanes",))


def lane_specs(tree):
    """Lanes (the last axis of every leaf) split over the mesh."""
    return jax.tree.map(lambda a: jax.sharding.PartitionSpec(*([None] * (a.ndim - 1)), "lanes"), tree)


def replicated_specs(tree):
    """Every leaf of ``tree`` whole on every device."""
    return jax.tree.map(lambda _: REPLICATED, tree)


def row_specs(tree):
    """Every leaf's rows (its leading axis) split over the mesh."""
    return jax.tree.map(lambda _: TABLE_ROWS, tree)


def put_rows(tree, n_dev: int):
    """``tree``'s rows split over the first ``n_dev`` devices (as it is when ``n_dev`` is 1): where a shared
    table is built (``kx.hyperneat.substrate.build``), so that the evaluator need not copy it whole onto
    every device (:func:`rows_split`)."""
    if n_dev == 1:
        return tree
    return jax.device_put(tree, jax.sharding.NamedSharding(mesh(n_dev), TABLE_ROWS))


def rows_split(tree, n_dev: int) -> bool:
    """Whether every leaf of a shared table is an array whose rows are split evenly over the first ``n_dev``
    devices (``n_dev`` > 1), as :func:`put_rows` or a computation sharded so leaves them. The evaluator's
    lanes are policy-major and never move between devices, so when the table's rows divide evenly, each
    device's lanes play exactly the rows it holds, and it reads them there instead of a whole copy
    (:func:`kx.sim.evaluate.evaluate`)."""
    if n_dev == 1:
        return False
    want = jax.sharding.NamedSharding(mesh(n_dev), TABLE_ROWS)
    leaves = jax.tree.leaves(tree)
    return bool(leaves) and all(isinstance(a, jax.Array) and a.ndim >= 1 and a.shape[0] % n_dev == 0
                                and a.sharding.is_equivalent_to(want, a.ndim) for a in leaves)


def put_lanes(tree, n_dev: int):
    """``tree``'s lanes split over the first ``n_dev`` devices (as they are when ``n_dev`` is 1)."""
    if n_dev == 1:
        return tree
    m = mesh(n_dev)
    return jax.device_put(tree, jax.tree.map(lambda sp: jax.sharding.NamedSharding(m, sp), lane_specs(tree)))


def put_replicated(tree, n_dev: int):
    """``tree`` on the devices, whole on each of the first ``n_dev`` (on the default device when 1)."""
    return jax.device_put(tree, jax.sharding.NamedSharding(mesh(n_dev), REPLICATED) if n_dev > 1 else None)


def onto_mesh(tree, n_dev: int):
    """``tree`` with every leaf committed to devices other than the first ``n_dev`` (a restored
    checkpoint's, say) copied onto them, replicated, so that one compiled call can take them all."""
    if n_dev == 1:
        return tree
    devices = set(jax.local_devices()[:n_dev])
    rep = jax.sharding.NamedSharding(mesh(n_dev), REPLICATED)
    return jax.tree.map(lambda a: jax.device_put(a, rep) if isinstance(a, jax.Array) and a.committed
                        and a.sharding.device_set != devices else a, tree)
