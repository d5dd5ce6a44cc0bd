"""Small XLA helpers shared by the simulator, the observations and the policies.

Every function here works on batch-last arrays (``[n, *B]`` for a short leading axis of agents or
candidates, ``[*B]`` per episode) and is rank-polymorphic in ``B``. Most are written as unrolled
elementwise selects rather than gathers or reductions over the short axis: on CPU, XLA fuses elementwise
code into the surrounding loop and vectorises it over the batch, while a gather or an ``argmax`` over a
leading axis of 3 to 5 entries neither fuses nor vectorises.
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
from jax.extend import core as jax_core


def col(n: int, batch_ndim: int) -> jax.Array:
    """``arange(n)`` (int32) shaped ``[n, 1, ..., 1]`` (``batch_ndim`` ones) to broadcast against
    ``[n, *B]``."""
    return jnp.arange(n, dtype=jnp.int32).reshape((n,) + (1,) * batch_ndim)


def pick(values: jax.Array, index: jax.Array) -> jax.Array:
    """``values[index]`` along axis 0 for batch-last ``values [n, *B]`` and ``index [*B]``.

    An unrolled select, not a gather or a reduction: for a handful of agents it stays elementwise and
    fuses into the surrounding loop. An ``index`` outside ``[0, n)`` gives ``values[0]``.
    """
    out = values[0]
    for i in range(1, values.shape[0]):
        out = jnp.where(index == i, values[i], out)
    return out


def argmin0(values: jax.Array) -> jax.Array:
    """First index (int32, ``[*B]``) of the minimum along a short axis 0 of ``values [n, *B]``,
    unrolled (elementwise only; ties go to the lower index)."""
    best, arg = values[0], jnp.zeros(values.shape[1:], jnp.int32)
    for i in range(1, values.shape[0]):
        better = values[i] < best
        best, arg = jnp.where(better, values[i], best), jnp.where(better, i, arg)
    return arg


def any0(values: jax.Array) -> jax.Array:
    """Logical or along a short axis 0 of boolean ``values [n, *B]``, unrolled (elementwise only)."""
    out = values[0]
    for i in range(1, values.shape[0]):
        out = out | values[i]
    return out


def fenced(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` behind a fusion boundary: its results are computed once and stored.

    XLA CPU fuses elementwise producers into every consumer, so a large computation with two consumers
    (an x and a y) is emitted, and executed, twice. A conditional cannot be fused across; its
    predicate is always true but read at run time so that it cannot be folded away. (Under ``vmap``
    the predicate is batched, the conditional becomes a select, and only speed is lost.)

    ``fn`` is traced once, to a jaxpr whose output shapes also give the never-taken branch its zeros,
    and the conditional replays that jaxpr (tracing it a second time, as ``jax.eval_shape`` and then
    ``lax.cond`` would, cost a sixth to a quarter of the simulator's tracing, nested fences compounding;
    the program is the same, instruction for instruction).
    """
    leaf = jax.tree.leaves(args)[0]
    pred = jnp.ravel(leaf)[0] > jnp.iinfo(jnp.int32).min
    closed, shapes = jax.make_jaxpr(fn, return_shape=True)(*args)
    out_tree = jax.tree.structure(shapes)
    taken = jax_core.jaxpr_as_fun(closed)
    never = lambda *_: [jnp.zeros(s.shape, s.dtype) for s in jax.tree.leaves(shapes)]  # noqa: E731
    return jax.tree.unflatten(out_tree, jax.lax.cond(pred, taken, never, *jax.tree.leaves(args)))


def top_k_first(values: jax.Array, k: int) -> jax.Array:
    """The indices (int32 ``[k]``) of the ``k`` largest of ``values [n]``, largest first, equal values in index
    order: ``argsort(-values, stable=True)[:k]``, as ``jax.lax.top_k`` gives on CPU, but on every backend.

    ``top_k`` leaves the order of equal values to the backend, and on GPUs XLA routes a small ``k`` to kernels
    of its own whose order of equal values is not defined; ``argmax`` breaks ties to the lower index on every
    backend. So: ``k`` rounds of ``argmax``, each taking its winner out (``-inf``). For the handful that the
    start states and the mutations draw (``k`` up to 8 of a few hundred), as cheap as ``top_k``. ``values`` must
    hold no NaN and, unless ``k`` is at most the count of entries above ``-inf``, no ``-inf``."""
    out = []
    x = values
    for _ in range(k):
        i = jnp.argmax(x).astype(jnp.int32)
        out.append(i)
        x = x.at[i].set(-jnp.inf)
    return jnp.stack(out)
